"""Continuous redundancy resolution of a 7-DOF arm for the control steps of the proposed method.

The dissertation's arms have six joints: one closed-form solution per branch, and the branch
nearest the previous step keeps the motion continuous. A 7-DOF arm (Talos) has a one-parameter
self-motion. The limb protocol's solver (``robot/general_ik.py``, ``RedundantLimbIK``) samples
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

No rclpy here.
"""
from __future__ import annotations

import numpy as np

from humanoid_reach_ros.robot.general_ik import Chain6, rotations
from humanoid_reach_ros.robot.general_ik_compiled import CompiledGeneralLimbIK
from humanoid_reach_ros.robot.ik_types import IKReason


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

    def solve(self, root_p, root_R, tip_p, tip_R, q_prev) -> tuple[int, np.ndarray]:
        """``(reason, q)``: ``IKReason`` code (0 = OK) and the (7,) angles (NaN on failure)."""
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


__all__ = ["RedundantArmTracker"]
