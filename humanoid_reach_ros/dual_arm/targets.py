"""Shared kinematics of the dissertation's whole-body reaching method (chapters 3-4).

Small pieces that Algorithms 1-3 and the baseline all need:

* input validation of hand targets (finite, right shapes, proper rotations) raising
  ``ValueError`` with a clear message;
* ``LN`` of the dissertation (rotation matrix -> angular vector, ref. [23]) expressed in
  world axes, so it pairs with pinocchio's LOCAL_WORLD_ALIGNED Jacobians:
  ``err_R = R LN(R^T R*)``;
* Rodrigues interpolation of an orientation (Sec. 3.4 / 4.5.2):
  ``R(s) = R_0 exp(s LN(R_0^T R*))``, ``s in [0, 1]``;
* the support-foot constraint of Algorithm 3 ("the robot's sole of the support leg is on
  the ground"): with ``v = (v_base, dq)`` and ``J_sup v = 0`` the base velocity is
  ``v_base = -J_sup,b^{-1} J_sup,q dq``, so any task Jacobian on the joints alone is
  ``J_eff = J_q + J_b B`` with ``B = -J_sup,b^{-1} J_sup,q``;
* the base (waist) pose that keeps the support sole at its world pose.

No rclpy here.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from scipy.linalg import lapack

from humanoid_reach_ros.robot.model import N_BASE_Q, N_BASE_V, RobotModel

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
ROTATION_TOL = 1e-6


def as_position(p, name: str) -> np.ndarray:
    """A finite 3-vector [m] or ``ValueError``."""
    a = np.asarray(p, dtype=float)
    if a.shape != (3,):
        raise ValueError(f"{name}: expected a position of shape (3,), got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: position must be finite, got {a.tolist()}")
    return a


def as_rotation(R, name: str) -> np.ndarray:
    """A finite proper 3x3 rotation matrix or ``ValueError``."""
    a = np.asarray(R, dtype=float)
    if a.shape != (3, 3):
        raise ValueError(f"{name}: expected a rotation matrix of shape (3, 3), got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: rotation must be finite")
    if np.abs(a.T @ a - np.eye(3)).max() > ROTATION_TOL or np.linalg.det(a) <= 0.0:
        raise ValueError(f"{name}: not a proper rotation matrix (R^T R != I or det <= 0)")
    return a


def as_joints(joints, n: int, name: str = "joints") -> np.ndarray:
    a = np.asarray(joints, dtype=float)
    if a.shape != (n,):
        raise ValueError(f"{name}: expected shape ({n},), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: must be finite")
    return a


@dataclass(frozen=True, eq=False)
class HandTargets:
    """Target poses of both hands (``p*_right, R*_right, p*_left, R*_left``), world frame."""

    p_right: np.ndarray
    R_right: np.ndarray
    p_left: np.ndarray
    R_left: np.ndarray

    @classmethod
    def make(cls, p_right, R_right, p_left, R_left) -> "HandTargets":
        """Validated constructor (``ValueError`` on NaN, wrong shapes, non-rotations)."""
        return cls(as_position(p_right, "p_right"), as_rotation(R_right, "R_right"),
                   as_position(p_left, "p_left"), as_rotation(R_left, "R_left"))

    @property
    def positions(self) -> np.ndarray:
        """(6,) ``(x1, y1, z1, x2, y2, z2)``: right then left, the regression input of Sec. 4.1."""
        return np.concatenate([self.p_right, self.p_left])


def rot_error(R: np.ndarray, R_target: np.ndarray) -> np.ndarray:
    """``R LN(R^T R*)``: the orientation error in world axes [rad]."""
    return R @ pin.log3(R.T @ R_target)


def pose_error(M: pin.SE3, p_target: np.ndarray, R_target: np.ndarray) -> np.ndarray:
    """6-vector ``(p* - p, R LN(R^T R*))`` of Algorithms 1 and 3 (line 4)."""
    return np.concatenate([p_target - M.translation, rot_error(M.rotation, R_target)])


def rodrigues_interpolate(R0: np.ndarray, R1: np.ndarray, s: float) -> np.ndarray:
    """``R0 exp(s LN(R0^T R1))`` (Rodrigues formula on the angular-velocity vector)."""
    return R0 @ pin.exp3(s * pin.log3(R0.T @ R1))


def support_elimination(J_sup: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """``B = -J_sup,b^{-1} J_sup,q`` (6 x len(cols)): base velocity per joint velocity
    that keeps the support sole still (``J_sup`` is the 6 x nv LWA sole Jacobian,
    ``cols`` velocity indices of the joints)."""
    return -solve(J_sup[:, :N_BASE_V], J_sup[:, cols])


def base_for_support(robot: RobotModel, joints: np.ndarray, sole_frame: str,
                     sole_world: pin.SE3, data: pin.Data | None = None) -> pin.SE3:
    """Waist pose putting ``sole_frame`` exactly at ``sole_world`` for these joint angles."""
    data = robot.data if data is None else data
    q = np.empty(robot.model.nq)
    q[:N_BASE_Q] = (0, 0, 0, 0, 0, 0, 1)
    q[N_BASE_Q:] = joints
    pin.forwardKinematics(robot.model, data, q)
    return sole_world * pin.updateFramePlacement(robot.model, data, robot.frame_id(sole_frame)).inverse()


def damped_pinv_apply(J: np.ndarray, e: np.ndarray, damping: float = 1e-10,
                      mobility: np.ndarray | None = None) -> np.ndarray:
    """``M J^T (J M J^T + damping I)^{-1} e`` -- eq. 3 applied to ``e`` with ``M = W^{-1}``
    (``mobility``; ``None`` = identity, the standard pseudo-inverse). ``damping`` is only a
    numerical guard at exact singularities (1e-10 by default, not a method parameter)."""
    JM = J if mobility is None else J * mobility[None, :]
    A = JM @ J.T
    A.flat[:: A.shape[0] + 1] += damping
    return JM.T @ spd_solve(A, e)


def solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``A^{-1} b`` by LAPACK ``gesv`` (no numpy wrapper overhead on these small systems)."""
    _, _, x, info = lapack.dgesv(A, b)
    if info != 0:
        raise np.linalg.LinAlgError(f"singular matrix (dgesv info {info})")
    return x


def spd_solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``A^{-1} b`` for symmetric positive-definite ``A`` by LAPACK ``posv`` (Cholesky);
    falls back to ``gesv`` if ``A`` is numerically not positive definite."""
    _, x, info = lapack.dposv(A, b)
    return x if info == 0 else solve(A, b)
