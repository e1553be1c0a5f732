"""Sphere tree of the environment (Quinlan 1994, as built in Kanehiro et al., Sec. II).

A sphere is assigned to every occupied voxel of the measured map (radius
``resolution_m / 2 + safety_margin_m``: the paper's spheres have the voxel size as
diameter, a larger radius is a safety margin) and a binary tree of bounding spheres
is built top down:

1. take the axis-aligned bounding box (AABB) of the node's spheres;
2. split the spheres into two groups at the centroid of their centres along the
   AABB's longest axis (a split leaving one side empty -- coincident centres --
   falls back to the median); recurse until every leaf holds exactly one sphere;
3. a node's radius is the smaller of (a) the sphere bounding the AABB of the
   subtree's sphere centres -- centre ``m`` = AABB centre, radius = half the
   AABB diagonal + the largest sphere radius -- and (b) the smallest sphere
   enclosing the two child bounding spheres.

Every node's sphere contains every leaf sphere of its subtree, which is all that the
branch-and-bound queries below need. With rule (a) a node need not contain its
children's bounding spheres themselves (a child chosen by (a) as well may stick out
of its parent's AABB sphere); with rule (b) it does by construction.

Storage (flat numpy, preorder: a node's left child is the next node): ``nodes``
(M, 4) ``[cx, cy, cz, r]`` and ``children`` (M, 2) int32 ``[left, right]``; a leaf
has ``left == -1`` and ``right`` = the index of its input sphere, and its node
sphere *is* that sphere. ``M = 2 N - 1`` for ``N`` spheres.

Robot shapes are capsules: a segment ``p0 -> p1`` swept by a ball of radius ``r``
(a sphere when ``p0 == p1``), the model of :mod:`humanoid_reach_ros.robot.shapes`.
The signed distance of a shape to an environment sphere ``(c_i, r_i)`` is
``|c_i - seg(p0, p1)| - r_i - r`` with the exact point-segment distance; negative
means penetration, and a shape *intersects* the environment when some distance is
``< 0`` (touching is not a collision).

Build and queries run in numba (``@njit(cache=True, nogil=True)``; compiled on first
use and cached on disk next to this module, :func:`warm_up` compiles them all ahead).
The ``tree_*`` kernels take the raw ``(nodes, children)`` arrays so that other numba
code (planners) can call them without any Python in between; :class:`SphereTree`
wraps them for Python callers. This module never imports rclpy.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba as nb
import numpy as np

_JIT = dict(cache=True, nogil=True, fastmath=False)


# =================================================================== build
@nb.njit(**_JIT)
def _build_kernel(centers, radii):
    """Top-down build with an explicit stack; returns (nodes, children, rule, depth).

    ``rule[i]``: -1 leaf, 0 radius from the AABB sphere (a), 1 from the children (b).
    """
    n = centers.shape[0]
    m = 2 * n - 1
    nodes = np.empty((m, 4))
    children = np.empty((m, 2), dtype=np.int32)
    rule = np.empty(m, dtype=np.int8)
    aabb = np.empty((m, 4))           # candidate (a): centre and radius
    perm = np.arange(n)
    st_node = np.empty(n + 1, dtype=np.int64)
    st_start = np.empty(n + 1, dtype=np.int64)
    st_end = np.empty(n + 1, dtype=np.int64)
    st_depth = np.empty(n + 1, dtype=np.int64)
    top = 0
    st_node[0] = 0
    st_start[0] = 0
    st_end[0] = n
    st_depth[0] = 0
    top = 1
    max_depth = 0
    while top > 0:
        top -= 1
        i = st_node[top]
        s = st_start[top]
        e = st_end[top]
        dep = st_depth[top]
        if dep > max_depth:
            max_depth = dep
        if e - s == 1:
            k = perm[s]
            nodes[i, 0] = centers[k, 0]
            nodes[i, 1] = centers[k, 1]
            nodes[i, 2] = centers[k, 2]
            nodes[i, 3] = radii[k]
            children[i, 0] = -1
            children[i, 1] = k
            rule[i] = -1
            continue
        # AABB of the centres, of the spheres, largest radius, centroid
        lo0 = lo1 = lo2 = np.inf
        hi0 = hi1 = hi2 = -np.inf
        slo0 = slo1 = slo2 = np.inf
        shi0 = shi1 = shi2 = -np.inf
        sum0 = sum1 = sum2 = 0.0
        rmax = 0.0
        for a in range(s, e):
            k = perm[a]
            x = centers[k, 0]
            y = centers[k, 1]
            z = centers[k, 2]
            rk = radii[k]
            lo0 = min(lo0, x)
            hi0 = max(hi0, x)
            lo1 = min(lo1, y)
            hi1 = max(hi1, y)
            lo2 = min(lo2, z)
            hi2 = max(hi2, z)
            slo0 = min(slo0, x - rk)
            shi0 = max(shi0, x + rk)
            slo1 = min(slo1, y - rk)
            shi1 = max(shi1, y + rk)
            slo2 = min(slo2, z - rk)
            shi2 = max(shi2, z + rk)
            sum0 += x
            sum1 += y
            sum2 += z
            rmax = max(rmax, rk)
        ex0 = 0.5 * (hi0 - lo0)
        ex1 = 0.5 * (hi1 - lo1)
        ex2 = 0.5 * (hi2 - lo2)
        aabb[i, 0] = 0.5 * (lo0 + hi0)
        aabb[i, 1] = 0.5 * (lo1 + hi1)
        aabb[i, 2] = 0.5 * (lo2 + hi2)
        aabb[i, 3] = math.sqrt(ex0 * ex0 + ex1 * ex1 + ex2 * ex2) + rmax
        # longest axis of the spheres' AABB, split at the centroid of the centres
        l0 = shi0 - slo0
        l1 = shi1 - slo1
        l2 = shi2 - slo2
        axis = 0
        mean = sum0 / (e - s)
        if l1 > l0 and l1 >= l2:
            axis = 1
            mean = sum1 / (e - s)
        elif l2 > l0 and l2 > l1:
            axis = 2
            mean = sum2 / (e - s)
        a = s
        b = e - 1
        while a <= b:
            if centers[perm[a], axis] < mean:
                a += 1
            else:
                tmp = perm[a]
                perm[a] = perm[b]
                perm[b] = tmp
                b -= 1
        nl = a - s
        if nl == 0 or nl == e - s:    # coincident centres (or rounding): median split
            sub = perm[s:e].copy()
            key = np.empty(e - s)
            for t in range(e - s):
                key[t] = centers[sub[t], axis]
            order = np.argsort(key, kind="mergesort")
            for t in range(e - s):
                perm[s + t] = sub[order[t]]
            nl = (e - s) // 2
        left = i + 1
        right = i + 2 * nl              # the left subtree holds 2 nl - 1 nodes
        rule[i] = 0
        children[i, 0] = left
        children[i, 1] = right
        st_node[top] = right
        st_start[top] = s + nl
        st_end[top] = e
        st_depth[top] = dep + 1
        top += 1
        st_node[top] = left
        st_start[top] = s
        st_end[top] = s + nl
        st_depth[top] = dep + 1
        top += 1
    # bottom up (children have larger indices): radius = min of rules (a) and (b)
    for i in range(m - 1, -1, -1):
        if children[i, 0] < 0:
            continue
        lc = children[i, 0]
        rc = children[i, 1]
        dx = nodes[rc, 0] - nodes[lc, 0]
        dy = nodes[rc, 1] - nodes[lc, 1]
        dz = nodes[rc, 2] - nodes[lc, 2]
        d = math.sqrt(dx * dx + dy * dy + dz * dz)
        rl = nodes[lc, 3]
        rr = nodes[rc, 3]
        if d + rr <= rl:
            bx, by, bz, rb = nodes[lc, 0], nodes[lc, 1], nodes[lc, 2], rl
        elif d + rl <= rr:
            bx, by, bz, rb = nodes[rc, 0], nodes[rc, 1], nodes[rc, 2], rr
        else:
            rb = 0.5 * (d + rl + rr)
            f = (rb - rl) / d
            bx = nodes[lc, 0] + f * dx
            by = nodes[lc, 1] + f * dy
            bz = nodes[lc, 2] + f * dz
        if aabb[i, 3] <= rb:
            nodes[i, 0] = aabb[i, 0]
            nodes[i, 1] = aabb[i, 1]
            nodes[i, 2] = aabb[i, 2]
            nodes[i, 3] = aabb[i, 3]
            rule[i] = 0
        else:
            nodes[i, 0] = bx
            nodes[i, 1] = by
            nodes[i, 2] = bz
            nodes[i, 3] = rb
            rule[i] = 1
    return nodes, children, rule, max_depth


# =================================================================== query kernels
@nb.njit(**_JIT)
def _seg_dist2(nodes, i, ax, ay, az, dx, dy, dz, inv_dd):
    """Squared distance from the centre of node ``i`` to the segment ``a + t d``, t in [0, 1]."""
    wx = nodes[i, 0] - ax
    wy = nodes[i, 1] - ay
    wz = nodes[i, 2] - az
    t = (wx * dx + wy * dy + wz * dz) * inv_dd
    if t < 0.0:
        t = 0.0
    elif t > 1.0:
        t = 1.0
    ex = wx - t * dx
    ey = wy - t * dy
    ez = wz - t * dz
    return ex * ex + ey * ey + ez * ez


@nb.njit(**_JIT)
def _inv_len2(dx, dy, dz):
    dd = dx * dx + dy * dy + dz * dz
    return 1.0 / dd if dd > 0.0 else 0.0


@nb.njit(**_JIT)
def _hits(nodes, children, ax, ay, az, bx, by, bz, r, stack):
    """True when the capsule (a, b, r) penetrates some leaf sphere (early exit)."""
    if nodes.shape[0] == 0:
        return False
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
        if _seg_dist2(nodes, i, ax, ay, az, dx, dy, dz, inv) >= rr * rr:
            continue
        lc = children[i, 0]
        if lc < 0:
            return True
        stack[top] = children[i, 1]
        stack[top + 1] = lc
        top += 2
    return False


@nb.njit(**_JIT)
def _nearest(nodes, children, ax, ay, az, bx, by, bz, r, stack, stack_lb):
    """(signed distance, sphere index) of the nearest leaf sphere; (inf, -1) when empty.

    Depth-first branch and bound, nearer child first; a subtree is skipped when the
    lower bound ``|c - seg| - r_node - r`` is not below the best distance so far.
    """
    if nodes.shape[0] == 0:
        return np.inf, -1
    dx = bx - ax
    dy = by - ay
    dz = bz - az
    inv = _inv_len2(dx, dy, dz)
    best = np.inf
    best_i = -1
    stack[0] = 0
    stack_lb[0] = math.sqrt(_seg_dist2(nodes, 0, ax, ay, az, dx, dy, dz, inv)) - nodes[0, 3] - r
    top = 1
    while top > 0:
        top -= 1
        i = stack[top]
        lb = stack_lb[top]
        if lb >= best:
            continue
        lc = children[i, 0]
        if lc < 0:                       # a leaf's bound is its exact distance
            best = lb
            best_i = children[i, 1]
            continue
        rc = children[i, 1]
        lb_l = math.sqrt(_seg_dist2(nodes, lc, ax, ay, az, dx, dy, dz, inv)) - nodes[lc, 3] - r
        lb_r = math.sqrt(_seg_dist2(nodes, rc, ax, ay, az, dx, dy, dz, inv)) - nodes[rc, 3] - r
        if lb_l <= lb_r:
            if lb_r < best:
                stack[top] = rc
                stack_lb[top] = lb_r
                top += 1
            if lb_l < best:
                stack[top] = lc
                stack_lb[top] = lb_l
                top += 1
        else:
            if lb_l < best:
                stack[top] = lc
                stack_lb[top] = lb_l
                top += 1
            if lb_r < best:
                stack[top] = rc
                stack_lb[top] = lb_r
                top += 1
    return best, best_i


@nb.njit(**_JIT)
def _within(nodes, children, ax, ay, az, bx, by, bz, r, bound, stack, shape_id, out_shape, out_sphere, out_dist,
            count):
    """Append every leaf sphere within signed distance ``bound`` of the capsule to the
    output buffers (growing them as needed); returns the buffers and the new count."""
    if nodes.shape[0] == 0:
        return out_shape, out_sphere, out_dist, count
    dx = bx - ax
    dy = by - ay
    dz = bz - az
    inv = _inv_len2(dx, dy, dz)
    stack[0] = 0
    top = 1
    while top > 0:
        top -= 1
        i = stack[top]
        thr = bound + nodes[i, 3] + r
        if thr < 0.0:
            continue
        d2 = _seg_dist2(nodes, i, ax, ay, az, dx, dy, dz, inv)
        if d2 > thr * thr:
            continue
        lc = children[i, 0]
        if lc < 0:
            dist = math.sqrt(d2) - nodes[i, 3] - r
            if dist <= bound:
                if count == out_sphere.shape[0]:
                    cap = 2 * count + 16
                    ns = np.empty(cap, dtype=np.int64)
                    nsh = np.empty(cap, dtype=np.int64)
                    nd = np.empty(cap)
                    ns[:count] = out_sphere[:count]
                    nsh[:count] = out_shape[:count]
                    nd[:count] = out_dist[:count]
                    out_sphere, out_shape, out_dist = ns, nsh, nd
                out_shape[count] = shape_id
                out_sphere[count] = children[i, 1]
                out_dist[count] = dist
                count += 1
            continue
        stack[top] = children[i, 1]
        stack[top + 1] = lc
        top += 2
    return out_shape, out_sphere, out_dist, count


# ------------------------------------------------------------------- public kernels
@nb.njit(**_JIT)
def tree_intersects(nodes, children, depth, p0, p1, r):
    """Does the capsule ``p0 -> p1`` (3,) with radius ``r`` penetrate the environment?"""
    stack = np.empty(depth + 2, dtype=np.int64)
    return _hits(nodes, children, p0[0], p0[1], p0[2], p1[0], p1[1], p1[2], r, stack)


@nb.njit(**_JIT)
def tree_nearest(nodes, children, depth, p0, p1, r):
    """(signed distance, index of the nearest environment sphere) of one capsule."""
    stack = np.empty(depth + 2, dtype=np.int64)
    stack_lb = np.empty(depth + 2)
    return _nearest(nodes, children, p0[0], p0[1], p0[2], p1[0], p1[1], p1[2], r, stack, stack_lb)


@nb.njit(**_JIT)
def tree_nearest_batch(nodes, children, depth, P0, P1, R, out_dist, out_index):
    """:func:`tree_nearest` of S capsules P0, P1 (S, 3), R (S,) into out_dist (S,), out_index (S,)."""
    stack = np.empty(depth + 2, dtype=np.int64)
    stack_lb = np.empty(depth + 2)
    for s in range(P0.shape[0]):
        d, k = _nearest(nodes, children, P0[s, 0], P0[s, 1], P0[s, 2], P1[s, 0], P1[s, 1], P1[s, 2], R[s],
                        stack, stack_lb)
        out_dist[s] = d
        out_index[s] = k


@nb.njit(**_JIT)
def tree_intersects_batch(nodes, children, depth, P0, P1, R, out):
    """:func:`tree_intersects` of S capsules into ``out`` (S,) bool (no early exit)."""
    stack = np.empty(depth + 2, dtype=np.int64)
    for s in range(P0.shape[0]):
        out[s] = _hits(nodes, children, P0[s, 0], P0[s, 1], P0[s, 2], P1[s, 0], P1[s, 1], P1[s, 2], R[s], stack)


@nb.njit(**_JIT)
def tree_any_intersection(nodes, children, depth, P0, P1, R):
    """Does any of S capsules (one robot configuration) penetrate the environment?
    Stops at the first colliding shape: put the likeliest shapes first."""
    stack = np.empty(depth + 2, dtype=np.int64)
    for s in range(P0.shape[0]):
        if _hits(nodes, children, P0[s, 0], P0[s, 1], P0[s, 2], P1[s, 0], P1[s, 1], P1[s, 2], R[s], stack):
            return True
    return False


@nb.njit(**_JIT)
def tree_any_intersection_configs(nodes, children, depth, P0, P1, R, out):
    """Per configuration of C x S capsules P0, P1 (C, S, 3), R (C, S): ``out`` (C,) bool."""
    stack = np.empty(depth + 2, dtype=np.int64)
    for c in range(P0.shape[0]):
        hit = False
        for s in range(P0.shape[1]):
            if _hits(nodes, children, P0[c, s, 0], P0[c, s, 1], P0[c, s, 2], P1[c, s, 0], P1[c, s, 1], P1[c, s, 2],
                     R[c, s], stack):
                hit = True
                break
        out[c] = hit


@nb.njit(**_JIT)
def tree_spheres_within(nodes, children, depth, P0, P1, R, bound):
    """Every (shape, sphere) pair of S capsules within signed distance ``bound``:
    returns shape indices, sphere indices and distances (K,), grouped by shape."""
    stack = np.empty(depth + 2, dtype=np.int64)
    cap = 64
    out_shape = np.empty(cap, dtype=np.int64)
    out_sphere = np.empty(cap, dtype=np.int64)
    out_dist = np.empty(cap)
    count = 0
    for s in range(P0.shape[0]):
        out_shape, out_sphere, out_dist, count = _within(
            nodes, children, P0[s, 0], P0[s, 1], P0[s, 2], P1[s, 0], P1[s, 1], P1[s, 2], R[s], bound, stack, s,
            out_shape, out_sphere, out_dist, count)
    return out_shape[:count].copy(), out_sphere[:count].copy(), out_dist[:count].copy()


# =================================================================== Python API
_F64 = np.dtype(np.float64)


def _vec3(p) -> np.ndarray:
    if type(p) is np.ndarray and p.dtype is _F64 and p.shape == (3,):
        return p
    a = np.asarray(p, dtype=np.float64)
    if a.shape != (3,):
        raise ValueError(f"expected a 3-vector, got shape {a.shape}")
    return a


def _shapes(P0, P1, R) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validated C-contiguous float64 capsules P0, P1 (S, 3) and radii R (S,).

    Arrays that already have that form are passed through after a few attribute
    checks (the hot path of collision checking); anything else is converted."""
    if (type(P0) is np.ndarray and type(P1) is np.ndarray and type(R) is np.ndarray
            and P0.dtype is _F64 and P1.dtype is _F64 and R.dtype is _F64
            and P0.ndim == 2 and P0.shape[1] == 3 and P1.shape == P0.shape and R.shape == (P0.shape[0],)
            and P0.flags.c_contiguous and P1.flags.c_contiguous and R.flags.c_contiguous):
        return P0, P1, R
    P0 = np.ascontiguousarray(P0, dtype=np.float64)
    P1 = np.ascontiguousarray(P1, dtype=np.float64)
    if P0.ndim != 2 or P0.shape[1] != 3 or P1.shape != P0.shape:
        raise ValueError(f"expected P0, P1 of shape (S, 3), got {P0.shape} and {P1.shape}")
    R = np.array(np.broadcast_to(np.asarray(R, dtype=np.float64), (P0.shape[0],)))
    return P0, P1, R


@dataclass(frozen=True, eq=False)
class SphereTree:
    """Quinlan sphere tree over N environment spheres (see the module docstring).

    Build with :meth:`build` (any centres and radii) or :meth:`from_voxels`. The
    arrays are read-only; ``nodes``/``children``/``depth`` can be passed straight to
    the ``tree_*`` numba kernels.
    """

    centers: np.ndarray                  # (N, 3) input sphere centres
    radii: np.ndarray                    # (N,) input sphere radii
    nodes: np.ndarray = field(repr=False)      # (M, 4) [cx, cy, cz, r], preorder
    children: np.ndarray = field(repr=False)   # (M, 2) int32 [left, right]; leaf: [-1, sphere]
    rule: np.ndarray = field(repr=False)       # (M,) int8: -1 leaf, 0 AABB sphere, 1 child-enclosing sphere
    depth: int = 0                             # longest root-leaf path (edges)

    def __post_init__(self) -> None:
        # read-only whichever way the tree was made: numba compiles one specialisation per array
        # flag, so a writable copy (a tree received through a pipe: pickle restores arrays
        # writable) would load another from the on-disk cache at its first query, inside a
        # control step (seen: the first step on the first measured map took 15-22 ms)
        for a in (self.centers, self.radii, self.nodes, self.children, self.rule):
            a.setflags(write=False)

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self.__post_init__()

    # ------------------------------------------------------------ construction
    @classmethod
    def build(cls, centers: np.ndarray, radii: np.ndarray | float) -> "SphereTree":
        """Tree over spheres ``centers`` (N, 3) with ``radii`` (N,) or one radius [m]."""
        c = np.ascontiguousarray(centers, dtype=np.float64).reshape(-1, 3)
        r = np.ascontiguousarray(np.broadcast_to(np.asarray(radii, dtype=np.float64), (len(c),)))
        if not (np.all(np.isfinite(c)) and np.all(np.isfinite(r))):
            raise ValueError("sphere centres and radii must be finite")
        if np.any(r < 0.0):
            raise ValueError("sphere radii must be >= 0")
        if len(c) == 0:
            nodes, children, rule, depth = np.empty((0, 4)), np.empty((0, 2), np.int32), np.empty(0, np.int8), 0
        else:
            nodes, children, rule, depth = _build_kernel(c, r)
        return cls(c, r, nodes, children, rule, int(depth))

    @classmethod
    def from_voxels(cls, voxel_centers: np.ndarray, resolution_m: float, safety_margin_m: float = 0.0) -> "SphereTree":
        """One sphere per occupied voxel, radius ``resolution_m / 2 + safety_margin_m``."""
        if not resolution_m > 0.0 or not safety_margin_m >= 0.0:
            raise ValueError(f"need resolution_m > 0 and safety_margin_m >= 0, got {resolution_m}, {safety_margin_m}")
        return cls.build(voxel_centers, 0.5 * resolution_m + safety_margin_m)

    # ------------------------------------------------------------ structure
    @property
    def n_spheres(self) -> int:
        return len(self.centers)

    @property
    def n_nodes(self) -> int:
        return len(self.nodes)

    @property
    def node_center(self) -> np.ndarray:
        """(M, 3) node sphere centres (a view)."""
        return self.nodes[:, :3]

    @property
    def node_radius(self) -> np.ndarray:
        """(M,) node sphere radii (a view)."""
        return self.nodes[:, 3]

    @property
    def left(self) -> np.ndarray:
        """(M,) left child index, -1 at leaves."""
        return self.children[:, 0]

    @property
    def right(self) -> np.ndarray:
        """(M,) right child index, -1 at leaves."""
        return np.where(self.children[:, 0] < 0, -1, self.children[:, 1])

    @property
    def leaf_sphere(self) -> np.ndarray:
        """(M,) index of the input sphere held by a leaf, -1 at internal nodes."""
        return np.where(self.children[:, 0] < 0, self.children[:, 1], -1)

    # ------------------------------------------------------------ one shape
    def intersects(self, p0, p1, r: float) -> bool:
        """Does the capsule ``p0 -> p1`` with radius ``r`` (a sphere if p0 == p1)
        penetrate some environment sphere (signed distance < 0)? Early exit."""
        return bool(tree_intersects(self.nodes, self.children, self.depth, _vec3(p0), _vec3(p1), float(r)))

    def nearest(self, p0, p1, r: float) -> tuple[float, int]:
        """(signed distance [m], index of the nearest sphere); (inf, -1) for an empty tree."""
        d, k = tree_nearest(self.nodes, self.children, self.depth, _vec3(p0), _vec3(p1), float(r))
        return float(d), int(k)

    def min_distance(self, p0, p1, r: float) -> float:
        """Signed distance [m] from the capsule to the nearest environment sphere
        (negative: penetration depth; inf for an empty tree). Branch and bound."""
        return self.nearest(p0, p1, r)[0]

    def spheres_within(self, p0, p1, r: float, bound: float) -> tuple[np.ndarray, np.ndarray]:
        """Indices (K,) and signed distances (K,) of every environment sphere whose
        surface is within ``bound`` [m] of the capsule's (distance <= bound)."""
        P0, P1, R = _shapes(_vec3(p0)[None], _vec3(p1)[None], r)
        _, idx, dist = tree_spheres_within(self.nodes, self.children, self.depth, P0, P1, R, float(bound))
        return idx, dist

    # ------------------------------------------------------------ many shapes
    def nearest_batch(self, P0, P1, R) -> tuple[np.ndarray, np.ndarray]:
        """Per shape of S capsules P0, P1 (S, 3), R (S,) or scalar: distances (S,), sphere indices (S,)."""
        P0, P1, R = _shapes(P0, P1, R)
        dist = np.empty(len(P0))
        idx = np.empty(len(P0), dtype=np.int64)
        tree_nearest_batch(self.nodes, self.children, self.depth, P0, P1, R, dist, idx)
        return dist, idx

    def min_distance_batch(self, P0, P1, R) -> np.ndarray:
        """Signed distances (S,) of S capsules to the environment."""
        return self.nearest_batch(P0, P1, R)[0]

    def intersects_batch(self, P0, P1, R) -> np.ndarray:
        """Per shape (S,) bool: does capsule s penetrate the environment?"""
        P0, P1, R = _shapes(P0, P1, R)
        out = np.empty(len(P0), dtype=np.bool_)
        tree_intersects_batch(self.nodes, self.children, self.depth, P0, P1, R, out)
        return out

    def any_intersection(self, P0, P1, R) -> bool:
        """Does any of the S capsules of one configuration penetrate the environment?
        Stops at the first hit (order the shapes likeliest first)."""
        P0, P1, R = _shapes(P0, P1, R)
        return bool(tree_any_intersection(self.nodes, self.children, self.depth, P0, P1, R))

    def any_intersection_configs(self, P0, P1, R) -> np.ndarray:
        """C configurations x S capsules: P0, P1 (C, S, 3), R (S,), (C, S) or scalar ->
        (C,) bool, each configuration with early exit."""
        P0 = np.ascontiguousarray(P0, dtype=np.float64)
        P1 = np.ascontiguousarray(P1, dtype=np.float64)
        if P0.ndim != 3 or P0.shape[2] != 3 or P1.shape != P0.shape:
            raise ValueError(f"expected P0, P1 of shape (C, S, 3), got {P0.shape} and {P1.shape}")
        R = np.ascontiguousarray(np.broadcast_to(np.asarray(R, dtype=np.float64), P0.shape[:2]))
        out = np.empty(P0.shape[0], dtype=np.bool_)
        tree_any_intersection_configs(self.nodes, self.children, self.depth, P0, P1, R, out)
        return out

    def spheres_within_batch(self, P0, P1, R, bound: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All (shape, sphere) pairs of S capsules within signed distance ``bound`` [m]
        (velocity-damper candidates): shape indices, sphere indices, distances (K,),
        grouped by shape in shape order."""
        P0, P1, R = _shapes(P0, P1, R)
        return tree_spheres_within(self.nodes, self.children, self.depth, P0, P1, R, float(bound))


def warm_up() -> None:
    """Compile (or load from the on-disk cache) every kernel with the argument types
    the :class:`SphereTree` methods use, so that the first real call is fast."""
    rng = np.random.default_rng(0)
    tree = SphereTree.build(rng.uniform(-1.0, 1.0, (8, 3)), 0.05)
    p, P = np.zeros(3), np.zeros((2, 3))
    tree.intersects(p, p, 0.1)
    tree.nearest(p, p, 0.1)
    tree.spheres_within(p, p, 0.1, 0.2)
    radii = np.full(len(P), 0.1)
    radii.setflags(write=False)     # a collision model's radii are read-only, a scalar's broadcast is not
    for R in (0.1, radii):
        tree.nearest_batch(P, P, R)
        tree.intersects_batch(P, P, R)
        tree.any_intersection(P, P, R)
        tree.spheres_within_batch(P, P, R, 0.2)
    tree.any_intersection_configs(P[None], P[None], 0.1)


__all__ = [
    "SphereTree",
    "warm_up",
    "tree_intersects",
    "tree_nearest",
    "tree_nearest_batch",
    "tree_intersects_batch",
    "tree_any_intersection",
    "tree_any_intersection_configs",
    "tree_spheres_within",
]
