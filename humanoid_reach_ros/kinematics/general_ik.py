"""Closed-form IK of a 6R chain from its geometry alone, whatever the axis directions and
link offsets, batched in numpy: the general counterpart of ``kinematics/hand_derived.py``'s two
hand-derived patterns (issue 13 part 2).

Solvable class (Pieper): three consecutive intersecting axes at one end of the chain (a
spherical wrist, or a hip) and two intersecting axes at the other (a shoulder with two
axes, or an ankle). Every humanoid limb we know is of this class (HRP-2's arms and legs,
Talos's legs, Talos's 7-DOF arms once one shoulder joint is fixed). A chain with the three
intersecting axes at its root is solved reversed (its inverse is a chain of the same form).
Other 6R chains (Pieper's general case needs a quartic) are refused with a ValueError.

Chain form (products of placements and rotations, the URDF's)::

    T(q) = M1 R(a1, q1) M2 R(a2, q2) ... M6 R(a6, q6) Me

with placements ``Mk = (Rk, tk)`` at q = 0 and unit axes ``ak`` in the joint frames. With
joints 1-2 intersecting (t2 = 0) and 4-5-6 intersecting (t5 = t6 = 0), the wrist centre
``w`` is the origin of joint 4's frame, and with ``c`` the centre of joints 1-2:

* elbow (Paden-Kahan subproblem 3): ``|w - c| = |t3 + R3 R(a3, q3) t4|`` depends on q3 alone:
  ``K0 + K1 cos q3 + K2 sin q3 = |w - c|^2``, two branches;
* shoulder (subproblem 2): ``R(a1, q1) R(R2 a2, q2) R2 v = R_c^T (w - c)``, two branches;
* wrist (subproblem 2 on the last axis, then subproblem 1):
  ``R(a4, q4) R(w5, q5) R(w6, q6) = rot(F4)^T R_tip Re^T (R5 R6)^T`` with ``w5 = R5 a5``,
  ``w6 = R5 R6 a6``, two branches.

That is 2 x 2 x 2 = 8 candidates per pose. Each angle is wrapped into ``[lower, lower + 2 pi)``;
a candidate is kept when it is within the joint limits and its forward kinematics reaches
the pose (``FK_TOL``: this check also settles singular configurations, where an angle the
pose leaves free is taken from ``q_ref``); the kept candidate nearest ``q_ref`` is returned.

No ROS here.
"""
from __future__ import annotations

from dataclasses import dataclass

import math

import numpy as np
import pinocchio as pin


TWO_PI = 2.0 * np.pi
ZERO_TOL = 1e-12     # a placement translation below this [m] is zero (axes intersect)
FK_TOL = 1e-8        # a candidate must reach the pose to this [m / rad]
LIMIT_TOL = 1e-10
_AXES = {"RX": (1.0, 0.0, 0.0), "RY": (0.0, 1.0, 0.0), "RZ": (0.0, 0.0, 1.0)}


def rotations(axis: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) about unit ``axis`` (3,) or (N, 3) by angles ``q`` (N,)."""
    a = np.broadcast_to(np.asarray(axis, float), (len(q), 3))
    c, s = np.cos(q), np.sin(q)
    x, y, z = a[:, 0], a[:, 1], a[:, 2]
    C = 1.0 - c
    R = np.empty((len(q), 3, 3))
    R[:, 0, 0] = c + x * x * C
    R[:, 0, 1] = x * y * C - z * s
    R[:, 0, 2] = x * z * C + y * s
    R[:, 1, 0] = y * x * C + z * s
    R[:, 1, 1] = c + y * y * C
    R[:, 1, 2] = y * z * C - x * s
    R[:, 2, 0] = z * x * C - y * s
    R[:, 2, 1] = z * y * C + x * s
    R[:, 2, 2] = c + z * z * C
    return R


@dataclass(frozen=True, eq=False)
class Chain6:
    """A chain of n revolute joints (module doc; six for :class:`GeneralLimbIK`, seven for
    :class:`RedundantLimbIK`): ``R`` (n, 3, 3) / ``t`` (n, 3) the placements M1..Mn,
    ``axes`` (n, 3), ``Re`` / ``te`` the tip placement, ``lower`` / ``upper`` (n,)."""

    R: np.ndarray
    t: np.ndarray
    axes: np.ndarray
    Re: np.ndarray
    te: np.ndarray
    lower: np.ndarray
    upper: np.ndarray

    @classmethod
    def from_model(cls, robot, root: str, joints, tip: str) -> "Chain6":
        """The chain of ``joints`` (6 or 7 names, root to tip) between frame ``root`` and frame
        ``tip`` of a :class:`~humanoid_reach_ros.robot.model.RobotModel`. ValueError if a
        joint is not revolute about a fixed axis or the joints are not one serial chain."""
        m = robot.model
        ids = [m.getJointId(j) for j in joints]
        if len(ids) not in (6, 7) or any(i >= m.njoints for i in ids):
            raise ValueError(f"need 6 joints (or 7) of the model, got {list(joints)}")
        for prev, j in zip(ids, ids[1:]):
            if m.parents[j] != prev:
                raise ValueError(f"{m.names[j]} does not follow {m.names[prev]} directly: not a serial 6R chain")
        axes = []
        for j in ids:
            kind = m.joints[j].shortname().replace("JointModel", "")
            if kind in _AXES:
                axes.append(_AXES[kind])
            elif kind == "RevoluteUnaligned":
                axes.append(np.asarray(m.joints[j].extract().axis, float))
            else:
                raise ValueError(f"{m.names[j]} is a {kind} joint: only revolute joints about a fixed axis")
        data = m.createData()
        q0 = pin.neutral(m)
        pin.forwardKinematics(m, data, q0)
        pin.updateFramePlacements(m, data)
        root_pose = data.oMf[m.getFrameId(root)]
        if m.frames[m.getFrameId(root)].parentJoint != m.parents[ids[0]]:
            raise ValueError(f"frame {root} is not on the link joint {m.names[ids[0]]} hangs from")
        tip_frame = m.frames[m.getFrameId(tip)]
        if tip_frame.parentJoint != ids[-1]:
            raise ValueError(f"frame {tip} does not hang from {m.names[ids[-1]]}")
        M = [root_pose.inverse() * data.oMi[ids[0]]] + [m.jointPlacements[j] for j in ids[1:]]
        idx = [robot.joint_index[j] for j in joints]
        return cls(np.array([p.rotation for p in M]), np.array([p.translation for p in M]), np.array(axes, float),
                   np.array(tip_frame.placement.rotation), np.array(tip_frame.placement.translation),
                   np.array(robot.lower[idx]), np.array(robot.upper[idx]))

    # ------------------------------------------------------------ structure
    def wrist_at_tip(self) -> bool:
        """Joints 1-2 and 4-5-6 intersect (the form solved directly)."""
        return bool(np.linalg.norm(self.t[1]) < ZERO_TOL and np.linalg.norm(self.t[4]) < ZERO_TOL
                    and np.linalg.norm(self.t[5]) < ZERO_TOL)

    def reversed(self) -> "Chain6":
        """The chain of T(q)^-1 in the joints ``-q[::-1]`` (module doc)."""
        n = len(self.axes)
        inv = [(R.T, -R.T @ t) for R, t in [(self.Re, self.te)] + [(self.R[k], self.t[k]) for k in range(n - 1, 0, -1)]]
        last = (self.R[0].T, -self.R[0].T @ self.t[0])
        return Chain6(np.array([R for R, _ in inv]), np.array([t for _, t in inv]), self.axes[::-1].copy(),
                      last[0], last[1], -self.upper[::-1], -self.lower[::-1])

    # ------------------------------------------------------------ kinematics
    def fk(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tip poses (N, 3), (N, 3, 3) relative to the root for joints ``q`` (N, n)."""
        q = np.atleast_2d(q)
        n = len(q)
        p, R = np.zeros((n, 3)), np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
        for k in range(len(self.axes)):
            p = p + R @ self.t[k]
            R = R @ self.R[k] @ rotations(self.axes[k], q[:, k])
        return p + R @ self.te, R @ self.Re


@dataclass(frozen=True)
class GeneralIKResult:
    q: np.ndarray       # (N, 6), NaN where not ok
    ok: np.ndarray      # (N,)


class GeneralLimbIK:
    """Closed-form IK of a :class:`Chain6` of the solvable class (module doc); ValueError
    for another chain. ``q_default`` (6,): the preferred solution when no ``q_ref`` is given."""

    def __init__(self, chain: Chain6, q_default: np.ndarray) -> None:
        if len(chain.axes) != 6:
            raise ValueError(f"GeneralLimbIK: a 6-joint chain, got {len(chain.axes)} (7: RedundantLimbIK)")
        self.chain = chain
        if chain.wrist_at_tip():
            self._solver, self.reversed = chain, False
        elif chain.reversed().wrist_at_tip():
            self._solver, self.reversed = chain.reversed(), True
        else:
            raise ValueError("not solvable in closed form: needs three consecutive intersecting axes at one end of "
                             "the chain and two at the other (placement offsets "
                             f"{np.round(np.linalg.norm(chain.t, axis=1), 4).tolist()} m)")
        self.q_default = np.asarray(q_default, float)

    def solve(self, target_p: np.ndarray, target_R: np.ndarray, q_ref: np.ndarray | None = None) -> GeneralIKResult:
        """Joints for tip poses relative to the chain's root: ``target_p`` (N, 3), ``target_R`` (N, 3, 3)."""
        P = np.atleast_2d(np.asarray(target_p, float))
        Rt = np.asarray(target_R, float).reshape(-1, 3, 3)
        n = len(P)
        ref = np.broadcast_to(self.q_default if q_ref is None else np.asarray(q_ref, float), (n, 6))
        if self.reversed:   # the reversed chain reaches T^-1 in the joints -q[::-1]
            Rs = np.transpose(Rt, (0, 2, 1))
            cand = _candidates(self._solver, -np.einsum("nij,nj->ni", Rs, P), Rs, -ref[:, ::-1])
            cand = -cand[:, :, ::-1]
        else:
            cand = _candidates(self._solver, P, Rt, ref)
        return self._select(cand, P, Rt, ref)

    def _select(self, cand, P, Rt, ref) -> GeneralIKResult:
        c = self.chain
        n = len(P)
        lo = c.lower
        wrapped = lo + np.mod(cand - lo, TWO_PI)
        inside = np.all((wrapped >= lo - LIMIT_TOL) & (wrapped <= c.upper + LIMIT_TOL), axis=2) & np.all(
            np.isfinite(cand), axis=2)
        flat = np.nan_to_num(np.clip(wrapped, lo, c.upper)).reshape(-1, 6)
        p, R = c.fk(flat)
        err_p = np.linalg.norm(p.reshape(n, -1, 3) - P[:, None], axis=2)
        err_R = np.linalg.norm((R.reshape(n, -1, 3, 3) - Rt[:, None]).reshape(n, -1, 9), axis=2)
        good = inside & (err_p < FK_TOL) & (err_R < FK_TOL)
        dist = np.where(good, np.linalg.norm(wrapped - ref[:, None], axis=2), np.inf)
        best = np.argmin(dist, axis=1)
        ok = np.isfinite(dist[np.arange(n), best])
        q = np.where(ok[:, None], np.clip(wrapped[np.arange(n), best], lo, c.upper), np.nan)
        return GeneralIKResult(q, ok)


def _sp1(w: np.ndarray, a: np.ndarray, b: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """Angle rotating ``a`` onto ``b`` about unit ``w`` (rows); ``fallback`` where ``a`` lies on the axis."""
    ap = a - np.einsum("ni,ni->n", w, a)[:, None] * w
    bp = b - np.einsum("ni,ni->n", w, b)[:, None] * w
    th = np.arctan2(np.einsum("ni,ni->n", w, np.cross(ap, bp)), np.einsum("ni,ni->n", ap, bp))
    return np.where(np.linalg.norm(ap, axis=1) < 1e-12, fallback, th)


def _sp2(w1: np.ndarray, w2: np.ndarray, p: np.ndarray, q: np.ndarray, ref1, ref2):
    """R(w1, t1) R(w2, t2) p = q for intersecting unit axes w1, w2 (3,): two (t1, t2) pairs,
    NaN where none exists."""
    n = len(p)
    w1n, w2n = np.broadcast_to(w1, (n, 3)), np.broadcast_to(w2, (n, 3))
    c12 = float(w1 @ w2)
    cr = np.cross(w1, w2)
    den = c12 * c12 - 1.0
    alpha = (c12 * (p @ w2) - q @ w1) / den
    beta = (c12 * (q @ w1) - p @ w2) / den
    g2 = (np.einsum("ni,ni->n", p, p) - alpha ** 2 - beta ** 2 - 2 * alpha * beta * c12) / float(cr @ cr)
    g2 = np.where((g2 < 0) & (g2 > -1e-10), 0.0, g2)
    out = []
    for sign in (1.0, -1.0):
        g = sign * np.sqrt(np.where(g2 >= 0, g2, np.nan))
        z = alpha[:, None] * w1 + beta[:, None] * w2 + g[:, None] * cr
        t2 = _sp1(w2n, p, z, ref2)
        t1 = _sp1(w1n, z, q, ref1)
        out.append((t1, t2))
    return out


def _elbow_terms(c) -> tuple[float, float, float]:
    """``K0, K1, K2`` of the elbow equation of a wrist-at-tip chain ``c``:
    ``|t3 + R3 R(a3, q3) t4|^2 = K0 + K1 cos q3 + K2 sin q3``, the squared distance between the
    centres of its two ends (joints 1-2 and the wrist) as the elbow (joint 3) turns."""
    a3, t3, R3, t4 = c.axes[2], c.t[2], c.R[2], c.t[3]
    upar = (a3 @ t4) * a3
    uperp = t4 - upar
    t3p = R3.T @ t3
    return t3 @ t3 + t4 @ t4 + 2 * (t3p @ upar), 2 * (t3p @ uperp), 2 * (t3p @ np.cross(a3, uperp))


def _centre_distance_range(c) -> tuple[float, float]:
    """The range of the distance between the two end centres of chain ``c`` over the elbow's
    turn: ``sqrt(K0 -+ rho)``, ``rho = |(K1, K2)|`` (:func:`_elbow_terms`)."""
    K0, K1, K2 = _elbow_terms(c)
    rho = float(np.hypot(K1, K2))
    return math.sqrt(max(K0 - rho, 0.0)), math.sqrt(K0 + rho)


def _candidates(c: Chain6, P: np.ndarray, Rt: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """(N, 8, 6) candidate joints of a wrist-at-tip chain for tip poses (P, Rt) relative to its root."""
    n = len(P)
    out = np.full((n, 8, 6), np.nan)
    w = P - Rt @ (c.Re.T @ c.te)                    # wrist centre: the origin of joint 4's frame
    cen = c.t[0]                                    # centre of joints 1-2
    Rc = c.R[0]
    u = (w - cen) @ Rc                              # R_c^T (w - c)
    d2 = np.einsum("ni,ni->n", u, u)
    # elbow: |t3 + R3 R(a3, q3) t4|^2 = K0 + K1 cos + K2 sin
    a3, t3, R3, t4 = c.axes[2], c.t[2], c.R[2], c.t[3]
    K0, K1, K2 = _elbow_terms(c)
    rho, phi = np.hypot(K1, K2), np.arctan2(K2, K1)
    cosx = (d2 - K0) / rho if rho > 1e-12 else np.full(n, np.nan)
    cosx = np.where(np.abs(cosx) <= 1 + 1e-10, np.clip(cosx, -1, 1), np.nan)
    k = 0
    for s3 in (1.0, -1.0):
        q3 = phi + s3 * np.arccos(cosx)
        v = t3 + (R3 @ rotations(a3, np.nan_to_num(q3)) @ t4)                 # (n, 3) in joint-2's rotated frame
        w2 = c.R[1] @ c.axes[1]
        for q1, q2 in _sp2(c.axes[0], w2, v @ c.R[1].T, u, ref[:, 0], ref[:, 1]):
            R1 = rotations(c.axes[0], np.nan_to_num(q1))
            R2 = rotations(c.axes[1], np.nan_to_num(q2))
            F4 = Rc @ R1 @ c.R[1] @ R2 @ R3 @ rotations(a3, np.nan_to_num(q3)) @ c.R[3]
            W = np.transpose(F4, (0, 2, 1)) @ Rt @ c.Re.T @ (c.R[4] @ c.R[5]).T
            w4, w5, w6 = c.axes[3], c.R[4] @ c.axes[4], c.R[4] @ c.R[5] @ c.axes[5]
            for q4, q5 in _sp2(w4, w5, np.broadcast_to(w6, (n, 3)), W @ w6, ref[:, 3], ref[:, 4]):
                X = np.transpose(rotations(w4, np.nan_to_num(q4)) @ rotations(w5, np.nan_to_num(q5)), (0, 2, 1)) @ W
                e = np.cross(w6, [1.0, 0.0, 0.0] if abs(w6[0]) < 0.9 else [0.0, 1.0, 0.0])
                e = np.broadcast_to(e / np.linalg.norm(e), (n, 3))
                q6 = _sp1(np.broadcast_to(w6, (n, 3)), e, X @ e[0], ref[:, 5])
                out[:, k] = np.stack([q1, q2, q3, q4, q5, q6], axis=1)
                k += 1
    return out




class RedundantLimbIK:
    """IK of a 7R arm in closed form on a 6-DOF subchain, the redundant joint sampled (our
    choice for 7-DOF arms, issue 13 part 2): the FIRST joint is held at ``samples`` values
    -- the reference's value first, then an even grid over its limits -- and joints 2..7,
    a chain of :class:`GeneralLimbIK`'s class (e.g. Talos: shoulder 2-3 intersecting,
    spherical wrist 5-6-7), are solved for each; per pose, the solution nearest ``q_ref``
    among those that reach it is kept. Simplification, named: the self-motion is searched
    on a grid, not parametrized continuously (a pose reachable only in a gap between grid
    values is reported unreachable)."""

    def __init__(self, chain: Chain6, q_default: np.ndarray, samples: int = 16) -> None:
        if len(chain.axes) != 7:
            raise ValueError(f"RedundantLimbIK: a 7-joint chain, got {len(chain.axes)}")
        self.chain = chain
        self.q_default = np.asarray(q_default, float)
        self.samples = int(samples)
        sub = Chain6(chain.R[1:], chain.t[1:], chain.axes[1:], chain.Re, chain.te, chain.lower[1:], chain.upper[1:])
        self.sub = GeneralLimbIK(sub, self.q_default[1:])   # ValueError outside the class
        # the subchain's wrist-centre distance range (elbow swing), for a cheap test per first-joint
        # value before the closed form runs (wrist at the tip only: the reversed form has its
        # centres the other way round)
        self._d_range = None
        if not self.sub.reversed:
            d_min, d_max = _centre_distance_range(self.sub._solver)
            self._d_range = (d_min - 1e-9, d_max + 1e-9)

    def solve(self, target_p: np.ndarray, target_R: np.ndarray, q_ref: np.ndarray | None = None) -> GeneralIKResult:
        """Per pose, the solution nearest ``q_ref`` over the first-joint values (the reference's,
        then the grid); a value whose subchain cannot reach the wrist centre (the elbow's
        distance range) is skipped for that pose before the closed form runs."""
        c = self.chain
        P = np.atleast_2d(np.asarray(target_p, float))
        Rt = np.asarray(target_R, float).reshape(-1, 3, 3)
        n = len(P)
        ref = np.broadcast_to(self.q_default if q_ref is None else np.asarray(q_ref, float), (n, 7))
        grid = np.linspace(c.lower[0], c.upper[0], max(self.samples - 1, 1))
        best_q, best_d = np.full((n, 7), np.nan), np.full(n, np.inf)
        if self._d_range is not None:   # wrist centre W in the root frame, for the distance test
            W = P - np.einsum("nij,j->ni", np.broadcast_to(Rt, (n, 3, 3)), c.Re.T @ c.te) - c.t[0]
        everyone = np.arange(n)
        for k in range(len(grid) + 1):
            q1 = np.clip(ref[:, 0] if k == 0 else np.full(n, grid[k - 1]), c.lower[0], c.upper[0])
            todo = everyone
            if self._d_range is not None:   # |W - R0 R(a0, q1) t1| outside the elbow's range: no solution
                d = np.linalg.norm(W - (c.R[0] @ rotations(c.axes[0], q1)) @ c.t[1], axis=1)
                todo = np.flatnonzero((d >= self._d_range[0]) & (d <= self._d_range[1]))
                if not len(todo):
                    continue
            R1 = c.R[0] @ rotations(c.axes[0], q1[todo])                # (m, 3, 3): joint 1's rotated frame
            R1T = np.transpose(R1, (0, 2, 1))
            sub = self.sub.solve(np.einsum("nij,nj->ni", R1T, P[todo] - c.t[0]),
                                 R1T @ (Rt[todo] if len(Rt) == n else Rt), ref[todo, 1:])
            q = np.column_stack([q1[todo], sub.q])
            dist = np.where(sub.ok, np.linalg.norm(q - ref[todo], axis=1), np.inf)
            better = dist < best_d[todo]
            best_q[todo[better]], best_d[todo[better]] = q[better], dist[better]
        return GeneralIKResult(best_q, np.isfinite(best_d))


__all__ = ["Chain6", "GeneralLimbIK", "RedundantLimbIK", "GeneralIKResult", "rotations"]
