"""Real-time dual-arm whole-body reaching controller (dissertation Sec. 4.5, Fig. 7-8, 5.3-5.4).

Per control step (period 5 ms) the controller (Fig. 8 data flow):

1. interpolates both hand targets from the reference at the time the targets arrived:
   positions linearly (straight line), orientations by Rodrigues
   ``R(s) = R_0 exp(s LN(R_0^T R*))`` (Sec. 3.4 / 4.5.2), with the step count ``n`` chosen
   so that neither hand nor the CoM moves faster than ``max_speed_mps`` = 0.38 m/s
   (Sec. 5.2.1). **Time scaling (named deviation):** the dissertation advances ``s``
   uniformly (``s = k / n``); a uniform ``s`` starts and stops at full speed, i.e. with an
   unbounded acceleration that puts the inverse-dynamics ZMP far outside the feet for one
   step (the dissertation's ZMP plots are moving-average filtered). We use the minimum-jerk
   profile ``s = 10 tau^3 - 15 tau^4 + 6 tau^5``, ``tau = k / n``, on the same straight
   line / Rodrigues path; its peak speed is 15/8 of the mean, so ``n`` is 15/8 times the
   uniform count and 0.38 m/s remains the maximum speed;
2. interpolates the chest angles from their value at target arrival to the torso
   regression's output, evaluated **once per target pair** (Sec. 4.5.3: "we use the
   regression once ... and interpolate the results");
3. interpolates the CoM from its reference at target arrival to the eq. 6 candidate;
4. solves Algorithm 3 for the legs (support sole fixed, waist upright, swing sole at its
   stance pose) and the closed-form IK of both arms from the resulting chest pose.

The regression input is the hand positions minus the eq. 6 CoM shift: the regression was
trained at the initial torso height (Sec. 4.1) and the workspace moves with the CoM (Fig. 6).

Modes: *follow targets* -- :meth:`set_targets` at any time re-plans from the current
reference (e.g. from AR markers, Sec. 5.3); *sequential random targets* --
:meth:`start_sequential` draws target pairs in the workspace (:meth:`sample_reachable`), the next one
as soon as the previous is reached (Sec. 5.4). A step never returns NaN angles.

Failure handling (not in the dissertation, which interpolates blindly): before moving, the
path is solved at ``path_checks`` (40) evenly spaced points and an unreachable pair is
refused with the reason; a step that still fails between those points (an arm target out
of reach or the legs not converging) holds the whole previous configuration, ends the
motion and reports ``ok = False`` with the reason -- it never moves on and later jumps.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from humanoid_reach_ros.dual_arm.com_target import ComTarget, ComTargetSelector
from humanoid_reach_ros.dual_arm.targets import HandTargets, rodrigues_interpolate
from humanoid_reach_ros.dual_arm.torso_regression import ReachWorkspace, TorsoRegression
from humanoid_reach_ros.dual_arm.whole_body_ik import LegTargets, ProposedWholeBodyIK
from humanoid_reach_ros.robot.model import N_BASE_Q, RobotModel


#: peak / mean speed of the minimum-jerk profile
PEAK_SPEED_RATIO = 15.0 / 8.0


def min_jerk(tau: float) -> float:
    """``s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5`` (0 -> 1 with zero velocity and
    acceleration at both ends); ``ds/dtau`` peaks at 15/8 for ``tau = 1/2``."""
    tau = min(max(tau, 0.0), 1.0)
    return tau * tau * tau * (10.0 + tau * (-15.0 + 6.0 * tau))


@dataclass(frozen=True)
class ControllerConfig:
    period_s: float = 0.005
    max_speed_mps: float = 0.38
    support: str = "right"
    #: path points solved at planning time (feasibility check, see set_targets); 40 costs
    #: about 5 ms per pair (12 ms max) and, on the bench's 729 pairs, left no executed pair
    #: failing between the points (10 left three)
    path_checks: int = 40

    def __post_init__(self) -> None:
        if not (math.isfinite(self.period_s) and self.period_s > 0):
            raise ValueError(f"period_s must be > 0, got {self.period_s}")
        if not (math.isfinite(self.max_speed_mps) and self.max_speed_mps > 0):
            raise ValueError(f"max_speed_mps must be > 0, got {self.max_speed_mps}")
        if self.path_checks < 1:
            raise ValueError(f"path_checks must be >= 1, got {self.path_checks}")
        if self.support not in ("right", "left"):
            raise ValueError(f"support must be 'right' or 'left', got {self.support!r}")


@dataclass(frozen=True, eq=False)
class ReachPlan:
    """What :meth:`DualArmReachController.set_targets` decided for one target pair."""

    targets: HandTargets
    com: ComTarget
    chest_target: np.ndarray        # (pitch, yaw) [rad] from the regression
    n_steps: int
    feasible: bool = True           # the path was solved at the check points
    reason: str = ""                # why not, when not feasible


@dataclass(frozen=True, eq=False)
class ControlStep:
    """One 5 ms step: ``joints`` (the robot's joints, model order), ``q`` (nq), progress ``s``, ``done``
    (the last interpolation step of the current target), ``ok`` / ``reason``, errors of the
    hands w.r.t. the step's reference and of the CoM [m], the reference CoM."""

    joints: np.ndarray
    q: np.ndarray
    s: float
    done: bool
    ok: bool
    reason: str
    hand_error: float
    com_error: float
    com_ref: np.ndarray
    hands: HandTargets | None = None


class DualArmReachController:
    """The proposed whole-body controller (ROS-free; the executor node wraps it). By default
    the workspace is the robot description's ``dual_arm_workspace`` and the regression its
    ``torso_regression`` (the model trained on that workspace)."""

    def __init__(self, robot: RobotModel | None = None, regression: TorsoRegression | None = None,
                 workspace: ReachWorkspace | None = None, config: ControllerConfig = ControllerConfig()) -> None:
        self.robot = RobotModel() if robot is None else robot
        self.ws = ReachWorkspace.for_robot(self.robot) if workspace is None else workspace
        self.regression = TorsoRegression.load(self.robot.spec.torso_regression) if regression is None else regression
        self.config = config
        self.q_init = self.ws.initial_posture(self.robot)
        self.ik = ProposedWholeBodyIK(self.robot, config.support, period_s=config.period_s)
        self.selector = ComTargetSelector(self.robot, self.q_init, self.ws.com_offset_m, self.ik.limb_ik)
        soles = self.robot.stance_soles
        self.sole_support, self.sole_swing = (soles if config.support == "right" else soles[::-1])
        self._d = self.robot.model.createData()
        #: R*_torso of Algorithm 3: the waist keeps its initial (upright) orientation
        self.R_torso = RobotModel.base_pose(self.q_init).rotation.copy()
        self._fid = {s: self.robot.frame_id(self.robot.limbs[f"{s}_arm"].tip) for s in ("right", "left")}
        self._chest_cols = (N_BASE_Q + self.robot.joint_index[self.robot.spec.chest_pitch],
                            N_BASE_Q + self.robot.joint_index[self.robot.spec.chest_yaw])
        self._seq: tuple[np.ndarray, np.ndarray] | None = None     # sequential mode's target pairs
        self._remaining = 0
        self.reset()

    # ------------------------------------------------------------ state
    def reset(self, q: np.ndarray | None = None) -> None:
        """Back to the initial posture (or ``q``), no target. Any configuration with the
        support sole at its stance pose (e.g. the executor node's last command) is a valid
        start: the next :meth:`set_targets` interpolates hands, CoM and chest from it."""
        q = self.q_init if q is None else np.asarray(q, float)
        if q.shape != (self.robot.model.nq,) or not np.all(np.isfinite(q)):
            raise ValueError(f"q must be a finite ({self.robot.model.nq},) configuration")
        self.q = q.copy()
        self._hold_references()
        self.plan: ReachPlan | None = None
        self._k = 0
        self._start = None
        self._brake: tuple[int, float, float, int] | None = None
        self._seq = None
        self._remaining = 0

    _STATE = ("q", "_ref", "_com_ref", "_chest_ref", "plan", "_k", "_start", "_brake", "_seq", "_remaining")

    def save_state(self) -> dict:
        """A snapshot of the controller's state (the node restores it when a new target
        pair turns out infeasible, so that the running motion can be braked smoothly).
        The attributes are replaced, never mutated in place, so a shallow copy suffices."""
        return {k: getattr(self, k) for k in self._STATE}

    def restore_state(self, state: dict) -> None:
        """Back to a :meth:`save_state` snapshot."""
        for k in self._STATE:
            setattr(self, k, state[k])

    @property
    def joints(self) -> np.ndarray:
        return self.q[N_BASE_Q:].copy()

    @property
    def busy(self) -> bool:
        return self.plan is not None and self._k < self.plan.n_steps

    @property
    def sequential_remaining(self) -> int:
        """Random target pairs still to come in sequential mode (0 otherwise)."""
        return self._remaining if self._seq is not None else 0

    @property
    def start_reference(self) -> tuple:
        """(right hand SE3, left hand SE3, CoM, chest) at the arrival of the current targets."""
        return self._start

    # ------------------------------------------------------------ targets
    def set_targets(self, p_right, R_right, p_left, R_left) -> ReachPlan:
        """Follow-targets mode: plan the interpolation from the current reference to the
        new hand poses (``ValueError`` on NaN / wrong shapes / non-rotations). The path is
        checked at ``config.path_checks`` points; an infeasible pair gives a plan with
        ``feasible = False`` and a reason, and the controller holds its posture."""
        t = HandTargets.make(p_right, R_right, p_left, R_left)
        com, chest = self._com_and_chest(t)
        start = (self._ref["right"].copy(), self._ref["left"].copy(), self._com_ref.copy(), self._chest_ref.copy())
        dist = max(np.linalg.norm(t.p_right - start[0].translation), np.linalg.norm(t.p_left - start[1].translation),
                   np.linalg.norm(com.p_com - start[2]))
        n = max(1, math.ceil(PEAK_SPEED_RATIO * dist / (self.config.max_speed_mps * self.config.period_s) - 1e-9))
        self.plan = ReachPlan(t, com, chest, n)
        self._start = start
        self._brake = None
        ok, reason = self._check_path()
        self.plan = ReachPlan(t, com, chest, n, ok, reason)
        self._k = 0
        return self.plan

    def brake(self, duration_s: float) -> int:
        """Smooth stop on the current path (the executor node's cancel / preempt; not in
        the dissertation): from step ``k`` the path parameter keeps its current per-step
        increment ``v = s(k+1) - s(k)`` and decays it linearly to zero over
        ``m = ceil(duration_s / period)`` steps, ``s(k + j) = s(k) + v (j - j^2 / 2m)``,
        stopping at ``s(k) + v m / 2`` short of the target (the hands, CoM and chest stop
        on their straight-line / Rodrigues references). If the minimum-jerk profile would
        stop sooner (near its end) it is kept. Sequential targets are dropped. Returns the
        steps left until the stop (0 when idle)."""
        self._seq, self._remaining = None, 0
        plan = self.plan
        if plan is None or not plan.feasible or self._k >= plan.n_steps:
            return 0
        k, n = self._k, plan.n_steps
        m = max(1, math.ceil(duration_s / self.config.period_s - 1e-9))
        if m >= n - k:
            return n - k
        s0 = self._s(k)
        v = self._s(k + 1) - s0
        if s0 + 0.5 * v * m >= 1.0:
            return n - k
        self._brake = (k, s0, v, m)
        self.plan = dataclasses.replace(plan, n_steps=k + m)
        return m

    def _s(self, k: int) -> float:
        """Path parameter of step ``k``: minimum jerk, or the braking profile (:meth:`brake`)."""
        if self._brake is not None and k >= self._brake[0]:
            k0, s0, v, m = self._brake
            j = min(k - k0, m)
            return s0 + v * (j - j * j / (2.0 * m))
        return min_jerk(k / self.plan.n_steps)

    def _check_path(self) -> tuple[bool, str]:
        """Solve the plan at ``path_checks`` evenly spaced points of the path (warm-started
        one from the other, like the motion itself): a pair whose path leaves the
        reachable set is refused before moving instead of failing half-way."""
        q = self.q
        n = self.plan.n_steps
        for j in range(1, self.config.path_checks + 1):
            k = max(1, round(j * n / self.config.path_checks))
            hands, com_ref, chest = self.reference_at(k)
            res = self.ik.step(q, hands, chest, self.leg_targets(com_ref), self.sole_support, measure=False)
            if not res.ok:
                return False, f"target pair unreachable at {100.0 * k / n:.0f}% of the path: {res.reason}"
            q = res.q
        return True, ""

    def reference_at(self, k: int) -> tuple[HandTargets, np.ndarray, np.ndarray]:
        """References of step ``k`` (1..n) of the current plan: hand targets, CoM, chest."""
        plan = self.plan
        if plan is None:
            raise ValueError("no target pair set")
        s = self._s(k)
        r0, l0, c0, ch0 = self._start
        t = plan.targets
        hands = HandTargets(r0.translation + s * (t.p_right - r0.translation),
                            rodrigues_interpolate(r0.rotation, t.R_right, s),
                            l0.translation + s * (t.p_left - l0.translation),
                            rodrigues_interpolate(l0.rotation, t.R_left, s))
        return hands, c0 + s * (plan.com.p_com - c0), ch0 + s * (plan.chest_target - ch0)

    def _com_and_chest(self, t: HandTargets) -> tuple[ComTarget, np.ndarray]:
        """eq. 6 CoM candidate and the regression's chest angles for hand targets ``t`` (the
        regression input is the hands minus the CoM shift, see the module docstring)."""
        com = self.selector.select(t)
        return com, self.regression.predict(t.p_right - com.shift, t.p_left - com.shift)

    def final_configuration(self, t: HandTargets):
        """The whole-body configuration at the end of a reach to ``t`` from the initial
        posture (eq. 6 CoM candidate, regression chest, Algorithm 3 + closed-form arms):
        an ``ik.step`` result whose ``ok`` says whether the pair can be held at all."""
        com, chest = self._com_and_chest(t)
        return self.ik.step(self.q_init, t, chest, self.leg_targets(com.p_com), self.sole_support, measure=False,
                            tracking=False)

    def sample_reachable(self, rng: np.random.Generator, n: int,
                         max_draws: int = 100000) -> tuple[np.ndarray, np.ndarray]:
        """``n`` right and ``n`` left hand target positions, uniform in the workspace boxes
        and each kept only if this method *reaches* it: the symmetric pair it forms with
        its own mirror image in the sagittal plane (``y -> -y``, the other hand's target)
        is planned from the initial posture and its path is feasible (:meth:`set_targets`).
        This is our reading of "random target poses in the workspace, as shown in
        Figure 5" (Sec. 5.2.3; Figures 5 and 6 show the postures and the movable areas of
        the method); the dissertation does not say how it drew them. About 40-45% of the
        uniform draws are kept for the HRP-2-class model (wrist +-92 deg, elbow and
        shoulder limits); pairs of independently drawn hands can still be jointly
        unreachable (the chest is shared). The controller's state is left as it was.
        ``ValueError`` if ``max_draws`` uniform draws per hand do not give ``n``."""
        if n < 0:
            raise ValueError(f"n must be >= 0, got {n}")
        saved = self.save_state()
        out = {}
        try:
            for side in ("right", "left"):
                kept, draws = [], 0
                while len(kept) < n:
                    if draws >= max_draws:
                        raise ValueError(f"only {len(kept)} reachable {side} hand targets in {max_draws} draws")
                    draws += 1
                    pr, pl = self.ws.sample(rng, 1)
                    p = pr[0] if side == "right" else pl[0]
                    m = p * np.array([1.0, -1.0, 1.0])
                    t = self.ws.targets(p, m) if side == "right" else self.ws.targets(m, p)
                    self.reset()
                    if self.set_targets(t.p_right, t.R_right, t.p_left, t.R_left).feasible:
                        kept.append(p)
                out[side] = np.array(kept).reshape(-1, 3)
        finally:
            self.restore_state(saved)
        return out["right"], out["left"]

    def start_sequential(self, count: int, seed: int = 0, pairs: tuple | None = None) -> ReachPlan:
        """Sequential-random-targets mode (Sec. 5.4): ``count`` pairs, each hand's target
        drawn by :meth:`sample_reachable` with ``seed`` (all drawn here, about 30 ms per pair,
        so that the control steps that chain them stay short) or given as ``pairs`` =
        ``(PR, PL)`` (``count`` x 3 each, e.g. drawn by another thread), reached one after
        the other."""
        if count < 1:
            raise ValueError(f"count must be >= 1, got {count}")
        if pairs is None:
            pairs = self.sample_reachable(np.random.default_rng(seed), count)
        PR, PL = (np.asarray(a, float) for a in pairs)
        if (PR.shape != (count, 3) or PL.shape != (count, 3)
                or not (np.all(np.isfinite(PR)) and np.all(np.isfinite(PL)))):
            raise ValueError(f"pairs must be two finite ({count}, 3) arrays")
        self._seq = (PR, PL)
        self._remaining = count
        return self._next_random()

    def _next_random(self) -> ReachPlan:
        assert self._seq is not None
        PR, PL = self._seq
        i = len(PR) - self._remaining
        self._remaining -= 1
        t = self.ws.targets(PR[i], PL[i])
        return self.set_targets(t.p_right, t.R_right, t.p_left, t.R_left)

    # ------------------------------------------------------------ control step
    def step(self, measure: bool = True) -> ControlStep:
        """One control step (module docstring). Without a target the posture is held.
        ``measure=False`` leaves the error fields NaN (timing of the method alone)."""
        if self.plan is None:
            return self._hold()
        if self._k >= self.plan.n_steps:
            if self._seq is not None and self._remaining > 0:
                self._next_random()
            else:
                return self._hold()
        plan = self.plan
        if not plan.feasible:               # clear failure, posture held
            step = self._hold()
            self._k = plan.n_steps
            return ControlStep(step.joints, step.q, 1.0, True, False, plan.reason, np.nan, np.nan, step.com_ref)
        self._k += 1
        s = self._s(self._k)
        hands, com_ref, chest = self.reference_at(self._k)
        legs = self.leg_targets(com_ref)
        res = self.ik.step(self.q, hands, chest, legs, self.sole_support, measure)
        if np.all(np.isfinite(res.q)):
            ok, reason = res.ok, res.reason
        else:               # never hand out NaN
            ok, reason = False, "non-finite IK output"
        if ok:
            self.q = res.q
            self._ref = {"right": pin.SE3(hands.R_right, hands.p_right), "left": pin.SE3(hands.R_left, hands.p_left)}
            self._com_ref = com_ref
            self._chest_ref = chest
        else:
            # a part failed between the planning check points: the whole previous
            # configuration is held (legs and arms never move apart, and the motion never
            # resumes with a jump when the part becomes solvable again), the motion ends
            # here and the references restart from what the robot holds.
            reason = f"{reason}; stopped at {100.0 * s:.0f}% of the path, posture held"
            self._k = plan.n_steps
            self._hold_references()
        return ControlStep(self.joints, self.q.copy(), s, self._k >= plan.n_steps, ok, reason,
                           res.hand_error, res.com_error, com_ref if ok else self._com_ref.copy(), hands)

    def _hold_references(self) -> None:
        """Hand, CoM and chest references := those of the configuration held (``self.q``)."""
        pin.framesForwardKinematics(self.robot.model, self._d, self.q)
        self._ref = {s: self._d.oMf[self._fid[s]].copy() for s in ("right", "left")}
        self._com_ref = pin.centerOfMass(self.robot.model, self._d, self.q).copy()
        self._chest_ref = np.array([self.q[c] for c in self._chest_cols])

    def leg_targets(self, com_ref: np.ndarray) -> LegTargets:
        """Algorithm 3 targets: CoM reference, upright waist, swing sole at its stance pose."""
        return LegTargets(com_ref, self.R_torso, self.sole_swing.translation, self.sole_swing.rotation)

    def _hold(self) -> ControlStep:
        return ControlStep(self.joints, self.q.copy(), 1.0, True, True, "", 0.0, 0.0, self._com_ref.copy())

    def run(self, max_steps: int = 100000) -> list[ControlStep]:
        """Step until the current target (and any sequential ones) is reached."""
        out = []
        while (self.busy or (self._seq is not None and self._remaining > 0)) and len(out) < max_steps:
            out.append(self.step())
        return out
