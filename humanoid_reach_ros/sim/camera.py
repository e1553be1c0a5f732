"""Simulated head sensors: pinhole camera, ray-cast rendering, depth point cloud, stereo pair.

The robot's head camera of the component pipeline (dissertation 004, Sec. 3.6: camera
capture -> marker localizer) and the depth / stereo sensor whose clouds become the
measured voxel map of Kanehiro et al. (Sec. II). Everything is ray cast against the
scene primitives with :meth:`humanoid_reach_ros.sim.scene.Scene.raycast` (numba), one ray
per pixel; the same ray cast serves the image and the depth cloud.

Conventions (OpenCV / REP 103 optical frame): the camera frame C has z forward along the
optical axis, x right and y down in the image; pixel ``(u, v)`` = (column, row) has its
centre at integer coordinates, so a point ``p_C`` projects to
``u = fx x / z + cx``, ``v = fy y / z + cy`` (no distortion). ``T_wc`` is the 4x4 pose of
the camera in the world frame (``world_T_camera``).

* :class:`PinholeCamera`: intrinsics ``K``, projection, pixel rays.
* :func:`cast`: ray cast of every pixel (:class:`RayHits`: range along each unit ray,
  primitive index, world points), in image tiles each cast only against the primitives
  whose projected bounding box overlaps the tile (exact; about twice as fast as casting
  every ray against every primitive), optionally on several threads.
* :func:`render_image`: shaded colour image. Lambertian shading under a head light
  (``I = albedo (ambient + (1 - ambient) |n . d|)``, analytic surface normals per
  primitive), an optional procedural texture in world coordinates (a sum of random plane
  waves, so that stereo matching has something to match), and the ArUco marker printed on
  the target at its configured pose (``scene.target.marker_pose``: the inverse of M_T_O)
  on a white label one cell wider than the marker. Marker pixels are anti-aliased by
  ``supersample x supersample`` sub-pixel rays intersected with the marker plane.
* :func:`depth_points`: the depth sensor's cloud in the optical frame, with Gaussian range
  noise ``sigma(r) = k r^2`` (the quadratic growth of structured-light / stereo depth
  error) and random dropouts, range-gated to ``[min_range_m, max_range_m]``.
* :func:`stereo_poses`: left = the head camera, right = shifted by the baseline along +x_C.

Simplifications (named): the robot's own body is not rendered (it never occludes the
scene); no lens distortion, no motion blur, no sensor noise in the image; the depth
sensor shares the colour camera's optical centre and intrinsics (a registered RGB-D
sensor); a pixel sees only the surface hit by its centre ray except on the marker label.

This module never imports rclpy.
"""
from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Iterable, Sequence

import cv2
import numba as nb
import numpy as np

from humanoid_reach_ros.geometry.camera import PinholeCamera, look_at
from humanoid_reach_ros.sim.scene import Box, Cylinder, Plane, Primitive, Scene, Sphere, Torus

ENCODINGS = ("rgb8", "mono8")


# ----------------------------------------------------------------- ray casting
@dataclass(frozen=True)
class RayHits:
    """One ray per pixel from a camera pose: ``range_m`` (H*W,) along the unit rays
    (inf: no hit), ``primitive`` (H*W,) index into ``scene.primitives`` (-1: none)."""

    camera: PinholeCamera
    T_wc: np.ndarray
    directions_c: np.ndarray
    range_m: np.ndarray
    primitive: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        return self.primitive >= 0

    def points_world(self) -> np.ndarray:
        """World points (H*W, 3) of the hits (rows of misses are inf/NaN)."""
        d_w = self.directions_c @ self.T_wc[:3, :3].T
        with np.errstate(invalid="ignore"):
            return self.T_wc[:3, 3] + self.range_m[:, None] * d_w


def cast(scene: Scene, camera: PinholeCamera, T_wc: np.ndarray, max_range_m: float = np.inf,
         tile_px: int = 80, threads: int = 1) -> RayHits:
    """Ray cast every pixel of ``camera`` at pose ``T_wc`` against ``scene``'s primitives.

    Tile culling: the image is cut into ``tile_px`` squares and each tile's rays are cast
    only against the primitives whose bounding box projects onto the tile (the convex hull
    of the projected box corners contains the box's image when every corner is in front of
    the camera; otherwise, and for unbounded primitives, the primitive is kept). The result
    equals casting every ray against every primitive (tested). With ``threads > 1`` the
    tiles are cast on that many threads (the numba kernel releases the GIL)."""
    T = np.asarray(T_wc, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError("camera pose must be a finite 4x4 transform")
    d_c = camera.rays()
    d_w = np.empty_like(d_c)
    _rotate_unit(d_c, np.ascontiguousarray(T[:3, :3]), d_w)
    boxes = _projected_bounds(scene, camera, T)
    W, H = camera.width, camera.height
    rng = np.empty(W * H)
    idx = np.empty(W * H, dtype=np.int64)
    pix = np.arange(W * H).reshape(H, W)
    def one_tile(corner: tuple[int, int]) -> None:
        u0, v0 = corner
        u1, v1 = min(u0 + tile_px, W) - 1, min(v0 + tile_px, H) - 1
        enabled = (boxes[:, 0] <= u1) & (boxes[:, 2] >= u0) & (boxes[:, 1] <= v1) & (boxes[:, 3] >= v0)
        p = pix[v0:v1 + 1, u0:u1 + 1].ravel()
        rng[p], idx[p] = scene.raycast_subset(T[:3, 3], d_w[p], enabled, max_range_m)

    tiles = [(u0, v0) for v0 in range(0, H, tile_px) for u0 in range(0, W, tile_px)]
    if threads > 1:
        list(_pool(threads).map(one_tile, tiles))
    else:
        for t in tiles:
            one_tile(t)
    return RayHits(camera, T, d_c, rng, idx)


@nb.njit(cache=True, nogil=True)
def _rotate_unit(D, R, out):
    """``out = R d / |R d|`` per row (normalised as Scene.raycast normalises its rays; numpy's
    matrix product of a (N, 3) array is much slower for this shape)."""
    for n in range(D.shape[0]):
        x = R[0, 0] * D[n, 0] + R[0, 1] * D[n, 1] + R[0, 2] * D[n, 2]
        y = R[1, 0] * D[n, 0] + R[1, 1] * D[n, 1] + R[1, 2] * D[n, 2]
        z = R[2, 0] * D[n, 0] + R[2, 1] * D[n, 1] + R[2, 2] * D[n, 2]
        r = math.sqrt(x * x + y * y + z * z)
        out[n, 0], out[n, 1], out[n, 2] = x / r, y / r, z / r


_POOLS: dict[int, ThreadPoolExecutor] = {}


def _pool(threads: int) -> ThreadPoolExecutor:
    if threads not in _POOLS:
        _POOLS[threads] = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="raycast")
    return _POOLS[threads]


def _projected_bounds(scene: Scene, camera: PinholeCamera, T_wc: np.ndarray) -> np.ndarray:
    """Per primitive the pixel box (umin, vmin, umax, vmax) (P, 4) that contains its image
    (infinite for unbounded primitives and boxes reaching behind the camera)."""
    T_cw = np.linalg.inv(T_wc)
    out = np.tile([-np.inf, -np.inf, np.inf, np.inf], (len(scene.primitives), 1))
    signs = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=bool)
    for i, prim in enumerate(scene.primitives):
        lo, hi = prim.bounds()
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            continue
        corners = np.where(signs, hi, lo) @ T_cw[:3, :3].T + T_cw[:3, 3]
        if np.any(corners[:, 2] <= 1e-6):
            continue
        uv, _ = camera.project(corners)
        out[i] = (uv[:, 0].min() - 1.0, uv[:, 1].min() - 1.0, uv[:, 0].max() + 1.0, uv[:, 1].max() + 1.0)
    return out


def without_primitives(scene: Scene, names: Iterable[str]) -> Scene:
    """The scene without the named primitives (``KeyError`` naming an unknown one)."""
    drop = set(names)
    unknown = sorted(drop - {p.name for p in scene.primitives})
    if unknown:
        raise KeyError(f"scene {scene.name!r} has no primitive(s) {unknown}; known: "
                       f"{[p.name for p in scene.primitives]}")
    return Scene(name=scene.name, primitives=tuple(p for p in scene.primitives if p.name not in drop),
                 target=scene.target, frame_id=scene.frame_id, resolution_m=scene.resolution_m, extent=scene.extent)


# ----------------------------------------------------------------- surface normals
def surface_normals(prim: Primitive, p: np.ndarray) -> np.ndarray:
    """Analytic outward unit normals (N, 3) of ``prim`` at surface points ``p`` (N, 3)
    (the shading kernel's normals: plane normal; radial for spheres and tori; the face of
    the largest relative local coordinate for boxes; side or cap, whichever is nearer, for
    cylinders)."""
    kinds, rows, _ = _shading_table([prim])
    pts = np.ascontiguousarray(np.asarray(p, dtype=float).reshape(-1, 3))
    out = np.empty_like(pts)
    _normals_kernel(int(kinds[0]), rows[0], pts, out)
    return out


# ----------------------------------------------------------------- marker print
@dataclass(frozen=True)
class MarkerPrint:
    """An ArUco marker printed on a surface: world pose of the marker frame (OpenCV
    convention: origin at the centre, z out of the printed face, x right, y up), black
    square edge ``size_m``, cells (``n x n`` incl. the black border; 1 = white) and a white
    label ``margin_cells`` wide around it."""

    T_wm: np.ndarray
    size_m: float
    cells: np.ndarray
    margin_cells: int = 1

    @property
    def label_half_m(self) -> float:
        n = self.cells.shape[0]
        return 0.5 * self.size_m * (n + 2 * self.margin_cells) / n

    def albedo(self, xy_m: np.ndarray) -> np.ndarray:
        """Reflectance (N,) at marker-plane coordinates (N, 2): 0.05 black cells, 0.92 white
        (cells and label), NaN outside the label."""
        n = self.cells.shape[0]
        x, y = xy_m[:, 0], xy_m[:, 1]
        col = np.floor((x / self.size_m + 0.5) * n).astype(np.int64)
        row = np.floor((0.5 - y / self.size_m) * n).astype(np.int64)
        inside = (col >= 0) & (col < n) & (row >= 0) & (row < n)
        out = np.full(len(x), 0.92)
        out[inside] = np.where(self.cells[row[inside], col[inside]] > 0, 0.92, 0.05)
        h = self.label_half_m
        out[(np.abs(x) > h) | (np.abs(y) > h)] = np.nan
        return out


def aruco_cells(dictionary: str, marker_id: int) -> np.ndarray:
    """``n x n`` 0/1 cells (incl. the 1-cell black border) of an OpenCV ArUco marker."""
    if not hasattr(cv2.aruco, dictionary):
        raise ValueError(f"unknown ArUco dictionary {dictionary!r}")
    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    n = d.markerSize + 2
    if not 0 <= marker_id < d.bytesList.shape[0]:
        raise ValueError(f"marker id {marker_id} is not in {dictionary} (0..{d.bytesList.shape[0] - 1})")
    img = cv2.aruco.generateImageMarker(d, int(marker_id), n, borderBits=1)
    return (img > 127).astype(np.uint8)


def marker_print_from_scene(scene: Scene) -> MarkerPrint | None:
    """The scene target's ArUco marker (None without one)."""
    t = scene.target
    if t is None or t.aruco is None:
        return None
    return MarkerPrint(t.marker_pose, t.aruco.size_m, aruco_cells(t.aruco.dictionary, t.aruco.marker_id))


# ----------------------------------------------------------------- rendering
@dataclass(frozen=True)
class RenderStyle:
    """Shading: ``ambient`` fraction, procedural texture amplitude (0: none) and
    wavelengths [m], sky colour of rays that hit nothing, marker anti-aliasing."""

    ambient: float = 0.3
    texture_amplitude: float = 0.0
    texture_wavelengths_m: tuple[float, float] = (0.01, 0.05)
    texture_waves: int = 8
    texture_seed: int = 7
    background: tuple[float, float, float] = (0.75, 0.8, 0.9)
    supersample: int = 4
    _waves: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not 0.0 <= self.ambient <= 1.0 or not 0.0 <= self.texture_amplitude <= 1.0:
            raise ValueError("ambient and texture_amplitude must be in [0, 1]")
        lo, hi = self.texture_wavelengths_m
        if not 0.0 < lo <= hi or self.texture_waves < 1 or self.supersample < 1:
            raise ValueError("texture wavelengths must be 0 < lo <= hi; waves and supersample >= 1")
        rng = np.random.default_rng(self.texture_seed)
        k = rng.normal(size=(self.texture_waves, 3))
        k *= (2.0 * math.pi / rng.uniform(lo, hi, self.texture_waves) / np.linalg.norm(k, axis=1))[:, None]
        waves = np.concatenate([k, rng.uniform(0.0, 2.0 * math.pi, (self.texture_waves, 1))], axis=1)
        object.__setattr__(self, "_waves", waves)

    def texture(self, p_w: np.ndarray) -> np.ndarray:
        """Multiplicative albedo factor (N,) ``1 + a mean_k sin(k_k . p + phi_k)`` at world points."""
        if self.texture_amplitude == 0.0:
            return np.ones(len(p_w))
        w = self._waves
        s = np.sin(p_w @ w[:, :3].T + w[:, 3]).mean(axis=1)
        return 1.0 + self.texture_amplitude * math.sqrt(2.0) * s


def _shading_table(primitives: Sequence[Primitive]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Kind codes (P,), parameter rows (P, 17) and colours (P, 3) of primitives for
    :func:`_shade_kernel` (rows: 0:3 point, 3:6 vector, 6, 7 scalars, 8:17 rotation)."""
    kinds = np.zeros(len(primitives), np.int64)
    rows = np.zeros((len(primitives), 17))
    for i, prim in enumerate(primitives):
        r = rows[i]
        if isinstance(prim, Plane):
            kinds[i], r[3:6] = _K_PLANE, prim.normal
        elif isinstance(prim, Box):
            kinds[i], r[0:3], r[3:6], r[8:17] = _K_BOX, prim.center, 0.5 * np.asarray(prim.size), prim.rotation.ravel()
        elif isinstance(prim, Cylinder):
            a, b = np.asarray(prim.p0), np.asarray(prim.p1)
            length = float(np.linalg.norm(b - a))
            kinds[i], r[0:3], r[3:6], r[6], r[7] = (_K_CYLINDER, 0.5 * (a + b), (b - a) / length,
                                                    0.5 * length, prim.radius)
        elif isinstance(prim, Sphere):
            kinds[i], r[0:3] = _K_SPHERE, prim.center
        elif isinstance(prim, Torus):
            kinds[i], r[0:3], r[3:6], r[6] = _K_TORUS, prim.center, prim.axis, prim.major_radius
        else:  # pragma: no cover - every scene primitive type is handled above
            raise TypeError(f"cannot shade {type(prim).__name__}")
    colors = np.array([p.color for p in primitives], dtype=np.float64).reshape(-1, 3)
    return kinds, rows, colors


_K_PLANE, _K_BOX, _K_CYLINDER, _K_SPHERE, _K_TORUS = range(5)


@nb.njit(cache=True, nogil=True)
def _normal(kind, r, px, py, pz):
    """Outward unit normal of one primitive at a surface point."""
    if kind == _K_PLANE:
        return r[3], r[4], r[5]
    wx, wy, wz = px - r[0], py - r[1], pz - r[2]
    if kind == _K_BOX:
        best, ax, sg = -1.0, 0, 1.0
        for a in range(3):
            q = wx * r[8 + a] + wy * r[11 + a] + wz * r[14 + a]
            ratio = abs(q) / r[3 + a]
            if ratio > best:
                best, ax, sg = ratio, a, (1.0 if q >= 0.0 else -1.0)
        return sg * r[8 + ax], sg * r[11 + ax], sg * r[14 + ax]
    if kind == _K_CYLINDER:
        h = wx * r[3] + wy * r[4] + wz * r[5]
        nx, ny, nz = wx - h * r[3], wy - h * r[4], wz - h * r[5]
        rho = math.sqrt(nx * nx + ny * ny + nz * nz)
        if abs(abs(h) - r[6]) < abs(rho - r[7]):
            sg = 1.0 if h >= 0.0 else -1.0
            return sg * r[3], sg * r[4], sg * r[5]
    elif kind == _K_SPHERE:
        nx, ny, nz = wx, wy, wz
    else:  # torus: away from the nearest point of the ring
        h = wx * r[3] + wy * r[4] + wz * r[5]
        ux, uy, uz = wx - h * r[3], wy - h * r[4], wz - h * r[5]
        rho = max(math.sqrt(ux * ux + uy * uy + uz * uz), 1e-12)
        nx, ny, nz = wx - r[6] * ux / rho, wy - r[6] * uy / rho, wz - r[6] * uz / rho
    n = math.sqrt(nx * nx + ny * ny + nz * nz)
    if n == 0.0:
        return 0.0, 0.0, 1.0
    return nx / n, ny / n, nz / n


@nb.njit(cache=True, nogil=True)
def _normals_kernel(kind, row, P, out):
    for n in range(P.shape[0]):
        out[n, 0], out[n, 1], out[n, 2] = _normal(kind, row, P[n, 0], P[n, 1], P[n, 2])


@nb.njit(cache=True, nogil=True)
def _shade_kernel(T, D, rng, idx, kinds, rows, colors, waves, tex_amp, ambient, background, Tm, label_half, img,
                  label_shade, on_label):
    """Per pixel: world point, normal, Lambert head-light shading, procedural texture, written
    as 8-bit RGB into ``img``; pixels whose hit lies on the marker label (``|z_M| < 2 mm``,
    inside the label square) get their shading in ``label_shade`` instead (albedo from the
    marker pass)."""
    nw = waves.shape[0]
    for n in range(D.shape[0]):
        k = idx[n]
        on_label[n] = False
        if k < 0:
            for c in range(3):
                img[n, c] = min(255, int(background[c] * 255.0 + 0.5))
            continue
        dx = T[0, 0] * D[n, 0] + T[0, 1] * D[n, 1] + T[0, 2] * D[n, 2]
        dy = T[1, 0] * D[n, 0] + T[1, 1] * D[n, 1] + T[1, 2] * D[n, 2]
        dz = T[2, 0] * D[n, 0] + T[2, 1] * D[n, 1] + T[2, 2] * D[n, 2]
        t = rng[n]
        px, py, pz = T[0, 3] + t * dx, T[1, 3] + t * dy, T[2, 3] + t * dz
        nx, ny, nz = _normal(kinds[k], rows[k], px, py, pz)
        shade = ambient + (1.0 - ambient) * abs(nx * dx + ny * dy + nz * dz)
        if label_half > 0.0:
            qx, qy, qz = px - Tm[0, 3], py - Tm[1, 3], pz - Tm[2, 3]
            mz = qx * Tm[0, 2] + qy * Tm[1, 2] + qz * Tm[2, 2]
            if abs(mz) < 2e-3:
                mx = qx * Tm[0, 0] + qy * Tm[1, 0] + qz * Tm[2, 0]
                my = qx * Tm[0, 1] + qy * Tm[1, 1] + qz * Tm[2, 1]
                if abs(mx) <= label_half and abs(my) <= label_half:
                    on_label[n] = True
                    label_shade[n] = shade
                    continue
        if tex_amp > 0.0:
            s = 0.0
            for w in range(nw):
                s += math.sin(waves[w, 0] * px + waves[w, 1] * py + waves[w, 2] * pz + waves[w, 3])
            shade *= 1.0 + tex_amp * math.sqrt(2.0) * s / nw
        for c in range(3):
            img[n, c] = max(0, min(255, int(colors[k, c] * shade * 255.0 + 0.5)))


@nb.njit(cache=True, nogil=True)
def _marker_kernel(pixels, width, fx, fy, cx, cy, T, Tm, size, cells, label_half, s, out):
    """Mean label albedo over ``s x s`` sub-pixel rays of each pixel, intersected with the
    marker plane; sub-rays off the label are left out of the mean (NaN if all are)."""
    n_cells = cells.shape[0]
    ox, oy, oz = T[0, 3] - Tm[0, 3], T[1, 3] - Tm[1, 3], T[2, 3] - Tm[2, 3]
    for i in range(pixels.shape[0]):
        u0 = pixels[i] % width
        v0 = pixels[i] // width
        acc, cnt = 0.0, 0
        for a in range(s):
            for b in range(s):
                xc = (u0 + (b + 0.5) / s - 0.5 - cx) / fx
                yc = (v0 + (a + 0.5) / s - 0.5 - cy) / fy
                dx = T[0, 0] * xc + T[0, 1] * yc + T[0, 2]
                dy = T[1, 0] * xc + T[1, 1] * yc + T[1, 2]
                dz = T[2, 0] * xc + T[2, 1] * yc + T[2, 2]
                dn = dx * Tm[0, 2] + dy * Tm[1, 2] + dz * Tm[2, 2]
                if dn == 0.0:
                    continue
                t = -(ox * Tm[0, 2] + oy * Tm[1, 2] + oz * Tm[2, 2]) / dn
                qx, qy, qz = ox + t * dx, oy + t * dy, oz + t * dz
                mx = qx * Tm[0, 0] + qy * Tm[1, 0] + qz * Tm[2, 0]
                my = qx * Tm[0, 1] + qy * Tm[1, 1] + qz * Tm[2, 1]
                if abs(mx) > label_half or abs(my) > label_half:
                    continue
                col = int(math.floor((mx / size + 0.5) * n_cells))
                row = int(math.floor((0.5 - my / size) * n_cells))
                white = True
                if 0 <= col < n_cells and 0 <= row < n_cells:
                    white = cells[row, col] > 0
                acc += _WHITE if white else _BLACK
                cnt += 1
        out[i] = acc / cnt if cnt > 0 else np.nan


_WHITE, _BLACK = 0.92, 0.05


def render_image(scene: Scene, hits: RayHits, marker: MarkerPrint | None = None,
                 style: RenderStyle = RenderStyle(), encoding: str = "rgb8") -> np.ndarray:
    """Shaded image (H, W, 3) uint8 for rgb8 or (H, W) for mono8 from one :func:`cast`
    (numba kernels: shading of every pixel, then the supersampled marker label pixels)."""
    if encoding not in ENCODINGS:
        raise ValueError(f"unsupported encoding {encoding!r}; use one of {ENCODINGS}")
    cam = hits.camera
    kinds, rows, colors = _shading_table(scene.primitives)
    n_pix = cam.width * cam.height
    img = np.empty((n_pix, 3), dtype=np.uint8)
    label_shade = np.empty(n_pix)
    on_label = np.empty(n_pix, np.bool_)
    Tm = np.eye(4) if marker is None else np.ascontiguousarray(marker.T_wm, dtype=float)
    half = 0.0 if marker is None else marker.label_half_m
    _shade_kernel(np.ascontiguousarray(hits.T_wc), np.ascontiguousarray(hits.directions_c), hits.range_m,
                  hits.primitive, kinds, rows, colors, style._waves, float(style.texture_amplitude),
                  float(style.ambient), np.asarray(style.background, float), Tm, half, img, label_shade, on_label)
    if marker is not None:
        pix = np.flatnonzero(on_label)
        if len(pix):
            a = np.empty(len(pix))
            _marker_kernel(pix, cam.width, cam.fx, cam.fy, cam.cx, cam.cy, np.ascontiguousarray(hits.T_wc), Tm,
                           float(marker.size_m), np.ascontiguousarray(marker.cells, dtype=np.uint8), half,
                           int(style.supersample), a)
            a = np.where(np.isfinite(a), a, _WHITE)     # no sub-ray on the label: white
            img[pix] = np.clip(label_shade[pix] * a * 255.0 + 0.5, 0, 255).astype(np.uint8)[:, None]
    img = img.reshape(cam.height, cam.width, 3)
    if encoding == "mono8":
        return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    return img


# ----------------------------------------------------------------- depth sensor
@dataclass(frozen=True)
class DepthNoise:
    """Range noise ``sigma = range_noise_per_m * r^2`` [m] along the ray, dropout
    probability per point, valid range [m] and pixel stride (every ``stride``-th row and column)."""

    range_noise_per_m: float = 0.0025
    dropout_probability: float = 0.02
    min_range_m: float = 0.1
    max_range_m: float = 5.0
    stride: int = 2

    def __post_init__(self) -> None:
        if self.range_noise_per_m < 0.0 or not 0.0 <= self.dropout_probability <= 1.0:
            raise ValueError("range_noise_per_m must be >= 0 and dropout_probability in [0, 1]")
        if not 0.0 <= self.min_range_m < self.max_range_m or self.stride < 1:
            raise ValueError("need 0 <= min_range_m < max_range_m and stride >= 1")


def depth_points(hits: RayHits, noise: DepthNoise, rng: np.random.Generator) -> np.ndarray:
    """The depth sensor's points (N, 3) in the optical frame: every ``stride``-th pixel's
    hit within the range gate, the range perturbed by ``N(0, (k r^2)^2)``, dropouts removed."""
    cam = hits.camera
    grid = np.arange(cam.width * cam.height).reshape(cam.height, cam.width)[::noise.stride, ::noise.stride].ravel()
    r = hits.range_m[grid]
    keep = np.isfinite(r) & (r >= noise.min_range_m) & (r <= noise.max_range_m)
    if noise.dropout_probability > 0.0:
        keep &= rng.random(len(r)) >= noise.dropout_probability
    r, d = r[keep], hits.directions_c[grid[keep]]
    if noise.range_noise_per_m > 0.0:
        r = r + rng.normal(size=len(r)) * noise.range_noise_per_m * r * r
    return d * r[:, None]


# ----------------------------------------------------------------- stereo pair
def stereo_poses(T_wc: np.ndarray, baseline_m: float) -> tuple[np.ndarray, np.ndarray]:
    """World poses of the left (= ``T_wc``) and right (``baseline_m`` along +x_C) cameras
    of a rectified pair (parallel optical axes, same intrinsics)."""
    if not (math.isfinite(baseline_m) and baseline_m > 0.0):
        raise ValueError(f"stereo baseline must be > 0, got {baseline_m}")
    right = np.array(T_wc, dtype=float)
    right[:3, 3] = right[:3, 3] + baseline_m * right[:3, 0]
    return np.array(T_wc, dtype=float), right


__all__ = [
    "ENCODINGS", "PinholeCamera", "RayHits", "cast", "without_primitives", "surface_normals", "MarkerPrint",
    "aruco_cells", "marker_print_from_scene", "RenderStyle", "render_image", "DepthNoise", "depth_points",
    "stereo_poses", "look_at",
]
