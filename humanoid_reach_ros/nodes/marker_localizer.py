"""``marker_localizer``: the target object's pose from an ArUco marker, R_T_O = R_T_C C_T_M M_T_O.

A thin node around ``humanoid_reach_ros.perception.markers`` (dissertation 004, eq. 1):

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

import math
import sys
import time
from collections import Counter

import numpy as np
import pinocchio as pin
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray, PoseStamped
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image, JointState

from humanoid_reach_ros.geometry.camera import CameraCalibration
from humanoid_reach_ros.io import msgs
from humanoid_reach_ros.nodes.common import LatestOnDemand, ParamSpec, declare_parameters, run_node
from humanoid_reach_ros.perception.markers import (JointStateBuffer, MarkerDetector, camera_pose, same_camera_pose,
                                                   marker_table, object_pose)
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


# ---------------------------------------------------------------- message parsers
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


def hand_target_poses(R_T_O: list[np.ndarray], workspace) -> list[pin.SE3]:
    """[right, left] hand targets from the two objects' 4x4 poses: their positions, and
    the workspace rule's orientations (``workspace`` given) or the objects' own."""
    out = []
    for side, T in zip(("right", "left"), R_T_O):
        p = np.asarray(T[:3, 3], float)
        R = T[:3, :3] if workspace is None else workspace.hand_rotation(side, p)
        out.append(pin.SE3(np.asarray(R, float), p))
    return out


class MarkerLocalizer(Node):
    """Thin node around ``MarkerDetector``: input checks, eq. 1, publishing and diagnostics."""

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
        self.joints = JointStateBuffer(p["joint_buffer_s"])
        self.intrinsics: CameraCalibration | None = None
        self._info_stamp_s = -math.inf
        self.counts: Counter[str] = Counter()   # images, localized, no_marker, skipped, rejected, ...
        self.last_skip_reason = ""
        self.last_rejection = ""
        self.last_error_px = math.nan
        self.last_target: np.ndarray | None = None
        self.last_hands: np.ndarray | None = None
        self._skipped_reported = 0
        self._window = {"start": time.monotonic(), "images": 0, "localized": 0, "max_process_s": 0.0}
        self._last_detection: tuple[np.ndarray, float] | None = None   # camera pose and time of the last detection

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
        self._js_gap_ms = self._js_gap_ms_total = 0.0
        self._js_newest = 0.0
        self.create_subscription(CameraInfo, "head_camera/camera_info", self._on_camera_info, sensor)
        self.create_subscription(Image, "head_camera/image_raw", self._on_image, sensor)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(p["diagnostics_period_s"], self._publish_diagnostics, clock=steady)
        self.get_logger().info(
            f"marker localizer ready: {self.table.dictionary} ids {sorted(self.table.markers)}, target id "
            f"{p['target_marker_id']}, camera frame {p['camera_frame_id']}; publishing target_pose, markers"
            + ("" if self.hand_ids is None else f", dual_arm/targets from ids {list(self.hand_ids)} (right, left; "
               f"{p['hand_orientation']} orientations)"))

    # ------------------------------------------------------------ helpers
    def _skip(self, what: str, reason: str) -> None:
        self.counts[what] += 1
        self.last_skip_reason = f"{what}: {reason}"
        self.get_logger().warning(f"skipping {what} ({self.counts[what]} so far): {reason}",
                                  throttle_duration_sec=self._p["warn_throttle_s"])

    # ------------------------------------------------------------ callbacks
    def _on_joint_states(self, msg: JointState) -> None:
        joints, reason = msgs.model_joints(msg, self.model)
        if joints is None:
            self._skip("joint_states", reason)
            return
        stamp = msgs.seconds_from_time(msg.header.stamp)
        if self._js_newest > 0.0 and stamp > self._js_newest:
            gap = (stamp - self._js_newest) * 1e3
            self._js_gap_ms, self._js_gap_ms_total = max(self._js_gap_ms, gap), max(self._js_gap_ms_total, gap)
        self._js_newest = max(self._js_newest, stamp)
        self.joints.push(stamp, joints)

    def _absorb_joint_states(self) -> None:
        for msg in self.joint_queue.take_all():
            self._on_joint_states(msg)

    def _on_camera_info(self, msg: CameraInfo) -> None:
        try:
            self.intrinsics = msgs.camera_calibration(msg)
            self._info_stamp_s = msgs.seconds_from_time(msg.header.stamp)
        except ValueError as exc:
            self._skip("camera_info", str(exc))

    def _on_image(self, msg: Image) -> None:
        t0 = time.perf_counter()
        self.counts["images"] += 1
        self._window["images"] += 1
        p = self._p
        cam = self.intrinsics
        if cam is None:
            self._skip("image", "no valid camera_info received yet")
            return
        stamp_s = msgs.seconds_from_time(msg.header.stamp)
        if abs(stamp_s - self._info_stamp_s) > p["camera_info_timeout_s"]:
            self._skip("image", f"the last valid camera_info is {abs(stamp_s - self._info_stamp_s):.1f} s away "
                                f"from the image stamp (> {p['camera_info_timeout_s']:g} s)")
            return
        try:
            height, width = msgs.check_image(msg)[:2]
        except ValueError as exc:
            self._skip("image", str(exc))
            return
        if (height, width) != (cam.height, cam.width):
            self._skip("image", f"image is {width} x {height} but camera_info says {cam.width} x {cam.height}")
            return
        self._absorb_joint_states()
        joints, reason = self.joints.at(stamp_s, p["max_stamp_gap_s"])
        if joints is None:
            self._skip("image", f"no camera pose at the image stamp: {reason}")
            return
        R_T_C = camera_pose(self.model, joints, p["camera_frame_id"])
        if self._still(R_T_C):
            self.counts["skipped_still"] += 1
            return
        result = self.detector.detect(msgs.gray_from_image(msg), cam.K, cam.D)
        for mid, why in result.rejected:
            self.counts["rejected"] += 1
            self.last_rejection = f"id {mid}: {why}"
            self.get_logger().warning(f"rejected marker {self.last_rejection}",
                                      throttle_duration_sec=p["warn_throttle_s"])
        if not result.detections:
            self.counts["no_marker"] += 1
            return
        world, stamp = p["world_frame_id"], msg.header.stamp
        poses = PoseArray(header=msgs.header(world, stamp))
        hands: dict[int, np.ndarray] = {}
        for det in result.detections:
            R_T_M = R_T_C @ det.C_T_M
            poses.poses.append(msgs.pose_from_se3(pin.SE3(R_T_M[:3, :3], R_T_M[:3, 3])))
            self.last_error_px = det.reprojection_error_px
            if self.hand_ids is not None and det.marker_id in self.hand_ids:
                hands[det.marker_id] = object_pose(R_T_C, det.C_T_M, self.table.markers[det.marker_id].M_T_O)
            if det.marker_id == p["target_marker_id"]:
                R_T_O = object_pose(R_T_C, det.C_T_M, self.table.markers[det.marker_id].M_T_O)
                self.target_pub.publish(msgs.pose_stamped(pin.SE3(R_T_O[:3, :3], R_T_O[:3, 3]), world, stamp))
                self.last_target = R_T_O[:3, 3].copy()
                self.counts["localized"] += 1
                self._window["localized"] += 1
        self.markers_pub.publish(poses)
        if self.hand_ids is not None:
            self._publish_hands(hands, world, stamp)
        self._window["max_process_s"] = max(self._window["max_process_s"], time.perf_counter() - t0)

    def _still(self, R_T_C: np.ndarray) -> bool:
        """The camera is where it was at the last detection (1 mm, 1 mrad) and that was less than
        ``still_period_s`` ago: this image is skipped (else this pose becomes the last detection's)."""
        period, now, last = self._p["still_period_s"], time.monotonic(), self._last_detection
        if period > 0 and self.hand_ids is None and last is not None and now - last[1] < period \
                and same_camera_pose(R_T_C, last[0]):
            return True
        self._last_detection = (R_T_C.copy(), now)
        return False

    def _publish_hands(self, hands: dict[int, np.ndarray], world: str, stamp) -> None:
        """``/dual_arm/targets`` [right, left] when both hand markers are in this image."""
        if not all(i in hands for i in self.hand_ids):
            self.counts["hand_pair_incomplete"] += 1
            return
        try:
            out = hand_target_poses([hands[i] for i in self.hand_ids], self.workspace)
        except ValueError as exc:       # e.g. a marker at the shoulder: no orientation rule
            self._skip("hand targets", str(exc))
            return
        msg = PoseArray(header=msgs.header(world, stamp))
        msg.poses = [msgs.pose_from_se3(M) for M in out]
        self.hands_pub.publish(msg)
        self.counts["hand_pairs"] += 1
        self.last_hands = np.array([M.translation for M in out])

    # ------------------------------------------------------------ diagnostics
    def _publish_diagnostics(self) -> None:
        self._absorb_joint_states()
        now = time.monotonic()
        w, self._window = self._window, {"start": now, "images": 0, "localized": 0, "max_process_s": 0.0}
        dt = max(now - w["start"], 1e-9)
        c = self.counts
        skipped = c["image"] + c["camera_info"] + c["joint_states"]
        values = {"images_total": c["images"], "localized_total": c["localized"], "no_marker_total": c["no_marker"],
                  "rejected_total": c["rejected"], "skipped_images_total": c["image"],
                  "still_skipped_images_total": c["skipped_still"],
                  "bad_camera_info_total": c["camera_info"], "bad_joint_states_total": c["joint_states"],
                  "image_rate_hz": w["images"] / dt, "localization_rate_hz": w["localized"] / dt,
                  "max_process_ms": 1e3 * w["max_process_s"], "last_reprojection_error_px": self.last_error_px,
                  "last_skip_reason": self.last_skip_reason, "last_rejection": self.last_rejection,
                  "joint_states_buffered": len(self.joints), "joint_states_max_gap_ms": self._js_gap_ms,
                  "joint_states_max_gap_ms_since_start": self._js_gap_ms_total}
        self._js_gap_ms = 0.0
        if self.hand_ids is not None:
            values.update({"hand_pairs_total": c["hand_pairs"], "hand_pair_incomplete_total": c["hand_pair_incomplete"],
                           "skipped_hand_targets_total": c["hand targets"]})
        if self.last_target is not None:
            values.update({"target_x_m": self.last_target[0], "target_y_m": self.last_target[1],
                           "target_z_m": self.last_target[2]})
        level, message = msgs.LEVEL_OK, f"localizing at {w['localized'] / dt:.1f} Hz"
        if self._window_skips(skipped):
            level, message = msgs.LEVEL_WARN, f"skipping input: {self.last_skip_reason}"
        elif w["images"] == 0:
            level, message = msgs.LEVEL_WARN, "no images received"
        elif w["localized"] == 0:
            level, message = msgs.LEVEL_WARN, (f"target marker {self._p['target_marker_id']} not seen"
                                               + (f" (last rejection: {self.last_rejection})"
                                                  if self.last_rejection else ""))
        status = msgs.diagnostic_status(f"{self.get_name()}: localization", level, message, values, self.hardware_id)
        self.diagnostics_pub.publish(msgs.diagnostic_array([status], self.get_clock().now().to_msg()))

    def _window_skips(self, skipped_total: int) -> bool:
        """Whether input was skipped since the previous diagnostics message."""
        new = skipped_total != self._skipped_reported
        self._skipped_reported = skipped_total
        return new


def main(args: list[str] | None = None) -> int:
    """Run the node until Ctrl-C / SIGTERM (exit 0); a configuration error exits 2."""
    return run_node(MarkerLocalizer, NODE_NAME, args)


if __name__ == "__main__":
    sys.exit(main())
