"""The physics plant: a MuJoCo model stepped at a fixed timestep, position targets in, the
measured joints and floating base out.

:class:`PhysicsPlant` holds one ``MjData``. :meth:`~PhysicsPlant.set_targets` takes the
servos' joint targets (clipped into the joints' ranges, the actuators' control range);
:meth:`~PhysicsPlant.advance` simulates a span of time in whole timesteps, carrying the
remainder to the next call, so that a caller ticking every 5 ms on the wall clock (the joint
driver's loop) keeps simulated time on its own; :meth:`~PhysicsPlant.run` simulates a span
either as fast as it can (tests, benches) or paced by the wall clock (``pace=True``: after
each chunk it waits until the wall clock has caught up with simulated time).

Timing (:class:`PlantTiming`): simulated time, the wall time since the first step, the time
spent stepping, and this thread's CPU time while stepping (``time.thread_time``), hence
* ``real_time_factor``: simulated over wall time (paced: about 1 while the plant keeps up);
* ``capacity``: simulated time over the time spent stepping (how much faster than real time the
  plant could run);
* ``cpu_pct``: the plant's own CPU time over the wall time.

No ROS here.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import mujoco
import numpy as np
import pinocchio as pin

from humanoid_reach_ros.sim.physics.metrics import ContactMetrics, StandReference, contact_metrics, stand_reference
from humanoid_reach_ros.sim.physics.model_builder import PhysicsModel, base_pose_from_se3

#: simulated time per chunk of a paced :meth:`PhysicsPlant.run` [s]
PACE_CHUNK_S = 0.005


@dataclass(frozen=True)
class PlantTiming:
    """The plant's clock figures (module doc)."""

    steps: int
    sim_time_s: float
    wall_time_s: float
    stepping_s: float
    cpu_s: float

    @property
    def real_time_factor(self) -> float:
        return self.sim_time_s / self.wall_time_s if self.wall_time_s > 0 else 0.0

    @property
    def capacity(self) -> float:
        return self.sim_time_s / self.stepping_s if self.stepping_s > 0 else 0.0

    @property
    def cpu_pct(self) -> float:
        return 100.0 * self.cpu_s / self.wall_time_s if self.wall_time_s > 0 else 0.0

    @property
    def step_cost_us(self) -> float:
        return 1e6 * self.stepping_s / self.steps if self.steps else 0.0


class PhysicsPlant:
    """One simulated robot (module doc). ``joints`` (robot model order) and ``base`` give the
    start state (default: half-sitting standing in the stance frame); the servos' targets start
    at the start joints."""

    def __init__(self, pm: PhysicsModel, joints: np.ndarray | None = None, base: pin.SE3 | None = None) -> None:
        self.pm = pm
        self.model = pm.model
        self.data = mujoco.MjData(self.model)
        robot = pm.robot
        joints = np.array(robot.half_sitting_joints if joints is None else joints, float)
        if joints.shape != (robot.n_joints,):
            raise ValueError(f"start joints: expected {robot.n_joints} values, got shape {joints.shape}")
        base = robot.base_on_feet(joints) if base is None else base
        self.data.qpos[:7] = base_pose_from_se3(base)
        self.data.qpos[pm.qpos_adr] = joints
        self._lo = self.model.actuator_ctrlrange[pm.actuator_ids, 0].copy()
        self._hi = self.model.actuator_ctrlrange[pm.actuator_ids, 1].copy()
        # kv / kp of each servo (MuJoCo's position actuator: gain kp, bias -kp q - kv qdot): the shift of
        # the position target that turns its damping into damping of the velocity error (advance_ramped)
        kp = self.model.actuator_gainprm[pm.actuator_ids, 0]
        self._kv_over_kp = np.where(kp > 0.0, -self.model.actuator_biasprm[pm.actuator_ids, 2] / np.where(
            kp > 0.0, kp, 1.0), 0.0)
        self._target = np.zeros(robot.n_joints)
        self._offset = np.zeros(robot.n_joints)     # the corrections under the servos (advance_ramped)
        self.set_targets(joints)
        mujoco.mj_forward(self.model, self.data)
        self.reference: StandReference = stand_reference(pm, self.data)
        self._carry_s = 0.0
        self._steps = 0
        self._stepping_s = 0.0
        self._cpu_s = 0.0
        self._wall_start: float | None = None

    # ------------------------------------------------------------ in and out
    def set_targets(self, joints: np.ndarray) -> None:
        """The servos' position targets (robot model joint order), clipped into the joint ranges;
        held still (no velocity feed-forward)."""
        self._target = np.clip(joints, self._lo, self._hi)
        self.data.ctrl[self.pm.actuator_ids] = np.clip(self._target + self._offset, self._lo, self._hi)

    @property
    def targets(self) -> np.ndarray:
        """The commanded position targets (without the corrections under the servos and without the velocity
        feed-forward's shift)."""
        return self._target.copy()

    @property
    def servo_targets(self) -> np.ndarray:
        """What the servos track: the targets plus the corrections (``advance_ramped``'s offsets), in range."""
        return np.clip(self._target + self._offset, self._lo, self._hi)

    @property
    def joints(self) -> np.ndarray:
        """Measured joint angles [rad] (robot model order)."""
        return self.data.qpos[self.pm.qpos_adr].copy()

    @property
    def joint_velocities(self) -> np.ndarray:
        return self.data.qvel[self.pm.dof_adr].copy()

    @property
    def joint_torques(self) -> np.ndarray:
        """The servos' torques [N m] (after the force limits)."""
        return self.data.actuator_force[self.pm.actuator_ids].copy()

    @property
    def base_pose(self) -> pin.SE3:
        """The floating base's measured pose in the world (stance) frame."""
        x, y, z, qw, qx, qy, qz = self.data.qpos[:7]
        return pin.XYZQUATToSE3(np.array([x, y, z, qx, qy, qz, qw]))

    @property
    def sim_time_s(self) -> float:
        return float(self.data.time)

    def metrics(self) -> ContactMetrics:
        """Contact and balance figures of the current state (metrics.py); the base's drop is
        measured from where the measured joints hold it on the feet."""
        held = float(self.pm.robot.base_on_feet(self.joints).translation[2])
        return contact_metrics(self.pm, self.data, self.reference, held)

    def timing(self) -> PlantTiming:
        wall = 0.0 if self._wall_start is None else time.perf_counter() - self._wall_start
        return PlantTiming(self._steps, self.sim_time_s, wall, self._stepping_s, self._cpu_s)

    # ------------------------------------------------------------ stepping
    def step(self, n: int = 1) -> None:
        """``n`` timesteps."""
        if self._wall_start is None:
            self._wall_start = time.perf_counter()
        t0, c0 = time.perf_counter(), time.thread_time()
        for _ in range(n):
            mujoco.mj_step(self.model, self.data)
        self._stepping_s += time.perf_counter() - t0
        self._cpu_s += time.thread_time() - c0
        self._steps += n

    def advance(self, duration_s: float) -> int:
        """Simulate ``duration_s`` in whole timesteps (the remainder carried to the next call);
        returns the steps taken."""
        if not duration_s >= 0.0:
            raise ValueError(f"advance: duration must be >= 0 s, got {duration_s}")
        dt = self.pm.timestep_s
        total = self._carry_s + duration_s
        n = int(total / dt + 1e-9)
        self._carry_s = total - n * dt
        if n:
            self.step(n)
        return n

    def advance_ramped(self, targets: np.ndarray, duration_s: float, offsets: np.ndarray | None = None,
                       still: np.ndarray | None = None) -> int:
        """Simulate ``duration_s`` (as :meth:`advance`) with the servos' targets ramped linearly from
        the current ones to ``targets`` over its steps: the interpolator of a real joint controller
        (1 kHz under a 200 Hz command). A tick that came late (a loaded machine) moves the targets
        in as many small steps as it simulates, not in one jump.

        The servos track the ramp with **velocity feed-forward**: MuJoCo's position servo is
        ``tau = kp (q_ref - q) - kv qdot``, whose damping brakes any motion, so at a speed ``v`` it lags
        ``kv v / kp`` (HRP-2's torso, kv/kp 0.1 s: 0.1 rad behind a 1 rad/s gaze, enough to tip the
        robot onto one foot). Its target shifted by ``(kv/kp) v_ref`` makes it
        ``tau = kp (q_ref - q) + kv (v_ref - qdot)``: a PD on the tracking error, what a joint
        controller does.

        ``offsets`` (robot joint order [rad]): corrections of the targets by the controllers under the
        servos (sim/physics/force_guard.py), ramped from the previous tick's over the same steps but
        **without** velocity feed-forward: a correction that changes from tick to tick would otherwise be
        multiplied by ``kv / kp / dt`` (HRP-2's legs: 27 times) into torque kicks. ``still`` (bool per joint):
        joints whose servo target a correction holds still (the force guard's): no feed-forward of the
        command's speed either (it would push on at that speed). Returns the steps taken."""
        dt = self.pm.timestep_s
        total = self._carry_s + duration_s
        n = int(total / dt + 1e-9)
        goal = np.clip(np.asarray(targets, float), self._lo, self._hi)
        off_goal = self._offset if offsets is None else np.asarray(offsets, float)
        if off_goal.shape != goal.shape or not np.all(np.isfinite(off_goal)):
            raise ValueError(f"advance_ramped: offsets must be {goal.shape[0]} finite values, got {off_goal!r}")
        if n < 1:
            self._carry_s = total
            self._offset = off_goal.copy()
            self.set_targets(goal)
            return 0
        start, off_start = self._target, self._offset
        self._carry_s = total - n * dt
        v_ref = (goal - start) / (n * dt)
        shift = self._kv_over_kp * v_ref
        if still is not None:
            shift = np.where(np.asarray(still, bool), 0.0, shift)
        ids = self.pm.actuator_ids
        for k in range(1, n + 1):
            self._target = start + (k / n) * (goal - start)
            self._offset = off_start + (k / n) * (off_goal - off_start)
            self.data.ctrl[ids] = np.clip(self._target + self._offset, self._lo, self._hi) + shift
            self.step(1)
        return n

    def run(self, duration_s: float, pace: bool = False, stop_on_fall: bool = False) -> ContactMetrics | None:
        """Simulate ``duration_s``: as fast as possible, or paced by the wall clock (module doc).
        With ``stop_on_fall`` it checks every chunk and returns the metrics of the first fallen
        state (else None when the span ends)."""
        chunk = max(PACE_CHUNK_S, self.pm.timestep_s)
        start_wall, start_sim = time.perf_counter(), self.sim_time_s
        end = start_sim + duration_s
        while self.sim_time_s < end - 1e-9:
            self.advance(min(chunk, end - self.sim_time_s))
            if stop_on_fall:
                m = self.metrics()
                if m.fallen:
                    return m
            if pace:
                lag = (self.sim_time_s - start_sim) - (time.perf_counter() - start_wall)
                if lag > 0.0:
                    time.sleep(lag)     # the wall clock paces simulated time
        return None


__all__ = ["PACE_CHUNK_S", "PhysicsPlant", "PlantTiming"]
