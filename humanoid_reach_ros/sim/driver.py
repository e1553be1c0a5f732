"""The simulated robot's driver state (no ROS): commands, staleness, loop statistics, diagnostics.

``nodes/joint_driver.py`` is the ROS adapter (messages, parameters, timers, publishing);
this is what it adapts: a :class:`~humanoid_reach_ros.sim.joint_sim.JointSimulator` behind
a lock (the command thread against the 200 Hz loop thread), and around it

* **commands** (:meth:`SimulatedDriver.command`): validated by the simulator, stamped on the
  monotonic clock; an accepted one ends a stale spell;
* **staleness** (:meth:`SimulatedDriver.begin_tick`): no command for ``command_timeout_s``
  holds the joints where they are, remembering how far from its target the joint furthest
  off stopped (a stale command *while moving* is a warning, an idle one is not);
* **loop statistics**: ticks, the period each tick measured, overruns (a period longer than
  ``overrun_factor`` times ``period_s``), the longest tick, totals and a window per
  diagnostics message;
* **diagnostics** (:meth:`SimulatedDriver.statuses`): the commands, limits, loop and odometry
  statuses as plain ``(name suffix, level, message, values)`` tuples (levels those of
  ``diagnostic_msgs``: 0 OK, 1 WARN), which the node turns into messages.
"""
from __future__ import annotations

import math
import threading
import time
from typing import Any, Callable, Sequence

from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.sim.joint_sim import CommandResult, JointSimulator

POSTURES = ("half_sitting", "zero")
OK, WARN = 0, 1     # diagnostic_msgs/DiagnosticStatus levels

#: one status of a diagnostics message: (name suffix, level, message, key -> value)
Status = tuple[str, int, str, dict[str, Any]]


def initial_joints(model: RobotModel, posture: str) -> Sequence[float]:
    """The joint angles of a named start posture; ``ValueError`` for an unknown name."""
    if posture == "half_sitting":
        return model.half_sitting_joints
    if posture == "zero":
        return [0.0] * model.n_joints
    raise ValueError(f"initial_posture must be one of {POSTURES}, got {posture!r}")


class SimulatedDriver:
    """A :class:`JointSimulator` with the driver's command, staleness and timing bookkeeping."""

    def __init__(self, model: RobotModel, posture: str, *, period_s: float, velocity_scale: float = 1.0,
                 time_constant_s: float = 0.01, command_timeout_s: float = 0.5,
                 stopped_short_warn_rad: float = 1e-4, overrun_factor: float = 1.5, min_rate_fraction: float = 0.9,
                 max_overrun_fraction: float = 0.02, left_foot_slip_warn_m: float = 0.005,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.sim = JointSimulator(model, initial_joints(model, posture), velocity_scale, time_constant_s)
        self.period_s = float(period_s)
        self.command_timeout_s = float(command_timeout_s)
        self.stopped_short_warn_rad = float(stopped_short_warn_rad)
        self.overrun_factor = float(overrun_factor)
        self.min_rate_fraction = float(min_rate_fraction)
        self.max_overrun_fraction = float(max_overrun_fraction)
        self.left_foot_slip_warn_m = float(left_foot_slip_warn_m)
        self.clock = clock
        self.lock = threading.Lock()        # the simulator: command callback vs loop thread
        # loop statistics: totals and the current diagnostics window
        self._last_tick: float | None = None
        self.ticks = 0
        self.overruns = 0
        self._window = self._new_window()
        self.stale = False
        self.stopped_short_rad = 0.0  # how far from its target the joint furthest off was when going stale
        self._rejected_reported = 0
        self._clip_events_reported = 0

    # ------------------------------------------------------------ commands
    def command(self, names: Sequence[str], positions: Sequence[float],
                velocities: Sequence[float] | None = None) -> tuple[CommandResult, bool]:
        """Hand a command to the simulator; returns its result and whether it ended a stale spell."""
        with self.lock:
            result = self.sim.set_command(names, positions, velocities, now=self.clock())
        resumed = False
        if result.accepted and self.stale:
            self.stale, resumed = False, True
        return result, resumed

    # ------------------------------------------------------------ loop
    def begin_tick(self) -> tuple[float, float, tuple[bool, str] | None]:
        """Start one loop tick: ``(t, dt, notice)`` -- its clock time, the step to simulate (the
        measured period; ``period_s`` on the first tick) and, when the command just went stale,
        ``(warning?, log text)`` (the joints then hold where they are)."""
        t = self.clock()
        if self._last_tick is None:
            dt = self.period_s
        else:
            dt = t - self._last_tick
            w = self._window
            w["periods"] += 1
            w["max_period_s"] = max(w["max_period_s"], dt)
            if dt > self.overrun_factor * self.period_s:
                self.overruns += 1
                w["overruns"] += 1
        self._last_tick = t
        self.ticks += 1
        notice = None
        sim = self.sim
        if not self.stale and math.isfinite(age := sim.command_age(t)) and age > self.command_timeout_s:
            self.stale = True
            self.stopped_short_rad = float(abs(sim.target - sim.q).max())
            sim.hold()
            if self.stopped_short_rad > self.stopped_short_warn_rad:
                notice = (True, f"joint_command stale (nothing for {self.command_timeout_s:g} s) while moving: "
                                f"holding position {self.stopped_short_rad:.3f} rad short of the target")
            else:
                notice = (False, f"joint_command idle for {self.command_timeout_s:g} s: holding position")
        return t, dt, notice

    def end_tick(self, t: float) -> None:
        """The tick begun at ``t`` is done (its duration goes into the window's longest tick)."""
        self._window["max_tick_s"] = max(self._window["max_tick_s"], self.clock() - t)

    def _new_window(self) -> dict[str, float]:
        """Statistics of one diagnostics period (the loop's totals live on the driver)."""
        return {"start": self.clock(), "ticks_at_start": self.ticks, "periods": 0, "overruns": 0,
                "max_period_s": 0.0, "max_tick_s": 0.0}

    # ------------------------------------------------------------ diagnostics
    def statuses(self, now: float, world_frame_id: str, base_frame_id: str) -> list[Status]:
        """The statuses of one diagnostics message; resets the timing window."""
        sim = self.sim
        w, self._window = self._window, self._new_window()
        statuses: list[Status] = []

        # commands
        rejected_recent = sim.rejected_count - self._rejected_reported
        self._rejected_reported = sim.rejected_count
        age = sim.command_age(now)
        values = {
            "accepted_total": sim.accepted_count,
            "rejected_total": sim.rejected_count,
            "rejected_recent": rejected_recent,
            "last_rejection_reason": sim.last_rejection,
            "command_age_s": age if math.isfinite(age) else "never",
            "command_timeout_s": self.command_timeout_s,
            "stale": self.stale,
            "stopped_short_rad": self.stopped_short_rad if self.stale else 0.0,
        }
        level, message = OK, "tracking joint_command"
        if sim.last_command_time is None:
            message = "no joint_command yet: holding the initial posture"
        if self.stale:
            message = f"joint_command idle ({age:.1f} s): holding position"
            if self.stopped_short_rad > self.stopped_short_warn_rad:
                level = WARN
                message = (f"joint_command stale ({age:.1f} s > {self.command_timeout_s:g} s) while moving: "
                           f"held position {self.stopped_short_rad:.3f} rad short of the target")
        if rejected_recent:
            level = WARN
            message = f"rejected {rejected_recent} joint_command(s), last: {sim.last_rejection}"
        statuses.append(("commands", level, message, values))

        # limits
        clip_recent = sim.clip_events - self._clip_events_reported
        self._clip_events_reported = sim.clip_events
        per_joint = {f"clipped_targets.{j}": int(c) for j, c in zip(sim.joint_names, sim.clip_count) if c}
        values = {"clip_events_total": sim.clip_events, "clip_events_recent": clip_recent,
                  "clipped_targets_total": int(sim.clip_count.sum()),
                  "velocity_scale": sim.velocity_scale, **per_joint}
        level, message = OK, "targets within position limits"
        if clip_recent:
            level = WARN
            message = f"{clip_recent} command(s) had targets clipped into position limits"
        statuses.append(("limits", level, message, values))

        # loop timing
        elapsed = max(now - w["start"], 1e-9)
        ticks = self.ticks - w["ticks_at_start"]
        rate = ticks / elapsed
        nominal = 1.0 / self.period_s
        overrun_frac = w["overruns"] / w["periods"] if w["periods"] else 0.0
        values = {"nominal_rate_hz": nominal, "achieved_rate_hz": rate, "overruns_total": self.overruns,
                  "overruns_recent": w["overruns"], "overrun_threshold_ms": self.overrun_factor * self.period_s * 1e3,
                  "max_period_ms": w["max_period_s"] * 1e3, "max_tick_ms": w["max_tick_s"] * 1e3,
                  "ticks_total": self.ticks}
        level, message = OK, f"{rate:.1f} Hz"
        if rate < self.min_rate_fraction * nominal or overrun_frac > self.max_overrun_fraction:
            level = WARN
            message = f"{rate:.1f} Hz of {nominal:.0f} Hz, {w['overruns']} overrun(s) in {w['periods']} periods"
        statuses.append(("loop", level, message, values))

        # odometry
        with self.lock:
            odom = sim.odometry()
        x, y, z = (float(v) for v in odom.base.translation)
        values = {"base_x_m": x, "base_y_m": y, "base_z_m": z, "left_foot_slip_m": odom.left_foot_slip_m,
                  "frame_id": world_frame_id, "child_frame_id": base_frame_id}
        level, message = OK, "right foot fixed, left foot on its stance pose"
        if odom.left_foot_slip_m > self.left_foot_slip_warn_m:
            level = WARN
            message = f"left foot {odom.left_foot_slip_m * 1e3:.1f} mm from its stance pose (feet-fixed odometry)"
        statuses.append(("odometry", level, message, values))
        return statuses


__all__ = ["POSTURES", "SimulatedDriver", "Status", "initial_joints"]
