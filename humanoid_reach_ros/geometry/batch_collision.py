"""Collision checks of many configurations at once, in SIMD lanes (the verdicts of
:class:`~humanoid_reach_ros.geometry.distance.RobotCollision`, faster).

:class:`BatchCollision` wraps a :class:`RobotCollision` and answers its ``check_batch`` and
``first_collision`` with the same verdicts, configuration for configuration. Configurations
go through in blocks of ``LANES`` (8: one AVX-512 register of doubles), laid out as
structures of arrays -- every pose and capsule end is an array ``[..., lane]`` -- so that
the forward kinematics ``oMi[j] = oMi[parent] * M_j * R_axis(q_j)`` of eight
configurations is one branch-free loop over the lanes per joint and per capsule, which LLVM
turns into vector instructions (the idea of VAMP, Thomason et al. 2024; this code is our
own). The verdict of every configuration is the scalar checker's (the tests say so on
28,000 configurations, bench/collision_batch.py on 100,000 per robot):

* **trigonometry in the lanes**: ``sin q_j``, ``cos q_j`` by a Taylor polynomial of degree
  17/18 after the reduction ``q = n pi/2 + r``, ``|r| <= pi/4`` (error below 1e-15, no
  libm call, so the loop vectorises); a joint's rotation applied to its columns in the
  order (axis, u, v), the same two-column turn for x, y and z; capsule ends from their
  joint's frame. The capsule ends then differ from the scalar kernel's by rounding only
  (below 1e-12 m over a 30-joint chain);
* **every test with a band**: a test whose value lies within ``EPS_M`` (1e-7 m, five orders
  above that difference) of its threshold is *undecided*, and the configuration is checked
  again by today's scalar kernels (libm, same arithmetic): every other verdict is the one
  the scalar checker gives, since its value is on the same side of the threshold;
* **self pairs**: the exact segment-segment distance of every pair in every lane (the
  scalar checker's expressions, Ericson 5.1.9, with its branches as selects), skipped for
  a pair whose bounding spheres are apart in all eight lanes (an edge's samples agree);
* **environment, broad phase**: a distance field ``F`` on a grid of ``field_cell_m``
  cells around the sphere centres: ``F(x) <= min_i |x - c_i| - r_i`` for every ``x`` in
  the cell (the exact Euclidean distance transform of the cells holding a centre, minus a
  cell diagonal for where ``x`` and ``c_i`` lie in their cells, minus the largest radius);
  outside the grid, the distance to the box of the centres minus the largest radius. A
  capsule ``(p0, p1, r)`` with ``F(m) - |p1 - p0| / 2 - r > EPS_M`` at its midpoint ``m``
  (or the same on both its halves) touches no sphere, and needs no tree query;
* **environment, narrow phase**: the other capsules go down the sphere tree as the scalar
  checker does (same node test ``|c - seg|^2 < (r_node + r)^2``), with the band on every node.

A configuration is valid when no self pair and no capsule collides: the same definition,
radii, pairs, margin and tree as the wrapped checker, whose counters it updates. This
module never imports rclpy.
"""
from __future__ import annotations

import math
import time

import numba as nb
import numpy as np

from humanoid_reach_ros.geometry.distance import (_JIT, RobotCollision, _check_kernel, _fk_shapes_kernel,
                                                   quaternion_rotation)
from humanoid_reach_ros.geometry.sphere_tree import _inv_len2, _seg_dist2

#: configurations per block (the SIMD lanes)
LANES = 8
#: undecided band [m] of every test (see the module doc)
EPS_M = 1e-7
#: joint angles beyond this [rad] are reduced less accurately: such batches take the scalar path
MAX_ANGLE_RAD = 1.0e3
_HALF_PI = 0.5 * math.pi
_TWO_OVER_PI = 2.0 / math.pi
# Taylor coefficients of sin (odd powers 3..17) and cos (even powers 2..18): (-1)^k / n!
_S = tuple((-1.0) ** k / math.factorial(2 * k + 1) for k in range(1, 9))
_C = tuple((-1.0) ** k / math.factorial(2 * k) for k in range(1, 10))
S1, S2, S3, S4, S5, S6, S7, S8 = _S
C1, C2, C3, C4, C5, C6, C7, C8, C9 = _C

#: the lane kernels with divisions: numpy's error model (no ZeroDivisionError branch per
#: division, which would keep LLVM from vectorising; every denominator there is made safe)
_JIT_LANES = dict(_JIT, error_model="numpy")

#: verdicts of the lane tests
CLEAR, HIT, UNDECIDED = 0, 1, 2


# =================================================================== lane kernels
@nb.njit(**_JIT)
def _sincos_lanes(QT, jq, SN, CS):
    """``SN[j, ln], CS[j, ln]`` = sin, cos of joint ``j``'s angle in lane ``ln`` of ``QT`` (nq, LANES)."""
    nl = SN.shape[1]
    for j in range(jq.shape[0]):
        col = jq[j]
        for ln in range(nl):
            x = QT[col, ln]
            n = np.floor(x * _TWO_OVER_PI + 0.5)
            r = x - n * _HALF_PI
            z = r * r
            s = r + r * z * (S1 + z * (S2 + z * (S3 + z * (S4 + z * (S5 + z * (S6 + z * (S7 + z * S8)))))))
            c = 1.0 + z * (C1 + z * (C2 + z * (C3 + z * (C4 + z * (C5 + z * (C6 + z * (C7 + z * (C8 + z * C9))))))))
            k = n - 4.0 * np.floor(0.25 * n)          # quadrant 0..3, in floats: selects, no branches
            odd = (k == 1.0) | (k == 3.0)
            sv = c if odd else s
            cv = s if odd else c
            sv = -sv if k >= 2.0 else sv
            cv = -cv if (k == 1.0) | (k == 2.0) else cv
            SN[j, ln] = sv
            CS[j, ln] = cv


@nb.njit(**_JIT)
def _fk_lanes(QT, lfk, W):
    """Capsule ends ``P0, P1 [s, a, ln]`` of the configurations ``QT[:, ln]`` (nq, LANES).

    ``lfk`` (:func:`lane_fk_args`): per joint its parent, placement ``jt`` and the rotation
    ``jRp`` with its columns in the order ``(w, u, v)`` (``w`` the joint axis, ``(u, v, w)``
    right-handed), so that ``R_axis(q)`` turns columns ``u, v`` alike for every axis; per shape
    its joint and its ends in that joint's frame. One loop over the lanes per joint and per
    shape, everything else in registers."""
    jparent, jperm, jRp, jt, jq, sj, p0j, p1j = lfk
    oR, ot, P0, P1, SN, CS, B = W
    nl = SN.shape[1]      # LANES, read at run time: a loop (not unrolled early) for the loop vectoriser
    for ln in range(nl):
        quaternion_rotation(QT[3, ln], QT[4, ln], QT[5, ln], QT[6, ln], B)
        for a in range(3):
            for b in range(3):
                oR[0, a, b, ln] = B[a, b]
            ot[0, a, ln] = QT[a, ln]
    _sincos_lanes(QT, jq, SN, CS)
    for j in range(jparent.shape[0]):
        p = jparent[j] + 1
        o = j + 1
        r00 = jRp[j, 0, 0]
        r01 = jRp[j, 0, 1]
        r02 = jRp[j, 0, 2]
        r10 = jRp[j, 1, 0]
        r11 = jRp[j, 1, 1]
        r12 = jRp[j, 1, 2]
        r20 = jRp[j, 2, 0]
        r21 = jRp[j, 2, 1]
        r22 = jRp[j, 2, 2]
        t0 = jt[j, 0]
        t1 = jt[j, 1]
        t2 = jt[j, 2]
        w = jperm[j, 0]
        u = jperm[j, 1]
        v = jperm[j, 2]
        for ln in range(nl):
            cs = CS[j, ln]
            sn = SN[j, ln]
            for a in range(3):
                x0 = oR[p, a, 0, ln]
                x1 = oR[p, a, 1, ln]
                x2 = oR[p, a, 2, ln]
                aw = x0 * r00 + x1 * r10 + x2 * r20
                au = x0 * r01 + x1 * r11 + x2 * r21
                av = x0 * r02 + x1 * r12 + x2 * r22
                oR[o, a, w, ln] = aw
                oR[o, a, u, ln] = au * cs + av * sn
                oR[o, a, v, ln] = av * cs - au * sn
                ot[o, a, ln] = ot[p, a, ln] + x0 * t0 + x1 * t1 + x2 * t2
    for s in range(sj.shape[0]):
        k = sj[s] + 1
        u0 = p0j[s, 0]
        u1 = p0j[s, 1]
        u2 = p0j[s, 2]
        v0 = p1j[s, 0]
        v1 = p1j[s, 1]
        v2 = p1j[s, 2]
        for ln in range(nl):
            for a in range(3):
                x0 = oR[k, a, 0, ln]
                x1 = oR[k, a, 1, ln]
                x2 = oR[k, a, 2, ln]
                P0[s, a, ln] = ot[k, a, ln] + x0 * u0 + x1 * u1 + x2 * u2
                P1[s, a, ln] = ot[k, a, ln] + x0 * v0 + x1 * v1 + x2 * v2


def lane_fk_args(fk: tuple) -> tuple:
    """The arguments of :func:`_fk_lanes` from ``RobotCollision._fk_args``."""
    jparent, jaxis, jR, jt, jq, lj, lR, lt, sl, p0l, p1l = fk
    perms = np.array([[0, 1, 2], [1, 2, 0], [2, 0, 1]], np.int64)     # (w, u, v) of x, y, z
    jperm = np.ascontiguousarray(perms[jaxis])
    jRp = np.ascontiguousarray(np.stack([jR[j][:, jperm[j]] for j in range(len(jR))]) if len(jR) else jR)
    sj = np.ascontiguousarray(lj[sl], dtype=np.int64)
    p0j = np.ascontiguousarray(lt[sl] + np.einsum("sab,sb->sa", lR[sl], p0l))
    p1j = np.ascontiguousarray(lt[sl] + np.einsum("sab,sb->sa", lR[sl], p1l))
    return (jparent, jperm, jRp, jt, jq, sj, p0j, p1j)


@nb.njit(**_JIT)
def _bounds_lanes(P0, P1, R, MC, BR):
    """Bounding sphere (centre ``MC[s, a, ln]``, radius ``BR[s, ln]``) of every capsule."""
    nl = BR.shape[1]
    for s in range(P0.shape[0]):
        rs = R[s]
        for ln in range(nl):
            dx = P1[s, 0, ln] - P0[s, 0, ln]
            dy = P1[s, 1, ln] - P0[s, 1, ln]
            dz = P1[s, 2, ln] - P0[s, 2, ln]
            MC[s, 0, ln] = P0[s, 0, ln] + 0.5 * dx
            MC[s, 1, ln] = P0[s, 1, ln] + 0.5 * dy
            MC[s, 2, ln] = P0[s, 2, ln] + 0.5 * dz
            BR[s, ln] = 0.5 * math.sqrt(dx * dx + dy * dy + dz * dz) + rs


@nb.njit(**_JIT_LANES)
def _self_lanes(P0, P1, MC, BR, pi, pj, R, margin, state, HIT_, UND_):
    """Self pairs, every pair in every lane: ``state[ln]`` becomes HIT (some pair certainly
    closer than ``margin``) or UNDECIDED (a pair within ``EPS_M`` of it, none certainly
    closer). The segment-segment distance is the scalar checker's
    (:func:`~humanoid_reach_ros.geometry.distance.closest_segment_params`, Ericson 5.1.9),
    same expressions, its branches turned into selects (safe denominators where a branch
    is not taken), so that the lanes vectorise. A pair whose bounding spheres (``MC``,
    ``BR``) are apart by more than ``margin + EPS_M`` in every lane is skipped (the lanes of
    an edge's samples mostly agree)."""
    nl = HIT_.shape[0]
    for ln in range(nl):
        HIT_[ln] = False
        UND_[ln] = False
    lo = margin - EPS_M
    hi = margin + EPS_M
    eps = 1e-18
    for k in range(pi.shape[0]):
        i = pi[k]
        j = pj[k]
        ri = R[i]
        rj = R[j]
        near = 0
        for ln in range(nl):
            dx = MC[i, 0, ln] - MC[j, 0, ln]
            dy = MC[i, 1, ln] - MC[j, 1, ln]
            dz = MC[i, 2, ln] - MC[j, 2, ln]
            lim = BR[i, ln] + BR[j, ln] + hi
            near += (lim <= 0.0) | (dx * dx + dy * dy + dz * dz < lim * lim)
        if near == 0:
            continue
        for ln in range(nl):
            d1x = P1[i, 0, ln] - P0[i, 0, ln]
            d1y = P1[i, 1, ln] - P0[i, 1, ln]
            d1z = P1[i, 2, ln] - P0[i, 2, ln]
            d2x = P1[j, 0, ln] - P0[j, 0, ln]
            d2y = P1[j, 1, ln] - P0[j, 1, ln]
            d2z = P1[j, 2, ln] - P0[j, 2, ln]
            rx = P0[i, 0, ln] - P0[j, 0, ln]
            ry = P0[i, 1, ln] - P0[j, 1, ln]
            rz = P0[i, 2, ln] - P0[j, 2, ln]
            a = d1x * d1x + d1y * d1y + d1z * d1z
            e = d2x * d2x + d2y * d2y + d2z * d2z
            f = d2x * rx + d2y * ry + d2z * rz
            c = d1x * rx + d1y * ry + d1z * rz
            b = d1x * d2x + d1y * d2y + d1z * d2z
            a_deg = a <= eps
            e_deg = e <= eps
            a_s = 1.0 if a_deg else a
            e_s = 1.0 if e_deg else e
            den = a * e - b * b
            gen = den > 1e-14 * a * e
            den_s = den if gen else 1.0
            s = min(max((b * f - c * e) / den_s, 0.0), 1.0) if gen else 0.0
            t = (b * s + f) / e_s
            s_lo = min(max(-c / a_s, 0.0), 1.0)
            s_hi = min(max((b - c) / a_s, 0.0), 1.0)
            s = s_lo if t < 0.0 else (s_hi if t > 1.0 else s)
            t = 0.0 if t < 0.0 else (1.0 if t > 1.0 else t)
            # the degenerate cases, in the scalar function's order
            t_a = min(max(f / e_s, 0.0), 1.0)
            s = 0.0 if a_deg else (s_lo if e_deg else s)
            t = (0.0 if e_deg else t_a) if a_deg else (0.0 if e_deg else t)
            dx = P0[i, 0, ln] + s * d1x - P0[j, 0, ln] - t * d2x
            dy = P0[i, 1, ln] + s * d1y - P0[j, 1, ln] - t * d2y
            dz = P0[i, 2, ln] + s * d1z - P0[j, 2, ln] - t * d2z
            d = math.sqrt(dx * dx + dy * dy + dz * dz) - ri - rj
            HIT_[ln] = HIT_[ln] | (d < lo)
            UND_[ln] = UND_[ln] | (d < hi)
    for ln in range(nl):
        state[ln] = HIT if HIT_[ln] else (UNDECIDED if UND_[ln] else CLEAR)


@nb.njit(**_JIT)
def _tree_lane(nodes, children, ax, ay, az, bx, by, bz, r, stack):
    """The scalar checker's tree descent for one capsule, with the band: HIT when a leaf is
    reached through node tests all certainly passed, UNDECIDED at the first node test within
    ``EPS_M``, else CLEAR."""
    dx = bx - ax
    dy = by - ay
    dz = bz - az
    inv = _inv_len2(dx, dy, dz)
    stack[0] = 0
    top = 1
    while top > 0:
        top -= 1
        i = stack[top]
        rr = nodes[i, 3] + r
        d2 = _seg_dist2(nodes, i, ax, ay, az, dx, dy, dz, inv)
        hi = rr + EPS_M
        if d2 >= hi * hi:
            continue
        lo = rr - EPS_M
        if lo <= 0.0 or d2 >= lo * lo:
            return UNDECIDED
        lc = children[i, 0]
        if lc < 0:
            return HIT
        stack[top] = children[i, 1]
        stack[top + 1] = lc
        top += 2
    return CLEAR


@nb.njit(**_JIT)
def _field_lb(field, origin, inv_cell, box_lo, box_hi, r_max, x, y, z):
    """Lower bound of ``min_i |p - c_i| - r_i`` at ``p = (x, y, z)`` (see the module doc; ``inv_cell``:
    1 / the cell size)."""
    nx, ny, nz = field.shape
    fx = (x - origin[0]) * inv_cell
    fy = (y - origin[1]) * inv_cell
    fz = (z - origin[2]) * inv_cell
    if fx >= 0.0 and fy >= 0.0 and fz >= 0.0 and fx < nx and fy < ny and fz < nz:
        return field[int(fx), int(fy), int(fz)]
    ex = max(box_lo[0] - x, 0.0, x - box_hi[0])
    ey = max(box_lo[1] - y, 0.0, y - box_hi[1])
    ez = max(box_lo[2] - z, 0.0, z - box_hi[2])
    return math.sqrt(ex * ex + ey * ey + ez * ez) - r_max


@nb.njit(**_JIT)
def _env_lanes(P0, P1, MC, BR, order, R, nodes, children, fld, origin, cell, box_lo, box_hi, r_max, state, stack):
    """Environment test of the lanes still open: the field (certainly clear), then the tree.
    (A certain-hit probe before the tree -- the sphere of the nearest occupied cell -- was
    measured slower: 3.0 vs 2.5 us CPU per free configuration, no faster on colliding ones.)"""
    inv_cell = 1.0 / cell
    for ln in range(LANES):
        if state[ln] != CLEAR:
            continue
        for q in range(order.shape[0]):
            s = order[q]
            lb = _field_lb(fld, origin, inv_cell, box_lo, box_hi, r_max, MC[s, 0, ln], MC[s, 1, ln], MC[s, 2, ln])
            if lb - BR[s, ln] > EPS_M:
                continue
            # a long capsule: its two halves, each in its own bounding sphere
            h = 0.5 * (BR[s, ln] - R[s])          # a quarter of the segment's length
            if h > 0.5 * cell:
                clear = True
                for f in (0.25, 0.75):
                    x = P0[s, 0, ln] + f * (P1[s, 0, ln] - P0[s, 0, ln])
                    y = P0[s, 1, ln] + f * (P1[s, 1, ln] - P0[s, 1, ln])
                    z = P0[s, 2, ln] + f * (P1[s, 2, ln] - P0[s, 2, ln])
                    if _field_lb(fld, origin, inv_cell, box_lo, box_hi, r_max, x, y, z) - h - R[s] <= 2.0 * EPS_M:
                        clear = False
                        break
                if clear:
                    continue
            v = _tree_lane(nodes, children, P0[s, 0, ln], P0[s, 1, ln], P0[s, 2, ln], P1[s, 0, ln], P1[s, 1, ln],
                           P1[s, 2, ln], R[s], stack)
            if v != CLEAR:
                state[ln] = v
                if v == HIT:
                    break


@nb.njit(**_JIT)
def _scalar_one(blk, ln, fk, R, order, pi, pj, margin, nodes, children, depth, do_env, WS):
    """The scalar checker on lane ``ln`` of ``blk`` (an undecided lane): True when in collision."""
    jparent, jaxis, jR, jt, jq, lj, lR, lt, sl, p0l, p1l = fk[0]
    row, S0, S1_, oe, os_ = WS[7], WS[8], WS[9], WS[10], WS[11]
    for k in range(row.shape[1]):
        row[0, k] = blk[k, ln]
    _fk_shapes_kernel(row, jparent, jaxis, jR, jt, jq, lj, lR, lt, sl, p0l, p1l, S0, S1_)
    _check_kernel(S0, S1_, R, order, pi, pj, R, margin, nodes, children, depth, do_env, True, True, oe, os_)
    return oe[0] or os_[0]


@nb.njit(**_JIT)
def lane_workspace(nq, J, S, depth):
    """Scratch of :func:`check_lanes` (one per kernel call)."""
    return ((np.empty((J + 1, 3, 3, LANES)), np.empty((J + 1, 3, LANES)), np.empty((S, 3, LANES)),
             np.empty((S, 3, LANES)), np.empty((J, LANES)), np.empty((J, LANES)), np.empty((3, 3))),
            np.empty((S, 3, LANES)), np.empty((S, LANES)), np.empty(LANES, np.int64), np.empty(LANES, np.bool_),
            np.empty(LANES, np.bool_), np.empty(depth + 2, np.int64),
            np.empty((1, nq)), np.empty((1, S, 3)), np.empty((1, S, 3)), np.zeros(1, np.bool_), np.zeros(1, np.bool_))


@nb.njit(**_JIT)
def check_lanes(blk, n, fk, R, order, pi, pj, margin, nodes, children, depth, do_env, fld, WS, hits, counts):
    """``hits[ln]`` (ln < n): configuration ``blk[:, ln]`` ((nq, LANES), every lane filled) collides,
    the scalar checker's verdict. ``fk``: (``RobotCollision._fk_args``, :func:`lane_fk_args`,
    ``BatchCollision.fk``); ``fld``: the distance field's arguments; ``WS``:
    :func:`lane_workspace`; ``counts[1]`` += the undecided lanes redone by the scalar kernels."""
    field, origin, cell, box_lo, box_hi, r_max = fld
    W, MC, BR, state, HIT_, UND_, stack = WS[0], WS[1], WS[2], WS[3], WS[4], WS[5], WS[6]
    P0 = W[2]
    P1 = W[3]
    _fk_lanes(blk, fk[1], W)
    _bounds_lanes(P0, P1, R, MC, BR)
    _self_lanes(P0, P1, MC, BR, pi, pj, R, margin, state, HIT_, UND_)
    if do_env:
        _env_lanes(P0, P1, MC, BR, order, R, nodes, children, field, origin, cell, box_lo, box_hi, r_max, state,
                   stack)
    for ln in range(n):
        hit = state[ln] == HIT
        if state[ln] == UNDECIDED:
            counts[1] += 1
            hit = _scalar_one(blk, ln, fk, R, order, pi, pj, margin, nodes, children, depth, do_env, WS)
        hits[ln] = hit


@nb.njit(**_JIT)
def _batch_kernel(Q, stop_first, fk, R, order, pi, pj, margin, nodes, children, depth, do_env, fld, out, counts):
    """``out[c]``: configuration ``c`` of ``Q`` (C, nq) collides. Blocks of LANES rows (the
    last block padded with copies of its last row). With ``stop_first`` returns after the
    block holding the first collision (its index; C if none). ``counts``: (configurations
    computed, undecided lanes redone by the scalar kernels)."""
    C = Q.shape[0]
    nq = Q.shape[1]
    WS = lane_workspace(nq, fk[1][0].shape[0], fk[1][5].shape[0], depth)
    blk = np.empty((nq, LANES))
    hits = np.zeros(LANES, np.bool_)
    for c0 in range(0, C, LANES):
        n = min(LANES, C - c0)
        for ln in range(LANES):
            src = c0 + min(ln, n - 1)
            for k in range(nq):
                blk[k, ln] = Q[src, k]
        check_lanes(blk, n, fk, R, order, pi, pj, margin, nodes, children, depth, do_env, fld, WS, hits, counts)
        first = C
        for ln in range(n):
            out[c0 + ln] = hits[ln]
            if hits[ln] and first == C:
                first = c0 + ln
        counts[0] += n
        if stop_first and first < C:
            return first
    return C


# =================================================================== distance field
def distance_field(centers: np.ndarray, radii: np.ndarray, cell_m: float, pad_m: float):
    """``(field, origin, box_lo, box_hi, r_max)``: the lower bound ``F`` of the module doc on
    a grid of ``cell_m`` cells covering the centres' box grown by ``pad_m``."""
    from scipy.ndimage import distance_transform_edt

    centers = np.asarray(centers, float)
    r_max = float(np.max(radii))
    box_lo, box_hi = centers.min(0), centers.max(0)
    origin = box_lo - pad_m
    shape = np.floor((box_hi + pad_m - origin) / cell_m).astype(int) + 1
    occ = np.ones(tuple(shape), bool)
    idx = np.clip(np.floor((centers - origin) / cell_m).astype(int), 0, shape - 1)
    occ[idx[:, 0], idx[:, 1], idx[:, 2]] = False
    edt = distance_transform_edt(occ, sampling=cell_m)
    # x and c_i anywhere in their cells: each at most half a diagonal from its cell's centre
    field = edt - math.sqrt(3.0) * cell_m - r_max - 1e-9
    # float32 (half the cache footprint), rounded down: still a lower bound
    f32 = field.astype(np.float32)
    f32 = np.where(f32.astype(float) > field, np.nextafter(f32, np.float32(-np.inf)), f32)
    field = np.ascontiguousarray(f32)
    return field, origin, box_lo, box_hi, r_max


#: a field that clears nothing: one cell holding every point, -inf
_NO_FIELD = (np.full((1, 1, 1), -np.inf, np.float32), np.full(3, -1e30), 1e31, np.zeros(3), np.zeros(3), 0.0)


# =================================================================== Python API
class BatchCollision:
    """The verdicts of ``collision`` (:class:`RobotCollision`) over batches, in SIMD lanes.

    ``field_cell_m``: cell of the environment's distance field (built on first use, once per
    tree); ``field_pad_m``: how far around the sphere centres the grid reaches (beyond, the
    bound is the distance to the centres' box); ``field_after_configs``: see :meth:`field_args`."""

    def __init__(self, collision: RobotCollision, field_cell_m: float = 0.04, field_pad_m: float = 0.3,
                 field_after_configs: int = 4096) -> None:
        if not (field_cell_m > 0 and field_pad_m >= 0 and math.isfinite(field_cell_m) and math.isfinite(field_pad_m)):
            raise ValueError(f"BatchCollision: need field_cell_m > 0 and field_pad_m >= 0, got {field_cell_m}, "
                             f"{field_pad_m}")
        self.collision = collision
        #: the forward kinematics' arguments: (scalar kernel's, lanes')
        self.fk = (collision._fk_args, lane_fk_args(collision._fk_args))
        self.field_cell_m = float(field_cell_m)
        self.field_pad_m = float(field_pad_m)
        self._field = None
        self.field_build_s = 0.0
        #: lanes that the band sent back to the scalar kernels (since construction)
        self.undecided = 0
        #: configurations checked (any caller), and how many before the field is built
        self.configs_checked = 0
        self.field_after_configs = int(field_after_configs)

    def field_args(self, lazy: bool = False) -> tuple:
        """The distance field's kernel arguments (built on first use). ``lazy``: until
        ``field_after_configs`` configurations have been checked on this tree, a field that
        clears nothing (every capsule goes down the tree: same verdicts), so that a map
        checked briefly does not pay the field's build (30 ms at load 10 vs 5 ms for the
        sphere tree of the same 21,640 voxels)."""
        if self._field is None and lazy and self.configs_checked < self.field_after_configs:
            return _NO_FIELD
        if self._field is None:
            tree = self.collision.tree
            t0 = time.perf_counter()
            if tree.n_spheres:
                sph = tree.nodes[tree.children[:, 0] < 0]     # a leaf's node sphere is its input sphere
                f, origin, lo, hi, r_max = distance_field(sph[:, :3], sph[:, 3], self.field_cell_m, self.field_pad_m)
            else:
                f, origin, lo, hi, r_max = np.zeros((1, 1, 1), np.float32), np.zeros(3), np.zeros(3), np.zeros(3), 0.0
            self._field = (f, np.ascontiguousarray(origin, float), self.field_cell_m, np.ascontiguousarray(lo, float),
                           np.ascontiguousarray(hi, float), float(r_max))
            self.field_build_s = time.perf_counter() - t0
        return self._field

    def _configs(self, Q) -> np.ndarray:
        Q = self.collision._as_batch(Q)
        if not np.all(np.isfinite(Q)):
            raise ValueError("BatchCollision: configurations must be finite (NaN or inf found)")
        return Q

    def _run(self, Q: np.ndarray, stop_first: bool) -> tuple[int, np.ndarray, int]:
        col = self.collision
        out = np.zeros(len(Q), np.bool_)
        tree = col.tree
        counts = np.zeros(2, np.int64)
        t0 = time.perf_counter()
        if len(Q) and np.abs(Q[:, 7:]).max(initial=0.0) > MAX_ANGLE_RAD:
            # the lane trigonometry's range: the scalar checker, as is
            if stop_first:
                k = col.first_collision(Q)
                out[k:k + 1] = True
                return k, out, min(k + 1, len(Q))
            return (0, ~col.check_batch(Q), len(Q))
        do_env = bool(tree.n_spheres > 0)
        fld = self.field_args(lazy=True)
        k = _batch_kernel(Q, bool(stop_first), self.fk, col.radii, col.env_order, col._pi, col._pj,
                          col.self_margin_m, tree.nodes, tree.children, tree.depth, do_env, fld, out, counts)
        self.undecided += int(counts[1])
        self.configs_checked += int(counts[0])
        c = col.counters
        c.check_time_s += time.perf_counter() - t0
        c.checks += int(counts[0])
        c.calls += 1
        return int(k), out, int(counts[0])

    def check_batch(self, Q) -> np.ndarray:
        """(C,) bool: collision-free, per configuration (``RobotCollision.check_batch``'s verdicts)."""
        Q = self._configs(Q)
        return ~self._run(Q, False)[1]

    def first_collision(self, Q) -> int:
        """Index of the first configuration of ``Q`` (C, nq) in collision, or C
        (``RobotCollision.first_collision``'s answer); blocks after its block are not computed."""
        Q = self._configs(Q)
        return self._run(Q, True)[0]


def batch_checker(collision: RobotCollision) -> BatchCollision:
    """The :class:`BatchCollision` of ``collision``, built once and kept on it (its tree never
    changes: a new map is a new :class:`RobotCollision`)."""
    bc = getattr(collision, "_batch", None)
    if bc is None:
        bc = BatchCollision(collision)
        collision._batch = bc
    return bc


__all__ = ["BatchCollision", "batch_checker", "check_lanes", "distance_field", "lane_fk_args", "lane_workspace",
           "LANES", "EPS_M"]
