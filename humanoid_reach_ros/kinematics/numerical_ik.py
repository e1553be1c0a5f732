"""Numerical IK of any 6R or 7R chain (issue 23: the Unitree G1's limbs, which neither the
hand-derived patterns of ``kinematics/hand_derived.py`` nor the general closed form of
``kinematics/general_ik.py`` solve): damped least squares on the 6-D pose error, compiled with
numba, one pose per kernel call, no allocation per iteration.

Simplification, named: this is a LOCAL method with restarts. It converges to a solution
near its start; when none of its starts leads to one it reports the pose unreachable, so it
can miss a solution the closed forms would find (for a 6R chain, a solution branch no start
leads to; near a singular configuration or a joint limit, a solution the iteration does not
reach from the starts tried). Where it answers, the answer is exact like the closed forms':
the tip reaches the pose within ``FK_TOL`` (in practice to 1e-12, after the Newton polish)
and every joint is within its limits.

Method, per start (the chain form of :class:`~humanoid_reach_ros.kinematics.general_ik.Chain6`,
``T(q) = M1 R(a1, q1) ... Mn R(an, qn) Me``):

* error ``e = (p* - p(q), log(R* R(q)^T))`` in the root frame (position [m], rotation
  vector [rad]); geometric Jacobian ``J`` (6, n) from the joint axes ``w_k`` and origins
  ``o_k``: ``(w_k x (p - o_k), w_k)``;
* Levenberg-Marquardt step ``dq = J^T (J J^T + lambda I)^-1 e`` -- for a 7R chain the
  damped minimal-norm step (the answer stays near the start), for a 6R chain the same
  expression equals ``(J^T J + lambda I)^-1 J^T e``; adaptive damping ``lambda = mu (|e|^2 +
  LAMBDA_FLOOR)``, ``mu`` halved after a step that lowers ``|e|`` and multiplied by 4 (the
  step rejected) after one that does not;
* the joint limits kept by projection: each step is clamped into the limits, and a joint
  at a limit that the step would take out of it drops out of the step (its Jacobian
  column zeroed, the step recomputed: an active set, rebuilt at every iteration);
* the start is given up early when ``|e|`` has not fallen below ``STALL_FACTOR`` times its
  value ``STALL_ITERS`` iterations before, when ``mu`` exceeds ``MU_MAX`` or after
  ``MAX_ITERS`` (the tunables are packed into the constants, ``params``);
* below ``POLISH_ERR`` undamped Newton steps (``lambda`` = 0; a light damping where the
  system is singular) polish the answer to ``POLISH_TOL``.

Starts: ``q_ref`` clipped into the limits first -- if it converges, its answer is returned
(the tracking case: a reference next to the answer costs a few iterations); otherwise
``q_default`` and a fixed set of ``n_starts`` deterministic quasi-random starts inside the
limits (a scrambled Halton sequence with a fixed seed, drawn once in ``__init__``) are all
run and the converged answer nearest ``q_ref`` is returned.

No ROS here.
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

from humanoid_reach_ros.kinematics.general_ik import FK_TOL, Chain6, GeneralIKResult
from humanoid_reach_ros.kinematics.general_ik_compiled import _mm, _one, _rot, _rows

#: numba options of the house (general_ik_compiled.py): nogil=False, see geometry/distance.py
_JIT = dict(cache=True, nogil=False, fastmath=False)

MAX_ITERS = 100          # iterations per start at most
STALL_ITERS = 8          # a start is given up when |e| has not fallen ...
STALL_FACTOR = 0.5       # ... below this fraction of its value STALL_ITERS iterations before
MU0 = 0.1                # initial damping multiplier
MU_MIN = 1e-6
MU_MAX = 1e8             # a start whose steps keep failing at this damping is given up
LAMBDA_FLOOR = 1e-6      # lambda = mu (|e|^2 + LAMBDA_FLOOR)
POLISH_ERR = 1e-5        # below this |e| the undamped Newton polish takes over
POLISH_TOL = 1e-12       # the polish stops below this |e|
POLISH_ITERS = 8
STEP_MAX = 0.5           # a step's largest joint change [rad] (a far-off start does not jump wildly)
N_STARTS = 16            # quasi-random starts besides q_ref and q_default
SEED = 23                # their fixed seed

#: the tracking iteration's weighted least norm (_active_step): a joint within this of a limit [rad] slows
#: down towards it, its mobility floored at MOBILITY_MIN. 0.4: on the G1's Table 2 (9 x 9 pairs) 0.2 left
#: 5 pairs whose elbow (full bend) or wrist pitch (+-92 deg) still reached its limit, a one-step kink
#: (600-1200 rad/s^2, the ZMP up to 8 cm out of the feet); 0.4 kept all 5 balanced (ZMP margin 6.6 cm)
TRACK_LIMIT_MARGIN = 0.4
MOBILITY_MIN = 1e-3

HIST_MAX = 16            # the stall ring's size (STALL_ITERS at most)
#: the tunables, as packed into K[2:8] (the kernels read them there)
PARAMS = (MAX_ITERS, STALL_ITERS, STALL_FACTOR, MU0, LAMBDA_FLOOR, STEP_MAX)

# packed constants K: [n, n_starts, the PARAMS (6), R (n, 3, 3), t (n, 3), axes (n, 3), Re (3, 3), te (3,), lower (n,),
# upper (n,), q_default (n,), starts (n_starts, n)] -- offsets from n (_offsets)


def _pack(chain: Chain6, q_default: np.ndarray, starts: np.ndarray, params=PARAMS) -> np.ndarray:
    n = len(chain.axes)
    if not 1 <= params[1] <= HIST_MAX:
        raise ValueError(f"stall iterations in [1, {HIST_MAX}], got {params[1]}")
    return np.concatenate([[float(n), float(len(starts))], np.asarray(params, float), chain.R.ravel(),
                           chain.t.ravel(), chain.axes.ravel(), chain.Re.ravel(), chain.te.ravel(), chain.lower,
                           chain.upper, q_default, starts.ravel()]).astype(np.float64)


@nb.njit(**_JIT)
def work_size(n):
    """Float scratch of one :func:`numerical_ik_pose` call for an ``n``-joint chain: the
    iteration's (qn, dq, free, J, Org, W, Orgn, Wn, A, L, e, en, y, M, R, Rn, Me, p, pn, the stall
    history) and the start and reference (2 n)."""
    return 3 * n + 6 * n + 12 * n + 72 + 18 + 27 + 27 + 6 + HIST_MAX + 2 * n


@nb.njit(**_JIT)
def _offsets(n):
    o_R = 8
    o_t = o_R + 9 * n
    o_a = o_t + 3 * n
    o_Re = o_a + 3 * n
    o_te = o_Re + 9
    o_lo = o_te + 3
    o_hi = o_lo + n
    o_qd = o_hi + n
    o_st = o_qd + n
    return o_R, o_t, o_a, o_Re, o_te, o_lo, o_hi, o_qd, o_st


@nb.njit(**_JIT)
def _fk(K, n, q, Org, W, p, R, M):
    """Tip position ``p`` (3,) and rotation ``R`` (3, 3) of joints ``q``, and in ``Org`` / ``W``
    (n, 3) each joint's origin and axis in the root frame. ``M`` (3, 3, 3) scratch."""
    o_R, o_t, o_a, o_Re, o_te, _, _, _, _ = _offsets(n)
    Rc, T, Rq = M[0], M[1], M[2]
    for i in range(3):
        p[i] = 0.0
        for j in range(3):
            Rc[i, j] = 1.0 if i == j else 0.0
    for k in range(n):
        t = K[o_t + 3 * k:o_t + 3 * k + 3]
        Mk = K[o_R + 9 * k:o_R + 9 * k + 9].reshape((3, 3))
        a = K[o_a + 3 * k:o_a + 3 * k + 3]
        for i in range(3):
            p[i] += Rc[i, 0] * t[0] + Rc[i, 1] * t[1] + Rc[i, 2] * t[2]
        _mm(Rc, Mk, T)
        for i in range(3):
            Org[k, i] = p[i]
            W[k, i] = T[i, 0] * a[0] + T[i, 1] * a[1] + T[i, 2] * a[2]
        _rot(a, q[k], Rq)
        _mm(T, Rq, Rc)
    te = K[o_te:o_te + 3]
    Re = K[o_Re:o_Re + 9].reshape((3, 3))
    for i in range(3):
        p[i] += Rc[i, 0] * te[0] + Rc[i, 1] * te[1] + Rc[i, 2] * te[2]
    _mm(Rc, Re, R)


@nb.njit(**_JIT)
def _error(P, Rt, p, R, e, M):
    """``e`` (6,) = (P - p, log(Rt R^T)); returns |e|. ``M`` (3, 3) scratch."""
    for i in range(3):
        e[i] = P[i] - p[i]
    for i in range(3):       # M = Rt R^T
        for j in range(3):
            M[i, j] = Rt[i, 0] * R[j, 0] + Rt[i, 1] * R[j, 1] + Rt[i, 2] * R[j, 2]
    sx, sy, sz = (M[2, 1] - M[1, 2]) / 2, (M[0, 2] - M[2, 0]) / 2, (M[1, 0] - M[0, 1]) / 2
    s = math.sqrt(sx * sx + sy * sy + sz * sz)
    c = (M[0, 0] + M[1, 1] + M[2, 2] - 1.0) / 2
    th = math.atan2(s, c)
    if s > 1e-7 or c > 0.0:
        f = th / s if s > 1e-12 else 1.0 + th * th / 6.0
        e[3], e[4], e[5] = f * sx, f * sy, f * sz
    else:    # th near pi: the axis from the symmetric part (its sign is free there)
        ax = math.sqrt(max((M[0, 0] - c) / (1.0 - c), 0.0))
        ay = math.sqrt(max((M[1, 1] - c) / (1.0 - c), 0.0))
        az = math.sqrt(max((M[2, 2] - c) / (1.0 - c), 0.0))
        if ax >= ay and ax >= az:
            ay = math.copysign(ay, M[0, 1] + M[1, 0])
            az = math.copysign(az, M[0, 2] + M[2, 0])
        elif ay >= az:
            ax = math.copysign(ax, M[0, 1] + M[1, 0])
            az = math.copysign(az, M[1, 2] + M[2, 1])
        else:
            ax = math.copysign(ax, M[0, 2] + M[2, 0])
            ay = math.copysign(ay, M[1, 2] + M[2, 1])
        e[3], e[4], e[5] = th * ax, th * ay, th * az
    r = 0.0
    for i in range(6):
        r += e[i] * e[i]
    return math.sqrt(r)


@nb.njit(**_JIT)
def _step(n, J, free, e, lam, A, L, y, dq):
    """``dq = M J^T (J M J^T + lam I)^-1 e`` with ``M = diag(free)`` the joints' mobilities:
    0 (a joint out of the step) or 1 (free) in the solver's iteration -- the step of the
    free joints' columns --, between them in the tracking iteration's weighted least norm
    (:func:`_active_step`). Cholesky on 6 x 6; False when the system is not positive definite
    (lam = 0, singular)."""
    for i in range(6):
        for j in range(i + 1):
            s = 0.0
            for k in range(n):
                if free[k] > 0.0:
                    s += free[k] * J[i, k] * J[j, k]
            A[i, j] = s
        A[i, i] += lam
    for i in range(6):           # A = L L^T
        for j in range(i + 1):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            if i == j:
                if not s > 1e-30:
                    return False
                L[i, i] = math.sqrt(s)
            else:
                L[i, j] = s / L[j, j]
    for i in range(6):           # L z = e
        s = e[i]
        for k in range(i):
            s -= L[i, k] * y[k]
        y[i] = s / L[i, i]
    for i in range(5, -1, -1):   # L^T y = z
        s = y[i]
        for k in range(i + 1, 6):
            s -= L[k, i] * y[k]
        y[i] = s / L[i, i]
    for k in range(n):
        s = 0.0
        if free[k] > 0.0:
            for i in range(6):
                s += J[i, k] * y[i]
            s *= free[k]
        dq[k] = s
    return True


@nb.njit(**_JIT)
def _jacobian(n, Org, W, p, J):
    for k in range(n):
        dx, dy, dz = p[0] - Org[k, 0], p[1] - Org[k, 1], p[2] - Org[k, 2]
        wx, wy, wz = W[k, 0], W[k, 1], W[k, 2]
        J[0, k] = wy * dz - wz * dy
        J[1, k] = wz * dx - wx * dz
        J[2, k] = wx * dy - wy * dx
        J[3, k], J[4, k], J[5, k] = wx, wy, wz


@nb.njit(**_JIT)
def _active_step(n, J, e, q, lo, hi, lam, free, A, L, y, dq, margin):
    """The step of :func:`_step` with the joint limits as an active set: a joint at a limit
    whose step would leave the limits drops out (its Jacobian column) and the step is
    recomputed, until no such joint is left; False when a system is singular.

    ``margin`` > 0 (the tracking iteration): a weighted least-norm step in the manner of Chan and
    Dubey (1995), simplified (named): a joint within ``margin`` [rad] of a limit has mobility
    ``max(d / margin, MOBILITY_MIN)`` (``d`` its distance to the nearer limit) while its step
    goes towards that limit, 1 when it goes away. A redundant chain's self-motion then slows a
    joint down continuously as it nears a limit, where the active set alone stops it dead in one
    step and swings the others (an unbounded acceleration). A square chain (6 joints) reaches the
    same solution either way (``M`` drops out of ``J^-1``). ``margin`` = 0: the plain active set."""
    for k in range(n):
        free[k] = 1.0
        if margin > 0.0:
            d = min(q[k] - lo[k], hi[k] - q[k])
            if d < margin:
                free[k] = max(d / margin, MOBILITY_MIN)
    for _ in range(2 * n + 1):
        if not _step(n, J, free, e, lam, A, L, y, dq):
            return False
        changed = False
        for k in range(n):
            if free[k] > 0.0 and ((q[k] <= lo[k] and dq[k] < 0.0) or (q[k] >= hi[k] and dq[k] > 0.0)):
                free[k] = 0.0
                changed = True
            elif 0.0 < free[k] < 1.0 and ((q[k] - lo[k] <= hi[k] - q[k]) == (dq[k] > 0.0)):
                free[k] = 1.0          # going away from the nearer limit: full mobility
                changed = True
        if not changed:
            return True
    return True


@nb.njit(**_JIT)
def _accept(n, errn, q, qn, p, pn, R, Rn, e, en, Org, Orgn, W, Wn):
    """The trial state becomes the current one; returns its |e|."""
    for k in range(n):
        q[k] = qn[k]
        for i in range(3):
            Org[k, i] = Orgn[k, i]
            W[k, i] = Wn[k, i]
    for i in range(3):
        p[i] = pn[i]
        for j in range(3):
            R[i, j] = Rn[i, j]
    for i in range(6):
        e[i] = en[i]
    return errn


@nb.njit(**_JIT)
def _converge(P, Rt, K, n, q, work, margin):
    """Run the iteration from ``q`` (n,) (inside the limits; updated in place); returns the
    final |e| (inf when given up). ``margin``: :func:`_active_step`'s (0: the plain active set)."""
    _, _, _, _, _, o_lo, o_hi, _, _ = _offsets(n)
    lo, hi = K[o_lo:o_lo + n], K[o_hi:o_hi + n]
    o = 0
    qn = work[o:o + n]
    o += n
    dq = work[o:o + n]
    o += n
    free = work[o:o + n]
    o += n
    J = work[o:o + 6 * n].reshape((6, n))
    o += 6 * n
    Org = work[o:o + 3 * n].reshape((n, 3))
    o += 3 * n
    W = work[o:o + 3 * n].reshape((n, 3))
    o += 3 * n
    Orgn = work[o:o + 3 * n].reshape((n, 3))
    o += 3 * n
    Wn = work[o:o + 3 * n].reshape((n, 3))
    o += 3 * n
    A = work[o:o + 36].reshape((6, 6))
    o += 36
    L = work[o:o + 36].reshape((6, 6))
    o += 36
    e = work[o:o + 6]
    o += 6
    en = work[o:o + 6]
    o += 6
    y = work[o:o + 6]
    o += 6
    M = work[o:o + 27].reshape((3, 3, 3))
    o += 27
    R = work[o:o + 9].reshape((3, 3))
    o += 9
    Rn = work[o:o + 9].reshape((3, 3))
    o += 9
    Me = work[o:o + 9].reshape((3, 3))
    o += 9
    p = work[o:o + 3]
    o += 3
    pn = work[o:o + 3]
    o += 3
    hist = work[o:o + HIST_MAX]     # |e| of the last ``stall`` iterations (a ring)
    max_iters, stall, stall_factor = int(K[2]), int(K[3]), K[4]
    mu0, floor, step_max = K[5], K[6], K[7]
    _fk(K, n, q, Org, W, p, R, M)
    err = _error(P, Rt, p, R, e, Me)
    mu = mu0
    it = 0
    while err > POLISH_ERR:
        if it >= max_iters:
            return np.inf
        if it >= stall and err > stall_factor * hist[it % stall]:
            return np.inf
        hist[it % stall] = err
        it += 1
        _jacobian(n, Org, W, p, J)
        while True:
            lam = mu * (err * err + floor)
            _active_step(n, J, e, q, lo, hi, lam, free, A, L, y, dq, margin)
            big = 0.0
            for k in range(n):
                big = max(big, abs(dq[k]))
            sc = step_max / big if big > step_max else 1.0
            for k in range(n):
                qn[k] = min(max(q[k] + sc * dq[k], lo[k]), hi[k])
            _fk(K, n, qn, Orgn, Wn, pn, Rn, M)
            errn = _error(P, Rt, pn, Rn, en, Me)
            if errn < err:
                break
            mu *= 4.0
            if mu > MU_MAX:
                return np.inf
        mu = max(mu * 0.5, MU_MIN)
        err = _accept(n, errn, q, qn, p, pn, R, Rn, e, en, Org, Orgn, W, Wn)
    # undamped Newton polish
    for _ in range(POLISH_ITERS):
        if err < POLISH_TOL:
            break
        _jacobian(n, Org, W, p, J)
        if not _active_step(n, J, e, q, lo, hi, 0.0, free, A, L, y, dq, margin):
            _active_step(n, J, e, q, lo, hi, 1e-3 * (err * err + floor), free, A, L, y, dq, margin)
        for k in range(n):
            qn[k] = min(max(q[k] + dq[k], lo[k]), hi[k])
        _fk(K, n, qn, Orgn, Wn, pn, Rn, M)
        errn = _error(P, Rt, pn, Rn, en, Me)
        if not errn < err:
            break
        err = _accept(n, errn, q, qn, p, pn, R, Rn, e, en, Org, Orgn, W, Wn)
    return err


@nb.njit(**_JIT)
def _reaches(P, Rt, K, n, q, work):
    """The closed forms' check (general_ik._select): |p - P| < FK_TOL and |R - Rt|_F < FK_TOL."""
    Org = work[0:3 * n].reshape((n, 3))
    W = work[3 * n:6 * n].reshape((n, 3))
    M = work[6 * n:6 * n + 36].reshape((4, 3, 3))
    p = work[6 * n + 36:6 * n + 39]
    R = M[3]
    _fk(K, n, q, Org, W, p, R, M[:3])
    s = 0.0
    for i in range(3):
        s += (p[i] - P[i]) ** 2
    if not math.sqrt(s) < FK_TOL:
        return False
    s = 0.0
    for i in range(3):
        for j in range(3):
            s += (R[i, j] - Rt[i, j]) ** 2
    return math.sqrt(s) < FK_TOL


@nb.njit(**_JIT)
def numerical_ik_pose(P, Rt, ref, K, q_out, work):
    """One pose (module doc): ``P`` (3,), ``Rt`` (3, 3) relative to the chain's root, ``ref``
    (n,); constants ``K`` (NumericalLimbIK.K); writes ``q_out`` (n,) (NaN when not ok),
    returns ok. ``work``: float scratch of :func:`work_size`."""
    n = int(K[0])
    ns = int(K[1])
    _, _, _, _, _, o_lo, o_hi, o_qd, o_st = _offsets(n)
    lo, hi = K[o_lo:o_lo + n], K[o_hi:o_hi + n]
    for k in range(n):
        q_out[k] = np.nan
    for i in range(3):
        if not np.isfinite(P[i]):
            return False
        for j in range(3):
            if not np.isfinite(Rt[i, j]):
                return False
    base = work.shape[0] - 2 * n
    q = work[base:base + n]
    r = work[base + n:base + 2 * n]
    inner = work[:base]
    for k in range(n):
        r[k] = min(max(ref[k], lo[k]), hi[k]) if np.isfinite(ref[k]) else K[o_qd + k]
    best = np.inf
    for s in range(ns + 2):
        for k in range(n):
            if s == 0:
                q[k] = r[k]
            elif s == 1:
                q[k] = K[o_qd + k]
            else:
                q[k] = K[o_st + (s - 2) * n + k]
        if s == 1:       # q_default: skip when it is the reference's start
            same = True
            for k in range(n):
                if q[k] != r[k]:
                    same = False
                    break
            if same:
                continue
        err = _converge(P, Rt, K, n, q, inner, 0.0)
        if not err < POLISH_ERR:
            continue
        if not _reaches(P, Rt, K, n, q, inner):
            continue
        d = 0.0
        for k in range(n):
            d += (q[k] - r[k]) ** 2
        if d < best:
            best = d
            for k in range(n):
                q_out[k] = q[k]
        if s == 0:
            return True
    return best < np.inf


@nb.njit(**_JIT)
def numerical_ik_track(P, Rt, ref, K, q_out, work, margin=TRACK_LIMIT_MARGIN):
    """The tracking case of :func:`numerical_ik_pose`: the iteration from ``ref`` (clipped into
    the limits) only -- no ``q_default``, no quasi-random starts -- so the answer is the
    solution the damped steps reach from the previous control step's angles (continuous along
    a motion; for a 7-joint chain the self-motion follows the damped least-norm steps, weighted
    away from the joint limits within ``margin`` [rad]: :func:`_active_step`).
    Writes ``q_out`` (n,) (NaN when not ok), returns ok. ``work``: :func:`work_size` floats."""
    n = int(K[0])
    _, _, _, _, _, o_lo, o_hi, o_qd, _ = _offsets(n)
    for k in range(n):
        q_out[k] = np.nan
    for i in range(3):
        if not np.isfinite(P[i]):
            return False
        for j in range(3):
            if not np.isfinite(Rt[i, j]):
                return False
    base = work.shape[0] - 2 * n
    q = work[base:base + n]
    inner = work[:base]
    for k in range(n):
        q[k] = min(max(ref[k], K[o_lo + k]), K[o_hi + k]) if np.isfinite(ref[k]) else K[o_qd + k]
    err = _converge(P, Rt, K, n, q, inner, margin)
    if not err < POLISH_ERR or not _reaches(P, Rt, K, n, q, inner):
        return False
    for k in range(n):
        q_out[k] = q[k]
    return True


@nb.njit(**_JIT)
def numerical_track_world(root_p, root_R, tip_p, tip_R, ref, K, q_out, work):
    """:func:`numerical_ik_track` on world poses: the root link at ``(root_p, root_R)``, the
    tip at ``(tip_p, tip_R)``; one call per limb and control step (``NumericalLimbTracker``).
    Returns an ``IKReason`` code: 0 OK, 1 UNREACHABLE, 3 INVALID_INPUT (a non-finite value)."""
    n = int(K[0])
    for k in range(n):
        q_out[k] = np.nan
        if not np.isfinite(ref[k]):
            return 3
    for i in range(3):
        if not (np.isfinite(root_p[i]) and np.isfinite(tip_p[i])):
            return 3
        for j in range(3):
            if not (np.isfinite(root_R[i, j]) and np.isfinite(tip_R[i, j])):
                return 3
    P = np.empty(3)
    Rt = np.empty((3, 3))
    for i in range(3):
        P[i] = (root_R[0, i] * (tip_p[0] - root_p[0]) + root_R[1, i] * (tip_p[1] - root_p[1])
                + root_R[2, i] * (tip_p[2] - root_p[2]))
        for j in range(3):
            Rt[i, j] = root_R[0, i] * tip_R[0, j] + root_R[1, i] * tip_R[1, j] + root_R[2, i] * tip_R[2, j]
    return 0 if numerical_ik_track(P, Rt, ref, K, q_out, work) else 1


def numerical_leg_constants(chain: Chain6, q_default: np.ndarray) -> np.ndarray:
    """The packed constants of :func:`numerical_ik_track` for ``chain`` (no quasi-random
    starts: the tracking iteration starts from the reference only); for kernels that solve a
    limb inside their own loop (the dual-arm method's compiled lower body)."""
    n = len(chain.axes)
    if n not in (6, 7):
        raise ValueError(f"a 6- or 7-joint chain, got {n}")
    return _pack(chain, np.clip(np.asarray(q_default, float), chain.lower, chain.upper), np.zeros((0, n)))


class NumericalLimbTracker:
    """Control-step IK of a limb of the numerical kind (the G1's 6- and 7-joint limbs): one
    compiled call of :func:`numerical_track_world` from the previous step's angles.

    **Simplification, named:** a local step; where the damped iteration from the previous
    angles does not reach the pose the limb is reported unreachable (the dual-arm controller
    then holds, or its path check refuses the pair) rather than restarted elsewhere, which
    would be a jump. A 7-joint limb's self-motion is the one the damped least-norm steps give,
    weighted away from the joint limits within ``TRACK_LIMIT_MARGIN`` (a simplified weighted
    least norm of Chan and Dubey: :func:`_active_step`; no optimisation of the self-motion
    beyond that, unlike ``RedundantArmTracker``'s cost over a window); the joint limits are kept
    by the iteration's active set."""

    def __init__(self, limb) -> None:
        if getattr(limb, "kind", "") != "numerical" or not isinstance(getattr(limb, "ik", None), NumericalLimbIK):
            raise ValueError(f"{getattr(limb, 'limb_name', limb)!r}: NumericalLimbTracker needs a limb of the "
                             "numerical kind (kinematics/general_limb.py)")
        self.limb = limb
        self.n_joints = limb.n_joints
        self.K = limb.ik.K
        self._work = np.empty(work_size(self.n_joints))

    def solve(self, root_p, root_R, tip_p, tip_R, q_prev) -> tuple[int, np.ndarray]:
        """``(reason, q)``: ``IKReason`` code (0 = OK; INVALID_INPUT for a non-finite value;
        UNREACHABLE where the iteration from ``q_prev`` does not reach the pose) and the (n,)
        angles (NaN on failure). ``ValueError`` on wrong shapes."""
        n = self.n_joints
        a = [np.ascontiguousarray(x, dtype=np.float64) for x in (root_p, root_R, tip_p, tip_R, q_prev)]
        if (a[0].shape, a[1].shape, a[2].shape, a[3].shape, a[4].shape) != ((3,), (3, 3), (3,), (3, 3), (n,)):
            raise ValueError(f"{self.limb.limb_name}: root / tip poses (3,), (3, 3) and q_prev ({n},) expected, got "
                             f"{[x.shape for x in a]}")
        q = np.empty(n)
        return int(numerical_track_world(a[0], a[1], a[2], a[3], a[4], self.K, q, self._work)), q


@nb.njit(**_JIT)
def numerical_ik_batch(P, Rt, ref, K, q_out, ok_out):
    """:func:`numerical_ik_pose` over N poses: ``P`` (N, 3), ``Rt`` (N or 1, 3, 3), ``ref``
    (N or 1, n); writes ``q_out`` (N, n), ``ok_out`` (N,)."""
    n = int(K[0])
    work = np.empty(work_size(n))
    for i in range(P.shape[0]):
        ok_out[i] = numerical_ik_pose(P[i], Rt[i if Rt.shape[0] > 1 else 0], ref[i if ref.shape[0] > 1 else 0],
                                      K, q_out[i], work)


@nb.njit(**_JIT)
def numerical_ik_world_batch(root_p, root_R, tip_p, tip_R, ref, K, q_out, ok_out, reason_out):
    """:func:`numerical_ik_pose` over N world poses in one call (``GeneralLimb.solve`` of the
    numerical kind, without its numpy passes: the G1's legs are solved ~10^4 times a plan, a few
    rows a call): the root link at ``root_p`` (N or 1, 3), ``root_R`` (N or 1, 3, 3), the tip at
    ``tip_p`` (N or 1, 3), ``tip_R`` (N or 1, 3, 3), ``ref`` (N or 1, n); the tip relative to the
    root ``P = root_R^T (tip_p - root_p)``, ``Rt = root_R^T tip_R``. Writes ``q_out`` (N, n)
    (NaN when not ok), ``ok_out`` (N,) and ``reason_out`` (N,) (``IKReason``: 0 OK,
    1 UNREACHABLE, 3 INVALID_INPUT where a pose is not finite)."""
    n = int(K[0])
    work = np.empty(work_size(n))
    P = np.empty(3)
    Rt = np.empty((3, 3))
    for r in range(q_out.shape[0]):
        rp = root_p[r if root_p.shape[0] > 1 else 0]
        rR = root_R[r if root_R.shape[0] > 1 else 0]
        tp = tip_p[r if tip_p.shape[0] > 1 else 0]
        tR = tip_R[r if tip_R.shape[0] > 1 else 0]
        finite = True
        for i in range(3):
            P[i] = rR[0, i] * (tp[0] - rp[0]) + rR[1, i] * (tp[1] - rp[1]) + rR[2, i] * (tp[2] - rp[2])
            if not np.isfinite(P[i]):
                finite = False
            for j in range(3):
                Rt[i, j] = rR[0, i] * tR[0, j] + rR[1, i] * tR[1, j] + rR[2, i] * tR[2, j]
                if not np.isfinite(Rt[i, j]):
                    finite = False
        if not finite:
            for k in range(n):
                q_out[r, k] = np.nan
            ok_out[r] = False
            reason_out[r] = 3
            continue
        ok_out[r] = numerical_ik_pose(P, Rt, ref[r if ref.shape[0] > 1 else 0], K, q_out[r], work)
        reason_out[r] = 0 if ok_out[r] else 1


def quasi_random_starts(lower: np.ndarray, upper: np.ndarray, count: int = N_STARTS, seed: int = SEED) -> np.ndarray:
    """``count`` deterministic starts inside the limits: a scrambled Halton sequence (fixed
    ``seed``) over the middle 90 % of each joint's range."""
    from scipy.stats import qmc

    u = qmc.Halton(d=len(lower), scramble=True, seed=seed).random(count)   # (the middle: measured best of 80-100 %)
    return lower + (upper - lower) * (0.05 + 0.9 * u)


class NumericalLimbIK:
    """Numerical IK of a :class:`~humanoid_reach_ros.kinematics.general_ik.Chain6` of 6 or 7
    revolute joints (module doc: a local method with restarts), with the compiled closed
    forms' API: ``solve(target_p (N, 3), target_R (N, 3, 3), q_ref=None) -> GeneralIKResult``
    (q within the limits, ok where the FK reaches the pose within FK_TOL) and ``solve_one``.
    ``q_default`` (n,): the reference when none is given (and the second start)."""

    def __init__(self, chain: Chain6, q_default: np.ndarray, n_starts: int = N_STARTS, seed: int = SEED,
                 params: tuple = PARAMS) -> None:
        n = len(chain.axes)
        if n not in (6, 7):
            raise ValueError(f"NumericalLimbIK: a 6- or 7-joint chain, got {n}")
        self.chain = chain
        self.n_joints = n
        self.q_default = np.clip(np.asarray(q_default, float), chain.lower, chain.upper)
        self.starts = quasi_random_starts(chain.lower, chain.upper, n_starts, seed)
        self.K = _pack(chain, self.q_default, self.starts, params)
        self._ref = np.array(self.q_default, dtype=np.float64).reshape(1, n)
        self._work = np.empty(work_size(n))

    def solve(self, target_p: np.ndarray, target_R: np.ndarray, q_ref: np.ndarray | None = None) -> GeneralIKResult:
        """Joints for tip poses relative to the chain's root: ``target_p`` (N, 3), ``target_R``
        (N or 1, 3, 3), ``q_ref`` (N or 1, n) or None (``q_default``)."""
        n = self.n_joints
        P, Rt, ref = _rows(target_p, 1), _rows(target_R, 2), _rows(self._ref if q_ref is None else q_ref, 1)
        if Rt.ndim != 3:
            Rt = _rows(Rt.reshape(-1, 3, 3), 2)
        N = len(P)
        if (P.ndim != 2 or P.shape[1] != 3 or Rt.shape[1:] != (3, 3) or ref.ndim != 2 or ref.shape[1] != n
                or len(Rt) not in (1, N) or len(ref) not in (1, N)):
            raise ValueError(f"positions {P.shape}, rotations {Rt.shape} and references {ref.shape} are not "
                             f"(N, 3), (N or 1, 3, 3), (N or 1, {n})")
        q, ok = np.empty((N, n)), np.empty(N, dtype=np.bool_)
        numerical_ik_batch(P, Rt, ref, self.K, q, ok)
        return GeneralIKResult(q, ok)

    def solve_world(self, root_p, root_R, tip_p, tip_R, q_ref=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Tip poses in the world, the chain's root at ``(root_p, root_R)`` (each (N or 1, ...)):
        ``(q (N, n), ok (N,), reason (N,) int8)`` in one compiled call
        (:func:`numerical_ik_world_batch`; the answers of :meth:`solve` on the relative poses)."""
        n = self.n_joints
        a = [_rows(root_p, 1), _rows(root_R, 2), _rows(tip_p, 1), _rows(tip_R, 2),
             _rows(self._ref if q_ref is None else q_ref, 1)]
        N = max(len(x) for x in a[:4])
        if (any(len(x) not in (1, N) for x in a) or a[0].shape[1:] != (3,) or a[1].shape[1:] != (3, 3)
                or a[2].shape[1:] != (3,) or a[3].shape[1:] != (3, 3) or a[4].shape[1:] != (n,)):
            raise ValueError(f"root / tip poses and references {[x.shape for x in a]} are not (N or 1, 3), "
                             f"(N or 1, 3, 3), (N or 1, 3), (N or 1, 3, 3), (N or 1, {n})")
        q, ok, reason = np.empty((N, n)), np.empty(N, dtype=np.bool_), np.empty(N, dtype=np.int8)
        numerical_ik_world_batch(a[0], a[1], a[2], a[3], a[4], self.K, q, ok, reason)
        return q, ok, reason

    def solve_one(self, target_p: np.ndarray, target_R: np.ndarray,
                  q_ref: np.ndarray | None = None) -> tuple[bool, np.ndarray]:
        """One pose, the cheapest call: ``(ok, q)`` with ``q`` (n,) a new array, NaN when not ok."""
        n = self.n_joints
        P, Rt = _one(target_p, (3,)), _one(target_R, (3, 3))
        ref = self._ref[0] if q_ref is None else _one(q_ref, (n,))
        q = np.empty(n)
        return bool(numerical_ik_pose(P, Rt, ref, self.K, q, self._work)), q


def warm_up() -> None:
    """Compile (or load from the numba cache) the kernels on one pose of a tiny 7R chain with
    offsets everywhere and of its 6R subchain."""
    ax = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0],
                   [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    t = np.array([[0.0, 0.1, 0.2], [0.0, 0.04, -0.01], [0.0, 0.0, -0.1], [0.02, 0.0, -0.2], [0.1, 0.0, -0.01],
                  [0.04, 0.0, 0.0], [0.05, 0.0, 0.0]])
    for nj in (7, 6):
        c = Chain6(np.broadcast_to(np.eye(3), (nj, 3, 3)).copy(), t[:nj].copy(), ax[:nj].copy(), np.eye(3),
                   np.zeros(3), np.full(nj, -2.0), np.full(nj, 2.0))
        ik = NumericalLimbIK(c, np.zeros(nj), n_starts=2)
        p, R = c.fk(np.full((1, nj), 0.3))
        ik.solve(p, R)
        ik.solve_one(p[0], R[0])
        ik.solve_world(np.zeros((1, 3)), np.eye(3)[None], p, R, np.full((1, nj), 0.29))
        q = np.empty(nj)
        numerical_track_world(np.zeros(3), np.eye(3), p[0], np.ascontiguousarray(R[0]), np.full(nj, 0.29), ik.K, q,
                              ik._work)


__all__ = ["NumericalLimbIK", "NumericalLimbTracker", "numerical_leg_constants", "numerical_ik_pose",
           "numerical_ik_track", "numerical_track_world", "numerical_ik_batch", "numerical_ik_world_batch",
           "quasi_random_starts", "warm_up", "work_size"]
