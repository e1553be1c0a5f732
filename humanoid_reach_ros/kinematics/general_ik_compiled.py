"""Compiled general closed-form IK: a numba twin of ``kinematics/general_ik.py``'s
:class:`~humanoid_reach_ros.kinematics.general_ik.GeneralLimbIK` (6R chains of the Pieper
class, direct and reversed form) and
:class:`~humanoid_reach_ros.kinematics.general_ik.RedundantLimbIK` (7R arms, first joint
sampled), one pose at a time, no temporaries per pose.

The numpy reference is batched: a single pose costs it hundreds of numpy calls on tiny
arrays (milliseconds for a 7-DOF arm), where HRP-2's hand-derived kernels
(``kinematics/hand_derived_compiled.py``, ``limb_ik._leg_ik_kernel``) take microseconds. The kernels here
run the same algorithm -- the same formulas (Paden-Kahan subproblems 1-3, the elbow
equation's ``K0, K1, K2``), the same 8 candidates in the same branch order, each angle
wrapped into ``[lower, lower + 2 pi)``, the same limit tolerance, the FK check with
``FK_TOL`` on the original chain, the nearest to ``q_ref`` with the first index winning a
tie; for the 7R arm the reference's first-joint value first, then the same grid, the same
distance pre-test, the nearest to ``q_ref`` over all values, the earliest value winning a
tie. The reference's constants (the solver chain GeneralLimbIK picks, its sp2 constants,
the elbow terms, the grid) are computed by the reference's own numpy expressions and
packed into one float array per limb (layout: the ``S_*`` / ``C_*`` / ``H_*`` offsets).

Shortcuts, none changing an answer (test/test_general_ik_compiled.py: ``ok`` equal and ``q``
to 1e-9 against the reference on Talos's arms and legs, HRP-2's four limbs, the 7R arm's
subchain and random chains of both forms and of 7R arms with and without the distance
pre-test, on reachable, unreachable and near-limit poses with default, drawn and random
references; a hypothesis property on Talos's arm):

* a branch is not computed further once its elbow, shoulder or wrist angles (joints 1-5
  of the solver chain) are outside the limits -- the reference drops those candidates at
  the end;
* the FK check runs lazily: the candidates within the limits are tried nearest to
  ``q_ref`` first, and the first to pass is the reference's argmin;
* the 7R arm visits its first-joint values in order of their distance to the reference's
  (the reference's own value first) and stops once ``|q1 - q_ref[0]|`` exceeds the best
  distance found plus ``PRUNE_MARGIN``: no later value can come nearer; inside a value, a
  branch whose partial distance already exceeds it is dropped.

Two products are associated differently (``R3 R(a3, q3) R4`` and ``Rt Re^T (R5 R6)^T`` are
formed once per pose or elbow branch), so ``q`` agrees to rounding, 1e-14 typically and up
to 1e-9 near a singular configuration. Not reproducible between the two: a joint exactly at
its LOWER limit. Both wrap a candidate into ``[lower, lower + 2 pi)``, and one that rounding
puts 1e-16 below the limit wraps to the far end and is dropped (limb_ik.wrap_angle starts
its window LIMIT_TOL lower for this reason; general_ik does not, so the reference drops
many such poses -- half of the leg poses with joints drawn at their limits, in a trial --
and which ones depends on the order of operations).

Measured (``python bench/general_ik.py``, one pose per call, median over 2,000 distinct
poses after warm-up; AMD EPYC VM, 2 cpus, load average 5-7 from another benchmark)::

    limb                          numpy ref.   compiled solve   (solve_one)   speedup
    Talos right arm, 7R           51,417 us         16.1 us        14.3 us      3,201x
      the same, q_ref = drawn     55,652 us          5.9 us         4.3 us      9,387x
    Talos right leg, 6R            3,722 us          5.2 us         3.6 us        717x
    HRP-2 right arm: CompiledArmIK.solve 3.9 us; this kernel's solve_one 3.8 us
    Talos arm / HRP-2 arm: 4.1 (default q_ref), 1.5 (q_ref next to the answer)

(the leg as a GeneralLimbIK chain: in the limb set Talos's legs get limb_ik's hand-derived
compiled leg kernel.)

No ROS here.
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

from humanoid_reach_ros.kinematics.general_ik import (
    FK_TOL, LIMIT_TOL, TWO_PI, Chain6, GeneralIKResult, GeneralLimbIK, RedundantLimbIK, _elbow_terms,
)

#: numba options of the house (limb_ik.py, fast_arms.py): nogil=False, see geometry/distance.py
_JIT = dict(cache=True, nogil=False, fastmath=False)

#: a first-joint value (7R) or candidate is skipped when it is farther than the best found by this [rad]
#: (covers the clipping into the limits, at most LIMIT_TOL per joint, and rounding)
PRUNE_MARGIN = 1e-6
AP_TOL = 1e-12          # general_ik._sp1: ``a`` on the axis below this
G2_SNAP = 1e-10         # general_ik._sp2: g^2 in (-G2_SNAP, 0) is 0
COS_TOL = 1e-10         # general_ik._candidates: |cos| <= 1 + COS_TOL is clipped, beyond is no elbow
RHO_TOL = 1e-12         # general_ik._candidates: an elbow with rho below this has no solution

# ---------------------------------------------------------------- packed constants
# 6R block (K6): the solver chain (wrist at its tip; the chain itself or its reversal)
S_R, S_T, S_A = 0, 54, 72          # placements R (6, 3, 3), t (6, 3), axes (6, 3)
S_RET, S_RETTE, S_R45T = 90, 99, 102   # Re^T, Re^T te, (R5 R6)^T
S_W2, S_W5, S_W6, S_E = 111, 114, 117, 120   # R2 a2, R5 a5, R5 R6 a6, q6's reference vector e
S_SP_SH, S_SP_WR = 123, 129        # sp2 constants (c12, c12^2 - 1, |w1 x w2|^2, w1 x w2) shoulder / wrist
S_ELB = 135                        # K0, rho, phi of the elbow equation
S_REV = 138                        # 1.0: the solver is the reversed chain
# the chain itself (FK check, limits)
C_R, C_T, C_A, C_RE, C_TE, C_LO, C_HI = 139, 193, 211, 229, 238, 241, 247
K6_SIZE = 253
# 7R header (K7): joint 1 and the grid of its values
H_R0, H_T0, H_A0, H_T1, H_RETTE = 0, 9, 12, 15, 18   # R1 (3, 3), t1, a1, t2, Re^T te of the 7R chain
H_LIM = 21                         # lower, upper of joint 1
H_D = 23                           # 1.0 if the distance pre-test applies, d_min, d_max
H_NG = 26                          # number of grid values
H_GRID = 27                        # the grid
# scratch (one float array per kernel call)
W_CAND, W_WRAP, W_DIST = 0, 48, 96     # candidates (8, 6), wrapped (8, 6), distances (8,)
W_MAT = 104                            # 12 matrices (3, 3)
W_VEC = W_MAT + 12 * 9                 # 12 vectors (3,)
W_REF = W_VEC + 12 * 3                 # the solver's reference (6,)
WORK6_SIZE = W_REF + 6
W7_Q = WORK6_SIZE                      # the subchain's answer (6,)
W7_P, W7_R = W7_Q + 6, W7_Q + 9        # the subchain's target (3,), (3, 3)
W7_ORDER = W7_Q + 18                   # visiting order of the first-joint values (as floats)


def _sp2_constants(w1: np.ndarray, w2: np.ndarray) -> list[float]:
    """``c12, c12^2 - 1, |cr|^2, cr`` as general_ik._sp2 computes them."""
    c12 = float(w1 @ w2)
    cr = np.cross(w1, w2)
    return [c12, c12 * c12 - 1.0, float(cr @ cr), *cr]


def pack_general(ik: GeneralLimbIK) -> np.ndarray:
    """The K6 constants of a :class:`GeneralLimbIK` (its solver chain, its chain)."""
    s, c = ik._solver, ik.chain
    K = np.zeros(K6_SIZE)
    K[S_R:S_R + 54] = s.R.ravel()
    K[S_T:S_T + 18] = s.t.ravel()
    K[S_A:S_A + 18] = s.axes.ravel()
    K[S_RET:S_RET + 9] = s.Re.T.ravel()
    K[S_RETTE:S_RETTE + 3] = s.Re.T @ s.te
    K[S_R45T:S_R45T + 9] = (s.R[4] @ s.R[5]).T.ravel()
    w2 = s.R[1] @ s.axes[1]
    w4, w5, w6 = s.axes[3], s.R[4] @ s.axes[4], s.R[4] @ s.R[5] @ s.axes[5]
    e = np.cross(w6, [1.0, 0.0, 0.0] if abs(w6[0]) < 0.9 else [0.0, 1.0, 0.0])
    K[S_W2:S_W2 + 3] = w2
    K[S_W5:S_W5 + 3] = w5
    K[S_W6:S_W6 + 3] = w6
    K[S_E:S_E + 3] = e / np.linalg.norm(e)
    K[S_SP_SH:S_SP_SH + 6] = _sp2_constants(s.axes[0], w2)
    K[S_SP_WR:S_SP_WR + 6] = _sp2_constants(w4, w5)
    K0, K1, K2 = _elbow_terms(s)
    K[S_ELB:S_ELB + 3] = K0, np.hypot(K1, K2), np.arctan2(K2, K1)
    K[S_REV] = 1.0 if ik.reversed else 0.0
    K[C_R:C_R + 54] = c.R.ravel()
    K[C_T:C_T + 18] = c.t.ravel()
    K[C_A:C_A + 18] = c.axes.ravel()
    K[C_RE:C_RE + 9] = c.Re.ravel()
    K[C_TE:C_TE + 3] = c.te
    K[C_LO:C_LO + 6] = c.lower
    K[C_HI:C_HI + 6] = c.upper
    return K


def pack_redundant(ik: RedundantLimbIK) -> np.ndarray:
    """The K7 header of a :class:`RedundantLimbIK` (joint 1, the distance pre-test, the grid)."""
    c = ik.chain
    grid = np.linspace(c.lower[0], c.upper[0], max(ik.samples - 1, 1))
    K = np.zeros(H_GRID + len(grid))
    K[H_R0:H_R0 + 9] = c.R[0].ravel()
    K[H_T0:H_T0 + 3] = c.t[0]
    K[H_A0:H_A0 + 3] = c.axes[0]
    K[H_T1:H_T1 + 3] = c.t[1]
    K[H_RETTE:H_RETTE + 3] = c.Re.T @ c.te
    K[H_LIM:H_LIM + 2] = c.lower[0], c.upper[0]
    if ik._d_range is not None:
        K[H_D:H_D + 3] = 1.0, ik._d_range[0], ik._d_range[1]
    K[H_NG] = len(grid)
    K[H_GRID:] = grid
    return K


# ---------------------------------------------------------------- small linear algebra
@nb.njit(**_JIT)
def _rot(a, q, out):
    """out = R(a, q) (general_ik.rotations, the same expressions)."""
    c, s = math.cos(q), math.sin(q)
    x, y, z = a[0], a[1], a[2]
    C = 1.0 - c
    out[0, 0] = c + x * x * C
    out[0, 1] = x * y * C - z * s
    out[0, 2] = x * z * C + y * s
    out[1, 0] = y * x * C + z * s
    out[1, 1] = c + y * y * C
    out[1, 2] = y * z * C - x * s
    out[2, 0] = z * x * C - y * s
    out[2, 1] = z * y * C + x * s
    out[2, 2] = c + z * z * C


@nb.njit(**_JIT)
def _mm(A, B, out):
    """out = A B (out distinct from A, B)."""
    for i in range(3):
        for j in range(3):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]


@nb.njit(**_JIT)
def _mtm(A, B, out):
    """out = A^T B."""
    for i in range(3):
        for j in range(3):
            out[i, j] = A[0, i] * B[0, j] + A[1, i] * B[1, j] + A[2, i] * B[2, j]


@nb.njit(**_JIT)
def _mv(A, v, out):
    """out = A v."""
    for i in range(3):
        out[i] = A[i, 0] * v[0] + A[i, 1] * v[1] + A[i, 2] * v[2]


@nb.njit(**_JIT)
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@nb.njit(**_JIT)
def _sp1(w, a, b, fallback):
    """general_ik._sp1 for one row: the angle turning ``a`` onto ``b`` about unit ``w``."""
    wa, wb = _dot(w, a), _dot(w, b)
    a0, a1, a2 = a[0] - wa * w[0], a[1] - wa * w[1], a[2] - wa * w[2]
    b0, b1, b2 = b[0] - wb * w[0], b[1] - wb * w[1], b[2] - wb * w[2]
    x0, x1, x2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    th = math.atan2(w[0] * x0 + w[1] * x1 + w[2] * x2, a0 * b0 + a1 * b1 + a2 * b2)
    if math.sqrt(a0 * a0 + a1 * a1 + a2 * a2) < AP_TOL:
        return fallback
    return th


@nb.njit(**_JIT)
def _sp2_terms(w1, w2, sp, p, q):
    """``alpha, beta, g^2`` of general_ik._sp2 (``sp``: the packed constants); g^2 < 0: none."""
    c12, den, crcr = sp[0], sp[1], sp[2]
    if den == 0.0 or crcr == 0.0:      # parallel axes: the reference divides by zero (NaN, no solution)
        return 0.0, 0.0, -1.0
    pw2, qw1 = _dot(p, w2), _dot(q, w1)
    alpha = (c12 * pw2 - qw1) / den
    beta = (c12 * qw1 - pw2) / den
    g2 = (_dot(p, p) - alpha * alpha - beta * beta - 2 * alpha * beta * c12) / crcr
    if g2 < 0 and g2 > -G2_SNAP:
        g2 = 0.0
    return alpha, beta, g2


@nb.njit(**_JIT)
def _sp2_point(w1, w2, sp, alpha, beta, g, z):
    """z = alpha w1 + beta w2 + g (w1 x w2)."""
    for i in range(3):
        z[i] = alpha * w1[i] + beta * w2[i] + g * sp[3 + i]


# ---------------------------------------------------------------- 6R
@nb.njit(**_JIT)
def _wrap(c, lo):
    """``lo + (c - lo) mod 2 pi`` as the reference computes it (the remainder is skipped where
    ``c - lo`` is already in ``[0, 2 pi)``: it returns it unchanged)."""
    x = c - lo
    if not (x >= 0.0 and x < TWO_PI):
        x = x % TWO_PI
    return lo + x


@nb.njit(**_JIT)
def _joint_term(K, rev, j, x, ref):
    """Solver joint ``j`` at ``x``, on the chain's joint (``-x`` on joint ``5 - j`` when reversed),
    wrapped as the selection wraps it: ``(q - ref)^2`` there, inf outside the limits or NaN."""
    o, c = (5 - j, -x) if rev else (j, x)
    if not np.isfinite(c):
        return np.inf
    w = _wrap(c, K[C_LO + o])
    if not w <= K[C_HI + o] + LIMIT_TOL:
        return np.inf
    d = w - ref[o]
    return d * d


@nb.njit(**_JIT)
def _candidates(P, Rt, ref, K, cand, work, ref_o, dq0_sq, bound):
    """general_ik._candidates for one pose of the solver chain: ``cand`` (8, 6), NaN rows
    where a branch has no solution -- or cannot be selected: a branch whose elbow,
    shoulder or wrist angles (joints 1-5) are outside the chain's limits, or whose partial
    distance to ``ref_o`` (the chain's reference) puts it beyond ``bound`` (general_ik_pose)
    is not computed further. False when no row is left."""
    sR = K[S_R:S_R + 54].reshape((6, 3, 3))
    sT = K[S_T:S_T + 18].reshape((6, 3))
    sA = K[S_A:S_A + 18].reshape((6, 3))
    ReT = K[S_RET:S_RET + 9].reshape((3, 3))
    ReTte = K[S_RETTE:S_RETTE + 3]
    R45T = K[S_R45T:S_R45T + 9].reshape((3, 3))
    w2s, w5, w6, e = K[S_W2:S_W2 + 3], K[S_W5:S_W5 + 3], K[S_W6:S_W6 + 3], K[S_E:S_E + 3]
    spS, spW = K[S_SP_SH:S_SP_SH + 6], K[S_SP_WR:S_SP_WR + 6]
    rev = K[S_REV] > 0.5
    limit = (bound + PRUNE_MARGIN) ** 2
    M = work[W_MAT:W_MAT + 108].reshape((12, 3, 3))
    V = work[W_VEC:W_VEC + 36].reshape((12, 3))
    for k in range(8):
        for j in range(6):
            cand[k, j] = np.nan
    Rc = sR[0]
    # wrist centre, in the frame of joints 1-2: u = Rc^T (P - Rt Re^T te - t1)
    d = V[0]
    for i in range(3):
        d[i] = (P[i] - (Rt[i, 0] * ReTte[0] + Rt[i, 1] * ReTte[1] + Rt[i, 2] * ReTte[2])) - sT[0, i]
    u = V[1]
    for j in range(3):
        u[j] = d[0] * Rc[0, j] + d[1] * Rc[1, j] + d[2] * Rc[2, j]
    d2 = _dot(u, u)
    K0, rho, phi = K[S_ELB], K[S_ELB + 1], K[S_ELB + 2]
    if not rho > RHO_TOL:
        return False
    cosx = (d2 - K0) / rho
    if not abs(cosx) <= 1 + COS_TOL:
        return False
    acx = math.acos(min(max(cosx, -1.0), 1.0))
    a3, R3, t3, t4 = sA[2], sR[2], sT[2], sT[3]
    Rq3, B, R1q, R2q, F, G, W, X, Y, RtC = M[0], M[1], M[2], M[3], M[4], M[5], M[6], M[7], M[8], M[9]
    v, p, z, qw, Xe = V[2], V[3], V[4], V[5], V[6]
    # Rt Re^T (R5 R6)^T, the pose's part of W = F4^T Rt Re^T (R5 R6)^T
    _mm(Rt, ReT, X)
    _mm(X, R45T, RtC)
    left = False
    for b3 in range(2):
        k = 4 * b3
        q3 = phi + (1.0 if b3 == 0 else -1.0) * acx
        e3 = _joint_term(K, rev, 2, q3, ref_o)
        if e3 == np.inf or dq0_sq + e3 > limit:
            continue
        _rot(a3, q3, Rq3)
        _mm(R3, Rq3, X)
        _mv(X, t4, v)
        for i in range(3):
            v[i] = t3[i] + v[i]
        _mv(sR[1], v, p)
        _mm(X, sR[3], B)                  # R3 R(a3, q3) R4
        alpha, beta, g2 = _sp2_terms(sA[0], w2s, spS, p, u)
        if not g2 >= 0.0:
            continue
        for b12 in range(2):
            k = 4 * b3 + 2 * b12
            _sp2_point(sA[0], w2s, spS, alpha, beta, (1.0 if b12 == 0 else -1.0) * math.sqrt(g2), z)
            q2 = _sp1(w2s, p, z, ref[1])
            q1 = _sp1(sA[0], z, u, ref[0])
            e12 = _joint_term(K, rev, 0, q1, ref_o) + _joint_term(K, rev, 1, q2, ref_o)
            if e12 == np.inf or dq0_sq + e12 + e3 > limit:
                continue
            # F4 = Rc R(a1, q1) R2 R(a2, q2) R3 R(a3, q3) R4
            _rot(sA[0], q1, R1q)
            _rot(sA[1], q2, R2q)
            _mm(Rc, R1q, F)
            _mm(F, sR[1], G)
            _mm(G, R2q, F)
            _mm(F, B, G)
            _mtm(G, RtC, W)               # W = F4^T Rt Re^T (R5 R6)^T
            _mv(W, w6, qw)
            alpha2, beta2, g22 = _sp2_terms(sA[3], w5, spW, w6, qw)
            if not g22 >= 0.0:
                continue
            for b45 in range(2):
                _sp2_point(sA[3], w5, spW, alpha2, beta2, (1.0 if b45 == 0 else -1.0) * math.sqrt(g22), z)
                q5 = _sp1(w5, w6, z, ref[4])
                q4 = _sp1(sA[3], z, qw, ref[3])
                e45 = _joint_term(K, rev, 3, q4, ref_o) + _joint_term(K, rev, 4, q5, ref_o)
                if e45 == np.inf or dq0_sq + e12 + e3 + e45 > limit:
                    continue
                # X = (R(w4, q4) R(w5, q5))^T W, q6 turns e onto X e about w6
                _rot(sA[3], q4, F)
                _rot(w5, q5, G)
                _mm(F, G, Y)
                _mtm(Y, W, X)
                _mv(X, e, Xe)
                q6 = _sp1(w6, e, Xe, ref[5])
                cand[k + b45, 0], cand[k + b45, 1], cand[k + b45, 2] = q1, q2, q3
                cand[k + b45, 3], cand[k + b45, 4], cand[k + b45, 5] = q4, q5, q6
                left = True
    return left


@nb.njit(**_JIT)
def _fk_reaches(K, q, P, Rt, work):
    """The chain's FK (Chain6.fk, the same order of products) at ``q`` reaches (P, Rt) to FK_TOL."""
    cR = K[C_R:C_R + 54].reshape((6, 3, 3))
    cT = K[C_T:C_T + 18].reshape((6, 3))
    cA = K[C_A:C_A + 18].reshape((6, 3))
    Re, te = K[C_RE:C_RE + 9].reshape((3, 3)), K[C_TE:C_TE + 3]
    M = work[W_MAT:W_MAT + 108].reshape((12, 3, 3))
    R, T, Rq = M[9], M[10], M[11]
    p0 = p1 = p2 = 0.0
    for i in range(3):
        for j in range(3):
            R[i, j] = 1.0 if i == j else 0.0
    for k in range(6):
        t = cT[k]
        p0 = p0 + (R[0, 0] * t[0] + R[0, 1] * t[1] + R[0, 2] * t[2])
        p1 = p1 + (R[1, 0] * t[0] + R[1, 1] * t[1] + R[1, 2] * t[2])
        p2 = p2 + (R[2, 0] * t[0] + R[2, 1] * t[1] + R[2, 2] * t[2])
        _mm(R, cR[k], T)
        _rot(cA[k], q[k], Rq)
        _mm(T, Rq, R)
    e0 = p0 + (R[0, 0] * te[0] + R[0, 1] * te[1] + R[0, 2] * te[2]) - P[0]
    e1 = p1 + (R[1, 0] * te[0] + R[1, 1] * te[1] + R[1, 2] * te[2]) - P[1]
    e2 = p2 + (R[2, 0] * te[0] + R[2, 1] * te[1] + R[2, 2] * te[2]) - P[2]
    if not math.sqrt(e0 * e0 + e1 * e1 + e2 * e2) < FK_TOL:
        return False
    _mm(R, Re, T)
    s = 0.0
    for i in range(3):
        for j in range(3):
            x = T[i, j] - Rt[i, j]
            s += x * x
    return math.sqrt(s) < FK_TOL


@nb.njit(**_JIT)
def general_ik_pose(P, Rt, ref, K, q_out, work):
    """One pose of a :class:`~humanoid_reach_ros.kinematics.general_ik.GeneralLimbIK` chain
    (constants ``K`` = :func:`pack_general`): writes ``q_out`` (6,) (NaN on failure), returns
    ok. ``P`` (3,), ``Rt`` (3, 3) relative to the chain's root, ``ref`` (6,); ``work``: float
    scratch of ``WORK6_SIZE``. For other numba kernels and :func:`general_ik_batch`."""
    return _general_ik_bounded(P, Rt, ref, K, q_out, work, 0.0, np.inf)


@nb.njit(**_JIT)
def _general_ik_bounded(P, Rt, ref, K, q_out, work, dq0_sq, bound):
    """:func:`general_ik_pose`, except that a candidate with ``sqrt(dq0_sq + |q - ref|^2) >
    bound + PRUNE_MARGIN`` is not tried (False if no other is left): the redundant arm's
    subchain, ``dq0_sq`` its first joint's term, ``bound`` the best distance so far."""
    cand = work[W_CAND:W_CAND + 48].reshape((8, 6))
    wrapped = work[W_WRAP:W_WRAP + 48].reshape((8, 6))
    dist = work[W_DIST:W_DIST + 8]
    lo, hi = K[C_LO:C_LO + 6], K[C_HI:C_HI + 6]
    if K[S_REV] > 0.5:   # the reversed chain reaches T^-1 in the joints -q[::-1]
        M = work[W_MAT:W_MAT + 108].reshape((12, 3, 3))
        V = work[W_VEC:W_VEC + 36].reshape((12, 3))
        Rs, Ps, rs = M[11], V[11], work[W_REF:W_REF + 6]
        for i in range(3):
            for j in range(3):
                Rs[i, j] = Rt[j, i]
        for i in range(3):
            Ps[i] = -(Rs[i, 0] * P[0] + Rs[i, 1] * P[1] + Rs[i, 2] * P[2])
        for j in range(6):
            rs[j] = -ref[5 - j]
        any_left = _candidates(Ps, Rs, rs, K, wrapped, work, ref, dq0_sq, bound)
        for k in range(8):
            for j in range(6):
                cand[k, j] = -wrapped[k, 5 - j]
    else:
        any_left = _candidates(P, Rt, ref, K, cand, work, ref, dq0_sq, bound)
    for j in range(6):
        q_out[j] = np.nan
    if not any_left:
        return False
    for k in range(8):
        dist[k] = np.inf
        inside = True
        for j in range(6):
            c = cand[k, j]
            if not np.isfinite(c):
                inside = False
                break
            x = _wrap(c, lo[j])
            if not (x >= lo[j] - LIMIT_TOL and x <= hi[j] + LIMIT_TOL):
                inside = False
                break
            wrapped[k, j] = x
        if inside:
            s = 0.0
            for j in range(6):
                x = wrapped[k, j] - ref[j]
                s += x * x
            dist[k] = math.sqrt(s)
    # the reference's argmin over the candidates that pass the FK check: try them nearest first
    qc = work[W_REF:W_REF + 6]
    for _ in range(8):
        best = -1
        best_d = np.inf
        for k in range(8):
            if dist[k] < best_d:
                best_d = dist[k]
                best = k
        if best < 0 or math.sqrt(dq0_sq + best_d * best_d) > bound + PRUNE_MARGIN:
            return False
        for j in range(6):
            qc[j] = min(max(wrapped[best, j], lo[j]), hi[j])
        if _fk_reaches(K, qc, P, Rt, work):
            for j in range(6):
                q_out[j] = qc[j]
            return True
        dist[best] = np.inf
    return False


@nb.njit(**_JIT)
def general_ik_batch(P, Rt, ref, K, q_out, ok_out):
    """:func:`general_ik_pose` over N poses: ``P`` (N, 3), ``Rt`` (N or 1, 3, 3), ``ref``
    (N or 1, 6); writes ``q_out`` (N, 6), ``ok_out`` (N,)."""
    work = np.empty(WORK6_SIZE)
    for n in range(P.shape[0]):
        ok_out[n] = general_ik_pose(P[n], Rt[n if Rt.shape[0] > 1 else 0], ref[n if ref.shape[0] > 1 else 0],
                                    K, q_out[n], work)


# ---------------------------------------------------------------- 7R
@nb.njit(**_JIT)
def redundant_ik_pose(P, Rt, ref, K6, K7, q_out, work):
    """One pose of a :class:`~humanoid_reach_ros.kinematics.general_ik.RedundantLimbIK` arm
    (``K6`` = :func:`pack_general` of its subchain's solver, ``K7`` = :func:`pack_redundant`):
    writes ``q_out`` (7,) (NaN on failure), returns ok. ``ref`` (7,); ``work``: float scratch
    of ``W7_ORDER + K7[H_NG] + 1``."""
    R0 = K7[H_R0:H_R0 + 9].reshape((3, 3))
    t0, a0, t1, ReTte = K7[H_T0:H_T0 + 3], K7[H_A0:H_A0 + 3], K7[H_T1:H_T1 + 3], K7[H_RETTE:H_RETTE + 3]
    lo0, hi0 = K7[H_LIM], K7[H_LIM + 1]
    use_d, d_min, d_max = K7[H_D] > 0.5, K7[H_D + 1], K7[H_D + 2]
    ng = int(K7[H_NG])
    grid = K7[H_GRID:H_GRID + ng]
    qs = work[W7_Q:W7_Q + 6]
    Ps = work[W7_P:W7_P + 3]
    Rs = work[W7_R:W7_R + 9].reshape((3, 3))
    order = work[W7_ORDER:W7_ORDER + ng + 1]
    M = work[W_MAT:W_MAT + 108].reshape((12, 3, 3))
    V = work[W_VEC:W_VEC + 36].reshape((12, 3))
    for j in range(7):
        q_out[j] = np.nan
    r0 = ref[0]
    # value 0 (the reference's) first, then the grid by distance to it (stable insertion sort)
    order[0] = 0.0
    for k in range(1, ng + 1):
        dk = abs(grid[k - 1] - r0)
        i = k
        while i > 1 and abs(grid[int(order[i - 1]) - 1] - r0) > dk:
            order[i] = order[i - 1]
            i -= 1
        order[i] = k
    # wrist centre in the root frame, for the distance pre-test
    Wc = V[7]
    for i in range(3):
        Wc[i] = (P[i] - (Rt[i, 0] * ReTte[0] + Rt[i, 1] * ReTte[1] + Rt[i, 2] * ReTte[2])) - t0[i]
    best_d = np.inf
    best_k = -1
    Rq, R1 = M[9], M[10]
    x = V[8]
    for o in range(ng + 1):
        k = int(order[o])
        q1 = min(max(r0 if k == 0 else grid[k - 1], lo0), hi0)
        dq = q1 - r0
        if abs(dq) > best_d + PRUNE_MARGIN:
            if k > 0:
                break        # the rest of the grid is farther still
            continue
        _rot(a0, q1, Rq)
        _mm(R0, Rq, R1)
        if use_d:    # the subchain cannot reach the wrist centre from this value
            _mv(R1, t1, x)
            e0, e1, e2 = Wc[0] - x[0], Wc[1] - x[1], Wc[2] - x[2]
            dd = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
            if not (dd >= d_min and dd <= d_max):
                continue
        # the subchain's target: R1^T (P - t0), R1^T Rt
        e0, e1, e2 = P[0] - t0[0], P[1] - t0[1], P[2] - t0[2]
        for i in range(3):
            Ps[i] = R1[0, i] * e0 + R1[1, i] * e1 + R1[2, i] * e2
        _mtm(R1, Rt, Rs)
        if not _general_ik_bounded(Ps, Rs, ref[1:], K6, qs, work, dq * dq, best_d):
            continue
        s = dq * dq
        for j in range(6):
            y = qs[j] - ref[j + 1]
            s += y * y
        dist = math.sqrt(s)
        if dist < best_d or (dist == best_d and k < best_k):
            best_d, best_k = dist, k
            q_out[0] = q1
            for j in range(6):
                q_out[j + 1] = qs[j]
    return best_k >= 0


@nb.njit(**_JIT)
def redundant_ik_batch(P, Rt, ref, K6, K7, q_out, ok_out):
    """:func:`redundant_ik_pose` over N poses: ``P`` (N, 3), ``Rt`` (N or 1, 3, 3), ``ref``
    (N or 1, 7); writes ``q_out`` (N, 7), ``ok_out`` (N,)."""
    work = np.empty(W7_ORDER + int(K7[H_NG]) + 1)
    for n in range(P.shape[0]):
        ok_out[n] = redundant_ik_pose(P[n], Rt[n if Rt.shape[0] > 1 else 0], ref[n if ref.shape[0] > 1 else 0],
                                      K6, K7, q_out[n], work)


# ---------------------------------------------------------------- Python classes
def _rows(a, ndim: int) -> np.ndarray:
    """``a`` as a stack of float rows of ``ndim`` dimensions (a single row gets a leading axis of
    1), C-contiguous and writeable as the kernels are compiled for (a read-only array, e.g. a
    broadcast one, would compile another specialization). The cheap path first: one pose per
    call is the common case."""
    a = np.asarray(a, dtype=np.float64)
    if a.ndim == ndim:
        a = a[None]
    flags = a.flags
    if not (flags.c_contiguous and flags.writeable):
        a = np.array(a, dtype=np.float64, order="C")
    return a


def _one(a, shape: tuple) -> np.ndarray:
    """One pose's argument of ``shape``, C-contiguous and writeable (ValueError for another shape:
    the kernels do not check bounds)."""
    a = np.asarray(a, dtype=np.float64)
    if a.shape != shape:
        raise ValueError(f"expected shape {shape}, got {a.shape}")
    flags = a.flags
    if not (flags.c_contiguous and flags.writeable):
        a = np.array(a, dtype=np.float64, order="C")
    return a


def _inputs(target_p, target_R, ref, n_joints):
    """The reference's input handling: ``P`` (N, 3) sets N; ``Rt`` (N or 1, 3, 3) and ``ref``
    (N or 1, n_joints); ValueError for other shapes (the kernels do not check bounds)."""
    P, Rt, ref = _rows(target_p, 1), _rows(target_R, 2), _rows(ref, 1)
    if Rt.ndim != 3:
        Rt = _rows(Rt.reshape(-1, 3, 3), 2)
    n = len(P)
    if (P.ndim != 2 or P.shape[1] != 3 or Rt.shape[1:] != (3, 3) or ref.ndim != 2 or ref.shape[1] != n_joints
            or len(Rt) not in (1, n) or len(ref) not in (1, n)):
        raise ValueError(f"positions {P.shape}, rotations {Rt.shape} and references {ref.shape} are not "
                         f"(N, 3), (N or 1, 3, 3), (N or 1, {n_joints})")
    return P, Rt, ref, n


class CompiledGeneralLimbIK:
    """:class:`~humanoid_reach_ros.kinematics.general_ik.GeneralLimbIK`'s answers from
    :func:`general_ik_batch`: the same constructor (ValueError for a chain outside the
    class), ``solve`` and attributes (``chain``, ``q_default``, ``reversed``, ``_solver``)."""

    def __init__(self, chain: Chain6, q_default: np.ndarray) -> None:
        self.reference = GeneralLimbIK(chain, q_default)
        self.chain, self.q_default = chain, self.reference.q_default
        self.reversed, self._solver = self.reference.reversed, self.reference._solver
        self.K = pack_general(self.reference)
        self._ref = np.array(self.q_default, dtype=np.float64).reshape(1, 6)
        self._work = np.empty(WORK6_SIZE)     # solve_one's scratch (the kernels hold the GIL: nogil=False)

    def solve(self, target_p: np.ndarray, target_R: np.ndarray, q_ref: np.ndarray | None = None) -> GeneralIKResult:
        """Joints for tip poses relative to the chain's root: ``target_p`` (N, 3), ``target_R`` (N, 3, 3)."""
        P, Rt, ref, n = _inputs(target_p, target_R, self._ref if q_ref is None else q_ref, 6)
        q, ok = np.empty((n, 6)), np.empty(n, dtype=np.bool_)
        general_ik_batch(P, Rt, ref, self.K, q, ok)
        return GeneralIKResult(q, ok)

    def solve_one(self, target_p: np.ndarray, target_R: np.ndarray,
                  q_ref: np.ndarray | None = None) -> tuple[bool, np.ndarray]:
        """One pose, the cheapest call (as ``reach/fast_arms.CompiledArmIK.solve``): ``(ok, q)``
        with ``q`` (6,) a new array, NaN when not ok. ``target_p`` (3,), ``target_R`` (3, 3)."""
        P, Rt, ref = _one(target_p, (3,)), _one(target_R, (3, 3)), self._ref[0] if q_ref is None else _one(q_ref, (6,))
        q = np.empty(6)
        return bool(general_ik_pose(P, Rt, ref, self.K, q, self._work)), q


class CompiledRedundantLimbIK:
    """:class:`~humanoid_reach_ros.kinematics.general_ik.RedundantLimbIK`'s answers from
    :func:`redundant_ik_batch`: the same constructor, ``solve`` and attributes (``chain``,
    ``q_default``, ``samples``, ``sub`` -- a :class:`CompiledGeneralLimbIK` with ``reversed``
    and ``_solver``)."""

    def __init__(self, chain: Chain6, q_default: np.ndarray, samples: int = 16) -> None:
        self.reference = RedundantLimbIK(chain, q_default, samples)
        self.chain, self.q_default, self.samples = chain, self.reference.q_default, self.reference.samples
        self.sub = CompiledGeneralLimbIK(self.reference.sub.chain, self.reference.sub.q_default)
        self._d_range = self.reference._d_range
        self.K6, self.K7 = self.sub.K, pack_redundant(self.reference)
        self._ref = np.array(self.q_default, dtype=np.float64).reshape(1, 7)
        self._work = np.empty(W7_ORDER + int(self.K7[H_NG]) + 1)

    def solve(self, target_p: np.ndarray, target_R: np.ndarray, q_ref: np.ndarray | None = None) -> GeneralIKResult:
        """Per pose, the solution nearest ``q_ref`` over the first-joint values (RedundantLimbIK.solve)."""
        P, Rt, ref, n = _inputs(target_p, target_R, self._ref if q_ref is None else q_ref, 7)
        q, ok = np.empty((n, 7)), np.empty(n, dtype=np.bool_)
        redundant_ik_batch(P, Rt, ref, self.K6, self.K7, q, ok)
        return GeneralIKResult(q, ok)

    def solve_one(self, target_p: np.ndarray, target_R: np.ndarray,
                  q_ref: np.ndarray | None = None) -> tuple[bool, np.ndarray]:
        """One pose, the cheapest call: ``(ok, q)`` with ``q`` (7,) a new array, NaN when not ok."""
        P, Rt, ref = _one(target_p, (3,)), _one(target_R, (3, 3)), self._ref[0] if q_ref is None else _one(q_ref, (7,))
        q = np.empty(7)
        return bool(redundant_ik_pose(P, Rt, ref, self.K6, self.K7, q, self._work)), q


def compiled_general_ik(chain: Chain6, q_default: np.ndarray, samples: int = 16):
    """The compiled twin for a chain of 6 joints (:class:`CompiledGeneralLimbIK`) or 7
    (:class:`CompiledRedundantLimbIK`, ``samples`` first-joint values), as GeneralLimb picks."""
    if len(chain.axes) == 7:
        return CompiledRedundantLimbIK(chain, q_default, samples)
    return CompiledGeneralLimbIK(chain, q_default)


def warm_up() -> None:
    """Compile (or load from the numba cache) the 6R and 7R kernels on one pose of a tiny
    chain (two 0.3 m links, shoulder 1-2, spherical wrist 4-5-6; a yaw joint before it)."""
    ax = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0],
                   [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    t = np.zeros((7, 3))
    t[1], t[3], t[4] = [0.0, 0.0, 0.1], [0.0, 0.0, -0.3], [0.0, 0.0, -0.3]
    arm = Chain6(np.broadcast_to(np.eye(3), (7, 3, 3)).copy(), t, ax, np.eye(3), np.zeros(3),
                 np.full(7, -2.5), np.full(7, 2.5))
    ik7 = CompiledRedundantLimbIK(arm, np.full(7, 0.3), samples=4)
    q = np.full((1, 7), 0.3)
    p, R = arm.fk(q)
    ik7.solve(p, R)
    ik7.solve_one(p[0], R[0])
    p6, R6 = ik7.sub.chain.fk(q[:, 1:])
    ik7.sub.solve(p6, R6)
    ik7.sub.solve_one(p6[0], R6[0])


__all__ = ["CompiledGeneralLimbIK", "CompiledRedundantLimbIK", "compiled_general_ik", "general_ik_pose",
           "general_ik_batch", "redundant_ik_pose", "redundant_ik_batch", "pack_general", "pack_redundant",
           "warm_up", "WORK6_SIZE", "W7_ORDER"]
