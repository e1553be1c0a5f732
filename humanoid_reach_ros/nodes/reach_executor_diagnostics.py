"""``/diagnostics`` of the ``reach_executor`` node: execution (state, counters), loop (tick
rate, steps and overruns since the last report, step times) and inputs (joint states, map)."""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from humanoid_reach_ros.execution.supervisor import IDLE
from humanoid_reach_ros.io import msgs


class LoopWindow:
    """The loop's counters at the previous report: the next one gives the steps, overruns
    and ticks since then."""

    def __init__(self) -> None:
        self.steps = self.overruns = self.ticks = 0
        self.t = time.monotonic()

    def advance(self, status: dict) -> tuple[int, int, int, float]:
        """(steps, overruns, ticks, elapsed s) since the previous call."""
        now = time.monotonic()
        out = (status.get("steps", 0) - self.steps, status.get("overruns", 0) - self.overruns,
               status.get("ticks", 0) - self.ticks, max(now - self.t, 1e-9))
        self.steps, self.overruns = status.get("steps", 0), status.get("overruns", 0)
        self.ticks, self.t = status.get("ticks", 0), now
        return out


def executor_statuses(node, window: LoopWindow) -> list:
    """The node's three DiagnosticStatus entries (module doc)."""
    st, c = dict(node.tracker.status), node.counters
    name, hw = node.get_name(), node.hardware_id
    values = {"state": st.get("mode", IDLE), "motion": st.get("motion_label", ""),
              "progress": st.get("progress", 0.0), "engine": st.get("engine", ""),
              "dual_arm_follow": bool(node.p["dual_arm_follow"]),
              **{k: v for k, v in dataclasses.asdict(c).items() if not k.startswith("map")}}
    message = f"{values['state']}" + (f": {values['motion']}" if values["motion"] else "")
    if c.last_rejection:
        message += f"; last rejection: {c.last_rejection}"
    out = [msgs.diagnostic_status(f"{name}: execution", msgs.LEVEL_OK, message, values, hw)]
    steps, overruns, ticks, elapsed = window.advance(st)
    values = {"nominal_rate_hz": 1.0 / node.period_s, "tick_rate_hz": ticks / elapsed, "steps_recent": steps,
              "overruns_recent": overruns, "overruns_total": st.get("overruns", 0),
              "missed_deadlines_total": st.get("missed_deadlines", 0), "published_total": st.get("published", 0),
              "step_p50_ms": st.get("step_p50_ms", 0.0), "step_p99_ms": st.get("step_p99_ms", 0.0),
              "max_step_ms": st.get("step_max_ms", 0.0), "hold_step_p99_ms": st.get("hold_step_p99_ms", 0.0),
              "slow_publishes_total": st.get("slow_publishes", 0), "max_publish_ms": st.get("max_publish_ms", 0.0),
              "loop_process_alive": node.loop.alive()}
    level, message = msgs.LEVEL_OK, f"{ticks / elapsed:.0f} Hz ticks, {steps} steps, {overruns} overruns"
    if st.get("mode", IDLE) == IDLE and not steps:
        message = "idle: the loop sleeps until the next motion (nothing to publish)"
    if not node.loop.alive():
        level, message = msgs.LEVEL_ERROR, "the control loop process is not running"
    elif steps and overruns / max(steps + overruns, 1) > node.p["max_overrun_fraction"]:
        level, message = msgs.LEVEL_WARN, f"{overruns} of {steps + overruns} periods overran (last command held)"
    out.append(msgs.diagnostic_status(f"{name}: loop", level, message, values, hw))
    joints, reason = node.current_joints()
    last = st.get("last_joints")
    values = {"joint_states_age_s": node.joint_states.age_s() if node.joint_states.latest() is not None
              else "never", "tracking_error_rad": float(np.max(np.abs(joints - last)))
              if joints is not None and last is not None else 0.0,
              **{k: v for k, v in dataclasses.asdict(c).items() if k.startswith("map")}}
    level, message = (msgs.LEVEL_OK, "joint_states current") if joints is not None else (msgs.LEVEL_WARN, reason)
    out.append(msgs.diagnostic_status(f"{name}: inputs", level, message, values, hw))
    return out


__all__ = ["LoopWindow", "executor_statuses"]
