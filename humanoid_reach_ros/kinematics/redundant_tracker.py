"""Continuous redundancy resolution of a 7-DOF arm for the control steps of the proposed method.

The dissertation's arms have six joints: one closed-form solution per branch, and the branch
nearest the previous step keeps the motion continuous. A 7-DOF arm (Talos) has a one-parameter
self-motion. The limb protocol's solver (``kinematics/general_ik.py``, ``RedundantLimbIK``) samples
the first joint on a grid over its whole range and returns the solution nearest the reference:
right for "is there a configuration" (the controller's final-configuration check), wrong for a
motion -- when the solution at the previous first-joint value leaves the joint limits (Talos's
wrist roll, +-40 deg, saturates first) it jumps to another grid value, up to 1.4 rad in one
5 ms step (measured), an unbounded acceleration that throws the ZMP far out of the feet.

:class:`RedundantArmTracker` keeps the self-motion continuous: per step the first joint may
move at most ``step_rad`` (its velocity limit times the control period) from its previous
value; ``2 window + 1`` values in that interval are tried, the 6-DOF subchain (joints 2..7, a
chain of ``GeneralLimbIK``'s class) is solved in closed form for each (one batched call), and
among the solutions within the limits the one of least cost is kept -- refined to the minimum
of the parabola through it and its two neighbours (a second call), so that the choice moves
continuously with the pose --,

    cost = |q - q_prev|^2 + w sum_j max(0, b_j(q) - b_j(q_prev)),
    b_j(q) = max(0, m - d_j(q))^2,   d_j = min(q_j - lower_j, upper_j - q_j),

the second term charging every step that takes a joint deeper into the margin ``m`` of a
limit, so that the self-motion turns away before a joint saturates; only the increase counts,
so a posture at rest inside the margin is not pushed out of it (that push would itself be a
jump at the first step of a motion). **Simplification, named:** a local search over a few first-joint values
per step (no continuous optimisation of the self-motion, no look-ahead beyond the limit
margin); a pose whose solutions all lie outside the window is reported unreachable (the
controller's path check then refuses the pair rather than jump).

Compiled: one step (the window's first-joint values, the closed form of joints 2..7 for each,
the costs, the parabola's refinement) is one numba call, :func:`track_step`, whose inner solve
is ``kinematics/general_ik_compiled.py``'s kernel. :meth:`RedundantArmTracker.solve_reference` is
the numpy reference it is tested against (test/test_talos_dual_arm.py: the same answers to
1e-9). Why: the numpy form spent ~0.3 ms of Python overhead per arm and step, most of a Talos
step; with the kernel Talos's step is ~6x HRP-2's rather than ~10x.

No rclpy here.
"""
from __future__ import annotations


import numba as nb
import numpy as np

from humanoid_reach_ros.kinematics.general_ik import Chain6, rotations
from humanoid_reach_ros.kinematics.general_ik_compiled import (WORK6_SIZE, CompiledGeneralLimbIK, _mm, _rot,
                                                                 general_ik_pose)
from humanoid_reach_ros.kinematics.ik_types import IKReason

_JIT = dict(cache=True, nogil=False, fastmath=False)


@nb.njit(**_JIT)
def _joint1_frame_T(R0, axis, q1, out):
    """``out = (R0 R(axis, q1))^T`` (``rotations()``'s matrix: general_ik_compiled's ``_rot``)."""
    Ra = np.empty((3, 3))
    M = np.empty((3, 3))
    _rot(axis, q1, Ra)
    _mm(R0, Ra, M)
    for i in range(3):
        for j in range(3):
            out[j, i] = M[i, j]


@nb.njit(**_JIT)
def _candidate(q1, P, R, q_prev, R0, t0, axis, lo, hi, margin, weight, K6, q_out, work):
    """The arm's joints ``q_out`` (7,) for first-joint value ``q1`` and their cost (inf where
    joints 2..7 have no solution within the limits): ``_candidates`` for one value."""
    R1T = np.empty((3, 3))
    _joint1_frame_T(R0, axis, q1, R1T)
    Ps = np.empty(3)
    Rs = np.empty((3, 3))
    for i in range(3):
        Ps[i] = R1T[i, 0] * (P[0] - t0[0]) + R1T[i, 1] * (P[1] - t0[1]) + R1T[i, 2] * (P[2] - t0[2])
        for j in range(3):
            Rs[i, j] = R1T[i, 0] * R[0, j] + R1T[i, 1] * R[1, j] + R1T[i, 2] * R[2, j]
    sub = q_out[1:]
    if not general_ik_pose(Ps, Rs, q_prev[1:], K6, sub, work):
        return np.inf
    q_out[0] = q1
    cost = 0.0
    deeper = 0.0
    for j in range(7):
        d = q_out[j] - q_prev[j]
        cost += d * d
        b = max(0.0, margin - min(q_out[j] - lo[j], hi[j] - q_out[j])) ** 2
        b0 = max(0.0, margin - min(q_prev[j] - lo[j], hi[j] - q_prev[j])) ** 2
        deeper += max(0.0, b - b0)
    return cost + weight * deeper


@nb.njit(**_JIT)
def track_step(P, R, q_prev, offsets, R0, t0, axis, lo, hi, margin, weight, K6, q_out, work):
    """One control step of :class:`RedundantArmTracker` (``solve_reference``'s algorithm):
    writes ``q_out`` (7,), returns True when a value of the window has a solution."""
    m = offsets.shape[0]
    q1 = np.empty(m)
    n = 0
    for k in range(m):   # np.unique(np.clip(...)): the offsets ascend, so do their clipped values
        v = min(max(q_prev[0] + offsets[k], lo[0]), hi[0])
        if n == 0 or v != q1[n - 1]:
            q1[n] = v
            n += 1
    Q = np.empty((n, 7))
    cost = np.empty(n)
    b = -1
    for k in range(n):
        cost[k] = _candidate(q1[k], P, R, q_prev, R0, t0, axis, lo, hi, margin, weight, K6, Q[k], work)
        if cost[k] < np.inf and (b < 0 or cost[k] < cost[b]):
            b = k
    if b < 0:
        return False
    if 0 < b < n - 1 and cost[b - 1] < np.inf and cost[b + 1] < np.inf:
        c0, c1, c2 = cost[b - 1], cost[b], cost[b + 1]
        h, den = q1[b + 1] - q1[b], c0 - 2.0 * c1 + c2
        if den > 0.0:
            x = q1[b] + 0.5 * h * (c0 - c2) / den
            if _candidate(x, P, R, q_prev, R0, t0, axis, lo, hi, margin, weight, K6, q_out, work) < np.inf:
                return True
    for j in range(7):
        q_out[j] = Q[b, j]
    return True


class RedundantArmTracker:
    """Control-step IK of one 7-DOF arm (a ``GeneralLimb`` of kind ``redundant``): module doc."""

    def __init__(self, limb, step_rad: float, window: int = 3, limit_margin_rad: float = 0.2,
                 limit_weight: float = 1.0) -> None:
        c = limb.chain
        if len(c.axes) != 7:
            raise ValueError(f"{limb.limb_name}: RedundantArmTracker needs a 7-joint arm, got {len(c.axes)}")
        if not (np.isfinite(step_rad) and step_rad > 0.0) or window < 1:
            raise ValueError(f"step_rad must be > 0 and window >= 1, got {step_rad}, {window}")
        self.limb = limb
        self.chain = c
        # joints 2..7 from joint 2's placement: the subchain RedundantLimbIK solves too (compiled:
        # the same answers as GeneralLimbIK, one numba call for the window's first-joint values)
        self.sub = CompiledGeneralLimbIK(Chain6(c.R[1:], c.t[1:], c.axes[1:], c.Re, c.te, c.lower[1:], c.upper[1:]),
                                 np.asarray(limb.q_default, float)[1:])
        self.offsets = step_rad * np.linspace(-1.0, 1.0, 2 * window + 1)
        self.margin, self.weight = float(limit_margin_rad), float(limit_weight)
        # the compiled step's arguments, contiguous float64 once (a read-only or strided array
        # would compile another specialization)
        self._R0, self._t0 = np.ascontiguousarray(c.R[0], float), np.ascontiguousarray(c.t[0], float)
        self._axis = np.ascontiguousarray(c.axes[0], float)
        self._work = np.empty(WORK6_SIZE)

    def solve(self, root_p, root_R, tip_p, tip_R, q_prev) -> tuple[int, np.ndarray]:
        """``(reason, q)``: ``IKReason`` code (0 = OK) and the (7,) angles (NaN on failure); one
        call of the compiled step (:func:`track_step`)."""
        root_R = np.asarray(root_R, float)
        P = root_R.T @ (np.asarray(tip_p, float) - root_p)
        R = root_R.T @ np.asarray(tip_R, float)
        q_prev = np.ascontiguousarray(q_prev, dtype=float)
        if not (np.isfinite(P).all() and np.isfinite(R).all() and np.isfinite(q_prev).all()):
            return int(IKReason.INVALID_INPUT), np.full(7, np.nan)
        q = np.empty(7)
        c = self.chain
        if not track_step(P, np.ascontiguousarray(R), q_prev, self.offsets, self._R0, self._t0, self._axis,
                          c.lower, c.upper, self.margin, self.weight, self.sub.K, q, self._work):
            return int(IKReason.UNREACHABLE), np.full(7, np.nan)
        return int(IKReason.OK), q

    def solve_reference(self, root_p, root_R, tip_p, tip_R, q_prev) -> tuple[int, np.ndarray]:
        """The numpy reference of :meth:`solve` (the same answers, ~30x slower)."""
        c = self.chain
        root_R = np.asarray(root_R, float)
        P = root_R.T @ (np.asarray(tip_p, float) - root_p)
        R = root_R.T @ np.asarray(tip_R, float)
        q_prev = np.asarray(q_prev, float)
        if not (np.all(np.isfinite(P)) and np.all(np.isfinite(R)) and np.all(np.isfinite(q_prev))):
            return int(IKReason.INVALID_INPUT), np.full(7, np.nan)
        q1 = np.unique(np.clip(q_prev[0] + self.offsets, c.lower[0], c.upper[0]))
        q, cost = self._candidates(q1, P, R, q_prev)
        if not np.any(np.isfinite(cost)):
            return int(IKReason.UNREACHABLE), np.full(7, np.nan)
        b = int(np.argmin(cost))
        if 0 < b < len(q1) - 1 and np.isfinite(cost[b - 1]) and np.isfinite(cost[b + 1]):
            # the parabola through the best value and its neighbours: its minimum moves
            # continuously with the pose, where the best grid value would flip between
            # neighbours from one step to the next (a kink in the first joint's velocity,
            # i.e. an acceleration spike the ZMP shows)
            c0, c1, c2 = cost[b - 1], cost[b], cost[b + 1]
            h, den = q1[b + 1] - q1[b], c0 - 2.0 * c1 + c2       # an even grid: q1[b] - q1[b - 1] = h too
            if den > 0.0:
                x = q1[b] + 0.5 * h * (c0 - c2) / den
                qx, cx = self._candidates(np.array([x]), P, R, q_prev)
                if np.isfinite(cx[0]):
                    return int(IKReason.OK), qx[0]
        return int(IKReason.OK), q[b]

    def _candidates(self, q1: np.ndarray, P: np.ndarray, R: np.ndarray, q_prev: np.ndarray):
        """The arm's joints (m, 7) and their costs (m,; inf where the subchain has no
        solution within the limits) for first-joint values ``q1`` (m,)."""
        c = self.chain
        R1T = np.transpose(c.R[0] @ rotations(c.axes[0], q1), (0, 2, 1))    # joint 1's frame, rotated
        sub = self.sub.solve(R1T @ (P - c.t[0]), R1T @ R, q_prev[1:])
        q = np.column_stack([q1, sub.q])
        deeper = np.maximum(0.0, self._barrier(q) - self._barrier(q_prev[None]))
        cost = ((q - q_prev) ** 2).sum(1) + self.weight * deeper.sum(1)
        return q, np.where(sub.ok, cost, np.inf)

    def _barrier(self, q: np.ndarray) -> np.ndarray:
        """``b_j(q)`` per joint (module doc), rows of ``q``."""
        c = self.chain
        return np.maximum(0.0, self.margin - np.minimum(q - c.lower, c.upper - q)) ** 2


def warm_up() -> None:
    """Compile (or load from the numba cache) :func:`track_step` on a tiny arm."""
    from humanoid_reach_ros.kinematics import general_ik_compiled
    general_ik_compiled.warm_up()
    ax = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0],
                   [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    t = np.zeros((7, 3))
    t[1], t[3], t[4] = [0.0, 0.0, 0.1], [0.0, 0.0, -0.3], [0.0, 0.0, -0.3]
    arm = Chain6(np.broadcast_to(np.eye(3), (7, 3, 3)).copy(), t, ax, np.eye(3), np.zeros(3),
                 np.full(7, -2.5), np.full(7, 2.5))

    class _Limb:
        chain, q_default, limb_name = arm, np.full(7, 0.3), "warm-up arm"
    tracker = RedundantArmTracker(_Limb(), 0.01)
    tracker.solve(np.zeros(3), np.eye(3), np.array([0.1, 0.0, -0.5]), np.eye(3), np.full(7, 0.3))


__all__ = ["RedundantArmTracker", "track_step", "warm_up"]
