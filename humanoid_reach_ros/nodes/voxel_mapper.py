"""``voxel_mapper``: the measured voxel map of Kanehiro et al. (Sec. II) from the head sensors.

A thin node around ``humanoid_reach_ros.perception.voxel_map.VoxelMap`` (003's weighted
incremental fusion with free-space clearing; see that module) and, with ``use_stereo``,
``humanoid_reach_ros.perception.stereo.StereoMatcher`` (rectification, semi-global
matching, left-right consistency check):

* subscribes ``/head_camera/points`` (sensor_msgs/PointCloud2, sensor-data QoS). A cloud in
  ``map_frame`` (``world``) is integrated as is; a cloud in a frame of the robot's URDF
  (``head_camera_optical_frame``, as ``scene_sim`` publishes by default) is placed by
  forward kinematics of ``/joint_states`` at the cloud's stamp (interpolated; feet fixed
  on the floor, ``RobotModel.base_on_feet``; an unstamped cloud (stamp 0) takes the newest
  joint state). The rays' origin, needed for free-space
  clearing, is the ``sensor_frame`` origin by the same forward kinematics (for a world-frame
  cloud without joint states at its stamp the points are marked but nothing is cleared).
  Any other frame is unknown: throttled warning + diagnostic, the cloud is not used;
* subscribes ``/joint_states`` (kept for ``joint_states_window_s``);
* with ``use_stereo``: ``/stereo/{left,right}/image_raw`` + ``camera_info``; a pair with equal
  stamps becomes a cloud in the left image's frame and is integrated the same way;
* publishes ``/voxel_map`` (PointCloud2 of occupied voxel centres, float32 x y z, frame
  ``map_frame``; reliable, transient local, depth 1: what ``reach_planner`` subscribes) and
  ``/voxel_map/markers`` (MarkerArray: one CUBE_LIST) every ``publish_period_s`` when the map
  changed, and ``/diagnostics``;
* publishes ``/voxel_map/unobserved`` (the same kind of cloud, latched): the frontier of
  unobserved space inside ``unobserved_region_{min,max}_m`` -- voxels no ray has reached
  that touch observed free space (``VoxelMap.frontier_centers``). A path from where the
  robot stands into space nobody has seen crosses it; ``reach_planner`` treats it as
  occupied by default. The space the robot's body has been in (its collision shapes grown by
  ``unobserved_robot_clearance_m`` at every posture ``/joint_states`` reported while the map
  was published) counts as observed free there: a head camera never sees around its own body
  (a named simplification: an obstacle that moved into it since would not be known); and
  ``/voxel_map/unobserved_blocks``: centres of the cubes of
  ``unobserved_block_voxels``^3 voxels inside the same box that no ray has reached (with
  nothing observed there is no frontier; the planner refuses a target inside such a cube);
* serves ``~/clear`` (std_srvs/Trigger): forget the map.

Throughput policy: the subscription callbacks only store clouds (or stereo pairs) in a
bounded mailbox of ``input_queue_depth``; a worker thread converts them in arrival order and
integrates them in the numba kernel. A short stall (a busy core, the first integrations) is
absorbed, so no view of a head scan is lost; a cloud that arrives when the mailbox is full
pushes out the oldest waiting one, counted as dropped: the node never queues without bound,
and the map's memory is fixed by the extent (``VoxelMap`` is a dense array over it), whatever
the input rate.

Bad input -- malformed clouds (missing x/y/z, non-float fields, wrong point_step or data
length), NaN points (dropped and counted), unknown frames, no joint states at the stamp,
unsupported image encodings, images without camera_info -- gets a throttled warning and a
diagnostic; the map is not touched by a rejected message.

Run: ``python -m humanoid_reach_ros.nodes.voxel_mapper --ros-args --params-file
config/voxel_mapper.yaml`` (``ros2 run humanoid_reach_ros voxel_mapper`` on an install).
"""
from __future__ import annotations

import collections
import math
import sys
import threading
import time
import traceback
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Point
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image, JointState, PointCloud2
from std_srvs.srv import Trigger
from visualization_msgs.msg import Marker, MarkerArray

from humanoid_reach_ros.io import msgs
from humanoid_reach_ros.nodes.common import LatestOnDemand, LATCHED, ParamSpec, declare_parameters, run_node
from humanoid_reach_ros.perception.markers import JointStateBuffer, camera_pose, same_camera_pose
from humanoid_reach_ros.perception.stereo import StereoCalibration, StereoMatcher, StereoParams
from humanoid_reach_ros.perception.voxel_map import FusionParams, VoxelMap
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.spec import DEFAULT_ROBOT
from humanoid_reach_ros.robot.shapes import load_collision_model

NODE_NAME = "voxel_mapper"

_F = FusionParams()
_S = StereoParams()
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
    "map_frame": ParamSpec("world", "frame of the map, /voxel_map and the markers (the stance frame)"),
    "sensor_frame": ParamSpec("", "URDF frame whose origin is the rays' origin for world-frame clouds; empty: "
                              "the robot description's head camera frame"),
    "robot_config": ParamSpec(DEFAULT_ROBOT, "robot: a name (config/robots/<name>/robot.yaml) or the path of "
                                          "a robot description (relative to config/, or absolute)"),
    "joint_states_window_s": ParamSpec(2.0, "how long joint states are kept for look-up at a cloud stamp [s]",
                                       (0.05, 60.0)),
    "joint_states_max_gap_s": ParamSpec(0.1, "a cloud stamp may lie this far outside the buffered joint states [s]",
                                        (0.0, 10.0)),
    "use_stereo": ParamSpec(False, "also map the stereo pair /stereo/{left,right}/image_raw + camera_info"),
    "input_queue_depth": ParamSpec(4, "clouds (or stereo pairs) waiting for the worker at most; when full, the "
                                   "oldest waiting one is dropped and counted (clouds_dropped_busy)", (1, 100)),
    "still_integration_period_s": ParamSpec(1.0, "while the camera has not moved (1 mm, 1 mrad) since the last "
                                            "integrated depth map, integrate at most one per this period [s] (a "
                                            "static view adds nothing new; a changed scene still shows within it); "
                                            "0 = every depth map", (0.0, 60.0)),
    "unobserved_region_min_m": ParamSpec([-1.0, -1.0, 0.1], "box where the frontier of unobserved space is "
                                         "published (/voxel_map/unobserved): the robot's reach [m, map_frame]"),
    "unobserved_region_max_m": ParamSpec([1.3, 1.0, 2.0], "... its upper corner [m, map_frame]"),
    "unobserved_robot_clearance_m": ParamSpec(0.25, "space within this distance of the robot's collision shapes, at "
                                              "every posture /joint_states reported, counts as observed free for "
                                              "the unobserved-space layers (a head camera cannot see around its own "
                                              "body; occupied voxels stay occupied) [m]", (0.0, 1.0)),
    "unobserved_block_voxels": ParamSpec(5, "edge of the coarse blocks of /voxel_map/unobserved_blocks [voxels]",
                                         (1, 50)),
    "minor_change_voxels": ParamSpec(100, "a map change of fewer voxels than this (occupied ones that flipped, "
                                     "plus newly observed or swept) from a still camera is published at most every "
                                     "minor_change_period_s: the depth noise on the surfaces of a still view flips "
                                     "10-30 voxels per depth map; 0 = publish every change", (0, 10**9)),
    "minor_change_period_s": ParamSpec(5.0, "period of the publication of minor changes [s]", (0.0, 3600.0)),
    "publish_period_s": ParamSpec(0.5, "period of /voxel_map and /voxel_map/markers when the map changed [s]",
                                  (0.01, 60.0)),
    "markers_enabled": ParamSpec(True, "publish /voxel_map/markers (a CUBE_LIST of the occupied voxels)"),
    "diagnostics_period_s": ParamSpec(1.0, "period of /diagnostics [s]", (0.05, 60.0)),
    "warn_throttle_s": ParamSpec(2.0, "minimum interval between repeated warnings of one kind [s]", (0.0, 3600.0)),
    "problem_hold_s": ParamSpec(5.0, "diagnostics stay WARN this long after a rejected input [s]", (0.0, 3600.0)),
}
PARAMETERS: dict[str, ParamSpec] = {**FUSION_PARAMETERS, **STEREO_PARAMETERS, **NODE_PARAMETERS}


def fusion_params(p: dict[str, Any]) -> FusionParams:
    return FusionParams(
        resolution_m=p["resolution_m"], extent_min_m=tuple(float(v) for v in p["extent_min_m"]),
        extent_max_m=tuple(float(v) for v in p["extent_max_m"]), hit_weight=p["hit_weight"],
        free_weight=p["free_weight"], max_weight=p["max_weight"], occupied_threshold=p["occupied_threshold"],
        min_weight=p["min_weight"], max_range_m=p["max_range_m"], floor_z_m=p["floor_z_m"],
        clear_margin_m=p["clear_margin_m"], discretize_rays=p["discretize_rays"])


def stereo_params(p: dict[str, Any]) -> StereoParams:
    return StereoParams(num_disparities=p["stereo_num_disparities"], block_size=p["stereo_block_size"],
                        uniqueness_ratio=p["stereo_uniqueness_ratio"], subpixel=p["stereo_subpixel"],
                        lr_max_diff_px=p["stereo_lr_max_diff_px"], min_depth_m=p["stereo_min_depth_m"],
                        max_depth_m=p["stereo_max_depth_m"])


def cube_list_marker(centres: np.ndarray, size_m: float, frame_id: str, stamp, ns: str = "voxel_map",
                     color: tuple[float, float, float, float] = (0.3, 0.6, 0.9, 0.8)) -> Marker:
    """One CUBE_LIST marker of cubes of edge ``size_m`` at ``centres`` (N, 3)."""
    m = Marker(header=msgs.header(frame_id, stamp), ns=ns, id=0, type=Marker.CUBE_LIST, action=Marker.ADD)
    m.pose.orientation.w = 1.0
    m.scale.x = m.scale.y = m.scale.z = float(size_m)
    m.color.r, m.color.g, m.color.b, m.color.a = color
    m.points = [Point(x=x, y=y, z=z) for x, y, z in np.asarray(centres, dtype=float).tolist()]
    return m


@dataclass
class MapperCounters:
    """What happened to the inputs (diagnostics)."""

    clouds_received: int = 0
    clouds_integrated: int = 0
    clouds_dropped_busy: int = 0
    clouds_rejected: int = 0
    unknown_frame: int = 0
    no_pose: int = 0
    points_integrated: int = 0
    points_nonfinite: int = 0
    points_outside: int = 0
    points_floor: int = 0
    points_beyond_range: int = 0
    stereo_pairs: int = 0
    stereo_rejected: int = 0
    joint_states_rejected: int = 0
    clouds_skipped_still: int = 0
    minor_changes_deferred: int = 0
    last_integration_s: float = 0.0
    last_integrated_stamp_s: float = 0.0      # header stamp of the newest depth map in the map (how fresh it is)
    integration_time_s: float = 0.0
    last_problem: str = ""
    last_problem_time: float = -1e9
    clears: int = 0
    problems: dict[str, int] = field(default_factory=dict)


@dataclass(frozen=True)
class Job:
    """A depth map waiting for the worker: points (N, 3) in ``frame``, stamp, source."""

    points: np.ndarray
    frame: str
    stamp_s: float
    source: str


class VoxelMapperNode(Node):
    """Conversions, pose look-up, a worker thread and publishing; fusion is ``VoxelMap``'s."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = declare_parameters(self, PARAMETERS)
        self._p = p
        for name in ("extent_min_m", "extent_max_m", "unobserved_region_min_m", "unobserved_region_max_m"):
            if len(p[name]) != 3 or not all(math.isfinite(v) for v in p[name]):
                raise ValueError(f"{name} must have 3 finite entries (x, y, z), got {list(p[name])}")
        self.map = VoxelMap(fusion_params(p))   # ValueError for bad fusion parameters
        self.map_frame: str = p["map_frame"]
        self.model = RobotModel(p["robot_config"])
        p["sensor_frame"] = p["sensor_frame"] or self.model.camera_frame
        self.model.frame_id(p["sensor_frame"])  # KeyError for a frame the URDF lacks
        self.joint_buffer = JointStateBuffer(p["joint_states_window_s"])
        self.stereo: StereoMatcher | None = None
        self._stereo_params = stereo_params(p)
        self._stereo_params.validate()
        self.counters = MapperCounters()
        self._map_lock = threading.Lock()
        self._state_lock = threading.Lock()
        self._cond = threading.Condition()
        # PointCloud2s or stereo tuples not yet taken by the worker, oldest first
        self._mailbox: collections.deque[Any] = collections.deque()
        self._stop = False
        self._published_version = -1     # VoxelMap.version last published
        self._published_mask: np.ndarray | None = None     # occupied voxels last published
        self._published_counts = (0, 0)   # observed and swept voxels last published
        self._published_time = -math.inf
        self._moved_since_publish = False   # a depth map from a new camera pose was integrated since
        self._view_moved = False            # (worker) the depth map being integrated is from a new pose
        self._last_warn: dict[str, float] = {}
        self._stereo_left: Image | None = None
        self._stereo_right: Image | None = None
        self._stereo_infos: dict[str, CameraInfo] = {}
        self._newest_joint_stamp = 0.0
        self._absorb_lock = threading.Lock()   # worker and diagnostics both take joint states
        self._last_integrated: tuple[np.ndarray, float] | None = None   # camera pose and time of the last map update
        self._published_centres: np.ndarray | None = None

        t0 = time.perf_counter()   # compile / load the numba kernels before the first cloud
        self.map.integrate(np.array([[0.0, 0.0, 1.0]]), np.eye(4))
        self.map.occupied_centers()
        self.map.clear()
        self.get_logger().info(f"fusion kernels warmed up in {1e3 * (time.perf_counter() - t0):.0f} ms")

        self.map_pub = self.create_publisher(PointCloud2, "voxel_map", LATCHED)
        self.unobserved_pub = self.create_publisher(PointCloud2, "voxel_map/unobserved", LATCHED)
        self.blocks_pub = self.create_publisher(PointCloud2, "voxel_map/unobserved_blocks", LATCHED)
        self._published_frontier: np.ndarray | None = None
        self.collision_model = load_collision_model(None, self.model)
        self._swept_joints: np.ndarray | None = None   # the posture last marked as swept
        self._published_blocks: np.ndarray | None = None
        self.markers_pub = self.create_publisher(MarkerArray, "voxel_map/markers", LATCHED)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        inputs = MutuallyExclusiveCallbackGroup()
        output = MutuallyExclusiveCallbackGroup()
        self.create_subscription(PointCloud2, "head_camera/points", self._on_cloud, qos_profile_sensor_data,
                                 callback_group=inputs)
        # joint states: no callbacks; the worker takes every queued message when a depth map needs the
        # head pose (depth 400: 2 s at 200 Hz), so the executor never wakes at 200 Hz
        self.joint_queue = LatestOnDemand(self, JointState, "joint_states",
                                          QoSProfile(depth=400, reliability=ReliabilityPolicy.BEST_EFFORT))
        self._js_gap_ms = 0.0            # largest gap between consecutive joint-state stamps (diagnostics window)
        self._js_gap_ms_total = 0.0
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
        self._worker = threading.Thread(target=self._work, name="voxel_mapper_integrate", daemon=True)
        self._worker.start()
        self._publish_map()
        m = self.map
        self.get_logger().info(
            f"voxel mapper ready: {m.shape[0]}x{m.shape[1]}x{m.shape[2]} voxels of {m.resolution_m} m over "
            f"{list(m.params.extent_min_m)}..{list(m.params.extent_max_m)} in {self.map_frame} "
            f"({m.nbytes / 1e6:.1f} MB), stereo {'on' if p['use_stereo'] else 'off'}")

    # ------------------------------------------------------------ problems
    def _problem(self, kind: str, text: str, counter: str = "", amount: int = 1) -> None:
        """Count (also into ``MapperCounters.<counter>`` by ``amount``), remember for diagnostics,
        and warn at most once per ``warn_throttle_s`` per kind."""
        now = time.monotonic()
        with self._state_lock:
            c = self.counters
            if counter:
                setattr(c, counter, getattr(c, counter) + amount)
            c.problems[kind] = c.problems.get(kind, 0) + 1
            c.last_problem, c.last_problem_time = f"{kind}: {text}", now
            last = self._last_warn.get(kind, -1e9)
            if now - last < self._p["warn_throttle_s"]:
                return
            self._last_warn[kind] = now
            n = c.problems[kind]
        self.get_logger().warning(f"{text} ({kind}, {n} so far)")

    # ------------------------------------------------------------ inputs
    def _on_joint_states(self, msg: JointState) -> None:
        """One /joint_states message into the look-up buffer (the worker, via :meth:`_absorb_joint_states`)."""
        joints, reason = msgs.model_joints(msg, self.model)
        if joints is None:
            self._problem("bad_joint_states", f"/joint_states ignored: {reason}", "joint_states_rejected")
            return
        with self._state_lock:
            self._newest_joint_stamp = msgs.seconds_from_time(msg.header.stamp)
            self.joint_buffer.push(self._newest_joint_stamp, joints)

    def _absorb_joint_states(self) -> None:
        with self._absorb_lock:
            for msg in self.joint_queue.take_all():
                previous = self._newest_joint_stamp
                self._on_joint_states(msg)
                if previous > 0.0 and self._newest_joint_stamp > previous:
                    gap = (self._newest_joint_stamp - previous) * 1e3
                    self._js_gap_ms = max(self._js_gap_ms, gap)
                    self._js_gap_ms_total = max(self._js_gap_ms_total, gap)

    def _post(self, item: Any) -> None:
        with self._cond:
            while len(self._mailbox) >= self._p["input_queue_depth"]:
                self._mailbox.popleft()
                self.counters.clouds_dropped_busy += 1
            self._mailbox.append(item)
            self._cond.notify()

    def _on_cloud(self, msg: PointCloud2) -> None:
        with self._state_lock:
            self.counters.clouds_received += 1
        self._post(msg)

    def _on_camera_info(self, side: str, msg: CameraInfo) -> None:
        with self._state_lock:
            self._stereo_infos[side] = msg

    def _on_stereo_image(self, side: str, msg: Image) -> None:
        if msg.encoding not in msgs.IMAGE_ENCODINGS:
            self._problem("stereo_encoding", f"/stereo/{side}/image_raw: unsupported encoding {msg.encoding!r} "
                          f"(use one of {', '.join(msgs.IMAGE_ENCODINGS)}); image ignored", "stereo_rejected")
            return
        with self._state_lock:
            if side == "left":
                self._stereo_left = msg
            else:
                self._stereo_right = msg
            left, right = self._stereo_left, self._stereo_right
            if left is None or right is None or left.header.stamp != right.header.stamp:
                return
            self._stereo_left = self._stereo_right = None
            infos = (self._stereo_infos.get("left"), self._stereo_infos.get("right"))
        if infos[0] is None or infos[1] is None:
            missing = [s for s, i in zip(("left", "right"), infos) if i is None]
            self._problem("stereo_no_camera_info", f"stereo pair ignored: no camera_info yet for {', '.join(missing)}",
                          "stereo_rejected")
            return
        self._post((left, right, infos[0], infos[1]))

    # ------------------------------------------------------------ worker
    def _work(self) -> None:
        while True:
            with self._cond:
                while not self._mailbox and not self._stop:
                    self._cond.wait(0.2)
                if self._stop:
                    return
                item = self._mailbox.popleft()
            try:
                job = self._stereo_job(item) if isinstance(item, tuple) else self._cloud_job(item)
                if job is not None:
                    self._integrate(job)
            except Exception as exc:  # the node never dies on an input
                self._problem("internal_error", f"internal error on an input: {type(exc).__name__}: {exc}\n"
                              f"{traceback.format_exc()}")

    def _cloud_job(self, msg: PointCloud2) -> Job | None:
        try:
            cloud = msgs.points_from_cloud(msg)
        except ValueError as exc:
            self._problem("malformed_cloud", f"/head_camera/points rejected: {exc}", "clouds_rejected")
            return None
        if cloud.dropped_nonfinite:
            self._problem("nonfinite_points", f"/head_camera/points: dropped {cloud.dropped_nonfinite} points with "
                          f"NaN/inf coordinates (of {cloud.dropped_nonfinite + len(cloud.points)})",
                          "points_nonfinite", cloud.dropped_nonfinite)
        return Job(cloud.points, cloud.frame_id, cloud.stamp_s, "/head_camera/points")

    def _stereo_job(self, item: tuple) -> Job | None:
        left, right, info_l, info_r = item
        try:
            calib = StereoCalibration.from_camera_infos(msgs.camera_calibration(info_l),
                                                        msgs.camera_calibration(info_r))
            if self.stereo is None or self.stereo.calibration != calib:
                self.stereo = StereoMatcher(calib, self._stereo_params)
            gl, gr = msgs.gray_from_image(left), msgs.gray_from_image(right)
            points = self.stereo.points(gl, gr)
        except ValueError as exc:
            self._problem("stereo_rejected", f"stereo pair rejected: {exc}", "stereo_rejected")
            return None
        with self._state_lock:
            self.counters.stereo_pairs += 1
        return Job(points, left.header.frame_id, msgs.seconds_from_time(left.header.stamp), "stereo")

    def _sensor_pose(self, frame: str, stamp_s: float) -> tuple[np.ndarray | None, str]:
        """World pose (4x4) of a URDF frame at a stamp by forward kinematics, or None and the reason."""
        self._absorb_joint_states()
        with self._state_lock:
            if stamp_s == 0.0 and len(self.joint_buffer):   # unstamped: the newest joint state
                joints, reason = self.joint_buffer.at(self._newest_joint_stamp, 0.0)
            else:
                joints, reason = self.joint_buffer.at(stamp_s, self._p["joint_states_max_gap_s"])
        if joints is None:
            return None, reason
        return camera_pose(self.model, joints, frame), ""

    def _integrate(self, job: Job) -> None:
        pts = job.points
        if job.frame == self.map_frame:
            pose, reason = self._sensor_pose(self._p["sensor_frame"], job.stamp_s)
            world = pts
            if pose is None:   # mark only: the rays' origin is unknown
                self._problem("no_pose", f"{job.source} in {job.frame!r}: no sensor origin ({reason}); points are "
                              "marked without free-space clearing")
        elif job.frame and self.model.model.existFrame(job.frame):
            pose, reason = self._sensor_pose(job.frame, job.stamp_s)
            if pose is None:
                self._problem("no_pose", f"{job.source} in {job.frame!r} ignored: no camera pose at its stamp "
                              f"({reason})", "no_pose")
                return
            world = None
        else:
            self._problem("unknown_frame", f"{job.source} ignored: unknown frame {job.frame!r} (use "
                          f"{self.map_frame!r} or a frame of the robot model, e.g. {self._p['sensor_frame']!r})",
                          "unknown_frame")
            return
        if pose is not None and self._still(pose):
            with self._state_lock:
                self.counters.clouds_skipped_still += 1
            return
        if pose is None:
            self._view_moved = True           # no pose to compare: publish at once
        t0 = time.perf_counter()
        with self._map_lock:
            self._moved_since_publish |= self._view_moved
            self._view_moved = False
            if world is None:
                st = self.map.integrate(pts, pose)
            elif pose is None:
                st = self.map.integrate(world, origin=None, mark_only=True)
            else:
                st = self.map.integrate(world, origin=pose[:3, 3])
        dt = time.perf_counter() - t0
        with self._state_lock:
            c = self.counters
            c.clouds_integrated += 1
            c.points_integrated += st.hits
            c.points_outside += st.outside
            c.points_floor += st.floor
            c.points_beyond_range += st.beyond_range
            c.last_integration_s = dt
            c.last_integrated_stamp_s = max(c.last_integrated_stamp_s, job.stamp_s)
            c.integration_time_s += dt

    def _still(self, pose: np.ndarray) -> bool:
        """The camera is where it was at the last integration (1 mm, 1 mrad) and that was less
        than ``still_integration_period_s`` ago: skip this depth map (else this pose becomes
        the last integration's)."""
        period = self._p["still_integration_period_s"]
        now = time.monotonic()
        last = self._last_integrated
        same = last is not None and same_camera_pose(pose, last[0])
        if period > 0 and same and now - last[1] < period:
            return True
        if not same:
            self._view_moved = True       # a new view: its changes are published at once
        self._last_integrated = (pose.copy(), now)
        return False

    # ------------------------------------------------------------ outputs
    def _on_clear(self, req: Trigger.Request, resp: Trigger.Response) -> Trigger.Response:
        with self._map_lock:
            n = self.map.occupied_count()
            self.map.clear()
        with self._state_lock:
            self.counters.clears += 1
        resp.success, resp.message = True, f"voxel map cleared ({n} occupied voxels forgotten)"
        self.get_logger().info(resp.message)
        self._publish_map(force=True)
        return resp

    def _sweep_robot(self) -> None:
        """Mark the space of the robot's body at its newest posture as swept (see the module
        docstring) when it moved since the last mark; a new mark is a map change."""
        self._absorb_joint_states()
        with self._state_lock:
            joints, _ = self.joint_buffer.at(self._newest_joint_stamp, 0.0) if len(self.joint_buffer) else (None, "")
        if joints is None or (self._swept_joints is not None and np.max(np.abs(joints - self._swept_joints)) < 1e-3):
            return
        q = self.model.config(joints, self.model.base_on_feet(joints))
        p0, p1, radii = self.collision_model.world_shapes(q)
        with self._map_lock:
            self.map.mark_swept(p0, p1, radii + self._p["unobserved_robot_clearance_m"])   # bumps map.version
        self._swept_joints = joints

    def _publish_map(self, force: bool = False) -> None:
        """Publish the map's layers when what they show changed: at once after a depth map
        from a new camera pose, a change of ``minor_change_voxels`` or more, or with ``force``;
        a smaller change from a still camera (the depth noise flipping surface voxels) at most
        every ``minor_change_period_s``, so that the readers (planner, executor) do not
        rebuild their collision trees every second while nothing moves."""
        self._sweep_robot()
        with self._map_lock:
            if self.map.version == self._published_version and not force:     # nothing a reader sees changed
                return
            now = time.monotonic()
            occupied = self.map.occupied_mask()
            counts = (self.map.observed_count, self.map.swept_count)
            changed = (occupied.size if self._published_mask is None
                       else int(np.count_nonzero(occupied != self._published_mask))) \
                + sum(abs(a - b) for a, b in zip(counts, self._published_counts))
            if not force and not self._moved_since_publish and changed < self._p["minor_change_voxels"] \
                    and now - self._published_time < self._p["minor_change_period_s"]:
                with self._state_lock:
                    self.counters.minor_changes_deferred += 1
                return
            self._published_mask, self._published_counts, self._published_time = occupied.copy(), counts, now
            self._moved_since_publish = False
            version = self.map.version
            centres = self.map.occupied_centers()
            region = (self._p["unobserved_region_min_m"], self._p["unobserved_region_max_m"])
            frontier = self.map.frontier_centers(*region)
            blocks = self.map.unobserved_blocks(*region, self._p["unobserved_block_voxels"])
        stamp = self.get_clock().now().to_msg()
        if self._published_blocks is None or not np.array_equal(blocks, self._published_blocks):
            self.blocks_pub.publish(msgs.cloud_from_points(blocks, self.map_frame, stamp))
            self._published_blocks = blocks
        # the frontier first: a planner that gets the new map has the matching frontier already
        if self._published_frontier is None or not np.array_equal(frontier, self._published_frontier):
            self.unobserved_pub.publish(msgs.cloud_from_points(frontier, self.map_frame, stamp))
            self._published_frontier = frontier
        if self._published_centres is None or not np.array_equal(centres, self._published_centres):
            self.map_pub.publish(msgs.cloud_from_points(centres, self.map_frame, stamp))
            if self._p["markers_enabled"]:
                self.markers_pub.publish(msgs.marker_array(
                    [cube_list_marker(centres, self.map.resolution_m, self.map_frame, stamp)], True, self.map_frame,
                    stamp))
            self._published_centres = centres
        self._published_version = version

    def diagnostic_statuses(self) -> list:
        name = self.get_name()
        self._absorb_joint_states()
        with self._map_lock:
            occupied, depth_maps = self.map.occupied_count(), self.map.depth_maps
            version, published = self.map.version, self._published_version
        with self._state_lock:
            c = MapperCounters(**{k: (dict(v) if isinstance(v, dict) else v) for k, v in vars(self.counters).items()})
            buffered = len(self.joint_buffer)
        m = self.map
        recent = time.monotonic() - c.last_problem_time < self._p["problem_hold_s"]
        mean_s = c.integration_time_s / c.clouds_integrated if c.clouds_integrated else 0.0
        values = {"occupied_voxels": occupied, "capacity_voxels": m.capacity, "memory_bytes": m.nbytes,
                  "resolution_m": m.resolution_m, "depth_maps": depth_maps, "frame_id": self.map_frame,
                  "last_integration_ms": c.last_integration_s * 1e3, "mean_integration_ms": mean_s * 1e3,
                  "last_integrated_stamp_s": f"{c.last_integrated_stamp_s:.6f}",
                  "points_per_s": (c.points_integrated + c.points_outside + c.points_floor) / c.integration_time_s
                  if c.integration_time_s > 0 else 0.0, "clears": c.clears,
                  "map_version": version, "published_version": published,
                  "unobserved_frontier_voxels": (0 if self._published_frontier is None
                                                 else len(self._published_frontier)),
                  "unobserved_blocks": 0 if self._published_blocks is None else len(self._published_blocks)}
        statuses = [msgs.diagnostic_status(f"{name}: map", msgs.LEVEL_OK,
                                           f"{occupied} occupied voxels from {depth_maps} depth maps", values)]
        values = {k: v for k, v in vars(c).items() if isinstance(v, int)}
        values["joint_states_buffered"] = buffered
        values["joint_states_max_gap_ms"], self._js_gap_ms = self._js_gap_ms, 0.0   # between stamps seen
        values["joint_states_max_gap_ms_since_start"] = self._js_gap_ms_total
        values["last_problem"] = c.last_problem
        for kind, n in sorted(c.problems.items()):
            values[f"problem_{kind}"] = n
        if recent:
            level, message = msgs.LEVEL_WARN, f"rejected input: {c.last_problem.splitlines()[0]}"
        elif c.clouds_received == 0 and c.stereo_pairs == 0:
            level, message = msgs.LEVEL_WARN, "no depth input yet"
        else:
            level, message = msgs.LEVEL_OK, (f"{c.clouds_integrated} depth maps integrated, "
                                             f"{c.clouds_dropped_busy} dropped while busy")
        statuses.append(msgs.diagnostic_status(f"{name}: inputs", level, message, values))
        return statuses

    def _publish_diagnostics(self) -> None:
        self.diagnostics_pub.publish(msgs.diagnostic_array(self.diagnostic_statuses(),
                                                           self.get_clock().now().to_msg()))

    def destroy_node(self) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        self._worker.join(timeout=5.0)
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """Run the node until Ctrl-C / SIGTERM (exit 0); a configuration error exits 2."""
    # single-threaded: every callback only stores (the worker thread integrates); a MultiThreadedExecutor
    # spent a whole core on its own dispatching here
    return run_node(VoxelMapperNode, NODE_NAME, args)


if __name__ == "__main__":
    sys.exit(main())
