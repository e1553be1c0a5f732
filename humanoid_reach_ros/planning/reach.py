"""Reaching motion planning, request to trajectory (Kanehiro et al., Sec. III-IV).

:class:`ReachPlanner` is the ROS-free core of the ``reach_planner`` node::

    set_map(voxels)        occupied voxel centres -> sphere tree (Quinlan) -> RobotCollision
    plan(start, request)   1. validate (finite start/region, arm, planner, map, start collision-free)
                           2. goal postures: sample_goals (Algorithm 1, right arm then left)
                           3. RRT-connect (or PRM) in q_plan = (q_arm, z_t, rpy_t) (eq. 2), seeded
                              with the start and every goal of the chosen arm; validity of a
                              batch of q_plan = project_plan_config ok (trunk horizontal position
                              by lines 3-4 of Algorithm 1, legs by closed-form IK, limits)
                              AND RobotCollision.check_batch
                           4. random shortcutting, waypoints -> full configurations (legs by IK)
                           5. durations T_i = max_j |q_{i+1,j} - q_{i,j}| / v, clamped cubic spline
                              over the 30 joints, sampled every ``output_period_s`` (and at
                              every waypoint time)

Arm ``"auto"``: goals are sampled for both arms in Algorithm 1's order (right arm
tried first on every sample); the arm of the first goal found is planned first and,
if no path is found within the budget, the other arm (if it has goals).

The start posture: the start joints with the base from ``RobotModel.base_on_feet``
(right sole at its stance pose). Its q_plan is ``Projector.plan_config_of``; the
projection of that q_plan puts the joints Algorithm 1 does not plan (the other arm,
chest, head, grippers) at the reference (half-sitting) values and the trunk
horizontally where COG_approx stays put. When the start differs from its projection
(any posture other than half-sitting with the reaching arm/trunk moved as the
planner would), the path begins with a *pre-segment*: the trunk pose and the
non-leg joints move linearly from the true start to the projected start, the legs
follow by closed-form IK to the stance feet; the pre-segment is collision-checked at
``edge_resolution`` like any planned edge (if the start's left foot is off its stance
pose, the legs are interpolated linearly with the base from ``base_on_feet``).

Error codes (:class:`PlanError`) are the numbers of
``humanoid_reach_interfaces/srv/PlanReach``. :meth:`ReachPlanner.plan` never raises.
No ROS here.
"""
from __future__ import annotations

import math
import threading
import time
import traceback
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np
import pinocchio as pin

from humanoid_reach_ros.geometry.distance import RobotCollision
from humanoid_reach_ros.planning.approach import ObjectDepthCheck
from humanoid_reach_ros.planning.goal_sampler import Goals, sample_goals
from humanoid_reach_ros.planning.trunk_region import TrunkRegion, TrunkSampler
from humanoid_reach_ros.planning.reach_map import InverseReach, ReachMap, region_centre
from humanoid_reach_ros.planning.enclosure import ArmTube, cell_size as enclosure_cell, enclosed, trunk_cells
from humanoid_reach_ros.planning.path import (
    PLANNER_NAMES, PlanningSpace, PlanStatus, ShortcutOptions, plan as run_planner, shortcut_path,
)
from humanoid_reach_ros.planning.plan_check import PlanChecker
from humanoid_reach_ros.planning.retreat import Retreat, RetreatParams, RetreatPlanner
from humanoid_reach_ros.codes import ARM_CODES, ARM_LEFT, ARM_NAMES, ARM_REQUESTS, ARM_RIGHT, PlanError, RequestError
from humanoid_reach_ros.planning.projector import LEGS, Projector, quat_xyzw_matrix
from humanoid_reach_ros.geometry.trajectory import SplineTrajectory, TrajectoryOptions
from humanoid_reach_ros.planning.wgr import WorkspaceGoalRegion, matrix_rpy
from humanoid_reach_ros.kinematics import LimbIKSet
from humanoid_reach_ros.robot.model import N_BASE_Q, RobotModel
from humanoid_reach_ros.robot.shapes import load_collision_model, point_segment_distance
from humanoid_reach_ros.scene.planning_scene import PlanningScene, SceneParams, SceneSnapshot, voxel_points

STAT_KEYS = (
    "goal_sampling_time_s", "goals_requested", "goals_found", "goals_right_arm", "goals_left_arm", "samples",
    "ik_failures_right_arm", "ik_failures_left_arm", "ik_failures_right_leg", "ik_failures_left_leg",
    "path_planning_time_s", "tree_nodes", "path_waypoints", "collision_checks", "collision_time_s",
    "map_voxels", "sphere_tree_build_time_s", "total_time_s",
)
"""Keys of :attr:`PlanOutcome.stats` = fields of ``humanoid_reach_interfaces/msg/PlanningStatistics``."""


@dataclass(frozen=True)
class PlannerParams:
    """Algorithm defaults of the reach planner (the node maps its ROS parameters onto these).

    Map: ``resolution_m`` voxel size = environment sphere diameter, ``safety_margin_m``
    added to every environment sphere radius. Requests: ``goal_count`` goal postures,
    ``planner`` (``rrt_connect`` | ``prm`` | ``modified_prm``), ``time_budget_s`` for goal
    sampling + path planning, ``seed``. Goal sampling runs until ``goal_count`` goals or
    ``goal_time_fraction`` of the budget (then plans with the goals found, >= 1; with none
    it keeps looking for one until the whole budget is spent: ``NO_GOAL_FOUND``). A target
    the geometric reach bound proves out of reach is answered ``TARGET_OUT_OF_REACH`` at
    once. Trunk ranges (:mod:`~humanoid_reach_ros.planning.trunk_region`): the heights and
    pitches the legs' IK allows at the stance within ``trunk_z_m`` (None: the legs' chain
    length decides) x ``trunk_pitch_rad``, narrowed to the cells from which the arm may
    reach the target; roll and yaw uniform in ``trunk_roll_rad`` / ``trunk_yaw_rad``. Arm
    ``auto``: the first arm gets at most ``first_arm_time_fraction`` of the remaining
    budget when the other arm has goals.
    Planning space (eq. 2) ``q_plan = (q_arm (n), z_t, rpy_t (3))``, ``n`` the arm's joints
    (6; 7 for a redundant arm: all planning variables): bounds = the arm
    joint limits and the request's trunk ranges, cut to ``trunk_space_margin`` (height
    [m], pitch [rad]; None: no cut) around the start and the goals (our choice: (0.1, 0.3)
    keeps paths from wandering through squats they do not need -- plant valve, 30 seeds:
    trajectory p50 / p90 3.6 / 5.1 s against 4.6 / 7.5 s uncut), and grown to include
    them; when RRT-connect finds no path there within ``trunk_space_cut_iterations``
    iterations (300: ~40 ms; 91 of 100 plant goals need fewer), the search goes on
    in the whole box (a detour may need it); metric ``||W dq||`` with ``W = (arm_weight xn, trunk_z_weight,
    trunk_rpy_weight x3)`` (:meth:`weights_for`), edges checked every ``edge_resolution``, RRT step ``rrt_step``.
    ``rrt_step`` is 1.0 (not 0.3): every checker call projects its batch through the
    closed-form leg IK, whose numpy cost was per call rather than per configuration, so
    fewer, longer CONNECT/EXTEND calls planned ~2.5x faster on the plant scene (20 valve
    requests: path mean 1.28 s at 0.3 vs 0.50 s at 1.0, with 3 vs 0 timeouts in 2 s;
    measured before the compiled projection kernel, which made the per-call cost small).
    Path: ``shortcut_iterations`` random shortcuts (``shortcut_time_s`` is only a safety
    cap: the result stays a deterministic function of the seed while it is not hit).
    Trajectory: ``joint_velocity_rad_s`` (durations rule), samples every
    ``output_period_s`` plus every waypoint time (``include_waypoint_times``); its exact peak
    velocity is held within the executor's level-1 bound ``velocity_scale * URDF limit`` per
    joint (``velocity_scale``: the ``reach_executor``'s parameter, 0.5 there too) by timing at
    ``min(joint_velocity_rad_s, bound)`` and stretching time when the cubic's peak passes the
    bound. Plant valve, 20 seeds: peaks 0.67-0.75 rad/s, at most 0.44 of the bound, so no
    stretch at scale 0.5 (at 0.2: p50 x1.0, max x1.10); capping the peak at
    ``joint_velocity_rad_s`` itself would make every reach ~1.5x longer (p50 3.4 -> 5.0 s).
    """

    resolution_m: float = 0.02
    safety_margin_m: float = 0.0
    goal_count: int = 10
    planner: str = "rrt_connect"
    time_budget_s: float = 2.0
    joint_velocity_rad_s: float = 0.5
    velocity_scale: float = 0.5       # fraction of the URDF velocity limits (the executor's parameter)
    output_period_s: float = 0.05
    edge_resolution: float = 0.03
    rrt_step: float = 1.0
    seed: int = 0
    # trunk ranges searched (planning/trunk_region.py: the legs and the target narrow them)
    trunk_z_m: tuple[float, float] | None = None
    trunk_roll_rad: tuple[float, float] = (-0.1, 0.1)
    trunk_pitch_rad: tuple[float, float] = (-0.3, 0.9)
    trunk_yaw_rad: tuple[float, float] = (-0.4, 0.4)
    trunk_space_margin: tuple[float, float] | None = (0.1, 0.3)
    trunk_space_cut_iterations: int = 300
    # metric weights
    arm_weight: float = 1.0
    trunk_z_weight: float = 2.0
    trunk_rpy_weight: float = 1.0
    # budgets
    goal_time_fraction: float = 0.6
    first_arm_time_fraction: float = 0.5
    goal_batch_size: int = 512
    shortcut_iterations: int = 30
    shortcut_time_s: float = 1.0
    prm_samples: int = 300
    include_waypoint_times: bool = True
    start_limit_tolerance_rad: float = 1e-3
    unobserved_check_budget_s: float = 1.0
    # the robot's reachability map (planning/reach_map.py; robot.yaml reach_map): the proof of
    # TARGET_OUT_OF_REACH and the goal sampler's trunk cells; roll x yaw cell size [rad] and
    # the capability map's proposals tried per goal sample
    use_reach_map: bool = True
    reach_map_step_rad: float = 0.05
    reach_map_candidates: int = 16
    reach_map_min_orientations: int = 4     # cells where the map holds fewer at the target come last
    reach_map_batch_size: int = 64          # goal samples per batch with the map (goal_batch_size without)
    # the target's object (the voxels left out around the target): a path's shapes no deeper in it than
    # at the path's ends, give or take this (planning/approach.py; the retreat back along it allows 15 mm,
    # so 3 mm stay for the executor's deviation). 3 mm left make demo ROBOT=talos without a path to the
    # valve (NO_PATH after 5 s, 203k collision checks; 2026-11-29), 12 mm planned it in 313 ms
    object_depth_tolerance_m: float = 0.012

    def __post_init__(self) -> None:
        for name in ("resolution_m", "time_budget_s", "joint_velocity_rad_s", "output_period_s", "edge_resolution",
                     "rrt_step", "arm_weight", "trunk_z_weight", "trunk_rpy_weight", "trunk_space_cut_iterations",
                     "reach_map_step_rad", "reach_map_candidates", "reach_map_min_orientations",
                     "reach_map_batch_size"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"PlannerParams.{name} must be finite and > 0, got {v}")
        if not self.object_depth_tolerance_m >= 0:     # inf: the object's depth unchecked (the old paths)
            raise ValueError(f"PlannerParams.object_depth_tolerance_m must be >= 0, got "
                             f"{self.object_depth_tolerance_m}")
        if not (self.safety_margin_m >= 0 and math.isfinite(self.safety_margin_m)):
            raise ValueError(f"PlannerParams.safety_margin_m must be >= 0, got {self.safety_margin_m}")
        if self.goal_count < 1:
            raise ValueError(f"PlannerParams.goal_count must be >= 1, got {self.goal_count}")
        if self.planner not in PLANNER_NAMES:
            raise ValueError(f"PlannerParams.planner must be one of {PLANNER_NAMES}, got {self.planner!r}")
        if not 0 < self.goal_time_fraction <= 1:
            raise ValueError("PlannerParams.goal_time_fraction must be in (0, 1]")
        m = self.trunk_space_margin
        if m is not None and not (len(m) == 2 and all(math.isfinite(x) and x >= 0 for x in m)):
            raise ValueError(f"PlannerParams.trunk_space_margin: need None or (height >= 0, pitch >= 0), got {m}")
        for name in ("trunk_z_m", "trunk_roll_rad", "trunk_pitch_rad", "trunk_yaw_rad"):
            r = getattr(self, name)
            if r is None and name == "trunk_z_m":
                continue
            if not (len(r) == 2 and all(math.isfinite(x) for x in r) and r[0] <= r[1]):
                raise ValueError(f"PlannerParams.{name}: need finite lo <= hi, got {r}")

    def weights_for(self, n_arm: int) -> np.ndarray:
        """The metric's weights of a planning space with ``n_arm`` arm joints."""
        return np.array([self.arm_weight] * n_arm + [self.trunk_z_weight] + [self.trunk_rpy_weight] * 3)

    @property
    def weights(self) -> np.ndarray:
        """:meth:`weights_for` six arm joints (the benches' HRP-2 figures)."""
        return self.weights_for(6)


@dataclass
class PlanRequest:
    """One reach request. ``region`` is in the world frame; ``None`` fields take the
    :class:`PlannerParams` value."""

    region: WorkspaceGoalRegion | None
    arm: str = "auto"
    goal_count: int | None = None
    planner: str | None = None
    time_budget_s: float | None = None
    seed: int | None = None
    home: bool = False              # plan back to the rest posture (region, arm, goal_count ignored)
    approach: np.ndarray | None = None   # (3,) the hand's last approach direction (retreat: reverse it first)


@dataclass
class PlanOutcome:
    """Result of :meth:`ReachPlanner.plan` (arrays ``None`` unless ``success``, except
    ``goals`` which holds whatever was sampled). ``waypoint_times`` (W,): the time of
    each waypoint in the trajectory (its sample is exactly the waypoint's joints);
    ``waypoints_plan`` (W', n + 4): the shortcut path in q_plan (without the pre-segment);
    ``goal_arms`` (G,) arm codes (``codes.ARM_RIGHT`` / ``ARM_LEFT``); ``goal_index``: the goal reached.
    ``stats["collision_time_s"]`` includes the capsule forward kinematics."""

    success: bool
    error: PlanError
    message: str
    arm: str | None
    joint_names: tuple[str, ...]
    times: np.ndarray | None = None
    positions: np.ndarray | None = None
    velocities: np.ndarray | None = None
    accelerations: np.ndarray | None = None
    waypoints: np.ndarray | None = None
    goals: np.ndarray | None = None
    waist_start: pin.SE3 | None = None
    stats: dict = field(default_factory=lambda: _empty_stats())
    # additions
    waypoint_times: np.ndarray | None = None
    waypoints_plan: np.ndarray | None = None
    goal_arms: np.ndarray | None = None
    goal_index: int | None = None
    trajectory: SplineTrajectory | None = None
    retreat: str = ""                        # the retreat planned first when the start touched the map
    #: every retreat tried and why it failed, when none freed a start in contact (the message keeps six)
    retreats_tried: tuple[str, ...] = ()
    unobserved_points: np.ndarray | None = None   # (K, 3) where the target / best path meets unobserved space
    scene_version: int = 0


def _empty_stats() -> dict:
    return {k: (0.0 if k.endswith("_s") else 0) for k in STAT_KEYS}


def _finite(a) -> bool:
    try:
        return bool(np.all(np.isfinite(np.asarray(a, dtype=float))))
    except (TypeError, ValueError):
        return False


#: caps of one request: an operator asking for more is a typo, and the node must stay responsive
MAX_GOAL_COUNT = 1000
MAX_TIME_BUDGET_S = 60.0


def check_plan_values(arm, planner, goal_count, time_budget_s, seed=None) -> None:
    """The one validator of a plan request's values, for ``ReachPlanner.plan`` and the
    ``PlanReach`` conversion alike (``io/msgs.reach_request``): ``RequestError``
    (``INVALID_REQUEST``) naming the value. ``None`` (or ``""``, ``0`` but for ``seed``): the
    planner's default."""
    def bad(text: str) -> RequestError:
        return RequestError(PlanError.INVALID_REQUEST, text, source="planner")
    if arm not in (None, "") and arm not in ARM_REQUESTS:
        raise bad(f"arm must be one of {tuple(ARM_REQUESTS)}, got {arm!r}")
    if planner not in (None, "") and planner not in PLANNER_NAMES:
        raise bad(f"planner {planner!r} is unknown; use one of {', '.join(PLANNER_NAMES)} (empty = node default)")
    if goal_count not in (None, 0) and not (isinstance(goal_count, (int, np.integer)) and
                                            1 <= goal_count <= MAX_GOAL_COUNT):
        raise bad(f"goal_count must be an integer in [1, {MAX_GOAL_COUNT}] (0 = node default), got {goal_count!r}")
    if time_budget_s not in (None, 0) and not (isinstance(time_budget_s, (int, float, np.floating)) and
                                               0.0 < time_budget_s <= MAX_TIME_BUDGET_S):
        raise bad(f"time_budget_s must be in [0, {MAX_TIME_BUDGET_S:g}] s (0 = node default), got {time_budget_s!r}")
    if seed is not None and not (isinstance(seed, (int, np.integer)) and seed >= 0):
        raise bad(f"seed must be a non-negative integer, got {seed!r}")


def _failure(error: PlanError, message: str, **extra) -> RequestError:
    """A plan that cannot be made: the core's one error type, from the planner."""
    return RequestError(error, message, source="planner", **extra)


#: ReachPlanner's default ``retreat`` (one frozen instance, shared by every planner)
_DEFAULT_RETREAT = RetreatParams()
#: the robot "stands at the last plan's end" (its reverse is the first retreat tried) when the
#: plan's hand is this close to the plan's end and no joint but the head's this far off it
REVERSE_HAND_TOL_M = 0.03
# the console's left-arm reach into the valve's hub ended 0.17-0.34 rad off the plan's end (chest yaw, the arm's
# shoulder; four graphs); at 0.35 one such Home tried no reverse (its hand had converged, so a joint was
# farther off) and no line freed the hand inside the wheel: START_IN_COLLISION. Every sample is checked
REVERSE_JOINT_TOL_RAD = 0.5
WAY_IN_REST_TOL_RAD = 0.02       # a plan that began this near rest (head aside): its way in, reversed, goes home


class ReachPlanner:
    """Goal sampling + path planning + trajectory for reach requests (see module doc).

    ``robot`` defaults to ``RobotModel()``; the collision model is the robot's default.
    ``compiled_kinematics=False`` projects q_plan through the numpy reference leg IK
    instead of the fused numba kernel, ``early_exit_checks=False`` checks every point of
    an edge chain even after an invalid one (both: same plans, slower; for baseline
    benchmarks).
    Thread safety: :meth:`set_map` may be called while a plan runs (a plan uses the map it
    started with); overlapping :meth:`plan` calls get ``BUSY``.
    """

    def __init__(self, robot: RobotModel | None = None, params: PlannerParams = PlannerParams(),
                 compiled_kinematics: bool = True, early_exit_checks: bool = True,
                 scene: PlanningScene | None = None, retreat: RetreatParams = _DEFAULT_RETREAT,
                 observable=None) -> None:
        self.robot = RobotModel() if robot is None else robot
        self.params = params
        if scene is None:
            self.collision_model = load_collision_model(None, self.robot)
            scene = PlanningScene(self.robot, SceneParams(resolution_m=params.resolution_m,
                                                          safety_margin_m=params.safety_margin_m),
                                  self.collision_model)
        else:
            self.collision_model = scene.collision_model
        self.scene = scene
        self.retreat_planner = RetreatPlanner(self.robot, self.collision_model, retreat)
        #: ``observable(joints (n,), points (K, 3)) -> (K,) bool``: whether some reachable gaze of the
        #: head camera sees each point (control/gaze.py); None: every point counts as observable
        self.observable = observable
        self._last_plan_end: tuple[np.ndarray, np.ndarray] | None = None   # (joints, hand approach direction)
        self._last_positions: np.ndarray | None = None   # the last successful plan's samples (its reverse: a retreat)
        # ... its sample times, waypoints and their times (the way home as its way in, reversed)
        self._last_way: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._last_arm: str | None = None                 # and its arm
        self.projector = Projector(self.robot, LimbIKSet(self.robot, compiled=compiled_kinematics))
        self.trunk_region = TrunkRegion(self.projector, params.trunk_z_m, params.trunk_pitch_rad,
                                        params.trunk_roll_rad, params.trunk_yaw_rad)
        #: the reach map's inverse (None: the robot names no map, or ``use_reach_map`` is off); a
        #: map the description names but that is missing or corrupt is a ValueError (the node exits 2)
        self.reach: InverseReach | None = None
        if params.use_reach_map and self.robot.spec.reach_map:
            self.reach = InverseReach(ReachMap.load(self.robot.spec.reach_map, self.robot), self.trunk_region,
                                      params.reach_map_step_rad)
        self.early_exit_checks = bool(early_exit_checks)
        self._tubes: dict | None = None   # arm -> enclosure.ArmTube (None: no proof for that arm), at first use
        self._trunk_cells: tuple | None = None   # enclosure.trunk_cells, without a reach map, at first use
        self._tree_build_s = 0.0
        self._pre_segment_why = ""
        self._plan_lock = threading.Lock()
        self._checker_lock = threading.Lock()
        self._checkers: dict = {}   # arm -> (collision, PlanChecker) of the last map used
        self.nq = self.robot.model.nq
        self._left_sole = self.robot.stance_soles[1]

    # ------------------------------------------------------------ map
    def set_map(self, voxels: np.ndarray, unobserved: np.ndarray | None = None) -> float:
        """Occupied voxel centres (N, 3) in the world into the planning scene; returns the build
        time [s] of its sphere tree. ValueError on a non-(N, 3) or non-finite array; N = 0 is
        free space. (The scene is the world model; this is the library's shortcut to it.)

        ``unobserved`` (K, 3): voxels of unobserved space the robot must not enter (a mapper's
        frontier), same resolution. Plans avoid them like occupied voxels; a plan that fails
        only because of them is answered ``UNOBSERVED_SPACE`` (checked against the occupied
        voxels alone, see :meth:`plan`)."""
        V = voxel_points(voxels, "voxels")
        U = None if unobserved is None else voxel_points(unobserved, "unobserved voxels")
        self.scene.set_occupied(V, source="set_map")
        if U is None:
            self.scene.forget_unobserved()
        else:
            self.scene.set_unobserved(U, np.zeros((0, 3)))
        snap = self.scene.snapshot()
        _, dt = snap.tree(None, snap.avoids_unobserved)
        self._tree_build_s = dt
        return dt

    def clear_map(self) -> None:
        self.scene.clear()

    @property
    def has_map(self) -> bool:
        return self.scene.has_map

    @property
    def map_voxels(self) -> int:
        return int(len(self.scene.snapshot().occupied))

    @property
    def unobserved_voxels(self) -> int:
        """Unobserved voxels the current map makes the robot avoid (0: none)."""
        snap = self.scene.snapshot()
        return int(len(snap.frontier)) if snap.avoids_unobserved else 0

    @property
    def collision(self) -> RobotCollision | None:
        """The current robot-vs-map checker (``None`` without a map)."""
        snap = self.scene.snapshot()
        if not snap.has_map:
            return None
        return snap.collision(self.robot, self.collision_model, None, snap.avoids_unobserved)[0]

    def _scene_collision(self, snap: SceneSnapshot, target: np.ndarray | None,
                         ) -> tuple[RobotCollision, RobotCollision | None, float]:
        """The plan's checker (occupied voxels, and the unobserved frontier when avoided, without
        the object at ``target``), the occupied-only checker when they differ, the build time."""
        full, dt = snap.collision(self.robot, self.collision_model, target, snap.avoids_unobserved)
        known = None
        if snap.avoids_unobserved and len(snap.frontier):
            known, dt2 = snap.collision(self.robot, self.collision_model, target, False)
            dt += dt2
        return full, known, dt

    # ------------------------------------------------------------ start
    def start_config(self, start_joints: np.ndarray) -> np.ndarray:
        """Full configuration of the start: joints + base from ``base_on_feet``."""
        j = np.asarray(start_joints, dtype=float).reshape(-1)
        return self.robot.config(j, self.robot.base_on_feet(j))

    def _validate_joints(self, start_joints) -> np.ndarray:
        if not _finite(start_joints):
            raise _failure(PlanError.INVALID_REQUEST, "start joint positions contain NaN/inf or are not numbers")
        j = np.asarray(start_joints, dtype=float).reshape(-1)
        if j.shape[0] != self.robot.n_joints:
            raise _failure(PlanError.INVALID_REQUEST,
                           f"start must have {self.robot.n_joints} joint positions, got {j.shape[0]}")
        tol = self.params.start_limit_tolerance_rad
        bad = np.flatnonzero((j < self.robot.lower - tol) | (j > self.robot.upper + tol))
        if bad.size:
            names = ", ".join(f"{self.robot.joint_names[i]}={j[i]:.3f}" for i in bad[:5])
            raise _failure(PlanError.INVALID_REQUEST, f"start joints outside their limits: {names}")
        return np.clip(j, self.robot.lower, self.robot.upper)

    def colliding_shapes(self, q: np.ndarray, collision: RobotCollision | None = None) -> list[str]:
        """Names of the robot shapes in collision at ``q``: ``"shape"`` (environment) and
        ``"a<->b"`` (self pairs)."""
        collision = self.collision if collision is None else collision
        if collision is None:
            return []
        P0, P1 = collision.world_shapes(q)
        names = list(self.collision_model.names)
        out = []
        if collision.tree.n_spheres:
            hit = collision.tree.intersects_batch(P0, P1, collision.radii)
            out += [names[s] for s in np.flatnonzero(hit)]
        out += [f"{a}<->{b}"
                for a, b, _ in self.collision_model.colliding_pairs(P0, P1, margin=collision.self_margin_m)]
        return out

    def check_start(self, start_joints) -> tuple[bool, str]:
        """Is the start valid (finite, 30 joints within limits) and collision-free in the
        current map? ``(ok, reason)``."""
        try:
            j = self._validate_joints(start_joints)
            collision = self.collision
            if collision is None:
                return False, "no map received yet"
            q = self.start_config(j)
            if not collision.check(q):
                shapes = self.colliding_shapes(q, collision)
                return False, "start posture in collision: " + (", ".join(shapes) if shapes else "unknown shapes")
            return True, "start posture valid"
        except RequestError as e:
            return False, e.message

    # ------------------------------------------------------------ planning space
    def trunk_sampling(self, region: WorkspaceGoalRegion, arm: str = "auto",
                       q_start: np.ndarray | None = None, cells: np.ndarray | None = None) -> TrunkSampler:
        """The trunk cells searched for ``region``, nearest the trunk of ``q_start`` (a full
        configuration) first: the reach map's inverse at the target (``cells`` (M, 4) from
        ``InverseReach.for_target``, computed here when None) where the robot has a map, else
        the heights x pitches of ``TrunkRegion.for_target``."""
        deep = None
        if self.reach is not None:
            if cells is None:
                _, cells, _ = self.reach.for_target(region, _arm_names(arm))
            if len(cells):
                trunk = self.trunk_region.from_cells(cells, self.reach.droll, self.reach.dyaw, self.reach.proposals,
                                                     self.params.reach_map_candidates)
                # cells from which the target is deep inside the capability map first (a voxel at the
                # reachable set's border holds few orientations and is reachable only in part)
                deep = self.reach.held(region, cells, _arm_names(arm)) >= self.params.reach_map_min_orientations
            else:
                trunk = self.trunk_region.for_target(region, arm)
        else:
            trunk = self.trunk_region.for_target(region, arm)
        if q_start is None:
            return trunk if deep is None else trunk.near(0.0, 0.0, 0.0, 0.0, first=deep)
        pitch = float(matrix_rpy(quat_xyzw_matrix(np.asarray(q_start[3:7], float)))[1])
        return trunk.near(float(q_start[2]), pitch, self.params.trunk_z_weight, self.params.trunk_rpy_weight,
                          first=deep)

    def planning_space(self, arm: str, include: np.ndarray | None = None,
                       trunk: TrunkSampler | None = None, cut: bool = True) -> PlanningSpace:
        """Box of eq. 2 for ``arm``: arm joint limits, the trunk ranges of ``trunk`` (default:
        every leg-feasible cell), cut to ``trunk_space_margin`` around ``include`` (k, n + 4)
        when ``cut``, and grown to include it."""
        p = self.params
        ji = np.array(self.robot.limbs[f"{arm}_arm"].joint_index)
        na = len(ji)
        t_lo, t_hi = (self.trunk_region.all_cells() if trunk is None else trunk).bounds()
        if cut and include is not None and len(include) and p.trunk_space_margin is not None:
            m = np.array([p.trunk_space_margin[0], p.trunk_roll_rad[1] - p.trunk_roll_rad[0], p.trunk_space_margin[1],
                          p.trunk_yaw_rad[1] - p.trunk_yaw_rad[0]])
            t_lo = np.maximum(t_lo, np.min(include[:, na:], axis=0) - m)
            t_hi = np.minimum(t_hi, np.max(include[:, na:], axis=0) + m)
        lo = np.concatenate([self.robot.lower[ji], t_lo])
        hi = np.concatenate([self.robot.upper[ji], t_hi])
        if include is not None and len(include):
            lo = np.minimum(lo, np.min(include, axis=0))
            hi = np.maximum(hi, np.max(include, axis=0))
        return PlanningSpace(lo, hi, p.weights_for(na), p.edge_resolution)

    def search_path(self, arm: str, start_plan: np.ndarray, goal_plan: np.ndarray, collision: RobotCollision,
                    rng: np.random.Generator, planner: str, budget_s: float, trunk: TrunkSampler | None = None,
                    shortcut_s=None, is_valid=None):
        """Path in ``q_plan`` from ``start_plan`` (n + 4,) to any of ``goal_plan`` (G, n + 4), then
        shortcut: ``(result, path or None, tree nodes)``. RRT-connect runs first in the
        planning space cut around the start and the goals (at most
        ``trunk_space_cut_iterations`` iterations: deterministic for a seed), then, if that
        found nothing, in the whole box of the target's trunk cells for the rest of
        ``budget_s``: short paths where they exist, a detour (ducking under a pipe) where
        one is needed. The roadmap planners search the whole box at once. ``shortcut_s``: a
        callable giving the shortcut's time cap when it starts (default ``shortcut_time_s``)."""
        p = self.params
        t0 = time.perf_counter()
        include = np.vstack([start_plan[None], goal_plan])
        is_valid = self.validity_fn(arm, collision) if is_valid is None else is_valid
        spaces = [(self.planning_space(arm, include, trunk, cut=False), None)]
        if p.trunk_space_margin is not None and planner == "rrt_connect":
            spaces.insert(0, (self.planning_space(arm, include, trunk), p.trunk_space_cut_iterations))
        nodes = 0
        for k, (space, iterations) in enumerate(spaces):
            remaining = budget_s - (time.perf_counter() - t0)
            if remaining <= 0 and k > 0:
                break
            options = self._planner_options(planner, max(0.0, remaining))
            if iterations is not None:
                options = replace(options, max_iterations=iterations)
            result = run_planner(planner, start_plan, goal_plan, is_valid, space, rng, options)
            nodes += result.stats.nodes
            if result.success:
                cap = p.shortcut_time_s if shortcut_s is None else shortcut_s()
                path = shortcut_path(result.path, is_valid, space, rng, ShortcutOptions(p.shortcut_iterations, cap))
                return result, path, nodes
        return result, None, nodes

    def validity_fn(self, arm: str, collision: RobotCollision, projector: Projector | None = None):
        """``is_valid_batch(Q_plan (k, n + 4)) -> (k,)``: projection ok and collision-free.

        With the compiled kinematics and early exit (the defaults) this is a
        :class:`~humanoid_reach_ros.planning.plan_check.PlanChecker` (projection, forward
        kinematics and collision tests fused in one kernel, specialised to the planning
        manifold; same verdicts), built once per arm and map. ``projector``: another manifold
        than the planner's (the way home's start-posture manifold), checked through it."""
        if projector is None and self.early_exit_checks and self.projector.compiled:
            return self._plan_checker(arm, collision)
        projector = self.projector if projector is None else projector

        def is_valid(Q: np.ndarray) -> np.ndarray:
            res = projector.project_plan_config(Q, arm)
            ok = res.ok.copy()
            idx = np.flatnonzero(ok)
            if idx.size:
                ok[idx] = collision.check_batch(res.q[idx])
            return ok

        def first_invalid(Q: np.ndarray) -> int:
            """The first row that does not project or collides (len(Q) if none); the
            rows after it are not collision-checked (see ``path.check_edges(prefix=True)``)."""
            res = projector.project_plan_config(Q, arm)
            k = len(Q) if res.ok.all() else int(np.argmin(res.ok))
            return collision.first_collision(res.q[:k]) if k else 0

        if self.early_exit_checks:
            is_valid.first_invalid = first_invalid
        return is_valid

    def _object_depth_check(self, arm: str, collision: RobotCollision, snap: SceneSnapshot, target: np.ndarray,
                            q_start: np.ndarray, start_plan: np.ndarray, goal_plan: np.ndarray,
                            ) -> ObjectDepthCheck | None:
        """The path search's checker with the target's object (planning/approach.py): the voxels
        ``collision`` leaves out around ``target``, no shape deeper in them than at the start (and
        its projection) or at the deepest of ``goal_plan``; None when nothing is left out."""
        r = float(snap.params.target_exclusion_radius_m)
        V = np.asarray(snap.occupied, float).reshape(-1, 3)
        if r <= 0.0 or not len(V) or not math.isfinite(self.params.object_depth_tolerance_m):
            return None
        obj = V[np.sum((V - np.asarray(target, float)) ** 2, axis=1) <= r * r]
        if not len(obj):
            return None

        def project(Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            res = self.projector.project_plan_config(Q, arm)
            return res.q, res.ok

        check = ObjectDepthCheck(self.validity_fn(arm, collision), project, collision, obj,
                                 float(snap.params.resolution_m), self.params.object_depth_tolerance_m,
                                 float(snap.params.safety_margin_m))
        q, ok = project(np.vstack([start_plan[None], goal_plan]))
        check.set_ends(np.vstack([q_start[None], q[ok]]))
        return check

    def _dense_full(self, path_plan: np.ndarray, arm: str) -> np.ndarray:
        """Full configurations of a q_plan path with its edges cut at ``edge_resolution`` (the
        metric's weights), the rows that do not project left out."""
        W = self.params.weights_for(path_plan.shape[1] - 4)
        rows = [path_plan[:1]]
        for a, b in zip(path_plan[:-1], path_plan[1:]):
            m = max(1, int(math.ceil(float(np.linalg.norm(W * (b - a))) / self.params.edge_resolution)))
            rows.append(a + (np.arange(1, m + 1)[:, None] / m) * (b - a))
        res = self.projector.project_plan_config(np.vstack(rows), arm)
        return res.q[res.ok]

    def _plan_checker(self, arm: str, collision: RobotCollision) -> PlanChecker:
        with self._checker_lock:
            hit = self._checkers.get(arm)
            if hit is not None and hit[0] is collision:
                return hit[1]
        checker = PlanChecker(self.projector, collision, arm)
        with self._checker_lock:
            self._checkers[arm] = (collision, checker)
        return checker

    def full_configs(self, Q_plan: np.ndarray, arm: str) -> np.ndarray:
        """Full configurations (n, nq) of q_plan rows (legs by IK); ValueError if one fails."""
        res = self.projector.project_plan_config(Q_plan, arm)
        if not np.all(res.ok):
            raise ValueError("a q_plan of the path does not project (leg IK / limits)")
        return res.q

    # ------------------------------------------------------------ pre-segment
    def _pre_segment(self, q_start: np.ndarray, q_proj: np.ndarray, collision: RobotCollision) -> np.ndarray | None:
        """Configurations (m+1, nq) from the true start to its projection (see module doc),
        every one collision-free and within limits, or ``None`` if the motion is invalid.
        Returns an empty (0, nq) array when the start equals its projection."""
        dj = np.abs(q_start[N_BASE_Q:] - q_proj[N_BASE_Q:])
        dp = np.linalg.norm(q_start[:3] - q_proj[:3])
        if dj.max() < 1e-9 and dp < 1e-9:
            return np.zeros((0, self.nq))
        w = self.params.edge_resolution
        m = max(1, int(math.ceil(max(dj.max() / (w / self.params.arm_weight), dp * self.params.trunk_z_weight / w))))
        s = np.arange(m + 1)[:, None] / m
        Q = q_start + s * (q_proj - q_start)
        # orientation: both have the same rpy_t (plan_config_of keeps it): keep the start quaternion
        Q[:, 3:7] = q_start[3:7]
        left_sole = self.robot.frame_pose(q_start, self.robot.sole_frames[1])
        feet_ok = (np.linalg.norm(left_sole.translation - self._left_sole.translation) < 5e-3
                   and np.linalg.norm(pin.log3(left_sole.rotation.T @ self._left_sole.rotation)) < 5e-3)
        if feet_ok:
            R_t = np.repeat(pin.XYZQUATToSE3(q_start[:7]).rotation[None], len(Q), axis=0)
            good = np.ones(len(Q), bool)
            for leg in LEGS:
                fp, fR = self.projector.feet[leg]
                res = self.projector.ik.solve(leg, Q[:, :3], R_t, fp, fR)
                good &= res.ok
                cols = self.projector.cols[leg]
                Q[np.ix_(np.flatnonzero(res.ok), cols)] = res.q[res.ok]
            if not np.all(good[1:]):
                feet_ok = False
            Q[0] = q_start
        if not feet_ok:  # linear joints, base on the right foot
            Q = q_start + s * (q_proj - q_start)
            for k in range(1, m):
                Q[k] = self.start_config(Q[k, N_BASE_Q:])
        joints = Q[:, N_BASE_Q:]
        if not np.all((joints >= self.robot.lower - 1e-9) & (joints <= self.robot.upper + 1e-9)):
            self._pre_segment_why = "a joint limit"
            return None
        ok = collision.check_batch(Q)
        if not np.all(ok):
            k = int(np.argmin(ok))
            self._pre_segment_why = (f"{', '.join(self.colliding_shapes(Q[k], collision)) or 'a shape'} at "
                                     f"{100 * k / max(len(Q) - 1, 1):.0f} %")
            return None
        return Q

    # ------------------------------------------------------------ plan
    def plan(self, start_joints: np.ndarray, request: PlanRequest) -> PlanOutcome:
        """Plan a reach (or, with ``request.home``, the way back to the rest posture) from
        ``start_joints`` (30,) in the planning scene as it is now; never raises. The start
        posture's body is marked in the scene as observed free space first."""
        if not self._plan_lock.acquire(blocking=False):
            return self._fail(PlanError.BUSY, "another plan is running", _empty_stats())
        t0 = time.perf_counter()
        stats = _empty_stats()
        snap = None
        try:
            try:
                self._request_values(request)
                joints = self._validate_joints(start_joints)
                self.scene.mark_body(joints)
                snap = self.scene.snapshot()   # the plan and its unobserved-space check use this one
                try:
                    outcome = self._plan(joints, request, stats, t0, snap)
                except RequestError as e:
                    outcome = self._fail(e.code, e.message, stats, t0, **e.extra)
                manifold = outcome.error == PlanError.START_IN_COLLISION and "pre_segment" in outcome.message
                for farther in (0.12, 0.2) if manifold else ():
                    # the start (or the retreat's end) is clear but the way onto the planning manifold
                    # is not: the pre-segment moves the trunk and the chest, the hand with them (seen
                    # after the demo's reach: the hand back into the valve at 38 % of it). Retreat
                    # from the nearest hand, farther (MoveIt Task Constructor's retreats: 0.12-0.25 m)
                    try:
                        outcome = self._plan(joints, request, _empty_stats(), t0, snap, force_retreat=True,
                                             min_retreat_m=farther)
                    except RequestError as e:
                        outcome = self._fail(e.code, e.message, stats, t0, **e.extra)
                    if outcome.error != PlanError.START_IN_COLLISION or "pre_segment" not in outcome.message:
                        break   # planned, or no retreat that long (a longer one is no easier)
                if manifold and not request.home and outcome.error == PlanError.START_IN_COLLISION:
                    # whatever the longer retreats answered (bench/session: "no retreat of 50-250 mm
                    # frees it" ended the reach, while the way home from the same posture planned)
                    outcome = self._via_home(joints, request, snap, t0, outcome)
            except RequestError as e:
                outcome = self._fail(e.code, e.message, stats, t0, **e.extra)
            if snap is not None:
                outcome = self._unobserved_check(outcome, start_joints, request, t0, snap)
                outcome.scene_version = snap.version
            if outcome.success:
                self._remember_end(outcome)
            return outcome
        except RequestError as e:
            return self._fail(e.code, e.message, stats, t0, **e.extra)
        except Exception as e:  # noqa: BLE001 -- the service must answer
            return self._fail(PlanError.INTERNAL_ERROR,
                              f"internal error: {type(e).__name__}: {e} ({traceback.format_exc(limit=3)!r})", stats, t0)
        finally:
            self._plan_lock.release()

    def _via_home(self, joints: np.ndarray, request: PlanRequest, snap: SceneSnapshot, t0: float,
                  failed: PlanOutcome) -> PlanOutcome:
        """A reach whose start cannot be moved onto the planning manifold (the hand would swing
        back into the object it rests on: seen in dense_pipes after a reach onto a pipe) goes by
        the rest posture: the way home (which keeps the chest and the other arm until the arm is
        home), then the reach from there. ``failed`` is returned when either part fails."""
        home = self._plan(joints, replace(request, home=True), _empty_stats(), t0, snap)
        if not home.success:
            return failed
        rest = np.asarray(home.positions[-1], float)
        try:
            reach = self._plan(rest, replace(request, approach=None), _empty_stats(), time.perf_counter(), snap)
        except RequestError:
            return failed
        if not reach.success:
            return failed
        Q = np.vstack([home.waypoints, reach.waypoints[1:]])
        out = self._trajectory(Q)
        stats = dict(reach.stats)
        stats["path_waypoints"] = len(Q)
        stats["total_time_s"] = time.perf_counter() - t0
        return replace(reach, message=f"{reach.message}; by the rest posture first ({home.message})", waypoints=Q,
                       times=out.times_out, positions=out.positions, velocities=out.velocities,
                       accelerations=out.accelerations, waypoint_times=out.waypoint_times, trajectory=out.spline,
                       waist_start=self.robot.base_pose(Q[0]), retreat=home.retreat, stats=stats)

    def _remember_end(self, outcome: PlanOutcome) -> None:
        """The last successful plan's samples (:meth:`_reverse_of_last`) and its hand's last
        approach direction (the reverse is the first Cartesian retreat tried after it)."""
        if outcome.positions is None or len(outcome.positions) < 2:
            return
        self._last_positions = np.asarray(outcome.positions, float).copy()
        self._last_way = None if outcome.times is None or outcome.waypoints is None or outcome.waypoint_times is None \
            else (np.asarray(outcome.times, float).copy(), np.asarray(outcome.waypoints, float).copy(),
                  np.asarray(outcome.waypoint_times, float).copy())
        self._last_arm = outcome.arm
        if outcome.arm is None:
            return
        tip = self.robot.limbs[f"{outcome.arm}_arm"].tip
        end = np.asarray(outcome.positions[-1], float)
        p_end = self.robot.frame_pose(self.start_config(end), tip).translation
        for j in np.asarray(outcome.positions, float)[::-1]:
            d = p_end - self.robot.frame_pose(self.start_config(j), tip).translation
            if np.linalg.norm(d) >= 0.03:
                self._last_plan_end = (end.copy(), d / np.linalg.norm(d))
                return

    def _approach_at(self, joints: np.ndarray, request: PlanRequest) -> np.ndarray | None:
        if request.approach is not None:
            return np.asarray(request.approach, float)
        last = self._last_plan_end
        if last is not None and self._near_last_end(joints):
            return last[1]
        return None

    def _near_last_end(self, joints: np.ndarray) -> bool:
        """Whether the robot stands where the last plan ended: its arm's hand within
        ``REVERSE_HAND_TOL_M`` of the plan's end and every joint but the head's within
        ``REVERSE_JOINT_TOL_RAD`` (the executor's whole-body IK puts the hand where the plan
        did, the chest and the legs where its own tasks take them: 0.19 rad off the plan's end,
        seen in bench/session's dense_pipes); without a planned arm, every joint within 0.02 rad."""
        P = self._last_positions
        if P is None:
            return False
        head = [self.robot.joint_index[n] for n in self.robot.spec.neck_joints]   # none without a neck
        keep = np.ones(self.robot.n_joints, bool)
        keep[head] = False
        off = float(np.max(np.abs(P[-1] - joints)[keep]))
        arm = self._last_arm
        if arm is None:
            return off <= 0.02
        if off > REVERSE_JOINT_TOL_RAD:
            return False
        tip = self.robot.limbs[f"{arm}_arm"].tip
        hand = self.robot.frame_pose(self.start_config(joints), tip).translation
        end = self.robot.frame_pose(self.start_config(P[-1]), tip).translation
        return float(np.linalg.norm(hand - end)) <= REVERSE_HAND_TOL_M

    def _reverse_of_last(self, joints: np.ndarray) -> np.ndarray | None:
        """The last plan's samples backwards from its end when the robot stands there
        (:meth:`_near_last_end`), else None: the way the hand came in is a way out. The
        robot's offset from the plan's end (head excluded: a look since turned it, and the
        samples keep it where it is now) is blended out along the way back: all of it at the
        first sample (which is ``joints``), none once the hand has come back the retreat's
        ``max_distance_m``; samples clipped to the joint limits. Every sample is then checked
        like any retreat's (planning/retreat.py)."""
        if not self._near_last_end(joints):
            return None
        P = self._last_positions
        head = [self.robot.joint_index[n] for n in self.robot.spec.neck_joints]   # none without a neck
        R = P[::-1].copy()
        delta = joints - P[-1]
        delta[head] = 0.0
        w = np.ones(len(R))
        if self._last_arm is not None:
            tip = self.robot.limbs[f"{self._last_arm}_arm"].tip
            h = np.array([self.robot.frame_pose(self.start_config(j), tip).translation for j in R])
            moved = np.maximum.accumulate(np.linalg.norm(h - h[0], axis=1))
            w = np.clip(1.0 - moved / self.retreat_planner.params.max_distance_m, 0.0, 1.0)
        R += w[:, None] * delta[None, :]
        R[:, head] = joints[head]
        R = np.clip(R, self.robot.lower, self.robot.upper)
        R[0] = joints
        return R

    def _unobserved_check(self, outcome: PlanOutcome, start_joints, request: PlanRequest, t0: float,
                          snap: SceneSnapshot) -> PlanOutcome:
        """A plan that failed (no goal, no path, budget spent) while unobserved voxels were
        avoided is tried again on the occupied voxels alone (``unobserved_check_budget_s``):
        if that succeeds, unobserved space is what stands in the way: ``UNOBSERVED_SPACE``,
        naming the robot shapes and where the permissive plan crosses it (``unobserved_points``:
        where to look). When no reachable gaze sees any of those points: ``UNOBSERVABLE_SPACE``."""
        if outcome.success or outcome.error not in (PlanError.NO_GOAL_FOUND, PlanError.NO_PATH):
            return outcome
        if not (snap.avoids_unobserved and len(snap.frontier)):
            return outcome
        joints = self._validate_joints(start_joints)
        target = None if request.home or request.region is None else request.region.target_p
        full, known, _ = self._scene_collision(snap, target)
        check = replace(request, time_budget_s=self.params.unobserved_check_budget_s)
        try:
            other = self._plan(joints, check, _empty_stats(), time.perf_counter(), snap, collisions=(known, None))
        except RequestError:
            return outcome
        if not other.success:
            return outcome
        pts, where = self._unobserved_entries(np.asarray(other.positions, float), full, known, snap.frontier)
        what = "the way home" if request.home else f"a {other.arm}-arm plan"
        return self._unobserved_failure(
            joints, pts, f"{outcome.error.name} while avoiding unobserved space ({len(snap.frontier)} frontier "
                         f"voxels), but {what} exists through it: {where}", outcome.message,
            dict(outcome.stats or {}), t0)

    def _unobserved_entries(self, positions: np.ndarray, full: RobotCollision, known: RobotCollision,
                            frontier: np.ndarray) -> tuple[np.ndarray, str]:
        """Where a plan made on the occupied voxels alone enters unobserved space: the centres of
        the robot shapes that meet the frontier (and no occupied voxel) at the trajectory's samples,
        then, when none does, 4x finer between them; points closer than 0.1 m merge. A plan can cross a
        thin frontier between even those: then the frontier voxel nearest the swept shapes is named, so that
        ``UNOBSERVED_SPACE`` always carries a point to look at (CI once answered it with none, and
        the operator could not look). ``(points (K, 3), words)``."""
        names = list(self.collision_model.names)

        def entries(Q: np.ndarray) -> tuple[list[np.ndarray], str]:
            points: list[np.ndarray] = []
            where = ""
            for j in Q:
                q = self.start_config(j)
                if full.check(q):
                    continue
                occupied = set(self.colliding_shapes(q, known))
                shapes = [n for n in self.colliding_shapes(q, full) if n not in occupied and n in names]
                if not shapes:
                    continue
                P0, P1 = full.world_shapes(q)
                mid = np.mean([(P0[names.index(n)] + P1[names.index(n)]) / 2 for n in shapes], axis=0)
                if not points:
                    where = f"the {', '.join(shapes)} would enter it around {np.round(mid, 2).tolist()} m"
                if all(np.linalg.norm(mid - p) > 0.1 for p in points):
                    points.append(mid)
            return points, where

        points, where = entries(positions)
        if not points and len(positions) > 1:
            s = np.linspace(0.0, 1.0, 4, endpoint=False)[1:, None, None]   # 1/4, 1/2, 3/4 of each interval
            between = positions[:-1] + s * (positions[1:] - positions[:-1])
            points, where = entries(between.reshape(-1, positions.shape[1]))
        if not points and len(frontier):
            Q = positions[::max(1, len(positions) // 60)]
            P0, P1 = full.world_shapes_batch(np.array([self.start_config(j) for j in Q]))   # (N, S, 3)
            F = np.asarray(frontier, float)
            near = np.all((F >= np.minimum(P0, P1).min(axis=(0, 1)) - 0.3)
                          & (F <= np.maximum(P0, P1).max(axis=(0, 1)) + 0.3), axis=1)
            F = F[near] if near.any() else F
            best, at, who = math.inf, F[0], names[0]
            for a, b in zip(P0, P1):
                d = point_segment_distance(F[:, None, :], a[None], b[None])[0] - full.radii[None]   # (K, S)
                k, i = np.unravel_index(int(np.argmin(d)), d.shape)
                if d[k, i] < best:
                    best, at, who = float(d[k, i]), F[k], names[i]
            points = [at]
            where = (f"the {who} passes {max(best, 0.0) * 1e3:.0f} mm from it around "
                     f"{np.round(at, 2).tolist()} m")
        return np.array(points, float).reshape(-1, 3), where or "somewhere along it"

    def _unobserved_failure(self, joints: np.ndarray, points: np.ndarray, what: str, was: str, stats: dict,
                            t0: float) -> PlanOutcome:
        """``UNOBSERVED_SPACE`` with the points to look at, or ``UNOBSERVABLE_SPACE`` when no
        reachable gaze of the head camera sees any of them."""
        seen = None if self.observable is None or not len(points) else np.asarray(self.observable(joints, points))
        was = f" (was: {was})" if was else ""
        if seen is not None and not np.any(seen):
            return self._fail(PlanError.UNOBSERVABLE_SPACE,
                              f"{what}; no reachable gaze of the head camera (head and chest within their limits) "
                              f"sees {np.round(points, 2).tolist()} m: the robot cannot observe that space from "
                              f"where it stands. Move the target or the robot, or plan through it with "
                              f"unobserved_space:=free at your own risk{was}", stats, t0, unobserved_points=points)
        return self._fail(PlanError.UNOBSERVED_SPACE,
                          f"{what}: look there (reach_operator looks by itself unless --no-auto-look; by hand "
                          f"--look YAW PITCH) or scan (--scan); unobserved_space:=free plans through it{was}",
                          stats, t0, unobserved_points=points)

    def _fail(self, error: PlanError, message: str, stats: dict, t0: float | None = None, **kw) -> PlanOutcome:
        if t0 is not None:
            stats["total_time_s"] = time.perf_counter() - t0
        return PlanOutcome(False, error, message, kw.pop("arm", None), self.robot.joint_names, stats=stats, **kw)

    def _request_values(self, request: PlanRequest):
        p = self.params
        if not isinstance(request, PlanRequest):
            raise _failure(PlanError.INVALID_REQUEST, "request must be a PlanRequest")
        region = request.region
        if request.approach is not None and not (_finite(request.approach) and np.shape(request.approach) == (3,)):
            raise _failure(PlanError.INVALID_REQUEST, "request.approach must be a finite 3-vector or None")
        if request.home:
            region = None
        elif not isinstance(region, WorkspaceGoalRegion):
            raise _failure(PlanError.INVALID_REQUEST, "request.region must be a WorkspaceGoalRegion")
        elif not all(_finite(a) for a in (region.target_p, region.target_R, region.lower, region.upper)):
            raise _failure(PlanError.INVALID_REQUEST, "target region contains NaN/inf")
        elif np.any(np.asarray(region.lower) > np.asarray(region.upper)):
            raise _failure(PlanError.INVALID_BOUNDS, "target region has lower > upper")
        check_plan_values(request.arm, request.planner, request.goal_count, request.time_budget_s, request.seed)
        arm = "auto" if request.arm in (None, "") else request.arm
        planner = p.planner if request.planner in (None, "") else request.planner
        n_goals = p.goal_count if request.goal_count in (None, 0) else request.goal_count
        budget = p.time_budget_s if request.time_budget_s in (None, 0) else request.time_budget_s
        seed = p.seed if request.seed is None else request.seed
        return region, arm, planner, int(n_goals), float(budget), int(seed)

    def _plan(self, start_joints, request: PlanRequest, stats: dict, t0: float, snap: SceneSnapshot,
              collisions: tuple[RobotCollision, RobotCollision | None] | None = None,
              force_retreat: bool = False, min_retreat_m: float | None = None) -> PlanOutcome:
        """One plan in ``snap`` (``collisions``: the checkers to use instead of the scene's, as
        ``_unobserved_check`` does): checks, the retreat from a contact, then a reach (goal
        sampling + path) or the way home."""
        p = self.params
        region, arm_req, planner, n_goals, budget, seed = self._request_values(request)
        joints = self._validate_joints(start_joints)
        reach_cells = None
        if region is not None:
            out_of_reach = self.trunk_region.out_of_reach(region, arm_req)
            if not out_of_reach and self.reach is not None:
                out_of_reach, reach_cells, _ = self.reach.for_target(region, _arm_names(arm_req))
            if out_of_reach:
                raise _failure(PlanError.TARGET_OUT_OF_REACH,
                               f"target out of reach ({out_of_reach}): move the target closer or walk the robot nearer")
        stats["map_voxels"] = int(len(snap.occupied))
        if not snap.has_map:
            raise _failure(PlanError.NO_MAP, "no map received yet")
        if region is not None and collisions is None:
            why = snap.unobserved_target(region.target_p)
            if why and not snap.knows_unobserved:
                raise _failure(PlanError.UNOBSERVED_SPACE, why)
            if why:
                block = snap.unobserved_block_at(region.target_p)
                pts = np.asarray(region.target_p, float)[None] if block is None else block[None]
                out = self._unobserved_failure(joints, pts, why, "", stats, t0)
                raise _failure(out.error, out.message, unobserved_points=out.unobserved_points)
        if collisions is None:
            collision, known, build_s = self._scene_collision(snap, None if region is None else region.target_p)
        else:
            collision, known, build_s = collisions[0], None, 0.0
        stats["sphere_tree_build_time_s"] = build_s
        stats["map_voxels"] = int((known or collision).tree.n_spheres)   # occupied, the target's object left out
        if region is not None:
            why = self._enclosed(region, arm_req, known or collision, reach_cells)
            if why:     # proven: no goal posture exists (issue 35: at once, not after the whole budget)
                raise _failure(PlanError.NO_GOAL_FOUND, why)
        c0 = replace(collision.counters)
        q_first = self.start_config(joints)
        # a retreat leaves the contact in the map as it is: the new target's object is left out of
        # the reach's checker only (around the target), not of the start's contact
        whole = (lambda: self._scene_collision(snap, None)) if collisions is None and region is not None else None
        retreat, joints = self._start_or_retreat(joints, q_first, collision, snap, self._approach_at(joints, request),
                                                 force_retreat, min_retreat_m, whole, known)
        q_start = self.start_config(joints)
        prefix = q_first[None] if retreat is None else np.array([self.start_config(j) for j in retreat.joints])
        retreat_kw = {} if retreat is None else {"retreat": retreat.describe()}
        deadline = t0 + budget
        rng = np.random.default_rng(seed)

        def collision_stats() -> None:
            c1 = collision.counters
            stats["collision_checks"] = c1.checks - c0.checks
            stats["collision_time_s"] = (c1.check_time_s - c0.check_time_s) + (c1.fk_time_s - c0.fk_time_s)

        if region is None:
            return self._plan_home(joints, q_start, prefix, collision, rng, planner, deadline, stats, t0,
                                   collision_stats, retreat_kw)

        # ---- goal postures (Algorithm 1)
        tg = time.perf_counter()
        trunk = self.trunk_sampling(region, arm_req, q_start, reach_cells)
        # the map's samples mostly solve: small batches (a batch is projected and checked whole)
        batch = p.goal_batch_size if trunk.proposals is None else p.reach_map_batch_size
        goals = sample_goals(region, n_goals, self.robot, collision, rng, arm=arm_req, trunk=trunk,
                             time_budget_s=max(0.0, p.goal_time_fraction * budget - (tg - t0)),
                             batch_size=batch, projector=self.projector)
        if len(goals) == 0 and time.perf_counter() < deadline:
            # the goal share of the budget ran out before a first goal: keep looking for one
            more = sample_goals(region, 1, self.robot, collision, rng, arm=arm_req, trunk=trunk,
                                time_budget_s=max(0.0, deadline - time.perf_counter()),
                                batch_size=batch, projector=self.projector)
            goals = _merge_goals(goals, more)
        gs = goals.stats
        stats.update(goal_sampling_time_s=time.perf_counter() - tg, goals_requested=n_goals, goals_found=len(goals),
                     goals_right_arm=int(np.count_nonzero(goals.arm == ARM_RIGHT)),
                     goals_left_arm=int(np.count_nonzero(goals.arm == ARM_LEFT)), samples=gs.n_samples,
                     ik_failures_right_arm=gs.ik_failures["right_arm"], ik_failures_left_arm=gs.ik_failures["left_arm"],
                     ik_failures_right_leg=gs.ik_failures["right_leg"], ik_failures_left_leg=gs.ik_failures["left_leg"])
        collision_stats()
        goal_kw = dict(goals=goals.q if len(goals) else None, goal_arms=goals.arm if len(goals) else None)
        if len(goals) == 0:
            f = gs.ik_failures
            tried = "either arm (right and left tried)" if arm_req == "auto" else f"the {arm_req} arm"
            other = "" if arm_req == "auto" else \
                f", try the other arm (--arm {'left' if arm_req == 'right' else 'right'})"
            hint = (f"all {gs.n_in_collision} postures the IK found collide: the target may be enclosed "
                    "(check /voxel_map there) or the region too tight (--wgr-deg)" if gs.n_in_collision else
                    f"widen the region (--wgr-deg){other} or raise --budget")
            raise _failure(PlanError.NO_GOAL_FOUND,
                           f"no balanced, collision-free goal posture for {tried} found in "
                           f"{stats['goal_sampling_time_s']:.2f} s "
                           f"({gs.n_samples} samples over {trunk.describe()}; IK failures arm right/left "
                           f"{f['right_arm']}/{f['left_arm']}, leg right/left {f['right_leg']}/{f['left_leg']}; "
                           f"{gs.n_in_collision} in collision): the target was not proven out of reach; {hint}")

        # ---- path planning, arm by arm (order of the first goal found)
        arms_order = []
        for code in goals.arm:
            a = ARM_NAMES[int(code)]
            if a not in arms_order:
                arms_order.append(a)
        tp = time.perf_counter()
        failures = []
        nodes = 0
        for k_arm, arm in enumerate(arms_order):
            remaining = deadline - time.perf_counter()
            if k_arm + 1 < len(arms_order):
                remaining *= p.first_arm_time_fraction
            if remaining <= 0:
                failures.append((arm, PlanStatus.TIMED_OUT))
                break
            sel = np.flatnonzero(goals.arm == ARM_CODES[arm])
            goal_plan = self.projector.plan_config_of(goals.q[sel], arm)
            goal_full = goals.q[sel]
            onto = self._onto_manifold(q_start, arm, collision, failures)
            if onto is None:
                continue
            pre, start_plan = onto
            # the target's object: the approach no deeper in it than its ends (planning/approach.py)
            depth_check = self._object_depth_check(arm, collision, snap, region.target_p, q_start, start_plan,
                                                   goal_plan)
            t_arm = time.perf_counter()
            while True:
                result, path_plan, n_nodes = self.search_path(
                    arm, start_plan, goal_plan, collision, rng, planner, remaining - (time.perf_counter() - t_arm),
                    trunk, shortcut_s=lambda: min(p.shortcut_time_s, max(0.0, deadline - time.perf_counter())),
                    is_valid=depth_check)
                nodes += n_nodes
                if path_plan is None or depth_check is None or depth_check.path_ok(
                        self._dense_full(path_plan, arm), goal_full[result.goal_index], q_start):
                    break
                # deeper in the object than the goal it reached lets it (the search bounds the depth by
                # the arm's deepest goal): that goal is dropped and the others searched again
                keep = np.arange(len(goal_plan)) != result.goal_index
                goal_plan, sel, goal_full, path_plan = goal_plan[keep], sel[keep], goal_full[keep], None
                if not len(goal_plan):
                    break
            if path_plan is None:
                failures.append((arm, result.status if len(goal_plan) else
                                 "every path found went deeper into the target's object than its goal"))
                continue
            stats["path_planning_time_s"] = time.perf_counter() - tp
            stats["tree_nodes"] = nodes
            Q = self.full_configs(path_plan, arm)
            Q = np.vstack([prefix, pre[1:], Q[1:]]) if len(pre) else np.vstack([prefix, Q[1:]])
            out = self._trajectory(Q)
            stats["path_waypoints"] = len(Q)
            collision_stats()
            stats["total_time_s"] = time.perf_counter() - t0
            g_idx = int(sel[result.goal_index])
            return PlanOutcome(
                True, PlanError.SUCCESS,
                f"planned {arm}-arm reach: {len(Q)} waypoints, {out.duration:.1f} s "
                f"({len(goals)} goals, planning {1e3 * stats['total_time_s']:.0f} ms)"
                + (f"; first a {retreat.describe()}" if retreat is not None else ""),
                arm, self.robot.joint_names, out.times_out, out.positions, out.velocities, out.accelerations,
                Q, goals.q, self.robot.base_pose(q_first), stats, waypoint_times=out.waypoint_times,
                waypoints_plan=path_plan, goal_arms=goals.arm, goal_index=g_idx, trajectory=out.spline, **retreat_kw)
        stats["path_planning_time_s"] = time.perf_counter() - tp
        stats["tree_nodes"] = nodes
        collision_stats()
        why = "; ".join(f"{a} arm: {s.value if isinstance(s, PlanStatus) else s}" for a, s in failures)
        if any(str(s).startswith(("start_projection", "pre_segment")) for _, s in failures) and not any(
                isinstance(s, PlanStatus) for _, s in failures):
            raise _failure(PlanError.START_IN_COLLISION,
                           f"the start posture cannot be moved to the planning manifold (trunk above COG_approx, "
                           f"other joints at the reference) without collision or leg IK failure ({why})")
        timed_out = any(s is PlanStatus.TIMED_OUT for _, s in failures) or time.perf_counter() >= deadline
        hint = ("raise --budget or --goals" if timed_out else
                "the search ended without connecting them: try rrt_connect (--planner) or more --goals")
        stats["total_time_s"] = time.perf_counter() - t0
        return self._fail(PlanError.NO_PATH, f"{len(goals)} goal postures found but no path to any within "
                                             f"{budget:.2f} s ({why}): {hint}", stats, **goal_kw, **retreat_kw)

    def _enclosed(self, region: WorkspaceGoalRegion, arm: str, collision: RobotCollision,
                  cells: np.ndarray | None = None) -> str:
        """The collision proof at the target (planning/enclosure.py): the message when the target
        lies in a pocket of the occupied map closed all round (every posture with the hand in the
        region collides), else ''. ``cells``: the trunk cells the reach map leaves for the arms
        (None: every cell of the trunk region, as the reach map's inverse grids it)."""
        names = _arm_names(arm)
        if self._tubes is None:
            self._tubes = {a: ArmTube.of(self.robot, self.collision_model, a) for a in ARM_NAMES.values()}
        tubes = [self._tubes[a] for a in names]
        tree = collision.tree
        if any(t is None for t in tubes) or not tree.n_spheres:
            return ""
        h = enclosure_cell(tubes, float(tree.radii.min()), self.params.resolution_m)
        if h is None:
            return ""
        if self.reach is not None and cells is not None:
            r = self.reach
            trunk = (cells, r.half, r.v, r.cog_xy, r.chest_p, r.chest_R)
        else:
            if self._trunk_cells is None:
                self._trunk_cells = trunk_cells(self.trunk_region, self.params.reach_map_step_rad)
            trunk = self._trunk_cells
        lo, hi = np.asarray(region.lower[:3], float), np.asarray(region.upper[:3], float)
        pocket = enclosed(region_centre(region), float(np.linalg.norm(hi - lo) / 2), tubes, tree.centers, tree.radii,
                          h, trunk)
        if pocket is None:
            return ""
        both = " and ".join(names)
        return (f"no goal posture exists (proven, not sampled): the target lies in {pocket.describe()} that the "
                f"occupied map (without the target's object) closes all round, and the {both} arm"
                f"{'s' if len(names) > 1 else ''} ({1e3 * min(t.radius for t in tubes):.0f} mm thick from the hand "
                f"to the chest) cannot reach into it without a collision: open a way in, or check /voxel_map there")

    # ------------------------------------------------------------ start, retreat, home
    def _start_or_retreat(self, joints: np.ndarray, q_start: np.ndarray, collision: RobotCollision,
                          snap: SceneSnapshot, approach: np.ndarray | None, force: bool = False,
                          min_retreat_m: float | None = None,
                          whole: Callable[[], tuple[RobotCollision, RobotCollision | None, float]] | None = None,
                          known: RobotCollision | None = None) -> tuple[Retreat | None, np.ndarray]:
        """The start as it is, or, when a hand touches the map, the end of a retreat
        (planning/retreat.py). START_IN_COLLISION names the links and the nearest voxels when
        something else collides, or when no retreat works; a colliding start is never moved at
        random. ``whole``: the checker of the whole map (nothing left out around the reach's
        target), on which a contact found in ``collision`` is described and retreated from:
        the contact's normal, its allowed voxels and the retreat's checks do not depend on
        where the next target is (bench/session, dense_pipes: a target 26 cm from the hand left
        part of the pipe under the forearm out, every retreat failed; the way home, on the whole
        map, found one from the same posture). ``known``: the occupied-only checker when
        ``collision`` also holds the unobserved frontier: a hand touches what was measured, never
        the frontier (since issue 31 it lies a self-filter margin from the body, and a hand
        hanging beside the hip is not in contact with it); the retreat itself keeps out of both."""
        margin = snap.params.safety_margin_m
        reach = self.retreat_planner.params.contact_radius_m if force else None
        contact, hit = self.retreat_planner.classify_start(q_start, (known or collision).tree, margin, reach)
        tree, known_tree = collision.tree, (known or collision).tree
        if contact is not None and hit is None and whole is not None:
            wc, wk, _ = whole()
            contact_w, hit_w = self.retreat_planner.classify_start(q_start, (wk or wc).tree, margin, reach)
            if contact_w is not None and hit_w is None:
                contact, tree, known_tree = contact_w, wc.tree, (wk or wc).tree
        if hit is not None:
            more = f"; also {contact.describe()}" if contact is not None else ""
            raise _failure(PlanError.START_IN_COLLISION,
                           f"start posture in collision: {hit.describe()}{more}. Only a hand may rest on the map "
                           "(a retreat is planned for it); move the robot clear (e.g. reach_executor with "
                           "--no-collision-avoidance is NOT a remedy: check /voxel_map there)")
        if contact is None:
            if not collision.check(q_start):
                shapes = self.colliding_shapes(q_start, collision)
                raise _failure(PlanError.START_IN_COLLISION,
                               "start posture in collision: " + (", ".join(shapes) if shapes else "unknown shapes"))
            return None, joints
        retreat, reasons = self.retreat_planner.plan(joints, contact, tree, margin, approach,
                                                     self._reverse_of_last(joints), min_retreat_m,
                                                     self_margin_m=collision.self_margin_m)
        if retreat is None and known_tree is not tree:
            # the frontier lies 3 cm from the body since issue 31, and a straight-line retreat of the
            # arm (or the chest going home) grazes it where the way in did not: retried against the
            # measured voxels alone, accepted only when its end is clear of unobserved space too (a
            # named simplification: the 5-25 cm between are not checked against it). test_session and
            # bench/session q7: every retreat from the passage pipe failed on the frontier
            second, more = self.retreat_planner.plan(joints, contact, known_tree, margin, approach,
                                                     self._reverse_of_last(joints), min_retreat_m,
                                                     self_margin_m=collision.self_margin_m)
            if second is not None and collision.check(self.start_config(second.joints[-1])):
                retreat = second
            else:
                reasons += [f"against the measured voxels alone: {r}" for r in more[:3]] + (
                    ["against the measured voxels alone: its end is in unobserved space"] if second is not None else [])
        if retreat is None:
            raise _failure(PlanError.START_IN_COLLISION,
                           f"{contact.describe()} and no retreat of "
                           f"{1e3 * self.retreat_planner.params.min_distance_m:.0f}"
                           f"-{1e3 * self.retreat_planner.params.max_distance_m:.0f} mm frees it: "
                           + "; ".join(reasons[:6])
                           + (f"; ... {len(reasons) - 6} more lines" if len(reasons) > 6 else ""),
                           retreats_tried=tuple(reasons))
        end = retreat.joints[-1]
        if not collision.check(self.start_config(end)):
            shapes = self.colliding_shapes(self.start_config(end), collision)
            raise _failure(PlanError.START_IN_COLLISION,
                           f"{contact.describe()}; the retreat's end still collides ({', '.join(shapes)})")
        return retreat, end

    def _way_in_reversed(self, prefix: np.ndarray, rest: np.ndarray, collision: RobotCollision) -> np.ndarray | None:
        """The way home as the last plan's own way in, backwards: full configurations (K, nq) from the
        end of ``prefix`` (the start, or the end of a retreat back along that plan's samples) through
        the plan's waypoints before that point, in reverse order, to ``rest``; when the robot stands at
        that plan's end (:meth:`_reverse_of_last`), the plan began at the rest posture (every joint
        within ``WAY_IN_REST_TOL_RAD``) and every edge is clear in ``collision``, the unobserved
        frontier included (checked every quarter ``edge_resolution``, the planner's own paths' rule);
        else None. The head may have begun anywhere (a scan ends with it pitched down: the console's
        Home after a reach that followed one, ci42): the last edge turns it to the rest posture's, and
        is checked like the others. The plan's waypoints keep the soles exactly on their stance (its samples between
        them do not). Why: the body swept that way, so it is observed free, where a new search must
        find its way through a tube of swept space 3 cm wider than the body (make demo ROBOT=talos:
        after the reach the way home was UNOBSERVED_SPACE beside the shoulder, three looks could not
        see it). The executor's deviation from the plan (the chest and the legs where its own tasks
        take them) is why every edge is checked, not assumed."""
        P, way = self._last_positions, self._last_way
        if P is None or way is None:
            return None
        body = np.ones(self.robot.n_joints, bool)     # the head may differ (a scan ends looking down)
        body[[self.robot.joint_index[n] for n in self.robot.spec.neck_joints]] = False
        if float(np.max(np.abs(P[0] - rest)[body])) > WAY_IN_REST_TOL_RAD:
            return None
        times, W, wt = way
        if len(times) != len(P):
            return None
        R = self._reverse_of_last(prefix[0][N_BASE_Q:])
        if R is None:
            return None
        end = prefix[-1][N_BASE_Q:]
        k = int(np.argmin(np.max(np.abs(R - end), axis=1)))
        if float(np.max(np.abs(R[k] - end))) > 1e-6:
            return None     # a retreat that left the way in (a line, not back along the approach)
        t_k = float(times[len(times) - 1 - k])
        before = np.flatnonzero(wt < t_k - 1e-9)[::-1]
        if not len(before):
            return None
        ways = W[before].copy()
        ways[-1] = self.start_config(rest)         # the plan's first waypoint: the rest posture, exactly
        J = np.vstack([end, ways[:, N_BASE_Q:]])
        step = self.params.edge_resolution / max(self.params.arm_weight, 1e-9) / 4.0
        dense = [J[0][None]]
        for a, b in zip(J[:-1], J[1:]):
            m = max(1, int(math.ceil(float(np.max(np.abs(b - a))) / step)))
            dense.append(a + (np.arange(1, m + 1)[:, None] / m) * (b - a))
        D = np.vstack(dense)
        if not np.all((D >= self.robot.lower - 1e-9) & (D <= self.robot.upper + 1e-9)):
            return None
        if not np.all(collision.check_batch(np.array([self.start_config(j) for j in D]))):
            return None
        return np.vstack([self.start_config(end)[None], ways])

    def _home_outcome(self, pieces, q_rest, path_plan, how, stats, tp, nodes, t0, collision_stats, note,
                      retreat_kw) -> PlanOutcome:
        """SUCCESS of a way home made of ``pieces`` (each starting where the last ended), ending
        exactly at ``q_rest``. Its arm is the one that travels most: the executor tracks that
        hand (the pre-segment may move the other arm home while the planned arm stays)."""
        Q = np.vstack([pieces[0]] + [x[1:] for x in pieces[1:] if len(x)])
        Q[-1] = q_rest
        out = self._trajectory(Q)
        travel = {a: float(np.abs(np.diff(Q[:, N_BASE_Q + np.array(self.robot.limbs[f"{a}_arm"].joint_index)],
                                          axis=0)).sum()) for a in ("right", "left")}
        arm = max(travel, key=travel.get)
        stats.update(path_planning_time_s=time.perf_counter() - tp, tree_nodes=nodes, path_waypoints=len(Q))
        collision_stats()
        stats["total_time_s"] = time.perf_counter() - t0
        return PlanOutcome(
            True, PlanError.SUCCESS, f"planned the way home ({arm} arm moving most{how}): {len(Q)} waypoints, "
                                     f"{out.duration:.1f} s, planning {1e3 * stats['total_time_s']:.0f} ms{note}",
            arm, self.robot.joint_names, out.times_out, out.positions, out.velocities, out.accelerations,
            Q, None, self.robot.base_pose(Q[0]), stats, waypoint_times=out.waypoint_times,
            waypoints_plan=path_plan, trajectory=out.spline, **retreat_kw)

    def _plan_home(self, joints, q_start, prefix, collision, rng, planner, deadline, stats, t0, collision_stats,
                   retreat_kw) -> PlanOutcome:
        """The way back to the rest posture (the robot description's half-sitting): each arm
        that is away from it in turn (the farther first) plans in its q_plan space (eq. 2) to
        the rest posture's plan configuration; the pre-segment brings the other joints to the
        reference, which is the rest posture's, so the path ends there (a last checked linear
        segment covers a projection that differs from it)."""
        rest = np.clip(self.robot.half_sitting_joints, self.robot.lower, self.robot.upper)
        q_rest = self.start_config(rest)
        note = f"; first a {retreat_kw['retreat']}" if retreat_kw else ""
        if np.max(np.abs(joints - rest)) < 1e-4:
            Q = prefix if len(prefix) > 1 else np.vstack([prefix, prefix])
            out = self._trajectory(Q)
            stats["total_time_s"] = time.perf_counter() - t0
            return PlanOutcome(True, PlanError.SUCCESS, "already at the rest posture" + note, None,
                               self.robot.joint_names, out.times_out, out.positions, out.velocities,
                               out.accelerations, Q, None, self.robot.base_pose(prefix[0]), stats,
                               waypoint_times=out.waypoint_times, trajectory=out.spline, **retreat_kw)
        away = {arm: float(np.max(np.abs((joints - rest)[list(self.robot.limbs[f"{arm}_arm"].joint_index)])))
                for arm in ("right", "left")}
        failures = []
        tp = time.perf_counter()
        nodes = 0
        way_in = self._way_in_reversed(prefix, rest, collision)
        if way_in is not None:
            return self._home_outcome([prefix, way_in], q_rest, None, ", the way in reversed", stats, tp, nodes,
                                      t0, collision_stats, note, retreat_kw)
        order = sorted(away, key=lambda a: -away[a])
        for k_arm, arm in enumerate(order):
            remaining = deadline - time.perf_counter()
            if k_arm + 1 < len(order):
                remaining *= self.params.first_arm_time_fraction
            if remaining <= 0:
                failures.append((arm, PlanStatus.TIMED_OUT))
                break
            goal_plan = self.projector.plan_config_of(q_rest, arm)
            res = self.projector.project_plan_config(goal_plan, arm)
            if not res.ok[0]:
                failures.append((arm, "rest posture off the planning manifold"))
                continue
            tail = self._pre_segment(q_rest, res.q[0], collision)
            if tail is None:
                failures.append((arm, "last segment to the rest posture collides"))
                continue
            onto = self._onto_manifold(q_start, arm, collision, failures)
            if onto is None:
                continue
            pre, start_plan = onto
            result, path_plan, n_nodes = self.search_path(
                arm, start_plan, goal_plan, collision, rng, planner, remaining, None,
                shortcut_s=lambda: min(self.params.shortcut_time_s, max(0.0, deadline - time.perf_counter())))
            nodes += n_nodes
            if path_plan is None:
                failures.append((arm, result.status))
                continue
            return self._home_outcome([prefix, pre, self.full_configs(path_plan, arm), tail[::-1]], q_rest,
                                      path_plan, "", stats, tp, nodes, t0, collision_stats, note, retreat_kw)
        # the pre-segment brings the chest and the other arm to the reference first, which can swing a
        # hand near an object into it (the executor's hand task leaves the chest where it needed it:
        # seen 16 deg of chest yaw after the demo's reach): plan on the manifold of the start posture
        # instead (those joints kept), the arm and the trunk to the rest posture's, the rest last
        for arm in order if all(str(s).startswith("pre_segment") for _, s in failures) else ():
            remaining = deadline - time.perf_counter()
            if remaining <= 0:
                break
            proj = Projector(self.robot, self.projector.ik, reference_joints=joints)
            start_plan = proj.plan_config_of(q_start, arm)
            goal_plan = proj.plan_config_of(q_rest, arm)
            ends = proj.project_plan_config(np.vstack([start_plan, goal_plan]), arm)
            if not np.all(ends.ok):
                failures.append((arm, "start-posture manifold: an end does not project"))
                continue
            pre = self._pre_segment(q_start, ends.q[0], collision)
            tail = self._pre_segment(q_rest, ends.q[1], collision)
            if pre is None or tail is None:
                failures.append((arm, f"start-posture manifold: {self._pre_segment_why}"))
                continue
            checker = PlanChecker(proj, collision, arm) if proj.compiled else self.validity_fn(arm, collision, proj)
            result, path_plan, n_nodes = self.search_path(
                arm, start_plan[0], goal_plan, collision, rng, planner, remaining, None,
                shortcut_s=lambda: min(self.params.shortcut_time_s, max(0.0, deadline - time.perf_counter())),
                is_valid=checker)
            nodes += n_nodes
            if path_plan is None:
                failures.append((arm, f"start-posture manifold: {result.status.value}"))
                continue
            res = proj.project_plan_config(path_plan, arm)
            if not np.all(res.ok):
                failures.append((arm, "start-posture manifold: a waypoint does not project"))
                continue
            return self._home_outcome([prefix, pre, res.q, tail[::-1]], q_rest, path_plan,
                                      "; the chest and the other arm kept until the arm is home", stats, tp, nodes,
                                      t0, collision_stats, note, retreat_kw)
        stats.update(path_planning_time_s=time.perf_counter() - tp, tree_nodes=nodes)
        collision_stats()
        why = "; ".join(f"{a} arm: {s.value if isinstance(s, PlanStatus) else s}" for a, s in failures)
        code = PlanError.START_IN_COLLISION if failures and all(
            str(s).startswith(("start_projection", "pre_segment")) for _, s in failures) else PlanError.NO_PATH
        return self._fail(code, f"no way home within the budget ({why}): raise --budget", stats, t0, **retreat_kw)

    def _onto_manifold(self, q_start: np.ndarray, arm: str, collision: RobotCollision,
                       failures: list) -> tuple[np.ndarray, np.ndarray] | None:
        """The pre-segment from ``q_start`` onto ``arm``'s planning manifold and the start's q_plan,
        or None with the reason appended to ``failures`` (a reach and the way home both begin so)."""
        q_proj_start, start_plan = self._projected_start(q_start, arm)
        if q_proj_start is None:
            failures.append((arm, "start_projection"))
            return None
        pre = self._pre_segment(q_start, q_proj_start, collision)
        if pre is None:
            failures.append((arm, f"pre_segment ({self._pre_segment_why})"))
            return None
        return pre, start_plan

    def _projected_start(self, q_start: np.ndarray, arm: str) -> tuple[np.ndarray | None, np.ndarray]:
        """The start on ``arm``'s planning manifold and its q_plan. The manifold sets the trunk's
        horizontal position from COG_approx and the other limbs at the reference, so a start the
        executor left off it (after a Talos reach whose waist turned 20 deg, the right leg could
        not reach its foot from the trunk so placed) may not project as it is: then the trunk's
        height and orientation are blended toward the reference's (1/4, 1/2, 3/4, all of the way),
        the arm's joints kept, and the first that projects is the start (the pre-segment to it is
        checked like any other)."""
        proj = self.projector
        start_plan = proj.plan_config_of(q_start, arm)[0]
        na = proj.arm_dof[arm]
        ref = proj.plan_config_of(proj.q_ref, arm)[0]
        a = np.array([0.0, 0.25, 0.5, 0.75, 1.0])[:, None]
        C = np.repeat(start_plan[None], len(a), axis=0)
        C[:, na:] = (1.0 - a) * start_plan[na:] + a * ref[na:]
        res = proj.project_plan_config(C, arm)
        k = int(np.argmax(res.ok))
        return (res.q[k] if res.ok[k] else None), C[k]

    def _planner_options(self, planner: str, remaining_s: float):
        p = self.params
        if planner == "rrt_connect":
            from humanoid_reach_ros.planning.rrt_connect import RRTConnectOptions

            return RRTConnectOptions(step=p.rrt_step, max_time_s=remaining_s, max_iterations=100_000,
                                     max_nodes=50_000)
        from humanoid_reach_ros.planning.prm import PRMOptions

        return PRMOptions(variant=planner, num_samples=p.prm_samples, max_time_s=remaining_s)

    def _trajectory(self, Q: np.ndarray) -> "_Traj":
        """Kanehiro Sec. IV timing of the path ``Q`` (geometry/trajectory.py: monotone cubic,
        within the joint limits wherever the waypoints are), its exact peak velocity held within
        the executor's level-1 bound ``velocity_scale * URDF limit_j``. Durations rule at
        ``min(joint_velocity_rad_s, that bound)`` per joint; ``respect_velocity_limit`` then
        stretches time only when the cubic's peak (1.5 x the durations' velocity on a single
        segment, up to 3 x where PCHIP slopes meet a short segment) passes the bound: on HRP-2
        the bound is 1.0-2.0 rad/s at scale 0.5 and plant reaches peak at 0.67-0.75 rad/s, so
        they keep the paper's timing (see PlannerParams)."""
        p = self.params
        if not 0.0 < p.velocity_scale <= 1.0:
            raise ValueError(f"PlannerParams.velocity_scale must be in (0, 1], got {p.velocity_scale}")
        W = Q[:, N_BASE_Q:]
        urdf = np.asarray(self.robot.velocity_limit, dtype=float)
        given = np.isfinite(urdf) & (urdf > 0.0)    # 0 / inf: the URDF gives no limit; time by ours alone
        bound = np.where(given, p.velocity_scale * np.where(given, urdf, 1.0), np.inf)
        v_dur = np.minimum(p.joint_velocity_rad_s, bound)
        spline = SplineTrajectory.from_path(W, TrajectoryOptions(
            joint_velocity=tuple(v_dur.tolist()), respect_velocity_limit=True, velocity_limit=tuple(bound.tolist())))
        t = spline.sample_times(p.output_period_s)
        if p.include_waypoint_times:
            near = np.min(np.abs(t[:, None] - spline.times[None]), axis=1) < 1e-6
            t = np.union1d(t[~near], spline.times)   # every waypoint time exactly, no near-duplicates
        pos, vel, acc = spline.evaluate(t)
        return _Traj(spline, t - spline.times[0], pos, vel, acc, spline.times - spline.times[0])

    # ------------------------------------------------------------ misc
    def warm_up(self, budget_s: float = 60.0) -> bool:
        """Compile the numba kernels (a free-space plan, to its end) so the first request is fast;
        True when the warm-up plan succeeded. The budget is generous on purpose: compiling the
        goal sampler's kernels takes seconds, and a plan that runs out of time before its path
        search never compiles the path checker's kernels, which the first real request would
        then compile inside its own budget (seen: NO_PATH within 4 s on a loaded machine)."""
        from humanoid_reach_ros.planning.wgr import valve_region
        from humanoid_reach_ros import kinematics

        kinematics.warm_up()
        if self._tubes is None:     # the enclosure proof's arms (planning/enclosure.py), not in a request's time
            self._tubes = {a: ArmTube.of(self.robot, self.collision_model, a) for a in ARM_NAMES.values()}
        tubes = [t for t in self._tubes.values() if t is not None]
        if tubes:                   # ... and its kernels, on a closed box far from the robot
            if self._trunk_cells is None:
                self._trunk_cells = trunk_cells(self.trunk_region, self.params.reach_map_step_rad)
            h = self.params.resolution_m
            g = np.arange(-5, 6) * h
            box = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
            box = box[np.max(np.abs(box), axis=1) > 4.5 * h] + 5.0
            enclosed(np.full(3, 5.0), 0.0, tubes, box, np.full(len(box), h), h, self._trunk_cells)
        saved, last, positions, way = self.scene, self._last_plan_end, self._last_positions, self._last_way
        try:   # a scene of its own: the shared one (fed by a node) is left alone
            self.scene = PlanningScene(self.robot, saved.params, self.collision_model)
            self.set_map(np.array([[5.0, 5.0, 5.0]]))
            out = self.plan(self.robot.half_sitting_joints,
                            PlanRequest(valve_region(), goal_count=1, time_budget_s=float(budget_s)))
            return bool(out.success)
        finally:
            self.scene, self._last_plan_end, self._last_positions, self._last_way = saved, last, positions, way


@dataclass(frozen=True, eq=False)
class _Traj:
    spline: SplineTrajectory
    times_out: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray
    waypoint_times: np.ndarray

    @property
    def duration(self) -> float:
        return self.spline.duration


def _arm_names(arm: str) -> tuple[str, ...]:
    """The arms a request allows: both for ``auto`` (right first, Algorithm 1's order)."""
    return ("right", "left") if arm in (None, "", "auto") else (arm,)


def _merge_goals(a: Goals, b: Goals) -> Goals:
    s = replace(a.stats)
    s.n_goals += b.stats.n_goals
    s.n_samples += b.stats.n_samples
    s.total_time_s += b.stats.total_time_s
    s.collision_checks += b.stats.collision_checks
    s.collision_time_s += b.stats.collision_time_s
    s.n_in_collision += b.stats.n_in_collision
    s.ik_failures = {k: a.stats.ik_failures[k] + b.stats.ik_failures[k] for k in a.stats.ik_failures}
    s.arm_used = {k: a.stats.arm_used[k] + b.stats.arm_used[k] for k in a.stats.arm_used}
    s.timed_out = b.stats.timed_out
    return Goals(np.vstack([a.q, b.q]), np.concatenate([a.arm, b.arm]), np.vstack([a.p_e, b.p_e]),
                 np.vstack([a.R_e, b.R_e]), s)


__all__ = ["PlanError", "PlannerParams", "PlanRequest", "PlanOutcome", "ReachPlanner", "STAT_KEYS"]
