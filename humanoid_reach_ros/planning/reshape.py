"""Smooth reshaping of a colliding trajectory (Yoshida, Esteves, Sakaguchi et al., Sec. IV).

Given the initial reach trajectory (30 joints, planner spline) and the environment
sphere tree, :class:`SmoothReshaper` returns a trajectory whose colliding portions
are deformed smoothly in the task space:

1. the trajectory is sampled at the control period ``dt`` (5 ms, "the trajectory's
   resolution") and turned into the motion as it will be executed -- both feet fixed
   and the exact COG held, by the prioritized IK below (our counterpart of the paper's
   dynamic pattern generator output); every sample is checked against the sphere tree
   and samples closer than ``clearance_m`` form the colliding portions ``[u_1, u_2]``;
2. for each portion a collision-free configuration is found at the most penetrating
   sample ``u*`` by *random sampling of the task space + IK*: hand offsets ``Delta``
   (position in a ball growing with the attempt, small rotation) and a random posture
   offset of the arm and chest, solved with the prioritized IK below, kept when its
   distance is at least ``clearance_m + sample_margin_m`` (self-collision free);
3. the anticipation and regaining windows ``ns_before``, ``ns_after`` follow from
   ``v_ref`` (0.3 m/s, 30 deg/s): ``T = 1.5 max(|Delta_p| / v_lin, |Delta_r| / v_ang)``
   (1.5: the peak slope of the cubic blend), ``ns = ceil(T / dt)``;
4. the hand pose in ``[u_1 - ns_before, u_2 + ns_after]`` is the original one displaced
   by ``w(t) Delta``, ``w`` the clamped cubic spline through the key frames
   ``(u_1 - ns_before, 0), (u_1, 1), (u_2, 1), (u_2 + ns_after, 0)`` -- i.e. the cubic
   interpolation of the paper's key frames ``P(u_1 - ns_before), P(u_1), P(u_2),
   P(u_2 + ns_after)`` written as a displacement of the original motion (motion
   warping), C1 at both junctions; resampled at ``dt``;
5. null-space prioritized IK along the resampled window, one or two steps per sample
   (eq. 2: ``dq = J_1^# dr_1 + (I - J_1^# J_1) y``, generalised to the levels joint
   limits > both feet 6D + exact COG xy > hand 6D > posture), the posture reference
   displaced by ``w(t) delta_q`` (``delta_q``: joints of the sampled configuration minus
   those at ``u*``); the windows also cover that configuration change:
   ``T >= 1.5 |delta_q|_inf / v_ref_joint``;
6. the reshaped samples are checked again; remaining collisions start another round
   (displacements of several rounds superpose), at most ``max_rounds``.

The start and the goal are imposed: a colliding run that contains the first or the
last sample is *pinned* (not displaced; the goal hand pose is the task), and a portion
without room for its anticipation / regaining window before an end is left as it is;
both are reported by :class:`ReshapeResult` (``pinned``, ``success``). Reshaping is an
offline step (seconds, not 5 ms): call it before :meth:`WholeBodyExecutor.start`,
outside the control loop.

Simplifications (named as required): collisions are those with the environment map
(self-collision is only checked on the sampled configuration); one displacement per
portion (the paper's object key frames are the hand pose here); the lower body is
not re-planned by a pattern generator (feet fixed, the executor keeps the exact COG).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin
from scipy.interpolate import CubicSpline

from humanoid_reach_ros.control.hqp import SaturatedNullSpaceHQP
from humanoid_reach_ros.control.tasks import DofSelection
from humanoid_reach_ros.geometry.distance import RobotCollision
from humanoid_reach_ros.geometry.sphere_tree import SphereTree
from humanoid_reach_ros.geometry.trajectory import SplineTrajectory
from humanoid_reach_ros.robot.model import N_BASE_Q, N_BASE_V, RobotModel
from humanoid_reach_ros.robot.shapes import CollisionModel

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


@dataclass(frozen=True)
class ReshapeParams:
    period_s: float = 0.005             # resampling period dt (the control period)
    clearance_m: float = 0.01           # samples closer than this to the environment collide
    sample_margin_m: float = 0.01       # the sampled configuration keeps clearance + this
    v_ref_mps: float = 0.3              # v_ref, hand translation
    v_ref_radps: float = math.radians(30.0)   # v_ref, hand rotation
    v_ref_joint_radps: float = 0.5      # v_ref of the posture offset (largest joint change)
    max_offset_m: float = 0.20          # largest sampled hand offset
    max_rotation_rad: float = 0.3       # largest sampled hand rotation offset
    posture_sigma_rad: float = 0.15     # std of the sampled arm/chest posture offset (at the last attempt)
    samples: int = 200                  # task-space samples per portion
    ik_iterations: int = 60             # IK iterations for a sampled configuration
    track_iterations: int = 2           # IK steps per resampled point
    max_rounds: int = 4
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("period_s", "v_ref_mps", "v_ref_radps", "v_ref_joint_radps", "max_offset_m"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"ReshapeParams.{name}={v!r} must be > 0")
        if self.clearance_m < 0 or self.sample_margin_m < 0:
            raise ValueError("ReshapeParams: clearance_m and sample_margin_m must be >= 0")
        if min(self.samples, self.ik_iterations, self.track_iterations, self.max_rounds) < 1:
            raise ValueError("ReshapeParams: samples, ik_iterations, track_iterations, max_rounds must be >= 1")


@dataclass(frozen=True)
class Portion:
    """One reshaped portion: colliding samples ``[u1, u2]``, window ``[a, b]`` (sample indices)."""

    u1: int
    u2: int
    a: int
    b: int
    offset_m: float          # |Delta_p| of the sampled configuration
    rotation_rad: float      # |Delta_r|
    attempts: int            # task-space samples tried


@dataclass
class ReshapeResult:
    trajectory: SplineTrajectory        # reshaped (or the original when nothing collides)
    times: np.ndarray                   # (N,) sample times
    joints: np.ndarray                  # (N, 30) reshaped samples
    distance_before: np.ndarray         # (N,) robot-environment distance of the original motion (feet + COG held)
    distance_after: np.ndarray          # (N,) of the reshaped samples
    distance_reference: np.ndarray      # (N,) of the planner's samples as they are (waist from base_on_feet)
    portions: list[Portion] = field(default_factory=list)
    success: bool = True                # no sample below clearance_m after reshaping (pinned ones aside)
    time_s: float = 0.0

    @property
    def reshaped(self) -> bool:
        return bool(self.portions)


class SmoothReshaper:
    """Smooth task-space reshaping of a reach trajectory (see the module docstring)."""

    def __init__(self, robot: RobotModel, collision: CollisionModel, params: ReshapeParams = ReshapeParams()) -> None:
        self.robot = robot
        self.cm = collision
        self.params = params
        self.model = robot.model
        self.data = self.model.createData()
        self.sel = DofSelection.without_grippers(robot)
        grip = {robot.joint_index[j] for j in robot.spec.gripper_joints}
        self._jsel = np.array([j for j in range(robot.n_joints) if j not in grip], dtype=np.intp)
        self._jcols = np.searchsorted(self.sel.index, N_BASE_V + self._jsel)
        self._sole_ids = tuple(robot.frame_id(f) for f in robot.sole_frames)
        self._soles = robot.stance_soles
        self._solver = SaturatedNullSpaceHQP()
        self.com_xy = np.zeros(2)
        # the arms' and the chest's joints, in model order (from the description, not by name)
        upper = {*robot.limbs["right_arm"].joints, *robot.limbs["left_arm"].joints, *robot.spec.chest_joints}
        self._perturb = np.array([robot.joint_index[n] for n in robot.joint_names
                                  if n in upper and robot.joint_index[n] not in grip], dtype=np.intp)

    # ------------------------------------------------------------ helpers
    def _full(self, joints: np.ndarray) -> np.ndarray:
        return self.robot.config(joints, self.robot.base_on_feet(joints))

    def distances(self, collision: RobotCollision, Q: np.ndarray) -> np.ndarray:
        """Robot-environment distance (N,) of configurations Q (N, nq)."""
        P0, P1 = collision.world_shapes_batch(Q)
        tree = collision.tree
        return np.array([float(np.min(tree.min_distance_batch(P0[c], P1[c], collision.radii)))
                         for c in range(len(Q))])

    def hand_pose(self, q: np.ndarray, arm: str) -> pin.SE3:
        pin.framesForwardKinematics(self.model, self.data, q)
        return self.data.oMf[self.robot.frame_id(self.robot.hand_frames[arm])].copy()

    def ik_step(self, q: np.ndarray, hand: pin.SE3, arm: str, posture: np.ndarray, gain: float = 1.0) -> np.ndarray:
        """One prioritized IK step: joint limits > both soles at the stance + exact COG xy at
        ``self.com_xy`` > hand 6D > posture."""
        model, data = self.model, self.data
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        sel = self.sel.index
        js = self._jsel
        qj = q[N_BASE_Q + js]
        k = len(js)
        G = np.zeros((2 * k, len(sel)))
        G[np.arange(k), self._jcols] = 1.0
        G[k + np.arange(k), self._jcols] = -1.0
        h = np.concatenate([self.robot.upper[js] - 1e-9 - qj, qj - self.robot.lower[js] - 1e-9])
        rows = []
        for fid, target, g in ((self._sole_ids[0], self._soles[0], 1.0), (self._sole_ids[1], self._soles[1], 1.0),
                               (self.robot.frame_id(self.robot.hand_frames[arm]), hand, gain)):
            J = pin.getFrameJacobian(model, data, fid, LWA)
            M = data.oMf[fid]
            Rt = target.rotation
            Jr = Rt @ pin.Jlog3(Rt.T @ M.rotation) @ M.rotation.T @ J[3:]
            e = np.concatenate([M.translation - target.translation, Rt @ pin.log3(Rt.T @ M.rotation)])
            rows.append((np.vstack([J[:3], Jr])[:, sel], -g * e))
        Jc = pin.jacobianCenterOfMass(model, data, True)
        feet = (np.vstack([rows[0][0], rows[1][0], Jc[:2, sel]]),
                np.concatenate([rows[0][1], rows[1][1], -(data.com[0][:2] - self.com_xy)]))
        A4 = np.zeros((k, len(sel)))
        A4[np.arange(k), self._jcols] = 1.0
        b4 = -(qj - posture[js])
        res = self._solver.solve(G, h, [feet, rows[2], (A4, b4)])
        return pin.integrate(model, q, self.sel.expand(res.x))

    def _sample_config(self, collision: RobotCollision, q_star: np.ndarray, arm: str, rng: np.random.Generator):
        """Task-space sampling + IK around ``q_star``: (q, Delta_p, Delta_r, delta_q, attempts) or None;
        ``delta_q`` is the joint change from ``q_star`` to the sampled configuration."""
        p = self.params
        H0 = self.hand_pose(q_star, arm)
        need = p.clearance_m + p.sample_margin_m
        for attempt in range(1, p.samples + 1):
            f = attempt / p.samples
            u = rng.normal(size=3)
            dp = u / np.linalg.norm(u) * p.max_offset_m * f * rng.uniform() ** (1.0 / 3.0)
            w = rng.normal(size=3)
            dr = w / np.linalg.norm(w) * p.max_rotation_rad * f * rng.uniform()
            dq = np.zeros(self.robot.n_joints)
            dq[self._perturb] = rng.normal(scale=p.posture_sigma_rad * f, size=len(self._perturb))
            target = pin.SE3(pin.exp3(dr) @ H0.rotation, H0.translation + dp)
            posture = np.clip(q_star[N_BASE_Q:] + dq, self.robot.lower, self.robot.upper)
            q = q_star.copy()
            for _ in range(p.ik_iterations):
                q_next = self.ik_step(q, target, arm, posture)
                step = float(np.max(np.abs(q_next - q)))
                q = q_next
                if step < 1e-7:
                    break
            H = self.hand_pose(q, arm)
            if np.linalg.norm(H.translation - target.translation) > 1e-3:
                continue
            if self.distances(collision, q[None])[0] < need:
                continue
            if self.cm.in_self_collision_at(self.data):
                continue
            return q, dp, dr, q[N_BASE_Q:] - q_star[N_BASE_Q:], attempt
        return None

    # ------------------------------------------------------------ main
    def reshape(self, reference: SplineTrajectory, tree: SphereTree, arm: str) -> ReshapeResult:
        """Reshape ``reference`` (30 joints, times from 0) against ``tree`` for the ``arm`` hand."""
        if arm not in self.robot.hand_frames:
            raise ValueError(f"unknown arm {arm!r}: expected 'right' or 'left'")
        if not isinstance(tree, SphereTree):
            raise ValueError("reshape needs a SphereTree environment")
        if reference.n_joints != self.robot.n_joints:
            raise ValueError(f"reference has {reference.n_joints} joints, expected {self.robot.n_joints}")
        t0 = time.perf_counter()
        p = self.params
        rng = np.random.default_rng(p.seed)
        collision = RobotCollision(self.robot, self.cm, tree)
        times = reference.sample_times(p.period_s)
        J0 = reference.position(times)
        Q0 = np.array([self._full(j) for j in J0])
        d_ref = self.distances(collision, Q0)
        N = len(times)
        hands0 = [self.hand_pose(q, arm) for q in Q0]
        pin.centerOfMass(self.model, self.data, Q0[0], False)
        self.com_xy = self.data.com[0][:2].copy()
        off_p = np.zeros((N, 3))
        off_r = np.zeros((N, 3))
        off_q = np.zeros((N, self.robot.n_joints))
        # the motion as executed (feet and exact COG held): what collides is checked on it
        Q = self._track(Q0, hands0, off_p, off_r, off_q, arm, 0)
        d0 = self.distances(collision, Q)
        d = d0.copy()
        portions: list[Portion] = []
        pinned = _pinned_ends(d0 < p.clearance_m)
        for _ in range(p.max_rounds):
            bad = (d < p.clearance_m) & ~pinned
            if not np.any(bad):
                break
            first = N
            for u1, u2 in _runs(bad):
                u_star = u1 + int(np.argmin(d[u1: u2 + 1]))
                found = self._sample_config(collision, Q[u_star], arm, rng)
                if found is None:
                    continue
                _, dp, dr, dq, attempts = found
                T = 1.5 * max(np.linalg.norm(dp) / p.v_ref_mps, np.linalg.norm(dr) / p.v_ref_radps,
                              float(np.max(np.abs(dq))) / p.v_ref_joint_radps)
                ns = max(int(math.ceil(T / p.period_s)), 2)
                a, b = max(u1 - ns, 1), min(u2 + ns, N - 2)
                if a >= u1 or b <= u2:
                    continue       # no room to anticipate / regain before the ends (start and goal are kept)
                w = _bump(times, a, u1, u2, b)
                off_p += w[:, None] * dp
                off_r += w[:, None] * dr
                off_q += w[:, None] * dq
                first = min(first, a)
                portions.append(Portion(int(u1), int(u2), int(a), int(b), float(np.linalg.norm(dp)),
                                        float(np.linalg.norm(dr)), attempts))
            if first == N:
                break
            Q = self._track(Q0, hands0, off_p, off_r, off_q, arm, first, Q)
            d = self.distances(collision, Q)
        joints = Q[:, N_BASE_Q:]
        traj = SplineTrajectory(joints, times)
        return ReshapeResult(traj, times, joints, d0, d, d_ref, portions,
                             bool(np.all((d >= p.clearance_m - 1e-9) | pinned)), time.perf_counter() - t0)

    def _track(self, Q0, hands0, off_p, off_r, off_q, arm, first: int, Q_prev=None) -> np.ndarray:
        """Prioritized IK along the (displaced) hand and posture references from sample
        ``first`` on (the samples before it are kept from ``Q_prev``)."""
        Q = Q0.copy() if Q_prev is None else Q_prev.copy()
        q = Q0[0].copy() if first == 0 else Q[first - 1].copy()
        for i in range(first, len(Q0)):
            H = hands0[i]
            target = pin.SE3(pin.exp3(off_r[i]) @ H.rotation, H.translation + off_p[i])
            posture = np.clip(Q0[i, N_BASE_Q:] + off_q[i], self.robot.lower, self.robot.upper)
            for _ in range(self.params.track_iterations):
                q = self.ik_step(q, target, arm, posture)
            Q[i] = q
        return Q


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Inclusive index ranges of the True runs of ``mask``."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    edges = np.flatnonzero(np.diff(m.astype(np.int8)))
    return [(int(s), int(e) - 1) for s, e in zip(edges[::2], edges[1::2])]


def _pinned_ends(bad: np.ndarray) -> np.ndarray:
    """The runs of ``bad`` that contain the first or the last sample: the start and the goal
    are imposed (the goal hand pose is the task), so they are never displaced."""
    pinned = np.zeros(len(bad), dtype=bool)
    for u1, u2 in _runs(bad):
        if u1 == 0 or u2 == len(bad) - 1:
            pinned[u1: u2 + 1] = True
    return pinned


def _bump(times: np.ndarray, a: int, u1: int, u2: int, b: int) -> np.ndarray:
    """Weight ``w(t)``: clamped cubic spline through (t_a, 0), (t_u1, 1), (t_u2, 1), (t_b, 0), 0 outside."""
    keys_t = [times[a], times[u1], times[u2], times[b]]
    keys_w = [0.0, 1.0, 1.0, 0.0]
    kt, kw = [keys_t[0]], [keys_w[0]]
    for t, w in zip(keys_t[1:], keys_w[1:]):
        if t > kt[-1] + 1e-12:
            kt.append(t)
            kw.append(w)
    w = np.zeros(len(times))
    if len(kt) < 2:
        w[a: b + 1] = 1.0
        return w
    spline = CubicSpline(kt, kw, bc_type="clamped")
    w[a: b + 1] = np.clip(spline(times[a: b + 1]), 0.0, None)
    return w


__all__ = ["ReshapeParams", "Portion", "ReshapeResult", "SmoothReshaper"]
