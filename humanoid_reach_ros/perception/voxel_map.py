"""Measured voxel map: weighted incremental fusion of depth maps with free-space clearing.

The environment model of Kanehiro et al. (Sec. II) is a voxel map accumulated from the
robot's range sensors; Das (003, "Mesh Modeling") fuses successive depth maps per
element ``v`` by the weighted incremental update

    V_M(v) = (W_{M-1}(v) V_{M-1}(v) + w_M(v) Z_M(v)) / (W_{M-1}(v) + w_M(v)),
    W_M(v) = W_{M-1}(v) + w_M(v),

which :class:`VoxelMap` applies to every voxel a depth map ``M`` observes:

* ``Z_M(v) = 1`` (occupied) when a measured point of depth map ``M`` ends in ``v``,
  with weight ``w_M = hit_weight``;
* ``Z_M(v) = 0`` (free) when the ray from the sensor origin to a measured point
  passes through ``v`` (and no point of the same depth map ends in it: hits take
  precedence within one depth map), with weight ``w_M = free_weight``.

Each voxel is updated at most once per depth map (a per-voxel stamp: 8 x the depth
map's number + flags hit / freed / ray end). ``V`` is thus the weighted fraction of depth maps
that saw the voxel occupied;
a voxel is *occupied* when ``V > occupied_threshold`` and ``W >= min_weight``.

Simplification of 003, named: the accumulated weight is capped,
``W_M = min(W_{M-1} + w_M, max_weight)`` (a fading memory), so that a change of the
scene -- a pipe removed -- is reflected after a bounded number of depth maps
(``V`` falls below the threshold after about ``max_weight / free_weight`` observations
of free space) instead of after as many depth maps as built the voxel up. Without
the cap (``max_weight = inf``) the update is exactly 003's.

Grid: the OctoMap key convention of :mod:`humanoid_reach_ros.sim.scene` (voxel ``i``
covers ``[i h, (i + 1) h)``, centre ``(i + 1/2) h``), so map voxels and
``Scene.voxelize`` ground truth coincide. The map is a dense array over the voxels
whose centres lie in the extent (bounds inclusive): memory is fixed by the extent
(12 bytes per voxel: ``V``, ``W`` float32 and an int32 stamp) whatever the input.
Points outside the extent are not integrated (counted), but their rays still clear
the part of the extent they cross. Points below ``floor_z_m`` are the ground (the
planner's map has no floor, cf. ``geometry.distance``): their rays clear, they are
not marked. Ranges beyond ``max_range_m`` are truncated: the ray clears up to the
maximum range and marks nothing.

Free-space clearing walks each ray with the 3D digital differential analyser of
Amanatides and Woo (:func:`ray_voxels`), in a numba kernel together with the point
transform and the hit pass (:meth:`VoxelMap.integrate`). The walk stops
``clear_margin_m`` short of the measured point, so that a ray grazing a surface does
not erode the voxels next to its own end point. Option ``discretize_rays`` (off by
default; the "discretized" point-cloud insertion of OctoMap): only the first point ending
in each voxel casts its ray in one depth map -- about 40 % fewer rays on the plant scene --
but a voxel crossed only by skipped rays is never cleared while the camera stands still
(seen in the node test: two voxels of a removed pipe's silhouette survived), so exact
clearing walks every ray.

This module never imports rclpy.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numba as nb
import numpy as np
from scipy.ndimage import binary_dilation

from humanoid_reach_ros.geometry.camera import PinholeCamera, look_at
from humanoid_reach_ros.geometry.voxels import mark_capsules

Vec3 = tuple[float, float, float]

#: refuse extents whose dense arrays would exceed this many voxels (12 B each)
MAX_VOXELS = 64_000_000


@dataclass(frozen=True)
class FusionParams:
    """Parameters of :class:`VoxelMap` (units in the names; weights are 003's ``w``).

    ``extent_min_m`` / ``extent_max_m``: the mapped box in the world frame [m];
    ``hit_weight`` / ``free_weight``: ``w_M`` of an occupied / free observation;
    ``max_weight``: cap of ``W`` (fading memory; ``inf`` = 003 exactly);
    ``occupied_threshold``: a voxel is occupied when ``V`` exceeds it;
    ``min_weight``: ... and ``W`` reaches it (less: not observed enough);
    ``max_range_m``: rays are truncated here; ``floor_z_m``: points below are ground;
    ``clear_margin_m``: free-space walk stops this short of the measured point;
    ``discretize_rays``: walk one ray per distinct end voxel and depth map.
    """

    resolution_m: float = 0.02
    extent_min_m: Vec3 = (-1.0, -1.0, -0.05)
    extent_max_m: Vec3 = (1.5, 1.0, 2.0)
    hit_weight: float = 1.0
    free_weight: float = 0.5
    max_weight: float = 3.0
    occupied_threshold: float = 0.5
    min_weight: float = 1.0
    max_range_m: float = 4.0
    floor_z_m: float = 0.02
    clear_margin_m: float = 0.02
    discretize_rays: bool = False

    def validate(self) -> None:
        """``ValueError`` naming the first bad field."""
        h = self.resolution_m
        if not (math.isfinite(h) and h > 0.0):
            raise ValueError(f"resolution_m must be a positive number, got {h}")
        lo, hi = np.asarray(self.extent_min_m, float), np.asarray(self.extent_max_m, float)
        if lo.shape != (3,) or hi.shape != (3,) or not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise ValueError("extent_min_m / extent_max_m must be finite 3-vectors")
        if np.any(hi - lo < h):
            raise ValueError(f"extent {lo.tolist()} .. {hi.tolist()} must span at least one voxel per axis")
        for name in ("hit_weight", "free_weight"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"{name} must be a positive number, got {v}")
        if not self.max_weight >= max(self.hit_weight, self.free_weight):
            raise ValueError(f"max_weight ({self.max_weight}) must be >= hit_weight and free_weight")
        if not 0.0 <= self.occupied_threshold < 1.0:
            raise ValueError(f"occupied_threshold must be in [0, 1), got {self.occupied_threshold}")
        if not (math.isfinite(self.min_weight) and self.min_weight >= 0.0):
            raise ValueError(f"min_weight must be >= 0, got {self.min_weight}")
        if not (math.isfinite(self.max_range_m) and self.max_range_m > 0.0):
            raise ValueError(f"max_range_m must be positive, got {self.max_range_m}")
        if not math.isfinite(self.floor_z_m):
            raise ValueError("floor_z_m must be finite (use a large negative value to keep everything)")
        if not (math.isfinite(self.clear_margin_m) and self.clear_margin_m >= 0.0):
            raise ValueError(f"clear_margin_m must be >= 0, got {self.clear_margin_m}")


@dataclass(frozen=True)
class IntegrationStats:
    """What one :meth:`VoxelMap.integrate` call did with its points."""

    points: int            # points given
    hits: int              # points that marked a voxel (inside the extent, above the floor, in range)
    outside: int           # points outside the extent (not marked; rays still clear)
    floor: int             # points below floor_z_m (ground: clear only)
    beyond_range: int      # points beyond max_range_m (truncated: clear only)
    voxels_hit: int        # distinct voxels updated as occupied
    voxels_freed: int      # distinct voxels updated as free
    rays_cast: int         # rays walked for free space (fewer than points with discretize_rays; only
                           # rays crossing the extent, clipped to it)


# ----------------------------------------------------------------- 3D DDA
@nb.njit(cache=True, nogil=True)
def _dda_axis(o, d, i, h):
    """One axis of the DDA: step direction, segment parameter t in [0, 1] of the first
    voxel boundary crossed, and t per voxel (inf when the segment does not move along it)."""
    if d > 0.0:
        return 1, ((i + 1) * h - o) / d, h / d
    if d < 0.0:
        return -1, (i * h - o) / d, -h / d
    return 0, np.inf, np.inf


@nb.njit(cache=True, nogil=True)
def _dda(ox, oy, oz, ex, ey, ez, inv_h, out):
    """Amanatides-Woo walk of the segment o -> e over the grid of pitch 1/inv_h.

    Writes the integer indices of the voxels the segment crosses, in order from
    voxel(o) to voxel(e) inclusive, into ``out`` (K, 3) and returns K (at most
    ``len(out)``: longer walks are cut)."""
    ix, iy, iz = math.floor(ox * inv_h), math.floor(oy * inv_h), math.floor(oz * inv_h)
    jx, jy, jz = math.floor(ex * inv_h), math.floor(ey * inv_h), math.floor(ez * inv_h)
    h = 1.0 / inv_h
    sx, tmx, tdx = _dda_axis(ox, ex - ox, ix, h)
    sy, tmy, tdy = _dda_axis(oy, ey - oy, iy, h)
    sz, tmz, tdz = _dda_axis(oz, ez - oz, iz, h)
    n_max = min(out.shape[0], abs(jx - ix) + abs(jy - iy) + abs(jz - iz) + 1)
    k = 0
    while k < n_max:
        out[k, 0], out[k, 1], out[k, 2] = ix, iy, iz
        k += 1
        if ix == jx and iy == jy and iz == jz:
            break
        if tmx <= tmy and tmx <= tmz:
            if tmx > 1.0:
                break
            ix += sx
            tmx += tdx
        elif tmy <= tmz:
            if tmy > 1.0:
                break
            iy += sy
            tmy += tdy
        else:
            if tmz > 1.0:
                break
            iz += sz
            tmz += tdz
    return k


def ray_voxels(origin: Sequence[float], end: Sequence[float], resolution_m: float) -> np.ndarray:
    """Integer indices (K, 3) of the voxels the segment ``origin -> end`` crosses, in order
    (3D DDA, Amanatides & Woo 1987), from the voxel of ``origin`` to that of ``end``."""
    o = np.asarray(origin, dtype=float)
    e = np.asarray(end, dtype=float)
    if o.shape != (3,) or e.shape != (3,) or not (np.all(np.isfinite(o)) and np.all(np.isfinite(e))):
        raise ValueError("origin and end must be finite 3-vectors")
    n = int(np.sum(np.abs(np.floor(e / resolution_m) - np.floor(o / resolution_m)))) + 1
    out = np.empty((n, 3), dtype=np.int64)
    k = _dda(o[0], o[1], o[2], e[0], e[1], e[2], 1.0 / resolution_m, out)
    return out[:k].copy()


# ----------------------------------------------------------------- fusion kernel
@nb.njit(cache=True, nogil=True)
def _fuse(V, W, i, j, k, z, w, w_max):
    """003's update of one voxel: V <- (W V + w Z) / (W + w), W <- min(W + w, w_max)."""
    Wv = W[i, j, k]
    V[i, j, k] = (Wv * V[i, j, k] + w * z) / (Wv + w)
    W[i, j, k] = min(Wv + w, w_max)


# per-voxel stamp: 8 * depth-map number + flags of what that depth map did to the voxel
_HIT, _FREE, _RAY_END = 1, 2, 4


@nb.njit(cache=True, nogil=True, inline="always")
def _flags(stamp, i, j, k, tag):
    s = stamp[i, j, k]
    return s & 7 if (s >> 3) == (tag >> 3) else 0


@nb.njit(cache=True, nogil=True)
def _integrate_kernel(P, R, t, V, W, stamp, tag, i_lo, h, hit_w, free_w, w_max,
                      max_range, floor_z, margin, discretize, buf, counts):
    """Transform points P (camera frame) by (R, t) into the world, mark hits, then clear rays.

    ``tag`` = 8 * depth-map number; counts: [hits, outside, floor, beyond_range, voxels_hit,
    voxels_freed, rays_cast]."""
    nx, ny, nz = V.shape
    inv_h = 1.0 / h
    ox, oy, oz = t[0], t[1], t[2]
    n = P.shape[0]
    E = np.empty((n, 3))
    R_eff = np.empty(n)
    # pass 1: world points, ranges, hits (hits take precedence over free space in one depth map)
    for m in range(n):
        px, py, pz = P[m, 0], P[m, 1], P[m, 2]
        wx = R[0, 0] * px + R[0, 1] * py + R[0, 2] * pz + ox
        wy = R[1, 0] * px + R[1, 1] * py + R[1, 2] * pz + oy
        wz = R[2, 0] * px + R[2, 1] * py + R[2, 2] * pz + oz
        dx, dy, dz = wx - ox, wy - oy, wz - oz
        r = math.sqrt(dx * dx + dy * dy + dz * dz)
        E[m, 0], E[m, 1], E[m, 2] = wx, wy, wz
        R_eff[m] = r
        if r > max_range:
            counts[3] += 1
            continue
        if wz < floor_z:
            counts[2] += 1
            continue
        i = math.floor(wx * inv_h) - i_lo[0]
        j = math.floor(wy * inv_h) - i_lo[1]
        k = math.floor(wz * inv_h) - i_lo[2]
        if i < 0 or j < 0 or k < 0 or i >= nx or j >= ny or k >= nz:
            counts[1] += 1
            continue
        counts[0] += 1
        f = _flags(stamp, i, j, k, tag)
        if not f & _HIT:
            stamp[i, j, k] = tag | f | _HIT
            _fuse(V, W, i, j, k, 1.0, hit_w, w_max)
            counts[4] += 1
    # pass 2: free space along each ray, up to clear_margin short of the point (or max range);
    # with ``discretize`` one ray per distinct end voxel (in the grid) and depth map
    for m in range(n):
        r = R_eff[m]
        if r <= 0.0:
            continue
        length = min(r, max_range) - margin
        if length <= 0.0:
            continue
        s = length / r
        ex = ox + (E[m, 0] - ox) * s
        ey = oy + (E[m, 1] - oy) * s
        ez = oz + (E[m, 2] - oz) * s
        if discretize and r <= max_range:
            i = math.floor(E[m, 0] * inv_h) - i_lo[0]
            j = math.floor(E[m, 1] * inv_h) - i_lo[1]
            k = math.floor(E[m, 2] * inv_h) - i_lo[2]
            if 0 <= i < nx and 0 <= j < ny and 0 <= k < nz:
                f = _flags(stamp, i, j, k, tag)
                if f & _RAY_END:
                    continue
                stamp[i, j, k] = tag | f | _RAY_END
        # clip the segment to the grid's box (slabs): no walking outside the extent
        t0, t1 = 0.0, 1.0
        for a in range(3):
            oa = (ox, oy, oz)[a]
            da = (ex, ey, ez)[a] - oa
            lo_a = i_lo[a] * h
            hi_a = (i_lo[a] + V.shape[a]) * h
            if da == 0.0:
                if oa < lo_a or oa >= hi_a:
                    t1 = -1.0
            else:
                ta, tb = (lo_a - oa) / da, (hi_a - oa) / da
                t0 = max(t0, min(ta, tb))
                t1 = min(t1, max(ta, tb))
        if t0 > t1:
            continue
        counts[6] += 1
        sx, sy, sz = ox + (ex - ox) * t0, oy + (ey - oy) * t0, oz + (ez - oz) * t0
        K = _dda(sx, sy, sz, ox + (ex - ox) * t1, oy + (ey - oy) * t1, oz + (ez - oz) * t1, inv_h, buf)
        for q in range(K):
            i = buf[q, 0] - i_lo[0]
            j = buf[q, 1] - i_lo[1]
            k = buf[q, 2] - i_lo[2]
            if i < 0 or j < 0 or k < 0 or i >= nx or j >= ny or k >= nz:
                continue
            f = _flags(stamp, i, j, k, tag)
            if f & (_HIT | _FREE):
                continue
            stamp[i, j, k] = tag | f | _FREE
            _fuse(V, W, i, j, k, 0.0, free_w, w_max)
            counts[5] += 1


# ----------------------------------------------------------------- the map
class VoxelMap:
    """Dense fusion map over a bounded extent (see the module docstring).

    Not thread-safe: callers serialise :meth:`integrate`, :meth:`clear` and the readers.
    """

    def __init__(self, params: FusionParams | None = None) -> None:
        p = params or FusionParams()
        p.validate()
        self.params = p
        h = p.resolution_m
        lo, hi = np.asarray(p.extent_min_m, float), np.asarray(p.extent_max_m, float)
        # voxel indices whose centres (i + 1/2) h lie in [lo, hi] (as Scene.voxelize)
        self.index_lo = np.ceil(lo / h - 0.5 - 1e-9).astype(np.int64)
        self.index_hi = np.floor(hi / h - 0.5 + 1e-9).astype(np.int64)
        dims = self.index_hi - self.index_lo + 1
        if np.any(dims <= 0):
            raise ValueError("extent contains no voxel centre")
        n = int(np.prod(dims))
        if n > MAX_VOXELS:
            raise ValueError(f"extent at {h} m has {n} voxels > {MAX_VOXELS}: enlarge resolution_m or shrink "
                             "the extent")
        self.shape = tuple(int(d) for d in dims)
        self.V = np.zeros(self.shape, dtype=np.float32)   # fused occupancy V_M(v) in [0, 1]
        self.W = np.zeros(self.shape, dtype=np.float32)   # accumulated weight W_M(v)
        self._stamp = np.zeros(self.shape, dtype=np.int32)   # 8 * depth map + flags (kernel)
        self.swept = np.zeros(self.shape, dtype=bool)   # space the robot's body has been in (mark_swept)
        self._occupied = np.zeros(self.shape, dtype=bool)   # occupied voxels (_update_layers)
        self.observed_count = 0     # voxels a ray has reached (W > 0): only grows until clear()
        self.swept_count = 0        # voxels the robot's body has been in (mark_swept)
        self.version = 0            # changes whenever the occupied, observed or swept voxels may have changed
        self._scan = 0
        max_steps = int(3 * (p.max_range_m / h + 2)) + 3
        self._buf = np.empty((max_steps, 3), dtype=np.int64)
        self.depth_maps = 0     # depth maps integrated since the last clear

    # ------------------------------------------------------------ properties
    @property
    def resolution_m(self) -> float:
        return self.params.resolution_m

    @property
    def nbytes(self) -> int:
        """Memory of the map's arrays [bytes] (fixed by the extent)."""
        return self.V.nbytes + self.W.nbytes + self._stamp.nbytes + self._buf.nbytes + self.swept.nbytes

    @property
    def capacity(self) -> int:
        """Voxels in the extent."""
        return self.V.size

    # ------------------------------------------------------------ updates
    def clear(self) -> None:
        """Forget everything (all voxels unknown)."""
        self.V.fill(0.0)
        self.W.fill(0.0)
        self.swept.fill(False)
        self._occupied.fill(False)
        self.observed_count = self.swept_count = 0
        self._stamp.fill(0)
        self._scan = 0
        self.depth_maps = 0
        self.version += 1

    def integrate(self, points: np.ndarray, sensor_pose: np.ndarray | None = None,
                  origin: Sequence[float] | None = None, mark_only: bool = False) -> IntegrationStats:
        """Fuse one depth map: points (N, 3) [m] in the sensor frame, ``sensor_pose`` the
        4x4 world-from-sensor transform (its translation is the rays' origin).

        Alternatively ``points`` in the world frame with ``sensor_pose=None`` and the
        rays' ``origin`` (3,) given. With ``mark_only`` (world points, origin unknown) the
        points are marked occupied and nothing is cleared (no range limit applies).
        Points must be finite (drop NaN before: ValueError).
        """
        P = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        if mark_only and sensor_pose is None and origin is None:
            origin = (0.0, 0.0, 0.0)
        if sensor_pose is None:
            if origin is None:
                raise ValueError("integrate needs sensor_pose or origin")
            T = np.eye(4)
            T[:3, 3] = np.asarray(origin, dtype=float).reshape(3)
            P = P - T[:3, 3]   # world points -> a sensor frame at the origin, axes of the world
        else:
            T = np.asarray(sensor_pose, dtype=float)
            if T.shape != (4, 4):
                raise ValueError(f"sensor_pose must be 4x4, got {T.shape}")
        if not np.all(np.isfinite(T)) or not np.all(np.isfinite(P)):
            raise ValueError("points and sensor pose must be finite")
        self._scan += 1
        if self._scan >= (1 << 28) - 1:  # stamps (8 * depth map, int32) wrap: forget them (not the map)
            self._stamp.fill(0)
            self._scan = 1
        counts = np.zeros(7, dtype=np.int64)
        p = self.params
        _integrate_kernel(P, np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]), self.V, self.W,
                          self._stamp, np.int32(8 * self._scan), self.index_lo, float(p.resolution_m),
                          float(p.hit_weight), float(p.free_weight), float(p.max_weight),
                          np.inf if mark_only else float(p.max_range_m), float(p.floor_z_m),
                          np.inf if mark_only else float(p.clear_margin_m), bool(p.discretize_rays), self._buf,
                          counts)
        self.depth_maps += 1
        self._update_layers()
        return IntegrationStats(len(P), *(int(c) for c in counts))

    def _update_layers(self) -> None:
        """The occupied voxels and the observed count after a depth map; bumps :attr:`version`
        when either changed (a depth map that changes only V and W leaves it)."""
        p = self.params
        occupied = (self.V > p.occupied_threshold) & (self.W >= p.min_weight)
        observed = int(np.count_nonzero(self.W))
        if observed != self.observed_count or not np.array_equal(occupied, self._occupied):
            self.version += 1
        self._occupied, self.observed_count = occupied, observed

    # ------------------------------------------------------------ readers
    def occupied_mask(self) -> np.ndarray:
        """Occupied voxels (bool, the map's shape; read-only): ``V > occupied_threshold`` and
        ``W >= min_weight``."""
        m = self._occupied.view()
        m.flags.writeable = False
        return m

    def occupied_count(self) -> int:
        return int(np.count_nonzero(self.occupied_mask()))

    def occupied_indices(self) -> np.ndarray:
        """Integer voxel indices (N, 3) of the occupied voxels (sorted by x, y, z)."""
        return np.argwhere(self.occupied_mask()).astype(np.int64) + self.index_lo

    def occupied_centers(self) -> np.ndarray:
        """Centres ``(i + 1/2) h`` (N, 3) [m, world] of the occupied voxels."""
        return (self.occupied_indices().astype(np.float64) + 0.5) * self.params.resolution_m

    def mark_swept(self, p0: np.ndarray, p1: np.ndarray, radii: np.ndarray) -> int:
        """Remember the voxels whose centres lie within capsules (segments ``p0``-``p1``
        (S, 3) [m, world], ``radii`` (S,)) as space the robot's body has been in: free for
        the unobserved-space readers (a head camera never sees around its own body), never
        for occupancy (an occupied voxel stays occupied). Returns the voxels newly marked."""
        added = int(mark_capsules(np.ascontiguousarray(p0, dtype=np.float64).reshape(-1, 3),
                                  np.ascontiguousarray(p1, dtype=np.float64).reshape(-1, 3),
                                  np.ascontiguousarray(radii, dtype=np.float64).reshape(-1),
                                  float(self.params.resolution_m), self.index_lo, self.swept))
        if added:
            self.swept_count += added
            self.version += 1
        return added

    def frontier_centers(self, region_min_m: Sequence[float], region_max_m: Sequence[float]) -> np.ndarray:
        """Centres (N, 3) [m, world] of the *unobserved frontier* inside a region: voxels no ray
        has reached (``W == 0``) and the robot's body has not swept, with an observed free or
        swept voxel among their 26 neighbours.

        Unobserved space is bounded by its frontier, so a robot that starts in observed space
        and must not enter unobserved space only has to avoid these voxels (at the map's
        resolution: the occupied voxels' own argument); the voxels behind a surface (seen from
        nowhere, next to occupied voxels only) are not on it. Outside ``[region_min_m,
        region_max_m]`` (clipped to the extent) nothing is returned."""
        h = self.params.resolution_m
        region = self._region_indices(region_min_m, region_max_m)
        if region is None:
            return np.empty((0, 3))
        lo, hi = region
        a = lo - self.index_lo
        b = hi - self.index_lo + 1
        # one voxel more on every side, so that a free neighbour just outside the region counts
        a1, b1 = np.maximum(a - 1, 0), np.minimum(b + 1, np.array(self.shape))
        sl = tuple(slice(int(x), int(y)) for x, y in zip(a1, b1))
        W, swept = self.W[sl], self.swept[sl]
        free = ((W > 0.0) | swept) & ~self.occupied_mask()[sl]
        near_free = binary_dilation(free, structure=np.ones((3, 3, 3), bool))
        frontier = near_free & (W == 0.0) & ~swept
        inner = tuple(slice(int(x - y), int(x - y + (c - x))) for x, y, c in zip(a, a1, b))
        idx = np.argwhere(frontier[inner]) + lo
        return (idx.astype(np.float64) + 0.5) * h

    def unobserved_blocks(self, region_min_m: Sequence[float], region_max_m: Sequence[float],
                          block_voxels: int) -> np.ndarray:
        """Centres (M, 3) [m, world] of the cubes of ``block_voxels``^3 voxels inside a region
        (from its lower corner; a partial cube at the upper end counts) of which no voxel has
        been reached by a ray nor swept by the robot: space nobody has observed, coarse (a
        frontier alone cannot tell it: with nothing observed yet there is no frontier)."""
        h, b = self.params.resolution_m, int(block_voxels)
        if b < 1:
            raise ValueError(f"block_voxels must be >= 1, got {block_voxels}")
        region = self._region_indices(region_min_m, region_max_m)
        if region is None:
            return np.empty((0, 3))
        lo, hi = region
        a, c = lo - self.index_lo, hi - self.index_lo + 1
        seen = (self.W[a[0]:c[0], a[1]:c[1], a[2]:c[2]] > 0.0) | self.swept[a[0]:c[0], a[1]:c[1], a[2]:c[2]]
        n = -(-np.array(seen.shape) // b)            # blocks per axis (ceil)
        padded = np.zeros(n * b, dtype=bool)          # beyond the region: counts as unobserved
        padded[:seen.shape[0], :seen.shape[1], :seen.shape[2]] = seen
        any_seen = padded.reshape(n[0], b, n[1], b, n[2], b).any(axis=(1, 3, 5))
        blocks = np.argwhere(~any_seen)
        return (lo + blocks * b).astype(np.float64) * h + 0.5 * b * h

    def _region_indices(self, region_min_m: Sequence[float], region_max_m: Sequence[float]):
        """Voxel index range ``(lo, hi)`` (inclusive) of the centres in a box, clipped to the
        extent (as the extent itself: ``__init__``); None when it holds none."""
        h = self.params.resolution_m
        lo = np.maximum(np.ceil(np.asarray(region_min_m, float) / h - 0.5 - 1e-9).astype(np.int64), self.index_lo)
        hi = np.minimum(np.floor(np.asarray(region_max_m, float) / h - 0.5 + 1e-9).astype(np.int64), self.index_hi)
        return None if np.any(hi < lo) else (lo, hi)

    def value_at(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(V, W) of the voxels containing world points (N, 3); NaN / 0 outside the extent."""
        idx = np.floor(np.asarray(points, float).reshape(-1, 3) / self.params.resolution_m).astype(np.int64)
        rel = idx - self.index_lo
        inside = np.all((rel >= 0) & (rel < np.array(self.shape)), axis=1)
        v = np.full(len(rel), np.nan)
        w = np.zeros(len(rel))
        r = rel[inside]
        v[inside] = self.V[r[:, 0], r[:, 1], r[:, 2]]
        w[inside] = self.W[r[:, 0], r[:, 1], r[:, 2]]
        return v, w


# ----------------------------------------------------------------- simulated depth cameras (tests, benches)
def depth_scan(scene, camera: PinholeCamera, pose: np.ndarray, max_range_m: float = 5.0,
               noise_m: float = 0.0, rng: np.random.Generator | None = None,
               exclude_groups: Sequence[str] = ()) -> np.ndarray:
    """Points (N, 3) in the optical frame that a depth camera at ``pose`` (world-from-optical)
    measures in ``scene`` (``Scene.raycast``); rays without a hit give no point. Optional
    Gaussian range noise ``noise_m`` (standard deviation along the ray)."""
    d_cam = camera.ray_directions()
    unit = d_cam / np.linalg.norm(d_cam, axis=1, keepdims=True)
    R, t = pose[:3, :3], pose[:3, 3]
    dist = scene.raycast(t, unit @ R.T, max_range=max_range_m, exclude_groups=tuple(exclude_groups))
    ok = np.isfinite(dist)
    r = dist[ok]
    if noise_m > 0.0:
        r = r + (rng or np.random.default_rng(0)).normal(0.0, noise_m, r.shape)
    return unit[ok] * r[:, None]


__all__ = ["FusionParams", "IntegrationStats", "VoxelMap", "ray_voxels", "PinholeCamera", "look_at", "depth_scan",
           "MAX_VOXELS"]
