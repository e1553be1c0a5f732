"""Tests of perception/voxel_map.py: 3D DDA, 003's weighted fusion, clearing, extent bounds."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from humanoid_reach_ros.perception.voxel_map import (
    FusionParams, PinholeCamera, VoxelMap, depth_scan, look_at, ray_voxels)
from humanoid_reach_ros.sim.scene import load_scene

H = 0.02
EYE = np.array([0.11, 0.0, 1.45])   # the head camera in half-sitting (config/scenes/plant.yaml)


@pytest.fixture(scope="module")
def scene():
    return load_scene("scenes/plant.yaml")


def head_poses(yaws_deg=(-30.0, 0.0, 30.0), pitches_deg=(25.0, 45.0)):
    out = []
    for yaw in np.radians(yaws_deg):
        for pitch in np.radians(pitches_deg):
            d = np.array([math.cos(pitch) * math.cos(yaw), math.cos(pitch) * math.sin(yaw), -math.sin(pitch)])
            out.append(look_at(EYE, EYE + d))
    return out


CAM = PinholeCamera.from_fov(240, 180, math.radians(60.0))


def scan_into(m: VoxelMap, scene, poses, exclude_groups=()):
    hits = []
    for T in poses:
        pts = depth_scan(scene, CAM, T, exclude_groups=exclude_groups)
        m.integrate(pts, T)
        hits.append(pts @ T[:3, :3].T + T[:3, 3])
    return np.concatenate(hits)


def keys(idx: np.ndarray) -> set:
    return set(map(tuple, np.asarray(idx, dtype=np.int64)))


def near(a: np.ndarray, b: np.ndarray, tol_voxels: int = 1) -> np.ndarray:
    """For integer voxel indices a (N, 3): is there an index of b within tol (Chebyshev)?"""
    bs = keys(b)
    offs = [(i, j, k) for i in range(-tol_voxels, tol_voxels + 1) for j in range(-tol_voxels, tol_voxels + 1)
            for k in range(-tol_voxels, tol_voxels + 1)]
    return np.array([any((x + i, y + j, z + k) in bs for i, j, k in offs) for x, y, z in a], dtype=bool)


# ---------------------------------------------------------------- DDA
def _segment_hits_box(o, e, lo, hi, eps):
    """Slab test: does segment o->e meet the box [lo - eps, hi + eps]?"""
    d = e - o
    t0, t1 = 0.0, 1.0
    for a in range(3):
        if abs(d[a]) < 1e-15:
            if o[a] < lo[a] - eps or o[a] > hi[a] + eps:
                return False
            continue
        ta, tb = (lo[a] - eps - o[a]) / d[a], (hi[a] + eps - o[a]) / d[a]
        t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
    return t0 <= t1


def test_dda_matches_brute_force() -> None:
    rng = np.random.default_rng(3)
    for trial in range(60):
        o = rng.uniform(-0.3, 0.3, 3)
        e = o + rng.normal(0.0, 0.15, 3) * (3.0 if trial % 5 == 0 else 1.0)
        walk = ray_voxels(o, e, H)
        # in order, 6-connected, from voxel(o) to voxel(e)
        assert tuple(walk[0]) == tuple(np.floor(o / H).astype(int))
        assert tuple(walk[-1]) == tuple(np.floor(e / H).astype(int))
        assert np.all(np.abs(np.diff(walk, axis=0)).sum(axis=1) == 1)
        lo = np.floor(np.minimum(o, e) / H).astype(int) - 1
        hi = np.floor(np.maximum(o, e) / H).astype(int) + 1
        grid = np.stack(np.meshgrid(*[np.arange(lo[a], hi[a] + 1) for a in range(3)], indexing="ij"), -1).reshape(-1, 3)
        strict = {tuple(c) for c in grid if _segment_hits_box(o, e, c * H, (c + 1) * H, -1e-9)}
        loose = {tuple(c) for c in grid if _segment_hits_box(o, e, c * H, (c + 1) * H, 1e-9)}
        got = keys(walk)
        assert strict <= got <= loose, trial
        assert len(got) == len(walk)  # no voxel twice


def test_dda_axis_aligned_and_degenerate() -> None:
    w = ray_voxels([0.001, 0.001, 0.001], [0.101, 0.001, 0.001], H)
    assert [tuple(x) for x in w] == [(i, 0, 0) for i in range(6)]
    assert ray_voxels([0.01, 0.01, 0.01], [0.01, 0.01, 0.01], H).tolist() == [[0, 0, 0]]
    w = ray_voxels([0.01, 0.01, 0.01], [-0.05, 0.01, 0.01], H)
    assert [tuple(x) for x in w] == [(0, 0, 0), (-1, 0, 0), (-2, 0, 0), (-3, 0, 0)]
    with pytest.raises(ValueError):
        ray_voxels([np.nan, 0, 0], [0, 0, 0], H)


# ---------------------------------------------------------------- fusion (003)
def test_version_follows_what_readers_see() -> None:
    """The map's version changes with the occupied, observed or swept voxels, not with every
    depth map (the same view again changes V and W only)."""
    p = FusionParams(resolution_m=H, extent_min_m=(-1.0, -1.0, -1.0), extent_max_m=(1.0, 1.0, 1.0),
                     hit_weight=1.0, free_weight=0.5, max_weight=2.5, floor_z_m=-10.0, clear_margin_m=0.0)
    m = VoxelMap(p)
    origin = np.array([-0.5, 0.01, 0.01])
    target, beyond = np.array([0.31, 0.01, 0.01]), np.array([0.71, 0.01, 0.01])
    v0 = m.version
    m.integrate(target[None], origin=origin)
    assert m.version > v0 and m.occupied_count() == 1 and m.observed_count == 41
    v1 = m.version
    m.integrate(target[None], origin=origin)            # the same view again: nothing a reader sees changes
    assert m.version == v1
    m.integrate(beyond[None], origin=origin)            # a new voxel observed (and hit)
    assert m.version > v1
    with pytest.raises(ValueError):
        m.occupied_mask()[0, 0, 0] = True               # the readers' view is read-only
    v2 = m.version
    assert m.mark_swept(np.array([[0.0, 0.5, 0.5]]), np.array([[0.0, 0.5, 0.6]]), np.array([0.05])) > 0
    assert m.version > v2
    v3 = m.version
    m.clear()
    assert m.version > v3 and m.occupied_count() == 0 and m.observed_count == 0


def test_weighted_fusion_follows_003() -> None:
    p = FusionParams(resolution_m=H, extent_min_m=(-1.0, -1.0, -1.0), extent_max_m=(1.0, 1.0, 1.0),
                     hit_weight=1.0, free_weight=0.5, max_weight=2.5, floor_z_m=-10.0, clear_margin_m=0.0)
    m = VoxelMap(p)
    origin = np.array([-0.5, 0.01, 0.01])
    target = np.array([0.31, 0.01, 0.01])         # voxel (15, 0, 0)
    beyond = np.array([0.71, 0.01, 0.01])
    V_ref, W_ref = 0.0, 0.0

    def update(z, w):
        nonlocal V_ref, W_ref
        V_ref = (W_ref * V_ref + w * z) / (W_ref + w)       # V_M = (W V + w Z) / (W + w)
        W_ref = min(W_ref + w, p.max_weight)                # W_M = W + w, capped

    # two hits from one depth map count once; hits take precedence over a ray through
    st = m.integrate(np.array([target, target + 0.001, beyond]), origin=origin)
    assert st.hits == 3 and st.voxels_hit == 2
    update(1.0, 1.0)
    v, w = m.value_at(target[None])
    assert v[0] == pytest.approx(V_ref) and w[0] == pytest.approx(W_ref)
    for _ in range(3):
        m.integrate(target[None], origin=origin)
        update(1.0, 1.0)
    for _ in range(6):                              # rays through the voxel: free observations
        m.integrate(beyond[None], origin=origin)
        update(0.0, 0.5)
        v, w = m.value_at(target[None])
        assert v[0] == pytest.approx(V_ref, rel=1e-5) and w[0] == pytest.approx(W_ref)
        assert (tuple(np.floor(target / H).astype(int)) in keys(m.occupied_indices())) == (V_ref > 0.5)
    assert V_ref < 0.5          # the cap let six free observations win over four hits
    # the far voxel: hit each time it was the end point
    v, w = m.value_at(beyond[None])
    assert v[0] == pytest.approx(1.0) and w[0] == pytest.approx(p.max_weight)
    # a voxel on the way, never hit: free
    v, w = m.value_at(np.array([[0.0, 0.01, 0.01]]))
    assert v[0] == 0.0 and w[0] > 0.0


def test_range_floor_and_margin() -> None:
    p = FusionParams(resolution_m=H, extent_min_m=(-1.0, -1.0, -1.0), extent_max_m=(1.0, 1.0, 1.0),
                     max_range_m=0.5, floor_z_m=-0.4, clear_margin_m=0.05)
    m = VoxelMap(p)
    o = np.array([0.0, 0.01, 0.01])
    st = m.integrate(np.array([[0.8, 0.01, 0.01], [0.0, 0.01, -0.45], [0.3, 0.01, 0.01]]), origin=o)
    assert (st.beyond_range, st.floor, st.hits) == (1, 1, 1)
    assert m.value_at(np.array([[0.7, 0.01, 0.01]]))[1][0] == 0.0      # beyond max range: untouched
    assert m.value_at(np.array([[0.45, 0.01, 0.01]]))[1][0] > 0.0      # truncated ray clears to 0.5 - margin
    assert m.value_at(np.array([[0.485, 0.01, 0.01]]))[1][0] == 0.0    # ... not within the margin
    assert m.value_at(np.array([[0.0, 0.01, -0.3]]))[1][0] > 0.0       # the floor ray clears
    assert m.occupied_count() == 1
    np.testing.assert_allclose(m.occupied_centers(), [[0.31, 0.01, 0.01]])


def test_bad_input_and_params() -> None:
    m = VoxelMap()
    with pytest.raises(ValueError):
        m.integrate(np.array([[np.nan, 0.0, 1.0]]), np.eye(4))
    with pytest.raises(ValueError):
        m.integrate(np.zeros((2, 3)), np.eye(3))
    with pytest.raises(ValueError):
        m.integrate(np.zeros((2, 3)))
    assert m.occupied_count() == 0 and m.depth_maps == 0
    for bad in (dict(resolution_m=0.0), dict(resolution_m=float("nan")), dict(extent_max_m=(1.0, 1.0)),
                dict(extent_min_m=(0.0, 0.0, 0.0), extent_max_m=(0.01, 1.0, 1.0)), dict(free_weight=-1.0),
                dict(max_weight=0.1), dict(occupied_threshold=1.0), dict(max_range_m=0.0),
                dict(clear_margin_m=-0.1), dict(resolution_m=1e-4)):
        with pytest.raises(ValueError):
            VoxelMap(FusionParams(**bad))


# ---------------------------------------------------------------- the plant scene
def test_scan_matches_scene_within_one_voxel(scene) -> None:
    m = VoxelMap(FusionParams(resolution_m=H))
    hits = scan_into(m, scene, head_poses())
    occ = m.occupied_indices()
    gt = np.floor(scene.voxelize(H, extent=((-0.5, -1.0, 0.0), (1.5, 1.0, 2.0))) / H).astype(np.int64)
    assert len(occ) > 2000
    # no false occupancy: every occupied voxel is within one voxel of the scene's surface voxels
    assert near(occ, gt).all()
    # completeness: the ground-truth voxels the scans saw (containing a hit, above the floor band)
    seen = np.unique(np.floor(hits[hits[:, 2] > 0.04] / H).astype(np.int64), axis=0)
    visible = np.array(sorted(keys(seen) & keys(gt)))
    found = near(visible, occ, 0).mean()
    assert found > 0.9, found
    assert near(visible, occ, 1).mean() > 0.99
    # the floor is not in the map
    assert occ[:, 2].min() * H >= 0.0


def test_removed_pipe_is_cleared(scene) -> None:
    m = VoxelMap(FusionParams(resolution_m=H))
    poses = head_poses()
    scan_into(m, scene, poses)
    scan_into(m, scene, poses)
    without = dataclasses.replace(scene, primitives=tuple(p for p in scene.primitives if p.name != "passage_pipe"))
    before = m.occupied_centers()
    # voxels that only the pipe explains: farther than 1.5 voxels from every other surface
    pipe_only = before[np.abs(without.sdf(before, include_floor=False)) > 1.5 * H]
    assert len(pipe_only) > 150
    others = before[np.abs(without.sdf(before, include_floor=False)) <= 0.5 * H]
    for _ in range(6):                      # rescan the changed scene (each voxel seen from ~2 poses)
        scan_into(m, without, poses)
    after = m.occupied_centers()
    kept = keys(np.floor(after / H).astype(np.int64))
    left = np.mean([tuple(k) in kept for k in np.floor(pipe_only / H).astype(np.int64)])
    assert left < 0.02, left                                      # the pipe is gone
    gt = np.floor(without.voxelize(H, extent=((-0.5, -1.0, 0.0), (1.5, 1.0, 2.0))) / H).astype(np.int64)
    assert near(np.floor(after / H).astype(np.int64), gt).all()   # and nothing else is wrong
    still = np.mean([tuple(k) in kept for k in np.floor(others / H).astype(np.int64)])
    assert still > 0.95, still                                    # the rest of the scene stays


def test_extent_bounds_memory_and_clear(scene) -> None:
    p = FusionParams(resolution_m=H, extent_min_m=(0.3, -0.3, 0.5), extent_max_m=(0.9, 0.3, 1.1))
    m = VoxelMap(p)
    assert m.shape == (30, 30, 30) and m.capacity == 27000
    nbytes = m.nbytes
    rng = np.random.default_rng(0)
    T = look_at(EYE, [0.7, 0.0, 0.9])
    for _ in range(5):
        pts = depth_scan(scene, CAM, T, noise_m=0.005, rng=rng)
        st = m.integrate(pts, T)
        assert st.outside > 0 and st.hits > 0 and st.hits + st.outside + st.floor + st.beyond_range == st.points
    # random far-away points never leave the extent
    st = m.integrate(rng.uniform(-5.0, 5.0, (20000, 3)), origin=EYE)
    assert st.outside > 0
    c = m.occupied_centers()
    assert len(c) > 0
    assert np.all(c >= np.array(p.extent_min_m)) and np.all(c <= np.array(p.extent_max_m))
    assert m.nbytes == nbytes and m.V.shape == (30, 30, 30)
    m.clear()
    assert m.occupied_count() == 0 and not m.W.any() and m.depth_maps == 0


def test_noisy_scans_stay_near_the_surface(scene) -> None:
    m = VoxelMap(FusionParams(resolution_m=H))
    rng = np.random.default_rng(1)
    for T in head_poses():
        m.integrate(depth_scan(scene, CAM, T, noise_m=0.003, rng=rng), T)
    occ = m.occupied_indices()
    gt = np.floor(scene.voxelize(H, extent=((-0.5, -1.0, 0.0), (1.5, 1.0, 2.0))) / H).astype(np.int64)
    assert near(occ, gt).mean() > 0.99


def test_discretized_rays_match_every_ray(scene) -> None:
    """One ray per distinct end voxel (OctoMap's discretized insertion) gives the map that
    walking every ray gives, walking a fraction of the rays."""
    maps = {}
    for disc in (True, False):
        m = VoxelMap(FusionParams(resolution_m=H, discretize_rays=disc))
        rays = points = 0
        for T in head_poses():
            st = m.integrate(depth_scan(scene, CAM, T), T)
            rays, points = rays + st.rays_cast, points + st.points
        maps[disc] = (keys(m.occupied_indices()), rays, points)
    (a, rays_d, points), (b, rays_all, _) = maps[True], maps[False]
    assert rays_all <= points and rays_d < 0.75 * rays_all
    assert len(a ^ b) < 0.01 * len(a | b)


# ---------------------------------------------------------------- unobserved space
def test_frontier_and_unobserved_blocks_on_one_ray() -> None:
    """One ray along +x at y = z = 0.51 m from x = 0.05 to a wall point at x = 0.55: the
    voxels it crossed are free, its end occupied; the frontier is the unobserved voxels
    beside the free ones (26-neighbours), not those beside the occupied end only; blocks
    that no ray reached are the unobserved blocks."""
    m = VoxelMap(FusionParams(resolution_m=H, extent_min_m=(0.0, 0.0, 0.0), extent_max_m=(1.0, 1.0, 1.0),
                              clear_margin_m=0.0, floor_z_m=-1.0))
    region = ((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    assert len(m.frontier_centers(*region)) == 0                 # nothing observed: no frontier ...
    assert len(m.unobserved_blocks(*region, 5)) == 10 ** 3       # ... and every block unobserved
    origin = np.array([0.05, 0.51, 0.51])
    m.integrate(np.array([[0.55, 0.51, 0.51]]), origin=origin)
    free = keys(ray_voxels(origin, [0.55, 0.51, 0.51], H)[:-1])
    occupied = keys(m.occupied_indices())
    assert occupied == {(27, 25, 25)}
    frontier = keys(np.floor(m.frontier_centers(*region) / H + 1e-9))
    expected = {(x + i, y + j, z + k) for x, y, z in free for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)}
    expected -= free | occupied
    assert frontier == expected
    assert (28, 25, 25) not in frontier                          # behind the hit: next to it, not to free space
    # a region that clips the ray: only its part, and free neighbours just outside still count
    part = keys(np.floor(m.frontier_centers((0.0, 0.0, 0.0), (0.2, 1.0, 1.0)) / H + 1e-9))
    assert part == {k for k in expected if k[0] <= 9} and part
    assert len(m.frontier_centers((2.0, 2.0, 2.0), (3.0, 3.0, 3.0))) == 0     # outside the extent
    blocks = m.unobserved_blocks(*region, 5)
    assert len(blocks) == 10 ** 3 - 6                            # the ray crossed blocks x 0..5 at y = z = 5
    seen = {tuple(np.floor(b / 0.1).astype(int))
            for b in np.array([[x, 0.51, 0.51] for x in np.arange(0.05, 0.6, 0.1)])}
    assert not seen & {tuple(np.floor(b / 0.1).astype(int)) for b in blocks}
    np.testing.assert_allclose(blocks[0], [0.05, 0.05, 0.05])    # a block's centre
    with pytest.raises(ValueError, match="block_voxels"):
        m.unobserved_blocks(*region, 0)


def test_scan_frontier_encloses_what_the_head_saw(scene) -> None:
    """After a head scan of the plant: the frontier lies next to observed free space and is
    not observed itself; the space in front of the robot at hand height is observed."""
    m = VoxelMap(FusionParams(resolution_m=H))
    scan_into(m, scene, head_poses())
    region = ((0.0, -1.0, 0.1), (1.3, 1.0, 2.0))
    F = m.frontier_centers(*region)
    assert 1000 < len(F) < 200_000
    _, w = m.value_at(F)
    assert np.all(w == 0.0)
    _, w = m.value_at(np.array([[0.5, 0.0, 0.9], [0.6, -0.2, 1.0]]))
    assert np.all(w > 0.0)


def test_swept_space_counts_as_observed_free_never_as_free_of_obstacles() -> None:
    m = VoxelMap(FusionParams(resolution_m=H, extent_min_m=(0.0, 0.0, 0.0), extent_max_m=(1.0, 1.0, 1.0),
                              clear_margin_m=0.0, floor_z_m=-1.0))
    m.integrate(np.array([[0.51, 0.51, 0.51]]), origin=(0.05, 0.51, 0.51))     # one hit at the capsule's axis
    occupied = keys(m.occupied_indices())
    n = m.mark_swept(np.array([[0.4, 0.5, 0.5]]), np.array([[0.6, 0.5, 0.5]]), np.array([0.1]))
    assert n > 1000 and m.mark_swept(np.array([[0.4, 0.5, 0.5]]), np.array([[0.6, 0.5, 0.5]]), np.array([0.1])) == 0
    assert keys(m.occupied_indices()) == occupied                           # occupancy untouched
    region = ((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    F = m.frontier_centers(*region)
    assert len(F) and np.all(m.value_at(F)[1] == 0.0)
    d = np.linalg.norm(F - np.clip(F, [0.4, 0.5, 0.5], [0.6, 0.5, 0.5]), axis=1)
    assert d.min() > 0.1 - 1e-9                                             # none inside the swept capsule
    assert len(m.unobserved_blocks(*region, 5)) < 10 ** 3 - 6               # swept blocks count as observed
    m.mark_swept(np.array([[5.0, 5.0, 5.0]]), np.array([[6.0, 5.0, 5.0]]), np.array([0.1]))   # outside: nothing
    m.clear()
    assert not m.swept.any() and len(m.frontier_centers(*region)) == 0
