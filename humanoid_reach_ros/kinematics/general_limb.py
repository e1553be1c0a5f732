"""A limb solved by the general closed form (``kinematics/general_ik.py``) behind the limb protocol
of ``kinematics/hand_derived.py`` (``solve`` / ``fk`` / ``maybe_reachable`` on world poses and the reach
geometry the planner's bounds use): the limbs neither of ``LimbIK``'s hand-derived patterns
covers -- Talos's 7-joint arms, any 6R chain of the solvable class. Its solver is the compiled
twin (``kinematics/general_ik_compiled.py``) unless asked for the numpy reference.

Any other 6R or 7R revolute chain (issue 23: the Unitree G1's arms and legs, offsets between
all their axes) gets the numerical solver of ``kinematics/numerical_ik.py`` (kind ``"numerical"``;
a named simplification: a local method with restarts, which can miss a solution a closed
form would find) and a reach geometry that is a plain upper bound (:class:`GeneralLimb`).

No ROS here.
"""
from __future__ import annotations

import math

import numpy as np

from humanoid_reach_ros.kinematics.general_ik import (Chain6, GeneralLimbIK, RedundantLimbIK, _centre_distance_range,
                                                 rotations)
from humanoid_reach_ros.kinematics.general_ik_compiled import CompiledGeneralLimbIK, CompiledRedundantLimbIK
from humanoid_reach_ros.kinematics.numerical_ik import NumericalLimbIK
from humanoid_reach_ros.kinematics.ik_types import IKReason, IKResult


class GeneralLimb:
    """:class:`GeneralLimbIK` (6 joints) or :class:`RedundantLimbIK` (7 joints) behind the
    interface of ``limb_ik.LimbIK`` (one protocol for every limb): ``solve`` / ``fk`` /
    ``maybe_reachable`` on world root and tip poses, and the reach geometry the planner's
    bounds use -- ``t0`` (the root-end axes' centre in the root link), ``te`` / ``Re`` (the
    tip in the frame whose origin is the tip-end centre), ``l1 + l2`` the longest and
    ``|l1 - l2|`` the shortest centre distance. For a 7-joint chain ``t0`` is joint 1's
    origin and the distances are bounds (the 6-DOF subchain's centre distances widened by
    the distance ``|t2|`` of the subchain's root-end centre from joint 1's origin, which
    joint 1 swings about): still conservative for ``maybe_reachable``, no longer tight; the
    planner's out-of-reach bound uses the tight form, :meth:`reach_centres`.

    A chain neither closed form accepts (kind ``"numerical"``, :class:`NumericalLimbIK`, the
    same solver with or without ``compiled_solver``): ``t0`` is joint 1's origin, the tip-end
    centre the last joint's origin (``te`` / ``Re`` the tip in the last joint's frame),
    ``l1 + l2`` the sum of the lengths of the translations between consecutive joint
    origins -- an upper bound of the distance between the two centres (the triangle
    inequality along the chain, whatever the angles) -- and ``|l1 - l2|`` = 0."""

    #: the planner's fused projection kernel is LimbIK's (hand-derived legs); not this limb's
    compiled = False

    def __init__(self, robot, limb_name: str, compiled_solver: bool = True) -> None:
        spec = robot.limbs[limb_name]
        self.limb_name, self.joint_names = limb_name, tuple(spec.joints)
        self.chain = Chain6.from_model(robot, spec.root, spec.joints, spec.tip)
        q_hs = np.asarray(robot.half_sitting_joints)[list(spec.joint_index)]
        self.lower, self.upper = self.chain.lower, self.chain.upper
        self.q_default = np.clip(q_hs, self.lower, self.upper)
        c = self.chain
        self.n_joints = len(c.axes)
        try:
            self._closed_form(compiled_solver)
        except ValueError:      # neither closed form accepts the chain: the numerical solver
            self.kind = "numerical"
            self.ik = NumericalLimbIK(c, self.q_default)
            d_max = float(np.sum(np.linalg.norm(c.t[1:], axis=1)))
            self.l1 = self.l2 = d_max / 2
            self.centre_reach = d_max
        # the root-end centre is joint 1's origin and the tip-end centre joint 6's (their
        # translations t2 (, t3) and t6 (, t5) are zero), whichever end has three axes;
        # a 7-joint chain: joint 1's origin, the subchain's centre |t2| from it; the numerical
        # kind: joint 1's and the last joint's origins
        self.t0 = c.t[0].copy()
        self.te, self.Re = c.te.copy(), c.Re.copy()

    def _closed_form(self, compiled_solver: bool) -> None:
        """The closed form's solver and reach geometry (ValueError when the chain is outside
        its class)."""
        c = self.chain
        # numba twins of the closed forms (kinematics/general_ik_compiled.py: the same answers, 16 us
        # instead of 51 ms a Talos arm pose), or the numpy references (``compiled_solver=False``)
        if self.n_joints == 7:
            ik = CompiledRedundantLimbIK(c, self.q_default) if compiled_solver \
                else RedundantLimbIK(c, self.q_default)
            kind, solver, swing = "redundant", ik.sub._solver, float(np.linalg.norm(c.t[1]))
        else:
            ik = CompiledGeneralLimbIK(c, self.q_default) if compiled_solver \
                else GeneralLimbIK(c, self.q_default)
            kind, solver, swing = "general", ik._solver, 0.0
        self.kind, self.ik = kind, ik
        # centres of the two ends and the distance range between them (elbow / knee swing)
        c_min, c_max = _centre_distance_range(solver)
        d_max, d_min = c_max + swing, max(c_min - swing, 0.0)
        self.l1, self.l2 = float((d_max + d_min) / 2), float((d_max - d_min) / 2)
        #: the closed form's own centre distance bound, without the swing (reach_centres)
        self.centre_reach = c_max

    def reach_centres(self, step_rad: float = 0.05) -> tuple[np.ndarray, float, float]:
        """The tight form of the reach bound: ``(points (K, 3), slack [m], reach [m])`` in the
        root link, such that every wrist (tip-end) centre the IK may solve for is within
        ``reach`` of a root-end centre lying within ``slack`` of one of the points.

        A 6-joint chain: joint 1's origin ``t0``, ``reach = l1 + l2``, no slack. A 7-joint
        chain: the subchain's root-end centre is joint 2's origin, which joint 1 carries on a
        circle about its axis; the points are that circle over joint 1's limits every
        ``step_rad`` (a point between two of them is at most ``r step_rad / 2`` from the
        nearer, ``r`` the circle's radius) and ``reach`` the subchain's own centre distance
        bound. Why not ``t0`` and ``l1 + l2`` here too: those widen the reach by the swing
        ``|t2|`` in every direction, while the centre only moves on the circle (Talos: the
        joint-2 centre is 0.047 m above joint 1's origin at any joint-1 angle, 0.539 m from the
        wrist at most, so the wrist rises 0.586 m above joint 1's origin at most; ``l1 + l2`` =
        0.683 m credits it with 0.098 m more). The numerical kind: ``t0``, ``l1 + l2``, no slack."""
        if self.n_joints == 6 or self.kind == "numerical":
            return self.t0[None].copy(), 0.0, self.l1 + self.l2
        c = self.chain
        n = max(1, int(math.ceil((c.upper[0] - c.lower[0]) / step_rad - 1e-9)))
        q1 = np.linspace(c.lower[0], c.upper[0], n + 1)
        pts = c.t[0] + np.einsum("ij,njk,k->ni", c.R[0], rotations(c.axes[0], q1), c.t[1])
        a = c.axes[0] / np.linalg.norm(c.axes[0])
        r = float(np.linalg.norm(c.t[1] - (a @ c.t[1]) * a))
        return pts, r * (c.upper[0] - c.lower[0]) / n / 2, self.centre_reach

    def fk(self, root_p, root_R, q):
        root_p = np.atleast_2d(np.asarray(root_p, float))
        root_R = np.asarray(root_R, float).reshape(-1, 3, 3)
        p, R = self.chain.fk(np.atleast_2d(q))
        return root_p + np.einsum("nij,nj->ni", np.broadcast_to(root_R, (len(p), 3, 3)), p), root_R @ R

    def _relative(self, root_p, root_R, tip_p, tip_R):
        root_p = np.atleast_2d(np.asarray(root_p, float))
        root_R = np.asarray(root_R, float).reshape(-1, 3, 3)
        tip_p = np.atleast_2d(np.asarray(tip_p, float))
        tip_R = np.asarray(tip_R, float).reshape(-1, 3, 3)
        n = max(len(root_p), len(root_R), len(tip_p), len(tip_R))
        rR = np.broadcast_to(root_R, (n, 3, 3))
        P = np.einsum("nji,nj->ni", rR, np.broadcast_to(tip_p, (n, 3)) - np.broadcast_to(root_p, (n, 3)))
        return P, np.transpose(rR, (0, 2, 1)) @ np.broadcast_to(tip_R, (n, 3, 3))

    def solve(self, root_p, root_R, tip_p, tip_R, q_ref=None):
        if self.kind == "numerical":     # the relative poses, the checks and the solve in one compiled call
            q, ok, reason = self.ik.solve_world(root_p, root_R, tip_p, tip_R, q_ref)
            return IKResult(q, ok, reason, np.where(ok, 0, -1).astype(np.int8))
        P, R = self._relative(root_p, root_R, tip_p, tip_R)
        finite = np.isfinite(P).all(axis=1) & np.isfinite(R).all(axis=(1, 2))
        res = self.ik.solve(np.nan_to_num(P), np.where(finite[:, None, None], R, np.eye(3)), q_ref)
        ok = res.ok & finite
        reason = np.where(ok, IKReason.OK, np.where(finite, IKReason.UNREACHABLE, IKReason.INVALID_INPUT))
        return IKResult(np.where(ok[:, None], res.q, np.nan), ok, reason.astype(np.int8),
                        np.where(ok, 0, -1).astype(np.int8))

    def maybe_reachable(self, root_p, root_R, tip_p, tip_R) -> np.ndarray:
        """Conservative: False only where the centre distance is outside [|l1 - l2|, l1 + l2]."""
        P, R = self._relative(root_p, root_R, tip_p, tip_R)
        d = np.linalg.norm(P - R @ (self.Re.T @ self.te) - self.t0, axis=1)
        with np.errstate(invalid="ignore"):
            return (d <= self.l1 + self.l2 + 1e-9) & (d >= abs(self.l1 - self.l2) - 1e-9)


__all__ = ["GeneralLimb"]
