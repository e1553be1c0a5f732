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
  the factor ``1 - xi`` per step, so ``d`` never crosses ``d_s``. With ``n`` the unit
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
from typing import TYPE_CHECKING, Sequence

import numpy as np
import pinocchio as pin

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
    up = np.maximum(np.minimum(np.asarray(upper, float)[sel] - qj, vdt), -vdt)
    lo = np.maximum(np.minimum(qj - np.asarray(lower, float)[sel], vdt), -vdt)
    k = len(sel)
    G = np.zeros((2 * k, N_BASE_V + nj))
    G[np.arange(k), N_BASE_V + sel] = 1.0
    G[k + np.arange(k), N_BASE_V + sel] = -1.0
    return LimitRows(G, np.concatenate([up, lo]))


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
    O = np.array([data.oMf[int(f)].translation for f in uniq])                       # (U, 3)
    r = points - O[inv]
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
    return LimitRows(G, xi * (d - d_s), d)


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
    return LimitRows(Ga - Gb, xi * (d - d_s), d)


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


__all__ = ["LimitRows", "joint_limit_rows", "point_normal_rows", "environment_damper_rows",
           "self_collision_damper_rows", "velocity_damper_rows"]
