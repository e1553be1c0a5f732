"""Whole-body IK of the dissertation (Sec. 4.3, Algorithm 3) and the full-body LM baseline.

:class:`LowerBodyIK` -- Algorithm 3 (its own module, ``dual_arm/lower_body_ik.py``; its
names are re-exported here).

:class:`ProposedWholeBodyIK` -- one control step of the proposed method (Fig. 8): chest
angles set, Algorithm 3 for the legs, then the closed-form IK of both arms
(``robot.limb_ik``) from the resulting ``CHEST_LINK1`` pose. By default both parts run
compiled: the legs by :class:`~humanoid_reach_ros.dual_arm.fast_legs.ClosedFormLowerBodyIK`
(Algorithm 3's 12 equations solved as closed-form legs + a 3-D Newton on the waist
position -- a named reformulation with the same solution, falling back to
:class:`LowerBodyIK` whenever it fails), the arms of the hand-derived 6-DOF arm pattern
(``LimbIK`` of kind ``arm``, e.g. HRP-2's) by
:class:`~humanoid_reach_ros.kinematics.hand_derived_compiled.CompiledArmIK` (numba twin of the closed-form
arm IK). Every other arm goes through the limb protocol (``LimbIKSet``, numpy; CompiledArmIK
covers only the hand-derived pattern): a general 6R chain (``GeneralLimb`` of kind
``general``) through its ``solve``; a 7-DOF arm (kind ``redundant``, e.g. Talos's) through
its ``solve`` (``RedundantLimbIK``: the first joint on a grid over its range) where a
configuration is looked for from afar (``step(..., tracking=False)``: the controller's
final-configuration check), and through
:class:`~humanoid_reach_ros.kinematics.redundant_tracker.RedundantArmTracker` (the first joint moved
at most its velocity limit times ``period_s`` per step, away from the joint limits) in the
steps of a motion, where the grid's jumps between first-joint values would be unbounded
accelerations. An arm that no closed form solves (kind ``numerical``, e.g. the Unitree G1's
7-joint arms, whose axes miss each other by millimetres) goes, in the steps of a motion,
through :class:`~humanoid_reach_ros.kinematics.numerical_ik.NumericalLimbTracker` (one
compiled damped least-squares iteration from the previous step's angles -- a named
simplification: local, the self-motion the damped minimal-norm steps give) and, for a
configuration looked for from afar, through the protocol's ``solve`` (with restarts); legs of
that kind run inside the compiled lower body by the same iteration
(``dual_arm/fast_legs.py``). ``closed_form_legs=False, compiled_arms=False`` gives the
reference path; the tests check both agree.

:class:`FullBodyLMIK` -- the conventional method of Sec. 5.2 (Table 2): one LM
(Sugihara, ref. [24]) on legs + chest + arms (26 joints on HRP-2, 28 with 7-joint arms) with 24 task rows (both hands'
poses, CoM, torso orientation, swing sole pose), the support sole fixed the same way.

No rclpy here.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from humanoid_reach_ros.dual_arm.fast_legs import ClosedFormLowerBodyIK
from humanoid_reach_ros.dual_arm.targets import (
    HandTargets, as_joints, as_position, as_rotation, pose_error, rot_error, spd_solve,
)
from humanoid_reach_ros.dual_arm.lower_body_ik import (
    LegTargets, LowerBodyIK, LowerBodyResult, _FloatingKinematics, lowered_initial_posture,
)
from humanoid_reach_ros.kinematics import IKReason, LimbIKSet
from humanoid_reach_ros.robot.model import N_BASE_Q, N_BASE_V, RobotModel


@dataclass(frozen=True, eq=False)
class WholeBodyStep:
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
                 compiled_arms: bool = True, period_s: float = 0.005, **lower_kw) -> None:
        self.robot = robot
        self.lower = LowerBodyIK(robot, support, **lower_kw)
        if closed_form_legs:      # same solution, compiled (dual_arm/fast_legs.py); falls back to LowerBodyIK
            self.lower = ClosedFormLowerBodyIK(robot, support, tol=self.lower.tol, max_iter=self.lower.max_iter,
                                               reference=self.lower)
        self.limb_ik = LimbIKSet(robot)
        self.chest_pitch = N_BASE_Q + robot.joint_index[robot.spec.chest_pitch]
        self.chest_yaw = N_BASE_Q + robot.joint_index[robot.spec.chest_yaw]
        self.arm_cols = {s: N_BASE_Q + np.array(robot.limbs[f"{s}_arm"].joint_index) for s in ("right", "left")}
        self.fid_chest = robot.frame_id(robot.limbs["right_arm"].root)
        self.fid_hand = {s: robot.frame_id(robot.limbs[f"{s}_arm"].tip) for s in ("right", "left")}
        #: side -> CompiledArmIK, or None: the limb protocol's solve (module docstring)
        self.arm_ik = {"right": None, "left": None}
        if compiled_arms:         # numba twin of the closed-form arm IK (kinematics/hand_derived_compiled.py)
            from humanoid_reach_ros.kinematics import CompiledArmIK
            for s in self.arm_ik:
                if CompiledArmIK.supports(self.limb_ik[f"{s}_arm"]):
                    self.arm_ik[s] = CompiledArmIK(self.limb_ik[f"{s}_arm"])
        #: side -> RedundantArmTracker for a 7-DOF arm of the closed form, NumericalLimbTracker for an
        #: arm of the numerical kind (the steps of a motion; module docstring)
        self.arm_track = {}
        for s in ("right", "left"):
            limb = self.limb_ik[f"{s}_arm"]
            if getattr(limb, "kind", "") == "redundant":
                from humanoid_reach_ros.kinematics import RedundantArmTracker
                first = N_BASE_V + robot.joint_index[limb.joint_names[0]]
                self.arm_track[s] = RedundantArmTracker(limb, float(robot.model.velocityLimit[first]) * period_s)
            elif getattr(limb, "kind", "") == "numerical":
                from humanoid_reach_ros.kinematics import NumericalLimbTracker
                self.arm_track[s] = NumericalLimbTracker(limb)
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
             legs: LegTargets, sole_world: pin.SE3, measure: bool = True, tracking: bool = True) -> WholeBodyStep:
        """One control step; ``measure=False`` skips the error bookkeeping (errors NaN)
        so that timing covers the method only (:func:`measure_errors` afterwards).
        ``tracking=False``: a 7-DOF arm's self-motion searched over its whole range (a
        configuration looked for from afar, not a step of a motion; module docstring)."""
        q = np.array(q_prev, dtype=float)
        q[self.chest_pitch], q[self.chest_yaw] = chest_pitch_yaw
        q[self.chest_pitch] = np.clip(q[self.chest_pitch], *self._lim(self.robot.spec.chest_pitch))
        q[self.chest_yaw] = np.clip(q[self.chest_yaw], *self._lim(self.robot.spec.chest_yaw))
        low = self.lower.solve(q, legs, sole_world)
        q = low.q
        C = self.lower.data.oMf[self.fid_chest]          # FK of low.q (LowerBodyIK.solve)
        reasons = []
        if not low.converged:
            reasons.append(f"lower body: |e| = {low.error_norm:.2e} after {low.iterations} iterations")
        for side, p, R in (("right", hands.p_right, hands.R_right), ("left", hands.p_left, hands.R_left)):
            cols = self.arm_cols[side]
            if self.arm_ik[side] is not None:
                code, qa = self.arm_ik[side].solve(C.translation, C.rotation, p, R, q[cols])
            elif tracking and side in self.arm_track:
                code, qa = self.arm_track[side].solve(C.translation, C.rotation, p, R, q[cols])
            else:
                res = self.limb_ik[f"{side}_arm"].solve(C.translation, C.rotation, p, R, q[cols])
                code, qa = int(res.reason[0]), res.q[0]
            if code == 0:
                q[cols] = qa
            else:
                reasons.append(f"{side} arm: {IKReason(code).name}")
        herr, cerr = measure_errors(self.robot, self.lower.data, q, hands, legs) if measure else (np.nan, np.nan)
        return WholeBodyStep(q, not reasons, "; ".join(reasons), herr, cerr, low.iterations)

    def _lim(self, joint: str) -> tuple[float, float]:
        i = self.robot.joint_index[joint]
        return float(self.robot.lower[i]), float(self.robot.upper[i])


class FullBodyLMIK(_FloatingKinematics):
    """Conventional full-body numerical IK (Sec. 5.2.1): LM on legs + chest + arms."""

    def __init__(self, robot: RobotModel, support: str = "right", tol: float = 1e-7,
                 max_iter: int = 100, omega: float = 1.0, w_bar: float = 1e-3) -> None:
        super().__init__(robot, support)
        chest = [robot.joint_index[j] for j in robot.spec.chest_joints]
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
             sole_world: pin.SE3, measure: bool = True) -> WholeBodyStep:
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
        return WholeBodyStep(q, converged, reason, herr, cerr, it)


def measure_errors(robot: RobotModel, data: pin.Data, q: np.ndarray, hands: HandTargets,
                   legs: LegTargets) -> tuple[float, float]:
    """``(|(e_right, e_left)|, |p_CoM - p*_CoM|)`` at ``q``: hand position error norm and
    CoM error [m]."""
    pin.framesForwardKinematics(robot.model, data, q)
    er = data.oMf[robot.frame_id(robot.limbs["right_arm"].tip)].translation - hands.p_right
    el = data.oMf[robot.frame_id(robot.limbs["left_arm"].tip)].translation - hands.p_left
    com = pin.centerOfMass(robot.model, data, q)
    return float(np.hypot(np.linalg.norm(er), np.linalg.norm(el))), float(np.linalg.norm(com - legs.p_com))


__all__ = ["LegTargets", "LowerBodyIK", "LowerBodyResult", "ProposedWholeBodyIK", "FullBodyLMIK", "WholeBodyStep",
           "lowered_initial_posture", "measure_errors", "as_position", "as_rotation", "as_joints"]
