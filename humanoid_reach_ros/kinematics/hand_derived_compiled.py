"""Compiled closed-form arm IK: a numba twin of ``LimbIK``'s single-pose arm solver.

``humanoid_reach_ros.kinematics.hand_derived`` compiles only the legs; its arms run the pure-Python
single-pose path (``LimbIK._solve_one`` + ``_arm_one``), about 0.1 ms per arm and call,
which dominated a control step of the proposed method (dissertation Sec. 4.4: closed-form
IK of both arms from the torso pose). :func:`arm_ik_pose` is the same algorithm -- the
formulas in limb_ik's module docstring (wrist pitch from ``r . f = k``, elbow and wrist
yaw from ``t``, shoulder Euler angles peeled off ``M = R_c^T R_5 Ry(-q5) Rz(-q4)
Ry(-q3)``), the same 8-candidate branch order, wrapping into ``[lower, lower + 2 pi)``,
the gimbal / stretched-arm redistribution and the nearest-to-``q_ref`` selection with
the same tolerances -- compiled, one pose, no temporaries. test_whole_body_ik.py checks
it against ``LimbIK.solve_reference`` to 1e-12 on random poses, including unreachable
and out-of-limit ones.

No rclpy here.
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

from humanoid_reach_ros.kinematics.hand_derived import (
    GIMBAL_TOL, LIMIT_TOL, PSI_SNAP, REACH_TOL, STRETCH_TOL, IKReason, LimbIK,
    _leg_rot_ok, redistribute_pair, wrap_angle,
)

_JIT = dict(cache=True, nogil=False, fastmath=False)


@nb.njit(**_JIT)
def _rmul_y(M, a, out):
    """out = M Ry(a)"""
    c, s = math.cos(a), math.sin(a)
    for r in range(3):
        m0, m2 = M[r, 0], M[r, 2]
        out[r, 0] = c * m0 - s * m2
        out[r, 1] = M[r, 1]
        out[r, 2] = s * m0 + c * m2


@nb.njit(**_JIT)
def _rmul_z(M, a, out):
    """out = M Rz(a)"""
    c, s = math.cos(a), math.sin(a)
    for r in range(3):
        m0, m1 = M[r, 0], M[r, 1]
        out[r, 0] = c * m0 + s * m1
        out[r, 1] = -s * m0 + c * m1
        out[r, 2] = M[r, 2]


@nb.njit(**_JIT)
def arm_ik_pose(rp, rR, tp, tR, rf, R0, t0, Re, te, U, F, lo, hi, q_out):
    """One arm pose: writes ``q_out`` (6,) (NaN on failure); returns ``(reason, branch)``
    (:class:`IKReason` code, branch index or -1). Constants as ``LimbIK._kc``."""
    s = (rp[0] + rp[1] + rp[2]) + (tp[0] + tp[1] + tp[2]) + (rf[0] + rf[1] + rf[2] + rf[3] + rf[4] + rf[5])
    if not (np.isfinite(s) and _leg_rot_ok(rR) and _leg_rot_ok(tR)):
        q_out[:] = np.nan
        return 3, -1
    Rc = np.empty((3, 3))
    R5 = np.empty((3, 3))
    Mt = np.empty((3, 3))
    c = np.empty(3)
    w = np.empty(3)
    r = np.empty(3)
    for a in range(3):
        for b in range(3):
            Rc[a, b] = rR[a, 0] * R0[0, b] + rR[a, 1] * R0[1, b] + rR[a, 2] * R0[2, b]
            R5[a, b] = tR[a, 0] * Re[b, 0] + tR[a, 1] * Re[b, 1] + tR[a, 2] * Re[b, 2]
        c[a] = rp[a] + rR[a, 0] * t0[0] + rR[a, 1] * t0[1] + rR[a, 2] * t0[2]
    for a in range(3):
        w[a] = tp[a] - (R5[a, 0] * te[0] + R5[a, 1] * te[1] + R5[a, 2] * te[2])
    d0, d1, d2 = c[0] - w[0], c[1] - w[1], c[2] - w[2]
    for a in range(3):
        r[a] = R5[0, a] * d0 + R5[1, a] * d1 + R5[2, a] * d2
        for b in range(3):
            Mt[a, b] = Rc[0, a] * R5[0, b] + Rc[1, a] * R5[1, b] + Rc[2, a] * R5[2, b]
    k = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2] + F * F - U * U) / (2.0 * F)
    rho = math.hypot(r[0], r[2])
    phi = math.atan2(r[0], r[2])
    gap = rho - abs(k)
    if not gap >= -REACH_TOL * rho:
        q_out[:] = np.nan
        return 1, -1
    cpsi = min(max(k / (rho if rho > 0.0 else 1.0), -1.0), 1.0)
    if gap < PSI_SNAP:
        cpsi = math.copysign(1.0, k) if k != 0.0 else 0.0
    psi = math.atan2(math.sqrt((1.0 - cpsi) * (1.0 + cpsi)), cpsi)
    W = np.empty((2, 4))          # per wrist branch: q5, q3p, q4p, stretched
    for wb in range(2):
        q5 = -phi + psi if wb == 0 else -phi - psi
        c5, s5 = math.cos(q5), math.sin(q5)
        tx = c5 * r[0] + s5 * r[2]
        ty = r[1]
        tz = -s5 * r[0] + c5 * r[2] - F
        h = math.hypot(tx, ty)
        st = h < STRETCH_TOL
        W[wb, 0] = q5
        W[wb, 1] = 0.0 if st else math.atan2(h, tz)
        W[wb, 2] = rf[4] if st else math.atan2(ty, -tx)
        W[wb, 3] = 1.0 if st else 0.0
    A1 = np.empty((3, 3))
    A2 = np.empty((3, 3))
    M = np.empty((3, 3))
    q = np.empty(6)
    best_b = -1
    best_d = np.inf
    b = -1
    for i in range(2):
        for wb in range(2):
            q5, q3p, q4p, stretched = W[wb, 0], W[wb, 1], W[wb, 2], W[wb, 3] > 0.5
            q3 = q3p if i == 0 else -q3p
            q4 = q4p if (i == 0 or stretched) else q4p + math.pi
            _rmul_y(Mt, -q5, A1)
            _rmul_z(A1, -q4, A2)
            _rmul_y(A2, -q3, M)
            gimbal = math.hypot(M[0, 2], M[2, 2]) < GIMBAL_TOL
            q0a = rf[0] if gimbal else math.atan2(M[0, 2], M[2, 2])
            for hb in range(2):
                b += 1
                q0 = q0a if hb == 0 else q0a + math.pi
                ca, sa = math.cos(q0), math.sin(q0)
                q2 = math.atan2(-(ca * M[0, 1] - sa * M[2, 1]), ca * M[0, 0] - sa * M[2, 0])
                q1 = math.atan2(-M[1, 2], sa * M[0, 2] + ca * M[2, 2])
                if gimbal:
                    q1 = math.copysign(0.5 * math.pi, q1)
                coef_g = math.sin(q1)
                q[0], q[1], q[2], q[3], q[4], q[5] = q0, q1, q2, q3, q4, q5
                for a in range(6):
                    q[a] = wrap_angle(q[a], lo[a])
                if gimbal or stretched:
                    if gimbal:
                        redistribute_pair(q, 0, 2, coef_g, rf, lo, hi)
                    if stretched:
                        redistribute_pair(q, 4, 2, -1.0, rf, lo, hi)
                    for a in range(6):
                        q[a] = wrap_angle(q[a], lo[a])
                inlim = True
                for a in range(6):
                    if not (q[a] <= hi[a] + LIMIT_TOL):     # NaN fails too
                        inlim = False
                        break
                if not inlim:
                    continue
                dist = 0.0
                for a in range(6):
                    q[a] = min(max(q[a], lo[a]), hi[a])
                    dist += (q[a] - rf[a]) ** 2
                if dist < best_d:
                    best_d = dist
                    best_b = b
                    for a in range(6):
                        q_out[a] = q[a]
    if best_b < 0:
        q_out[:] = np.nan
        return 2, -1
    return 0, best_b


class CompiledArmIK:
    """Single-pose closed-form IK of one arm (:func:`arm_ik_pose`) with the constants of
    a :class:`LimbIK` of kind ``arm``."""

    @staticmethod
    def supports(limb) -> bool:
        """Whether ``limb`` (a ``LimbIKSet`` entry) is of the hand-derived 6-DOF arm pattern
        this kernel compiles; other arms (``GeneralLimb``: general 6R, 7-DOF) are not."""
        return isinstance(limb, LimbIK) and limb.kind == "arm"

    def __init__(self, limb: LimbIK) -> None:
        if not self.supports(limb):
            raise ValueError(f"{limb.limb_name}: CompiledArmIK needs an arm, got a {limb.kind}")
        self.limb = limb
        self._kc = limb._kc
        self.q = np.empty(6)

    def solve(self, root_p: np.ndarray, root_R: np.ndarray, tip_p: np.ndarray, tip_R: np.ndarray,
              q_ref: np.ndarray) -> tuple[int, np.ndarray]:
        """``(reason, q)``: ``IKReason`` code (0 = OK) and the (6,) angles (NaN on failure;
        a new array)."""
        q = np.empty(6)
        reason, _ = arm_ik_pose(np.ascontiguousarray(root_p, float), np.ascontiguousarray(root_R, float),
                                np.ascontiguousarray(tip_p, float), np.ascontiguousarray(tip_R, float),
                                np.ascontiguousarray(q_ref, float), *self._kc, q)
        return int(reason), q


__all__ = ["arm_ik_pose", "CompiledArmIK", "IKReason"]
