"""``marker_localizer``: the target object's pose from an ArUco marker, R_T_O = R_T_C C_T_M M_T_O.

A thin node around ``humanoid_reach_ros.perception.localizing`` (the per-image pipeline, over
``perception/markers.py``; dissertation 004, eq. 1):

* subscribes ``/head_camera/image_raw`` (sensor_msgs/Image: mono8, rgb8, bgr8, rgba8, bgra8),
  ``/head_camera/camera_info`` (K and the distortion coefficients; the latest one is used)
  and ``/joint_states`` (buffered for ``joint_buffer_s``), all sensor-data QoS;
* per image: ArUco detection, edge-line corners, IPPE-square PnP (``C_T_M``), rejection of
  detections whose RMS reprojection error exceeds ``max_reprojection_error_px`` or whose id
  is unknown,
  ``R_T_C`` by forward kinematics at the image stamp (joint angles interpolated between the
  buffered states that bracket it), and ``M_T_O`` per id from the parameters
  ``marker_ids`` / ``marker_sizes_m`` / ``marker_object_poses``;
* publishes ``/target_pose`` (geometry_msgs/PoseStamped in ``world_frame_id``: the OBJECT
  pose R_T_O of ``target_marker_id``, e.g. the valve centre) and ``/markers``
  (geometry_msgs/PoseArray of every accepted marker's pose R_T_C C_T_M), both stamped with
  the image stamp, and ``/diagnostics`` (inputs, detections, rejections, rate);
* dual-arm hand targets (dissertation Sec. 5.2.2 / 5.3: both hands follow AR markers): when
  ``hand_marker_ids`` names two markers ``[right, left]`` and both are accepted in one
  image, publishes ``/dual_arm/targets`` (geometry_msgs/PoseArray, world frame, image
  stamp: right hand, then left hand) -- the object positions R_T_O of the two markers,
  with orientations by ``hand_orientation``: ``workspace`` (default) the dual-arm
  workspace rule of ``dual_arm_workspace`` (tool axis from the shoulder to the target, the
  rule the torso regression was trained with; the dissertation takes only positions from
  its markers) or ``marker`` (the object frame R_T_O itself). ``reach_executor`` follows
  them while its ``dual_arm_follow`` parameter is true. ``[-1, -1]`` (default): off.

Bad input -- unsupported encodings, data sizes that disagree with width/height/step,
images without (or with stale, or differently sized) camera_info, camera_info with a zero
or non-finite focal length, images whose stamp the joint-state buffer does not cover,
malformed joint states -- is skipped with a throttled warning and counted in the
diagnostics; the node keeps running.

Run: ``python -m humanoid_reach_ros.nodes.marker_localizer --ros-args --params-file
config/marker_localizer.yaml`` (``ros2 run humanoid_reach_ros marker_localizer`` on an install).
"""
from __future__ import annotations

import sys
import time
from typing import Iterator

import pinocchio as pin
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray, PoseStamped
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image, JointState

from humanoid_reach_ros.io import msgs
from humanoid_reach_ros.io.endpoints import LatestOnDemand
from humanoid_reach_ros.nodes.common import declare_parameters, run_node
from humanoid_reach_ros.params import ParamSpec
from humanoid_reach_ros.perception.localizing import JointSample, MarkerLocalizing
from humanoid_reach_ros.perception.markers import MarkerDetector, marker_table
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.spec import DEFAULT_ROBOT

NODE_NAME = "marker_localizer"

# Defaults match config/marker_localizer.yaml (checked by test_marker_localizer_node).
PARAMETERS: dict[str, ParamSpec] = {
    "dictionary": ParamSpec("DICT_4X4_50", "OpenCV ArUco dictionary of the printed markers"),
    "marker_ids": ParamSpec([7], "known marker ids"),
    "marker_sizes_m": ParamSpec([0.1], "printed black-square edge length per id [m]"),
    "marker_object_poses": ParamSpec([0.0, 0.0, 0.04, -0.5, 0.5, 0.5, 0.5],
                                     "M_T_O per id: x y z [m] qx qy qz qw of the object in the marker frame"),
    "target_marker_id": ParamSpec(7, "marker whose object pose is published on /target_pose"),
    "hand_marker_ids": ParamSpec([-1, -1], "[right, left] markers whose object poses are published as dual-arm "
                                 "hand targets on /dual_arm/targets; [-1, -1]: off"),
    "hand_orientation": ParamSpec("workspace", "hand target orientation: workspace (dual-arm workspace rule) | "
                                  "marker (the object frame)"),
    "dual_arm_workspace": ParamSpec("", "dual-arm workspace YAML (orientation rule), relative to config/ or "
                                    "absolute; empty: the robot description's dual_arm_workspace"),
    "robot_config": ParamSpec(DEFAULT_ROBOT, "robot: a name (config/robots/<name>/robot.yaml) or the path of "
                                          "a robot description (relative to config/, or absolute)"),
    "camera_frame_id": ParamSpec("", "URDF frame of the camera (R_T_C by FK); empty: the robot description's "
                                 "head camera frame"),
    "world_frame_id": ParamSpec("world", "frame of /target_pose and /markers"),
    "max_reprojection_error_px": ParamSpec(1.0, "reject detections with a larger RMS reprojection error [px]",
                                           (1e-3, 100.0)),
    "corner_refine_window_px": ParamSpec(5, "sub-pixel corner refinement half window [px]"),
    "edge_refinement": ParamSpec(True, "re-estimate corners from lines fitted to the marker's edges "
                                 "(undistorted cameras)"),
    "joint_buffer_s": ParamSpec(2.0, "/joint_states history kept for stamp lookups [s]", (0.01, 60.0)),
    "max_stamp_gap_s": ParamSpec(0.05, "image stamp this far outside / between buffered joint states -> skip [s]",
                                 (0.0, 10.0)),
    "camera_info_timeout_s": ParamSpec(2.0, "images stamped this far from the last valid camera_info [s] "
                                       "are skipped (stale intrinsics)",
                                       (0.001, 3600.0)),
    "still_period_s": ParamSpec(0.5, "while the camera has not moved (1 mm, 1 mrad) since the last detection, "
                                "detect in at most one image per this period [s] (a marker moving before a still "
                                "head is then seen at 1/still_period_s Hz); 0 = every image; not applied with "
                                "hand_marker_ids (the hands follow moving markers)", (0.0, 60.0)),
    "diagnostics_period_s": ParamSpec(1.0, "period of /diagnostics [s]", (0.05, 60.0)),
    "warn_throttle_s": ParamSpec(1.0, "minimum interval between repeated warnings [s]", (0.0, 3600.0)),
}


# ---------------------------------------------------------------- parameters of the hand markers
def hand_marker_setup(ids, orientation: str, workspace_yaml: str, known) -> tuple[tuple[int, int] | None, object]:
    """Checks the dual-arm hand marker parameters: ``(None, None)`` when off (``[-1, -1]``),
    else ``((right_id, left_id), ReachWorkspace or None)``; ``ValueError`` with the reason."""
    ids = [int(i) for i in ids]
    if len(ids) != 2:
        raise ValueError(f"hand_marker_ids needs 2 ids [right, left] (or [-1, -1]), got {ids}")
    if orientation not in ("workspace", "marker"):
        raise ValueError(f"hand_orientation must be 'workspace' or 'marker', got {orientation!r}")
    if ids == [-1, -1]:
        return None, None
    if ids[0] == ids[1]:
        raise ValueError(f"hand_marker_ids must be two different markers, got {ids}")
    unknown = [i for i in ids if i not in known]
    if unknown:
        raise ValueError(f"hand_marker_ids {unknown} are not among marker_ids {sorted(known)}")
    if orientation == "marker":
        return (ids[0], ids[1]), None
    from humanoid_reach_ros.dual_arm.torso_regression import ReachWorkspace
    return (ids[0], ids[1]), ReachWorkspace.load(workspace_yaml)


class MarkerLocalizer(Node):
    """Thin node around ``MarkerLocalizing`` (perception/localizing.py): messages, parameters, publishing."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = declare_parameters(self, PARAMETERS)
        self._p = p
        self.table = marker_table(p["dictionary"], p["marker_ids"], p["marker_sizes_m"], p["marker_object_poses"],
                                  "parameters")
        if p["target_marker_id"] not in self.table.markers:
            raise ValueError(f"target_marker_id {p['target_marker_id']} is not among marker_ids {p['marker_ids']}")
        if not 1 <= p["corner_refine_window_px"] <= 50:
            raise ValueError("corner_refine_window_px must be in 1..50")
        self.model = RobotModel(p["robot_config"])
        self.hand_ids, self.workspace = hand_marker_setup(
            p["hand_marker_ids"], p["hand_orientation"], p["dual_arm_workspace"] or self.model.spec.dual_arm_workspace,
            self.table.markers)
        self.detector = MarkerDetector(self.table, p["max_reprojection_error_px"], p["corner_refine_window_px"],
                                       p["edge_refinement"])
        p["camera_frame_id"] = p["camera_frame_id"] or self.model.camera_frame
        self.model.frame_id(p["camera_frame_id"])  # KeyError for a frame the URDF lacks
        self.hardware_id = self.model.name + " head camera"
        self.core = MarkerLocalizing(
            self.model, self.table, self.detector, camera_frame_id=p["camera_frame_id"],
            target_marker_id=p["target_marker_id"], hand_ids=self.hand_ids, workspace=self.workspace,
            joint_buffer_s=p["joint_buffer_s"], max_stamp_gap_s=p["max_stamp_gap_s"],
            camera_info_timeout_s=p["camera_info_timeout_s"], still_period_s=p["still_period_s"],
            on_skip=self._warn_skip, on_rejection=self._warn_rejection)

        sensor = qos_profile_sensor_data
        self.target_pub = self.create_publisher(PoseStamped, "target_pose", sensor)
        self.markers_pub = self.create_publisher(PoseArray, "markers", sensor)
        self.hands_pub = (self.create_publisher(PoseArray, "dual_arm/targets", sensor)
                          if self.hand_ids is not None else None)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        # no joint-state callbacks: every queued message is taken when an image needs the head pose
        self.joint_queue = LatestOnDemand(self, JointState, "joint_states",
                                          QoSProfile(depth=400, history=HistoryPolicy.KEEP_LAST,
                                                     reliability=ReliabilityPolicy.BEST_EFFORT))
        self.create_subscription(CameraInfo, "head_camera/camera_info", self._on_camera_info, sensor)
        self.create_subscription(Image, "head_camera/image_raw", self._on_image, sensor)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(p["diagnostics_period_s"], self._publish_diagnostics, clock=steady)
        self.get_logger().info(
            f"marker localizer ready: {self.table.dictionary} ids {sorted(self.table.markers)}, target id "
            f"{p['target_marker_id']}, camera frame {p['camera_frame_id']}; publishing target_pose, markers"
            + ("" if self.hand_ids is None else f", dual_arm/targets from ids {list(self.hand_ids)} (right, left; "
               f"{p['hand_orientation']} orientations)"))

    # ------------------------------------------------------------ warnings (two call sites: two throttles)
    def _warn_skip(self, what: str, count: int, reason: str) -> None:
        self.get_logger().warning(f"skipping {what} ({count} so far): {reason}",
                                  throttle_duration_sec=self._p["warn_throttle_s"])

    def _warn_rejection(self, text: str) -> None:
        self.get_logger().warning(f"rejected marker {text}", throttle_duration_sec=self._p["warn_throttle_s"])

    # ------------------------------------------------------------ callbacks
    def _joint_samples(self) -> Iterator[JointSample]:
        """The queued /joint_states as ``(stamp, joints or None, reason)``."""
        for msg in self.joint_queue.take_all():
            joints, reason = msgs.model_joints(msg, self.model)
            yield (msgs.seconds_from_time(msg.header.stamp) if joints is not None else 0.0), joints, reason

    def _on_camera_info(self, msg: CameraInfo) -> None:
        try:
            self.core.set_intrinsics(msgs.camera_calibration(msg), msgs.seconds_from_time(msg.header.stamp))
        except ValueError as exc:
            self.core.skip("camera_info", str(exc))

    def _on_image(self, msg: Image) -> None:
        t0 = time.perf_counter()
        out = self.core.localize(msgs.seconds_from_time(msg.header.stamp), lambda: msgs.check_image(msg)[:2],
                                 lambda: msgs.gray_from_image(msg), self._joint_samples)
        if out is None:
            return
        world, stamp = self._p["world_frame_id"], msg.header.stamp
        for R_T_O in out.targets:
            self.target_pub.publish(msgs.pose_stamped(pin.SE3(R_T_O[:3, :3], R_T_O[:3, 3]), world, stamp))
        poses = PoseArray(header=msgs.header(world, stamp))
        poses.poses = [msgs.pose_from_se3(pin.SE3(T[:3, :3], T[:3, 3])) for T in out.markers]
        self.markers_pub.publish(poses)
        if out.hands is not None:
            hands = PoseArray(header=msgs.header(world, stamp))
            hands.poses = [msgs.pose_from_se3(M) for M in out.hands]
            self.hands_pub.publish(hands)
        self.core.processed(time.perf_counter() - t0)

    # ------------------------------------------------------------ diagnostics
    def _publish_diagnostics(self) -> None:
        self.core.add_joint_states(self._joint_samples())
        level, message, values = self.core.diagnostics()
        status = msgs.diagnostic_status(f"{self.get_name()}: localization", level, message, values, self.hardware_id)
        self.diagnostics_pub.publish(msgs.diagnostic_array([status], self.get_clock().now().to_msg()))


def main(args: list[str] | None = None) -> int:
    """Run the node until Ctrl-C / SIGTERM (exit 0); a configuration error exits 2."""
    return run_node(MarkerLocalizer, NODE_NAME, args)


if __name__ == "__main__":
    sys.exit(main())
