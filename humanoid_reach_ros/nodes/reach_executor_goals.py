"""The ``reach_executor`` node's side of its motions (``nodes/reach_executor.py``).

* :class:`MotionTracker`: the motions handed to the control loop process and their ends
  (the loop's events, ``execution/messages.py``: ``MotionStarted``, ``MotionFinished``,
  ``LoopStatus``, ``LogLine``, ``LoopExited``), and
  :meth:`MotionTracker.follow`, which waits for a motion while forwarding feedback and a
  client's cancel;
* :func:`execute_goal` and :func:`look_goal`: the ``/execute_reach`` and ``/look`` actions
  built on it (inputs validated by ``execution/requests.py``; a bad goal is answered, never
  raised).
"""
from __future__ import annotations

import dataclasses
import math
import threading
import time
import traceback
from typing import Callable

import numpy as np
from humanoid_reach_interfaces.action import ExecuteReach, Look

from humanoid_reach_ros.codes import ExecuteCode as C, RequestError
from humanoid_reach_ros.execution.messages import (LogLine, LoopEvent, LoopExited, LoopStatus, MotionFinished,
                                                   MotionStarted, StartMotion, StopMotion)
from humanoid_reach_ros.execution.supervisor import Motion
from humanoid_reach_ros.io import exec_msgs

RESULT_NAMES = {int(c): c.name for c in C}


def counted(n: int, plural: str) -> str:
    """``1 head pose``, ``2 head poses``."""
    return f"{n} {plural[:-1] if n == 1 else plural}"


@dataclasses.dataclass(eq=False)
class Pending:
    """A motion handed to the loop, as the node follows it."""

    label: str
    finished: threading.Event = dataclasses.field(default_factory=threading.Event)
    code: int | None = None
    message: str = ""
    summary: dict = dataclasses.field(default_factory=dict)


class MotionTracker:
    """Motions in the control loop process, as the node sees them (module doc).

    ``send``: puts a command to the loop process; ``logger``: the node's; ``counters``: the
    node's ``ExecutionCounters``; ``params``: the node's parameter dict (``warn_throttle_s``,
    ``feedback_period_s``); ``ok``: false once the node shuts down."""

    def __init__(self, send: Callable, logger, counters, params: dict, ok: Callable[[], bool]) -> None:
        self.send, self.log, self.counters, self.p, self.ok = send, logger, counters, params, ok
        self.status = LoopStatus()            # the loop's latest (idle before the first)
        self.last_result: Pending | None = None
        self._pending: dict[int, Pending] = {}
        self._lock = threading.Lock()

    def submit(self, motion: Motion) -> Pending:
        pend = Pending(motion.label)
        with self._lock:
            self._pending[motion.id] = pend
        self.send(StartMotion(motion))
        return pend

    def on_event(self, event: LoopEvent) -> None:
        log = self.log
        match event:
            case LoopStatus():
                self.status = event
            case MotionStarted(motion_id=mid, note=note, source=source):
                with self._lock:
                    pend = self._pending.get(mid)
                line = f"{pend.label}: started from {source}" + (f": {note}" if note else "") if pend else ""
                if pend is not None and pend.label.startswith("/dual_arm"):   # followed targets: throttled
                    log.info(line, throttle_duration_sec=self.p["warn_throttle_s"])
                elif pend is not None:
                    log.info(line)
            case MotionFinished():
                self._finished(event)
            case LogLine(level="error", text=text):
                log.error(text)
            case LogLine(level="warning", text=text):
                log.warning(text)
            case LogLine(text=text):
                log.info(text)
            case LoopExited(returncode=returncode):
                self._exited(returncode)

    def _exited(self, returncode: int | None) -> None:
        """The loop process is gone: every motion still pending ends ABORTED."""
        if self.ok():
            self.log.error(f"the control loop process exited ({returncode}): no more commands")
        with self._lock:
            pending, self._pending = list(self._pending.values()), {}
        for pend in pending:
            pend.code, pend.message = C.ABORTED, "the control loop process exited"
            pend.finished.set()

    def _finished(self, event: MotionFinished) -> None:
        with self._lock:
            pend = self._pending.pop(event.motion_id, None)
        if pend is None:
            return
        code, message, s = event.code, event.message, event.summary
        pend.code, pend.message, pend.summary = code, message, s.as_dict()
        self.last_result = pend
        c = self.counters
        c.last_result = f"{pend.label}: {RESULT_NAMES.get(code, code)}"
        c.successes += int(code == C.SUCCESS)
        if code == C.INVALID_GOAL and message.startswith("infeasible"):
            c.dual_arm_infeasible += 1
            c.last_infeasible = f"{pend.label}: {message}"
        line = (f"{pend.label}: {RESULT_NAMES.get(code, code)} at progress {event.progress:.2f}: "
                f"{message} [{s.duration_s:.2f} s, "
                f"{s.steps} steps, {s.overruns} overruns, max COG error "
                f"{s.max_com_error_m * 1e3:.2f} mm, min distance {s.min_distance_m:.4f} m, "
                f"final hand error {s.final_hand_error_m * 1e3:.2f} mm]")
        if code in (C.SUCCESS, C.PREEMPTED, C.CANCELED):
            self.log.info(line)
        else:
            self.log.warning(line)
        pend.finished.set()

    def follow(self, goal_handle, motion: Motion, feedback) -> Pending:
        """Submit ``motion`` and wait for its end, sending ``feedback(status)`` while it runs and
        the stop to the loop when the client cancels."""
        pend = self.submit(motion)
        cancel_sent = False
        while not pend.finished.wait(self.p["feedback_period_s"]):
            if not self.ok():
                break
            if goal_handle.is_cancel_requested and not cancel_sent:
                cancel_sent = True
                self.send(StopMotion(motion.id, int(C.CANCELED), "canceled by the client"))
            st = self.status
            if st.motion_id == motion.id and st.last is not None and goal_handle.is_active:
                feedback(st)
        if pend.code is None:
            pend.code, pend.message = C.ABORTED, "the reach_executor node is shutting down"
        return pend


def close_goal(goal_handle, code: int) -> None:
    if code == C.SUCCESS:
        goal_handle.succeed()
    elif code == C.CANCELED and goal_handle.is_cancel_requested:
        goal_handle.canceled()
    else:
        goal_handle.abort()


def reject(node, counter: str, label: str, exc: Exception) -> None:
    """Count and log a refused input (goals at WARN, topics throttled, internal errors at ERROR)."""
    code = exc.code if isinstance(exc, RequestError) else C.ABORTED
    what = RESULT_NAMES.get(code, code) if isinstance(exc, RequestError) else "internal error"
    c = node.counters
    setattr(c, counter, getattr(c, counter) + 1)
    c.last_rejection = f"{label}: {what}: {exc}"
    log = node.get_logger()
    if isinstance(exc, RequestError) and counter == "goals_rejected":
        log.warning(f"{label} rejected ({what}): {exc}")
    elif isinstance(exc, RequestError):   # topics: throttled (a flood must not flood the log)
        log.warning(f"rejected {label} ({what}): {exc}", throttle_duration_sec=node.p["warn_throttle_s"])
    else:
        log.error(f"{label}: internal error: {exc}\n{traceback.format_exc()}")


def execute_goal(node, goal_handle) -> ExecuteReach.Result:
    """``/execute_reach``: a trajectory (``MODE_TRAJECTORY``) or dual-arm targets, followed to its end."""
    node.counters.goals = max(node.counters.goals, n := next(node.goal_ids))
    label, req = f"goal #{n}", goal_handle.request
    try:
        joints = node.current_joints()
        if req.mode == ExecuteReach.Goal.MODE_DUAL_ARM:
            try:
                targets = exec_msgs.goal_hand_targets(req.right_hand_target, req.left_hand_target)
                motion = node.requests.dual(next(node.motion_ids), label, targets, *joints)
            except RequestError as exc:
                raise RequestError(exc.code, f"MODE_DUAL_ARM goal: {exc}") from None
            node.counters.dual_arm_goals += 1
        elif req.mode != ExecuteReach.Goal.MODE_TRAJECTORY:
            raise RequestError(C.INVALID_GOAL, f"mode {req.mode} is unknown; use 0 (TRAJECTORY) or 1 (DUAL_ARM)")
        else:
            ref = exec_msgs.reference_from_trajectory(req.trajectory, node.robot)
            motion = node.requests.trajectory(next(node.motion_ids), label, ref, req.trajectory.header.frame_id,
                                              req.arm, req.disable_collision_avoidance, req.disable_com_compensation,
                                              req.smooth_reshaping, *joints, log=node.get_logger().info)
    except Exception as exc:  # never die on a goal
        reject(node, "goals_rejected", label, exc)
        goal_handle.abort()
        code = exc.code if isinstance(exc, RequestError) else C.ABORTED
        return exec_msgs.result_message(code, str(exc) if isinstance(exc, RequestError)
                                        else f"internal error: {type(exc).__name__}: {exc}")
    if goal_handle.is_cancel_requested:  # while it was being validated / reshaped
        node.get_logger().info(f"{label}: CANCELED before execution started")
        goal_handle.canceled()
        return exec_msgs.result_message(C.CANCELED, "canceled before execution started")
    node.get_logger().info(f"{label}: accepted: {node.requests.describe(motion)}")
    pend = node.tracker.follow(goal_handle, motion, lambda st: goal_handle.publish_feedback(
        exec_msgs.execute_feedback(st.last)))
    result = exec_msgs.result_message(pend.code, pend.message, pend.summary)
    close_goal(goal_handle, pend.code)
    return result


def look_goal(node, goal_handle) -> Look.Result:
    """``/look``: one whole-body motion per head pose, or per gaze point (``gaze_points``: the
    balanced whole-body gaze of ``control/gaze.py``, chest and head, computed from the joints
    measured when its turn comes), each followed by ``dwell_s`` of holding (the loop holds
    after a motion); feedback names the pose and the head joints' targets. A gaze point no
    reachable gaze brings into view is still looked at (the best effort) and the result's
    message says so."""
    node.counters.goals = max(node.counters.goals, n := next(node.goal_ids))
    label, req, t0 = f"look #{n}", goal_handle.request, time.monotonic()
    result = Look.Result(error_code=int(C.SUCCESS))
    try:
        points, poses, directions = exec_msgs.gaze_points(req), None, False
        if points is None:   # head angles; a robot without a neck looks in their directions by a gaze
            poses, points = node.requests.look_targets(list(req.yaw_rad), list(req.pitch_rad))
            directions = points is not None
        dwell = float(req.dwell_s) if math.isfinite(req.dwell_s) and req.dwell_s > 0 else node.p["scan_dwell_s"]
        if dwell > 60.0:
            raise RequestError(C.INVALID_GOAL, f"dwell_s {dwell:g} s is longer than 60 s")
    except RequestError as exc:
        reject(node, "goals_rejected", label, exc)
        goal_handle.abort()
        return Look.Result(error_code=exc.code, message=str(exc))
    log = node.get_logger()
    count, what, item = (len(poses), "head poses", "pose") if points is None else (len(points), "gaze points", "point")
    log.info(f"{label}: accepted: {counted(count, what)}, {dwell:g} s each"
             + (" (the directions asked, for a robot without a neck)" if directions else ""))
    fb = Look.Feedback(pose_count=count)
    unseen = []
    for k in range(count):
        try:
            if points is None:
                yaw, pitch = poses[k]
                motion = node.requests.look(next(node.motion_ids), f"{label} pose {k}", (yaw, pitch),
                                            *node.current_joints())
            else:
                motion, gaze = node.requests.gaze(next(node.motion_ids), f"{label} point {k}", points[k],
                                                  *node.current_joints())
                yaw, pitch = node.requests.head_targets(gaze.joints)
                if not gaze.visible:
                    unseen.append(f"point {k} {np.round(points[k], 3).tolist()} {gaze.unseen_reason}")
        except RequestError as exc:
            result.error_code, result.message = exc.code, f"{item} {k}: {exc}"
            break
        fb.pose_index, fb.yaw_rad, fb.pitch_rad, fb.holding = k, float(yaw), float(pitch), False
        goal_handle.publish_feedback(fb)
        pend = node.tracker.follow(goal_handle, motion, lambda st: None)
        result.max_com_error_m = max(result.max_com_error_m, float(pend.summary.get("max_com_error_m", 0.0)))
        if pend.code != C.SUCCESS:
            result.error_code, result.message = pend.code, f"{item} {k}: {pend.message}"
            break
        fb.holding = True
        goal_handle.publish_feedback(fb)
        end = time.monotonic() + dwell
        while time.monotonic() < end and not goal_handle.is_cancel_requested and node.context.ok():
            time.sleep(min(0.05, max(0.0, end - time.monotonic())))
        if goal_handle.is_cancel_requested:
            result.error_code, result.message = int(C.CANCELED), f"canceled at {item} {k} (holding there)"
            break
        result.poses_done = k + 1
    result.success = result.error_code == C.SUCCESS
    result.duration_s = time.monotonic() - t0
    if result.success and points is None:
        result.message = f"{counted(count, 'head poses')} reached and held {dwell:g} s each"
    elif result.success:
        result.message = (f"{counted(count, 'gaze points')} looked at and held {dwell:g} s each"
                          + (f"; {'; '.join(unseen)}" if unseen else ": every point in view"))
    line = (f"{label}: {RESULT_NAMES.get(result.error_code, result.error_code)}: {result.message} "
            f"[{result.duration_s:.1f} s, max COG error {result.max_com_error_m * 1e3:.2f} mm]")
    if result.error_code in (C.SUCCESS, C.CANCELED):   # one severity per call site (rclpy's rule)
        log.info(line)
    else:
        log.warning(line)
    close_goal(goal_handle, result.error_code)
    return result


__all__ = ["Pending", "MotionTracker", "RESULT_NAMES", "close_goal", "reject", "execute_goal", "look_goal"]
