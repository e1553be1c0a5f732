"""Inequality rows ``G dq <= h`` of the whole-body IK (Sec. IV, level 1).

``dq`` is the configuration displacement of one control step of ``dt`` seconds
(tangent vector in ``R^nv``, see :mod:`humanoid_reach_ros.control.tasks`).

* :func:`joint_limit_rows`: joint position limits over one step and velocity limits.
* :func:`velocity_damper_rows`: Faverjon-Tournassoud velocity dampers between the
  robot's capsules and the environment spheres (and between self-collision pairs).
  For a distance ``d <= d_i`` (influence distance) the rows enforce, per step,

      delta_d >= -xi (d - d_s)          (xi in (0, 1], d_s the security distance)

  i.e. the velocity damper ``d_dot >= -xi_FT (d - d_s) / (d_i - d_s)`` with
  ``xi_FT = xi (d_i - d_s) / dt``. To first order ``d - d_s`` then shrinks at most by
  the factor ``1 - xi`` per step, so ``d`` never crosses ``d_s``. A pair already
  inside ``d_s`` (e.g. a start there) gets ``delta_d >= 0``: the bound
  ``xi max(d - d_s, 0)`` (:func:`damper_bound`) lets ``d`` grow and never shrink, and
  ``dq = 0`` always satisfies it, so the dampers never make level 1 infeasible
  (a forced push-out ``-xi (d - d_s) > 0`` could conflict with other rows). With ``n`` the unit
  vector from the robot point ``p`` to the other point:

  - static environment sphere (centre ``c``): ``delta_d = n^T (0 - J_p dq)``, row
    ``n^T J_p dq <= xi (d - d_s)``;
  - self-collision (points ``p_a``, ``p_b``, ``n`` from a to b):
    ``delta_d = n^T (J_b - J_a) dq``, row ``n^T (J_a - J_b) dq <= xi (d - d_s)``.

  ``J_p`` is the translational Jacobian of the closest point on the capsule's
  *segment* (the LWA frame Jacobian of the link shifted to the point:
  ``n^T J_p = n^T J_v + (r x n)^T J_w`` with ``r = p - o_link``); the surface point
  ``p + radius n`` has the same ``n^T J`` since ``n^T (w x n) = 0``.
"""
from __future__ import annotations

from dataclasses import dataclass
import math
from typing import TYPE_CHECKING, Sequence

import numba as nb
import numpy as np
import pinocchio as pin

from humanoid_reach_ros.geometry.distance import closest_segment_params
from humanoid_reach_ros.robot.model import N_BASE_Q, N_BASE_V
from humanoid_reach_ros.robot.shapes import point_segment_distance, segment_segment_distance

if TYPE_CHECKING:  # pragma: no cover
    from humanoid_reach_ros.geometry.sphere_tree import SphereTree
    from humanoid_reach_ros.robot.shapes import CollisionModel

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


@dataclass(frozen=True)
class LimitRows:
    """Inequality rows ``G dq <= h``; ``distance`` (damper rows only) for diagnostics."""

    G: np.ndarray
    h: np.ndarray
    distance: np.ndarray | None = None

    @staticmethod
    def stack(*rows: "LimitRows") -> "LimitRows":
        return LimitRows(np.vstack([r.G for r in rows]), np.concatenate([r.h for r in rows]))

    def __len__(self) -> int:
        return len(self.h)


def joint_step_bounds(qj: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                      vdt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of one step ``dq_j <= up_j`` and ``-dq_j <= lo_j`` of joints at ``qj``:
    ``up = max(min(upper - q, v dt), -v dt)``, ``lo = max(min(q - lower, v dt), -v dt)``
    (the rows of :func:`joint_limit_rows`; the executor's level 1 uses them with its own
    constant row matrix)."""
    up = np.maximum(np.minimum(upper - qj, vdt), -vdt)
    lo = np.maximum(np.minimum(qj - lower, vdt), -vdt)
    return up, lo


def braking_speed(s: np.ndarray, a: float, dt: float) -> np.ndarray:
    """Largest speed ``v >= 0`` from which a distance ``s`` (clamped at 0) can still be stopped
    within, moving ``v dt`` this step and then decelerating at ``a``: ``v dt + v^2 / (2 a) <= s``,
    ``v = a (sqrt(dt^2 + 2 s / a) - dt)``. The discrete braking distance is below ``v^2 / (2 a)``,
    so the bound is conservative, and it is recursively feasible: from ``v <= braking_speed(s)``
    the next step's ``max(v - a dt, 0)`` is within ``braking_speed(s - v dt)`` (for any ``dt``)."""
    s = np.maximum(np.asarray(s, dtype=float), 0.0)
    return a * (np.sqrt(dt * dt + 2.0 * s / a) - dt)


def joint_step_box(qj: np.ndarray, lower: np.ndarray, upper: np.ndarray, vmax: np.ndarray,
                   v_prev: np.ndarray, a: float, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bounds ``dq_j <= up_j``, ``-dq_j <= lo_j`` of one step of ``dt`` with the joint
    acceleration bounded by ``a`` (Kanoun-style acceleration rows on a velocity-resolved IK,
    the position limits made viable as in Del Prete, RA-L 2018): the joint velocity
    ``dq / dt`` within ``v_prev +- a dt``, within ``+-vmax``, within :func:`braking_speed` of
    each limit (so the joint can always stop at it with ``a``), and ``q + dq`` in the range.

    Where the acceleration box and the position/velocity box do not meet (a joint that moved
    faster than its limit allows, a shrunk velocity limit, a start outside the range) the
    acceleration bound is dropped for that joint this step (returned ``relaxed`` mask): the
    position and velocity limits win. A joint outside its range returns at most at ``vmax``,
    as :func:`joint_step_bounds`. Returns ``(up, lo, relaxed)``."""
    s_up = upper - qj
    s_lo = qj - lower
    p_hi = np.minimum(vmax, braking_speed(s_up, a, dt))
    p_lo = -np.minimum(vmax, braking_speed(s_lo, a, dt))
    hi = np.minimum(p_hi, v_prev + a * dt)
    lo_v = np.maximum(p_lo, v_prev - a * dt)
    relaxed = lo_v > hi
    if np.any(relaxed):
        hi = np.where(relaxed, p_hi, hi)
        lo_v = np.where(relaxed, p_lo, lo_v)
    vdt = vmax * dt
    up = np.maximum(np.minimum(hi * dt, s_up), -vdt)
    lo = np.maximum(np.minimum(-lo_v * dt, s_lo), -vdt)
    return up, lo, relaxed


def damper_braking_bound(d: np.ndarray, d_s: float, xi: float, approach_speed: np.ndarray,
                         a: "float | np.ndarray", dt: float) -> np.ndarray:
    """Right-hand side of the damper rows with the approach decelerating at most ``a`` [m/s^2]
    (one value, or one per row):
    per step the distance ``d`` may shrink by ``dt max(braking_speed(d - d_s, a), v - a dt)``
    (``v`` the pair's approach speed at the previous step's velocity: a pair that entered the
    influence distance faster than the braking curve allows, or whose obstacle appeared in a new
    map, keeps braking at ``a`` instead of being stopped in one step), and never by more than
    :func:`damper_bound`'s ``xi max(d - d_s, 0)`` (the Faverjon-Tournassoud damper: ``d`` never
    crosses ``d_s``). Never negative: ``dq = 0`` satisfies every row."""
    s = np.maximum(np.asarray(d, dtype=float) - d_s, 0.0)
    a = np.maximum(a, 1e-6)
    v = np.maximum(braking_speed(s, a, dt), np.asarray(approach_speed, dtype=float) - a * dt)
    return np.minimum(xi * s, dt * v)


def joint_limit_rows(q: np.ndarray, lower: np.ndarray, upper: np.ndarray, dt: float,
                     velocity_limit: np.ndarray, joints: Sequence[int] | None = None) -> LimitRows:
    """Position limits over one step and velocity limits of the selected joints.

    For joint ``j`` (velocity column ``6 + j``):

        dq_j <=  max(min(upper_j - q_j,  v_j dt), -v_j dt)
       -dq_j <=  max(min(q_j - lower_j,  v_j dt), -v_j dt)

    so a joint inside its range stays inside after ``q + dq`` and one outside returns
    at most at the velocity limit (the rows stay consistent).
    """
    nj = len(lower)
    sel = np.arange(nj) if joints is None else np.asarray(joints, dtype=np.intp)
    qj = np.asarray(q, float)[N_BASE_Q + sel]
    vdt = np.asarray(velocity_limit, float)[sel] * dt
    up, lo = joint_step_bounds(qj, np.asarray(lower, float)[sel], np.asarray(upper, float)[sel], vdt)
    k = len(sel)
    G = np.zeros((2 * k, N_BASE_V + nj))
    G[np.arange(k), N_BASE_V + sel] = 1.0
    G[k + np.arange(k), N_BASE_V + sel] = -1.0
    return LimitRows(G, np.concatenate([up, lo]))


def damper_bound(d: np.ndarray, d_s: float, xi: float) -> np.ndarray:
    """Right-hand side ``xi max(d - d_s, 0)`` of the damper rows (never negative)."""
    return xi * np.maximum(np.asarray(d, dtype=float) - d_s, 0.0)


def point_normal_rows(model: pin.Model, data: pin.Data, frame_ids: np.ndarray, points: np.ndarray,
                      normals: np.ndarray) -> np.ndarray:
    """``n_k^T J_{p_k}`` (K, nv) for points ``p_k`` rigidly attached to frames ``frame_ids[k]``.

    Needs :func:`~humanoid_reach_ros.control.tasks.compute_kinematics` on ``data``.
    """
    frame_ids = np.asarray(frame_ids, dtype=np.intp)
    if len(frame_ids) == 0:
        return np.zeros((0, model.nv))
    uniq, inv = np.unique(frame_ids, return_inverse=True)
    J = np.array([pin.getFrameJacobian(model, data, int(f), LWA) for f in uniq])      # (U, 6, nv)
    origins = np.array([data.oMf[int(f)].translation for f in uniq])                 # (U, 3)
    r = points - origins[inv]
    rxn = np.cross(r, normals)
    return np.einsum("ki,kin->kn", normals, J[inv, :3]) + np.einsum("ki,kin->kn", rxn, J[inv, 3:])


def _unit(v: np.ndarray) -> np.ndarray:
    nrm = np.linalg.norm(v, axis=-1, keepdims=True)
    fallback = np.zeros_like(v)
    fallback[..., 2] = 1.0
    return np.where(nrm > 1e-12, v / np.where(nrm > 1e-12, nrm, 1.0), fallback)


def environment_damper_rows(model: pin.Model, data: pin.Data, cm: "CollisionModel", tree: "SphereTree",
                            d_i: float, d_s: float, xi: float) -> LimitRows:
    """Dampers between every robot capsule and every environment sphere within ``d_i``."""
    P0, P1, R = cm.world_shapes(data)
    s_idx, k_idx, _ = tree.spheres_within_batch(P0, P1, R, d_i)
    s_idx = np.asarray(s_idx, dtype=np.intp)
    k_idx = np.asarray(k_idx, dtype=np.intp)
    if len(s_idx) == 0:
        return LimitRows(np.zeros((0, model.nv)), np.zeros(0), np.zeros(0))
    c = tree.centers[k_idx]
    a, b = P0[s_idx], P1[s_idx]
    dist, u = point_segment_distance(c, a, b)
    p = a + u[:, None] * (b - a)
    n = _unit(c - p)
    d = dist - R[s_idx] - tree.radii[k_idx]
    G = point_normal_rows(model, data, cm.frame_ids[cm.shape_link[s_idx]], p, n)
    return LimitRows(G, damper_bound(d, d_s, xi), d)


def self_collision_damper_rows(model: pin.Model, data: pin.Data, cm: "CollisionModel",
                               d_i: float, d_s: float, xi: float) -> LimitRows:
    """Dampers between the self-collision pairs of ``cm`` closer than ``d_i``."""
    P0, P1, R = cm.world_shapes(data)
    i, j = cm.pair_index[:, 0], cm.pair_index[:, 1]
    dist, s, t = segment_segment_distance(P0[i], P1[i], P0[j], P1[j])
    d = dist - R[i] - R[j]
    near = d <= d_i
    if not np.any(near):
        return LimitRows(np.zeros((0, model.nv)), np.zeros(0), np.zeros(0))
    i, j, s, t, d = i[near], j[near], s[near], t[near], d[near]
    pa = P0[i] + s[:, None] * (P1[i] - P0[i])
    pb = P0[j] + t[:, None] * (P1[j] - P0[j])
    n = _unit(pb - pa)
    Ga = point_normal_rows(model, data, cm.frame_ids[cm.shape_link[i]], pa, n)
    Gb = point_normal_rows(model, data, cm.frame_ids[cm.shape_link[j]], pb, n)
    return LimitRows(Ga - Gb, damper_bound(d, d_s, xi), d)


def velocity_damper_rows(model: pin.Model, data: pin.Data, cm: "CollisionModel", tree: "SphereTree | None",
                         d_i: float = 0.10, d_s: float = 0.005, xi: float = 0.5,
                         self_collision: bool = True) -> LimitRows:
    """All velocity-damper rows: environment (if ``tree``) and self-collision pairs."""
    parts = []
    if tree is not None and tree.n_spheres:
        parts.append(environment_damper_rows(model, data, cm, tree, d_i, d_s, xi))
    if self_collision and cm.n_pairs:
        parts.append(self_collision_damper_rows(model, data, cm, d_i, d_s, xi))
    if not parts:
        return LimitRows(np.zeros((0, model.nv)), np.zeros(0), np.zeros(0))
    return LimitRows(np.vstack([p.G for p in parts]), np.concatenate([p.h for p in parts]),
                     np.concatenate([p.distance for p in parts]))


# ---------------------------------------------------------------- fast path (executor)
_JIT = dict(cache=True, nogil=True, fastmath=False)


@nb.njit(**_JIT)
def _set_unit(out, row, x, y, z, length):
    """``out[row] = (x, y, z) / length``, or ``+z`` for a (near) zero vector (coincident points)."""
    if length > 1e-12:
        out[row, 0] = x / length
        out[row, 1] = y / length
        out[row, 2] = z / length
    else:
        out[row, 0] = 0.0
        out[row, 1] = 0.0
        out[row, 2] = 1.0


@nb.njit(**_JIT)
def self_pair_geometry(P0, P1, R, pi, pj, bound):
    """Self-collision pairs (pi[k], pj[k]) of capsules P0, P1 (S, 3), R (S,).

    Returns (index (M,) of the pairs with signed distance <= bound, their closest
    points pa, pb (M, 3) on the segments, unit normals n (M, 3) from a to b, signed
    distances d (M,)) and the smallest signed distance over all pairs."""
    K = pi.shape[0]
    idx = np.empty(K, np.int64)
    pa = np.empty((K, 3))
    pb = np.empty((K, 3))
    nrm = np.empty((K, 3))
    dist = np.empty(K)
    m = 0
    dmin = np.inf
    for k in range(K):
        i = pi[k]
        j = pj[k]
        s, t = closest_segment_params(P0, P1, i, j)
        ax = P0[i, 0] + s * (P1[i, 0] - P0[i, 0])
        ay = P0[i, 1] + s * (P1[i, 1] - P0[i, 1])
        az = P0[i, 2] + s * (P1[i, 2] - P0[i, 2])
        bx = P0[j, 0] + t * (P1[j, 0] - P0[j, 0])
        by = P0[j, 1] + t * (P1[j, 1] - P0[j, 1])
        bz = P0[j, 2] + t * (P1[j, 2] - P0[j, 2])
        dx = bx - ax
        dy = by - ay
        dz = bz - az
        ln = math.sqrt(dx * dx + dy * dy + dz * dz)
        d = ln - R[i] - R[j]
        if d < dmin:
            dmin = d
        if d <= bound:
            idx[m] = k
            pa[m, 0] = ax
            pa[m, 1] = ay
            pa[m, 2] = az
            pb[m, 0] = bx
            pb[m, 1] = by
            pb[m, 2] = bz
            _set_unit(nrm, m, dx, dy, dz, ln)
            dist[m] = d
            m += 1
    return idx[:m].copy(), pa[:m].copy(), pb[:m].copy(), nrm[:m].copy(), dist[:m].copy(), dmin


@nb.njit(**_JIT)
def env_pair_geometry(P0, P1, s_idx, centers):
    """Closest points p (K, 3) on the segments ``s_idx`` to the sphere centres ``centers``
    (K, 3) and unit normals n (K, 3) from p to the centre."""
    K = s_idx.shape[0]
    pts = np.empty((K, 3))
    nrm = np.empty((K, 3))
    for k in range(K):
        s = s_idx[k]
        dx = P1[s, 0] - P0[s, 0]
        dy = P1[s, 1] - P0[s, 1]
        dz = P1[s, 2] - P0[s, 2]
        cx = centers[k, 0] - P0[s, 0]
        cy = centers[k, 1] - P0[s, 1]
        cz = centers[k, 2] - P0[s, 2]
        dd = dx * dx + dy * dy + dz * dz
        u = 0.0
        if dd > 1e-18:
            u = min(max((cx * dx + cy * dy + cz * dz) / dd, 0.0), 1.0)
        px = P0[s, 0] + u * dx
        py = P0[s, 1] + u * dy
        pz = P0[s, 2] + u * dz
        pts[k, 0] = px
        pts[k, 1] = py
        pts[k, 2] = pz
        nx = centers[k, 0] - px
        ny = centers[k, 1] - py
        nz = centers[k, 2] - pz
        ln = math.sqrt(nx * nx + ny * ny + nz * nz)
        _set_unit(nrm, k, nx, ny, nz, ln)
    return pts, nrm


def support_masks(model: pin.Model, frame_ids: Sequence[int]) -> np.ndarray:
    """(F, nv) 0/1 masks of the velocity columns that move each frame (its joint's support)."""
    masks = np.zeros((len(frame_ids), model.nv))
    for r, f in enumerate(frame_ids):
        for j in model.supports[model.frames[int(f)].parentJoint]:
            if j > 0:
                masks[r, model.idx_vs[j]: model.idx_vs[j] + model.nvs[j]] = 1.0
    return masks


@nb.njit(cache=True)       # short kernel: no GIL release (its cost would dominate)
def _add_point_rows(J, masks, index, points, normals, sign, out):
    """``out[k] += sign * (n_k^T J_v + (p_k x n_k)^T J_w)`` on the columns of ``masks[index[k]]``."""
    nv = J.shape[1]
    for k in range(len(index)):
        m = index[k]
        px, py, pz = points[k, 0], points[k, 1], points[k, 2]
        nx, ny, nz = normals[k, 0], normals[k, 1], normals[k, 2]
        cx, cy, cz = py * nz - pz * ny, pz * nx - px * nz, px * ny - py * nx
        for j in range(nv):
            if masks[m, j] != 0.0:
                out[k, j] += sign * (nx * J[0, j] + ny * J[1, j] + nz * J[2, j]
                                     + cx * J[3, j] + cy * J[4, j] + cz * J[5, j])


def world_point_rows(J_world: np.ndarray, masks: np.ndarray, points: np.ndarray, normals: np.ndarray,
                     index: np.ndarray | None = None) -> np.ndarray:
    """``n_k^T J_{p_k}`` (K, nv) from the WORLD joint Jacobian stack ``data.J`` (6, nv)
    filled by ``computeJointJacobians``: ``n^T J_v + (p x n)^T J_w``, restricted to the
    supporting columns of each point's link (the spatial velocity of the world-origin
    point, ``v_p = v_O + w x p``): ``masks`` (K, nv), or (F, nv) with ``index`` (K,)
    naming the row of each point. Same rows as :func:`point_normal_rows` without one
    ``getFrameJacobian`` per link (numba, no temporaries)."""
    points = np.ascontiguousarray(points, dtype=float)
    normals = np.ascontiguousarray(normals, dtype=float)
    index = np.arange(len(points), dtype=np.int64) if index is None else np.ascontiguousarray(index, dtype=np.int64)
    out = np.zeros((len(points), J_world.shape[1]))
    _add_point_rows(np.ascontiguousarray(J_world), masks, index, points, normals, 1.0, out)
    return out


def pair_point_rows(J_world: np.ndarray, masks: np.ndarray, index_a: np.ndarray, points_a: np.ndarray,
                    index_b: np.ndarray, points_b: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Self-collision rows ``n^T (J_{p_a} - J_{p_b})`` (K, nv), see :func:`world_point_rows`."""
    J = np.ascontiguousarray(J_world)
    normals = np.ascontiguousarray(normals, dtype=float)
    out = np.zeros((len(normals), J.shape[1]))
    _add_point_rows(J, masks, np.ascontiguousarray(index_a, dtype=np.int64),
                    np.ascontiguousarray(points_a, dtype=float), normals, 1.0, out)
    _add_point_rows(J, masks, np.ascontiguousarray(index_b, dtype=np.int64),
                    np.ascontiguousarray(points_b, dtype=float), normals, -1.0, out)
    return out


def warm_up() -> None:
    """Compile (or load from the on-disk cache) the numba kernels of this module."""
    P = np.zeros((2, 3))
    P[1, 0] = 1.0
    self_pair_geometry(P, P + 0.5, np.full(2, 0.1), np.zeros(1, np.int64), np.ones(1, np.int64), 0.1)
    env_pair_geometry(P, P + 0.5, np.zeros(1, np.int64), np.zeros((1, 3)))
    pair_point_rows(np.zeros((6, 3)), np.ones((2, 3)), np.zeros(1, np.int64), P[:1], np.ones(1, np.int64), P[1:],
                    P[1:])


__all__ = ["joint_step_bounds", "braking_speed", "joint_step_box", "damper_braking_bound",
           "LimitRows", "damper_bound", "joint_limit_rows", "point_normal_rows",
           "environment_damper_rows", "self_collision_damper_rows", "velocity_damper_rows", "self_pair_geometry",
           "env_pair_geometry", "support_masks", "world_point_rows", "pair_point_rows", "warm_up"]
