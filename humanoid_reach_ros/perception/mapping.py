"""The voxel mapper's pipeline: depth maps in, the map's layers out (``voxel_mapper``'s core).

What the ``voxel_mapper`` node does with its inputs, without ROS (the node only converts
messages to numpy and back; :class:`MappingPipeline` decides everything else):

* **Frame routing.** A depth map (points (N, 3) in a frame, a stamp) in ``map_frame``
  (``world``) is integrated as is; one in a frame of the robot's URDF
  (``head_camera_optical_frame``, as ``scene_sim`` publishes by default) is placed by forward
  kinematics of the joint states at its stamp (interpolated, :class:`JointStateBuffer`; feet
  fixed on the floor, ``RobotModel.base_on_feet``; an unstamped depth map (stamp 0) takes the
  newest joint state). The rays' origin, needed for free-space clearing, is the
  ``sensor_frame`` origin by the same forward kinematics (for a world-frame depth map without
  joint states at its stamp the points are marked but nothing is cleared). Any other frame
  is unknown: counted, warned (throttled), the depth map is not used.
* **Still camera.** While the camera has not moved (1 mm, 1 mrad) since the last integrated
  depth map, at most one per ``still_integration_period_s`` is integrated (a static view adds
  nothing new; a changed scene still shows within the period); the others are counted as
  skipped.
* **Publish policy** (:meth:`MappingPipeline.layers_to_publish`, called every
  ``publish_period_s``): the layers are published when what they show changed -- at once
  after a depth map from a new camera pose, a change of ``minor_change_voxels`` or more
  (occupied voxels that flipped, plus newly observed or swept ones), or when forced (a
  clear); a smaller change from a still camera (the depth noise flipping 10-30 surface voxels
  per depth map) at most every ``minor_change_period_s``, so that the readers (planner,
  executor) do not rebuild their collision trees every second while nothing moves. Each
  layer goes out only when its points changed.
* **Unobserved space.** The frontier (``VoxelMap.frontier_centers``: voxels no ray has
  reached that touch observed free space) and the unobserved blocks (cubes of
  ``unobserved_block_voxels``^3 voxels no ray has reached) inside
  ``unobserved_region_{min,max}_m``. The space the robot's body has been in counts as observed
  free there, under the robot-volume policy of ``geometry/body_sweep.py``: its collision shapes
  grown by ``unobserved_robot_clearance_m`` (the self-filter margin, 0.03 m, derived there) at
  every posture ``/joint_states`` reported, and swept between consecutive ones (swept before
  each publication). Nothing around the body counts as observed by being near it (a named
  simplification: an obstacle that moved into the body's space since would not be known) --
  except the **stance zone**, an assumption, named and bounded: the robot's shapes at the
  reference posture it stands in (the feet where they are), grown by ``stance_clearance_m``
  (0.12 m), count as observed free from the first joint state on (and after a clear): the
  operator keeps that much clear around the robot where it is placed. No reachable gaze of a
  head camera sees behind the waist, in front of its own chest or between the arms and the
  torso, yet every balanced reach moves the body there (HRP-2 at the plant's valve: the waist
  and backpack 11-15 cm back, the chest 17-19 cm forward); with the body's volume alone, and a
  scan that also looks all around the body, 3 of 7 targets in front of HRP-2 planned (the
  valve not); with 0.10 m all 7, but the valve's plan took 1.5-3.6 s (narrow passages beside the
  body), with 0.12 m 0.04-0.22 s, as before issue 31.
  Unlike the 0.25 m shell it replaces, it does not follow the robot: an arm stretched behind
  the back does not make the space around it "seen". It is marked here, where the frontier is
  computed, so that the frontier bounds unobserved space at the zone's edge.
* **Self filter.** The points of a depth map within ``unobserved_robot_clearance_m`` of the
  robot's shapes at its stamp are the robot's own links (a real head camera sees its arms):
  they are dropped before fusion and counted (``points_self``), so that the body never becomes
  occupied voxels. The same margin grows the swept space: what the filter hides is counted
  with the body, and no more.
* **Throughput.** Inputs are only stored (:meth:`MappingPipeline.post`) in a bounded mailbox
  of ``input_queue_depth``; a worker thread converts them (the adapter's function) in
  arrival order and integrates them in the numba kernel. A short stall (a busy core, the
  first integrations) is absorbed, so no view of a head scan is lost; an input that arrives
  when the mailbox is full pushes out the oldest waiting one, counted as dropped: nothing
  queues without bound, and the map's memory is fixed by the extent (``VoxelMap`` is a dense
  array over it), whatever the input rate.
* **Problems.** Bad input (malformed clouds, NaN points, unknown frames, no joint states at
  the stamp, bad images ...) is counted per kind (:class:`MapperCounters`), remembered for
  ``problem_hold_s`` (the diagnostics stay WARN) and warned at most once per
  ``warn_throttle_s`` per kind; the map is not touched by a rejected input, and the worker
  never dies on one.

This module never imports rclpy.
"""
from __future__ import annotations

import collections
import dataclasses
import math
import threading
import time
import traceback
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Mapping

import numpy as np

from humanoid_reach_ros.counters import Counters
from humanoid_reach_ros.geometry.body_sweep import DEFAULT_SELF_FILTER_MARGIN_M, BodySweep
from humanoid_reach_ros.geometry.camera import CameraCalibration
from humanoid_reach_ros.geometry.voxels import points_within_capsules
from humanoid_reach_ros.perception.markers import JointStateBuffer, camera_pose, same_camera_pose
from humanoid_reach_ros.perception.stereo import StereoCalibration, StereoMatcher, StereoParams
from humanoid_reach_ros.perception.voxel_map import FusionParams, VoxelMap
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.shapes import load_collision_model

Vec3 = tuple[float, float, float]
_VECTORS = ("unobserved_region_min_m", "unobserved_region_max_m")


@dataclass(frozen=True)
class MappingConfig:
    """The pipeline's settings (the ``voxel_mapper`` parameters of the same names; the fusion
    ones are ``FusionParams``' fields, the stereo ones ``stereo_`` + ``StereoParams``' fields)."""

    fusion: FusionParams = field(default_factory=FusionParams)
    stereo: StereoParams = field(default_factory=StereoParams)
    map_frame: str = "world"
    sensor_frame: str = ""                     # empty: the robot's head camera frame
    joint_states_window_s: float = 2.0
    joint_states_max_gap_s: float = 0.1
    input_queue_depth: int = 4
    still_integration_period_s: float = 1.0
    unobserved_region_min_m: Vec3 = (-1.0, -1.0, 0.1)
    unobserved_region_max_m: Vec3 = (1.3, 1.0, 2.0)
    unobserved_robot_clearance_m: float = DEFAULT_SELF_FILTER_MARGIN_M
    stance_clearance_m: float = 0.12
    unobserved_block_voxels: int = 5
    minor_change_voxels: int = 100
    minor_change_period_s: float = 5.0
    warn_throttle_s: float = 2.0
    problem_hold_s: float = 5.0

    @classmethod
    def from_parameters(cls, p: Mapping[str, Any]) -> MappingConfig:
        """From the node's parameter values (extra keys ignored); ``ValueError`` for a box
        corner that is not three finite numbers."""
        for name in ("extent_min_m", "extent_max_m", *_VECTORS):
            if len(p[name]) != 3 or not all(math.isfinite(v) for v in p[name]):
                raise ValueError(f"{name} must have 3 finite entries (x, y, z), got {list(p[name])}")
        fusion = {f.name: p[f.name] for f in dataclasses.fields(FusionParams)}
        fusion.update({k: tuple(float(v) for v in p[k]) for k in ("extent_min_m", "extent_max_m")})
        stereo = {f.name: p["stereo_" + f.name] for f in dataclasses.fields(StereoParams) if "stereo_" + f.name in p}
        own = {f.name: p[f.name] for f in dataclasses.fields(cls) if f.name not in ("fusion", "stereo")}
        own.update({k: tuple(float(v) for v in p[k]) for k in _VECTORS})
        return cls(fusion=FusionParams(**fusion), stereo=StereoParams(**stereo), **own)


@dataclass
class MapperCounters(Counters):
    """What happened to the inputs (diagnostics; updated under the pipeline's state lock)."""

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
    points_self: int = 0                      # dropped by the self filter (the robot's own links)
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
class DepthJob:
    """A depth map for the pipeline: points (N, 3) in ``frame``, its stamp, its source (for messages)."""

    points: np.ndarray
    frame: str
    stamp_s: float
    source: str


@dataclass(frozen=True)
class MapLayers:
    """The layers to publish (each (N, 3) voxel centres in ``map_frame``), None for one unchanged
    since its last publication. Publish the frontier before the occupied voxels: a reader that
    gets the new map has the matching frontier already."""

    occupied: np.ndarray | None
    frontier: np.ndarray | None
    blocks: np.ndarray | None


@dataclass(frozen=True)
class MappingStatus:
    """The diagnostics: the map's values and message, the inputs' values, health and message."""

    map_values: dict[str, Any]
    map_message: str
    inputs_values: dict[str, Any]
    inputs_ok: bool
    inputs_message: str


class MappingPipeline:
    """Frame routing, the still-camera skip, fusion, the robot sweep, the publish policy, the
    mailbox and its worker, the counters (see the module docstring). Inputs may be posted and
    problems reported from any thread while the worker integrates; :meth:`layers_to_publish`,
    :meth:`clear` and :meth:`status` are called from one thread (the node's output callbacks).

    ``joint_states``: called before every look-up, returns the (stamp [s], joints) received
    since the last call (the adapter reports the rejected ones by :meth:`problem`). ``warn``:
    where throttled warnings go. ``clock``: monotonic time [s] (tests pass their own).
    """

    def __init__(self, config: MappingConfig, model: RobotModel, collision_model: Any = None,
                 joint_states: Callable[[], Iterable[tuple[float, np.ndarray]]] = lambda: (),
                 warn: Callable[[str], None] = lambda text: None, clock: Callable[[], float] = time.monotonic) -> None:
        self.map = VoxelMap(config.fusion)   # ValueError for bad fusion parameters
        self.model = model
        config = dataclasses.replace(config, sensor_frame=config.sensor_frame or model.camera_frame)
        model.frame_id(config.sensor_frame)  # KeyError for a frame the URDF lacks
        config.stereo.validate()
        self.config = config
        self.collision_model = collision_model or load_collision_model(None, model)
        self._joint_states, self._warn, self._clock = joint_states, warn, clock
        self.joint_buffer = JointStateBuffer(config.joint_states_window_s)
        self.counters = MapperCounters()
        self.stereo: StereoMatcher | None = None
        self._map_lock = threading.Lock()
        self._state_lock = threading.Lock()
        self._absorb_lock = threading.Lock()   # worker and diagnostics both take joint states
        self._cond = threading.Condition()
        self._mailbox: collections.deque[Any] = collections.deque()   # inputs not yet taken, oldest first
        self._stop = False
        self._worker: threading.Thread | None = None
        self._last_warn: dict[str, float] = {}
        self._newest_joint_stamp = 0.0
        self.js_gap_ms = 0.0              # largest gap between consecutive joint-state stamps (diagnostics window)
        self.js_gap_ms_total = 0.0
        self._last_integrated: tuple[np.ndarray, float] | None = None   # camera pose and time of the last update
        self._view_moved = False            # (worker) the depth map being integrated is from a new pose
        self._moved_since_publish = False   # a depth map from a new camera pose was integrated since
        self.sweep = BodySweep(model, self.collision_model, config.unobserved_robot_clearance_m,
                               step_m=0.5 * config.fusion.resolution_m, max_gap_s=config.joint_states_max_gap_s)
        self._swept_stamp = -math.inf      # the newest joint-state stamp swept
        self._stance_marked = False        # the stance zone is in the map (module doc)
        self.published_version = -1       # VoxelMap.version last published
        self._published_mask: np.ndarray | None = None     # occupied voxels last published
        self._published_counts = (0, 0)   # observed and swept voxels last published
        self._published_time = -math.inf
        self.published: dict[str, np.ndarray | None] = {"occupied": None, "frontier": None, "blocks": None}

    def warm_up(self) -> float:
        """Compile / load the numba kernels before the first depth map; returns the seconds it took."""
        t0 = time.perf_counter()
        with self._map_lock:
            self.map.integrate(np.array([[0.0, 0.0, 1.0]]), np.eye(4))
            self.map.occupied_centers()
            self.map.clear()
        return time.perf_counter() - t0

    # ------------------------------------------------------------ problems
    def problem(self, kind: str, text: str, counter: str = "", amount: int = 1) -> None:
        """Count (also into ``MapperCounters.<counter>`` by ``amount``), remember for diagnostics,
        and warn at most once per ``warn_throttle_s`` per kind."""
        now = self._clock()
        with self._state_lock:
            c = self.counters
            if counter:
                c.count(counter, amount)
            c.problems[kind] = c.problems.get(kind, 0) + 1
            c.last_problem, c.last_problem_time = f"{kind}: {text}", now
            if now - self._last_warn.get(kind, -1e9) < self.config.warn_throttle_s:
                return
            self._last_warn[kind] = now
            n = c.problems[kind]
        self._warn(f"{text} ({kind}, {n} so far)")

    def count(self, counter: str, amount: int = 1) -> None:
        with self._state_lock:
            self.counters.count(counter, amount)

    # ------------------------------------------------------------ joint states
    def add_joint_state(self, stamp_s: float, joints: np.ndarray) -> None:
        """One measured posture (model order) into the look-up buffer."""
        with self._state_lock:
            previous, self._newest_joint_stamp = self._newest_joint_stamp, stamp_s
            self.joint_buffer.push(stamp_s, joints)
            if previous > 0.0 and stamp_s > previous:
                gap = (stamp_s - previous) * 1e3
                self.js_gap_ms, self.js_gap_ms_total = max(self.js_gap_ms, gap), max(self.js_gap_ms_total, gap)

    def absorb_joint_states(self) -> None:
        with self._absorb_lock:
            for stamp_s, joints in self._joint_states():
                self.add_joint_state(stamp_s, joints)

    def _joints_at(self, stamp_s: float | None) -> tuple[np.ndarray | None, str]:
        """Joints at a stamp (None or 0: the newest), or None and the reason."""
        self.absorb_joint_states()
        with self._state_lock:
            if not stamp_s and len(self.joint_buffer):
                return self.joint_buffer.at(self._newest_joint_stamp, 0.0)
            return self.joint_buffer.at(stamp_s or 0.0, self.config.joint_states_max_gap_s)

    def sensor_pose(self, frame: str, stamp_s: float) -> tuple[np.ndarray | None, str]:
        """World pose (4x4) of a URDF frame at a stamp by forward kinematics, or None and the reason."""
        pose, _, reason = self._pose_and_joints(frame, stamp_s)
        return pose, reason

    def _pose_and_joints(self, frame: str, stamp_s: float) -> tuple[np.ndarray | None, np.ndarray | None, str]:
        joints, reason = self._joints_at(stamp_s)
        return (None, None, reason) if joints is None else (camera_pose(self.model, joints, frame), joints, "")

    def self_filter(self, world_points: np.ndarray, joints: np.ndarray | None) -> np.ndarray:
        """Which of ``world_points`` (N, 3) are NOT the robot's own links at ``joints`` (bool
        (N,); all True without joints): outside its shapes grown by the margin (module doc)."""
        keep = np.ones(len(world_points), dtype=bool)
        if joints is None or not len(world_points):
            return keep
        P0, P1, R = self.sweep.capsules(joints)
        keep = ~points_within_capsules(np.ascontiguousarray(world_points, dtype=np.float64),
                                       np.ascontiguousarray(P0), np.ascontiguousarray(P1),
                                       np.ascontiguousarray(R, dtype=np.float64))
        return keep

    # ------------------------------------------------------------ mailbox and worker
    def post(self, item: Any, counter: str = "") -> None:
        """Store an input for the worker (counted into ``counter`` first); a full mailbox drops its oldest."""
        if counter:
            self.count(counter)
        with self._cond:
            while len(self._mailbox) >= self.config.input_queue_depth:
                self._mailbox.popleft()
                self.count("clouds_dropped_busy")
            self._mailbox.append(item)
            self._cond.notify()

    def start(self, convert: Callable[[Any], DepthJob | None], name: str = "voxel_mapper_integrate") -> None:
        """Start the worker: each posted input, in arrival order, ``convert``-ed (None: rejected,
        the adapter reported why) and integrated."""
        self._worker = threading.Thread(target=self._work, args=(convert,), name=name, daemon=True)
        self._worker.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        if self._worker is not None:
            self._worker.join(timeout=timeout_s)

    def _work(self, convert: Callable[[Any], DepthJob | None]) -> None:
        while True:
            with self._cond:
                while not self._mailbox and not self._stop:
                    self._cond.wait(0.2)
                if self._stop:
                    return
                item = self._mailbox.popleft()
            try:
                job = convert(item)
                if job is not None:
                    self.integrate(job)
            except Exception as exc:  # the worker never dies on an input
                self.problem("internal_error", f"internal error on an input: {type(exc).__name__}: {exc}\n"
                             f"{traceback.format_exc()}")

    def stereo_points(self, left: CameraCalibration, right: CameraCalibration, gray_left: np.ndarray,
                      gray_right: np.ndarray) -> np.ndarray:
        """Points (N, 3) in the left camera's optical frame of a grey stereo pair (``ValueError``
        for a pair that cannot be matched); counted as a stereo pair."""
        calib = StereoCalibration.from_camera_infos(left, right)
        if self.stereo is None or self.stereo.calibration != calib:
            self.stereo = StereoMatcher(calib, self.config.stereo)
        points = self.stereo.points(gray_left, gray_right)
        self.count("stereo_pairs")
        return points

    # ------------------------------------------------------------ integration
    def integrate(self, job: DepthJob) -> str:
        """Route one depth map by its frame and fuse it. Returns what happened: ``integrated``,
        ``marked`` (world points without a sensor origin: no clearing), ``still`` (skipped),
        ``no_pose`` or ``unknown_frame`` (rejected, reported)."""
        c = self.config
        if job.frame == c.map_frame:
            pose, joints, reason = self._pose_and_joints(c.sensor_frame, job.stamp_s)
            world = job.points
            if pose is None:   # mark only: the rays' origin is unknown
                self.problem("no_pose", f"{job.source} in {job.frame!r}: no sensor origin ({reason}); points are "
                             "marked without free-space clearing")
        elif job.frame and self.model.model.existFrame(job.frame):
            pose, joints, reason = self._pose_and_joints(job.frame, job.stamp_s)
            if pose is None:
                self.problem("no_pose", f"{job.source} in {job.frame!r} ignored: no camera pose at its stamp "
                             f"({reason})", "no_pose")
                return "no_pose"
            world = None
        else:
            self.problem("unknown_frame", f"{job.source} ignored: unknown frame {job.frame!r} (use "
                         f"{c.map_frame!r} or a frame of the robot model, e.g. {c.sensor_frame!r})", "unknown_frame")
            return "unknown_frame"
        if pose is not None and self._still(pose):
            self.count("clouds_skipped_still")
            return "still"
        if pose is None:
            self._view_moved = True           # no pose to compare: publish at once
        t0 = time.perf_counter()
        points = job.points
        if world is None:
            keep = self.self_filter(points @ pose[:3, :3].T + pose[:3, 3], joints)
            points = points[keep]
        else:
            keep = self.self_filter(world, joints)
            world = world[keep]
        dropped = int(len(keep) - np.count_nonzero(keep))
        with self._map_lock:
            self._moved_since_publish |= self._view_moved
            self._view_moved = False
            if world is None:
                st = self.map.integrate(points, pose)
            elif pose is None:
                st = self.map.integrate(world, origin=None, mark_only=True)
            else:
                st = self.map.integrate(world, origin=pose[:3, 3])
        dt = time.perf_counter() - t0
        with self._state_lock:
            k = self.counters
            k.clouds_integrated += 1
            k.points_integrated += st.hits
            k.points_outside += st.outside
            k.points_floor += st.floor
            k.points_beyond_range += st.beyond_range
            k.points_self += dropped
            k.last_integration_s = dt
            k.last_integrated_stamp_s = max(k.last_integrated_stamp_s, job.stamp_s)
            k.integration_time_s += dt
        return "integrated" if pose is not None else "marked"

    def _still(self, pose: np.ndarray) -> bool:
        """The camera is where it was at the last integration (1 mm, 1 mrad) and that was less
        than ``still_integration_period_s`` ago: skip this depth map (else this pose becomes
        the last integration's)."""
        period = self.config.still_integration_period_s
        now = self._clock()
        last = self._last_integrated
        same = last is not None and same_camera_pose(pose, last[0])
        if period > 0 and same and now - last[1] < period:
            return True
        if not same:
            self._view_moved = True       # a new view: its changes are published at once
        self._last_integrated = (pose.copy(), now)
        return False

    def clear(self) -> int:
        """Forget the map (the body's swept space too: the next publish sweeps the body at its
        posture then, moved or not); returns the occupied voxels forgotten."""
        with self._map_lock:
            n = self.map.occupied_count()
            self.map.clear()
            self.sweep.reset()
            self._swept_stamp = -math.inf
            self._stance_marked = False
        self.count("clears")
        return n

    # ------------------------------------------------------------ outputs
    def sweep_robot(self) -> int:
        """Mark the space of the robot's body as swept (the robot-volume policy, module
        docstring) at the postures reported since the last call and between them; a new mark
        is a map change. Returns the voxels newly marked."""
        self.absorb_joint_states()
        with self._state_lock:
            newest = self.joint_buffer.newest_stamp
            if newest is not None and newest < self._swept_stamp:     # time jumped back
                self._swept_stamp = -math.inf
            states = self.joint_buffer.since(self._swept_stamp)
        if not states:
            return 0
        self._swept_stamp = states[-1][0]
        added = 0
        if not self._stance_marked:
            self._stance_marked = True
            if self.config.stance_clearance_m > 0.0:
                p0, p1, radii = self.stance_zone()
                with self._map_lock:
                    added += self.map.mark_swept(p0, p1, radii)
        postures = self.sweep.postures(states)
        if not postures:
            return added
        p0, p1, radii = self.sweep.capsules_of(postures)
        with self._map_lock:
            return added + self.map.mark_swept(p0, p1, radii)   # bumps map.version

    def stance_zone(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The stance zone's capsules (module doc): the shapes at the reference posture, on the
        feet, grown by ``stance_clearance_m``."""
        return self.sweep.capsules(self.model.half_sitting_joints, self.config.stance_clearance_m)

    def layers_to_publish(self, force: bool = False) -> MapLayers | None:
        """The robot swept in, then the layers when the publish policy (module docstring) says
        publish, each None if its points did not change -- or None: nothing to publish now.
        What is returned counts as published."""
        self.sweep_robot()
        c = self.config
        with self._map_lock:
            if self.map.version == self.published_version and not force:     # nothing a reader sees changed
                return None
            now = self._clock()
            occupied = self.map.occupied_mask()
            counts = (self.map.observed_count, self.map.swept_count)
            changed = (occupied.size if self._published_mask is None
                       else int(np.count_nonzero(occupied != self._published_mask))) \
                + sum(abs(a - b) for a, b in zip(counts, self._published_counts))
            if not force and not self._moved_since_publish and changed < c.minor_change_voxels \
                    and now - self._published_time < c.minor_change_period_s:
                self.count("minor_changes_deferred")
                return None
            self._published_mask, self._published_counts, self._published_time = occupied.copy(), counts, now
            self._moved_since_publish = False
            self.published_version = self.map.version
            region = (c.unobserved_region_min_m, c.unobserved_region_max_m)
            layers = {"occupied": self.map.occupied_centers(), "frontier": self.map.frontier_centers(*region),
                      "blocks": self.map.unobserved_blocks(*region, c.unobserved_block_voxels)}
        changed_layers = {}
        for name, points in layers.items():
            last = self.published[name]
            changed_layers[name] = points if last is None or not np.array_equal(points, last) else None
            self.published[name] = points
        return MapLayers(**changed_layers)

    def status(self) -> MappingStatus:
        """The diagnostics' values (the keys ``voxel_mapper`` publishes), health and messages.
        Resets the joint-state gap of the diagnostics window."""
        self.absorb_joint_states()
        m = self.map
        with self._map_lock:
            occupied, depth_maps = m.occupied_count(), m.depth_maps
            version, published = m.version, self.published_version
        with self._state_lock:
            c = self.counters.snapshot()
            buffered = len(self.joint_buffer)
            gap_ms, self.js_gap_ms = self.js_gap_ms, 0.0   # between stamps seen
        recent = self._clock() - c.last_problem_time < self.config.problem_hold_s
        mean_s = c.integration_time_s / c.clouds_integrated if c.clouds_integrated else 0.0
        frontier, blocks = self.published["frontier"], self.published["blocks"]
        map_values = {
            "occupied_voxels": occupied, "capacity_voxels": m.capacity, "memory_bytes": m.nbytes,
            "resolution_m": m.resolution_m, "depth_maps": depth_maps, "frame_id": self.config.map_frame,
            "last_integration_ms": c.last_integration_s * 1e3, "mean_integration_ms": mean_s * 1e3,
            "last_integrated_stamp_s": f"{c.last_integrated_stamp_s:.6f}",
            "points_per_s": (c.points_integrated + c.points_outside + c.points_floor) / c.integration_time_s
            if c.integration_time_s > 0 else 0.0, "clears": c.clears,
            "map_version": version, "published_version": published,
            "unobserved_frontier_voxels": 0 if frontier is None else len(frontier),
            "unobserved_blocks": 0 if blocks is None else len(blocks)}
        values = {k: v for k, v in vars(c).items() if isinstance(v, int)}
        values["joint_states_buffered"] = buffered
        values["joint_states_max_gap_ms"] = gap_ms
        values["joint_states_max_gap_ms_since_start"] = self.js_gap_ms_total
        values["last_problem"] = c.last_problem
        for kind, n in sorted(c.problems.items()):
            values[f"problem_{kind}"] = n
        if recent:
            ok, message = False, f"rejected input: {c.last_problem.splitlines()[0]}"
        elif c.clouds_received == 0 and c.stereo_pairs == 0:
            ok, message = False, "no depth input yet"
        else:
            ok, message = True, (f"{c.clouds_integrated} depth maps integrated, "
                                 f"{c.clouds_dropped_busy} dropped while busy")
        return MappingStatus(map_values, f"{occupied} occupied voxels from {depth_maps} depth maps", values, ok,
                             message)


__all__ = ["MappingConfig", "MapperCounters", "DepthJob", "MapLayers", "MappingStatus", "MappingPipeline"]
