"""Workspace Goal Region (Kanehiro et al., Sec. III-A, eq. 3; after Berenson's TSRs).

A WGR is a target frame ``T_target`` and bounds ``lower``, ``upper`` (6,) on
``(x, y, z, roll, pitch, yaw)`` offsets expressed in it. An end-effector pose in the
region is

    T_e = T_target * Trans(x, y, z) * RPY(roll, pitch, yaw),
    RPY(roll, pitch, yaw) = Rz(yaw) Ry(pitch) Rx(roll),

with every offset within its bounds. The paper's valve region (eq. 3) fixes the
position at the valve centre and leaves the hand's z axis anywhere in the upper
hemisphere: ``[0.71 0.71; 0.03 0.03; 0.9 0.9; -pi/2 pi/2; -pi/2 pi/2; -pi pi]`` in
the world, i.e. :func:`valve_region` around the target pose (0.71, 0.03, 0.90) with
identity orientation. No ROS here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

# Rotation bounds a little beyond +-pi are a typed pi (3.1416, 180 deg rounded): accepted and
# clamped to +-pi. Farther out they are an error (a bound past pi is a misunderstanding of the
# region, not a rounding).
ANGLE_TOL = 1e-3


def clamp_angle_bounds(lo: np.ndarray, hi: np.ndarray, tol: float = ANGLE_TOL) -> tuple[np.ndarray, np.ndarray]:
    """Angle bounds (roll, pitch, yaw lower and upper, each (3,)) clamped to [-pi, pi].

    A bound within ``tol`` of the interval is clamped onto it; one farther out raises
    ``ValueError`` naming each offending bound and how far beyond pi it lies.
    """
    lo = np.asarray(lo, dtype=float).reshape(-1)
    hi = np.asarray(hi, dtype=float).reshape(-1)
    names = ("roll", "pitch", "yaw")
    bad = [f"{side} {names[i]} {float(v[i])!r} ({abs(v[i]) - math.pi:.4g} rad beyond pi)"
           for side, v in (("lower", lo), ("upper", hi)) for i in range(v.size)
           if abs(v[i]) > math.pi + tol]
    if bad:
        raise ValueError(f"WGR: rotation bounds must lie within [-pi, pi] (values within {tol:g} rad of +-pi are "
                         f"clamped to +-pi): {', '.join(bad)}; got lower {lo.tolist()}, upper {hi.tolist()}")
    return np.clip(lo, -math.pi, math.pi), np.clip(hi, -math.pi, math.pi)


def rpy_matrix(rpy: np.ndarray) -> np.ndarray:
    """``Rz(yaw) Ry(pitch) Rx(roll)`` of rpy (..., 3) -> (..., 3, 3)."""
    rpy = np.asarray(rpy, dtype=float)
    cr, sr = np.cos(rpy[..., 0]), np.sin(rpy[..., 0])
    cp, sp = np.cos(rpy[..., 1]), np.sin(rpy[..., 1])
    cy, sy = np.cos(rpy[..., 2]), np.sin(rpy[..., 2])
    R = np.empty(rpy.shape[:-1] + (3, 3))
    R[..., 0, 0] = cy * cp
    R[..., 0, 1] = cy * sp * sr - sy * cr
    R[..., 0, 2] = cy * sp * cr + sy * sr
    R[..., 1, 0] = sy * cp
    R[..., 1, 1] = sy * sp * sr + cy * cr
    R[..., 1, 2] = sy * sp * cr - cy * sr
    R[..., 2, 0] = -sp
    R[..., 2, 1] = cp * sr
    R[..., 2, 2] = cp * cr
    return R


def matrix_rpy(R: np.ndarray) -> np.ndarray:
    """One rpy (..., 3) with ``Rz(y) Ry(p) Rx(r) = R``, pitch in [-pi/2, pi/2]."""
    R = np.asarray(R, dtype=float)
    pitch = np.arctan2(-R[..., 2, 0], np.hypot(R[..., 0, 0], R[..., 1, 0]))
    roll = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    yaw = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    return np.stack([roll, pitch, yaw], axis=-1)


def _angle_in(a: np.ndarray, lo: float, hi: float, tol: float) -> np.ndarray:
    """Is some ``a + 2 pi k`` within ``[lo - tol, hi + tol]``? (wrap-around aware)"""
    if hi - lo >= 2.0 * math.pi - 2.0 * tol:
        return np.ones(np.shape(a), bool)
    k = np.ceil((lo - tol - a) / (2.0 * math.pi))
    return a + 2.0 * math.pi * k <= hi + tol


@dataclass(frozen=True)
class WorkspaceGoalRegion:
    """Target pose (``target_p`` (3,), ``target_R`` (3, 3)) and bounds ``lower``/``upper``
    (6,) on (x, y, z [m], roll, pitch, yaw [rad]) in the target frame (eq. 3 form).

    Validation (ValueError): finite values, a proper rotation, ``lower <= upper``,
    angle bounds within [-pi, pi]; angle bounds within ``ANGLE_TOL`` (1e-3 rad) of +-pi
    are clamped to +-pi (a typed 3.1416 is pi), farther out they are refused.
    """

    target_p: np.ndarray
    target_R: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    _ok: bool = field(default=True, init=False, repr=False)

    def __post_init__(self) -> None:
        p = np.array(self.target_p, dtype=float).reshape(-1)
        R = np.array(self.target_R, dtype=float)
        lo = np.array(self.lower, dtype=float).reshape(-1)
        hi = np.array(self.upper, dtype=float).reshape(-1)
        if p.shape != (3,) or R.shape != (3, 3):
            raise ValueError(f"WGR: target position must be (3,) and rotation (3, 3), got {p.shape}, {R.shape}")
        if lo.shape != (6,) or hi.shape != (6,):
            raise ValueError(f"WGR: lower and upper must have 6 values (x, y, z, roll, pitch, yaw), "
                             f"got {lo.shape}, {hi.shape}")
        for name, a in (("target position", p), ("target rotation", R), ("lower", lo), ("upper", hi)):
            if not np.all(np.isfinite(a)):
                raise ValueError(f"WGR: {name} has non-finite values: {a.tolist()}")
        if not (np.allclose(R @ R.T, np.eye(3), atol=1e-6) and np.linalg.det(R) > 0):
            raise ValueError("WGR: target rotation is not a rotation matrix")
        bad = np.flatnonzero(lo > hi)
        names = ("x", "y", "z", "roll", "pitch", "yaw")
        if bad.size:
            raise ValueError("WGR: lower > upper for " + ", ".join(f"{names[i]} ({lo[i]} > {hi[i]})" for i in bad))
        lo[3:], hi[3:] = clamp_angle_bounds(lo[3:], hi[3:])
        lo += 0.0   # -0.0 -> 0.0: numpy's uniform refuses upper -0.0 above lower 0.0 ("high - low < 0")
        hi += 0.0
        for name, a in (("target_p", p), ("target_R", R), ("lower", lo), ("upper", hi)):
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    @classmethod
    def from_pose(cls, target: np.ndarray, lower, upper) -> "WorkspaceGoalRegion":
        """From a 4x4 homogeneous target pose (or a pinocchio SE3)."""
        H = np.asarray(target.homogeneous if hasattr(target, "homogeneous") else target, dtype=float)
        return cls(H[:3, 3], H[:3, :3], lower, upper)

    # ------------------------------------------------------------ sampling
    def sample_offsets(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """(n, 6) offsets uniform in [lower, upper]."""
        return rng.uniform(self.lower, self.upper, size=(n, 6))

    def poses_from_offsets(self, off: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World poses p (n, 3), R (n, 3, 3) of offsets (n, 6)."""
        off = np.asarray(off, dtype=float)
        p = self.target_p + off[:, :3] @ self.target_R.T
        R = self.target_R @ rpy_matrix(off[:, 3:])
        return p, R

    def sample(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        """n poses ``T_target Trans(xyz) RPY(rpy)`` with offsets uniform in the bounds."""
        return self.poses_from_offsets(self.sample_offsets(rng, n))

    # ------------------------------------------------------------ membership
    def contains(self, p, R, tol: float = 1e-9) -> bool | np.ndarray:
        """Does the pose (p (3,), R (3, 3)) -- or each of a batch (n, 3), (n, 3, 3) --
        lie in the region (bounds grown by ``tol``)?

        The pose is expressed in the target frame; its rotation is accepted when
        either rpy decomposition ``(r, p, y)`` or ``(r + pi, pi - p, y + pi)`` fits the
        bounds modulo 2 pi; at gimbal lock (|pitch| = pi/2) only ``roll -+ yaw`` is
        defined and any split within the bounds is accepted.
        """
        p = np.asarray(p, dtype=float)
        R = np.asarray(R, dtype=float)
        single = p.ndim == 1
        p = p.reshape(-1, 3)
        R = R.reshape(-1, 3, 3)
        loc_p = (p - self.target_p) @ self.target_R
        loc_R = np.einsum("ji,njk->nik", self.target_R, R)
        lo, hi = self.lower, self.upper
        ok = np.all((loc_p >= lo[:3] - tol) & (loc_p <= hi[:3] + tol), axis=1)
        rpy = matrix_rpy(loc_R)
        alt = np.stack([rpy[:, 0] + math.pi, math.pi - rpy[:, 1], rpy[:, 2] + math.pi], axis=1)

        def fits(a):
            return (_angle_in(a[:, 0], lo[3], hi[3], tol) & _angle_in(a[:, 1], lo[4], hi[4], tol)
                    & _angle_in(a[:, 2], lo[5], hi[5], tol))

        rot_ok = fits(rpy) | fits(alt)
        # gimbal lock: R = Rz(y) Ry(+-pi/2) Rx(r) depends on r -+ y only
        cp = np.hypot(loc_R[:, 0, 0], loc_R[:, 1, 0])
        lock = cp < 1e-7
        if np.any(lock):
            sgn = np.sign(-loc_R[lock, 2, 0])             # sin(pitch)
            pitch = sgn * math.pi / 2
            # with pitch = +pi/2: R[0,1] = sin(r - y), R[1,1] = cos(r - y); -pi/2: sin(-(r + y)) ...
            c = np.where(sgn > 0, np.arctan2(loc_R[lock, 0, 1], loc_R[lock, 1, 1]),
                         np.arctan2(-loc_R[lock, 0, 1], loc_R[lock, 1, 1]))
            lin_lo = np.where(sgn > 0, lo[3] - hi[5], lo[3] + lo[5])
            lin_hi = np.where(sgn > 0, hi[3] - lo[5], hi[3] + hi[5])
            pok = np.array([_angle_in(np.array([pt]), lo[4], hi[4], tol + 1e-6)[0] for pt in pitch])
            cok = np.array([_angle_in(np.array([ci]), a, b, tol + 1e-6)[0] for ci, a, b in zip(c, lin_lo, lin_hi)])
            rot_ok[lock] |= pok & cok
        res = ok & rot_ok
        return bool(res[0]) if single else res


def valve_region(target_p=(0.71, 0.03, 0.90), target_R=None) -> WorkspaceGoalRegion:
    """The paper's valve WGR (eq. 3): hand position at the valve centre, roll and pitch
    in [-pi/2, pi/2], yaw free (the hand z axis anywhere in the upper hemisphere of
    the target frame). ``target_p``/``target_R`` default to the plant scene's valve
    (world), which gives eq. 3 literally; a 4x4 pose may be passed as ``target_p``."""
    if np.ndim(target_p) == 2 or hasattr(target_p, "homogeneous"):
        H = np.asarray(target_p.homogeneous if hasattr(target_p, "homogeneous") else target_p, dtype=float)
        target_p, target_R = H[:3, 3], H[:3, :3]
    target_R = np.eye(3) if target_R is None else target_R
    h = math.pi / 2
    return WorkspaceGoalRegion(np.asarray(target_p, float), np.asarray(target_R, float),
                               np.array([0.0, 0.0, 0.0, -h, -h, -math.pi]), np.array([0.0, 0.0, 0.0, h, h, math.pi]))


__all__ = ["WorkspaceGoalRegion", "valve_region", "rpy_matrix", "matrix_rpy"]
