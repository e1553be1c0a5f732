"""Robot shapes vs the environment sphere tree and vs each other (Kanehiro et al., Sec. II).

:class:`RobotCollision` turns configurations ``q`` (pinocchio free-flyer layout:
base xyz, base quaternion xyzw, 30 joints) into the world capsules of the collision
model (:mod:`humanoid_reach_ros.robot.shapes`) and checks them

* against the environment: signed distance ``|c_i - seg(p0, p1)| - r_i - r < 0`` for
  some environment sphere ``i`` of the :class:`~humanoid_reach_ros.geometry.sphere_tree.SphereTree`
  (branch and bound, early exit);
* against themselves: the model's self-collision pairs, exact segment-segment distance
  minus both radii ``< self_margin_m``.

A configuration is *valid* when neither holds. Feet against the floor are not checked
(the feet stay on their stance poses; the voxel map is built without the floor).

Forward kinematics and checks run in numba over a batch of C configurations, with no
Python per configuration: every joint of this model is revolute about a local axis
(x, y or z) after a constant placement, so ``oMi[j] = oMi[parent] * M_j * R_axis(q_j)``
in topological order; shape-carrying links are ``oMi[parent] * M_frame``. The
pinocchio model is only read at construction (and :meth:`RobotCollision.world_shapes_pin`
keeps a pinocchio path for cross-checking). FK and collision time are counted apart
(:class:`CollisionCounters`). This module never imports rclpy.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numba as nb
import numpy as np

from humanoid_reach_ros.geometry.sphere_tree import SphereTree, tree_any_intersection
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.shapes import CollisionModel

#: nogil=False on purpose: these kernels run on the planning thread of a multithreaded rclpy
#: node (reach_planner). Releasing the GIL for each ~50 us call lets the executor threads
#: (200 Hz /joint_states) take it, and the planning thread then queues to get it back
#: (GIL convoy): bench/operator_wait.py measured plans 2.1x slower in the node than
#: in-process with nogil=True, 1.06x with nogil=False (per-request medians, same load).
#: Nothing runs these kernels in parallel threads, so holding the GIL costs nothing.
_JIT = dict(cache=True, nogil=False, fastmath=False)


@nb.njit(**_JIT)
def quaternion_rotation(x: float, y: float, z: float, w: float, out: np.ndarray) -> None:
    """``out`` (3, 3) = the rotation of the quaternion ``(x, y, z, w)`` (normalised here)."""
    n = 1.0 / math.sqrt(x * x + y * y + z * z + w * w)
    x *= n
    y *= n
    z *= n
    w *= n
    out[0, 0] = 1 - 2 * (y * y + z * z)
    out[0, 1] = 2 * (x * y - z * w)
    out[0, 2] = 2 * (x * z + y * w)
    out[1, 0] = 2 * (x * y + z * w)
    out[1, 1] = 1 - 2 * (x * x + z * z)
    out[1, 2] = 2 * (y * z - x * w)
    out[2, 0] = 2 * (x * z - y * w)
    out[2, 1] = 2 * (y * z + x * w)
    out[2, 2] = 1 - 2 * (x * x + y * y)
_AXES = {"JointModelRX": 0, "JointModelRY": 1, "JointModelRZ": 2}


def _z_to(axis: np.ndarray) -> np.ndarray:
    """A rotation B with B e_z = ``axis`` (unit)."""
    a = axis / np.linalg.norm(axis)
    e = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(e, a)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(a, x), a])


# =================================================================== kernels
@nb.njit(**_JIT)
def _fk_shapes_kernel(Q, jparent, jaxis, jR, jt, jq, lj, lR, lt, sl, p0l, p1l, P0, P1):
    """World segment ends P0, P1 (C, S, 3) of C configurations Q (C, nq)."""
    C = Q.shape[0]
    J = jparent.shape[0]
    L = lj.shape[0]
    S = sl.shape[0]
    oR = np.empty((J + 1, 3, 3))   # slot 0: base, slot j + 1: joint j
    ot = np.empty((J + 1, 3))
    LR = np.empty((L, 3, 3))
    Lt = np.empty((L, 3))
    A = np.empty((3, 3))
    for c in range(C):
        # base: translation + unit quaternion (x, y, z, w)
        quaternion_rotation(Q[c, 3], Q[c, 4], Q[c, 5], Q[c, 6], oR[0])
        ot[0, 0] = Q[c, 0]
        ot[0, 1] = Q[c, 1]
        ot[0, 2] = Q[c, 2]
        for j in range(J):
            p = jparent[j] + 1
            # A = oR[p] * jR[j]; t = ot[p] + oR[p] jt[j]
            for a in range(3):
                for b in range(3):
                    A[a, b] = oR[p, a, 0] * jR[j, 0, b] + oR[p, a, 1] * jR[j, 1, b] + oR[p, a, 2] * jR[j, 2, b]
                ot[j + 1, a] = ot[p, a] + oR[p, a, 0] * jt[j, 0] + oR[p, a, 1] * jt[j, 1] + oR[p, a, 2] * jt[j, 2]
            th = Q[c, jq[j]]
            cs = math.cos(th)
            sn = math.sin(th)
            ax = jaxis[j]
            for a in range(3):
                if ax == 0:      # A Rx
                    oR[j + 1, a, 0] = A[a, 0]
                    oR[j + 1, a, 1] = A[a, 1] * cs + A[a, 2] * sn
                    oR[j + 1, a, 2] = -A[a, 1] * sn + A[a, 2] * cs
                elif ax == 1:    # A Ry
                    oR[j + 1, a, 0] = A[a, 0] * cs - A[a, 2] * sn
                    oR[j + 1, a, 1] = A[a, 1]
                    oR[j + 1, a, 2] = A[a, 0] * sn + A[a, 2] * cs
                else:            # A Rz
                    oR[j + 1, a, 0] = A[a, 0] * cs + A[a, 1] * sn
                    oR[j + 1, a, 1] = -A[a, 0] * sn + A[a, 1] * cs
                    oR[j + 1, a, 2] = A[a, 2]
        for k in range(L):
            p = lj[k] + 1
            for a in range(3):
                for b in range(3):
                    LR[k, a, b] = oR[p, a, 0] * lR[k, 0, b] + oR[p, a, 1] * lR[k, 1, b] + oR[p, a, 2] * lR[k, 2, b]
                Lt[k, a] = ot[p, a] + oR[p, a, 0] * lt[k, 0] + oR[p, a, 1] * lt[k, 1] + oR[p, a, 2] * lt[k, 2]
        for s in range(S):
            k = sl[s]
            for a in range(3):
                P0[c, s, a] = Lt[k, a] + LR[k, a, 0] * p0l[s, 0] + LR[k, a, 1] * p0l[s, 1] + LR[k, a, 2] * p0l[s, 2]
                P1[c, s, a] = Lt[k, a] + LR[k, a, 0] * p1l[s, 0] + LR[k, a, 1] * p1l[s, 1] + LR[k, a, 2] * p1l[s, 2]


@nb.njit(**_JIT)
def closest_segment_params(P0, P1, i, j):
    """Parameters (s, t) in [0, 1] of the closest points P0[i] + s d_i and P0[j] + t d_j of
    segments i and j (rows of P0, P1) (Ericson 5.1.9)."""
    d1x = P1[i, 0] - P0[i, 0]
    d1y = P1[i, 1] - P0[i, 1]
    d1z = P1[i, 2] - P0[i, 2]
    d2x = P1[j, 0] - P0[j, 0]
    d2y = P1[j, 1] - P0[j, 1]
    d2z = P1[j, 2] - P0[j, 2]
    rx = P0[i, 0] - P0[j, 0]
    ry = P0[i, 1] - P0[j, 1]
    rz = P0[i, 2] - P0[j, 2]
    a = d1x * d1x + d1y * d1y + d1z * d1z
    e = d2x * d2x + d2y * d2y + d2z * d2z
    f = d2x * rx + d2y * ry + d2z * rz
    eps = 1e-18
    if a <= eps and e <= eps:
        return 0.0, 0.0
    if a <= eps:
        return 0.0, min(max(f / e, 0.0), 1.0)
    c = d1x * rx + d1y * ry + d1z * rz
    if e <= eps:
        return min(max(-c / a, 0.0), 1.0), 0.0
    b = d1x * d2x + d1y * d2y + d1z * d2z
    den = a * e - b * b
    s = min(max((b * f - c * e) / den, 0.0), 1.0) if den > 1e-14 * a * e else 0.0
    t = (b * s + f) / e
    if t < 0.0:
        t = 0.0
        s = min(max(-c / a, 0.0), 1.0)
    elif t > 1.0:
        t = 1.0
        s = min(max((b - c) / a, 0.0), 1.0)
    return s, t


@nb.njit(**_JIT)
def _seg_seg_dist(P0, P1, i, j):
    """Exact distance between segments i and j of one configuration."""
    s, t = closest_segment_params(P0, P1, i, j)
    dx = P0[i, 0] + s * (P1[i, 0] - P0[i, 0]) - P0[j, 0] - t * (P1[j, 0] - P0[j, 0])
    dy = P0[i, 1] + s * (P1[i, 1] - P0[i, 1]) - P0[j, 1] - t * (P1[j, 1] - P0[j, 1])
    dz = P0[i, 2] + s * (P1[i, 2] - P0[i, 2]) - P0[j, 2] - t * (P1[j, 2] - P0[j, 2])
    return math.sqrt(dx * dx + dy * dy + dz * dz)


@nb.njit(**_JIT)
def _self_hit(P0, P1, pi, pj, R, margin):
    for k in range(pi.shape[0]):
        i = pi[k]
        j = pj[k]
        if _seg_seg_dist(P0, P1, i, j) - R[i] - R[j] < margin:
            return True
    return False


@nb.njit(**_JIT)
def _self_min(P0, P1, pi, pj, R):
    best = np.inf
    for k in range(pi.shape[0]):
        d = _seg_seg_dist(P0, P1, pi[k], pj[k]) - R[pi[k]] - R[pj[k]]
        if d < best:
            best = d
    return best


@nb.njit(**_JIT)
def _check_kernel(P0, P1, R, order, pi, pj, R_self, margin, nodes, children, depth, do_env, do_self, stop_early,
                  out_env, out_self):
    """Per configuration: env hit (ordered shapes, early exit) and self hit (pairs).

    With ``stop_early`` the second test is skipped once the first one failed (its
    output is then False); self-collision is tested first (fixed, small cost)."""
    C = P0.shape[0]
    Q0 = np.empty((order.shape[0], 3))
    Q1 = np.empty((order.shape[0], 3))
    RO = np.empty(order.shape[0])
    for s in range(order.shape[0]):
        RO[s] = R[order[s]]
    for c in range(C):
        hit_self = False
        if do_self:
            hit_self = _self_hit(P0[c], P1[c], pi, pj, R_self, margin)
        out_self[c] = hit_self
        hit_env = False
        if do_env and not (stop_early and hit_self):
            for s in range(order.shape[0]):
                for a in range(3):
                    Q0[s, a] = P0[c, order[s], a]
                    Q1[s, a] = P1[c, order[s], a]
            hit_env = tree_any_intersection(nodes, children, depth, Q0, Q1, RO)
        out_env[c] = hit_env


@nb.njit(**_JIT)
def _first_hit_kernel(Q, jparent, jaxis, jR, jt, jq, lj, lR, lt, sl, p0l, p1l, R, order, pi, pj, margin, nodes,
                      children, depth, do_env):
    """Configurations in order: FK, self then environment test; returns the index of
    the first one in collision (or C) -- the rows after it are never computed."""
    C = Q.shape[0]
    S = sl.shape[0]
    P0 = np.empty((1, S, 3))
    P1 = np.empty((1, S, 3))
    out_env = np.zeros(1, np.bool_)
    out_self = np.zeros(1, np.bool_)
    for c in range(C):
        _fk_shapes_kernel(Q[c:c + 1], jparent, jaxis, jR, jt, jq, lj, lR, lt, sl, p0l, p1l, P0, P1)
        _check_kernel(P0, P1, R, order, pi, pj, R, margin, nodes, children, depth, do_env, True, True,
                      out_env, out_self)
        if out_env[0] or out_self[0]:
            return c
    return C


# =================================================================== Python API
@dataclass
class CollisionCounters:
    """Statistics of a :class:`RobotCollision` (reset with :meth:`RobotCollision.reset_counters`).

    ``checks``: configurations checked; ``calls``: API calls; ``check_time_s``: time
    in the collision tests (environment + self) only -- except for
    :meth:`RobotCollision.first_collision`, whose kernel interleaves FK and tests and
    counts both here; ``fk_time_s``: time computing world capsules from configurations.
    """

    checks: int = 0
    calls: int = 0
    check_time_s: float = 0.0
    fk_time_s: float = 0.0

    @property
    def check_time_per_config_s(self) -> float:
        return self.check_time_s / self.checks if self.checks else 0.0

    @property
    def fk_time_per_config_s(self) -> float:
        return self.fk_time_s / self.checks if self.checks else 0.0


class RobotCollision:
    """Collision checker of the robot's capsules vs a sphere tree and vs themselves.

    ``robot``: :class:`RobotModel`; ``collision_model``: its :class:`CollisionModel`
    (padded radii used against the environment); ``tree``: the environment
    :class:`SphereTree`; ``self_margin_m``: self pairs closer than this collide
    (default 0: penetration of the padded shapes).

    Configurations: ``q`` (nq,) or ``Q`` (C, nq) in the pinocchio layout; the joint
    positions are read from ``q`` (no limits check here).
    """

    def __init__(self, robot: RobotModel, collision_model: CollisionModel, tree: SphereTree,
                 self_margin_m: float = 0.0) -> None:
        self.robot = robot
        self.cm = collision_model
        self.tree = tree
        self.self_margin_m = float(self_margin_m)
        m = robot.model
        # joints 2.. (1 is the free flyer); index 0 of our arrays = pinocchio joint 2
        J = m.njoints - 2
        jparent = np.empty(J, np.int64)
        jaxis = np.empty(J, np.int64)
        jR = np.empty((J, 3, 3))
        jt = np.empty((J, 3))
        jq = np.empty(J, np.int64)
        tilt = {}   # joint index k -> B with B e_z = its axis (a revolute joint about any fixed axis)
        for k in range(J):
            j = k + 2
            short = m.joints[j].shortname()
            if short == "JointModelRevoluteUnaligned":
                tilt[k] = _z_to(np.asarray(m.joints[j].extract().axis, float))
                short = "JointModelRZ"
            if short not in _AXES:
                raise ValueError(f"RobotCollision: joint {m.names[j]!r} is {short}, expected a revolute joint about "
                                 "a fixed axis")
            par = m.parents[j]
            if par < 1 or par >= j:
                raise ValueError(f"RobotCollision: joint {m.names[j]!r} has parent {par}; expected the base or an "
                                 "earlier joint")
            jparent[k] = par - 2   # -1: base
            jaxis[k] = _AXES[short]
            jR[k] = m.jointPlacements[j].rotation
            jt[k] = m.jointPlacements[j].translation
            jq[k] = m.idx_qs[j]
        L = len(collision_model.links)
        lj = np.empty(L, np.int64)
        lR = np.empty((L, 3, 3))
        lt = np.empty((L, 3))
        for k, fid in enumerate(collision_model.frame_ids):
            fr = m.frames[int(fid)]
            if fr.parentJoint < 1:
                raise ValueError(f"RobotCollision: link {collision_model.links[k]!r} is fixed to the universe")
            lj[k] = fr.parentJoint - 2
            lR[k] = fr.placement.rotation
            lt[k] = fr.placement.translation
        # a joint about any axis a is R(a, q) = B Rz(q) B^T: its frame is turned by B (placement
        # M B), and what hangs from it (child joints, shape links) by B^T -- the kernels stay z-only
        for k, B in tilt.items():
            jR[k] = jR[k] @ B
            for c in np.flatnonzero(jparent == k):
                jR[c], jt[c] = B.T @ jR[c], B.T @ jt[c]
            for c in np.flatnonzero(lj == k):
                lR[c], lt[c] = B.T @ lR[c], B.T @ lt[c]
        self._fk_args = (jparent, jaxis, jR, jt, jq, lj, lR, lt,
                         np.ascontiguousarray(collision_model.shape_link, dtype=np.int64),
                         np.ascontiguousarray(collision_model.p0_local), np.ascontiguousarray(collision_model.p1_local))
        self.radii = np.ascontiguousarray(collision_model.radii, dtype=float)
        # shapes tested first against the environment: the likeliest to hit, those farthest down
        # the kinematic tree (hands, forearms, ...); the verdict does not depend on the order
        depth = np.zeros(J + 1, np.int64)        # depth[k + 1]: joints from the base to joint k
        for k in range(J):
            depth[k + 1] = depth[jparent[k] + 1] + 1
        shape_depth = depth[lj[np.asarray(collision_model.shape_link)] + 1]
        self.env_order = np.argsort(-shape_depth, kind="stable").astype(np.int64)
        self._pi = np.ascontiguousarray(collision_model.pair_index[:, 0], dtype=np.int64)
        self._pj = np.ascontiguousarray(collision_model.pair_index[:, 1], dtype=np.int64)
        self.counters = CollisionCounters()

    # ------------------------------------------------------------ kinematics
    def _as_batch(self, Q) -> np.ndarray:
        Q = np.ascontiguousarray(Q, dtype=np.float64)
        if Q.ndim == 1:
            Q = Q[None]
        if Q.ndim != 2 or Q.shape[1] != self.robot.model.nq:
            raise ValueError(f"expected configurations of shape (C, {self.robot.model.nq}), got {Q.shape}")
        return Q

    def world_shapes_batch(self, Q) -> tuple[np.ndarray, np.ndarray]:
        """World segment ends P0, P1 (C, S, 3) of configurations Q (C, nq) (numba FK)."""
        Q = self._as_batch(Q)
        P0 = np.empty((len(Q), self.cm.n_shapes, 3))
        P1 = np.empty_like(P0)
        t0 = time.perf_counter()
        _fk_shapes_kernel(Q, *self._fk_args, P0, P1)
        self.counters.fk_time_s += time.perf_counter() - t0
        return P0, P1

    def world_shapes(self, q) -> tuple[np.ndarray, np.ndarray]:
        """World segment ends P0, P1 (S, 3) of one configuration."""
        P0, P1 = self.world_shapes_batch(q)
        return P0[0], P1[0]

    def world_shapes_pin(self, q) -> tuple[np.ndarray, np.ndarray]:
        """The same from pinocchio's forward kinematics (reference path, slower)."""
        P0, P1, _ = self.cm.world_shapes(np.asarray(q, dtype=float))
        return P0, P1

    # ------------------------------------------------------------ checks
    def _run(self, Q, do_env: bool, do_self: bool, stop_early: bool) -> tuple[np.ndarray, np.ndarray]:
        P0, P1 = self.world_shapes_batch(Q)
        return self.check_shapes(P0, P1, do_env, do_self, stop_early)

    def check_shapes(self, P0: np.ndarray, P1: np.ndarray, do_env: bool = True, do_self: bool = True,
                     stop_early: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """(env hit (C,), self hit (C,)) of world capsules P0, P1 (C, S, 3); counted."""
        C = P0.shape[0]
        out_env = np.zeros(C, np.bool_)
        out_self = np.zeros(C, np.bool_)
        do_env = bool(do_env and self.tree.n_spheres > 0)
        t0 = time.perf_counter()
        _check_kernel(P0, P1, self.radii, self.env_order, self._pi, self._pj, self.radii, self.self_margin_m,
                      self.tree.nodes, self.tree.children, self.tree.depth, do_env, bool(do_self), bool(stop_early),
                      out_env, out_self)
        c = self.counters
        c.check_time_s += time.perf_counter() - t0
        c.checks += C
        c.calls += 1
        return out_env, out_self

    def in_collision_env(self, q) -> bool | np.ndarray:
        """Does a robot shape penetrate the environment? bool for q (nq,), (C,) for Q (C, nq)."""
        env, _ = self._run(q, True, False, False)
        return bool(env[0]) if np.ndim(q) == 1 else env

    def in_self_collision(self, q) -> bool | np.ndarray:
        """Is some self-collision pair closer than ``self_margin_m``? bool or (C,)."""
        _, slf = self._run(q, False, True, False)
        return bool(slf[0]) if np.ndim(q) == 1 else slf

    def check(self, q) -> bool:
        """True when the configuration is collision-free (environment and self)."""
        env, slf = self._run(q, True, True, True)
        return not (env[0] or slf[0])

    def check_batch(self, Q) -> np.ndarray:
        """(C,) bool: collision-free, per configuration (e.g. an edge at a resolution)."""
        env, slf = self._run(Q, True, True, True)
        return ~(env | slf)

    def first_collision(self, Q) -> int:
        """Index of the first configuration of ``Q`` (C, nq) in collision (environment or
        self), or C when all are free. Configurations after it are not computed (a
        path or edge check that only needs the first invalid point). Counted: the
        configurations computed, FK and check time together in ``check_time_s``."""
        Q = self._as_batch(Q)
        t0 = time.perf_counter()
        k = _first_hit_kernel(Q, *self._fk_args, self.radii, self.env_order, self._pi, self._pj, self.self_margin_m,
                              self.tree.nodes, self.tree.children, self.tree.depth, bool(self.tree.n_spheres > 0))
        c = self.counters
        c.check_time_s += time.perf_counter() - t0
        c.checks += min(int(k) + 1, len(Q))
        c.calls += 1
        return int(k)

    def min_distance(self, q) -> float:
        """Smallest signed distance [m] between a robot shape and the environment."""
        P0, P1 = self.world_shapes(q)
        if self.tree.n_spheres == 0:
            return math.inf
        return float(np.min(self.tree.min_distance_batch(P0, P1, self.radii)))

    def self_min_distance(self, q) -> float:
        """Smallest signed distance [m] over the self-collision pairs."""
        P0, P1 = self.world_shapes(q)
        return float(_self_min(P0, P1, self._pi, self._pj, self.radii))

    def reset_counters(self) -> None:
        self.counters = CollisionCounters()


__all__ = ["RobotCollision", "CollisionCounters"]
