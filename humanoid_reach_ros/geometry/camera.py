"""The pinhole camera model and the optical frame (z forward, x right, y down).

Intrinsics ``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``; a point ``p_C`` of the optical
frame projects to ``u = fx x / z + cx``, ``v = fy y / z + cy``. Shared by the simulated
sensors (``sim/camera.py``) and the simulated depth scans of ``perception/voxel_map.py``.

No rclpy here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PinholeCamera:
    """Pinhole intrinsics: image size [px], focal lengths and principal point [px]."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1:
            raise ValueError(f"image size must be positive, got {self.width} x {self.height}")
        if not all(math.isfinite(v) for v in (self.fx, self.fy, self.cx, self.cy)) or self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"focal lengths must be finite and > 0 (fx {self.fx}, fy {self.fy})")

    @classmethod
    def from_fov(cls, width: int, height: int, horizontal_fov_rad: float) -> "PinholeCamera":
        """Square pixels, principal point at the image centre ``((W - 1)/2, (H - 1)/2)``,
        ``fx = fy = (W / 2) / tan(hfov / 2)``."""
        if not 0.0 < horizontal_fov_rad < math.pi:
            raise ValueError(f"horizontal field of view must be in (0, pi) rad, got {horizontal_fov_rad}")
        f = 0.5 * width / math.tan(0.5 * horizontal_fov_rad)
        return cls(int(width), int(height), f, f, 0.5 * (width - 1), 0.5 * (height - 1))

    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def project(self, points_c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates (N, 2) and depths z (N,) of points (N, 3) in the optical frame
        (points behind the camera get NaN pixels)."""
        p = np.asarray(points_c, dtype=float).reshape(-1, 3)
        z = p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.stack([self.fx * p[:, 0] / z + self.cx, self.fy * p[:, 1] / z + self.cy], axis=1)
        uv[z <= 0.0] = np.nan
        return uv, z

    def pixel_directions(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Unit ray directions (N, 3) in the optical frame through pixel coordinates."""
        d = np.stack([(np.asarray(u, float) - self.cx) / self.fx, (np.asarray(v, float) - self.cy) / self.fy,
                      np.ones(np.shape(u))], axis=-1)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def rays(self) -> np.ndarray:
        """Unit ray directions (H * W, 3), row-major (pixel ``(u, v)`` at ``v * W + u``)."""
        return _rays_cached(self)

    def ray_directions(self) -> np.ndarray:
        """Unnormalised optical-frame directions (H*W, 3) with z = 1, row-major pixels."""
        u, v = np.meshgrid(np.arange(self.width, dtype=float), np.arange(self.height, dtype=float))
        return np.stack([(u - self.cx) / self.fx, (v - self.cy) / self.fy, np.ones_like(u)], -1).reshape(-1, 3)


_RAY_CACHE: dict[PinholeCamera, np.ndarray] = {}


#: the distortion vector lengths OpenCV takes (and camera_info's plumb_bob / rational_polynomial)
DISTORTION_SIZES = (0, 4, 5, 8, 12, 14)


@dataclass(frozen=True, eq=False)
class CameraCalibration:
    """One camera's calibration with ``sensor_msgs/CameraInfo`` semantics: image size [px],
    intrinsics ``K`` (3x3), distortion ``D``, rectifying rotation ``R`` (3x3) and rectified
    projection ``P`` (3x4; a right stereo camera's ``P[0, 3] = -fx B``). ``ValueError`` for an
    empty image, non-finite values, a non-positive focal length in ``K`` or a distortion
    vector OpenCV does not take. The one conversion of a camera_info: ``io/msgs.py``
    (``camera_calibration``, ``camera_info``) turns messages into it and back."""

    width: int
    height: int
    K: np.ndarray
    D: np.ndarray
    R: np.ndarray
    P: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "K", np.asarray(self.K, float).reshape(3, 3))
        object.__setattr__(self, "D", np.asarray(self.D, float).ravel())
        object.__setattr__(self, "R", np.asarray(self.R, float).reshape(3, 3))
        object.__setattr__(self, "P", np.asarray(self.P, float).reshape(3, 4))
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"camera_info image size {self.width} x {self.height} is empty")
        for name in ("K", "D", "R", "P"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise ValueError(f"camera_info {name} has non-finite values")
        if not (self.K[0, 0] > 0.0 and self.K[1, 1] > 0.0):
            raise ValueError(f"camera_info focal lengths must be > 0 (fx {self.K[0, 0]}, fy {self.K[1, 1]})")
        if self.D.size not in DISTORTION_SIZES:
            raise ValueError(f"camera_info has {self.D.size} distortion coefficients (OpenCV takes 4, 5, 8, 12 "
                             "or 14)")

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) [px]."""
        return (int(self.width), int(self.height))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, CameraCalibration):
            return NotImplemented
        return self.size == other.size and all(np.array_equal(getattr(self, k), getattr(other, k))
                                               for k in ("K", "D", "R", "P"))

    @classmethod
    def pinhole(cls, camera: PinholeCamera, tx_m: float = 0.0) -> "CameraCalibration":
        """A distortion-free pinhole camera (5 zero plumb_bob coefficients); ``tx_m`` is the
        stereo offset B of a right camera (``P[0, 3] = -fx B``)."""
        P = np.zeros((3, 4))
        P[:, :3] = camera.K
        P[0, 3] = -camera.fx * tx_m
        return cls(camera.width, camera.height, camera.K, np.zeros(5), np.eye(3), P)


def _rays_cached(cam: PinholeCamera) -> np.ndarray:
    if cam not in _RAY_CACHE:
        if len(_RAY_CACHE) > 8:
            _RAY_CACHE.clear()
        v, u = np.mgrid[0:cam.height, 0:cam.width]
        d = cam.pixel_directions(u.ravel(), v.ravel())
        d.setflags(write=False)
        _RAY_CACHE[cam] = d
    return _RAY_CACHE[cam]



def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0)) -> np.ndarray:
    """World pose (4x4) of an optical frame at ``eye`` whose z axis points at ``target`` and
    whose image "up" (-y) is as close to ``up`` as possible."""
    eye, target, up = (np.asarray(v, dtype=float) for v in (eye, target, up))
    z = target - eye
    if np.linalg.norm(z) < 1e-12:
        raise ValueError("eye and target coincide")
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("viewing direction is parallel to up")
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = eye
    return T


__all__ = ["PinholeCamera", "CameraCalibration", "DISTORTION_SIZES", "look_at"]
