"""Execution requests: what the node validated, turned into a supervisor :class:`Motion`.

ROS-free (the node converts messages with ``io/exec_msgs.py`` first):

* which arm a trajectory moves (:func:`arm_motion`, :func:`resolve_arm`: its hand is the task
  of level 3) and the check that a requested arm is the one the trajectory moves;
* dual-arm hand targets in ``world`` or ``base_link`` (:func:`targets_in_world` through the
  waist of the measured joints);
* the collision map, from the planning scene (``scene/planning_scene.py``, the one world
  model; the node feeds it the scene file's voxels until a measured ``/voxel_map`` arrives): the
  voxels within ``target_exclusion_radius_m`` of the motion's start and final hand positions
  left out (the object to be reached, or left), the sphere tree built here, outside the control
  loop;
* where a motion ended (:meth:`ExecutionRequests.contact_at`, :class:`HandContact`): whether a
  hand rests on the map, on the WHOLE map (the object reached included), by the planner's own
  contact test (``planning/retreat.py``: what makes its next plan retreat first);
* smooth reshaping (Yoshida et al., ``planning/reshape.py``) of a goal that asks for it,
  seconds, in the caller's thread while the loop keeps running or holding;
* the ``/look`` motions: head poses (:meth:`ExecutionRequests.look`) and balanced whole-body
  gazes at world points (:meth:`ExecutionRequests.gaze`, ``control/gaze.py``);
* :class:`ExecutionRequests`: the above plus the counters the node's diagnostics report.

Every refusal is a :class:`~humanoid_reach_ros.codes.RequestError` whose code is the
``ExecuteReach`` result and whose message says what is wrong.
"""
from __future__ import annotations

import dataclasses
import hashlib
import math
import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pinocchio as pin

from humanoid_reach_ros.counters import Counters
from humanoid_reach_ros.execution.config import ExecutionConfig
from humanoid_reach_ros.codes import ARM_AUTO, ARM_NAMES, ExecuteCode as C, RequestError
from humanoid_reach_ros.geometry.sphere_tree import SphereTree
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.scene.planning_scene import PlanningScene, SceneParams

HAND_LIMBS = {"right": "right_arm", "left": "left_arm"}
def _cache_dir() -> Path:
    """Where computed per-robot data is kept between runs: ``$XDG_CACHE_HOME/humanoid_reach_ros``."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "humanoid_reach_ros"


#: one computation of the scan's gaze points around the body at a time (ExecutionRequests.surroundings_points)
_SURROUNDINGS_LOCK = threading.Lock()
#: serialises the gaze solves of every ExecutionRequests (a GazeSolver owns one pinocchio data)
_GAZE_LOCK = threading.Lock()

# A requested arm whose joints travel less than this fraction of the other arm's, while the other
# arm's travel more than WRONG_ARM_MIN_TRAVEL_RAD, is the wrong arm for the trajectory.
WRONG_ARM_RATIO = 0.1
WRONG_ARM_MIN_TRAVEL_RAD = 0.05

@dataclass(frozen=True)
class ArmMotion:
    """How much one arm moves along a trajectory: the summed |delta q| of its joints [rad]
    and the length of its hand's path [m] (standing on the feet)."""

    joint_travel_rad: float
    hand_travel_m: float


def arm_motion(robot: RobotModel, positions: np.ndarray, samples: int = 12) -> dict[str, ArmMotion]:
    """:class:`ArmMotion` of the right and left arm over ``positions`` (K, 30); the hand
    path is measured at up to ``samples`` evenly spaced points."""
    P = np.asarray(positions, dtype=float)
    idx = np.unique(np.linspace(0, len(P) - 1, min(len(P), samples)).round().astype(int))
    out = {}
    for arm, limb in HAND_LIMBS.items():
        spec = robot.limbs[limb]
        joint = float(np.abs(np.diff(P[:, list(spec.joint_index)], axis=0)).sum())
        pts = np.array([robot.frame_pose(robot.config(j, robot.base_on_feet(j)), spec.tip).translation
                        for j in P[idx]])
        out[arm] = ArmMotion(joint, float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum()))
    return out


def resolve_arm(code: int, motion: dict[str, ArmMotion]) -> str:
    """The executor arm ('right' | 'left') of an ``ExecuteReach.arm`` code given each arm's
    motion (:func:`arm_motion`). 0 = the arm whose joints move more (the planner moves only
    the reaching arm; a tie, e.g. a trunk-only motion, goes to the hand that travels further).
    1 / 2 = right / left, refused as the wrong arm when that arm's joints stay (almost) still
    while the other arm's joints move (less than ``WRONG_ARM_RATIO`` of its travel, which
    exceeds ``WRONG_ARM_MIN_TRAVEL_RAD``)."""
    bad = C.INVALID_REQUEST
    if code == ARM_AUTO:
        return max(("right", "left"), key=lambda a: (round(motion[a].joint_travel_rad, 6), motion[a].hand_travel_m))
    if code not in ARM_NAMES:
        raise RequestError(bad, f"arm {code} is unknown; use 0 (from the trajectory), 1 (right) or 2 (left)")
    arm = ARM_NAMES[code]
    other = "left" if arm == "right" else "right"
    mine, theirs = motion[arm].joint_travel_rad, motion[other].joint_travel_rad
    if theirs > WRONG_ARM_MIN_TRAVEL_RAD and mine < WRONG_ARM_RATIO * theirs:
        raise RequestError(bad, f"wrong arm: the trajectory moves the {other} arm's joints ({theirs:.2f} rad in "
                                  f"all) while the requested {arm} arm's move {mine:.2f} rad")
    return arm



@dataclass(frozen=True)
class HandContact:
    """Where the hands are at the end of a motion, against the whole map (the object reached
    included, unlike the motion's ``min_distance_m``): ``in_contact`` when a hand's shapes come
    within the planner's ``contact_distance_m`` of the occupied voxels
    (``RetreatPlanner.classify_start``: exactly what makes the next plan retreat first);
    ``distance_m`` the nearest hand shape's signed distance to the nearest voxel (< 0: inside;
    inf: no map or no joint states); ``with_what`` what it touches ("" without a contact)."""

    in_contact: bool
    distance_m: float
    with_what: str

    def as_dict(self) -> dict[str, Any]:
        """The ``ExecuteReach`` result's fields."""
        return {"hand_in_contact": self.in_contact, "contact_distance_m": self.distance_m,
                "contact_with": self.with_what}

    def describe(self) -> str:
        if self.in_contact:
            return f"hand in contact ({1e3 * self.distance_m:.1f} mm): {self.with_what}"
        if math.isfinite(self.distance_m):
            return f"no hand in contact: the nearest voxel is {1e3 * self.distance_m:.1f} mm from a hand"
        return f"no hand in contact ({self.with_what})"


@dataclass(frozen=True, eq=False)
class HandTarget:
    """One validated hand target: its pose in ``frame`` ('world' or 'base_link')."""

    frame: str
    pose: pin.SE3



def needs_waist(targets: tuple[HandTarget, ...]) -> bool:
    return any(t.frame == "base_link" for t in targets)


def targets_in_world(targets: tuple[HandTarget, HandTarget], waist: pin.SE3 | None) -> tuple[pin.SE3, pin.SE3]:
    """World poses of the targets; ``waist`` = the waist pose in world (``base_on_feet`` of
    the measured joints) for base_link targets (``NO_JOINT_STATES`` when it is missing)."""
    out = []
    for t in targets:
        if t.frame == "base_link":
            if waist is None:
                raise RequestError(C.NO_JOINT_STATES,
                                     "a base_link hand target needs a recent /joint_states to place the waist")
            out.append(waist * t.pose)
        else:
            out.append(t.pose)
    return out[0], out[1]


@dataclass
class RequestCounters(Counters):
    """What the executor's requests and maps did (its ``/diagnostics``)."""

    goals: int = 0
    goals_rejected: int = 0
    trajectories: int = 0
    trajectories_rejected: int = 0
    successes: int = 0
    last_rejection: str = ""
    last_result: str = ""
    maps_received: int = 0
    maps_rejected: int = 0
    map_source: str = "none"
    map_voxels: int = 0
    unobserved_voxels: int = -1              # the mapper's frontier (-1: none received)
    map_build_ms: float = 0.0
    dual_arm_goals: int = 0
    dual_arm_infeasible: int = 0
    last_infeasible: str = ""
    target_messages: int = 0
    target_messages_rejected: int = 0
    target_messages_ignored: int = 0
    target_messages_unchanged: int = 0


class ExecutionRequests:
    """Builds motions from validated inputs; owns the map the loop gets (see the module doc).

    ``config``: an :class:`~humanoid_reach_ros.execution.config.ExecutionConfig` (or parameter
    values to make one of); the manager replaces it on a run-time change."""

    def __init__(self, robot: RobotModel, config: ExecutionConfig | dict[str, Any]) -> None:
        self.robot = robot
        self.config = config if isinstance(config, ExecutionConfig) else ExecutionConfig.from_values(config)
        self.counters = RequestCounters()
        self._fk_lock = threading.Lock()
        # the executor avoids occupied voxels only: unobserved space is the planner's concern
        self.scene = PlanningScene(robot, self._scene_params())
        self._target_p: np.ndarray | None = None
        self._tree_cache: SphereTree | None = None
        self._reshaper = None
        self._look_cm = None      # the collision model and checker of look_clearance, made on first use
        self._look_coll = None
        self._look_unseen = None  # ... and its checker on the map plus the unobserved frontier
        self._frontier: np.ndarray | None = None            # the last /voxel_map/unobserved
        self._frontier_in_scene: np.ndarray | None = None   # the one the scene holds (set when a gaze needs it)
        self._retreat = None      # the planner's contact test (planning/retreat.py), made on first use
        self._reshape_lock = threading.Lock()
        self._sampler = None
        self._sampler_lock = threading.Lock()
        self._map_lock = threading.Lock()
        self.send_map: Callable[[SphereTree], None] = lambda tree: None   # set by the node: to the loop
        from humanoid_reach_ros.geometry import sphere_tree
        sphere_tree.warm_up()    # the first /voxel_map must not pay the tree kernels' first call (1.3 s seen)

    # ------------------------------------------------------------ map
    def _scene_params(self) -> SceneParams:
        return SceneParams(resolution_m=self.config.resolution_m, safety_margin_m=self.config.safety_margin_m,
                           target_exclusion_radius_m=float(self.config.target_exclusion_radius_m),
                           unobserved_space="free")

    def _tree(self, exclude: np.ndarray | None) -> SphereTree:
        """The scene's sphere tree without the voxels around ``exclude`` (cached per version)."""
        wanted = self._scene_params()
        if wanted != self.scene.params:   # a parameter changed at run time
            self.scene.set_params(wanted)
        snap = self.scene.snapshot()
        tree, dt = snap.tree(exclude if snap.source == "/voxel_map" else None)
        self.counters.set(map_voxels=int(tree.n_spheres))
        if dt > 0:
            self.counters.set(map_build_ms=dt * 1e3)
        self._tree_cache = tree
        return tree

    def scene_map(self, voxels: np.ndarray | None, path: str = "") -> tuple[SphereTree | None, str]:
        """The scene file's map (``voxels``, read by the node; None: no scene file) until a
        /voxel_map arrives, and a log line."""
        if voxels is None:
            return None, ("map source: none yet (scene_file is empty): executing without environment until "
                          "/voxel_map arrives")
        self.scene.set_occupied(voxels, source=f"scene file {path}")
        tree = self._tree(None)
        self.counters.set(map_source=f"scene file {path}")
        return tree, (f"map source: scene file {path} ({len(voxels)} voxels without groups "
                      f"{list(self.config.scene_exclude_groups)}, sphere tree built in "
                      f"{self.counters.map_build_ms:.1f} ms); a /voxel_map replaces it")

    def measured_map(self, cloud) -> tuple[SphereTree, str, bool]:
        """A parsed /voxel_map (``msgs.points_from_cloud``) -> (tree, log line, source changed)."""
        if cloud.frame_id not in ("", self.config.map_frame):
            raise ValueError(f"frame_id {cloud.frame_id!r} is not the map frame {self.config.map_frame!r}")
        with self._map_lock:
            self.scene.set_occupied(cloud.points, source="/voxel_map")
            tree = self._tree(self._target_p)
        c = self.counters
        previous, changed = c.map_source, c.map_source != "/voxel_map"
        c.count("maps_received")
        c.set(map_source="/voxel_map")
        dropped = f", {cloud.dropped_nonfinite} NaN/inf points dropped" if cloud.dropped_nonfinite else ""
        return tree, (f"map source: /voxel_map ({len(cloud.points)} voxels{dropped}, sphere tree built in "
                      f"{c.map_build_ms:.1f} ms; replaces {previous})"), changed

    def unobserved_map(self, cloud) -> tuple[str, bool]:
        """A parsed /voxel_map/unobserved (the mapper's frontier: unobserved voxels next to observed
        free space, the body-swept space already out of it) -> (log line, first one). Only gazes use
        it (``look_avoids_unobserved``): the loop's map stays the occupied voxels, whose dampers
        follow plans that already keep out of unobserved space."""
        if cloud.frame_id not in ("", self.config.map_frame):
            raise ValueError(f"frame_id {cloud.frame_id!r} is not the map frame {self.config.map_frame!r}")
        points = np.asarray(cloud.points, float).reshape(-1, 3)
        with self._map_lock:   # into the scene when a gaze needs it: a new scene version rebuilds the loop's tree
            self._frontier = points
        first = self.counters.unobserved_voxels < 0
        self.counters.set(unobserved_voxels=len(cloud.points))
        off = "" if self.config.look_avoids_unobserved else " (off: look_avoids_unobserved is false)"
        return (f"unobserved frontier: /voxel_map/unobserved ({len(cloud.points)} voxels): gazes keep the body out "
                f"of it{off}"), first

    def reject_map(self, exc: Exception, topic: str = "/voxel_map") -> None:
        self.counters.count("maps_rejected")
        self.counters.set(last_rejection=f"{topic}: {type(exc).__name__}: {exc}")

    def _aim_map_at(self, positions: np.ndarray, arm: str, log: Callable[[str], None] | None) -> None:
        """Before a motion: leave the voxels around its hand's start and final positions out of
        a measured map (the object to be reached, or the one the hand leaves: a motion back from
        the valve starts with the hand inside the valve's voxels)."""
        with self._fk_lock:
            ends = []
            for joints in (positions[0], positions[-1]):
                q = self.robot.config(joints, self.robot.base_on_feet(joints))
                ends.append(self.robot.frame_pose(q, self.robot.limbs[HAND_LIMBS[arm]].tip).translation.copy())
        target = np.array(ends)
        with self._map_lock:
            self._target_p = target
            snap = self.scene.snapshot()
            if snap.source != "/voxel_map":
                return
            tree = self._tree(target)
        self.send_map(tree)
        kept, total = tree.n_spheres, len(snap.occupied)
        if kept < total and log is not None:
            log(f"/voxel_map: {total - kept} of {total} voxels within "
                f"{self.config.target_exclusion_radius_m:g} m of the hand's start {np.round(target[0], 3).tolist()} "
                f"or final position {np.round(target[1], 3).tolist()} left out (the object reached or left)")

    # ------------------------------------------------------------ where a motion ended
    def contact_at(self, joints: np.ndarray | None, reason: str = "") -> HandContact:
        """:class:`HandContact` of the joint angles ``joints`` (the measured end of a motion) on
        the whole map: the voxels near the motion's target are NOT left out here (the loop's map
        leaves them out so that the hand may reach its object; a touch is what this reports).
        Contact is the planner's test (``RetreatPlanner.classify_start`` with its default
        ``RetreatParams``: a hand's shapes, forearm to fingers, within ``contact_distance_m`` of the
        voxels); the touched voxels are the target's object when the nearest lies within
        ``target_exclusion_radius_m`` of the motion's final hand position."""
        from humanoid_reach_ros.planning.retreat import RetreatPlanner, hand_shape_mask
        if joints is None:
            return HandContact(False, math.inf, f"unknown: {reason or 'no /joint_states'}")
        with self._map_lock:
            snap = self.scene.snapshot()
            tree, _ = snap.tree(None)
            target = None if self._target_p is None else self._target_p[-1].copy()
        if tree.n_spheres == 0:
            return HandContact(False, math.inf, "no map")
        if self._retreat is None:
            if self._look_cm is None:
                from humanoid_reach_ros.robot.shapes import load_collision_model
                self._look_cm = load_collision_model(None, self.robot)
            cm = self._look_cm
            self._retreat = (RetreatPlanner(self.robot, cm),
                             hand_shape_mask(self.robot, cm, "right") | hand_shape_mask(self.robot, cm, "left"))
        planner, hands = self._retreat
        margin = float(snap.params.safety_margin_m)   # the tree's spheres are grown by it
        with self._fk_lock:
            q = self.robot.config(joints, self.robot.base_on_feet(joints))
            contact, _ = planner.classify_start(q, tree, margin)
            P0, P1, R = planner.cm.world_shapes(q)
        dist, _ = tree.nearest_batch(P0[hands], P1[hands], R[hands])
        nearest = float(np.min(dist)) + margin
        if contact is None:
            return HandContact(False, nearest, "")
        radius = float(self.config.target_exclusion_radius_m)
        occupied = np.asarray(snap.occupied, float).reshape(-1, 3)
        where = f"the {contact.arm} hand ({', '.join(contact.shapes)})"
        if target is not None and np.linalg.norm(contact.point - target) <= radius:
            n = int(np.count_nonzero(np.linalg.norm(occupied - target, axis=1) <= radius))
            what = f"{where} on the target object ({n} voxels within {1e3 * radius:.0f} mm of the target)"
        else:
            what = (f"{where} on the voxels around {np.round(contact.point, 3).tolist()} m ({len(contact.voxels)} "
                    f"within {1e3 * planner.params.contact_radius_m:.0f} mm of the hand), not the target's object")
        return HandContact(True, min(nearest, contact.distance_m), what)

    # ------------------------------------------------------------ motions
    def measured_start(self, joints: np.ndarray | None, reason: str) -> np.ndarray:
        if joints is None:
            raise RequestError(C.NO_JOINT_STATES, reason)
        with self._fk_lock:
            return self.robot.config(joints, self.robot.base_on_feet(joints))

    def trajectory(self, mid: int, label: str, ref, frame_id: str, arm_code: int, no_avoidance: bool,
                   no_com: bool, reshaping: bool, joints: np.ndarray | None, reason: str,
                   log: Callable[[str], None] | None = None):
        """A whole-body executor motion along ``ref`` (an ``exec_msgs.Reference``)."""
        from humanoid_reach_ros.execution.supervisor import Motion
        if frame_id not in ("", self.config.map_frame):
            raise RequestError(C.INVALID_REQUEST, f"trajectory frame_id {frame_id!r} is not the map frame "
                                               f"{self.config.map_frame!r}")
        with self._fk_lock:
            arm = resolve_arm(int(arm_code), arm_motion(self.robot, ref.positions))
        q0 = self.measured_start(joints, reason)
        self._aim_map_at(ref.positions, arm, log)
        spline, note = ref.spline, ""
        if reshaping:
            spline, note = self._reshape(ref.spline, arm)
            if log is not None:
                log(f"{label}: {note}")
        params = dataclasses.replace(self._executor_params(), collision_avoidance=not no_avoidance,
                                     com_compensation=not no_com)
        return Motion(mid, label, "trajectory", spline=spline, arm=arm, params=params, q_measured=q0, note=note)

    def look_targets(self, yaw: list[float], pitch: list[float]) -> tuple[np.ndarray | None, np.ndarray | None]:
        """What a look request at head angles turns into: ``(head poses (K, 2) [rad], None)`` on a
        robot with a neck (:meth:`head_poses`), ``(None, gaze points (K, 3) [m, world])`` on one
        without (:meth:`direction_points`: the balanced whole-body gaze then aims the camera
        with the chest). An empty request is the scan pattern either way."""
        if self.robot.spec.has_neck:
            return self.head_poses(yaw, pitch), None
        return None, self.direction_points(yaw, pitch)

    def _requested_angles(self, yaw: list[float], pitch: list[float]) -> tuple[np.ndarray, str, bool]:
        """``(poses (K, 2) [rad], what, scan)``: the goal's yaw/pitch pairs, or the scan pattern
        (``scan_poses_deg``) for an empty goal; INVALID_REQUEST for unpaired or NaN/inf angles."""
        bad = C.INVALID_REQUEST
        if len(yaw) != len(pitch):
            raise RequestError(bad, f"{len(yaw)} yaw angles but {len(pitch)} pitch angles: give one pitch per yaw")
        scan = len(yaw) == 0
        if scan:
            flat = np.radians(np.asarray(self.config.scan_poses_deg, dtype=float))
            if len(flat) < 2 or len(flat) % 2:
                raise RequestError(bad, f"parameter scan_poses_deg must hold yaw, pitch pairs, got {len(flat)} values")
            poses, what = flat.reshape(-1, 2), "scan_poses_deg"
        else:
            poses, what = np.column_stack([np.asarray(yaw, float), np.asarray(pitch, float)]), "the goal"
        if not np.all(np.isfinite(poses)):
            raise RequestError(bad, f"{what} has NaN/inf angles")
        return poses, what, scan

    def head_poses(self, yaw: list[float], pitch: list[float]) -> np.ndarray:
        """Validated head poses (K, 2) [rad] of a look request: as many yaws as pitches, finite,
        within the head joints' limits; an empty request is the scan pattern (``scan_poses_deg``,
        a parameter for any robot: its poses are clamped into this robot's head limits, where a
        goal's poses outside them are refused). A robot without a neck has no head angles
        (INVALID_REQUEST): :meth:`look_targets` turns its looks into gaze points."""
        bad = C.INVALID_REQUEST
        try:
            self.robot.spec.require_neck("a look at head angles (yaw_rad/pitch_rad, or the scan's scan_poses_deg)")
        except ValueError as exc:
            raise RequestError(bad, str(exc)) from None
        poses, what, scan = self._requested_angles(yaw, pitch)
        idx = [self.robot.joint_index[n] for n in self.head_joints]
        lo, hi = self.robot.lower[idx], self.robot.upper[idx]
        if scan:
            poses = np.clip(poses, lo, hi)
        for k, pose in enumerate(poses):
            for j, (name, label) in enumerate(zip(self.head_joints, ("yaw", "pitch"))):
                if not lo[j] <= pose[j] <= hi[j]:
                    raise RequestError(bad, f"pose {k} of {what}: {label} {math.degrees(pose[j]):.1f} deg is outside "
                                            f"{name}'s limits [{math.degrees(lo[j]):.1f}, {math.degrees(hi[j]):.1f}] "
                                            "deg")
        return poses

    def direction_points(self, yaw: list[float], pitch: list[float]) -> np.ndarray:
        """Gaze points (K, 3) [m, world] for look directions: each yaw/pitch pair [rad] (pitch > 0
        looks down, yaw > 0 to the left, both from the stance's forward axis, world x) is the
        point ``look_distance_m`` from the camera at the reference posture (half-sitting on the
        stance feet) in that direction. This is how a robot without a neck (its camera turns only
        with the body) takes the scan pattern and a look at angles: the same directions the
        head's angles give a robot whose camera looks level at zero head angles. INVALID_REQUEST
        for unpaired or NaN/inf angles or a pitch beyond +-90 deg."""
        poses, what, _ = self._requested_angles(yaw, pitch)
        steep = np.abs(poses[:, 1]) > math.pi / 2
        if steep.any():
            k = int(np.argmax(steep))
            raise RequestError(C.INVALID_REQUEST, f"pose {k} of {what}: pitch {math.degrees(poses[k, 1]):.1f} deg is "
                                               "beyond +-90 deg (straight down or up)")
        with self._fk_lock:
            hs = self.robot.half_sitting_joints
            camera = self.robot.frame_pose(self.robot.config(hs, self.robot.base_on_feet(hs)),
                                           self.robot.camera_frame).translation.copy()
        y, p = poses[:, 0], poses[:, 1]
        d = np.column_stack([np.cos(p) * np.cos(y), np.cos(p) * np.sin(y), -np.sin(p)])
        return camera + float(self.config.look_distance_m) * d

    @property
    def head_joints(self) -> list[str]:
        """Head yaw and pitch joints of the robot description; without a neck, the chest's yaw
        and pitch (the joints that aim the camera: ``control/gaze.py``)."""
        spec = self.robot.spec
        return list(spec.neck_joints if spec.has_neck else spec.chest_joints)

    def look(self, mid: int, label: str, pose: np.ndarray, joints: np.ndarray | None, reason: str):
        """A whole-body motion that turns the head to ``pose`` (yaw, pitch [rad]) from the measured
        joints, every other joint's reference held: the executor keeps the feet, the exact COG and
        the right hand (level 3) where they are while the posture task (level 4) turns the head.
        Timed by :meth:`_look_spline` (``head_speed_rad_s``, the spline's peak)."""
        from humanoid_reach_ros.execution.supervisor import Motion
        q0 = self.measured_start(joints, reason)   # NO_JOINT_STATES without joints
        start = np.asarray(joints, float)
        goal = start.copy()
        goal[[self.robot.joint_index[n] for n in self.head_joints]] = pose
        note = f"head to yaw {math.degrees(pose[0]):.1f}, pitch {math.degrees(pose[1]):.1f} deg"
        return Motion(mid, label, "trajectory", spline=self._look_spline(start, goal), arm="right",
                      params=self._executor_params(), q_measured=q0, note=note)

    def back_to(self, mid: int, label: str, goal: np.ndarray, joints: np.ndarray | None, reason: str):
        """A whole-body motion from the measured joints back to ``goal`` (joints the robot stood in,
        e.g. when a scan began: its gazes around the body leave the chest turned), timed as a look
        (:meth:`_look_spline`) and executed like one (feet and exact COG first)."""
        from humanoid_reach_ros.execution.supervisor import Motion
        q0 = self.measured_start(joints, reason)
        start = np.asarray(joints, float)
        goal = np.asarray(goal, float).reshape(-1)
        if goal.shape != start.shape or not np.all(np.isfinite(goal)):
            raise RequestError(C.INVALID_REQUEST, f"back_to: {len(start)} finite joint angles needed")
        return Motion(mid, label, "trajectory", spline=self._look_spline(start, goal), arm="right",
                      params=self._executor_params(), q_measured=q0, note="back to the posture the look began in")

    def _look_spline(self, start: np.ndarray, goal: np.ndarray):
        """The reference of a look or gaze motion from ``start`` to ``goal``: a joint's peak speed
        is ``head_speed_rad_s``, or the share of its URDF limit the executor may command
        (``velocity_scale``) when that is lower. Why: Talos's head joints (1 rad/s, so 0.5 rad/s
        commanded) lagged a 1 rad/s reference by 7-14 deg, and the motion ended (hand converged)
        before the head arrived."""
        from humanoid_reach_ros.geometry.trajectory import SplineTrajectory, TrajectoryOptions
        v = np.minimum(float(self.config.head_speed_rad_s),
                       float(self.config.executor.velocity_scale) * self.robot.velocity_limit)
        return SplineTrajectory.from_path(np.stack([start, goal]), TrajectoryOptions(
            joint_velocity=v, min_segment_duration_s=0.1, respect_velocity_limit=True))

    def gaze_solver(self):
        """The robot's :class:`~humanoid_reach_ros.control.gaze.GazeSolver`, built on first use;
        its calls are serialised by ``_GAZE_LOCK`` (it owns one pinocchio data)."""
        solver = getattr(self, "_gaze_solver", None)
        if solver is None:
            from humanoid_reach_ros.control.gaze import GazeSolver
            with self._fk_lock:
                _ = self.robot.stance_soles      # cached on the shared data now, never under a gaze
            solver = self._gaze_solver = GazeSolver(self.robot)
        return solver

    def surroundings_points(self) -> np.ndarray:
        """The scan's gaze points at the space around the robot's own body (K, 3) [m, world]:
        ``control/gaze.py`` ``cover_gazes`` over ``surroundings_points`` of the shapes at the
        reference posture, the points the head poses of ``scan_poses_deg`` already see left out;
        at most ``scan_surroundings_looks``. Computed once per robot and count (about 3 s for
        HRP-2 here), then cached."""
        with _SURROUNDINGS_LOCK:
            return self._surroundings_points()

    def warm_surroundings(self) -> threading.Thread:
        """Compute :meth:`surroundings_points` in a thread (the node's start-up: the first scan
        then does not wait for it)."""
        t = threading.Thread(target=self.surroundings_points, name="scan_surroundings", daemon=True)
        t.start()
        return t

    def _surroundings_points(self) -> np.ndarray:
        k = int(self.config.scan_surroundings_looks)
        cache = getattr(self, "_surroundings", None)
        if cache is not None and cache[0] == k:
            return cache[1]
        if k <= 0:
            self._surroundings = (k, np.zeros((0, 3)))
            return self._surroundings[1]
        from humanoid_reach_ros.control.gaze import cover_gazes, surroundings_points
        from humanoid_reach_ros.robot.shapes import load_collision_model
        hs = self.robot.half_sitting_joints
        with self._fk_lock:
            cm = load_collision_model(None, self.robot)
            q = self.robot.config(hs, self.robot.base_on_feet(hs))
            P0, P1, R = cm.world_shapes(q)
            camera = self.robot.frame_pose(q, self.robot.camera_frame)
        poses = self.head_poses([], []) if self.robot.spec.has_neck else np.zeros((0, 2))
        solver = self.gaze_solver()
        # what the result depends on: the body, the camera, the gaze joints' limits, the scan, the count
        key = hashlib.sha1(np.concatenate([np.round(x, 6).ravel() for x in (
            P0, P1, np.asarray(R), camera.homogeneous, solver.lower, solver.upper, poses,
            np.array([k, solver.camera.half_fov_rad, solver.camera.min_range_m, solver.camera.max_range_m, 1.0]))
        ]).tobytes()).hexdigest()[:16]
        cache = _cache_dir() / f"scan_surroundings_{key}.npy"
        try:
            points = np.load(cache)
        except (OSError, ValueError):
            P = surroundings_points(P0, P1, R)
            seen = np.zeros(len(P), bool)
            with _GAZE_LOCK:
                idx = [self.robot.joint_index[n] for n in self.head_joints]
                for pose in poses:
                    j = hs.copy()
                    j[idx] = pose
                    seen |= solver.sees(j, P)
                points, _ = cover_gazes(solver, hs, P, seen, max_gazes=k, min_gain=0.02, grid_m=0.25)
            try:
                cache.parent.mkdir(parents=True, exist_ok=True)
                tmp = cache.with_suffix(f".{os.getpid()}.tmp.npy")
                np.save(tmp, points)
                os.replace(tmp, cache)
            except OSError:
                pass   # a read-only home: computed again next time
        self._surroundings = (k, points)
        return points

    def gaze(self, mid: int, label: str, point, joints: np.ndarray | None, reason: str):
        """A whole-body motion that aims the head camera at ``point`` (3,) [m, world] from the
        measured joints: (``Motion``, :class:`~humanoid_reach_ros.control.gaze.Gaze`). The goal is
        the balanced gaze of ``control/gaze.py`` (``GazeSolver.balanced``): head first, the chest
        where the head's limits cannot aim, the legs keeping the exact COG over the same point;
        the arms' joints held. The executor runs it like :meth:`look` (feet and exact COG at
        level 2, the right hand at level 3, the posture carrying the gaze at level 4), timed by
        :meth:`_look_spline`. A point no gaze brings into view is still looked at (the best
        effort; ``Gaze.visible`` False). ``INVALID_REQUEST`` for a NaN/inf or malformed point,
        ``NO_JOINT_STATES`` without joints."""
        from humanoid_reach_ros.execution.supervisor import Motion
        q0 = self.measured_start(joints, reason)
        start = np.asarray(joints, float)
        try:
            with _GAZE_LOCK:
                g = self.gaze_solver().balanced(start, point)
        except ValueError as exc:
            raise RequestError(C.INVALID_REQUEST, f"gaze point {point!r}: {exc}") from None
        share, why = self.look_clearance(start, g.joints)
        if share < 1.0:   # the body would come too near the map or itself: turn only part of the way
            partial = start + share * (g.joints - start)
            with _GAZE_LOCK:   # ... and the head alone the rest of its way, where that keeps the clearance
                reaimed = self.gaze_solver().head_reaimed(partial, g.point)
            head = self.look_clearance(start, reaimed)[0] >= 1.0 and not np.allclose(reaimed, partial)
            with _GAZE_LOCK:
                g = self.gaze_solver().stopped_short(
                    g, start, reaimed if head else partial,
                    f"turned {100 * share:.0f} % of the way to its gaze"
                    + (", the head alone further" if head else "") + f": {why}")
        yaw, pitch = self.head_targets(g.joints)
        note = (f"gaze at {np.round(g.point, 3).tolist()}: head yaw {math.degrees(yaw):.1f}, pitch "
                f"{math.degrees(pitch):.1f} deg, chest moved {math.degrees(g.chest_moved_rad):.1f} deg, "
                f"{g.off_axis_deg:.2f} deg off the camera axis" + ("" if g.visible else f"; {g.unseen_reason}")
                + (f"; {g.held_back}" if g.held_back and g.visible else ""))
        return Motion(mid, label, "trajectory", spline=self._look_spline(start, g.joints), arm="right",
                      params=self._executor_params(), q_measured=q0, note=note), g

    def look_clearance(self, start: np.ndarray, goal: np.ndarray, samples: int = 20,
                       bisections: int = 6) -> tuple[float, str]:
        """How far a look or gaze from joints ``start`` towards ``goal`` may go: ``(share, why)``,
        ``share`` in [0, 1] of the joint-space way (the look's reference is that straight line,
        timed), the largest with every sample keeping the clearance ``security_distance_m +
        look_clearance_m`` to the map and between the robot's own shapes (or, from a start
        already nearer, no nearer than the start), and why it stops (``""`` at 1). Why: a gaze
        that turns the chest swings the arms with it (a robot without a neck turns its body to
        look); where that reference runs into the velocity dampers the hand stays off its
        reference and the look fails after the settle timeout (the G1's 33 deg turns, hands in
        front of its thighs). From a start already nearer than that clearance (a hand resting at
        the valve) the motion may come ``look_clearance_m`` nearer, never within 2 mm of
        ``security_distance_m`` nor, from nearer still, nearer than the start. ``samples``
        points along the way, then ``bisections`` halvings between the last clear and the first
        blocked one."""
        coll, unseen = self._look_collision(), self._look_unseen_collision()
        d_s, margin = float(self.config.executor.security_distance_m), float(self.config.look_clearance_m)
        need = d_s + margin

        def distances(share: float) -> tuple[float, str, float]:
            j = start + share * (goal - start)
            with self._fk_lock:
                q = self.robot.config(j, self.robot.base_on_feet(j))
            d_env, d_self = coll.min_distance(q), coll.self_min_distance(q)
            d_unseen = unseen.min_distance(q) if unseen is not None else math.inf
            return (d_env, "the map", d_unseen) if d_env <= d_self else (d_self, "its own body", d_unseen)

        d0, _, u0 = distances(0.0)
        if d0 < need:   # a start already nearer (a hand at the valve): it may come nearer by the margin,
            # never within 2 mm of the dampers' d_s, never nearer than it is where it is nearer still
            need = min(max(d_s + 0.002, d0 - margin), d0)
        need_unseen = min(0.0, u0)   # out of the frontier's voxels; from a start already in them, no deeper

        def blocked(share: float) -> str:
            d, what, u = distances(share)
            if d < need:
                return f"further, the body would come within {max(d, 0.0) * 1e3:.0f} mm of {what} (the look " \
                       f"keeps {need * 1e3:.0f} mm)"
            if u < need_unseen:
                return "further, the body would enter space no sensor has seen (the unobserved frontier)"
            return ""

        last = 0.0
        for share in np.linspace(0.0, 1.0, samples + 1)[1:]:
            why = blocked(float(share))
            if why:
                lo, hi = last, float(share)
                for _ in range(bisections):
                    mid = 0.5 * (lo + hi)
                    if not blocked(mid):
                        lo = mid
                    else:
                        hi = mid
                return lo, why
            last = float(share)
        return 1.0, ""

    def _look_collision(self):
        """A :class:`~humanoid_reach_ros.geometry.distance.RobotCollision` on the current map
        (cached per sphere tree) for :meth:`look_clearance`."""
        from humanoid_reach_ros.geometry.distance import RobotCollision
        from humanoid_reach_ros.robot.shapes import load_collision_model
        with self._map_lock:
            tree = self._tree_cache if self._tree_cache is not None else self._tree(None)
        if self._look_cm is None:
            self._look_cm = load_collision_model(None, self.robot)
        if self._look_coll is None or self._look_coll.tree is not tree:
            self._look_coll = RobotCollision(self.robot, self._look_cm, tree)
        return self._look_coll

    def _look_unseen_collision(self):
        """A :class:`~humanoid_reach_ros.geometry.distance.RobotCollision` on the measured map plus
        the unobserved frontier (cached per sphere tree) for :meth:`look_clearance`; None where
        ``look_avoids_unobserved`` is off, no frontier came or the map is not a measured one."""
        if not self.config.look_avoids_unobserved:
            return None
        from humanoid_reach_ros.geometry.distance import RobotCollision
        from humanoid_reach_ros.robot.shapes import load_collision_model
        with self._map_lock:
            if self._frontier is not self._frontier_in_scene:
                self.scene.set_unobserved(frontier=self._frontier)
                self._frontier_in_scene = self._frontier
            snap = self.scene.snapshot()
            if snap.source != "/voxel_map" or snap.frontier is None or not len(snap.frontier):
                return None
            tree, _ = snap.tree(None, unobserved=True)
        if self._look_cm is None:
            self._look_cm = load_collision_model(None, self.robot)
        if self._look_unseen is None or self._look_unseen.tree is not tree:
            self._look_unseen = RobotCollision(self.robot, self._look_cm, tree)
        return self._look_unseen

    def head_targets(self, joints: np.ndarray) -> tuple[float, float]:
        """Head yaw and pitch [rad] of a joint vector (the ``Look`` feedback's fields); without a
        neck, the chest's (:attr:`head_joints`)."""
        yaw, pitch = (float(joints[self.robot.joint_index[n]]) for n in self.head_joints)
        return yaw, pitch

    def _executor_params(self):
        return self.config.executor

    def dual_arm_model(self) -> str | None:
        """The torso regression model of the dual-arm mode: the parameter, else the robot's."""
        return self.config.dual_arm_regression or self.robot.spec.torso_regression

    def dual_arm_workspace(self) -> str:
        """The dual-arm workspace file: the parameter, else the robot's (the one its model was trained on)."""
        return self.config.dual_arm_workspace or self.robot.spec.dual_arm_workspace

    def _need_dual_arm(self) -> None:
        if not self.dual_arm_model():
            raise RequestError(C.INVALID_REQUEST, f"robot {self.robot.name!r} has no dual-arm torso regression model "
                                               "(robot.yaml torso_regression: tools/train_torso_regression.py "
                                               f"--robot {self.robot.name}; or the dual_arm_regression parameter)")

    def dual(self, mid: int, label: str, targets, joints: np.ndarray | None, reason: str, follow: bool = False):
        """A dual-arm motion to validated hand targets; feasibility is the controller's, at the start."""
        from humanoid_reach_ros.execution.supervisor import Motion
        self._need_dual_arm()
        waist = None
        if needs_waist(targets) and joints is not None:
            with self._fk_lock:
                waist = self.robot.base_on_feet(joints)
        right, left = targets_in_world(targets, waist)
        q0 = self.measured_start(joints, reason)
        return Motion(mid, label, "dual", arm="both", targets=(right, left), follow=follow, q_measured=q0)

    def sequential(self, mid: int, label: str, count: int, seed: int, joints: np.ndarray | None, reason: str):
        """Sequential random targets (Sec. 5.4): ``count`` pairs the method reaches, drawn here
        (~30 ms a pair) by a controller of its own, built on the first call."""
        self._need_dual_arm()
        from humanoid_reach_ros.execution.supervisor import Motion
        q0 = self.measured_start(joints, reason)
        with self._sampler_lock:
            if self._sampler is None:
                from humanoid_reach_ros.dual_arm.controller import ControllerConfig, DualArmReachController
                from humanoid_reach_ros.dual_arm.torso_regression import ReachWorkspace, TorsoRegression
                self._sampler = DualArmReachController(
                    RobotModel(self.config.robot_config), TorsoRegression.load(self.dual_arm_model()),
                    ReachWorkspace.load(self.dual_arm_workspace()),
                    ControllerConfig(period_s=self.config.executor.period_s,
                                     max_speed_mps=self.config.dual_arm_max_speed_mps))
            pairs = self._sampler.sample_reachable(np.random.default_rng(seed), count)
        return Motion(mid, label, "sequential", arm="both", sequential=(count, seed, pairs), q_measured=q0)

    def unchanged(self, targets, current) -> bool:
        """The dual-arm controller already runs to / holds at (nearly) these targets."""
        if current is None:
            return False
        p_tol, r_tol = self.config.dual_arm_retarget_threshold_m, self.config.dual_arm_retarget_threshold_rad
        return all(np.linalg.norm(a.translation - b.translation) <= p_tol
                   and np.linalg.norm(pin.log3(a.rotation.T @ b.rotation)) <= r_tol
                   for a, b in zip(targets, current))

    def _reshape(self, spline, arm: str):
        """Smooth reshaping of ``spline`` against the current map (one at a time)."""
        from humanoid_reach_ros.robot.shapes import load_collision_model
        tree = self._tree_cache
        if tree is None or tree.n_spheres == 0:
            return spline, "smooth reshaping: no map, trajectory unchanged"
        t0 = time.perf_counter()
        if not self._reshape_lock.acquire(blocking=False):
            raise RequestError(C.ABORTED, "smooth reshaping busy: another goal is being reshaped; send it again "
                                          "when that one has started")
        try:
            if self._reshaper is None:
                from humanoid_reach_ros.planning.reshape import SmoothReshaper
                robot = RobotModel(self.config.robot_config)   # its own pinocchio data: thread safety
                self._reshaper = SmoothReshaper(robot, load_collision_model(None, robot))
            out = self._reshaper.reshape(spline, tree, arm)
        except Exception as exc:
            raise RequestError(C.ABORTED, f"smooth reshaping failed: {type(exc).__name__}: {exc}") from None
        finally:
            self._reshape_lock.release()
        before = float(np.min(out.distance_before)) if len(out.distance_before) else math.inf
        after = float(np.min(out.distance_after)) if len(out.distance_after) else math.inf
        return out.trajectory, (f"smooth reshaping: {len(out.portions)} portion(s) reshaped in "
                                f"{time.perf_counter() - t0:.2f} s, min distance {before:.4f} -> {after:.4f} m"
                                f"{'' if out.success else ' (collisions remain)'}")

    @staticmethod
    def describe(motion) -> str:
        """One line on an accepted motion."""
        if motion.kind == "sequential":
            return f"{motion.sequential[0]} sequential random target pairs (seed {motion.sequential[1]})"
        if motion.kind == "dual":
            r, l_ = motion.targets
            return (f"dual-arm reach, right hand to {np.round(r.translation, 3).tolist()}, left hand to "
                    f"{np.round(l_.translation, 3).tolist()} (world)")
        s, p = motion.spline, motion.params
        return (f"{motion.arm}-arm trajectory, {len(s.times)} points over {s.duration:.2f} s; collision "
                f"avoidance {'on' if p.collision_avoidance else 'OFF'}, COM compensation "
                f"{'on' if p.com_compensation else 'OFF'}" + (f"; {motion.note}" if motion.note else ""))
