"""Upper-body IK on the chest + both arms (dissertation Sec. 3.3-3.5 and 4.1).

Unknowns ``q = (q_chest, q_right, q_left)`` (2 + 6 + 6 = 14 joints on HRP-2, 16 with 7-joint arms; the grippers, head,
legs and the waist pose stay as given). Error ``err`` (12) = position and ``LN``
orientation error of each hand (Algorithm 1, line 4), Jacobian ``J`` (12 x 14) of
eq. 2, both in world axes (LOCAL_WORLD_ALIGNED).

* :meth:`UpperBodyIK.solve_pinv` -- Algorithm 1 with either the standard pseudo-inverse
  ``J^# = J^T (J J^T)^{-1}`` or the weighted one of eq. 3,
  ``J_W^# = W^{-1} J^T (J W^{-1} J^T)^{-1}``, update eq. 4 ``q <- q + alpha J_W^# err``.
  **Weight convention.** Sec. 5.1.2 sets "the diagonal elements corresponding to the chest
  joint equal to 0.1, the others 1.0", and Sec. 3.5 / 5.1.3 say this makes the chest
  *harder* to move and restricts the chest angle. Put literally into ``W`` of eq. 3 a 0.1
  would make the chest 10x *cheaper* to move (``J_W^#`` is the minimiser of
  ``dq^T W dq``), contradicting the reported result, so the 0.1 is applied to
  ``W^{-1}`` (chest mobility 0.1, i.e. ``W_chest = 10``): the stated intent.
* :meth:`UpperBodyIK.solve_lm` -- Levenberg-Marquardt *BothArmsIK* of Algorithm 2 after
  Sugihara (ref. [24]): ``dq = (J^T J + W_N)^{-1} J^T err`` with the damping added to the
  diagonal ``W_N = omega E + w_bar``, ``E = 1/2 err^T err``; the chest mobility enters
  as ``W_N = diag(W) (omega E + w_bar)`` so the damping is heavier on the chest.
* :meth:`UpperBodyIK.generate_sample` -- Algorithm 2: repeat BothArmsIK from ``q_0``
  with ``omega <- omega + 1.0`` until it converges (the "exploratory damping increase";
  at most ``max_tries`` tries), then return the chest angles.

Joint limits: each update is clipped onto the URDF limits (projection; the paper does
not state its limit handling).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from humanoid_reach_ros.dual_arm.targets import (
    LWA, HandTargets, as_joints, damped_pinv_apply, pose_error, spd_solve,
)
from humanoid_reach_ros.robot.model import N_BASE_Q, N_BASE_V, RobotModel

#: chest weight of eq. 3 (Sec. 5.1.2), applied as mobility ``W^{-1}`` (module docstring)
CHEST_WEIGHT = 0.1


@dataclass(frozen=True, eq=False)
class UpperBodyResult:
    """Outcome of one IK solve: full configuration, convergence flag, iterations,
    final error norm ``|err|`` and the hands' position error norms [m]."""

    q: np.ndarray
    converged: bool
    iterations: int
    error_norm: float
    position_error: float
    omega: float = 0.0


class UpperBodyIK:
    """Chest + two-arm IK of Algorithm 1 (standard / weighted pinv) and Algorithm 2 (LM)."""

    def __init__(self, robot: RobotModel, chest_weight: float = CHEST_WEIGHT) -> None:
        if not (np.isfinite(chest_weight) and chest_weight > 0.0):
            raise ValueError(f"chest_weight must be > 0, got {chest_weight}")
        self.robot = robot
        self.model = robot.model
        self.data = self.model.createData()
        chest = [robot.joint_index[j] for j in robot.spec.chest_joints]
        self.chest_index = np.array(chest, dtype=np.intp)
        self.right_index = np.array(robot.limbs["right_arm"].joint_index, dtype=np.intp)
        self.left_index = np.array(robot.limbs["left_arm"].joint_index, dtype=np.intp)
        #: joint indices (into the 30-vector) of q = (q_chest, q_right, q_left)
        self.index = np.concatenate([self.chest_index, self.right_index, self.left_index])
        self.cols = N_BASE_V + self.index
        self.qcols = N_BASE_Q + self.index
        self.lower = robot.lower[self.index]
        self.upper = robot.upper[self.index]
        self.mobility = np.ones(len(self.index))
        self.mobility[: len(chest)] = chest_weight
        self.fid_right = robot.frame_id(robot.limbs["right_arm"].tip)
        self.fid_left = robot.frame_id(robot.limbs["left_arm"].tip)
        self.chest_pitch_col = int(np.flatnonzero(self.index == robot.joint_index[robot.spec.chest_pitch])[0])
        self.chest_yaw_col = int(np.flatnonzero(self.index == robot.joint_index[robot.spec.chest_yaw])[0])

    # ------------------------------------------------------------ kinematics
    def error_jacobian(self, q: np.ndarray, targets: HandTargets) -> tuple[np.ndarray, np.ndarray]:
        """``err`` (12) and ``J`` (12 x 14) of Algorithm 1 line 3-4 / eq. 2 at ``q``."""
        m, d = self.model, self.data
        pin.computeJointJacobians(m, d, q)
        pin.updateFramePlacements(m, d)
        err = np.concatenate([
            pose_error(d.oMf[self.fid_right], targets.p_right, targets.R_right),
            pose_error(d.oMf[self.fid_left], targets.p_left, targets.R_left),
        ])
        J = np.vstack([
            pin.getFrameJacobian(m, d, self.fid_right, LWA)[:, self.cols],
            pin.getFrameJacobian(m, d, self.fid_left, LWA)[:, self.cols],
        ])
        return err, J

    def _check(self, q0: np.ndarray) -> np.ndarray:
        return as_joints(q0, self.model.nq, "q0").copy()

    def _result(self, q, err, converged, it, omega=0.0) -> UpperBodyResult:
        pos = float(np.hypot(np.linalg.norm(err[0:3]), np.linalg.norm(err[6:9])))
        return UpperBodyResult(q, converged, it, float(np.linalg.norm(err)), pos, omega)

    # ------------------------------------------------------------ Algorithm 1
    def solve_pinv(self, q0: np.ndarray, targets: HandTargets, weighted: bool = True,
                   alpha: float = 1.0, tol: float = 1e-6, max_iter: int = 100) -> UpperBodyResult:
        """Algorithm 1 from the full configuration ``q0`` (nq); eq. 4 if ``weighted``."""
        q = self._check(q0)
        mob = self.mobility if weighted else None
        err = np.zeros(12)
        for it in range(max_iter + 1):
            err, J = self.error_jacobian(q, targets)
            if np.linalg.norm(err) < tol:
                return self._result(q, err, True, it)
            if it == max_iter:
                break
            dq = alpha * damped_pinv_apply(J, err, mobility=mob)
            q[self.qcols] = np.clip(q[self.qcols] + dq, self.lower, self.upper)
        return self._result(q, err, False, max_iter)

    # ------------------------------------------------------------ Algorithm 2
    def solve_lm(self, q0: np.ndarray, targets: HandTargets, omega: float = 1.0,
                 w_bar: float = 1e-3, tol: float = 1e-6, max_iter: int = 200) -> UpperBodyResult:
        """*BothArmsIK*: LM with damping ``W_N = diag(W) (omega E + w_bar)`` (Sugihara)."""
        q = self._check(q0)
        wdiag = 1.0 / self.mobility
        err = np.zeros(12)
        for it in range(max_iter + 1):
            err, J = self.error_jacobian(q, targets)
            e2 = float(err @ err)
            if np.sqrt(e2) < tol:
                return self._result(q, err, True, it, omega)
            if it == max_iter:
                break
            H = J.T @ J
            H.flat[:: H.shape[0] + 1] += wdiag * (omega * 0.5 * e2 + w_bar)
            dq = spd_solve(H, J.T @ err)
            q[self.qcols] = np.clip(q[self.qcols] + dq, self.lower, self.upper)
        return self._result(q, err, False, max_iter, omega)

    def generate_sample(self, q0: np.ndarray, targets: HandTargets, omega0: float = 1.0,
                        max_tries: int = 4, tol: float = 1e-6, max_iter: int = 200
                        ) -> tuple[np.ndarray | None, UpperBodyResult]:
        """Algorithm 2: LM from ``q0``, ``omega <- omega + 1.0`` until solvable.

        Returns ``((q_chest_pitch, q_chest_yaw), result)``, or ``(None, last result)`` when
        no try converged within the limits."""
        omega = omega0
        res = None
        for _ in range(max_tries):
            res = self.solve_lm(q0, targets, omega=omega, tol=tol, max_iter=max_iter)
            if res.converged:
                qu = res.q[self.qcols]
                return np.array([qu[self.chest_pitch_col], qu[self.chest_yaw_col]]), res
            omega += 1.0
        assert res is not None
        return None, res
