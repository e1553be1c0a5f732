"""Quinlan sphere tree (humanoid_reach_ros.geometry.sphere_tree): structure and every
query against brute force over all spheres."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from humanoid_reach_ros.geometry.sphere_tree import SphereTree, tree_any_intersection, warm_up

TOL = 1e-12


@pytest.fixture(scope="module", autouse=True)
def _compiled():
    warm_up()


# ------------------------------------------------------------------ brute force
def brute_distances(centers, radii, p0, p1, r) -> np.ndarray:
    """Signed distances (N,) of one capsule to every sphere, plain numpy."""
    centers = np.asarray(centers, float).reshape(-1, 3)
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    d = p1 - p0
    dd = d @ d
    t = np.clip((centers - p0) @ d / dd, 0.0, 1.0) if dd > 0.0 else np.zeros(len(centers))
    closest = p0 + t[:, None] * d
    return np.linalg.norm(centers - closest, axis=1) - np.broadcast_to(radii, (len(centers),)) - r


def random_spheres(rng, n, spread=1.0, uniform_radius=None):
    c = rng.uniform(-spread, spread, (n, 3))
    r = np.full(n, uniform_radius) if uniform_radius is not None else rng.uniform(0.0, 0.1, n)
    return c, r


def random_shapes(rng, s, spread=1.2, sphere_fraction=0.3):
    P0 = rng.uniform(-spread, spread, (s, 3))
    P1 = P0 + rng.normal(0.0, 0.25, (s, 3))
    spheres = rng.random(s) < sphere_fraction
    P1[spheres] = P0[spheres]
    R = rng.uniform(0.0, 0.12, s)
    return P0, P1, R


def subtree_leaves(tree: SphereTree) -> list[np.ndarray]:
    """Input-sphere indices under every node (preorder: the subtree of i is i .. i + 2n - 2)."""
    leaf = tree.leaf_sphere
    out = [None] * tree.n_nodes
    for i in range(tree.n_nodes - 1, -1, -1):
        left, right = tree.children[i]
        out[i] = np.array([leaf[i]]) if left < 0 else np.concatenate([out[left], out[right]])
    return out


# ------------------------------------------------------------------ structure
def check_invariants(tree: SphereTree) -> None:
    n, m = tree.n_spheres, tree.n_nodes
    assert m == max(0, 2 * n - 1)
    if n == 0:
        return
    leaf = tree.leaf_sphere
    is_leaf = leaf >= 0
    # leaves are exactly the input spheres, each once, with their own centre and radius
    assert np.array_equal(np.sort(leaf[is_leaf]), np.arange(n))
    assert np.array_equal(tree.node_center[is_leaf], tree.centers[leaf[is_leaf]])
    assert np.array_equal(tree.node_radius[is_leaf], tree.radii[leaf[is_leaf]])
    assert np.all(tree.rule[is_leaf] == -1) and np.all(tree.rule[~is_leaf] >= 0)
    # preorder layout: the left child follows its parent
    internal = np.flatnonzero(~is_leaf)
    assert np.array_equal(tree.left[internal], internal + 1)
    assert np.all(tree.right[internal] > internal + 1)
    leaves = subtree_leaves(tree)
    for i in internal:
        lc, rc = tree.children[i]
        sub = leaves[i]
        c, r = tree.centers[sub], tree.radii[sub]
        # every leaf sphere of the subtree is inside the node sphere
        reach = np.linalg.norm(c - tree.node_center[i], axis=1) + r
        assert reach.max() <= tree.node_radius[i] * (1 + 1e-12) + TOL, f"node {i} does not bound its leaves"
        # radius rule: min of (a) AABB sphere of the centres + largest radius, (b) enclosing the children
        lo, hi = c.min(axis=0), c.max(axis=0)
        ra = 0.5 * np.linalg.norm(hi - lo) + r.max()
        cl, rl = tree.node_center[lc], tree.node_radius[lc]
        cr, rr = tree.node_center[rc], tree.node_radius[rc]
        d = np.linalg.norm(cr - cl)
        rb = max(rl, rr, 0.5 * (d + rl + rr))
        assert tree.node_radius[i] == pytest.approx(min(ra, rb), rel=1e-12, abs=TOL)
        if tree.rule[i] == 0:
            assert np.allclose(tree.node_center[i], 0.5 * (lo + hi), atol=TOL)
        else:
            # (b) contains both child spheres
            for cc, rc_ in ((cl, rl), (cr, rr)):
                assert np.linalg.norm(cc - tree.node_center[i]) + rc_ <= tree.node_radius[i] * (1 + 1e-12) + TOL
        # split at the centroid of the centres along the longest axis of the spheres' AABB
        axis = int(np.argmax((c + r[:, None]).max(axis=0) - (c - r[:, None]).min(axis=0)))
        left_c = tree.centers[leaves[lc], axis]
        right_c = tree.centers[leaves[rc], axis]
        assert len(left_c) + len(right_c) == len(sub)
        mean = c[:, axis].mean()
        if np.any(c[:, axis] < mean - 1e-9) and np.any(c[:, axis] > mean + 1e-9):   # not degenerate
            assert left_c.max() < mean + 1e-9 and right_c.min() >= mean - 1e-9
        elif np.all(c[:, axis] == c[0, axis]):  # coincident: median split into halves
            assert len(left_c) == len(sub) // 2


@pytest.mark.parametrize("n", [1, 2, 3, 7, 64, 500])
def test_invariants_random(n):
    rng = np.random.default_rng(n)
    check_invariants(SphereTree.build(*random_spheres(rng, n)))
    check_invariants(SphereTree.build(*random_spheres(rng, n, uniform_radius=0.01)))


def test_invariants_voxel_grid_and_duplicates():
    rng = np.random.default_rng(3)
    grid = (rng.integers(-20, 20, (400, 3)) + 0.5) * 0.02   # voxel centres, many on shared planes
    check_invariants(SphereTree.from_voxels(np.unique(grid, axis=0), 0.02))
    dup = np.repeat(rng.uniform(-1, 1, (5, 3)), 9, axis=0)   # every centre 9 times
    tree = SphereTree.build(dup, 0.05)
    check_invariants(tree)
    same = SphereTree.build(np.zeros((17, 3)), 0.1)         # all coincident: median splits only
    check_invariants(same)
    assert same.depth == int(np.ceil(np.log2(17)))


def test_empty_and_single():
    empty = SphereTree.build(np.empty((0, 3)), 0.01)
    assert empty.n_nodes == 0 and empty.n_spheres == 0
    p = np.zeros(3)
    assert empty.min_distance(p, p, 0.1) == np.inf
    assert empty.nearest(p, p, 0.1) == (np.inf, -1)
    assert not empty.intersects(p, p, 0.1)
    idx, dist = empty.spheres_within(p, p, 0.1, 10.0)
    assert len(idx) == 0 and len(dist) == 0
    assert not empty.any_intersection(np.zeros((3, 3)), np.zeros((3, 3)), 0.1)
    assert not empty.any_intersection_configs(np.zeros((2, 3, 3)), np.zeros((2, 3, 3)), 0.1).any()

    one = SphereTree.build(np.array([[1.0, 2.0, 3.0]]), 0.5)
    check_invariants(one)
    assert one.n_nodes == 1 and one.depth == 0
    assert one.min_distance([1.0, 2.0, 0.0], [1.0, 2.0, 1.0], 0.25) == pytest.approx(2.0 - 0.75)
    assert one.nearest([1.0, 2.0, 3.0], [1.0, 2.0, 3.0], 0.1) == (pytest.approx(-0.6), 0)
    assert one.intersects([0.0, 2.0, 3.0], [2.0, 2.0, 3.0], 0.0)


def test_from_voxels_radius_and_validation():
    v = np.array([[0.01, 0.01, 0.01], [0.03, 0.01, 0.01]])
    tree = SphereTree.from_voxels(v, 0.02, safety_margin_m=0.005)
    assert np.allclose(tree.radii, 0.015)
    with pytest.raises(ValueError):
        SphereTree.from_voxels(v, 0.0)
    with pytest.raises(ValueError):
        SphereTree.from_voxels(v, 0.02, safety_margin_m=-0.01)
    with pytest.raises(ValueError):
        SphereTree.build(np.array([[0.0, np.nan, 0.0]]), 0.01)
    with pytest.raises(ValueError):
        SphereTree.build(np.zeros((2, 3)), [-0.1, 0.1])
    with pytest.raises(ValueError):
        tree.any_intersection(np.zeros((2, 2)), np.zeros((2, 2)), 0.1)
    with pytest.raises(ValueError):
        tree.intersects(np.zeros(2), np.zeros(3), 0.1)
    assert not tree.nodes.flags.writeable and not tree.children.flags.writeable


# ------------------------------------------------------------------ queries
def check_queries(tree: SphereTree, P0, P1, R, bound: float = 0.05) -> None:
    c, rad = tree.centers, tree.radii
    D = np.array([brute_distances(c, rad, a, b, r) for a, b, r in zip(P0, P1, R)])   # (S, N)
    dmin = D.min(axis=1)
    clear = np.abs(dmin) > 1e-12          # sign well defined despite round-off

    dist, idx = tree.nearest_batch(P0, P1, R)
    assert np.allclose(dist, dmin, atol=1e-12, rtol=0)
    assert np.allclose(D[np.arange(len(D)), idx], dmin, atol=1e-12, rtol=0)   # the index attains it
    assert np.allclose(tree.min_distance_batch(P0, P1, R), dmin, atol=1e-12, rtol=0)
    hits = tree.intersects_batch(P0, P1, R)
    assert np.array_equal(hits[clear], (dmin < 0)[clear])
    for s in range(len(P0)):
        d1, k1 = tree.nearest(P0[s], P1[s], R[s])
        assert d1 == pytest.approx(dmin[s], abs=1e-12) and k1 == idx[s]
        assert tree.min_distance(P0[s], P1[s], R[s]) == d1
        assert tree.intersects(P0[s], P1[s], R[s]) == hits[s]
        ids, ds = tree.spheres_within(P0[s], P1[s], R[s], bound)
        near = np.abs(D[s] - bound) > 1e-12
        want = set(np.flatnonzero((D[s] <= bound) & near))
        got = set(ids.tolist())
        assert want <= got and got - want <= set(np.flatnonzero(~near))
        assert np.allclose(ds, D[s, ids], atol=1e-12, rtol=0)
    if clear.all():
        assert tree.any_intersection(P0, P1, R) == bool((dmin < 0).any())
    sh, sp, ds = tree.spheres_within_batch(P0, P1, R, bound)
    assert np.all(np.diff(sh) >= 0)              # grouped by shape, in shape order
    assert np.allclose(ds, D[sh, sp], atol=1e-12, rtol=0)
    assert np.all(ds <= bound + 1e-12)
    strict = (D <= bound - 1e-12).sum()
    assert strict <= len(sh) <= (D <= bound + 1e-12).sum()


@pytest.mark.parametrize("n", [1, 2, 5, 50, 800])
def test_queries_random(n):
    rng = np.random.default_rng(100 + n)
    for uniform in (None, 0.01):
        tree = SphereTree.build(*random_spheres(rng, n, uniform_radius=uniform))
        check_queries(tree, *random_shapes(rng, 60), bound=0.1)


def test_queries_duplicates():
    rng = np.random.default_rng(7)
    c = np.repeat(rng.uniform(-0.5, 0.5, (20, 3)), 4, axis=0)
    tree = SphereTree.build(c, 0.03)
    check_queries(tree, *random_shapes(rng, 80, spread=0.6), bound=0.05)


def test_near_touching():
    """Capsules and spheres placed 1e-7 m outside / inside a sphere's surface."""
    rng = np.random.default_rng(11)
    c, r = random_spheres(rng, 300, uniform_radius=0.02)
    tree = SphereTree.build(c, r)
    for k in rng.choice(300, 40, replace=False):
        D_all = None
        for gap in (1e-7, -1e-7):
            n = rng.normal(size=3)
            n /= np.linalg.norm(n)
            rs = 0.05
            # a capsule whose closest point to sphere k lies on its interior, perpendicular to n
            u = np.cross(n, rng.normal(size=3))
            u /= np.linalg.norm(u)
            mid = c[k] + n * (r[k] + rs + gap)
            p0, p1 = mid - 0.1 * u, mid + 0.1 * u
            D_all = brute_distances(c, r, p0, p1, rs)
            assert tree.min_distance(p0, p1, rs) == pytest.approx(D_all.min(), abs=1e-12)
            assert tree.intersects(p0, p1, rs) == bool(D_all.min() < 0)
            if np.all(np.delete(D_all, k) > 1e-6):   # sphere k decides
                assert tree.intersects(p0, p1, rs) == (gap < 0)
            # the same as a sphere shape
            q = c[k] + n * (r[k] + rs + gap)
            D_s = brute_distances(c, r, q, q, rs)
            assert tree.intersects(q, q, rs) == bool(D_s.min() < 0)
            ids, _ = tree.spheres_within(q, q, rs, 0.0)
            assert (k in ids) == (gap < 0)


def test_any_intersection_configs_matches_brute_force():
    rng = np.random.default_rng(5)
    tree = SphereTree.build(*random_spheres(rng, 400, uniform_radius=0.01))
    C, S = 200, 25
    P0 = rng.uniform(-1.1, 1.1, (C, S, 3))
    P1 = P0 + rng.normal(0.0, 0.05, (C, S, 3))
    R = rng.uniform(0.0, 0.04, S)
    want = np.array([
        min(brute_distances(tree.centers, tree.radii, P0[c, s], P1[c, s], R[s]).min() for s in range(S)) < 0
        for c in range(C)
    ])
    assert 0 < want.sum() < C          # both kinds present
    assert np.array_equal(tree.any_intersection_configs(P0, P1, R), want)
    assert np.array_equal(tree.any_intersection_configs(P0, P1, np.broadcast_to(R, (C, S))), want)
    for c in range(C):
        assert tree.any_intersection(P0[c], P1[c], R) == want[c]
        # the raw kernel callable from other numba code
        assert tree_any_intersection(tree.nodes, tree.children, tree.depth,
                                     np.ascontiguousarray(P0[c]), np.ascontiguousarray(P1[c]), R) == want[c]


def test_python_inputs_and_scalar_radius():
    tree = SphereTree.build([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], 0.1)
    assert tree.any_intersection([[0.5, 0.0, 0.0]], [[0.95, 0.0, 0.0]], 0.0)
    assert not tree.any_intersection([[0.5, 0.0, 0.0]], [[0.85, 0.0, 0.0]], 0.0)
    d = tree.min_distance_batch([[0.5, 0.0, 0.0], [0.5, 1.0, 0.0]], [[0.5, 0.0, 0.0], [0.5, 1.0, 0.0]], 0.1)
    assert np.allclose(d, [0.3, np.hypot(0.5, 1.0) - 0.2])


finite = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)
point = st.tuples(finite, finite, finite)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    centers=st.lists(point, min_size=1, max_size=40),
    radius=st.floats(0.0, 0.2),
    p0=point, p1=point, r=st.floats(0.0, 0.3),
    as_sphere=st.booleans(),
)
def test_hypothesis_queries(centers, radius, p0, p1, r, as_sphere):
    c = np.array(centers)
    tree = SphereTree.build(c, radius)
    check_invariants(tree)
    p1 = p0 if as_sphere else p1
    check_queries(tree, np.array([p0]), np.array([p1]), np.array([r]), bound=0.1)
