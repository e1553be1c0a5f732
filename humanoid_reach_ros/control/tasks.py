"""Equality tasks of the whole-body IK (Sec. IV, levels 2-4) on the floating-base model.

Unknown: the configuration displacement of one control step ``dq`` (tangent vector,
``R^nv``, ``nv = 36``: 6 base + 30 joints, pinocchio's convention, base velocity in
the base frame), applied with ``q+ = integrate(q, dq)`` (:func:`integrate`). Every
task gives the rows ``A dq = b`` with ``A = J`` (the task Jacobian, LOCAL_WORLD_ALIGNED:
world axes, at the frame origin) and ``b = -gain * e`` (``e`` the task error,
``gain`` in (0, 1] the fraction of the error removed per step).

Gripper joints (RARM_JOINT6, LARM_JOINT6) are *not* IK variables: their columns are
removed (:class:`DofSelection`), the IK works on ``n = 34`` unknowns and
:meth:`DofSelection.expand` puts zeros back (the grippers keep their angle).

Requires :func:`compute_kinematics` (joint Jacobians and frame placements) on ``q``
before :meth:`rows`; :class:`ComTask` computes its own CoM Jacobian.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import pinocchio as pin

from humanoid_reach_ros.robot.model import N_BASE_Q, N_BASE_V, RobotModel

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


@dataclass(frozen=True)
class TaskRows:
    """``A dq = b`` with ``b = -gain * error`` (rows already masked)."""

    A: np.ndarray
    b: np.ndarray
    error: np.ndarray


def compute_kinematics(model: pin.Model, data: pin.Data, q: np.ndarray) -> None:
    """Joint Jacobians + frame placements at ``q`` (what FrameTask and the limits read)."""
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)


def integrate(model: pin.Model, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
    """``q (+) dq``: configuration after applying the displacement ``dq`` (R^nv)."""
    return pin.integrate(model, q, dq)


@dataclass(frozen=True, eq=False)
class DofSelection:
    """The IK unknowns: all velocity indices except the fixed (gripper) joints."""

    nv: int
    index: np.ndarray            # (n,) velocity indices kept

    @classmethod
    def without_grippers(cls, robot: RobotModel) -> "DofSelection":
        fixed = {N_BASE_V + robot.joint_index[j] for j in robot.spec.gripper_joints}
        keep = np.array([i for i in range(robot.model.nv) if i not in fixed], dtype=np.intp)
        return cls(robot.model.nv, keep)

    @property
    def n(self) -> int:
        return len(self.index)

    def reduce(self, A: np.ndarray) -> np.ndarray:
        """Columns of ``A`` (..., nv) for the kept unknowns (..., n)."""
        return A[..., self.index]

    def expand(self, x: np.ndarray) -> np.ndarray:
        """Full ``dq`` (nv,) from the IK unknowns (n,); fixed joints get 0."""
        dq = np.zeros(self.nv)
        dq[self.index] = x
        return dq


def _mask_rows(J: np.ndarray, e: np.ndarray, gain: float, mask: Sequence[bool]) -> TaskRows:
    m = np.asarray(mask, dtype=bool)
    return TaskRows(J[m], -gain * e[m], e[m])


@dataclass(frozen=True, eq=False)
class FrameTask:
    """Pose of a frame: position rows then orientation rows (mask of 6, world axes).

    Error ``e = [p - p*, log3(R R*^T)]`` (the SO(3) part of ``log6``, in world axes;
    position as the plain world difference so its Jacobian is exactly the LWA linear
    Jacobian). Jacobian ``[J_v ; R* Jlog3(R*^T R) R^T J_w]`` since
    ``log3(R R*^T) = R* log3(R*^T R)`` and ``d log3(M) = Jlog3(M) R^T w``.
    """

    frame_id: int
    target: pin.SE3
    gain: float = 1.0
    mask: tuple[bool, bool, bool, bool, bool, bool] = (True,) * 6

    @classmethod
    def of(cls, robot: RobotModel, frame: str, target: pin.SE3, gain: float = 1.0,
           mask: Sequence[bool] = (True,) * 6) -> "FrameTask":
        return cls(robot.frame_id(frame), target.copy(), float(gain), tuple(bool(m) for m in mask))

    def error(self, data: pin.Data) -> np.ndarray:
        T = data.oMf[self.frame_id]
        Rt = self.target.rotation
        return np.concatenate([T.translation - self.target.translation,
                               Rt @ pin.log3(Rt.T @ T.rotation)])

    def jacobian(self, model: pin.Model, data: pin.Data) -> np.ndarray:
        J = pin.getFrameJacobian(model, data, self.frame_id, LWA)
        R = data.oMf[self.frame_id].rotation
        Rt = self.target.rotation
        Jr = Rt @ pin.Jlog3(Rt.T @ R) @ R.T @ J[3:]
        return np.vstack([J[:3], Jr])

    def rows(self, model: pin.Model, data: pin.Data, q: np.ndarray | None = None) -> TaskRows:
        return _mask_rows(self.jacobian(model, data), self.error(data), self.gain, self.mask)


@dataclass(frozen=True, eq=False)
class ComTask:
    """Horizontal position of the exact centre of mass: ``e = c_xy - c*_xy``,
    ``A = J_com[:2]`` (``pin.jacobianCenterOfMass``)."""

    target_xy: np.ndarray
    gain: float = 1.0

    def rows(self, model: pin.Model, data: pin.Data, q: np.ndarray | None = None) -> TaskRows:
        """``q``: computes the kinematics at ``q``; ``None``: uses the joint Jacobians already
        in ``data`` (:func:`compute_kinematics` of this step: the executor's fast path)."""
        Jc = pin.jacobianCenterOfMass(model, data, False) if q is None else pin.jacobianCenterOfMass(model, data, q)
        e = data.com[0][:2] - np.asarray(self.target_xy, float)
        return TaskRows(Jc[:2].copy(), -self.gain * e, e)


@dataclass(frozen=True, eq=False)
class PostureTask:
    """Joint angles toward a reference: ``e = q_j - q*_j`` on the selected joints,
    ``A`` = rows of the identity on their velocity columns."""

    q_ref: np.ndarray                      # (30,) joint angles
    gain: float = 1.0
    joints: tuple[int, ...] | None = None  # indices into the 30 joints; None = all

    def error(self, q: np.ndarray, n_joints: int) -> np.ndarray:
        """``q_j - q*_j`` on the selected joints (``n_joints``: the model's joint count)."""
        sel = np.arange(n_joints) if self.joints is None else np.asarray(self.joints, dtype=np.intp)
        return q[N_BASE_Q + sel] - np.asarray(self.q_ref, float)[sel]

    def rows(self, model: pin.Model, data: pin.Data, q: np.ndarray) -> TaskRows:
        nj = model.nv - N_BASE_V
        sel = np.arange(nj) if self.joints is None else np.asarray(self.joints, dtype=np.intp)
        e = self.error(q, nj)
        A = np.zeros((len(sel), model.nv))
        A[np.arange(len(sel)), N_BASE_V + sel] = 1.0
        return TaskRows(A, -self.gain * e, e)


__all__ = ["TaskRows", "compute_kinematics", "integrate", "DofSelection", "FrameTask", "ComTask", "PostureTask"]
