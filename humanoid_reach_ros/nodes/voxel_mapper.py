"""``voxel_mapper``: the measured voxel map of Kanehiro et al. (Sec. II) from the head sensors.

A thin node around ``humanoid_reach_ros.perception.mapping.MappingPipeline`` (frame routing by
forward kinematics of ``/joint_states`` at a cloud's stamp, the still-camera skip, the publish
policy, the robot-body sweep into observed-free space, the bounded input mailbox and its worker,
the counters: see that module), which fuses into ``perception.voxel_map.VoxelMap`` (003's
weighted incremental fusion with free-space clearing) and, with ``use_stereo``, matches by
``perception.stereo.StereoMatcher``. The node converts messages (``io/msgs``) and holds the interface:

* subscribes ``/head_camera/points`` (sensor_msgs/PointCloud2, sensor-data QoS) in ``map_frame``
  (``world``) or a frame of the robot's URDF (``head_camera_optical_frame``, as ``scene_sim``
  publishes by default); ``/joint_states`` (kept for ``joint_states_window_s``, taken on demand);
* with ``use_stereo``: ``/stereo/{left,right}/image_raw`` + ``camera_info``; a pair with equal
  stamps becomes a cloud in the left image's frame and is integrated the same way;
* publishes ``/voxel_map`` (PointCloud2 of occupied voxel centres, float32 x y z, frame
  ``map_frame``; reliable, transient local, depth 1: what ``reach_planner`` subscribes) and
  ``/voxel_map/markers`` (MarkerArray: one CUBE_LIST) every ``publish_period_s`` when the map
  changed, and ``/diagnostics``;
* publishes ``/voxel_map/unobserved`` (the same kind of cloud, latched): the frontier of
  unobserved space inside ``unobserved_region_{min,max}_m``, which ``reach_planner`` treats as
  occupied by default, and ``/voxel_map/unobserved_blocks``: centres of the cubes of
  ``unobserved_block_voxels``^3 voxels there that no ray has reached (the planner refuses a
  target inside one);
* serves ``~/clear`` (std_srvs/Trigger): forget the map.

Bad input -- malformed clouds (missing x/y/z, non-float fields, wrong point_step or data length),
NaN points (dropped), unknown frames, no joint states at the stamp, unsupported image encodings,
images without camera_info -- is counted and warned (throttled); the map is not touched by it.

Run: ``python -m humanoid_reach_ros.nodes.voxel_mapper --ros-args --params-file
config/voxel_mapper.yaml`` (``ros2 run humanoid_reach_ros voxel_mapper`` on an install).
"""
from __future__ import annotations

import sys

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image, JointState, PointCloud2
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from humanoid_reach_ros.io import msgs
from humanoid_reach_ros.io.endpoints import LATCHED, LatestOnDemand
from humanoid_reach_ros.nodes.common import declare_parameters, run_node
from humanoid_reach_ros.params import ParamSpec
from humanoid_reach_ros.perception.mapping import DepthJob, MappingConfig, MappingPipeline
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.spec import DEFAULT_ROBOT

NODE_NAME = "voxel_mapper"

_M = MappingConfig()
_F, _S = _M.fusion, _M.stereo
# Defaults match config/voxel_mapper.yaml (checked by test_voxel_mapper_node).
FUSION_PARAMETERS: dict[str, ParamSpec] = {
    "resolution_m": ParamSpec(_F.resolution_m, "voxel size h [m] (voxel i covers [i h, (i+1) h))", (0.001, 1.0)),
    "extent_min_m": ParamSpec(list(_F.extent_min_m), "lower corner of the mapped box in map_frame [m] (x, y, z)"),
    "extent_max_m": ParamSpec(list(_F.extent_max_m), "upper corner of the mapped box in map_frame [m] (x, y, z)"),
    "hit_weight": ParamSpec(_F.hit_weight, "w_M of an occupied observation (003's weighted fusion)", (1e-6, 1e6)),
    "free_weight": ParamSpec(_F.free_weight, "w_M of a free observation (a ray through the voxel)", (1e-6, 1e6)),
    "max_weight": ParamSpec(_F.max_weight, "cap of the accumulated weight W (fading memory: removed objects clear)",
                            (1e-6, 1e9)),
    "occupied_threshold": ParamSpec(_F.occupied_threshold, "a voxel is occupied when V exceeds this", (0.0, 0.999)),
    "min_weight": ParamSpec(_F.min_weight, "... and its weight W reaches this", (0.0, 1e9)),
    "max_range_m": ParamSpec(_F.max_range_m, "rays are truncated at this range [m] (farther points only clear)",
                             (0.01, 100.0)),
    "floor_z_m": ParamSpec(_F.floor_z_m, "points below this height [m, map_frame] are the floor: they clear, "
                           "they are not marked", (-1e3, 1e3)),
    "clear_margin_m": ParamSpec(_F.clear_margin_m, "free-space clearing stops this short of the measured point [m]",
                                (0.0, 1.0)),
    "discretize_rays": ParamSpec(_F.discretize_rays, "clear along one ray per distinct end voxel and depth map "
                                 "(OctoMap's discretized insertion; faster, may leave voxels only skipped rays cross)"),
}
STEREO_PARAMETERS: dict[str, ParamSpec] = {
    "stereo_num_disparities": ParamSpec(_S.num_disparities, "StereoSGBM numDisparities (multiple of 16)"),
    "stereo_block_size": ParamSpec(_S.block_size, "StereoSGBM blockSize (odd) [px]"),
    "stereo_uniqueness_ratio": ParamSpec(_S.uniqueness_ratio, "StereoSGBM uniquenessRatio [%] (rejects ambiguous "
                                         "matches)"),
    "stereo_lr_max_diff_px": ParamSpec(_S.lr_max_diff_px, "left-right consistency: max disparity disagreement [px]",
                                       (0.0, 100.0)),
    "stereo_subpixel": ParamSpec(_S.subpixel, "re-estimate disparities by a parabola through the block SSD (removes "
                                 "SGBM's integer locking)"),
    "stereo_min_depth_m": ParamSpec(_S.min_depth_m, "stereo points nearer than this are dropped [m]", (0.0, 100.0)),
    "stereo_max_depth_m": ParamSpec(_S.max_depth_m, "stereo points farther than this are dropped [m]", (0.01, 100.0)),
}
NODE_PARAMETERS: dict[str, ParamSpec] = {
    "map_frame": ParamSpec(_M.map_frame, "frame of the map, /voxel_map and the markers (the stance frame)"),
    "sensor_frame": ParamSpec(_M.sensor_frame, "URDF frame whose origin is the rays' origin for world-frame "
                              "clouds; empty: the robot description's head camera frame"),
    "robot_config": ParamSpec(DEFAULT_ROBOT, "robot: a name (config/robots/<name>/robot.yaml) or the path of "
                                          "a robot description (relative to config/, or absolute)"),
    "joint_states_window_s": ParamSpec(_M.joint_states_window_s, "how long joint states are kept for look-up at "
                                       "a cloud stamp [s]", (0.05, 60.0)),
    "joint_states_max_gap_s": ParamSpec(_M.joint_states_max_gap_s, "a cloud stamp may lie this far outside the "
                                        "buffered joint states [s]", (0.0, 10.0)),
    "use_stereo": ParamSpec(False, "also map the stereo pair /stereo/{left,right}/image_raw + camera_info"),
    "input_queue_depth": ParamSpec(_M.input_queue_depth, "clouds (or stereo pairs) waiting for the worker at most; "
                                   "when full, the oldest waiting one is dropped and counted (clouds_dropped_busy)",
                                   (1, 100)),
    "still_integration_period_s": ParamSpec(_M.still_integration_period_s, "while the camera has not moved (1 mm, "
                                            "1 mrad) since the last integrated depth map, integrate at most one per "
                                            "this period [s] (a static view adds nothing new; a changed scene still "
                                            "shows within it); 0 = every depth map", (0.0, 60.0)),
    "unobserved_region_min_m": ParamSpec(list(_M.unobserved_region_min_m), "box where the frontier of unobserved "
                                         "space is published (/voxel_map/unobserved): the robot's reach [m, "
                                         "map_frame]"),
    "unobserved_region_max_m": ParamSpec(list(_M.unobserved_region_max_m), "... its upper corner [m, map_frame]"),
    "unobserved_robot_clearance_m": ParamSpec(_M.unobserved_robot_clearance_m, "the self-filter margin and the "
                                              "robot-volume policy: depth points within this distance of the robot's "
                                              "collision shapes are its own links (dropped), and the shapes grown by "
                                              "it, at every posture /joint_states reported and swept between them, "
                                              "count as observed free for the unobserved-space layers (occupied "
                                              "voxels stay occupied); more counts space no sensor saw as seen [m]",
                                              (0.0, 0.1)),
    "stance_clearance_m": ParamSpec(_M.stance_clearance_m, "the stance assumption: the robot's shapes at the "
                                    "reference posture it stands in, grown by this, count as observed free: keep this "
                                    "much clear around the robot where it is placed (no gaze sees behind its waist or "
                                    "in front of its chest, where every balanced reach moves the trunk); 0 = none [m]",
                                    (0.0, 0.3)),
    "unobserved_block_voxels": ParamSpec(_M.unobserved_block_voxels, "edge of the coarse blocks of "
                                         "/voxel_map/unobserved_blocks [voxels]", (1, 50)),
    "minor_change_voxels": ParamSpec(_M.minor_change_voxels, "a map change of fewer voxels than this (occupied "
                                     "ones that flipped, plus newly observed or swept) from a still camera is "
                                     "published at most every minor_change_period_s: the depth noise on the surfaces "
                                     "of a still view flips 10-30 voxels per depth map; 0 = publish every change",
                                     (0, 10**9)),
    "minor_change_period_s": ParamSpec(_M.minor_change_period_s, "period of the publication of minor changes [s]",
                                       (0.0, 3600.0)),
    "publish_period_s": ParamSpec(0.5, "period of /voxel_map and /voxel_map/markers when the map changed [s]",
                                  (0.01, 60.0)),
    "markers_enabled": ParamSpec(True, "publish /voxel_map/markers (a CUBE_LIST of the occupied voxels)"),
    "diagnostics_period_s": ParamSpec(1.0, "period of /diagnostics [s]", (0.05, 60.0)),
    "warn_throttle_s": ParamSpec(_M.warn_throttle_s, "minimum interval between repeated warnings of one kind [s]",
                                 (0.0, 3600.0)),
    "problem_hold_s": ParamSpec(_M.problem_hold_s, "diagnostics stay WARN this long after a rejected input [s]",
                                (0.0, 3600.0)),
}
PARAMETERS: dict[str, ParamSpec] = {**FUSION_PARAMETERS, **STEREO_PARAMETERS, **NODE_PARAMETERS}


class VoxelMapperNode(Node):
    """Parameters -> ``MappingConfig``, messages -> numpy for ``MappingPipeline``, its layers ->
    messages; timers, the service and diagnostics."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = declare_parameters(self, PARAMETERS)
        config = MappingConfig.from_parameters(p)   # ValueError for a box corner that is not 3 finite numbers
        self.model = RobotModel(p["robot_config"])
        # ValueError / KeyError for bad fusion or stereo parameters, a sensor_frame the URDF lacks
        self.pipeline = MappingPipeline(config, self.model, joint_states=self._joint_states,
                                        warn=self.get_logger().warning)
        self.map_frame = config.map_frame
        self._markers_enabled = p["markers_enabled"]
        # the stereo callbacks share one mutually exclusive group: these need no lock
        self._stereo_images: dict[str, Image] = {}   # the newest of each side, until paired
        self._stereo_infos: dict[str, CameraInfo] = {}
        self.get_logger().info(f"fusion kernels warmed up in {1e3 * self.pipeline.warm_up():.0f} ms")

        self.map_pub = self.create_publisher(PointCloud2, "voxel_map", LATCHED)
        self.unobserved_pub = self.create_publisher(PointCloud2, "voxel_map/unobserved", LATCHED)
        self.blocks_pub = self.create_publisher(PointCloud2, "voxel_map/unobserved_blocks", LATCHED)
        self.markers_pub = self.create_publisher(MarkerArray, "voxel_map/markers", LATCHED)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        inputs, output = MutuallyExclusiveCallbackGroup(), MutuallyExclusiveCallbackGroup()
        self.create_subscription(PointCloud2, "head_camera/points", lambda m: self.pipeline.post(m, "clouds_received"),
                                 qos_profile_sensor_data, callback_group=inputs)
        # joint states: no callbacks; the worker takes every queued message when a depth map needs the
        # head pose (depth 400: 2 s at 200 Hz), so the executor never wakes at 200 Hz
        self.joint_queue = LatestOnDemand(self, JointState, "joint_states",
                                          QoSProfile(depth=400, reliability=ReliabilityPolicy.BEST_EFFORT))
        if p["use_stereo"]:
            for side in ("left", "right"):
                self.create_subscription(Image, f"stereo/{side}/image_raw",
                                         lambda m, s=side: self._on_stereo_image(s, m), qos_profile_sensor_data,
                                         callback_group=inputs)
                self.create_subscription(CameraInfo, f"stereo/{side}/camera_info",
                                         lambda m, s=side: self._on_camera_info(s, m), qos_profile_sensor_data,
                                         callback_group=inputs)
        self.create_service(Trigger, "~/clear", self._on_clear, callback_group=output)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(p["publish_period_s"], self._publish_map, clock=steady, callback_group=output)
        self.create_timer(p["diagnostics_period_s"], self._publish_diagnostics, clock=steady, callback_group=output)
        self.pipeline.start(self._job)
        self._publish_map()
        m = self.pipeline.map
        self.get_logger().info(
            f"voxel mapper ready: {m.shape[0]}x{m.shape[1]}x{m.shape[2]} voxels of {m.resolution_m} m over "
            f"{list(m.params.extent_min_m)}..{list(m.params.extent_max_m)} in {self.map_frame} "
            f"({m.nbytes / 1e6:.1f} MB), stereo {'on' if p['use_stereo'] else 'off'}")

    # ------------------------------------------------------------ inputs (messages -> numpy)
    def _joint_states(self):
        """The queued /joint_states as (stamp, joints) for the pipeline; a bad message is reported."""
        for msg in self.joint_queue.take_all():
            joints, reason = msgs.model_joints(msg, self.model)
            if joints is None:
                self.pipeline.problem("bad_joint_states", f"/joint_states ignored: {reason}", "joint_states_rejected")
            else:
                yield msgs.seconds_from_time(msg.header.stamp), joints

    def _on_camera_info(self, side: str, msg: CameraInfo) -> None:
        self._stereo_infos[side] = msg

    def _on_stereo_image(self, side: str, msg: Image) -> None:
        if msg.encoding not in msgs.IMAGE_ENCODINGS:
            self.pipeline.problem("stereo_encoding", f"/stereo/{side}/image_raw: unsupported encoding "
                                  f"{msg.encoding!r} (use one of {', '.join(msgs.IMAGE_ENCODINGS)}); image ignored",
                                  "stereo_rejected")
            return
        self._stereo_images[side] = msg
        left, right = self._stereo_images.get("left"), self._stereo_images.get("right")
        if left is None or right is None or left.header.stamp != right.header.stamp:
            return
        self._stereo_images.clear()
        infos = (self._stereo_infos.get("left"), self._stereo_infos.get("right"))
        if infos[0] is None or infos[1] is None:
            missing = [s for s, i in zip(("left", "right"), infos) if i is None]
            self.pipeline.problem("stereo_no_camera_info", "stereo pair ignored: no camera_info yet for "
                                  f"{', '.join(missing)}", "stereo_rejected")
            return
        self.pipeline.post((left, right, infos[0], infos[1]))

    def _job(self, item: PointCloud2 | tuple) -> DepthJob | None:
        """(The pipeline's worker) a posted cloud or stereo pair as a depth map, or None: rejected."""
        if isinstance(item, tuple):
            left, right, info_l, info_r = item
            try:
                points = self.pipeline.stereo_points(msgs.camera_calibration(info_l), msgs.camera_calibration(info_r),
                                                     msgs.gray_from_image(left), msgs.gray_from_image(right))
            except ValueError as exc:
                self.pipeline.problem("stereo_rejected", f"stereo pair rejected: {exc}", "stereo_rejected")
                return None
            return DepthJob(points, left.header.frame_id, msgs.seconds_from_time(left.header.stamp), "stereo")
        try:
            cloud = msgs.points_from_cloud(item)
        except ValueError as exc:
            self.pipeline.problem("malformed_cloud", f"/head_camera/points rejected: {exc}", "clouds_rejected")
            return None
        if cloud.dropped_nonfinite:
            self.pipeline.problem("nonfinite_points", f"/head_camera/points: dropped {cloud.dropped_nonfinite} "
                                  f"points with NaN/inf coordinates (of {cloud.dropped_nonfinite + len(cloud.points)})",
                                  "points_nonfinite", cloud.dropped_nonfinite)
        return DepthJob(cloud.points, cloud.frame_id, cloud.stamp_s, "/head_camera/points")

    # ------------------------------------------------------------ outputs (numpy -> messages)
    def _on_clear(self, req: Trigger.Request, resp: Trigger.Response) -> Trigger.Response:
        n = self.pipeline.clear()
        resp.success, resp.message = True, f"voxel map cleared ({n} occupied voxels forgotten)"
        self.get_logger().info(resp.message)
        self._publish_map(force=True)
        return resp

    def _publish_map(self, force: bool = False) -> None:
        """The layers the pipeline's publish policy releases, those that changed (the frontier
        before the map: a planner that gets the new map has the matching frontier already)."""
        layers = self.pipeline.layers_to_publish(force)
        if layers is None:
            return
        stamp = self.get_clock().now().to_msg()
        for pub, points in ((self.blocks_pub, layers.blocks), (self.unobserved_pub, layers.frontier),
                            (self.map_pub, layers.occupied)):
            if points is not None:
                pub.publish(msgs.cloud_from_points(points, self.map_frame, stamp))
        if layers.occupied is not None and self._markers_enabled:
            marker = msgs.cube_list_marker(layers.occupied, self.pipeline.map.resolution_m, self.map_frame, stamp)
            self.markers_pub.publish(msgs.marker_array([marker], True, self.map_frame, stamp))

    def diagnostic_statuses(self) -> list:
        s, name = self.pipeline.status(), self.get_name()
        return [msgs.diagnostic_status(f"{name}: map", msgs.LEVEL_OK, s.map_message, s.map_values),
                msgs.diagnostic_status(f"{name}: inputs", msgs.LEVEL_OK if s.inputs_ok else msgs.LEVEL_WARN,
                                       s.inputs_message, s.inputs_values)]

    def _publish_diagnostics(self) -> None:
        self.diagnostics_pub.publish(msgs.diagnostic_array(self.diagnostic_statuses(),
                                                           self.get_clock().now().to_msg()))

    def destroy_node(self) -> None:
        self.pipeline.stop()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """Run the node until Ctrl-C / SIGTERM (exit 0); a configuration error exits 2."""
    # single-threaded: every callback only stores (the worker thread integrates); a MultiThreadedExecutor
    # spent a whole core on its own dispatching here
    return run_node(VoxelMapperNode, NODE_NAME, args)


if __name__ == "__main__":
    sys.exit(main())
