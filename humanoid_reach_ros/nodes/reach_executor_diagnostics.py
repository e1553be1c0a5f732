"""``/diagnostics`` of the ``reach_executor`` node: execution (state, counters), loop (tick
rate, steps and overruns since the last report, step times) and inputs (joint states, map)."""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from humanoid_reach_ros.execution.messages import LoopStatus
from humanoid_reach_ros.execution.supervisor import IDLE
from humanoid_reach_ros.io import msgs


class LoopWindow:
    """The loop's counters at the previous report: the next one gives the steps, overruns
    and ticks since then."""

    def __init__(self) -> None:
        self.steps = self.overruns = self.ticks = 0
        self.t = time.monotonic()

    def advance(self, status: LoopStatus) -> tuple[int, int, int, float]:
        """(steps, overruns, ticks, elapsed s) since the previous call."""
        now = time.monotonic()
        out = (status.steps - self.steps, status.overruns - self.overruns, status.ticks - self.ticks,
               max(now - self.t, 1e-9))
        self.steps, self.overruns, self.ticks, self.t = status.steps, status.overruns, status.ticks, now
        return out


def executor_statuses(node, window: LoopWindow) -> list:
    """The node's three DiagnosticStatus entries (module doc)."""
    st, c = node.tracker.status, node.counters          # one status (frozen): consistent values
    name, hw = node.get_name(), node.hardware_id
    values = {"state": st.mode, "motion": st.motion_label, "progress": st.progress, "engine": st.engine,
              "dual_arm_follow": bool(node.p["dual_arm_follow"]),
              **{k: v for k, v in dataclasses.asdict(c).items() if not k.startswith("map")}}
    message = f"{values['state']}" + (f": {values['motion']}" if values["motion"] else "")
    if c.last_rejection:
        message += f"; last rejection: {c.last_rejection}"
    out = [msgs.diagnostic_status(f"{name}: execution", msgs.LEVEL_OK, message, values, hw)]
    steps, overruns, ticks, elapsed = window.advance(st)
    values = {"nominal_rate_hz": 1.0 / node.period_s, "tick_rate_hz": ticks / elapsed, "steps_recent": steps,
              "overruns_recent": overruns, "overruns_total": st.overruns,
              "missed_deadlines_total": st.missed_deadlines, "published_total": st.published,
              "step_p50_ms": st.step_p50_ms, "step_p99_ms": st.step_p99_ms,
              "max_step_ms": st.step_max_ms, "hold_step_p99_ms": st.hold_step_p99_ms,
              "slow_publishes_total": st.slow_publishes, "max_publish_ms": st.max_publish_ms,
              "loop_process_alive": node.loop.alive()}
    level, message = msgs.LEVEL_OK, f"{ticks / elapsed:.0f} Hz ticks, {steps} steps, {overruns} overruns"
    if st.mode == IDLE and not steps:
        message = "idle: the loop sleeps until the next motion (nothing to publish)"
    if not node.loop.alive():
        level, message = msgs.LEVEL_ERROR, "the control loop process is not running"
    elif steps and overruns / max(steps + overruns, 1) > node.p["max_overrun_fraction"]:
        level, message = msgs.LEVEL_WARN, f"{overruns} of {steps + overruns} periods overran (last command held)"
    out.append(msgs.diagnostic_status(f"{name}: loop", level, message, values, hw))
    joints, reason = node.current_joints()
    last = st.last_joints
    values = {"joint_states_age_s": node.joint_states.age_s() if node.joint_states.latest() is not None
              else "never", "tracking_error_rad": float(np.max(np.abs(joints - last)))
              if joints is not None and last is not None else 0.0,
              **{k: v for k, v in dataclasses.asdict(c).items() if k.startswith("map")}}
    level, message = (msgs.LEVEL_OK, "joint_states current") if joints is not None else (msgs.LEVEL_WARN, reason)
    out.append(msgs.diagnostic_status(f"{name}: inputs", level, message, values, hw))
    return out


__all__ = ["LoopWindow", "executor_statuses"]
