"""Whole-body IK of the dissertation (Sec. 4.3, Algorithm 3) and the full-body LM baseline.

:class:`LowerBodyIK` -- Algorithm 3. Unknowns: the 12 leg joints ``q_legs``; the upper
body (chest, arms, head, grippers) is held at ``q_upperBody`` (the chest at the value the
regression gives, the arms at the previous control step). The support sole (right by
default, Sec. 4.3: "we simply choose one of the legs as the support leg") stays at its
world pose: the waist pose follows from the support leg (``base_for_support``) and the
Jacobians use the constraint elimination of :func:`kinematics.support_elimination`.

    e  = (p*_CoM - p_CoM, LN(R_torso^T R*_torso), p*_swing - p_swing, LN(R_swing^T R*_swing))
    J  = [J_CoM; J_torso; J_swing]                        (eq. 7, 12 x 12)
    q'_legs = q_legs + alpha J^# e                        (line 8)
    e' = (LN(R'_torso^T R*_torso), p*_swing - p'_swing, LN(R'_swing^T R*_swing))
    q_legs  = q'_legs + beta J'^# e'                      (line 11, J' 9 x 12)

The torso is the waist link ``base_link`` (the legs cannot move the chest link).

:class:`ProposedWholeBodyIK` -- one control step of the proposed method (Fig. 8): chest
angles set, Algorithm 3 for the legs, then the closed-form IK of both arms
(``robot.limb_ik``) from the resulting ``CHEST_LINK1`` pose. By default both parts run
compiled: the legs by :class:`~humanoid_reach_ros.reach.fast_legs.ClosedFormLowerBodyIK`
(Algorithm 3's 12 equations solved as closed-form legs + a 3-D Newton on the waist
position -- a named reformulation with the same solution, falling back to
:class:`LowerBodyIK` whenever it fails), the arms by
:class:`~humanoid_reach_ros.reach.fast_arms.CompiledArmIK` (numba twin of the closed-form
arm IK). ``closed_form_legs=False, compiled_arms=False`` gives the reference path; the
tests check both agree.

:class:`FullBodyLMIK` -- the conventional method of Sec. 5.2 (Table 2): one LM
(Sugihara, ref. [24]) on legs + chest + arms (26 joints) with 24 task rows (both hands'
poses, CoM, torso orientation, swing sole pose), the support sole fixed the same way.

No rclpy here.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from humanoid_reach_ros.reach.kinematics import (
    LWA, HandTargets, as_joints, as_position, as_rotation, base_for_support,
    damped_pinv_apply, pose_error, rot_error, spd_solve, support_elimination,
)
from humanoid_reach_ros.robot.limb_ik import IKReason, LimbIKSet
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


@dataclass(frozen=True, eq=False)
class StepResult:
    """One control step: configuration ``q`` (nq) -- never NaN --, whether every part
    succeeded, a reason string ("" when ok), the hands' and CoM errors [m]."""

    q: np.ndarray
    ok: bool
    reason: str
    hand_error: float
    com_error: float
    lower_iterations: int


class ProposedWholeBodyIK:
    """One control step of the proposed method: chest set -> Algorithm 3 -> closed-form arms."""

    def __init__(self, robot: RobotModel, support: str = "right", closed_form_legs: bool = True,
                 compiled_arms: bool = True, **lower_kw) -> None:
        self.robot = robot
        self.lower = LowerBodyIK(robot, support, **lower_kw)
        if closed_form_legs:      # same solution, compiled (reach/fast_legs.py); falls back to LowerBodyIK
            from humanoid_reach_ros.reach.fast_legs import ClosedFormLowerBodyIK
            self.lower = ClosedFormLowerBodyIK(robot, support, tol=self.lower.tol, max_iter=self.lower.max_iter,
                                               reference=self.lower)
        self.limb_ik = LimbIKSet(robot)
        self.chest_pitch = N_BASE_Q + robot.joint_index["CHEST_JOINT1"]
        self.chest_yaw = N_BASE_Q + robot.joint_index["CHEST_JOINT0"]
        self.arm_cols = {s: N_BASE_Q + np.array(robot.limbs[f"{s}_arm"].joint_index) for s in ("right", "left")}
        self.fid_chest = robot.frame_id(robot.limbs["right_arm"].root)
        self.fid_hand = {s: robot.frame_id(robot.limbs[f"{s}_arm"].tip) for s in ("right", "left")}
        self.arm_ik = None
        if compiled_arms:         # numba twin of the closed-form arm IK (reach/fast_arms.py)
            from humanoid_reach_ros.reach.fast_arms import CompiledArmIK
            self.arm_ik = {s: CompiledArmIK(self.limb_ik[f"{s}_arm"]) for s in ("right", "left")}
        if closed_form_legs or compiled_arms:
            self.warm_up()

    def warm_up(self) -> None:
        """One step at half-sitting: compiles (or loads from numba's cache) the kernels
        now rather than in the first control step."""
        q = self.robot.half_sitting()
        M = {s: self.robot.frame_pose(q, self.robot.limbs[f"{s}_arm"].tip) for s in ("right", "left")}
        soles = dict(zip(("right", "left"), self.robot.stance_soles))
        sup = self.lower.support
        swing = "left" if sup == "right" else "right"
        hands = HandTargets(M["right"].translation, M["right"].rotation, M["left"].translation, M["left"].rotation)
        legs = LegTargets(self.robot.com(q), self.robot.frame_pose(q, self.robot.base_link).rotation,
                          soles[swing].translation, soles[swing].rotation)
        self.step(q, hands, np.array([q[self.chest_pitch], q[self.chest_yaw]]), legs, soles[sup], measure=False)

    def step(self, q_prev: np.ndarray, hands: HandTargets, chest_pitch_yaw: np.ndarray,
             legs: LegTargets, sole_world: pin.SE3, measure: bool = True) -> StepResult:
        """One control step; ``measure=False`` skips the error bookkeeping (errors NaN)
        so that timing covers the method only (:func:`measure_errors` afterwards)."""
        q = np.array(q_prev, dtype=float)
        q[self.chest_pitch], q[self.chest_yaw] = chest_pitch_yaw
        q[self.chest_pitch] = np.clip(q[self.chest_pitch], *self._lim("CHEST_JOINT1"))
        q[self.chest_yaw] = np.clip(q[self.chest_yaw], *self._lim("CHEST_JOINT0"))
        low = self.lower.solve(q, legs, sole_world)
        q = low.q
        C = self.lower.data.oMf[self.fid_chest]          # FK of low.q (LowerBodyIK.solve)
        reasons = []
        if not low.converged:
            reasons.append(f"lower body: |e| = {low.error_norm:.2e} after {low.iterations} iterations")
        for side, p, R in (("right", hands.p_right, hands.R_right), ("left", hands.p_left, hands.R_left)):
            cols = self.arm_cols[side]
            if self.arm_ik is not None:
                code, qa = self.arm_ik[side].solve(C.translation, C.rotation, p, R, q[cols])
            else:
                res = self.limb_ik[f"{side}_arm"].solve(C.translation, C.rotation, p, R, q[cols])
                code, qa = int(res.reason[0]), res.q[0]
            if code == 0:
                q[cols] = qa
            else:
                reasons.append(f"{side} arm: {IKReason(code).name}")
        herr, cerr = measure_errors(self.robot, self.lower.data, q, hands, legs) if measure else (np.nan, np.nan)
        return StepResult(q, not reasons, "; ".join(reasons), herr, cerr, low.iterations)

    def _lim(self, joint: str) -> tuple[float, float]:
        i = self.robot.joint_index[joint]
        return float(self.robot.lower[i]), float(self.robot.upper[i])


class FullBodyLMIK(_FloatingKinematics):
    """Conventional full-body numerical IK (Sec. 5.2.1): LM on legs + chest + arms."""

    def __init__(self, robot: RobotModel, support: str = "right", tol: float = 1e-7,
                 max_iter: int = 100, omega: float = 1.0, w_bar: float = 1e-3) -> None:
        super().__init__(robot, support)
        chest = [robot.joint_index[j] for j in robot.semantic["chest_joints"]]
        arms = list(robot.limbs["right_arm"].joint_index) + list(robot.limbs["left_arm"].joint_index)
        self.index = np.concatenate([self.leg_index, np.array(chest + arms, dtype=np.intp)])
        self.qcols = N_BASE_Q + self.index
        self.lower = robot.lower[self.index]
        self.upper = robot.upper[self.index]
        self.tol, self.max_iter, self.omega, self.w_bar = tol, max_iter, omega, w_bar
        self.fid_hand = {s: robot.frame_id(robot.limbs[f"{s}_arm"].tip) for s in ("right", "left")}

    def _error(self, hands: HandTargets, legs: LegTargets) -> np.ndarray:
        d = self.data
        return np.concatenate([
            pose_error(d.oMf[self.fid_hand["right"]], hands.p_right, hands.R_right),
            pose_error(d.oMf[self.fid_hand["left"]], hands.p_left, hands.R_left),
            legs.p_com - d.com[0],
            rot_error(d.oMf[self.fid_torso].rotation, legs.R_torso),
            pose_error(d.oMf[self.fid_swing], legs.p_swing, legs.R_swing),
        ])

    def step(self, q_prev: np.ndarray, hands: HandTargets, legs: LegTargets,
             sole_world: pin.SE3, measure: bool = True) -> StepResult:
        q = np.array(q_prev, dtype=float)
        self.place_base(q, sole_world)
        e = np.zeros(24)
        converged = False
        it = 0
        for it in range(self.max_iter + 1):
            cols, B = self.jacobians(q, self.index)
            e = self._error(hands, legs)
            if np.linalg.norm(e) < self.tol:
                converged = True
                break
            if it == self.max_iter:
                break
            J = np.vstack([self.frame_jac(self.fid_hand["right"], cols, B),
                           self.frame_jac(self.fid_hand["left"], cols, B),
                           self.com_jac(cols, B),
                           self.frame_jac(self.fid_torso, cols, B)[3:],
                           self.frame_jac(self.fid_swing, cols, B)])
            e2 = float(e @ e)
            H = J.T @ J
            H.flat[:: H.shape[0] + 1] += self.omega * 0.5 * e2 + self.w_bar
            q[self.qcols] = np.clip(q[self.qcols] + spd_solve(H, J.T @ e), self.lower, self.upper)
            self.place_base(q, sole_world)
        herr, cerr = measure_errors(self.robot, self.data, q, hands, legs) if measure else (np.nan, np.nan)
        reason = "" if converged else f"LM: |e| = {np.linalg.norm(e):.2e} after {it} iterations"
        return StepResult(q, converged, reason, herr, cerr, it)


def measure_errors(robot: RobotModel, data: pin.Data, q: np.ndarray, hands: HandTargets,
                   legs: LegTargets) -> tuple[float, float]:
    """``(|(e_right, e_left)|, |p_CoM - p*_CoM|)`` at ``q``: hand position error norm and
    CoM error [m]."""
    pin.framesForwardKinematics(robot.model, data, q)
    er = data.oMf[robot.frame_id(robot.limbs["right_arm"].tip)].translation - hands.p_right
    el = data.oMf[robot.frame_id(robot.limbs["left_arm"].tip)].translation - hands.p_left
    com = pin.centerOfMass(robot.model, data, q)
    return float(np.hypot(np.linalg.norm(er), np.linalg.norm(el))), float(np.linalg.norm(com - legs.p_com))


def lowered_initial_posture(robot: RobotModel, drop_m: float) -> np.ndarray:
    """Half-sitting with the CoM lowered by ``drop_m`` (Algorithm 3, waist kept upright,
    feet at the stance poses). Raises ``ValueError`` if the legs cannot do it."""
    if not (np.isfinite(drop_m) and 0.0 <= drop_m < 0.3):
        raise ValueError(f"initial_com_drop_m must be in [0, 0.3), got {drop_m}")
    q0 = robot.half_sitting()
    r_sole, l_sole = robot.stance_soles
    low = LowerBodyIK(robot, "right", max_iter=100)
    com = robot.com(q0) - np.array([0.0, 0.0, drop_m])
    res = low.solve(q0, LegTargets(com, np.eye(3), l_sole.translation, l_sole.rotation), r_sole)
    if not res.converged:
        raise ValueError(f"cannot lower the CoM by {drop_m} m (|e| = {res.error_norm:.2e})")
    return res.q


__all__ = ["LegTargets", "LowerBodyIK", "ProposedWholeBodyIK", "FullBodyLMIK", "StepResult",
           "lowered_initial_posture", "measure_errors", "as_position", "as_rotation", "as_joints"]
