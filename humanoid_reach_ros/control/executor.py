"""Whole-body reach executor: the 5 ms prioritized IK loop of Kanehiro et al., Sec. IV-V.

Every control step of ``dt = period_s`` the reference trajectory (30 joints, from the
planner) is evaluated at ``t``; the unknown is the configuration displacement ``dq``
of the floating-base model (tangent space, 6 base + 30 joints, the two gripper joints
excluded: ``n = 34`` unknowns, :class:`~humanoid_reach_ros.control.tasks.DofSelection`).
The priority levels are those of the paper:

1. joint position limits over one step, joint velocity limits (``velocity_scale`` of
   the URDF limits) and Faverjon-Tournassoud velocity dampers
   ``delta_d >= -xi max(d - d_s, 0)`` (never a forced push-out: always feasible) between every
   environment sphere within the distance
   bound ``d_i`` of a robot shape (sphere-tree query ``spheres_within_batch``) and
   between the self-collision pairs closer than ``d_i`` (inequalities
   ``G dq <= h``, :mod:`humanoid_reach_ros.control.limits`);
2. both soles 6D fixed at their pose at :meth:`WholeBodyExecutor.start` and the
   horizontal position of the *exact* COG (``J_com``, all link masses) held at its
   value at ``start``; when that value is off the nominal COG (half-sitting's,
   relative to the right sole; e.g. after a motion without compensation) the target
   ramps back to the nominal point (quintic, ``com_recenter_speed_mps`` on average);
3. the hand 6D pose of the reference: forward kinematics of the reference joints at
   ``t`` with the waist of :meth:`RobotModel.base_on_feet`, expressed relative to the
   right sole so it stays consistent with the real stance;
4. the posture: the reference joints (residual redundancy).

The solver is :class:`humanoid_reach_ros.control.hqp.SaturatedNullSpaceHQP` (closed-form
null-space projections with saturation of violated level-1 rows, OSQP lexicographic QP
as the fallback); its docstring names the simplifications of Kanoun's lexicographic QP.
With ``solver="osqp"`` every step runs the full OSQP cascade
(:class:`~humanoid_reach_ros.control.hqp.HierarchicalQP`), the reference implementation.

Speed (bench/execution.py): one ``computeJointJacobians`` + ``updateFramePlacements``
per step; the capsules from the numba forward kinematics of :class:`RobotCollision`;
only environment spheres within ``d_i`` make damper rows, their closest points and
normals in numba and their rows ``n^T J_v + (p x n)^T J_w`` straight from the WORLD
joint Jacobians in one numba kernel (no per-link Jacobian calls, no temporaries); the
constant joint-limit and posture rows built once; the closed-form solver needs no QP in the
common case. The executor limits BLAS to ``blas_threads`` (default 1, process-wide):
on these small matrices BLAS threads only add synchronisation (a 34x34 product took
0.29 ms with threads on a loaded machine, 8 us without). Smooth reshaping of the
reference (``planning/reshape.py``, seconds) is the caller's, outside the control loop
(``execution/requests.py``): control never imports planning.

Continuity: ``start`` begins from the given (last commanded) configuration; when the
reference's first point differs from it, the joint reference is blended in with a
quintic smoothstep over ``blend_s`` seconds (at least ``blend_min_s``, long enough for
the largest difference at half the velocity limit), and the hand reference follows
from the blended joints. :meth:`WholeBodyExecutor.hold` keeps the last commanded
configuration as a constant reference; every step is bounded by the level-1 velocity
rows, so a command never jumps.
"""
from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass, replace

import numpy as np
import pinocchio as pin
from threadpoolctl import threadpool_limits

from humanoid_reach_ros.control.active_set import ActiveSetCascade
from humanoid_reach_ros.control.hqp import HierarchicalQP, Level, SaturatedNullSpaceHQP
from humanoid_reach_ros.control.limits import (braking_speed, damper_bound, damper_braking_bound, env_pair_geometry,
                                               joint_step_bounds, joint_step_box, pair_point_rows,
                                               self_pair_geometry, support_masks, world_point_rows)
from humanoid_reach_ros.control.tasks import ComTask, DofSelection, FrameTask, PostureTask
from humanoid_reach_ros.geometry.distance import RobotCollision
from humanoid_reach_ros.geometry.sphere_tree import SphereTree
from humanoid_reach_ros.geometry.trajectory import SplineTrajectory
from humanoid_reach_ros.robot.model import N_BASE_Q, N_BASE_V, RobotModel
from humanoid_reach_ros.robot.shapes import CollisionModel

SOLVERS = ("nullspace", "osqp")


@dataclass(frozen=True)
class ExecutorParams:
    """Parameters of :class:`WholeBodyExecutor` (units in the names)."""

    period_s: float = 0.005                 # control step dt
    distance_bound_m: float = 0.10          # d_i: spheres / self pairs closer than this enter level 1
    security_distance_m: float = 0.01       # d_s of the velocity damper
    damper_xi: float = 0.5                  # xi of the damper (per-step fraction, see control/limits.py)
    collision_avoidance: bool = True        # level-1 velocity dampers on/off (Fig. 8 "without")
    self_collision: bool = True             # self-collision pairs among the dampers
    com_compensation: bool = True           # level-2 exact COG xy task on/off (Fig. 7 "without")
    hand_gain: float = 1.0
    com_gain: float = 1.0
    feet_gain: float = 1.0
    posture_gain: float = 0.2
    velocity_scale: float = 1.0             # fraction of URDF joint velocity limits allowed
    blend_min_s: float = 0.2                # shortest blend of a reference that starts elsewhere
    converge_position_m: float = 1e-3       # done: hand position error below this after the end
    converge_rotation_rad: float = 1e-2     # ... and orientation error below this
    settle_timeout_s: float = 2.0           # done anyway this long after the end of the reference
    limit_margin_rad: float = 1e-9          # joint rows keep q this far inside the URDF range
    solver: str = "nullspace"               # "nullspace" (closed form + saturation) or "osqp" (reference)
    max_saturation_iter: int = 30           # active-set iterations of the closed-form solver
    active_set: bool = True                 # exact dual active-set cascade (DAQP, control/active_set.py) for
    active_set_min_rows: int = 24           # steps with at least this many damper rows (False: saturation
                                            # and its OSQP fallback always)
    feasibility_tol: float = 1e-9           # level-1 rows count as satisfied within this
    osqp_eps: float = 1e-6
    osqp_max_iter: int = 400
    blas_threads: int = 1                   # process-wide BLAS thread limit set by the executor (0: leave)
    com_recenter_speed_mps: float = 0.05    # mean speed of the COG target back to its nominal point
    max_catch_up_periods: float = 4.0       # a late step may cover at most this many periods (step(t))
    com_recenter_min_m: float = 0.005       # a start this close to the nominal COG holds it where it is
    max_joint_acceleration_rad_s2: float = 0.0    # bound of every commanded joint acceleration (0: none;
                                                  # the node's default is 10.0, config/reach_executor.yaml)
    damper_deceleration_mps2: float = 1.5   # a damper pair's approach speed brakes at most at this [m/s^2]

    def validate(self) -> "ExecutorParams":
        checks = [
            ("period_s", self.period_s > 0), ("distance_bound_m", self.distance_bound_m > 0),
            ("security_distance_m", 0 <= self.security_distance_m < self.distance_bound_m),
            ("damper_xi", 0 < self.damper_xi <= 1), ("hand_gain", 0 < self.hand_gain <= 1),
            ("com_gain", 0 < self.com_gain <= 1), ("feet_gain", 0 < self.feet_gain <= 1),
            ("posture_gain", 0 < self.posture_gain <= 1), ("velocity_scale", 0 < self.velocity_scale <= 1),
            ("blend_min_s", self.blend_min_s >= 0), ("settle_timeout_s", self.settle_timeout_s >= 0),
            ("max_saturation_iter", self.max_saturation_iter >= 1),
            ("active_set_min_rows", self.active_set_min_rows >= 0),
            ("com_recenter_speed_mps", self.com_recenter_speed_mps > 0),
            ("max_catch_up_periods", self.max_catch_up_periods >= 1), ("blas_threads", self.blas_threads >= 0),
            ("osqp_max_iter", self.osqp_max_iter >= 1),
            ("max_joint_acceleration_rad_s2", self.max_joint_acceleration_rad_s2 >= 0),
            ("damper_deceleration_mps2", self.damper_deceleration_mps2 > 0),
        ]
        for name, ok in checks:
            v = getattr(self, name)
            if not (ok and (isinstance(v, bool) or np.isfinite(v))):
                raise ValueError(f"ExecutorParams.{name}={v!r} is out of range")
        if self.solver not in SOLVERS:
            raise ValueError(f"ExecutorParams.solver={self.solver!r}: expected one of {SOLVERS}")
        return self


@dataclass(frozen=True)
class StepMetrics:
    """Per-step figures (msg/ExecutorMetrics, Figs. 7-10)."""

    t: float                    # reference time [s]
    progress: float             # t / duration in [0, 1]
    solve_time_s: float         # whole step wall time
    distance_time_s: float      # sphere-tree query part
    ik_time_s: float            # prioritized QP part
    spheres_in_bound: int       # environment spheres within distance_bound_m (Fig. 9)
    active_constraints: int     # inequality rows active at the solution
    active_levels: int          # number of priority levels solved
    com_error_m: float          # horizontal distance of the EXACT COG from its target (value at start(),
                                # or the recentering ramp after a start away from the nominal COG)
    min_distance_m: float       # robot-environment minimum distance (inf without a map)
    hand_error_m: float         # position error of the hand vs the reference at t
    hand_error_rad: float
    level_slack: tuple[float, ...]
    self_distance_m: float = math.inf   # smallest self-collision pair distance
    damper_rows: int = 0                # velocity-damper rows in level 1 (environment + self)
    fallback: bool = False              # the closed-form solver fell back to OSQP
    accel_relaxed: int = 0              # joints whose acceleration bound gave way to their position/velocity
                                        # limits (1..k); < 0: level 1 was infeasible with the dampers' braking
                                        # curves: -10 solved with the plain dampers, -40 with them and the
                                        # bound x4, -1000 without the bound


@dataclass(frozen=True)
class StepResult:
    q: np.ndarray               # full pinocchio configuration (7 base + 30 joints) after the step
    joints: np.ndarray          # the 30 joint positions to command (model.joint_names order)
    metrics: StepMetrics
    done: bool                  # reference finished and the hand has converged (or hold mode)


def _smoothstep5(s: float) -> float:
    s = min(max(s, 0.0), 1.0)
    return s * s * s * (10.0 + s * (-15.0 + 6.0 * s))


_SMOOTHSTEP5_PEAK_ACC = 10.0 / math.sqrt(3.0)   # max |s5''(u)| on [0, 1]
_HOLD_DECELERATION = 0.8                         # a hold brakes at this fraction of the acceleration bound
_ACCEL_INFEASIBLE = 1e-6                         # level-1 violation above which a step widens the bound
_ACCEL_LEVEL2 = 1e-8                             # ... and level-2 (feet, COG) residual [m, rad a step]
_ACCEL_TIERS = (1.0, 4.0, 0.0)                   # then, one solve each, the plain dampers with the bound
                                                 # times these (0: no bound)
_DAMPER_JOINT_SHARE = 0.5                        # a damper pair brakes with at most this share of the joints' bound


def _pick(cands):
    """The step among the tiers' candidates (first = the bound and the braking curves): level 1
    met first, then the feet and COG; among steps that meet level 1 and hold level 2 as well as
    the best one (within 1e-8 or a factor 2), the first tier's: a joint limit or a damper that
    keeps the feet/COG off their target for every tier is no reason to drop the bound."""
    ok = [c for c in cands if c[1][0] <= _ACCEL_INFEASIBLE]
    if not ok:
        return min(cands, key=lambda c: c[1][0])
    best = min(c[1][1] if len(c[1]) > 1 else 0.0 for c in ok)
    return next(c for c in ok if (c[1][1] if len(c[1]) > 1 else 0.0) <= max(2.0 * best, best + _ACCEL_LEVEL2))


class _BrakingReference:
    """The reference of :meth:`WholeBodyExecutor.hold` under an acceleration bound: each joint
    from ``q0`` at its commanded velocity ``v0`` decelerating at ``a`` to rest. A constant
    reference would ask the bounded acceleration to stop at once: the joints would overshoot
    it and swing back."""

    def __init__(self, q0: np.ndarray, v0: np.ndarray, a: float) -> None:
        self.q0, self.v0, self.a = q0.copy(), v0.copy(), float(a)
        self.t_stop = np.abs(self.v0) / self.a
        self.duration = 0.0                     # a hold: done at once, as with a constant reference
        self.waypoints = self.position(float(self.t_stop.max(initial=0.0)))[None]
        self.times = np.zeros(1)

    def position(self, t: float) -> np.ndarray:
        tt = np.minimum(t, self.t_stop)
        return self.q0 + self.v0 * tt - 0.5 * np.sign(self.v0) * self.a * tt * tt


class WholeBodyExecutor:
    """Stateful 5 ms whole-body executor (see the module docstring for the levels)."""

    def __init__(self, robot: RobotModel, collision: CollisionModel, params: ExecutorParams = ExecutorParams()) -> None:
        self.robot = robot
        self.cm = collision
        self.model = robot.model
        self.data = self.model.createData()
        self._ref_data = self.model.createData()
        self.sel = DofSelection.without_grippers(robot)
        self.params = params.validate()
        self._tree: SphereTree | None = None
        self._q: np.ndarray | None = None
        self._ref: SplineTrajectory | None = None
        self._arm = "right"
        self._t = 0.0
        self._dt = params.period_s              # elapsed time covered by the current step
        self._active = False
        self._holding = False
        self._end_t = 0.0
        self._v = np.zeros(self.sel.n)          # velocity of the last step (selected unknowns, per second)
        self._h_xi = np.zeros(0)                # this step's damper rows without the braking curve
        self._ref_now: tuple | None = None      # (joints, hand pose) of the reference at self._t
        self._history: deque = deque(maxlen=16)  # (q, v) of the last steps: a start from one keeps its velocity
        self._blend_offset = np.zeros(robot.n_joints)
        self._blend_s = 0.0
        self._sole_targets: tuple[pin.SE3, pin.SE3] | None = None
        self._com_target = np.zeros(2)
        self._com_offset = np.zeros(2)          # COG target = _com_target + (1 - s5(t / _com_blend_s)) _com_offset
        self._com_blend_s = 0.0
        self._stance_r_inv = robot.stance_soles[0].inverse()
        # nominal COG: that of half-sitting, in the right-sole frame (where a balanced stance has it)
        self._com_nominal_in_sole = self._stance_r_inv.act(robot.com(robot.half_sitting()))
        self._sole_ids = tuple(robot.frame_id(f) for f in robot.sole_frames)
        self._hand_ids = {a: robot.frame_id(f) for a, f in robot.hand_frames.items()}
        # joint rows: the selected joints (grippers excluded)
        grip = {robot.joint_index[j] for j in robot.spec.gripper_joints}
        self._joint_sel = np.array([j for j in range(robot.n_joints) if j not in grip], dtype=np.intp)
        self._joint_cols = np.searchsorted(self.sel.index, N_BASE_V + self._joint_sel)
        self._joint_groups = np.full(2 * len(self._joint_sel), -1, dtype=np.int64)
        # constant rows, built once: joint-limit rows (+I; -I) and the posture task (I)
        k, nx = len(self._joint_sel), self.sel.n
        self._G_joint = np.zeros((2 * k, nx))
        self._G_joint[np.arange(k), self._joint_cols] = 1.0
        self._G_joint[k + np.arange(k), self._joint_cols] = -1.0
        self._A_posture = np.ascontiguousarray(self._G_joint[:k])
        self._posture_joints = tuple(int(j) for j in self._joint_sel)
        self._pi = np.ascontiguousarray(collision.pair_index[:, 0], dtype=np.int64)
        self._pj = np.ascontiguousarray(collision.pair_index[:, 1], dtype=np.int64)
        self._radii = np.ascontiguousarray(collision.radii, dtype=float)
        self._shape_masks = support_masks(self.model, collision.frame_ids)[collision.shape_link]
        self._fk = RobotCollision(robot, collision, SphereTree.build(np.zeros((0, 3)), 0.0))
        if self.params.blas_threads > 0:
            # small dense algebra: BLAS threads only cost synchronisation (process-wide)
            threadpool_limits(self.params.blas_threads, user_api="blas")
        self._make_solvers()

    def _make_solvers(self) -> None:
        p = self.params
        self._ns = SaturatedNullSpaceHQP(max_iter=p.max_saturation_iter, tol=p.feasibility_tol,
                                         active_set_min_rows=p.active_set_min_rows)
        self._osqp = HierarchicalQP(eps=p.osqp_eps, max_iter=p.osqp_max_iter, polish=False)
        self._active_set = ActiveSetCascade() if p.active_set else None

    # ------------------------------------------------------------ state
    @property
    def active(self) -> bool:
        """True while a reference is executed or held."""
        return self._active

    @property
    def holding(self) -> bool:
        return self._holding

    @property
    def t(self) -> float:
        return self._t

    @property
    def duration(self) -> float:
        return 0.0 if self._ref is None else self._ref.duration

    @property
    def q(self) -> np.ndarray:
        if self._q is None:
            raise ValueError("executor has no configuration yet: call start() or hold(q)")
        return self._q.copy()

    @property
    def arm(self) -> str:
        return self._arm

    def set_environment(self, tree: SphereTree | None) -> None:
        """New environment map (``None``: no environment, dampers on self pairs only)."""
        if tree is not None and not isinstance(tree, SphereTree):
            raise ValueError(f"set_environment expects a SphereTree or None, got {type(tree).__name__}")
        self._tree = tree if tree is not None and tree.n_spheres else None

    # ------------------------------------------------------------ validation
    def _check_q(self, q, what: str = "q") -> np.ndarray:
        q = np.array(q, dtype=float).reshape(-1) if q is not None else None
        if q is None or q.shape != (self.model.nq,):
            raise ValueError(f"{what} must be a full configuration of {self.model.nq} values "
                             f"(7 base + {self.robot.n_joints} joints), got shape {None if q is None else q.shape}")
        if not np.all(np.isfinite(q)):
            raise ValueError(f"{what} contains NaN or inf")
        nrm = np.linalg.norm(q[3:7])
        if abs(nrm - 1.0) > 1e-3:
            raise ValueError(f"{what}: base quaternion is not unit (norm {nrm:.4f})")
        q[3:7] /= nrm
        return q

    def _check_reference(self, reference) -> SplineTrajectory:
        if not isinstance(reference, SplineTrajectory):
            raise ValueError(f"reference must be a SplineTrajectory, got {type(reference).__name__}")
        if reference.n_joints != self.robot.n_joints:
            raise ValueError(f"reference has {reference.n_joints} joints, expected {self.robot.n_joints}")
        if not (np.all(np.isfinite(reference.waypoints)) and np.all(np.isfinite(reference.times))):
            raise ValueError("reference contains NaN or inf")
        if abs(reference.times[0]) > 1e-9:
            raise ValueError(f"reference times must start at 0, got {reference.times[0]}")
        return reference

    # ------------------------------------------------------------ commands
    def start(self, q: np.ndarray, reference: SplineTrajectory, arm: str,
              params: ExecutorParams | None = None) -> None:
        """Execute ``reference`` from configuration ``q`` with the ``arm`` hand ('right'|'left').

        Fixes both sole poses and the exact COG xy at their values in ``q``.
        """
        if arm not in self._hand_ids:
            raise ValueError(f"unknown arm {arm!r}: expected 'right' or 'left'")
        q = self._check_q(q)
        reference = self._check_reference(reference)
        if params is not None:
            p_new = params.validate()
            if (p_new.max_saturation_iter, p_new.feasibility_tol, p_new.osqp_eps, p_new.osqp_max_iter) != (
                    self.params.max_saturation_iter, self.params.feasibility_tol, self.params.osqp_eps,
                    self.params.osqp_max_iter):
                self.params = p_new
                self._make_solvers()
            self.params = p_new
        self._fix_stance(q)
        self._recenter_com(q)
        self._v = self._velocity_at(q)
        self._q = q
        self._ref = reference
        self._arm = arm
        self._t = 0.0
        self._end_t = reference.duration
        self._holding = False
        self._active = True
        self._ref_now = None
        self._set_blend(reference.position(0.0))

    def hold(self, q: np.ndarray | None = None) -> None:
        """Stop: track the current hand pose and posture with feet and COG fixed.

        ``q`` (optional) is used only when the executor has no configuration yet (it
        becomes the state); otherwise the last commanded configuration is held, so a
        hold never jumps.
        """
        if q is not None:
            q = self._check_q(q)
        if self._q is None:
            if q is None:
                raise ValueError("hold() needs q before the first start()")
            self._q = q
            self._v = np.zeros(self.sel.n)
        if self._sole_targets is None or q is not None and not self._active:
            self._fix_stance(self._q)
        # a hold freezes the COG target where it is (mid-recentering included)
        self._com_target = self._com_ref(self._t)
        self._com_offset = np.zeros(2)
        self._com_blend_s = 0.0
        joints = self._q[N_BASE_Q:].copy()
        a = self.params.max_joint_acceleration_rad_s2
        vj = np.zeros(self.robot.n_joints)
        vj[self._joint_sel] = self._v[self._joint_cols]
        if a > 0 and np.any(vj != 0.0):
            self._ref = _BrakingReference(joints, vj, _HOLD_DECELERATION * a)
        else:
            self._ref = SplineTrajectory(joints[None], np.zeros(1))
        self._t = 0.0
        self._end_t = 0.0
        self._ref_now = None
        self._holding = True
        self._active = True
        self._blend_offset[:] = 0.0
        self._blend_s = 0.0

    def _fix_stance(self, q: np.ndarray) -> None:
        pin.framesForwardKinematics(self.model, self.data, q)
        self._sole_targets = tuple(self.data.oMf[i].copy() for i in self._sole_ids)
        self._com_target = pin.centerOfMass(self.model, self.data, q)[:2].copy()
        self._com_offset = np.zeros(2)
        self._com_blend_s = 0.0

    def _recenter_com(self, q: np.ndarray) -> None:
        """With COG compensation, move the level-2 COG target from the COG of ``q`` to the
        nominal one (half-sitting's, relative to the real right sole) along a quintic
        ramp at ``com_recenter_speed_mps`` on average.

        Root cause of issue #4: a motion WITHOUT compensation leaves the COG off its
        nominal point (66 mm after a cancel at 27 %); holding the COG *there* for the whole
        next motion forces the legs and waist far from the reference posture (level 4
        cannot be met), pushes the body into the obstacles and makes the damper rows
        conflict with the level-2 task. The paper holds the COG at its (balanced)
        initial value: the nominal point plays that role after such a start."""
        if not self.params.com_compensation:
            return
        nominal = self._sole_targets[0].act(self._com_nominal_in_sole)[:2]
        offset = self._com_target - nominal
        dist = float(np.linalg.norm(offset))
        if dist <= self.params.com_recenter_min_m:   # e.g. the head turned: the paper holds the initial COG
            return
        self._com_target = nominal
        self._com_offset = offset
        self._com_blend_s = max(self.params.blend_min_s, dist / self.params.com_recenter_speed_mps)

    def _com_ref(self, t: float) -> np.ndarray:
        """Level-2 COG xy target at ``t``."""
        if self._com_blend_s > 0.0 and t < self._com_blend_s:
            return self._com_target + (1.0 - _smoothstep5(t / self._com_blend_s)) * self._com_offset
        return self._com_target

    def _velocity_at(self, q: np.ndarray) -> np.ndarray:
        """The commanded velocity at ``q`` when ``q`` is one of the last steps (a start from the
        last *sent* command, which may be a few steps behind the computed ones), else zero."""
        for qh, vh in reversed(self._history):
            if np.max(np.abs(qh - q)) <= 1e-12:
                return vh.copy()
        return np.zeros(self.sel.n)

    def _set_blend(self, ref0: np.ndarray) -> None:
        diff = self._q[N_BASE_Q:] - ref0
        v = self.robot.velocity_limit * self.params.velocity_scale
        need = float(np.max(np.abs(diff) / (0.5 * v))) if len(v) else 0.0
        a = self.params.max_joint_acceleration_rad_s2
        if a > 0 and len(diff):   # the blend's own acceleration within half the bound
            need = max(need, 0.5 * math.sqrt(_SMOOTHSTEP5_PEAK_ACC * float(np.max(np.abs(diff))) / (0.5 * a)))
        self._blend_offset = diff
        self._blend_s = max(self.params.blend_min_s, 2.0 * need) if np.any(np.abs(diff) > 1e-9) else 0.0

    # ------------------------------------------------------------ references
    def reference_joints(self, t: float) -> np.ndarray:
        """Reference joints at ``t`` including the start blend."""
        qr = self._ref.position(t)
        if self._blend_s > 0.0 and t < self._blend_s:
            qr = qr + (1.0 - _smoothstep5(t / self._blend_s)) * self._blend_offset
        return qr

    def reference_hand(self, joints_ref: np.ndarray) -> pin.SE3:
        """Hand pose of the reference joints on the feet, relative to the real right sole."""
        d = self._ref_data
        q0 = self.robot.config(joints_ref)
        pin.framesForwardKinematics(self.model, d, q0)
        sole = d.oMf[self._sole_ids[0]]
        hand_in_sole = sole.actInv(d.oMf[self._hand_ids[self._arm]])
        # base_on_feet: the right sole at its stance pose; the real right sole replaces it
        return self._sole_targets[0].act(hand_in_sole)

    # ------------------------------------------------------------ step
    def step(self, t: float | None = None) -> StepResult:
        """One step: reference at ``t`` -> distances -> prioritized solve -> integrate.

        ``t``: the reference time of this step (seconds since :meth:`start`); default the
        previous step's plus ``period_s``. A control loop that missed deadlines passes the
        time of the deadline the step will be sent at, so the motion follows the clock and
        is never stretched: the step covers the elapsed ``dt = t - t_prev`` (clamped to
        ``[period_s, max_catch_up_periods * period_s]``) and its joint velocity rows allow
        ``v dt``, so it catches up within the velocity limits; feet, COG, dampers and joint
        position limits stay rows of the step as always. In hold mode ``t`` is ignored.
        """
        if not self._active or self._q is None:
            raise ValueError("executor is not active: call start() or hold(q) first")
        p = self.params
        t0 = time.perf_counter()
        model, data, q = self.model, self.data, self._q
        dt = p.period_s
        if t is not None and not self._holding:
            dt = min(max(float(t) - self._t, p.period_s), p.max_catch_up_periods * p.period_s)
        self._dt = dt
        t_next = self._t + dt
        # ---- kinematics (one pass: joint Jacobians + frames)
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        # ---- distances (level 1 dampers)
        td = time.perf_counter()
        G_d, h_d, groups_d, n_env, dmin_env, dmin_self = self._damper_rows()
        distance_time = time.perf_counter() - td
        # ---- tasks
        ti = time.perf_counter()
        jr = self.reference_joints(t_next)
        hand_target = self.reference_hand(jr)
        com_target = self._com_ref(t_next)
        accel = p.max_joint_acceleration_rad_s2 > 0
        if accel and self._ref_now is None:
            jr0 = self.reference_joints(self._t)
            self._ref_now = (jr0, self.reference_hand(jr0))
        levels, x_pred, n_relaxed = self._levels(q, jr, hand_target, G_d, h_d, com_target, accel)
        x, slacks, n_act, fallback = self._solve(levels, groups_d)
        if accel:
            h_xi = self._h_xi
            cands = [(x + x_pred, slacks, n_act, fallback, n_relaxed)]
            for widen in _ACCEL_TIERS:
                if slacks[0] <= _ACCEL_INFEASIBLE and (len(slacks) < 2 or slacks[1] <= _ACCEL_LEVEL2):
                    break
                # the acceleration bound and the dampers' braking curves admit no step together, or
                # none that holds the feet and the exact COG (a pair that entered the influence
                # distance too fast, an obstacle that appeared close, a pair whose approach speed
                # grows with the posture faster than the bound can brake it): the bound with the
                # plain Faverjon-Tournassoud dampers (d never crosses d_s); the bound x4; then no
                # bound, the step the smallest change of the last velocity that keeps level 1 and
                # the feet and COG (hand and posture wait a step)
                levels, x_pred, n_relaxed = self._levels(q, jr, hand_target, G_d, h_xi, com_target, True, widen)
                if widen == 0.0:
                    levels = levels[:2]
                x, slacks, n_act, fallback = self._solve(levels, groups_d)
                cands.append((x + x_pred, slacks, n_act, fallback, -int(10 * widen) if widen > 0 else -1000))
            x, slacks, n_act, fallback, n_relaxed = _pick(cands)
        self._v = x / dt
        dq = self.sel.expand(x)
        q_new = pin.integrate(model, q, dq)
        ik_time = time.perf_counter() - ti
        # ---- metrics at the new configuration (position errors only: cheap FK)
        self._q = q_new
        self._t = t_next
        self._history.append((q_new, self._v))
        self._ref_now = (jr, hand_target)
        pin.framesForwardKinematics(model, data, q_new)
        H = data.oMf[self._hand_ids[self._arm]]
        e_pos = float(np.linalg.norm(H.translation - hand_target.translation))
        e_rot = float(np.linalg.norm(pin.log3(hand_target.rotation.T @ H.rotation)))
        com = pin.centerOfMass(model, data, pin.KinematicLevel.POSITION, False)   # placements just computed
        com_err = float(np.linalg.norm(com[:2] - self._com_ref(t_next)))
        dur = self.duration
        progress = 1.0 if dur <= 0 else min(t_next / dur, 1.0)
        # with the acceleration bound a motion ends at rest (every joint slow enough to stop within a step:
        # the hold that follows repeats the last command)
        moving = accel and float(np.max(np.abs(self._v[self._joint_cols]), initial=0.0)) > \
            p.max_joint_acceleration_rad_s2 * p.period_s
        done = self._holding or (t_next >= self._end_t and (
            (e_pos <= p.converge_position_m and e_rot <= p.converge_rotation_rad and not moving)
            or t_next >= self._end_t + p.settle_timeout_s))
        solve_time = time.perf_counter() - t0
        m = StepMetrics(t_next, progress, solve_time, distance_time, ik_time, n_env, n_act, len(levels),
                        com_err, dmin_env, e_pos, e_rot, tuple(float(s) for s in slacks), dmin_self,
                        len(h_d), fallback, n_relaxed)
        return StepResult(q_new.copy(), q_new[N_BASE_Q:].copy(), m, bool(done))

    def _braking_feedback(self, q, jr, hand_target, b3, b4):
        """Hand and posture rows with the acceleration bound: the reference's own motion over the
        step (feed-forward) plus a correction of the error at the step's start whose speed is
        one the bounded motion can still brake to zero at the target (:func:`braking_speed`;
        the hand at ``damper_deceleration_mps2`` and half the bound in rad/s^2, the joints at half
        the bound). A per-step gain of 1 on the whole error asks a bounded acceleration to stop
        at once: the hand overshoots and swings about its target at the velocity limits."""
        p = self.params
        dt, a = self._dt, p.max_joint_acceleration_rad_s2
        jr0, hand0 = self._ref_now
        fid = self._hand_ids[self._arm]
        e_next = FrameTask(fid, hand_target).error(self.data)
        e_now = FrameTask(fid, hand0).error(self.data)
        fb = -p.hand_gain * e_now
        for part, acc in ((slice(0, 3), p.damper_deceleration_mps2), (slice(3, 6), 0.5 * a)):
            n = float(np.linalg.norm(fb[part]))
            if n > 0.0:
                fb[part] *= min(1.0, dt * float(braking_speed(n, acc, dt)) / n)
        b3 = (e_now - e_next) + fb
        e4 = PostureTask(jr0, joints=self._posture_joints).error(q, self.robot.n_joints)
        fb4 = -p.posture_gain * e4
        cap = dt * braking_speed(np.abs(e4), 0.5 * a, dt)
        b4 = (jr - jr0)[self._joint_sel] + np.clip(fb4, -cap, cap)
        return b3, b4

    def _solve(self, levels, groups_d):
        """The prioritized solve of ``levels``: ``(x, slacks, n_active, fallback)``."""
        p = self.params
        G, h = levels[0][2], levels[0][3]
        eq = [(A, b) for A, b, _, _ in levels[1:]]
        if p.solver == "osqp":
            res = self._osqp.solve([Level(None, None, G, h)] + [Level(A, b) for A, b in eq], n=self.sel.n)
            x, slacks, n_act, fallback = res.x, res.slacks, res.n_active_inequalities, False
        else:
            r = self._ns.solve(G, h, eq, fallback=self._osqp, groups=np.concatenate([self._joint_groups, groups_d]),
                               active_set=self._active_set)
            x, slacks, n_act, fallback = r.x, r.slacks, r.n_active, r.fallback
        return x, slacks, n_act, fallback

    # ------------------------------------------------------------ rows
    def _levels(self, q, jr, hand_target, G_d, h_d, com_target, accel: bool = False, widen: float = 1.0):
        """([(None, None, G, h) level 1, (A, b, ...) levels 2-4] on the selected unknowns,
        x_pred, relaxed joints).

        The rows are those of :mod:`~humanoid_reach_ros.control.tasks` (``FrameTask``,
        ``ComTask``, ``PostureTask``) and :mod:`~humanoid_reach_ros.control.limits`
        (``joint_step_bounds``, the damper rows), the implementations their tests check;
        only the constant joint-row matrices are built once here.

        With ``accel`` (the acceleration bound) the joint rows are :func:`joint_step_box`'s
        and the unknown is the step's *difference* from ``x_pred``, the last step's velocity
        continued (each joint's clipped into its box, the base's as it was): the solvers need
        ``x = 0`` inside level 1 (their task scaling, DAQP's start), and a moving joint's
        acceleration box need not contain ``dq = 0``. The caller adds ``x_pred`` back."""
        p = self.params
        model, data, sel = self.model, self.data, self.sel.index
        # level 1: joint limits + velocity limits (selected joints) and dampers
        js = self._joint_sel
        qj = q[N_BASE_Q + js]
        lower, upper = self.robot.lower[js] + p.limit_margin_rad, self.robot.upper[js] - p.limit_margin_rad
        vmax = self.robot.velocity_limit[js] * p.velocity_scale
        x_pred, n_relaxed = None, 0
        if accel:
            cols = self._joint_cols
            if widen > 0:
                up, lo, relaxed = joint_step_box(qj, lower, upper, vmax, self._v[cols],
                                                 widen * p.max_joint_acceleration_rad_s2, self._dt)
                n_relaxed = int(np.count_nonzero(relaxed))
            else:   # the bound dropped: position and velocity limits only
                up, lo = joint_step_bounds(qj, lower, upper, vmax * self._dt)
            x_pred = self._v * self._dt
            pj = np.minimum(np.maximum(x_pred[cols], -lo), up)
            x_pred[cols] = pj
            up, lo = up - pj, lo + pj
        else:
            up, lo = joint_step_bounds(qj, lower, upper, vmax * self._dt)
        k = len(js)
        G = np.empty((2 * k + len(h_d), len(sel)))
        G[:2 * k] = self._G_joint
        if len(h_d):
            np.take(G_d, sel, axis=1, out=G[2 * k:])
        if x_pred is not None and len(h_d):
            h_d = h_d - G[2 * k:] @ x_pred
        h = np.concatenate([up, lo, h_d])
        # level 2: soles 6D + COG xy
        rows = [FrameTask(fid, target, p.feet_gain).rows(model, data)
                for fid, target in zip(self._sole_ids, self._sole_targets)]
        if p.com_compensation:
            rows.append(ComTask(com_target, p.com_gain).rows(model, data))   # joint Jacobians of this step
        A2 = np.vstack([r.A for r in rows])[:, sel]
        b2 = np.concatenate([r.b for r in rows])
        # level 3: hand 6D
        hand = FrameTask(self._hand_ids[self._arm], hand_target, p.hand_gain).rows(model, data)
        A3, b3 = hand.A[:, sel], hand.b
        # level 4: posture on the selected joints
        b4 = -p.posture_gain * PostureTask(jr, joints=self._posture_joints).error(q, self.robot.n_joints)
        if accel and self._ref_now is not None:
            b3, b4 = self._braking_feedback(q, jr, hand_target, b3, b4)
        if x_pred is not None:
            b2, b3, b4 = b2 - A2 @ x_pred, b3 - A3 @ x_pred, b4 - x_pred[self._joint_cols]
        return ([(None, None, G, h), (A2, b2, None, None), (A3, b3, None, None), (self._A_posture, b4, None, None)],
                x_pred, n_relaxed)

    def _damper_rows(self):
        """Velocity-damper rows ``n^T J_p dq <= xi (d - d_s)`` (all nv columns; with the acceleration
        bound :func:`~humanoid_reach_ros.control.limits.damper_braking_bound`), the number of
        environment spheres in the bound, and the environment / self minimum distances.

        Capsules from the numba forward kinematics of :class:`RobotCollision`, the
        environment pairs from ``SphereTree.spheres_within_batch`` (only spheres within
        ``d_i`` make rows), closest points and normals in numba, the rows from the WORLD
        joint Jacobians already computed for the step (:func:`world_point_rows`)."""
        p = self.params
        P0, P1 = self._fk.world_shapes(self._q)
        R = self._radii
        J = self.data.J
        rows_G, rows_h, rows_g = [], [], []
        n_env = 0
        dmin_env = math.inf
        tree = self._tree
        if tree is not None:
            s_idx, k_idx, dist = tree.spheres_within_batch(P0, P1, R, p.distance_bound_m)
            if len(s_idx):
                n_env = len(np.unique(k_idx))
                dmin_env = float(dist.min())
                if p.collision_avoidance:
                    pts, nrm = env_pair_geometry(P0, P1, s_idx, tree.centers[k_idx])
                    rows_G.append(world_point_rows(J, self._shape_masks, pts, nrm, s_idx))
                    rows_h.append(dist)
                    rows_g.append(np.asarray(s_idx, dtype=np.int64))
            else:
                dmin_env = float(tree.min_distance_batch(P0, P1, R).min())
        dmin_self = math.inf
        if len(self._pi):
            k, pa, pb, nrm, d, dmin_self = self_pair_geometry(P0, P1, R, self._pi, self._pj, p.distance_bound_m)
            if p.collision_avoidance and p.self_collision and len(k):
                rows_G.append(pair_point_rows(J, self._shape_masks, self._pi[k], pa, self._pj[k], pb, nrm))
                rows_h.append(d)
                rows_g.append(self.cm.n_shapes + k)
        if rows_G:
            G = rows_G[0] if len(rows_G) == 1 else np.vstack(rows_G)
            d = rows_h[0] if len(rows_h) == 1 else np.concatenate(rows_h)
            g = rows_g[0] if len(rows_g) == 1 else np.concatenate(rows_g)
            if p.max_joint_acceleration_rad_s2 > 0:
                # approach speeds at the last step's velocity; each pair brakes at damper_deceleration_mps2,
                # or at what half the joints' acceleration bound gives it (|n^T J_joints|_1 a / 2: a pair
                # moved by short levers, e.g. the two thighs, cannot be braked harder by the bounded joints)
                Gs = G[:, self.sel.index]
                a_row = np.minimum(p.damper_deceleration_mps2,
                                   _DAMPER_JOINT_SHARE * p.max_joint_acceleration_rad_s2
                                   * np.abs(Gs[:, N_BASE_V:]).sum(axis=1))
                h = damper_braking_bound(d, p.security_distance_m, p.damper_xi, Gs @ self._v, a_row, self._dt)
                self._h_xi = damper_bound(d, p.security_distance_m, p.damper_xi)
            else:
                h = damper_bound(d, p.security_distance_m, p.damper_xi)
            return G, h, g, n_env, dmin_env, float(dmin_self)
        self._h_xi = np.zeros(0)
        return np.zeros((0, self.model.nv)), np.zeros(0), np.zeros(0, np.int64), n_env, dmin_env, float(dmin_self)

    def warm_up(self) -> None:
        """Compile / load the numba kernels and touch every code path once (a few steps on
        a throw-away state); call before the control loop starts. The state is reset."""
        from humanoid_reach_ros.control.limits import warm_up as limits_warm_up
        from humanoid_reach_ros.geometry.sphere_tree import warm_up as tree_warm_up
        limits_warm_up()
        tree_warm_up()   # every tree kernel: a step far from the map calls some the steps below do not
        saved = (self._tree, self._q, self._ref, self._arm, self._t, self._active, self._holding, self._end_t,
                 self._blend_offset, self._blend_s, self._sole_targets, self._com_target, self._com_offset,
                 self._com_blend_s, self._v, self._dt, list(self._history))
        try:
            q = self.robot.half_sitting()
            hand = self.robot.frame_pose(q, self.robot.hand_frames["right"]).translation
            self._tree = SphereTree.build((hand + [0.05, 0.0, 0.0])[None], 0.01)
            self.start(q, SplineTrajectory(q[N_BASE_Q:][None], np.zeros(1)), "right")
            for _ in range(3):
                self.step()
        finally:
            (self._tree, self._q, self._ref, self._arm, self._t, self._active, self._holding, self._end_t,
             self._blend_offset, self._blend_s, self._sole_targets, self._com_target, self._com_offset,
                 self._com_blend_s, self._v, self._dt, history) = saved
            self._history.clear()
            self._history.extend(history)

    def with_params(self, **changes) -> ExecutorParams:
        """A copy of the current parameters with ``changes`` (for ``start(..., params=)``)."""
        return replace(self.params, **changes)


__all__ = ["ExecutorParams", "StepMetrics", "StepResult", "WholeBodyExecutor"]
