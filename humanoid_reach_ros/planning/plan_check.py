"""Validity of planning-space rows, fused and specialised to the planning manifold.

The planner's checker (:meth:`ReachPlanner.validity_fn`) takes rows ``q_plan = (q_arm,
z_t, rpy_t)`` (eq. 2), projects them (trunk above COG_approx, legs by closed-form IK,
arm limits: :meth:`Projector.project_plan_config`) and checks the full configurations
with :class:`~humanoid_reach_ros.geometry.distance.RobotCollision`. :class:`PlanChecker`
gives the same answers with less work per configuration, in one numba kernel per call:

* **fused, with early exit**: each row is projected, its capsules computed and checked
  before the next row is touched; ``first_invalid`` stops at the first invalid row (no
  projection or forward kinematics of the rows after it);
* **forward kinematics on the manifold**: every joint that the projection does not set
  (chest, head, grippers, the other arm) is at its reference value, so every link whose
  path to the trunk crosses none of the moving joints (the planning arm, both legs) is
  rigidly attached to the trunk: its capsules are the trunk pose times constant
  trunk-frame capsules computed once; only the moving chains are composed joint by joint;
* **self-collision pairs**: a pair of shapes rigid with respect to each other on the
  manifold (e.g. the other arm vs the chest) keeps one distance for every row; it is
  measured once at construction and dropped when it is clear of the margin (when it is
  not, every row collides and is reported so); every other pair is first tested on
  bounding spheres (centre of the segment, half its length + radius) and the exact
  segment-segment distance computed only where the spheres come within the margin
  (plus 1e-9 m: rounding never flips an answer).

The checks are the same as the unfused path's -- same capsules and padded radii, same
sphere tree and self margin, same joint limits -- so the verdicts are the same (the
tests compare them on random rows). The legs are solved in the kernel by the hand-derived
compiled leg kernel (``kinematics/hand_derived.py``, ``leg_ik_pose``, through the projector's
kernel): a planner whose legs have another solver runs the unfused path. No ROS here.
"""
from __future__ import annotations

import math
import time

import numba as nb
import numpy as np

from humanoid_reach_ros.geometry.batch_collision import LANES, batch_checker, check_lanes, lane_workspace
from humanoid_reach_ros.geometry.distance import RobotCollision, _fk_shapes_kernel, _seg_seg_dist, quaternion_rotation
from humanoid_reach_ros.geometry.sphere_tree import tree_any_intersection
from humanoid_reach_ros.planning.projector import LEGS, Projector, _project_plan_kernel

_JIT = dict(cache=True, nogil=False, fastmath=False)
#: bounding-sphere slack [m] of the self-pair prefilter
BOUND_SLACK = 1e-9


@nb.njit(**_JIT)
def _fk_manifold(q, jparent, jaxis, jR, jt, jq, jmode, relR, relt, lj, lR, lt, lrigid, sl, p0l, p1l, p0b, p1b,
                 srigid, oR, ot, LR, Lt, A, P0, P1):
    """World capsule ends P0, P1 (S, 3) of one full configuration ``q`` on the manifold.

    ``jmode[j]``: 0 skip (rigid, nothing moving below), 1 rigid but needed (pose = trunk
    * relR/relt), 2 moving (composed from its parent). Shapes with ``srigid`` come from
    the trunk-frame ends ``p0b``/``p1b``; the others from their link pose."""
    quaternion_rotation(q[3], q[4], q[5], q[6], oR[0])
    ot[0, 0] = q[0]
    ot[0, 1] = q[1]
    ot[0, 2] = q[2]
    J = jparent.shape[0]
    for j in range(J):
        mode = jmode[j]
        if mode == 0:
            continue
        if mode == 1:
            for a in range(3):
                for b in range(3):
                    oR[j + 1, a, b] = (oR[0, a, 0] * relR[j, 0, b] + oR[0, a, 1] * relR[j, 1, b]
                                       + oR[0, a, 2] * relR[j, 2, b])
                ot[j + 1, a] = ot[0, a] + oR[0, a, 0] * relt[j, 0] + oR[0, a, 1] * relt[j, 1] + oR[0, a, 2] * relt[j, 2]
            continue
        p = jparent[j] + 1
        for a in range(3):
            for b in range(3):
                A[a, b] = oR[p, a, 0] * jR[j, 0, b] + oR[p, a, 1] * jR[j, 1, b] + oR[p, a, 2] * jR[j, 2, b]
            ot[j + 1, a] = ot[p, a] + oR[p, a, 0] * jt[j, 0] + oR[p, a, 1] * jt[j, 1] + oR[p, a, 2] * jt[j, 2]
        th = q[jq[j]]
        cs = math.cos(th)
        sn = math.sin(th)
        ax = jaxis[j]
        for a in range(3):
            if ax == 0:
                oR[j + 1, a, 0] = A[a, 0]
                oR[j + 1, a, 1] = A[a, 1] * cs + A[a, 2] * sn
                oR[j + 1, a, 2] = -A[a, 1] * sn + A[a, 2] * cs
            elif ax == 1:
                oR[j + 1, a, 0] = A[a, 0] * cs - A[a, 2] * sn
                oR[j + 1, a, 1] = A[a, 1]
                oR[j + 1, a, 2] = A[a, 0] * sn + A[a, 2] * cs
            else:
                oR[j + 1, a, 0] = A[a, 0] * cs + A[a, 1] * sn
                oR[j + 1, a, 1] = -A[a, 0] * sn + A[a, 1] * cs
                oR[j + 1, a, 2] = A[a, 2]
    for k in range(lj.shape[0]):
        if lrigid[k]:
            continue
        p = lj[k] + 1
        for a in range(3):
            for b in range(3):
                LR[k, a, b] = oR[p, a, 0] * lR[k, 0, b] + oR[p, a, 1] * lR[k, 1, b] + oR[p, a, 2] * lR[k, 2, b]
            Lt[k, a] = ot[p, a] + oR[p, a, 0] * lt[k, 0] + oR[p, a, 1] * lt[k, 1] + oR[p, a, 2] * lt[k, 2]
    for s in range(sl.shape[0]):
        if srigid[s]:
            for a in range(3):
                P0[s, a] = ot[0, a] + oR[0, a, 0] * p0b[s, 0] + oR[0, a, 1] * p0b[s, 1] + oR[0, a, 2] * p0b[s, 2]
                P1[s, a] = ot[0, a] + oR[0, a, 0] * p1b[s, 0] + oR[0, a, 1] * p1b[s, 1] + oR[0, a, 2] * p1b[s, 2]
        else:
            k = sl[s]
            for a in range(3):
                P0[s, a] = Lt[k, a] + LR[k, a, 0] * p0l[s, 0] + LR[k, a, 1] * p0l[s, 1] + LR[k, a, 2] * p0l[s, 2]
                P1[s, a] = Lt[k, a] + LR[k, a, 0] * p1l[s, 0] + LR[k, a, 1] * p1l[s, 1] + LR[k, a, 2] * p1l[s, 2]


@nb.njit(**_JIT)
def _self_hit_bounded(P0, P1, pi, pj, R, margin, C, BR):
    """Any pair (pi[k], pj[k]) closer than ``margin``? Bounding spheres first."""
    for s in range(P0.shape[0]):
        dx = P1[s, 0] - P0[s, 0]
        dy = P1[s, 1] - P0[s, 1]
        dz = P1[s, 2] - P0[s, 2]
        C[s, 0] = P0[s, 0] + 0.5 * dx
        C[s, 1] = P0[s, 1] + 0.5 * dy
        C[s, 2] = P0[s, 2] + 0.5 * dz
        BR[s] = 0.5 * math.sqrt(dx * dx + dy * dy + dz * dz) + R[s]
    lim = margin + BOUND_SLACK
    for k in range(pi.shape[0]):
        i = pi[k]
        j = pj[k]
        dx = C[i, 0] - C[j, 0]
        dy = C[i, 1] - C[j, 1]
        dz = C[i, 2] - C[j, 2]
        if math.sqrt(dx * dx + dy * dy + dz * dz) - BR[i] - BR[j] >= lim:
            continue
        if _seg_seg_dist(P0, P1, i, j) - R[i] - R[j] < margin:
            return True
    return False


@nb.njit(**_JIT)
def _row_valid(q_row, proj, fk, pi, pj, R, order, RO, margin, nodes, children, depth, do_env, all_hit, W, counts):
    """One q_plan row: project, capsules, self then environment test (``W``: scratch)."""
    Q, ok, tp, tR, fails, oR, ot, LR, Lt, A, P0, P1, C, BR, O0, O1 = W
    (v, cog_xy, q_ref, arm_cols, arm_lo, arm_hi, leg_cols, feet_p, feet_R, leg_ref, R0, t0, Re, te, l1, l2, leg_lo,
     leg_hi) = proj
    jparent, jaxis, jR, jt, jq, jmode, relR, relt, lj, lR, lt, lrigid, sl, p0l, p1l, p0b, p1b, srigid = fk
    _project_plan_kernel(q_row, v, cog_xy, q_ref, arm_cols, arm_lo, arm_hi, leg_cols, feet_p, feet_R, leg_ref, R0,
                         t0, Re, te, l1, l2, leg_lo, leg_hi, Q, ok, tp, tR, fails)
    counts[0] += 1
    if not ok[0]:
        return False
    counts[1] += 1
    if all_hit:
        return False
    _fk_manifold(Q[0], jparent, jaxis, jR, jt, jq, jmode, relR, relt, lj, lR, lt, lrigid, sl, p0l, p1l, p0b, p1b,
                 srigid, oR, ot, LR, Lt, A, P0, P1)
    if _self_hit_bounded(P0, P1, pi, pj, R, margin, C, BR):
        return False
    if do_env:
        for s in range(P0.shape[0]):
            for a in range(3):
                O0[s, a] = P0[order[s], a]
                O1[s, a] = P1[order[s], a]
        if tree_any_intersection(nodes, children, depth, O0, O1, RO):
            return False
    return True


@nb.njit(**_JIT)
def _scratch(nq, J, L, S):
    return (np.empty((1, nq)), np.empty(1, np.bool_), np.empty((1, 3)), np.empty((1, 3, 3)), np.zeros(3, np.int64),
            np.empty((J + 1, 3, 3)), np.empty((J + 1, 3)), np.empty((L, 3, 3)), np.empty((L, 3)), np.empty((3, 3)),
            np.empty((S, 3)), np.empty((S, 3)), np.empty((S, 3)), np.empty(S), np.empty((S, 3)), np.empty((S, 3)))


@nb.njit(**_JIT)
def _radii_in_order(R, order):
    RO = np.empty(order.shape[0])
    for s in range(order.shape[0]):
        RO[s] = R[order[s]]
    return RO


@nb.njit(**_JIT)
def _plan_rows_kernel(q_plan, stop_first, proj, fk, R, order, pi, pj, margin, nodes, children, depth, do_env,
                      all_hit, out, counts):
    """Rows in order; ``out[k]``: row valid. With ``stop_first`` returns at the first
    invalid row (its index; n if none), the rows after it untouched. ``counts``: (rows
    projected, rows collision-checked)."""
    n = q_plan.shape[0]
    W = _scratch(proj[2].shape[0], fk[0].shape[0], fk[8].shape[0], fk[12].shape[0])
    RO = _radii_in_order(R, order)
    first = n
    for k in range(n):
        good = _row_valid(q_plan[k:k + 1], proj, fk, pi, pj, R, order, RO, margin, nodes, children, depth, do_env,
                          all_hit, W, counts)
        out[k] = good
        if not good and first == n:
            first = k
            if stop_first:
                return first
    return first


@nb.njit(**_JIT)
def _bisect_fill(lo, hi, buf, queue):
    """:func:`~humanoid_reach_ros.planning.space.bisect_order` of ``range(lo, hi + 1)``
    into ``buf``; returns the count."""
    n_out = 0
    if hi < lo:
        return 0
    head = 0
    tail = 0
    queue[tail, 0] = lo
    queue[tail, 1] = hi
    tail += 1
    while head < tail:
        a = queue[head, 0]
        b = queue[head, 1]
        head += 1
        if b - a < 2:
            continue
        mid = (a + b) // 2
        buf[n_out] = mid
        n_out += 1
        queue[tail, 0] = a
        queue[tail, 1] = mid
        tail += 1
        queue[tail, 0] = mid
        queue[tail, 1] = b
        tail += 1
    buf[n_out] = lo
    n_out += 1
    if hi > lo:
        buf[n_out] = hi
        n_out += 1
    return n_out


@nb.njit(**_JIT)
def _bisect_buffers(m):
    """Scratch of :func:`_edge_order` for edges of up to ``max(m)`` steps."""
    mmax = 1
    for e in range(m.shape[0]):
        mmax = max(mmax, m[e])
    return np.empty(mmax + 2, np.int64), np.empty((2 * mmax + 4, 2), np.int64)


@nb.njit(**_JIT)
def _edge_order(me, with_ends, buf, queue):
    """The step indices of an edge of ``me`` steps (``0..me`` with ``with_ends``, else
    ``1..me-1``) in bisect order into ``buf``; returns their count."""
    if with_ends:
        return _bisect_fill(0, me, buf, queue)
    return _bisect_fill(1, me - 1, buf, queue)


@nb.njit(**_JIT)
def _plan_edges_kernel(A, B, m, with_ends, proj, fk, R, order, pi, pj, margin, nodes, children, depth, do_env,
                       all_hit, counts):
    """Edges ``A[e] -> B[e]`` in order, each cut into ``m[e]`` steps, its points
    ``A + (i / m)(B - A)`` (``i = 0..m`` with ``with_ends``, else ``1..m-1``) checked in
    bisect order; returns the first invalid edge (E if none)."""
    E = A.shape[0]
    d = A.shape[1]
    W = _scratch(proj[2].shape[0], fk[0].shape[0], fk[8].shape[0], fk[12].shape[0])
    RO = _radii_in_order(R, order)
    buf, queue = _bisect_buffers(m)
    row = np.empty((1, d))
    for e in range(E):
        me = m[e]
        cnt = _edge_order(me, with_ends, buf, queue)
        for t in range(cnt):
            i = buf[t]
            s = i / me
            for c in range(d):
                row[0, c] = A[e, c] + s * (B[e, c] - A[e, c])
            if not _row_valid(row, proj, fk, pi, pj, R, order, RO, margin, nodes, children, depth, do_env, all_hit,
                              W, counts):
                return e
    return E


@nb.njit(**_JIT)
def _plan_edges_lanes_kernel(A, B, m, with_ends, proj, fk, R, order, pi, pj, margin, nodes, children, depth, do_env,
                             all_hit, fld, counts):
    """:func:`_plan_edges_kernel`'s answer with the collision tests in SIMD lanes: each
    edge's points in bisect order are projected one by one (a point that does not
    project ends the edge), their full configurations gathered LANES at a time and
    checked by :func:`~humanoid_reach_ros.geometry.batch_collision.check_lanes` (the
    scalar checker's verdicts); the edge ends at the first block holding a collision."""
    (v, cog_xy, q_ref, arm_cols, arm_lo, arm_hi, leg_cols, feet_p, feet_R, leg_ref, R0, t0, Re, te, l1, l2, leg_lo,
     leg_hi) = proj
    E = A.shape[0]
    d = A.shape[1]
    nq = q_ref.shape[0]
    Q = np.empty((1, nq))
    ok = np.empty(1, np.bool_)
    tp = np.empty((1, 3))
    tR = np.empty((1, 3, 3))
    fails = np.zeros(3, np.int64)
    WS = lane_workspace(nq, fk[1][0].shape[0], fk[1][5].shape[0], depth)
    blk = np.empty((nq, LANES))
    hits = np.zeros(LANES, np.bool_)
    lane_counts = np.zeros(2, np.int64)
    buf, queue = _bisect_buffers(m)
    row = np.empty((1, d))
    for e in range(E):
        me = m[e]
        cnt = _edge_order(me, with_ends, buf, queue)
        n = 0
        for t in range(cnt):
            s = buf[t] / me
            for c in range(d):
                row[0, c] = A[e, c] + s * (B[e, c] - A[e, c])
            _project_plan_kernel(row, v, cog_xy, q_ref, arm_cols, arm_lo, arm_hi, leg_cols, feet_p, feet_R, leg_ref,
                                 R0, t0, Re, te, l1, l2, leg_lo, leg_hi, Q, ok, tp, tR, fails)
            counts[0] += 1
            if not ok[0]:
                return e
            counts[1] += 1
            if all_hit:
                return e
            for k in range(nq):
                blk[k, n] = Q[0, k]
            n += 1
            if n == LANES or t == cnt - 1:
                for ln in range(n, LANES):          # pad the block with its last configuration
                    for k in range(nq):
                        blk[k, ln] = blk[k, n - 1]
                check_lanes(blk, n, fk, R, order, pi, pj, margin, nodes, children, depth, do_env, fld, WS, hits,
                            lane_counts)
                for ln in range(n):
                    if hits[ln]:
                        return e
                n = 0
    return E


class PlanChecker:
    """``is_valid_batch`` / ``first_invalid`` of q_plan rows for one arm (see module doc).

    Same verdicts as ``project_plan_config(Q, arm).ok & collision.check_batch(...)``
    (``lanes``: :meth:`first_invalid_edge` through the SIMD-lane kernel, see there);
    counted in ``collision.counters`` (configurations checked, time in
    ``check_time_s``: projection, FK and tests are interleaved here, so it holds all three)."""

    def __init__(self, projector: Projector, collision: RobotCollision, arm: str, lanes: bool = True) -> None:
        if not projector.compiled:
            raise ValueError("PlanChecker needs a projector on the compiled leg IK")
        self.projector = projector
        self.collision = collision
        self.arm = arm
        #: edges checked in SIMD lanes (full forward kinematics of LANES projected points at a
        #: time, geometry/batch_collision.py); False: the scalar fused kernel, point by point
        self.lanes = bool(lanes)
        robot = projector.robot
        m = robot.model
        cm = collision.cm
        jparent, jaxis, jR, jt, jq, lj, lR, lt, sl, p0l, p1l = collision._fk_args
        J = len(jparent)
        # moving joints (our index = pinocchio joint id - 2): the planning arm and both legs
        moving = np.zeros(J, bool)
        for limb in (f"{arm}_arm",) + LEGS:
            for name in robot.limbs[limb].joints:
                moving[m.getJointId(name) - 2] = True
        # a joint is rigid to the trunk when it and every ancestor up to the trunk are fixed
        rigid = np.zeros(J, bool)
        for j in range(J):
            p = jparent[j]
            rigid[j] = (not moving[j]) and (p < 0 or rigid[p])
        needed = np.zeros(J, bool)   # rigid joints whose pose a moving joint or a link uses
        for j in range(J):
            if not rigid[j] and jparent[j] >= 0 and rigid[jparent[j]]:
                needed[jparent[j]] = True
        lrigid = np.array([rigid[k] if k >= 0 else True for k in lj], bool)
        jmode = np.where(rigid, np.where(needed, 1, 0), 2).astype(np.int64)
        # trunk-frame poses of the rigid joints and shapes at the reference configuration
        q_ref = np.ascontiguousarray(projector.q_ref, dtype=float)
        q_unit = q_ref.copy()
        q_unit[:7] = [0, 0, 0, 0, 0, 0, 1]    # trunk at the origin: world = trunk frame
        P0b, P1b = np.empty((1, cm.n_shapes, 3)), np.empty((1, cm.n_shapes, 3))
        _fk_shapes_kernel(q_unit[None], *collision._fk_args, P0b, P1b)
        relR, relt = _joint_poses(q_unit, jparent, jaxis, jR, jt, jq)
        srigid = lrigid[sl]
        self._fk = (jparent, jaxis, jR, jt, jq, jmode, relR, relt, lj, lR, lt, lrigid, sl, p0l, p1l,
                    np.ascontiguousarray(P0b[0]), np.ascontiguousarray(P1b[0]), srigid)
        # self pairs: drop the pairs rigid with respect to each other if clear at the reference
        pi, pj = collision._pi, collision._pj
        sig = [frozenset(self._moving_ancestors(int(lj[int(sl[s])]), jparent, moving)) for s in range(cm.n_shapes)]
        rigid_pair = np.array([sig[i] == sig[j] for i, j in zip(pi, pj)], bool)
        R = collision.radii
        margin = collision.self_margin_m
        d_rigid = np.array([_seg_seg_dist(P0b[0], P1b[0], int(i), int(j)) - R[i] - R[j]
                            for i, j in zip(pi[rigid_pair], pj[rigid_pair])])
        self.all_hit = bool(np.any(d_rigid < margin))
        keep = ~rigid_pair
        self.n_pairs_dropped = int(np.count_nonzero(rigid_pair))
        self._pairs = (np.ascontiguousarray(pi[keep]), np.ascontiguousarray(pj[keep]))
        self._proj = projector._kernel_args(arm)
        self.last_examined = 0

    @staticmethod
    def _moving_ancestors(j: int, jparent: np.ndarray, moving: np.ndarray) -> set:
        out = set()
        while j >= 0:
            if moving[j]:
                out.add(j)
            j = int(jparent[j])
        return out

    def _run(self, Q: np.ndarray, stop_first: bool) -> tuple[int, np.ndarray]:
        Q = np.ascontiguousarray(np.atleast_2d(np.asarray(Q, dtype=np.float64)))
        d = self.projector.plan_dim(self.arm)
        if Q.shape[1] != d:
            raise ValueError(f"q_plan must have {d} columns (q_arm, z_t, rpy_t), got {Q.shape}")
        col = self.collision
        tree = col.tree
        out = np.zeros(len(Q), np.bool_)
        counts = np.zeros(2, np.int64)
        t0 = time.perf_counter()
        k = _plan_rows_kernel(Q, bool(stop_first), self._proj, self._fk, col.radii, col.env_order, *self._pairs,
                              col.self_margin_m, tree.nodes, tree.children, tree.depth, bool(tree.n_spheres > 0),
                              self.all_hit, out, counts)
        self._count(t0, counts)
        return int(k), out

    def _count(self, t0: float, counts: np.ndarray) -> None:
        c = self.collision.counters
        c.check_time_s += time.perf_counter() - t0
        c.checks += int(counts[1])
        c.calls += 1
        self.last_examined = int(counts[0])

    def first_invalid_edge(self, A: np.ndarray, B: np.ndarray, m: np.ndarray, include_endpoints: bool) -> int:
        """First invalid edge of ``A[e] -> B[e]`` cut into ``m[e]`` steps (E if all are
        valid): the points of :func:`~humanoid_reach_ros.planning.space.check_edges`,
        generated in the kernel, edge after edge, each edge in bisect order, stopping at
        the first invalid point (with ``lanes``: at the first block of LANES points holding
        it). ``last_examined``: the points examined."""
        A = np.ascontiguousarray(A, dtype=np.float64)
        B = np.ascontiguousarray(B, dtype=np.float64)
        m = np.ascontiguousarray(m, dtype=np.int64)
        col = self.collision
        tree = col.tree
        counts = np.zeros(2, np.int64)
        if self.lanes:
            bc = batch_checker(col)
            fld = bc.field_args(lazy=True)      # before the clock: built once per map, when it pays
            t0 = time.perf_counter()
            e = _plan_edges_lanes_kernel(A, B, m, bool(include_endpoints), self._proj, bc.fk, col.radii,
                                         col.env_order, *self._pairs, col.self_margin_m, tree.nodes, tree.children,
                                         tree.depth, bool(tree.n_spheres > 0), self.all_hit, fld, counts)
            bc.configs_checked += int(counts[1])
        else:
            t0 = time.perf_counter()
            e = _plan_edges_kernel(A, B, m, bool(include_endpoints), self._proj, self._fk, col.radii, col.env_order,
                                   *self._pairs, col.self_margin_m, tree.nodes, tree.children, tree.depth,
                                   bool(tree.n_spheres > 0), self.all_hit, counts)
        self._count(t0, counts)
        return int(e)

    def __call__(self, Q: np.ndarray) -> np.ndarray:
        """(n,) bool: each row projects and is collision-free."""
        return self._run(Q, False)[1]

    def first_invalid(self, Q: np.ndarray) -> int:
        """Index of the first invalid row (len(Q) if none); later rows are not computed."""
        return self._run(Q, True)[0]


def _joint_poses(q, jparent, jaxis, jR, jt, jq) -> tuple[np.ndarray, np.ndarray]:
    """Joint frames (J, 3, 3), (J, 3) of ``q`` with the base at the origin (numpy, once)."""
    J = len(jparent)
    oR = np.empty((J, 3, 3))
    ot = np.empty((J, 3))
    for j in range(J):
        p = jparent[j]
        PR, Pt = (np.eye(3), np.zeros(3)) if p < 0 else (oR[p], ot[p])
        c, s = math.cos(q[jq[j]]), math.sin(q[jq[j]])
        ax = jaxis[j]
        if ax == 0:
            Rq = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
        elif ax == 1:
            Rq = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
        else:
            Rq = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        ot[j] = Pt + PR @ jt[j]
        oR[j] = PR @ jR[j] @ Rq
    return np.ascontiguousarray(oR), np.ascontiguousarray(ot)


__all__ = ["PlanChecker", "BOUND_SLACK"]
