"""Stereo depth: rectification, semi-global matching and the left-right consistency check of 003.

Das (003, "Stereo Camera", "Image Rectification", "Online state monitoring") obtains depth
from a rectified stereo pair and rejects unreliable matches with a consistency check:
a region A of the left image is matched in the right image (B), B is matched back in
the left image (C), and the match is kept only when C is A. Here:

1. **Rectification** (:class:`StereoCalibration`): from two ROS camera_infos (K, D, R, P;
   the right P carries ``Tx = -fx B``) or from the pair's extrinsics by
   ``cv2.stereoRectify``; when the images are not already rectified (distortion, or a
   rectifying rotation other than identity) they are remapped with
   ``cv2.initUndistortRectifyMap`` / ``cv2.remap``.
2. **Matching**: OpenCV's semi-global block matching ``cv2.StereoSGBM`` (Hirschmueller)
   gives the left disparity ``d_L(u, v)`` (A -> B).
3. **Left-right consistency** (A -> B -> C): the right image's disparity ``d_R`` is
   computed by the same matcher on the horizontally flipped pair (the right image becomes
   the reference; ``cv2.ximgproc`` is not part of opencv-python-headless), and a left pixel
   is kept only when ``|d_L(u, v) - d_R(u - d_L(u, v), v)| <= lr_max_diff_px`` (default
   1 px): pixels occluded in the right image, whose match B does not match back, are
   rejected.
4. **Sub-pixel refinement** (``subpixel``, default on): SGBM's own sub-pixel interpolation
   on Birchfield-Tomasi costs locks onto integer disparities (measured: 0.22 px, a
   5.6 mm bias at 1 m), so each kept disparity is re-estimated around its rounded value
   ``d0`` by the vertex of the parabola through the block sums of squared differences
   ``C(d0 - 1), C(d0), C(d0 + 1)`` (block ``block_size``), kept only where ``C(d0)`` is
   the minimum of the three (else the pixel is dropped).
5. **Reprojection**: ``Z = f B / d``, ``X = (u - c_x) Z / f``, ``Y = (v - c_y) Z / f`` in the
   rectified left frame, rotated back into the left camera's optical frame (``R_1^T``);
   depths outside ``[min_depth_m, max_depth_m]`` are dropped.

The resulting cloud is fused into the voxel map like a depth sensor's
(:mod:`humanoid_reach_ros.perception.voxel_map`). Depth resolution falls with distance,
``dZ = Z^2 / (f B) dd`` (003: "the stereo method has a reciprocal relationship with
distance and resolution"). :func:`render_textured_pair` renders a rectified pair of textured
planes for tests and benches (ground truth depth and occlusion known).

This module never imports rclpy.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from humanoid_reach_ros.geometry.camera import CameraCalibration

#: StereoSGBM disparities are fixed point with 4 fractional bits
_DISP_SCALE = 16.0


@dataclass(frozen=True)
class StereoParams:
    """Matcher settings: ``num_disparities`` (multiple of 16), ``block_size`` (odd) and
    ``uniqueness_ratio`` [%] of StereoSGBM (3-way mode), the consistency threshold
    ``lr_max_diff_px`` and the kept depth range [m]. The high uniqueness ratio rejects the
    ambiguous matches of repetitive texture (bench/voxel_map.py: on scene_sim's rendered
    plant, stereo voxels within one voxel of the depth map rise from 0.72 at 10 to 0.89
    at 25 with block 7, coverage unchanged)."""

    num_disparities: int = 64
    block_size: int = 7
    lr_max_diff_px: float = 1.0
    min_depth_m: float = 0.2
    max_depth_m: float = 4.0
    uniqueness_ratio: int = 25
    speckle_window_size: int = 100
    speckle_range: int = 2
    subpixel: bool = True

    def validate(self) -> None:
        if self.num_disparities <= 0 or self.num_disparities % 16:
            raise ValueError(f"num_disparities must be a positive multiple of 16, got {self.num_disparities}")
        if self.block_size < 1 or self.block_size % 2 == 0 or self.block_size > 31:
            raise ValueError(f"block_size must be odd in [1, 31], got {self.block_size}")
        if not (math.isfinite(self.lr_max_diff_px) and self.lr_max_diff_px >= 0.0):
            raise ValueError(f"lr_max_diff_px must be >= 0, got {self.lr_max_diff_px}")
        if not 0 <= self.uniqueness_ratio <= 100:
            raise ValueError(f"uniqueness_ratio must be in [0, 100] %, got {self.uniqueness_ratio}")
        if not 0.0 <= self.min_depth_m < self.max_depth_m:
            raise ValueError(f"need 0 <= min_depth_m < max_depth_m, got {self.min_depth_m}, {self.max_depth_m}")


@dataclass(frozen=True, eq=False)
class StereoCalibration:
    """A stereo pair: per camera intrinsics ``K``, distortion ``D``, rectifying rotation ``R``
    and rectified projection ``P`` (ROS camera_info semantics), image ``size`` (w, h).

    The baseline is ``B = -P_right[0, 3] / P_right[0, 0]`` > 0 (right camera along +x)."""

    K1: np.ndarray
    D1: np.ndarray
    R1: np.ndarray
    P1: np.ndarray
    K2: np.ndarray
    D2: np.ndarray
    R2: np.ndarray
    P2: np.ndarray
    size: tuple[int, int]

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, StereoCalibration):
            return NotImplemented
        return self.size == other.size and all(
            np.array_equal(getattr(self, k), getattr(other, k))
            for k in ("K1", "D1", "R1", "P1", "K2", "D2", "R2", "P2"))

    @property
    def baseline_m(self) -> float:
        return float(-self.P2[0, 3] / self.P2[0, 0])

    @property
    def focal_px(self) -> float:
        return float(self.P1[0, 0])

    @property
    def needs_rectification(self) -> bool:
        return bool(np.any(self.D1 != 0.0) or np.any(self.D2 != 0.0) or not np.allclose(self.R1, np.eye(3))
                    or not np.allclose(self.R2, np.eye(3)) or not np.allclose(self.P1[:, :3], self.K1)
                    or not np.allclose(self.P2[:, :3], self.K2))

    @staticmethod
    def from_camera_infos(left: CameraCalibration, right: CameraCalibration) -> "StereoCalibration":
        """From the two cameras' calibrations (each validated already: size, finite values,
        focal lengths); ``ValueError`` for a pair that is not a rectified stereo pair."""
        for side, info in (("left", left), ("right", right)):
            if not info.P[0, 0] > 0.0:
                raise ValueError(f"{side} camera_info has no focal length in P (P all zero?)")
        if left.size != right.size:
            raise ValueError(f"left and right image sizes differ: {left.size} vs {right.size}")
        cal = StereoCalibration(left.K, left.D, left.R, left.P, right.K, right.D, right.R, right.P, left.size)
        if not cal.baseline_m > 0.0:
            raise ValueError(f"right camera_info P[0, 3] = {cal.P2[0, 3]} gives baseline {cal.baseline_m} m: "
                             "expected Tx = -fx B < 0 (right camera along +x of the left)")
        if not np.allclose(cal.P1[:, :3], cal.P2[:, :3]):
            raise ValueError("left and right rectified projections P differ in their 3x3 part: not a rectified pair")
        return cal

    @staticmethod
    def from_extrinsics(K1: np.ndarray, D1: np.ndarray, K2: np.ndarray, D2: np.ndarray, R: np.ndarray,
                        T: np.ndarray, size: tuple[int, int]) -> "StereoCalibration":
        """Rectification of a calibrated pair by ``cv2.stereoRectify`` (``R``, ``T``: the right
        camera's pose as OpenCV's stereoCalibrate gives it: x_right = R x_left + T)."""
        R1, R2, P1, P2, _Q, _r1, _r2 = cv2.stereoRectify(np.asarray(K1, float), np.asarray(D1, float),
                                                          np.asarray(K2, float), np.asarray(D2, float),
                                                          tuple(size), np.asarray(R, float),
                                                          np.asarray(T, float).reshape(3, 1),
                                                          flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
        return StereoCalibration(np.asarray(K1, float), np.asarray(D1, float).ravel(), R1, P1,
                                 np.asarray(K2, float), np.asarray(D2, float).ravel(), R2, P2, tuple(size))


class StereoMatcher:
    """Rectify, match (SGBM), check left-right consistency, reproject (module docstring)."""

    def __init__(self, calibration: StereoCalibration, params: StereoParams | None = None) -> None:
        self.params = params or StereoParams()
        self.params.validate()
        self.calibration = c = calibration
        p = self.params
        self._sgbm = cv2.StereoSGBM_create(
            minDisparity=0, numDisparities=p.num_disparities, blockSize=p.block_size,
            P1=8 * p.block_size ** 2, P2=32 * p.block_size ** 2, disp12MaxDiff=-1,
            uniquenessRatio=p.uniqueness_ratio, speckleWindowSize=p.speckle_window_size,
            speckleRange=p.speckle_range, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
        self._maps = None
        if c.needs_rectification:
            self._maps = tuple(cv2.initUndistortRectifyMap(K, D, R, P[:, :3], c.size, cv2.CV_32FC1)
                               for K, D, R, P in ((c.K1, c.D1, c.R1, c.P1), (c.K2, c.D2, c.R2, c.P2)))

    def rectify(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        w, h = self.calibration.size
        for name, img in (("left", left), ("right", right)):
            if img.ndim != 2 or img.shape != (h, w) or img.dtype != np.uint8:
                raise ValueError(f"{name} image must be 8-bit grey {w}x{h} (camera_info), got {img.shape} {img.dtype}")
        if self._maps is None:
            return left, right
        (m1x, m1y), (m2x, m2y) = self._maps
        return (cv2.remap(left, m1x, m1y, cv2.INTER_LINEAR), cv2.remap(right, m2x, m2y, cv2.INTER_LINEAR))

    def _match(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        d = self._sgbm.compute(a, b).astype(np.float32) / _DISP_SCALE
        d[d <= 0.0] = np.nan   # invalid (OpenCV marks them (minDisparity - 1) * 16) or at infinity
        return d

    def disparities(self, left: np.ndarray, right: np.ndarray, check: bool = True
                    ) -> tuple[np.ndarray, np.ndarray]:
        """Left disparity (H, W) [px, NaN = invalid] of a rectified pair after the left-right
        check (``check=False``: without it), and the right disparity ``d_R`` (H, W)."""
        d_left = self._match(left, right)
        # right reference: match the flipped pair, flip back (d_R(u') pairs u' with u' + d_R)
        d_right = self._match(np.ascontiguousarray(right[:, ::-1]), np.ascontiguousarray(left[:, ::-1]))[:, ::-1]
        if check:
            d_left = left_right_check(d_left, d_right, self.params.lr_max_diff_px)
        if self.params.subpixel:
            d_left = refine_subpixel(d_left, left, right, self.params.block_size)
        return d_left, d_right

    def depth(self, left: np.ndarray, right: np.ndarray, check: bool = True) -> np.ndarray:
        """Depth Z (H, W) [m] in the rectified left frame (NaN = no valid match)."""
        rl, rr = self.rectify(left, right)
        d, _ = self.disparities(rl, rr, check)
        c = self.calibration
        return c.focal_px * c.baseline_m / d

    def points(self, left: np.ndarray, right: np.ndarray, check: bool = True) -> np.ndarray:
        """Points (N, 3) [m] in the left camera's optical frame from a grey image pair."""
        Z = self.depth(left, right, check)
        c, p = self.calibration, self.params
        P = c.P1
        v, u = np.nonzero(np.isfinite(Z) & (Z >= p.min_depth_m) & (Z <= p.max_depth_m))
        z = Z[v, u].astype(np.float64)
        rect = np.stack([(u - P[0, 2]) * z / P[0, 0], (v - P[1, 2]) * z / P[1, 1], z], axis=1)
        return rect @ c.R1   # rectified -> left camera: x_cam = R1^T x_rect (row vectors: x R1)


def left_right_check(d_left: np.ndarray, d_right: np.ndarray, max_diff_px: float = 1.0) -> np.ndarray:
    """003's consistency check: keep ``d_L(u, v)`` only when the right pixel it points to,
    ``u - d_L``, has a disparity ``d_R`` within ``max_diff_px`` of it (A -> B -> C = A)."""
    h, w = d_left.shape
    out = np.full_like(d_left, np.nan)
    v, u = np.nonzero(np.isfinite(d_left))
    d = d_left[v, u]
    ur = np.rint(u - d).astype(np.int64)
    inside = (ur >= 0) & (ur < w)
    v, u, d, ur = v[inside], u[inside], d[inside], ur[inside]
    back = d_right[v, ur]
    ok = np.isfinite(back) & (np.abs(back - d) <= max_diff_px)
    out[v[ok], u[ok]] = d[ok]
    return out


def refine_subpixel(d: np.ndarray, left: np.ndarray, right: np.ndarray, block: int) -> np.ndarray:
    """Parabola vertex of the block SSD ``C`` at ``d0 - 1, d0, d0 + 1`` (``d0`` = rounded ``d``)
    for every finite disparity; pixels where ``C(d0)`` is not the smallest of the three, or
    whose neighbours leave the image, become NaN."""
    out = np.full_like(d, np.nan)
    v, u = np.nonzero(np.isfinite(d))
    if len(u) == 0:
        return out
    h, w = left.shape
    L, R = left.astype(np.float32), right.astype(np.float32)
    d0 = np.rint(d[v, u]).astype(np.int64)
    c = np.full((3, len(u)), np.inf, dtype=np.float32)
    for shift in range(max(int(d0.min()) - 1, 0), int(d0.max()) + 2):
        sel = np.abs(d0 - shift) <= 1
        if not sel.any() or shift >= w:
            continue
        diff = np.full((h, w), 1e12, dtype=np.float32)   # no match left of the shift
        diff[:, shift:] = (L[:, shift:] - R[:, :w - shift]) ** 2
        C = cv2.boxFilter(diff, -1, (block, block), normalize=False, borderType=cv2.BORDER_REPLICATE)
        for k, off in enumerate((-1, 0, 1)):
            m = d0 + off == shift
            c[k, m] = C[v[m], u[m]]
    den = c[0] - 2.0 * c[1] + c[2]
    ok = np.isfinite(den) & (den > 0.0) & (c[1] <= c[0]) & (c[1] <= c[2]) & (c[0] < 1e11) & (c[2] < 1e11)
    out[v[ok], u[ok]] = d0[ok] + 0.5 * (c[0, ok] - c[2, ok]) / den[ok]
    return out


# ----------------------------------------------------------------- synthetic pairs (tests, benches)
def texture(x: np.ndarray, y: np.ndarray, seed: int = 0, wavelengths_m: tuple[float, float] = (0.006, 0.05)
            ) -> np.ndarray:
    """A band-limited random texture in [0, 255] on world coordinates (sum of 24 random
    plane waves with wavelengths in ``wavelengths_m``): no aliasing at the rendered scales."""
    rng = np.random.default_rng(seed)
    out = np.zeros(np.broadcast(x, y).shape)
    for _ in range(24):
        lam = rng.uniform(*wavelengths_m)
        a = rng.uniform(0.0, math.pi)
        out += np.sin(2.0 * math.pi * (x * math.cos(a) + y * math.sin(a)) / lam + rng.uniform(0.0, 2.0 * math.pi))
    return np.clip(127.5 + 127.5 * out / 6.0, 0.0, 255.0)


@dataclass(frozen=True)
class SyntheticPair:
    """A rendered rectified pair with ground truth: left depth (H, W) [m] and the mask of left
    pixels whose surface point is occluded in the right image."""

    left: np.ndarray
    right: np.ndarray
    depth: np.ndarray
    occluded: np.ndarray
    calibration: StereoCalibration


def render_textured_pair(width: int = 640, height: int = 480, focal_px: float = 554.0, baseline_m: float = 0.07,
                         plane_depth_m: float = 1.0, box: tuple[float, float, float, float, float] | None = None,
                         seed: int = 0) -> SyntheticPair:
    """Rectified pair of a fronto-parallel textured plane at ``plane_depth_m`` and an optional
    textured rectangle ``box = (x0, x1, y0, y1, z)`` [m, left optical frame] in front of it.
    Rays are intersected analytically (2x2 supersampled) and textured by :func:`texture`
    (different seeds for plane and rectangle); the right camera is at ``(B, 0, 0)``."""
    cx, cy = 0.5 * (width - 1), 0.5 * (height - 1)

    def render(cam_x: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        acc = np.zeros((height, width))
        for du in (-0.25, 0.25):
            for dv in (-0.25, 0.25):
                u, v = np.meshgrid(np.arange(width) + du, np.arange(height) + dv)
                rx, ry = (u - cx) / focal_px, (v - cy) / focal_px
                X, Y = cam_x + rx * plane_depth_m, ry * plane_depth_m
                img = texture(X, Y, seed)
                Z = np.full(u.shape, plane_depth_m)
                if box is not None:
                    x0, x1, y0, y1, zb = box
                    bx, by = cam_x + rx * zb, ry * zb
                    on = (bx >= x0) & (bx <= x1) & (by >= y0) & (by <= y1)
                    img = np.where(on, texture(bx, by, seed + 1), img)
                    Z = np.where(on, zb, Z)
                acc += img
        u, v = np.meshgrid(np.arange(width), np.arange(height))
        return np.clip(np.rint(acc / 4.0), 0, 255).astype(np.uint8), Z, u

    left, Z, u = render(0.0)
    right, _, _ = render(baseline_m)
    occluded = np.zeros_like(left, dtype=bool)
    if box is not None:   # left pixels on the background that the rectangle hides from the right camera
        x0, x1, y0, y1, zb = box
        X = (u - cx) / focal_px * Z
        Y = (np.arange(height)[:, None] - cy) / focal_px * Z
        # the ray from the right camera (B, 0, 0) to (X, Y, Z) at depth zb
        s = zb / Z
        bx = baseline_m + (X - baseline_m) * s
        by = Y * s
        occluded = (Z > zb) & (bx >= x0) & (bx <= x1) & (by >= y0) & (by <= y1)
    K = np.array([[focal_px, 0.0, cx], [0.0, focal_px, cy], [0.0, 0.0, 1.0]])
    P1 = np.hstack([K, np.zeros((3, 1))])
    P2 = P1.copy()
    P2[0, 3] = -focal_px * baseline_m
    cal = StereoCalibration(K, np.zeros(5), np.eye(3), P1, K.copy(), np.zeros(5), np.eye(3), P2, (width, height))
    return SyntheticPair(left, right, Z, occluded, cal)


__all__ = ["StereoParams", "StereoCalibration", "StereoMatcher", "left_right_check", "refine_subpixel",
           "texture",
           "SyntheticPair", "render_textured_pair"]
