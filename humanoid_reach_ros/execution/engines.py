"""The two solvers the supervisor drives, behind one interface.

* :class:`TrajectoryEngine`: the prioritized whole-body IK of Kanehiro et al. Sec. IV
  (``control/executor.py``) tracking a planned joint trajectory with one hand;
* :class:`DualArmEngine`: the real-time dual-arm whole-body reaching controller of the
  dissertation (``dual_arm/controller.py``: torso regression, eq. 6 CoM, Algorithm 3 legs +
  closed-form arms) to two hand targets.

Both answer ``start(q0, motion)``, ``step(t)`` -> :class:`StepOutcome`, ``stop()`` (the
executor's hold mode / braking the dual-arm motion on its path) and ``settled``.

Dual-arm metrics (named simplifications): the controller works in free space (no collision
avoidance, as the dissertation's experiments), so ``min_distance_m = inf``; ``com_error_m``
is the horizontal distance of the commanded CoM from the controller's CoM reference of the
step, ``hand_error_m`` / ``hand_error_rad`` the larger hand error w.r.t. the step's
interpolated hand references.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import pinocchio as pin

from humanoid_reach_ros.control.executor import StepMetrics, WholeBodyExecutor
from humanoid_reach_ros.dual_arm.controller import ControlStep, DualArmReachController
from humanoid_reach_ros.robot.model import RobotModel


@dataclass(frozen=True)
class DualArmMetrics:
    """One step of the dual-arm controller in the field names of the executor's ``StepMetrics``
    (what ``io/exec_msgs.executor_metrics`` and the action feedback read)."""

    t: float
    progress: float
    solve_time_s: float
    com_error_m: float
    hand_error_m: float
    hand_error_rad: float
    ik_time_s: float = 0.0
    distance_time_s: float = 0.0
    spheres_in_bound: int = 0
    active_constraints: int = 0
    active_levels: int = 0
    level_slack: tuple[float, ...] = ()
    min_distance_m: float = float("inf")


@dataclass(frozen=True, eq=False)
class StepOutcome:
    """One computed step: the full configuration, the 30 joints to command, its metrics."""

    q: np.ndarray
    joints: np.ndarray
    metrics: Any                # StepMetrics | DualArmMetrics
    done: bool                  # the motion is over (sequential: the last pair's last step)
    ok: bool = True             # False: the dual-arm step failed (the posture is held)
    reason: str = ""
    pair_done: bool = False     # dual arm, sequential: the last step of one target pair


@dataclass(frozen=True)
class DualPlan:
    feasible: bool
    reason: str
    note: str


class TrajectoryEngine:
    """The whole-body executor tracking ``motion.spline`` with the hand of ``motion.arm``."""

    name = "executor"

    def __init__(self, executor: WholeBodyExecutor) -> None:
        self.executor = executor

    def start(self, q0: np.ndarray, motion) -> None:
        self.executor.start(q0, motion.spline, motion.arm, motion.params)

    def step(self, t: float | None) -> StepOutcome:
        r = self.executor.step(t)
        return StepOutcome(r.q, r.joints, r.metrics, r.done)

    def stop(self, brake_s: float) -> None:
        self.executor.hold()

    def set_environment(self, tree) -> None:
        self.executor.set_environment(tree)

    @property
    def converge_position_m(self) -> float:
        return self.executor.params.converge_position_m


class DualArmEngine:
    """The dual-arm controller; its own pinocchio data for the metrics."""

    name = "dual"

    def __init__(self, controller: DualArmReachController, robot: RobotModel) -> None:
        self.ctl = controller
        self.robot = robot
        self._data = robot.model.createData()
        self._fid_hand = {s: robot.frame_id(robot.limbs[f"{s}_arm"].tip) for s in ("right", "left")}
        self.targets: tuple[pin.SE3, pin.SE3] | None = None   # of the last started motion (None: stopped short)

    def start(self, q0: np.ndarray, motion, was_running: bool) -> DualPlan:
        """Plan the motion's target pair (or sequential pairs) from ``q0``. Infeasible: the
        controller's previous state is restored and the plan says why."""
        ctl = self.ctl
        saved = ctl.save_state()
        t0 = time.perf_counter()
        try:
            if not was_running or not np.array_equal(ctl.q, q0):
                ctl.reset(q0)
            if motion.sequential is not None:
                plan = ctl.start_sequential(*motion.sequential)
                feasible, reason = True, ""          # infeasible random pairs are skipped, not refused
            else:
                r, l_ = motion.targets
                plan = ctl.set_targets(r.translation, r.rotation, l_.translation, l_.rotation)
                feasible, reason = plan.feasible, plan.reason
        except Exception as exc:   # e.g. a target the controller refuses as a value
            plan, feasible, reason = None, False, f"{type(exc).__name__}: {exc}"
        plan_s = time.perf_counter() - t0
        if not feasible:
            ctl.restore_state(saved)
            return DualPlan(False, reason, "")
        self.targets = motion.targets
        if motion.sequential is not None:
            note = f"{motion.sequential[0]} random target pairs (seed {motion.sequential[1]})"
        else:
            note = (f"{plan.n_steps} steps, CoM candidate {plan.com.label!r}, chest target "
                    f"{np.round(plan.chest_target, 3).tolist()} rad, planned in {plan_s * 1e3:.0f} ms")
        return DualPlan(True, "", note)

    def step(self, t: float | None, steps_done: int = 0, last=None) -> StepOutcome:
        t0 = time.perf_counter()
        st: ControlStep = self.ctl.step(measure=False)
        solve_s = time.perf_counter() - t0
        m, d = self.robot.model, self._data
        pin.framesForwardKinematics(m, d, st.q)
        com = pin.centerOfMass(m, d, st.q, False)
        com_err = float(np.linalg.norm(com[:2] - st.com_ref[:2]))
        e_p, e_r = 0.0, 0.0
        hands = st.hands
        if hands is not None:
            for side, p, Rt in (("right", hands.p_right, hands.R_right), ("left", hands.p_left, hands.R_left)):
                M = d.oMf[self._fid_hand[side]]
                e_p = max(e_p, float(np.linalg.norm(M.translation - p)))
                e_r = max(e_r, float(np.linalg.norm(pin.log3(M.rotation.T @ Rt))))
        elif last is not None:
            e_p, e_r = last.hand_error_m, last.hand_error_rad
        tt = (steps_done + 1) * self.ctl.config.period_s
        metrics = DualArmMetrics(tt, float(st.s), solve_s, com_err, e_p, e_r, ik_time_s=solve_s)
        final = bool(st.done) and self.ctl.sequential_remaining == 0
        return StepOutcome(st.q, st.joints, metrics, final, bool(st.ok), st.reason, bool(st.done))

    def stop(self, brake_s: float) -> None:
        self.ctl.brake(brake_s)
        self.targets = None       # stopped short: the same targets again must restart

    @property
    def busy(self) -> bool:
        return bool(self.ctl.busy)


__all__ = ["DualArmMetrics", "StepOutcome", "DualPlan", "TrajectoryEngine", "DualArmEngine", "StepMetrics"]
