"""``scene_sim``: the robot's simulated head sensors (camera, depth sensor, optional stereo pair).

The camera is fixed to the URDF frame ``camera_frame_id`` (``head_camera_optical_frame``);
its world pose ``R_T_C`` comes from the latest ``/joint_states`` by forward kinematics with
the feet fixed on the floor (``RobotModel.base_on_feet``). Every ``period_s`` the scene
(``scene_file``: pipes, valve, floor, the ArUco marker printed on the valve hub) is ray cast
once (``humanoid_reach_ros.sim.camera``) and published, all stamped with the stamp of the
``/joint_states`` message the pose came from, sensor-data QoS:

* ``/head_camera/image_raw`` (sensor_msgs/Image, ``image_encoding`` rgb8 or mono8) and
  ``/head_camera/camera_info`` (pinhole K/P, no distortion), frame ``camera_frame_id``;
* ``/head_camera/points`` (sensor_msgs/PointCloud2, float32 x y z): the depth sensor's
  points with range noise ``sigma = range_noise_per_m r^2`` and dropouts, every
  ``points_stride``-th pixel. ``points_frame: optical`` (default) publishes them in the
  camera's optical frame (``header.frame_id = camera_frame_id``: the sensor origin is the
  frame origin, as a real depth camera does); ``points_frame: world`` transforms them into
  ``world_frame_id``;
* with ``stereo_enabled``: ``/stereo/left/image_raw`` + ``camera_info`` (frame
  ``camera_frame_id``: the left camera is the head camera) and ``/stereo/right/...`` (frame
  ``stereo_right_frame_id``, ``stereo_baseline_m`` along +x of the left optical frame; its
  camera_info P carries ``Tx = -fx B`` as in ROS stereo), rendered with a procedural
  texture of amplitude ``stereo_texture_amplitude`` so that block matching finds features;
* ``/diagnostics``: joint-state input, render time and achieved rate, disabled primitives.

``disabled_primitives`` (string array, changeable at run time with set_parameters) removes
named primitives from the rendered scene (e.g. a pipe for the voxel-mapper clearing
test); unknown names are refused with a reason naming the known ones. Empty strings in the
list are ignored (an empty list cannot be written in a ROS parameter file).

Without a ``/joint_states`` newer than ``joint_states_timeout_s`` nothing is published
(diagnostic WARN). Malformed joint states get a throttled warning and are skipped.

Run: ``python -m humanoid_reach_ros.nodes.scene_sim --ros-args --params-file
config/scene_sim.yaml`` (``ros2 run humanoid_reach_ros scene_sim`` on an install).
"""
from __future__ import annotations

import math
import sys
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image, JointState, PointCloud2

from humanoid_reach_ros.geometry.camera import CameraCalibration
from humanoid_reach_ros.io import msgs
from humanoid_reach_ros.io.endpoints import LatestOnDemand
from humanoid_reach_ros.nodes.common import declare_parameters, run_node
from humanoid_reach_ros.params import ParamSpec
from humanoid_reach_ros.paths import config_path
from humanoid_reach_ros.perception.markers import camera_pose
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.spec import DEFAULT_ROBOT
from humanoid_reach_ros.sim import camera as cam
from humanoid_reach_ros.sim.scene import load_scene
from humanoid_reach_ros.sim.sensors import HeadSensors, RenderWindow, SensorSettings

NODE_NAME = "scene_sim"
POINTS_FRAMES = ("optical", "world")

# Defaults match config/scene_sim.yaml (checked by test_scene_sim_node).
PARAMETERS: dict[str, ParamSpec] = {
    "robot_config": ParamSpec(DEFAULT_ROBOT, "robot: a name (config/robots/<name>/robot.yaml) or the path of "
                                          "a robot description (relative to config/, or absolute)"),
    "scene_file": ParamSpec("scenes/plant.yaml", "scene to render, relative to config/ or absolute"),
    "camera_frame_id": ParamSpec("", "URDF frame of the head camera (optical: z forward); empty: the robot "
                                 "description's head camera frame"),
    "world_frame_id": ParamSpec("world", "the stance frame (frame of world-frame point clouds)"),
    "period_s": ParamSpec(0.1, "sensor period [s] (images, clouds)", (0.01, 60.0)),
    "width": ParamSpec(640, "image width [px]"),
    "height": ParamSpec(480, "image height [px]"),
    "horizontal_fov_rad": ParamSpec(1.0471975511965976, "horizontal field of view [rad]", (0.05, 3.0)),
    "image_encoding": ParamSpec("rgb8", "head camera image encoding", constraints="rgb8 or mono8"),
    "texture_amplitude": ParamSpec(0.0, "procedural surface texture amplitude in the head camera image "
                                   "(0 = plain shading)", (0.0, 1.0)),
    "publish_points": ParamSpec(True, "publish the depth sensor's /head_camera/points"),
    "points_frame": ParamSpec("optical", "frame of /head_camera/points",
                              constraints="optical (camera_frame_id) or world (world_frame_id)"),
    "points_stride": ParamSpec(2, "depth sensor: every points_stride-th pixel row and column"),
    "range_noise_per_m": ParamSpec(0.0025, "depth noise sigma = range_noise_per_m * range^2 [1/m]",
                                   (0.0, 1.0)),
    "dropout_probability": ParamSpec(0.02, "probability that a depth point is missing", (0.0, 1.0)),
    "min_range_m": ParamSpec(0.1, "depth sensor minimum range [m]", (0.0, 100.0)),
    "max_range_m": ParamSpec(5.0, "depth sensor maximum range [m]", (0.01, 100.0)),
    "stereo_enabled": ParamSpec(False, "publish the stereo pair /stereo/{left,right}/image_raw + camera_info"),
    "stereo_baseline_m": ParamSpec(0.07, "stereo baseline along +x of the left optical frame [m]", (0.001, 2.0)),
    "stereo_texture_amplitude": ParamSpec(0.3, "procedural texture amplitude of the stereo images", (0.0, 1.0)),
    "stereo_right_frame_id": ParamSpec("", "frame of the right stereo camera (left frame + baseline along x); "
                                       "empty: the camera frame's name + '_right'"),
    "disabled_primitives": ParamSpec([""], "scene primitives left out of the rendering (names; empty "
                                     "strings ignored)", read_only=False),
    "render_threads": ParamSpec(1, "threads of the ray cast (the numba kernel runs without the GIL)"),
    "seed": ParamSpec(0, "seed of the depth noise generator"),
    "joint_states_timeout_s": ParamSpec(0.5, "no /joint_states for this long [s] -> stop publishing",
                                        (0.001, 3600.0), read_only=False),
    "diagnostics_period_s": ParamSpec(1.0, "period of /diagnostics [s]", (0.05, 60.0)),
    "warn_throttle_s": ParamSpec(1.0, "minimum interval between repeated warnings [s]", (0.0, 3600.0)),
}


# ---------------------------------------------------------------- message builders
def camera_info_msg(camera: cam.PinholeCamera, frame_id: str, stamp, tx_m: float = 0.0) -> CameraInfo:
    """``sensor_msgs/CameraInfo`` of a distortion-free pinhole camera; ``tx_m`` is the
    stereo offset B of a right camera (P[0, 3] = -fx B)."""
    return msgs.camera_info(CameraCalibration.pinhole(camera, tx_m), frame_id, stamp)


class SceneSim(Node):
    """Thin node around ``sim.camera``: pose from /joint_states, publishing and diagnostics."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = declare_parameters(self, PARAMETERS)
        self._p = p
        if p["points_frame"] not in POINTS_FRAMES:
            raise ValueError(f"points_frame must be one of {POINTS_FRAMES}, got {p['points_frame']!r}")
        if not (1 <= p["width"] <= 8192 and 1 <= p["height"] <= 8192 and 1 <= p["points_stride"] <= 64
                and 1 <= p["render_threads"] <= 64):
            raise ValueError("width and height must be in 1..8192 px, points_stride in 1..64 and render_threads "
                             "in 1..64")
        self.model = RobotModel(p["robot_config"])
        p["camera_frame_id"] = p["camera_frame_id"] or self.model.camera_frame
        p["stereo_right_frame_id"] = p["stereo_right_frame_id"] or p["camera_frame_id"] + "_right"
        self.model.frame_id(p["camera_frame_id"])  # KeyError for a frame the URDF lacks
        self.camera = cam.PinholeCamera.from_fov(p["width"], p["height"], p["horizontal_fov_rad"])
        self.sensors = HeadSensors(load_scene(config_path(p["scene_file"])), self.camera, SensorSettings(
            p["image_encoding"], cam.DepthNoise(p["range_noise_per_m"], p["dropout_probability"], p["min_range_m"],
                                                p["max_range_m"], p["points_stride"]) if p["publish_points"] else None,
            p["points_frame"] == "world", p["stereo_baseline_m"] if p["stereo_enabled"] else None,
            cam.RenderStyle(texture_amplitude=p["texture_amplitude"]),
            cam.RenderStyle(texture_amplitude=p["stereo_texture_amplitude"]), p["render_threads"]), p["seed"])
        self.sensors.disable(p["disabled_primitives"])
        self.hardware_id = self.model.name + " head sensors"
        self._images: tuple = ()         # the last frame's Image messages (reused, new stamp, while it is)
        self._last_stamp_ns: int | None = None
        self.counters = self.sensors.counters
        self._window = RenderWindow()

        sensor = qos_profile_sensor_data
        self.image_pub = self.create_publisher(Image, "head_camera/image_raw", sensor)
        self.info_pub = self.create_publisher(CameraInfo, "head_camera/camera_info", sensor)
        self.points_pub = self.create_publisher(PointCloud2, "head_camera/points", sensor) \
            if p["publish_points"] else None
        self.stereo_pubs = None
        if p["stereo_enabled"]:
            self.stereo_pubs = tuple((self.create_publisher(Image, f"stereo/{side}/image_raw", sensor),
                                      self.create_publisher(CameraInfo, f"stereo/{side}/camera_info", sensor))
                                     for side in ("left", "right"))
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        # the camera pose at each frame only: the latest joint state taken per frame (no 200 Hz callbacks)
        self.joint_states = LatestOnDemand(self, JointState, "joint_states", sensor)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.render_timer = self.create_timer(p["period_s"], self._tick, clock=steady)
        self.diagnostics_timer = self.create_timer(p["diagnostics_period_s"], self._publish_diagnostics, clock=steady)
        outputs = ["head_camera/image_raw", "head_camera/camera_info"]
        if self.points_pub is not None:
            outputs.append(f"head_camera/points ({p['points_frame']} frame)")
        if self.stereo_pubs is not None:
            outputs.append(f"stereo pair (baseline {p['stereo_baseline_m']:g} m)")
        self.get_logger().info(
            f"scene sensors ready: scene {self.sensors.scene_full.name!r} ({len(self.sensors.scene.primitives)} "
            f"primitives rendered), "
            f"camera {p['camera_frame_id']} {self.camera.width}x{self.camera.height} "
            f"f={self.camera.fx:.1f} px at {1.0 / p['period_s']:.1f} Hz; publishing {', '.join(outputs)}")

    # ------------------------------------------------------------ parameters
    def _validate_parameters(self, params: list[Parameter]) -> SetParametersResult:
        for prm in params:
            if prm.name == "disabled_primitives":
                if prm.type_ != Parameter.Type.STRING_ARRAY:
                    return SetParametersResult(successful=False,
                                               reason="disabled_primitives must be a list of primitive names")
                try:
                    self.sensors.without(list(prm.value))
                except KeyError as exc:
                    return SetParametersResult(successful=False, reason=str(exc.args[0]))
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params: list[Parameter]) -> None:
        for prm in params:
            if prm.name == "disabled_primitives":
                self.sensors.disable(list(prm.value))
                self.get_logger().info(f"disabled primitives: {self.sensors.disabled or 'none'} "
                                       f"({len(self.sensors.scene.primitives)} primitives rendered)")
            self._p[prm.name] = prm.value

    # ------------------------------------------------------------ callbacks
    def _on_joint_states(self, msg: JointState) -> None:
        """A joint state as if it had arrived (in-process use)."""
        self.joint_states.put(msg)

    def _tick(self) -> None:
        msg, age = self.joint_states.latest(), self.joint_states.age_s()
        if msg is None or age > self._p["joint_states_timeout_s"]:
            return
        stamp_ns = msgs.nanoseconds_from_time(msg.header.stamp)
        if stamp_ns == self._last_stamp_ns:
            return  # no new joint state since the last frame: nothing new to stamp
        joints, reason = msgs.model_joints(msg, self.model)
        if joints is None:
            n = self.counters.count("bad_joint_states")
            self.counters.set(last_bad_joint_states=reason)
            self.get_logger().warning(f"skipping /joint_states ({n} so far): {reason}",
                                      throttle_duration_sec=self._p["warn_throttle_s"])
            self._last_stamp_ns = stamp_ns
            return
        self._last_stamp_ns = stamp_ns
        t0 = time.perf_counter()
        self.publish_frame(camera_pose(self.model, joints, self._p["camera_frame_id"]), msg.header.stamp)
        self._window.add(time.perf_counter() - t0)

    def publish_frame(self, T_wc: np.ndarray, stamp) -> None:
        """Render and publish one frame of every enabled sensor at camera pose ``T_wc``."""
        p, frame = self._p, self._p["camera_frame_id"]
        f = self.sensors.frame(T_wc)
        frames = (frame, p["stereo_right_frame_id"])
        if f.reused and self._images:   # the same images: the same messages, new stamps
            for m in self._images:
                m.header.stamp = stamp
        else:
            self._images = (msgs.image_msg(f.image, p["image_encoding"], frame, stamp),
                            *(msgs.image_msg(im, "mono8", fid, stamp) for im, fid in zip(f.stereo or (), frames)))
        self.image_pub.publish(self._images[0])
        self.info_pub.publish(camera_info_msg(self.camera, frame, stamp))
        if self.points_pub is not None:
            self.points_pub.publish(msgs.cloud_from_points(f.points, p["world_frame_id"] if p["points_frame"] == "world"
                                                           else frame, stamp))
        if self.stereo_pubs is not None:
            for (img_pub, info_pub), msg, fid, tx in zip(self.stereo_pubs, self._images[1:], frames,
                                                         (0.0, p["stereo_baseline_m"])):
                img_pub.publish(msg)
                info_pub.publish(camera_info_msg(self.camera, fid, stamp, tx))

    # ------------------------------------------------------------ diagnostics
    def _publish_diagnostics(self) -> None:
        w, name, p = self._window.report(), self.get_name(), self._p
        age, rate = self.joint_states.age_s(), w["rate_hz"]
        c = self.counters.snapshot()
        values = {"frames_total": c.frames, "rate_hz": rate, "nominal_rate_hz": 1.0 / p["period_s"],
                  "mean_render_ms": w["mean_render_ms"], "max_render_ms": w["max_render_ms"],
                  "joint_states_age_s": age if math.isfinite(age) else "never",
                  "bad_joint_states_total": c.bad_joint_states, "frames_from_cache": c.reused_frames,
                  "last_bad_joint_states": c.last_bad_joint_states,
                  "disabled_primitives": ",".join(n for n in p["disabled_primitives"] if n) or "none",
                  "width": self.camera.width, "height": self.camera.height}
        level, message = msgs.LEVEL_OK, f"publishing at {rate:.1f} Hz"
        if self.joint_states.latest() is None:
            level, message = msgs.LEVEL_WARN, "no /joint_states yet: camera pose unknown, nothing published"
        elif age > p["joint_states_timeout_s"]:
            level, message = msgs.LEVEL_WARN, f"/joint_states stale ({age:.1f} s): nothing published"
        elif c.bad_joint_states and w["frames"] == 0:
            level, message = msgs.LEVEL_WARN, f"skipping malformed /joint_states: {c.last_bad_joint_states}"
        status = msgs.diagnostic_status(f"{name}: sensors", level, message, values, self.hardware_id)
        self.diagnostics_pub.publish(msgs.diagnostic_array([status], self.get_clock().now().to_msg()))


def main(args: list[str] | None = None) -> int:
    """Run the node until Ctrl-C / SIGTERM (exit 0); a configuration error exits 2."""
    return run_node(SceneSim, NODE_NAME, args)


if __name__ == "__main__":
    sys.exit(main())
