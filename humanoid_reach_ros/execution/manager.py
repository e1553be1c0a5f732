"""The execution manager: the executor's requests, the motions in the control loop process and
their ends, without ROS (in the spirit of MoveIt's trajectory execution manager).

``reach_executor`` (``nodes/reach_executor.py``) adapts messages to it and back; its tests
drive it directly (``test/test_execution_manager.py``). It owns

* the typed configuration (:class:`~humanoid_reach_ros.execution.config.ExecutionConfig`,
  replaced whole on a run-time change) and the inputs' validation
  (:class:`~humanoid_reach_ros.execution.requests.ExecutionRequests`);
* :class:`MotionTracker`: the motions handed to the loop (``StartMotion``) and the loop's
  events (``execution/messages.py``: ``MotionStarted``, ``MotionFinished``, ``LoopStatus``,
  ``LogLine``, ``LoopExited``); :meth:`MotionTracker.follow` waits for a motion while passing
  on its progress and a client's cancel;
* the requests: :meth:`ExecutionManager.execute` (a trajectory or dual-arm targets, followed to
  its end), :meth:`ExecutionManager.look` (head poses or gaze points in turn, each held),
  :meth:`~ExecutionManager.trajectory_topic`, :meth:`~ExecutionManager.targets_topic`,
  :meth:`~ExecutionManager.sequential`, :meth:`~ExecutionManager.map_message`;
* the stale-joint-state abort (:meth:`~ExecutionManager.watch_joint_states`) and the
  diagnostics' values (:meth:`~ExecutionManager.diagnostics`).

A request arrives as a callable that builds its typed goal from the message (the node's
conversion; it raises :class:`~humanoid_reach_ros.codes.RequestError` on a bad input), so a
conversion error is answered like any other: counted, logged and returned, never raised.
A client's goal is seen through a :class:`GoalPort` (cancel requested, still active, feedback).
"""
from __future__ import annotations

import dataclasses
import itertools
import math
import threading
import time
import traceback
from typing import Any, Callable, Protocol

import numpy as np

from humanoid_reach_ros.codes import ARM_AUTO, ExecuteCode as C, RequestError, code_name
from humanoid_reach_ros.execution.config import MAX_SEQUENTIAL, ExecutionConfig
from humanoid_reach_ros.execution.messages import (LogLine, LoopCommand, LoopEvent, LoopExited, LoopStatus,
                                                   MotionFinished, MotionStarted, SetMap, StartMotion, StopMotion)
from humanoid_reach_ros.execution.requests import ExecutionRequests, HandContact
from humanoid_reach_ros.execution.supervisor import IDLE, Motion

LEVEL_OK, LEVEL_WARN, LEVEL_ERROR = 0, 1, 2      # diagnostic levels (diagnostic_msgs' numbering)
#: a gaze whose joints move less than this [rad] (held back at 0 %: nothing new in view) is not dwelt on
STILL_RAD = 1e-3


def counted(n: int, plural: str) -> str:
    """``1 head pose``, ``2 head poses``."""
    return f"{n} {plural[:-1] if n == 1 else plural}"


class Log(Protocol):
    """A logger as rclpy's (``throttle_duration_sec`` keyword)."""

    def info(self, text: str, **kw: Any) -> Any: ...
    def warning(self, text: str, **kw: Any) -> Any: ...
    def error(self, text: str, **kw: Any) -> Any: ...
    def debug(self, text: str, **kw: Any) -> Any: ...


class Loop(Protocol):
    """The control loop process as the manager uses it (``execution/process.LoopProcess``)."""

    def send(self, command: LoopCommand) -> None: ...
    def alive(self) -> bool: ...


class GoalPort(Protocol):
    """A client's goal: whether it asked to cancel, whether it is still active, and its feedback
    (``feedback(LoopStatus)`` of an execution; ``feedback(LookProgress)`` of a look)."""

    def cancel_requested(self) -> bool: ...
    def active(self) -> bool: ...
    def feedback(self, value: Any) -> None: ...


# ---------------------------------------------------------------- typed goals and outcomes
@dataclasses.dataclass(frozen=True)
class TrajectoryGoal:
    """Execute ``reference`` (an ``exec_msgs.Reference``) with the hand of ``arm`` (an arm code)."""

    reference: Any
    frame_id: str = ""
    arm: int = ARM_AUTO
    no_collision_avoidance: bool = False
    no_com_compensation: bool = False
    smooth_reshaping: bool = False


@dataclasses.dataclass(frozen=True)
class DualArmGoal:
    """The dissertation's dual-arm controller to (right, left) ``HandTarget`` s."""

    targets: tuple


@dataclasses.dataclass(frozen=True)
class LookGoal:
    """Head poses (``yaw``, ``pitch`` [rad]; both empty: the scan pattern) or ``points`` (K, 3)
    [m] to gaze at, each held ``dwell_s`` (<= 0 or not finite: ``scan_dwell_s``)."""

    yaw: tuple[float, ...] = ()
    pitch: tuple[float, ...] = ()
    points: np.ndarray | None = None
    dwell_s: float = 0.0
    come_back: bool = False   # after the last pose or point, back to the posture the look began in


@dataclasses.dataclass(frozen=True)
class LookProgress:
    """A look's feedback: the pose (or point) now, of how many, its head targets, holding or moving."""

    pose_index: int
    pose_count: int
    yaw_rad: float
    pitch_rad: float
    holding: bool


@dataclasses.dataclass
class Outcome:
    """The end of an execution (``summary``: the motion's figures and where the hands ended,
    ``HandContact.as_dict``) or a look (``poses_done``,
    ``duration_s``, ``max_com_error_m``)."""

    code: int
    message: str
    summary: dict = dataclasses.field(default_factory=dict)
    poses_done: int = 0
    duration_s: float = 0.0
    max_com_error_m: float = 0.0

    @property
    def success(self) -> bool:
        return self.code == C.SUCCESS


# ---------------------------------------------------------------- the motions in the loop
@dataclasses.dataclass(eq=False)
class Pending:
    """A motion handed to the loop, as the manager follows it."""

    label: str
    finished: threading.Event = dataclasses.field(default_factory=threading.Event)
    code: int | None = None
    message: str = ""
    summary: dict = dataclasses.field(default_factory=dict)


class MotionTracker:
    """Motions in the control loop process (module doc). ``send``: a command to the loop;
    ``config``: the manager's current configuration; ``ok``: false once shutting down."""

    def __init__(self, send: Callable[[LoopCommand], None], log: Log, counters,
                 config: Callable[[], ExecutionConfig], ok: Callable[[], bool]) -> None:
        self.send, self.log, self.counters, self.config, self.ok = send, log, counters, config, ok
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
                    log.info(line, throttle_duration_sec=self.config().warn_throttle_s)
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
        c.set(last_result=f"{pend.label}: {code_name(code)}")
        c.count("successes", int(code == C.SUCCESS))
        if code == C.INVALID_REQUEST and message.startswith("infeasible"):
            c.count("dual_arm_infeasible")
            c.set(last_infeasible=f"{pend.label}: {message}")
        line = (f"{pend.label}: {code_name(code)} at progress {event.progress:.2f}: "
                f"{message} [{s.duration_s:.2f} s, "
                f"{s.steps} steps, {s.overruns} overruns, max COG error "
                f"{s.max_com_error_m * 1e3:.2f} mm, min distance {s.min_distance_m:.4f} m, "
                f"final hand error {s.final_hand_error_m * 1e3:.2f} mm]")
        if code in (C.SUCCESS, C.PREEMPTED, C.CANCELED):
            self.log.info(line)
        else:
            self.log.warning(line)
        pend.finished.set()

    def follow(self, port: GoalPort, motion: Motion, feedback: Callable[[LoopStatus], None]) -> Pending:
        """Submit ``motion`` and wait for its end, passing ``feedback(status)`` while it runs and
        the stop to the loop when the client cancels."""
        pend = self.submit(motion)
        cancel_sent = False
        while not pend.finished.wait(self.config().feedback_period_s):
            if not self.ok():
                break
            if port.cancel_requested() and not cancel_sent:
                cancel_sent = True
                self.send(StopMotion(motion.id, int(C.CANCELED), "canceled by the client"))
            st = self.status
            if st.motion_id == motion.id and st.last is not None and port.active():
                feedback(st)
        if pend.code is None:
            pend.code, pend.message = C.ABORTED, "the reach_executor node is shutting down"
        return pend


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


# ---------------------------------------------------------------- the manager
class ExecutionManager:
    """The executor's requests and motions (module doc).

    ``joints()``: the latest valid joint angles or ``(None, reason)``; ``joint_states_age()``:
    seconds since the newest ``/joint_states`` (inf: none); ``log``: a :class:`Log`; ``ok()``:
    false once shutting down. :meth:`attach` gives it the loop (whose events go to
    :meth:`on_event`)."""

    def __init__(self, robot, config: ExecutionConfig, joints: Callable[[], tuple[np.ndarray | None, str]],
                 joint_states_age: Callable[[], float], log: Log, ok: Callable[[], bool] = lambda: True) -> None:
        self.robot, self.log, self.ok = robot, log, ok
        self._joints, self._age = joints, joint_states_age
        self.requests = ExecutionRequests(robot, config)
        self.counters = self.requests.counters     # goals, trajectories, target messages: their labels' numbers too
        self.loop: Loop | None = None
        self.tracker = MotionTracker(self._send, log, self.counters, lambda: self.config, ok)
        self._motion_ids, self._sequential_ids = itertools.count(1), itertools.count(1)
        self._aborted_id: int | None = None
        self._window = LoopWindow()

    def attach(self, loop: Loop) -> None:
        self.loop = loop
        self.requests.send_map = lambda tree: loop.send(SetMap(tree))

    def _send(self, command: LoopCommand) -> None:
        if self.loop is None:
            raise RuntimeError("no control loop attached")
        self.loop.send(command)

    def on_event(self, event: LoopEvent) -> None:
        self.tracker.on_event(event)

    @property
    def config(self) -> ExecutionConfig:
        """The configuration in effect (the requests' own: one copy)."""
        return self.requests.config

    def reconfigure(self, values: dict[str, Any]) -> None:
        """Run-time parameter changes (name -> value): a new configuration, whole."""
        self.requests.config = self.config.changed(values)

    def joints(self) -> tuple[np.ndarray | None, str]:
        return self._joints()

    # ------------------------------------------------------------ refusals
    def reject(self, counter: str, label: str, exc: Exception) -> int:
        """Count and log a refused input (goals at WARN, topics throttled, internal errors at
        ERROR); returns its code (``ABORTED`` for an internal error)."""
        known = isinstance(exc, RequestError)
        code = exc.code if known else C.ABORTED
        what = code_name(code) if known else "internal error"
        c = self.counters
        c.count(counter)
        c.set(last_rejection=f"{label}: {what}: {exc}")
        if known and counter == "goals_rejected":
            self.log.warning(f"{label} rejected ({what}): {exc}")
        elif known:   # topics: throttled (a flood must not flood the log)
            self.log.warning(f"rejected {label} ({what}): {exc}", throttle_duration_sec=self.config.warn_throttle_s)
        else:
            self.log.error(f"{label}: internal error: {exc}\n{traceback.format_exc()}")
        return int(code)

    def _goal_label(self, kind: str) -> str:
        return f"{kind} #{self.counters.count('goals')}"

    # ------------------------------------------------------------ /execute_reach
    def execute(self, build: Callable[[], TrajectoryGoal | DualArmGoal], port: GoalPort) -> Outcome:
        """A trajectory or dual-arm targets (``build()``: the goal, or RequestError), followed to
        its end; ``port.feedback(LoopStatus)`` while it runs."""
        label = self._goal_label("goal")
        try:
            goal = build()
            motion = self._motion(goal, label)
        except Exception as exc:  # never die on a goal
            code = self.reject("goals_rejected", label, exc)
            return Outcome(code, str(exc) if isinstance(exc, RequestError)
                           else f"internal error: {type(exc).__name__}: {exc}")
        if port.cancel_requested():  # while it was being validated / reshaped
            self.log.info(f"{label}: CANCELED before execution started")
            return Outcome(int(C.CANCELED), "canceled before execution started")
        self.log.info(f"{label}: accepted: {self.requests.describe(motion)}")
        pend = self.tracker.follow(port, motion, port.feedback)
        return Outcome(int(pend.code), pend.message, {**pend.summary, **self._contact(label).as_dict()})

    def _contact(self, label: str) -> HandContact:
        """Where the hands ended (``ExecutionRequests.contact_at`` on the measured joints), logged;
        an internal error is logged and answered "unknown", never raised."""
        try:
            contact = self.requests.contact_at(*self.joints())
        except Exception as exc:
            self.log.error(f"{label}: contact at the end: internal error: {exc}\n{traceback.format_exc()}")
            return HandContact(False, math.inf, f"unknown: {type(exc).__name__}: {exc}")
        self.log.info(f"{label}: {contact.describe()}")
        return contact

    def _motion(self, goal: TrajectoryGoal | DualArmGoal, label: str) -> Motion:
        joints = self.joints()
        if isinstance(goal, DualArmGoal):
            try:
                motion = self.requests.dual(next(self._motion_ids), label, goal.targets, *joints)
            except RequestError as exc:
                raise RequestError(exc.code, f"MODE_DUAL_ARM goal: {exc}") from None
            self.counters.count("dual_arm_goals")
            return motion
        return self.requests.trajectory(next(self._motion_ids), label, goal.reference, goal.frame_id, goal.arm,
                                        goal.no_collision_avoidance, goal.no_com_compensation,
                                        goal.smooth_reshaping, *joints, log=self.log.info)

    # ------------------------------------------------------------ /look
    def look(self, build: Callable[[], LookGoal], port: GoalPort) -> Outcome:
        """One whole-body motion per head pose, or per gaze point (the balanced whole-body gaze of
        ``control/gaze.py``, from the joints measured when its turn comes), each followed by
        ``dwell_s`` of holding (the loop holds after a motion; not after a scan's way back to its
        start posture, nor after a gaze held back at 0 %: neither brings anything new into view);
        ``port.feedback(LookProgress)``
        names the pose and the head joints' targets. A gaze point no reachable gaze brings into
        view is still looked at (the best effort) and the message says so."""
        label, t0 = self._goal_label("look"), time.monotonic()
        try:
            goal = build()
            points, poses, directions = goal.points, None, False
            scan = points is None and not len(goal.yaw) and not len(goal.pitch)
            if points is None:   # head angles; a robot without a neck looks in their directions by a gaze
                poses, points = self.requests.look_targets(list(goal.yaw), list(goal.pitch))
                directions = points is not None
            around = self.requests.surroundings_points() if scan else np.zeros((0, 3))
            dwell = float(goal.dwell_s) if math.isfinite(goal.dwell_s) and goal.dwell_s > 0 else \
                self.config.scan_dwell_s
            if dwell > 60.0:
                raise RequestError(C.INVALID_REQUEST, f"dwell_s {dwell:g} s is longer than 60 s")
        except Exception as exc:
            code = self.reject("goals_rejected", label, exc)
            return Outcome(code, str(exc))
        # a scan first gazes around the body, then returns to the posture those gazes began in (they turn
        # the chest, which a head pose holds), then takes its head poses (or its directions' gaze
        # points): it ends looking at the workspace in front. The poses first was tried (2026-11-29) and
        # reverted: with the poses' voxels in the map the gazes stop where their straight joint-space
        # way would come near them (Talos: the first gaze's chest turn 86 deg -> 45 %), so the space
        # beside the shoulder stayed unseen and make demo ROBOT=talos ended UNOBSERVED_SPACE after three
        # looks. Gazes first turn on a map with less in it -- the known gap docs/operator.md names
        # (in the physics plant HRP-2's first gaze hit a riser no pose had yet seen).
        # ``come_back`` (the automatic looks): after the last pose or point, back to where the look
        # began, through the space the body just swept -- the next plan starts where the robot stood,
        # not bent over a gaze (the hosts test: from a gaze with the chest pitched 60 deg, the way onto
        # the planning manifold went a few cm beside the swept space, into unobserved space:
        # START_IN_COLLISION)
        start = self.joints()[0] if len(around) or goal.come_back else None
        start = None if start is None else np.array(start, float)   # a copy: the measured joints move on
        items = [("point", p) for p in around] + ([("back", start)] if len(around) and start is not None else []) \
            + ([("pose", p) for p in poses] if points is None else [("point", p) for p in points]) \
            + ([("back", start)] if goal.come_back and start is not None else [])
        asked, what = (len(poses), "head poses") if points is None else (len(points), "gaze points")
        self.log.info(f"{label}: accepted: {counted(asked, what)}, {dwell:g} s each"
                      + (" (the directions asked, for a robot without a neck)" if directions else "")
                      + (f", then {counted(len(around), 'gazes')} around the body" if len(around) else ""))
        out, unseen, short = Outcome(int(C.SUCCESS), ""), [], []
        count = len(items)
        for k, (item, target) in enumerate(items):
            still = item == "back"   # nothing new to see: no dwell (the way back; a gaze held back at 0 %)
            try:
                if item == "pose":
                    yaw, pitch = target
                    motion = self.requests.look(next(self._motion_ids), f"{label} pose {k}", (yaw, pitch),
                                                *self.joints())
                elif item == "back":
                    motion = self.requests.back_to(next(self._motion_ids), f"{label} back {k}", target,
                                                   *self.joints())
                    yaw, pitch = self.requests.head_targets(target)
                else:
                    joints = self.joints()
                    motion, gaze = self.requests.gaze(next(self._motion_ids), f"{label} point {k}", target,
                                                      *joints)
                    yaw, pitch = self.requests.head_targets(gaze.joints)
                    if not gaze.visible:
                        unseen.append(f"point {k} {np.round(target, 3).tolist()} {gaze.unseen_reason}")
                    if joints[0] is not None and np.abs(gaze.joints - joints[0]).max() < STILL_RAD:
                        still = True
            except RequestError as exc:
                out.code, out.message = int(exc.code), f"{item} {k}: {exc}"
                break
            port.feedback(LookProgress(k, count, float(yaw), float(pitch), False))
            pend = self.tracker.follow(port, motion, lambda st: None)
            out.max_com_error_m = max(out.max_com_error_m, float(pend.summary.get("max_com_error_m", 0.0)))
            if pend.code == C.TARGET_NOT_REACHED:
                # a damper or a limit held the body a little short of this pose, and the loop holds it
                # there safely: a look is for seeing, so it looks from there and goes on (a scan's gaze
                # around the body, 1.2 mm short with a damper at 10 mm, ended whole scans: test_session
                # and the console test on a fresh clone)
                short.append(f"{item} {k} held short ({pend.message.split(';')[0]})")
            elif pend.code != C.SUCCESS:
                out.code, out.message = int(pend.code), f"{item} {k}: {pend.message}"
                break
            port.feedback(LookProgress(k, count, float(yaw), float(pitch), True))
            end = time.monotonic() + (0.0 if still else dwell)
            while time.monotonic() < end and not port.cancel_requested() and self.ok():
                time.sleep(min(0.05, max(0.0, end - time.monotonic())))
            if port.cancel_requested():
                out.code, out.message = int(C.CANCELED), f"canceled at {item} {k} (holding there)"
                break
            out.poses_done = k + 1
        out.duration_s = time.monotonic() - t0
        if out.success and points is None:
            around_text = f", then {counted(len(around), 'gazes')} around the body" if len(around) else ""
            out.message = (f"{counted(len(poses), 'head poses')} reached and held {dwell:g} s each{around_text}"
                           + (f" ({'; '.join(unseen + short)})" if unseen or short else ""))
        elif out.success:
            out.message = (f"{counted(asked, 'gaze points')} looked at and held {dwell:g} s each"
                           + (f"; {'; '.join(unseen)}" if unseen else ": every point in view")
                           + (f"; {'; '.join(short)}" if short else "")
                           + ("; then back to the posture the look began in" if goal.come_back else ""))
        line = (f"{label}: {code_name(out.code)}: {out.message} "
                f"[{out.duration_s:.1f} s, max COG error {out.max_com_error_m * 1e3:.2f} mm]")
        if out.code in (C.SUCCESS, C.CANCELED):   # one severity per call site (rclpy's rule)
            self.log.info(line)
        else:
            self.log.warning(line)
        return out

    # ------------------------------------------------------------ topics and services
    def trajectory_topic(self, build: Callable[[], TrajectoryGoal]) -> bool:
        """``/reach_trajectory``: executed like a goal with ``arm = 0``; nobody waits for it."""
        label = f"/reach_trajectory #{self.counters.count('trajectories')}"
        try:
            motion = self._motion(build(), label)
        except Exception as exc:  # never die on an input
            self.reject("trajectories_rejected", label, exc)
            return False
        self.log.info(f"{label}: accepted: {self.requests.describe(motion)}")
        self.tracker.submit(motion)
        return True

    def targets_topic(self, build: Callable[[], tuple]) -> bool:
        """``/dual_arm/targets`` (right, left): followed while ``dual_arm_follow``; targets that
        did not move past the retarget thresholds are dropped."""
        c = self.counters
        label = f"/dual_arm/targets #{c.count('target_messages')}"
        try:
            targets = build()
            if not self.config.dual_arm_follow:
                c.count("target_messages_ignored")
                self.log.info(f"{label} ignored: dual_arm_follow is false (set it true to follow the targets)",
                              throttle_duration_sec=self.config.warn_throttle_s)
                return False
            motion = self.requests.dual(next(self._motion_ids), label, targets, *self.joints(), follow=True)
        except Exception as exc:
            self.reject("target_messages_rejected", label, exc)
            return False
        if self.requests.unchanged(motion.targets, self.tracker.status.dual_targets):
            c.count("target_messages_unchanged")
            return False
        self.log.info(f"{label}: accepted: {self.requests.describe(motion)}",
                      throttle_duration_sec=self.config.warn_throttle_s)
        self.tracker.submit(motion)
        return True

    def sequential(self) -> tuple[bool, str]:
        """``~/dual_arm_sequential``: ``dual_arm_sequential_count`` random reachable target pairs
        (seed ``dual_arm_sequential_seed``) in turn (Sec. 5.4)."""
        count, seed = int(self.config.dual_arm_sequential_count), int(self.config.dual_arm_sequential_seed)
        label = f"sequential #{next(self._sequential_ids)}"
        t0 = time.perf_counter()
        try:
            if not 1 <= count <= MAX_SEQUENTIAL:
                raise RequestError(C.INVALID_REQUEST, f"dual_arm_sequential_count must be in 1..{MAX_SEQUENTIAL}, "
                                                   f"got {count}")
            if seed < 0:
                raise RequestError(C.INVALID_REQUEST, f"dual_arm_sequential_seed must be >= 0, got {seed}")
            motion = self.requests.sequential(next(self._motion_ids), label, count, seed, *self.joints())
        except Exception as exc:
            self.reject("goals_rejected", "~/dual_arm_sequential", exc)
            return False, str(exc)
        self.log.info(f"{label}: accepted: {self.requests.describe(motion)}")
        self.tracker.submit(motion)
        return True, (f"{label}: {count} random target pairs (seed {seed}, drawn in "
                      f"{time.perf_counter() - t0:.2f} s)")

    def scene_map(self, voxels: np.ndarray | None, path: str = "") -> None:
        """The scene file's voxels (None: no scene file) are the map until a /voxel_map arrives."""
        tree, note = self.requests.scene_map(voxels, path)
        if tree is not None:
            self._send(SetMap(tree))
        self.log.info(note)

    def map_message(self, build: Callable[[], Any]) -> bool:
        """``/voxel_map`` (``build()``: the parsed cloud): the loop's sphere tree, the object at the
        motion's target left out; a malformed one is counted and the previous map kept."""
        try:
            tree, line, changed = self.requests.measured_map(build())
        except Exception as exc:  # malformed cloud: keep the previous map
            self.requests.reject_map(exc)
            self.log.warning(f"rejected /voxel_map ({self.counters.maps_rejected} so far): {exc}; keeping the "
                             f"previous map ({self.counters.map_source})",
                             throttle_duration_sec=self.config.warn_throttle_s)
            return False
        self._send(SetMap(tree))
        if changed:   # state changes at INFO, repetition at DEBUG
            self.log.info(line)
        else:
            self.log.debug(line)
        return True

    def unobserved_message(self, build: Callable[[], Any]) -> bool:
        """``/voxel_map/unobserved`` (``build()``: the parsed cloud): the frontier gazes keep the
        body out of; a malformed one is counted and the previous one kept."""
        try:
            line, first = self.requests.unobserved_map(build())
        except Exception as exc:
            self.requests.reject_map(exc, "/voxel_map/unobserved")
            self.log.warning(f"rejected /voxel_map/unobserved ({self.counters.maps_rejected} maps rejected so far): "
                             f"{exc}; keeping the previous frontier", throttle_duration_sec=self.config.warn_throttle_s)
            return False
        if first:
            self.log.info(line)
        else:
            self.log.debug(line)
        return True

    def watch_joint_states(self) -> bool:
        """A running motion whose /joint_states went stale (``joint_states_abort_s``) is aborted
        (the loop holds the last command); True when it sent the stop."""
        mid, age = self.tracker.status.motion_id, self._age()
        if mid is None or mid == self._aborted_id or age <= self.config.joint_states_abort_s:
            return False
        self._aborted_id = mid
        self._send(StopMotion(mid, int(C.ABORTED), f"stopped: /joint_states stale ({age:.2f} s > "
                                                   f"{self.config.joint_states_abort_s:g} s)"))
        return True

    # ------------------------------------------------------------ diagnostics
    def diagnostics(self, period_s: float) -> list[tuple[str, int, str, dict]]:
        """``(name, level, message, values)`` of the execution (state, counters), the loop (tick
        rate, steps and overruns since the last call, step times) and the inputs (joint states,
        map); ``period_s``: the nominal control period."""
        st, c = self.tracker.status, self.counters          # one status (frozen): consistent values
        values: dict[str, Any] = {"state": st.mode, "motion": st.motion_label, "progress": st.progress,
                                  "engine": st.engine, "dual_arm_follow": bool(self.config.dual_arm_follow),
                                  **c.values(exclude="map")}
        message = f"{values['state']}" + (f": {values['motion']}" if values["motion"] else "")
        if c.last_rejection:
            message += f"; last rejection: {c.last_rejection}"
        out = [("execution", LEVEL_OK, message, values)]
        steps, overruns, ticks, elapsed = self._window.advance(st)
        alive = self.loop is not None and self.loop.alive()
        values = {"nominal_rate_hz": 1.0 / period_s, "tick_rate_hz": ticks / elapsed, "steps_recent": steps,
                  "overruns_recent": overruns, "overruns_total": st.overruns,
                  "missed_deadlines_total": st.missed_deadlines, "published_total": st.published,
                  "step_p50_ms": st.step_p50_ms, "step_p99_ms": st.step_p99_ms,
                  "max_step_ms": st.step_max_ms, "hold_step_p99_ms": st.hold_step_p99_ms,
                  "slow_publishes_total": st.slow_publishes, "max_publish_ms": st.max_publish_ms,
                  "loop_process_alive": alive}
        level, message = LEVEL_OK, f"{ticks / elapsed:.0f} Hz ticks, {steps} steps, {overruns} overruns"
        if st.mode == IDLE and not steps:
            message = "idle: the loop sleeps until the next motion (nothing to publish)"
        if not alive:
            level, message = LEVEL_ERROR, "the control loop process is not running"
        elif steps and overruns / max(steps + overruns, 1) > self.config.max_overrun_fraction:
            level, message = LEVEL_WARN, f"{overruns} of {steps + overruns} periods overran (last command held)"
        out.append(("loop", level, message, values))
        joints, reason = self.joints()
        last, age = st.last_joints, self._age()
        values = {"joint_states_age_s": age if math.isfinite(age) else "never",
                  "tracking_error_rad": float(np.max(np.abs(joints - last)))
                  if joints is not None and last is not None else 0.0,
                  **c.values(prefix="map")}
        level, message = (LEVEL_OK, "joint_states current") if joints is not None else (LEVEL_WARN, reason)
        out.append(("inputs", level, message, values))
        return out


__all__ = ["ExecutionManager", "MotionTracker", "Pending", "LoopWindow", "GoalPort", "TrajectoryGoal",
           "DualArmGoal", "LookGoal", "LookProgress", "Outcome", "LEVEL_OK", "LEVEL_WARN",
           "LEVEL_ERROR", "counted"]
