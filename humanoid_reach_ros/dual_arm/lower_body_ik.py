"""Algorithm 3 of the dissertation (Sec. 4.3): the lower-body IK with the support sole fixed.

:class:`LowerBodyIK`. Unknowns: the 12 leg joints ``q_legs``; the upper body (chest, arms,
head, grippers) is held at ``q_upperBody``. The support sole (right by default, Sec. 4.3:
"we simply choose one of the legs as the support leg") stays at its world pose: the waist
pose follows from the support leg (``base_for_support``) and the Jacobians use the
constraint elimination of :func:`kinematics.support_elimination`.

    e  = (p*_CoM - p_CoM, LN(R_torso^T R*_torso), p*_swing - p_swing, LN(R_swing^T R*_swing))
    J  = [J_CoM; J_torso; J_swing]                        (eq. 7, 12 x 12)
    q'_legs = q_legs + alpha J^# e                        (line 8)
    e' = (LN(R'_torso^T R*_torso), p*_swing - p'_swing, LN(R'_swing^T R*_swing))
    q_legs  = q'_legs + beta J'^# e'                      (line 11, J' 9 x 12)

The torso is the waist link ``base_link`` (the legs cannot move the chest link).
:class:`_FloatingKinematics` (pinocchio with the support sole held fixed) is shared with the
full-body LM baseline of ``whole_body_ik``; the compiled closed-form twin of
:class:`LowerBodyIK` (``fast_legs.ClosedFormLowerBodyIK``) falls back to it. Both import it
from here: ``whole_body_ik -> fast_legs -> lower_body_ik``, no cycle.

No rclpy here.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from humanoid_reach_ros.dual_arm.targets import (
    LWA, base_for_support, damped_pinv_apply, pose_error, rot_error, support_elimination,
)
from humanoid_reach_ros.robot.model import N_BASE_Q, N_BASE_V, RobotModel


@dataclass(frozen=True)
class LegTargets:
    """Targets of Algorithm 3: ``p*_CoM``, ``R*_torso``, swing sole pose (world)."""

    p_com: np.ndarray
    R_torso: np.ndarray
    p_swing: np.ndarray
    R_swing: np.ndarray


@dataclass(frozen=True, eq=False)
class LowerBodyResult:
    q: np.ndarray
    converged: bool
    iterations: int
    error_norm: float


class _FloatingKinematics:
    """Pinocchio evaluations with the support sole held fixed."""

    def __init__(self, robot: RobotModel, support: str = "right") -> None:
        if support not in ("right", "left"):
            raise ValueError(f"support must be 'right' or 'left', got {support!r}")
        self.robot = robot
        self.model = robot.model
        self.data = self.model.createData()
        swing = "left" if support == "right" else "right"
        self.support = support
        self.sup_frame = robot.limbs[f"{support}_leg"].tip
        self.swing_frame = robot.limbs[f"{swing}_leg"].tip
        self.fid_sup = robot.frame_id(self.sup_frame)
        self.fid_swing = robot.frame_id(self.swing_frame)
        self.fid_torso = robot.frame_id(robot.base_link)
        self.sup_index = np.array(robot.limbs[f"{support}_leg"].joint_index, dtype=np.intp)
        self.swing_index = np.array(robot.limbs[f"{swing}_leg"].joint_index, dtype=np.intp)
        self.leg_index = np.concatenate([self.sup_index, self.swing_index])
        self._sup_masks: dict[bytes, np.ndarray] = {}

    def place_base(self, q: np.ndarray, sole_world: pin.SE3) -> None:
        """Overwrite the base of ``q`` so that the support sole is at ``sole_world``."""
        base = base_for_support(self.robot, q[N_BASE_Q:], self.sup_frame, sole_world, self.data)
        q[:N_BASE_Q] = pin.SE3ToXYZQUAT(base)

    def jacobians(self, q: np.ndarray, index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Kinematics at ``q`` and ``B`` (support elimination) for the joints ``index``.

        Returns ``(cols, B)``; afterwards ``self.data`` holds frames, joint Jacobians
        and the CoM Jacobian (``data.Jcom``, ``data.com[0]``)."""
        m, d = self.model, self.data
        pin.jacobianCenterOfMass(m, d, q, False)     # also computes the joint Jacobians
        pin.updateFramePlacements(m, d)
        cols = N_BASE_V + index
        Jsup = pin.getFrameJacobian(m, d, self.fid_sup, LWA)
        B = np.zeros((6, len(index)))
        key = index.tobytes()
        sup_mask = self._sup_masks.get(key)
        if sup_mask is None:
            sup_mask = self._sup_masks.setdefault(key, np.isin(index, self.sup_index))
        B[:, sup_mask] = support_elimination(Jsup, cols[sup_mask])
        return cols, B

    def frame_jac(self, fid: int, cols: np.ndarray, B: np.ndarray) -> np.ndarray:
        J = pin.getFrameJacobian(self.model, self.data, fid, LWA)
        return J[:, cols] + J[:, :N_BASE_V] @ B

    def com_jac(self, cols: np.ndarray, B: np.ndarray) -> np.ndarray:
        Jc = self.data.Jcom
        return Jc[:, cols] + Jc[:, :N_BASE_V] @ B


class LowerBodyIK(_FloatingKinematics):
    """Algorithm 3 on the 12 leg joints with the support sole fixed."""

    def __init__(self, robot: RobotModel, support: str = "right", alpha: float = 1.0,
                 beta: float = 1.0, tol: float = 1e-7, max_iter: int = 20) -> None:
        super().__init__(robot, support)
        self.alpha, self.beta, self.tol, self.max_iter = alpha, beta, tol, max_iter
        self.lower = robot.lower[self.leg_index]
        self.upper = robot.upper[self.leg_index]
        self.qcols = N_BASE_Q + self.leg_index

    def _error(self, t: LegTargets, with_com: bool) -> np.ndarray:
        d = self.data
        parts = [rot_error(d.oMf[self.fid_torso].rotation, t.R_torso),
                 pose_error(d.oMf[self.fid_swing], t.p_swing, t.R_swing)]
        if with_com:
            parts.insert(0, t.p_com - d.com[0])
        return np.concatenate(parts)

    def solve(self, q0: np.ndarray, targets: LegTargets, sole_world: pin.SE3) -> LowerBodyResult:
        """Algorithm 3 from ``q0`` (nq); returns the configuration with new legs and base.

        On return ``self.data`` holds the frame placements and CoM of the returned
        configuration (callers read the chest pose from it)."""
        q = np.array(q0, dtype=float)
        m, d = self.model, self.data
        self.place_base(q, sole_world)
        cols, B = self.jacobians(q, self.leg_index)
        e = self._error(targets, True)
        it = 0
        while np.linalg.norm(e) >= self.tol and it < self.max_iter:
            it += 1
            J = np.vstack([self.com_jac(cols, B), self.frame_jac(self.fid_torso, cols, B)[3:],
                           self.frame_jac(self.fid_swing, cols, B)])
            q[self.qcols] = np.clip(q[self.qcols] + self.alpha * damped_pinv_apply(J, e), self.lower, self.upper)
            self.place_base(q, sole_world)
            # lines 9-11: re-establish torso orientation and swing sole exactly
            cols, B = self.jacobians(q, self.leg_index)
            e2 = self._error(targets, False)
            J2 = np.vstack([self.frame_jac(self.fid_torso, cols, B)[3:], self.frame_jac(self.fid_swing, cols, B)])
            q[self.qcols] = np.clip(q[self.qcols] + self.beta * damped_pinv_apply(J2, e2), self.lower, self.upper)
            self.place_base(q, sole_world)
            # convergence test (line 5 of the next iteration) on FK + CoM only
            pin.framesForwardKinematics(m, d, q)
            pin.centerOfMass(m, d, q, False)
            e = self._error(targets, True)
            if np.linalg.norm(e) < self.tol or it == self.max_iter:
                break
            cols, B = self.jacobians(q, self.leg_index)
        en = float(np.linalg.norm(e))
        return LowerBodyResult(q, en < self.tol, it, en)



def lowered_initial_posture(robot: RobotModel, drop_m: float, q_start: np.ndarray | None = None) -> np.ndarray:
    """Half-sitting (or ``q_start``: half-sitting with other upper-body joints) with the CoM
    lowered by ``drop_m`` from half-sitting's (Algorithm 3, waist kept upright, feet at the
    stance poses). Raises ``ValueError`` if the legs cannot do it."""
    if not (np.isfinite(drop_m) and 0.0 <= drop_m < 0.3):
        raise ValueError(f"initial_com_drop_m must be in [0, 0.3), got {drop_m}")
    q0 = robot.half_sitting() if q_start is None else np.array(q_start, dtype=float)
    r_sole, l_sole = robot.stance_soles
    low = LowerBodyIK(robot, "right", max_iter=100)
    com = robot.com(robot.half_sitting()) - np.array([0.0, 0.0, drop_m])
    res = low.solve(q0, LegTargets(com, np.eye(3), l_sole.translation, l_sole.rotation), r_sole)
    if not res.converged:
        raise ValueError(f"cannot lower the CoM by {drop_m} m (|e| = {res.error_norm:.2e})")
    return res.q


__all__ = ["LegTargets", "LowerBodyResult", "LowerBodyIK", "lowered_initial_posture"]
