"""Execution supervisor: accept, execute, cancel, preempt, hold the last safe command.

ROS-free and thread-free: a clock (``clock() -> seconds``, monotonic) and a command sink
(``sink(joints, metrics, overruns)``) are injected, and two callers drive it:

* the **solver side** calls :meth:`work` whenever :meth:`has_work` (it applies the queued
  commands -- start, stop, map -- and computes the next step of the running engine);
* the **tick side** calls :meth:`tick` at every deadline ``t_0 + k period_s``: it hands the
  oldest step the solver finished to the sink; when none is finished (the step overran its
  period) the last safe command goes out again, an overrun is counted, and the late step
  follows at the next deadline: a half-computed command is never sent.

The solver works ``lookahead_steps`` deadlines ahead (default 4: the steps for the next
four deadlines are computed before they are due; 3 until a 19 ms solve overran in a session). A step depends only on the
step before it and on the reference at its own deadline, never on when it is published, so
computing ahead changes no command; it absorbs a late wake-up of either thread (measured on
this 2-vCPU VM: a trivial SCHED_FIFO thread woke up to 4.5 ms late within 20 s, and a 1.5 ms
solver working one deadline ahead overran once in 6,000 deadlines; in the running graph, 12
head scans: 13 overruns in 24,312 steps two deadlines ahead, 0 in 24,323 three ahead). The
cost: a new map or a stop reaches the published command ``lookahead_steps - 1`` periods later
(15 ms at 4); a start drops the steps computed ahead and begins from the last *published* command,
as before.

States: ``idle`` (nothing commanded yet, or the hold timed out: nothing is published),
``running``, ``settling`` (after a cancel / abort the engine keeps solving in its hold mode
for ``hold_settle_s``; a dual-arm motion brakes on its path), ``holding`` (the last command
is republished every period, for ``hold_timeout_s``; 0 = until the next motion).

Continuity: every start begins from the last *commanded* configuration (the measured one
only when nothing was commanded yet); a new motion preempts the running one (PREEMPTED),
and the engine blends its reference in.

The reference follows the clock: the step computed for a deadline evaluates the reference
at that deadline's time since the motion's start (``WholeBodyExecutor.step(t)``), so a late
step never stretches the motion; the next step catches up within the velocity limits over
the elapsed time, every constraint (feet, COG, dampers, joint limits) still enforced.

Starts are reported through ``on_start(motion)``, outcomes through ``on_finish(motion)``
once per motion (``motion.code`` is an
:class:`~humanoid_reach_ros.codes.ExecuteCode`).
"""
from __future__ import annotations

import math
import resource
import threading
import time
import traceback
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from humanoid_reach_ros.codes import ExecuteCode as C
from humanoid_reach_ros.execution.engines import StepOutcome

IDLE, RUN, SETTLE, HOLD = "idle", "running", "settling", "holding"
OVERRUN_LOGS_PER_MOTION = 3           # an overrun logs why (what the solver was doing); at most this many per motion
SLOW_STEP_PERIODS = 2.0               # a step longer than this many periods is logged with its thread's usage ...
SLOW_STEP_LOGS = 5                    # ... the first few of the process, then every 100th


def _thread_usage():
    """The calling thread's ``getrusage`` (Linux), else None."""
    try:
        return resource.getrusage(resource.RUSAGE_THREAD)
    except (AttributeError, OSError):
        return None


def _step_of(motion, ahead: int) -> tuple[int, str]:
    """(number, motion label) of the step computed ``ahead`` steps past the motion's last
    published one ("the hold" without a motion)."""
    return (motion.steps if motion is not None else 0) + ahead + 1, motion.label if motion is not None else "the hold"


def _describe(command: tuple) -> str:
    """What applying a queued command is, for an overrun's report."""
    kind = command[0]
    if kind == "map":
        tree = command[1]
        return f"applying a new map ({getattr(tree, 'n_spheres', 0)} spheres)"
    if kind == "start":
        return f"starting {command[1].label}"
    return f"applying a {kind}"


@dataclass(frozen=True)
class SupervisorConfig:
    period_s: float = 0.005
    hold_settle_s: float = 0.25       # after a cancel / abort the engine keeps solving this long [s]
    hold_timeout_s: float = 0.0       # republish the held command this long after a motion; 0 = forever
    dual_arm_brake_s: float = 0.2     # a stopped dual-arm motion brakes on its path over this long [s]
    lookahead_steps: int = 4          # steps computed before their deadline (1: only the next one)
    step_history: int = 4000          # step times kept for the percentiles
    resume_tolerance_rad: float = 0.0  # idle: start from the last command when every measured joint is this close


@dataclass(eq=False)
class Motion:
    """One execution request and its figures. ``kind``: trajectory | dual | sequential."""

    id: int
    label: str                                  # "goal #3" | "/reach_trajectory #2" | ...
    kind: str = "trajectory"
    spline: Any = None                          # SplineTrajectory (trajectory)
    arm: str = "right"                          # "right" | "left" | "both"
    params: Any = None                          # ExecutorParams (trajectory)
    targets: Any = None                         # (right, left) pin.SE3 in world (dual)
    sequential: tuple | None = None             # (count, seed, pairs) (sequential)
    follow: bool = False                        # dual arm from /dual_arm/targets
    q_measured: np.ndarray | None = None        # start when nothing was commanded yet
    note: str = ""
    # ---- figures
    started: float = math.nan
    ended: float = math.nan
    steps: int = 0
    overruns: int = 0
    max_com_error_m: float = 0.0
    min_distance_m: float = math.inf
    pairs_reached: int = 0
    pairs_skipped: int = 0
    last: Any = None                            # metrics of the last published step
    code: int | None = None
    message: str = ""
    source: str = ""                            # "the last command" | "/joint_states"
    t_origin: float = math.nan                  # clock time of reference t = 0

    @property
    def dual(self) -> bool:
        return self.kind in ("dual", "sequential")

    def summary(self, now: float) -> dict[str, float]:
        last = self.last
        end = self.ended if math.isfinite(self.ended) else now
        return {"duration_s": end - self.started if math.isfinite(self.started) else 0.0,
                "steps": self.steps, "overruns": self.overruns, "max_com_error_m": self.max_com_error_m,
                "min_distance_m": self.min_distance_m,
                "final_hand_error_m": last.hand_error_m if last is not None else 0.0,
                "final_hand_error_rad": last.hand_error_rad if last is not None else 0.0}


@dataclass
class LoopStats:
    """Counters of the tick side (diagnostics)."""

    ticks: int = 0
    published: int = 0
    steps: int = 0
    overruns: int = 0
    missed_deadlines: int = 0
    step_times: deque = field(default_factory=lambda: deque(maxlen=4000))
    hold_step_times: deque = field(default_factory=lambda: deque(maxlen=4000))


class ExecutionSupervisor:
    """The state machine of execution (see the module docstring)."""

    def __init__(self, trajectory_engine, dual_engine=None, config: SupervisorConfig = SupervisorConfig(),
                 clock: Callable[[], float] | None = None,
                 sink: Callable[[np.ndarray, Any, int], None] | None = None,
                 on_finish: Callable[[Motion], None] | None = None,
                 on_start: Callable[[Motion], None] | None = None,
                 log: Callable[[str, str], None] | None = None) -> None:
        self.engines = {"executor": trajectory_engine}
        if dual_engine is not None:
            self.engines["dual"] = dual_engine
        self.config = config
        self.clock = clock or time.monotonic
        self.sink = sink or (lambda joints, metrics, overruns: None)
        self.on_finish = on_finish or (lambda motion: None)
        self.on_start = on_start or (lambda motion: None)
        self.log = log or (lambda level, text: None)
        self._cond = threading.Condition()
        self._pending: list[tuple] = []
        self.mode = IDLE
        self.engine = "executor"                 # which engine made the last command
        self.motion: Motion | None = None        # running (RUN) or None
        # steps computed ahead, oldest first: (motion, outcome); at most config.lookahead_steps
        self._ready: deque[tuple[Motion | None, StepOutcome]] = deque()
        self._starting = False                   # inside an engine start: ticks hold, no overrun
        self.last_q: np.ndarray | None = None
        self.last_joints: np.ndarray | None = None
        self._settle_until = 0.0
        self.hold_since = 0.0
        self._next_deadline = math.nan           # time of the next tick (set by the tick side)
        self._applying = False                   # the solver side is applying queued commands
        self.stats = LoopStats(step_times=deque(maxlen=config.step_history),
                               hold_step_times=deque(maxlen=config.step_history))
        self.last_finished: Motion | None = None
        self.closed = False
        # what the solver side is doing and since when (clock): an overrun says what it waited on
        self._busy: tuple[Any, float] | None = None
        self._last_work_end = math.nan
        self._slow_steps = 0

    # ------------------------------------------------------------ inputs (any thread)
    def submit(self, motion: Motion) -> None:
        """Queue ``motion``; it starts at the solver's next turn and preempts the running one."""
        self._queue(("start", motion))

    def stop(self, motion_id: int | None, code: int, message: str) -> None:
        """Stop motion ``motion_id`` (``None``: whichever runs) with ``code`` and hold."""
        self._queue(("stop", motion_id, int(code), message))

    def set_map(self, tree) -> None:
        """New environment (a ``SphereTree`` or None), applied before the next step."""
        self._queue(("map", tree))

    def close(self, message: str = "the executor is shutting down") -> None:
        with self._cond:
            self.closed = True
            if self.motion is not None:
                self._finish(self.motion, C.ABORTED, message)
                self.motion = None
            self._cond.notify_all()

    def _queue(self, command: tuple) -> None:
        with self._cond:
            self._pending.append(command)
            self._cond.notify_all()

    # ------------------------------------------------------------ state (any thread)
    def status(self) -> dict[str, Any]:
        """A copy of the state for feedback and diagnostics (plain values, picklable).

        Only the copies are taken under the lock the loop's threads share (tens of
        microseconds); the percentiles are computed after it is released, so a caller
        descheduled mid-way never holds up a step."""
        with self._cond:
            m = self.motion
            st = self.stats
            times, hold = list(st.step_times), list(st.hold_step_times)
            dual = self.engines.get("dual")
            out = {"mode": self.mode, "engine": self.engine,
                   "motion_id": m.id if m is not None else None, "motion_label": m.label if m is not None else "",
                   "progress": float(m.last.progress) if m is not None and m.last is not None else 0.0,
                   "last": m.last if m is not None else None,
                   "dual_targets": dual.targets if dual is not None and self.engine == "dual"
                   and self.mode != IDLE else None,
                   "ticks": st.ticks, "published": st.published, "steps": st.steps, "overruns": st.overruns,
                   "missed_deadlines": st.missed_deadlines,
                   "last_joints": None if self.last_joints is None else self.last_joints.copy()}
        t, h = np.asarray(times, float), np.asarray(hold, float)
        out.update({"step_p50_ms": float(np.percentile(t, 50)) * 1e3 if len(t) else 0.0,
                    "step_p99_ms": float(np.percentile(t, 99)) * 1e3 if len(t) else 0.0,
                    "step_max_ms": float(t.max()) * 1e3 if len(t) else 0.0,
                    "hold_step_p99_ms": float(np.percentile(h, 99)) * 1e3 if len(h) else 0.0})
        return out

    # ------------------------------------------------------------ solver side
    def has_work(self) -> bool:
        return bool(self._pending) or (self.mode in (RUN, SETTLE) and len(self._ready) < self._depth)

    @property
    def _depth(self) -> int:
        return max(1, int(self.config.lookahead_steps))

    def wait_for_work(self, timeout: float) -> bool:
        with self._cond:
            if not self.closed and not self.has_work():
                self._cond.wait(timeout)
            return not self.closed and self.has_work()

    def wake(self) -> None:
        with self._cond:
            self._cond.notify_all()

    def sleep_while_idle(self, timeout: float) -> bool:
        """Tick side: while idle with nothing queued (nothing to publish, no deadline to keep),
        sleep until a command arrives or ``timeout`` passes; True if it slept. The next
        deadline is forgotten meanwhile, so a motion started after the sleep takes its
        reference origin from its own start, not from a deadline of before the sleep."""
        with self._cond:
            if not self._idle_now():
                return False
            self._next_deadline = math.nan
            self._cond.wait(timeout)
            return True

    def _idle_now(self) -> bool:
        return self.mode == IDLE and not self._pending and not self._applying and not self.closed

    def work(self) -> None:
        """Apply the queued commands, then compute the next step if one is due."""
        with self._cond:
            commands, self._pending = self._pending, []
            self._applying = bool(commands)
        try:
            for cmd in commands:
                self._busy = (_describe(cmd), self.clock())
                self._apply(cmd)
            if commands:
                with self._cond:
                    self._applying = False
                    self._cond.notify_all()     # a tick side asleep while idle wakes to the new mode
            self._maybe_step()
        except Exception as exc:  # an engine error must not kill the loop: stop and hold
            self.log("error", f"executor step failed: {type(exc).__name__}: {exc}\n{traceback.format_exc()}")
            with self._cond:
                if self.motion is not None:
                    self._finish(self.motion, C.ABORTED, f"executor error: {type(exc).__name__}: {exc}")
                self.motion = None
                self._ready.clear()
                self.mode = HOLD if self.last_q is not None else IDLE
                self.hold_since = self.clock()
                self._starting = False
                self._applying = False
                self._cond.notify_all()
        finally:
            self._busy = None
            self._last_work_end = self.clock()

    def _apply(self, cmd: tuple) -> None:
        kind = cmd[0]
        if kind == "map":
            self.engines["executor"].set_environment(cmd[1])
        elif kind == "start":
            self._start(cmd[1])
        elif kind == "stop":
            _, motion_id, code, message = cmd
            with self._cond:
                current = self.motion
                if motion_id is not None and (current is None or current.id != motion_id):
                    return    # finished or replaced already
                self.motion = None
                if current is not None:
                    self._finish(current, code, message + "; holding the last command")
                if self.mode == IDLE or self.last_q is None:
                    return
                self.mode = SETTLE
                self._settle_until = self.clock() + self.config.hold_settle_s
            self.engines[self.engine].stop(self.config.dual_arm_brake_s)

    def _begin_start(self, motion: Motion):
        """Common part of a start: the start configuration and its source, or None (finished)."""
        with self._cond:
            if motion.code is not None:
                return None
            previous = self.motion
            if self.last_q is not None and (self.mode != IDLE or self._resumable(motion.q_measured)):
                q0, source = self.last_q.copy(), "the last command"
            else:
                q0, source = motion.q_measured, "/joint_states"
            mode_before = self.mode
            self._ready.clear()      # the steps of the previous motion not yet sent are dropped
            self.motion = None
            self._starting = True    # ticks republish the last command meanwhile (not an overrun)
            if q0 is None:
                self._starting = False
                self._finish(motion, C.NO_JOINT_STATES, "no recent /joint_states to start from")
                if previous is not None:
                    self.motion = previous
                return None
        motion.source = source
        return q0, previous, mode_before

    def _resumable(self, q_measured: np.ndarray | None) -> bool:
        """Idle, may a motion start from the last command? When every measured joint is within
        ``resume_tolerance_rad`` of it: the joint driver holds the last command, and a plant whose
        servos sit a little off it under gravity (the physics plant: HRP-2's knees 0.01 rad) would
        otherwise get the measured posture as its next targets and sink by as much each motion."""
        tol = self.config.resume_tolerance_rad
        if tol <= 0.0 or q_measured is None or self.last_q is None:
            return False
        return bool(np.max(np.abs(np.asarray(q_measured)[7:] - self.last_q[7:])) <= tol)

    def _start(self, motion: Motion) -> None:
        """Start ``motion`` from the last commanded configuration (measured when none)."""
        begun = self._begin_start(motion)
        if begun is None:
            return
        q0, previous, mode_before = begun
        if motion.dual:
            was_running = self.engine == "dual"
            plan = self.engines["dual"].start(q0, motion, was_running)
            if not plan.feasible:
                with self._cond:
                    self._starting = False
                    self._finish(motion, C.INVALID_REQUEST, f"infeasible target pair: {plan.reason}; holding")
                    if previous is not None:
                        self._finish(previous, C.PREEMPTED, f"preempted by {motion.label}, which is infeasible; "
                                                            "stopping smoothly and holding")
                        self.mode = SETTLE
                        self._settle_until = self.clock() + self.config.hold_settle_s
                    elif mode_before in (RUN, SETTLE):
                        self.mode = mode_before
                if previous is not None:
                    self.engines[self.engine].stop(self.config.dual_arm_brake_s)
                return
            motion.note = plan.note
            engine = "dual"
        else:
            try:
                self.engines["executor"].start(q0, motion)
            except Exception as exc:
                with self._cond:
                    self._starting = False
                    self._finish(motion, C.ABORTED, f"executor refused the reference: {type(exc).__name__}: {exc}")
                    if previous is not None:
                        self._finish(previous, C.PREEMPTED, f"replaced by {motion.label}, which failed to start")
                        self.mode = SETTLE
                        self._settle_until = self.clock() + self.config.hold_settle_s
                if previous is not None:
                    self.engines[self.engine].stop(self.config.dual_arm_brake_s)
                return
            engine = "executor"
        with self._cond:
            if previous is not None:
                self._finish(previous, C.PREEMPTED, f"preempted by {motion.label} (from the last command)")
            motion.started = self.clock()
            # reference time origin: the step for the next deadline is at t = one period
            period = self.config.period_s
            nxt = self._next_deadline if math.isfinite(self._next_deadline) else motion.started
            if nxt < motion.started:  # the tick is late: the first step goes out at the first deadline after now
                nxt += math.ceil((motion.started - nxt) / period) * period
            motion.t_origin = nxt - period
            self.motion = motion
            self.mode = RUN
            self._starting = False
            self.engine = engine
            self.on_start(motion)

    def _step_time(self, motion: Motion | None, ahead: int = 0) -> float | None:
        """Reference time of the step being computed: that of the deadline it will be sent at,
        ``ahead`` deadlines after the next one (the steps already computed go out first; the
        first deadline after now when the solver runs late)."""
        if motion is None or not math.isfinite(motion.t_origin):
            return None
        period = self.config.period_s
        deadline = self._next_deadline
        now = self.clock()
        if not math.isfinite(deadline):
            deadline = now
        elif now > deadline:  # late: the step goes out at the first deadline after now
            deadline += math.ceil((now - deadline) / period) * period
        return max(deadline + ahead * period - motion.t_origin, period)

    def _maybe_step(self) -> None:
        with self._cond:
            if self.mode not in (RUN, SETTLE) or len(self._ready) >= self._depth:
                return
            engine = self.engine
            settled = self.clock() >= self._settle_until if engine == "executor" \
                else not self.engines["dual"].busy
            if self.mode == SETTLE and settled:
                self.mode = HOLD
                self.hold_since = self.clock()
                return
            motion = self.motion
            ahead = len(self._ready)
            last = self._ready[-1][1].metrics if self._ready else (motion.last if motion is not None else None)
            t = self._step_time(motion, ahead) if self.mode == RUN else None
        self._busy = (("step", motion, ahead), self.clock())   # formatted only by an overrun's report
        w0, r0 = time.perf_counter(), _thread_usage()
        if engine == "executor":
            result = self.engines["executor"].step(t)
        else:
            result = self.engines["dual"].step(t, (motion.steps if motion is not None else 0) + ahead, last)
        wall = time.perf_counter() - w0
        if wall > SLOW_STEP_PERIODS * self.config.period_s:
            self._report_slow_step(motion, ahead, wall, r0, _thread_usage())
        with self._cond:
            if motion is self.motion and self.mode in (RUN, SETTLE):
                self._ready.append((motion, result))

    # ------------------------------------------------------------ tick side
    def tick(self, next_deadline: float | None = None) -> None:
        """One deadline: hand the finished step (or the last safe command) to the sink.
        ``next_deadline``: when the following tick is due (the reference time of the step
        the solver computes next)."""
        out = None
        late = ""
        with self._cond:
            st = self.stats
            st.ticks += 1
            if next_deadline is not None:
                self._next_deadline = next_deadline
            mode = self.mode
            if mode == IDLE:
                return
            cfg = self.config
            if mode == HOLD and cfg.hold_timeout_s > 0 and self.clock() - self.hold_since > cfg.hold_timeout_s:
                self.mode = IDLE
                self.log("info", f"held the last command for {cfg.hold_timeout_s:g} s: stop publishing")
                return
            ready = self._ready.popleft() if self._ready else None
            metrics, overruns = None, 0
            if ready is not None:
                motion, res = ready
                self.last_q, self.last_joints = res.q, res.joints
                m = metrics = res.metrics
                st.steps += 1
                st.step_times.append(m.solve_time_s)
                if motion is None or mode == SETTLE or getattr(m, "progress", 0.0) >= 1.0:
                    st.hold_step_times.append(m.solve_time_s)
                if motion is not None:
                    motion.steps += 1
                    motion.last = m
                    motion.max_com_error_m = max(motion.max_com_error_m, m.com_error_m)
                    motion.min_distance_m = min(motion.min_distance_m, m.min_distance_m)
                    overruns = motion.overruns
                    self._after_step(motion, res)
            elif mode in (RUN, SETTLE) and self.last_q is not None and not self._starting and not (
                    self.motion is not None and self.motion.steps == 0):
                # the step for this deadline is not ready (it overran): hold the last safe command
                # (a motion whose first step is not out yet is still starting: its start IS the last command)
                st.overruns += 1
                if self.motion is not None:
                    self.motion.overruns += 1
                    if self.motion.overruns <= OVERRUN_LOGS_PER_MOTION:
                        late = self._overrun_report(self.motion)
            joints = self.last_joints
            st.published += 1
            self._cond.notify_all()
            if joints is not None:
                out = (joints, metrics, overruns)
        if late:
            self.log("warning", late)
        if out is not None:
            self.sink(*out)

    def _report_slow_step(self, motion: Motion | None, ahead: int, wall: float, r0, r1) -> None:
        """A step that took longer than ``SLOW_STEP_PERIODS`` periods: wall time, the solver
        thread's own CPU time, page faults and context switches (computed, or waited: for the
        interpreter lock, the CPU, memory). The first ``SLOW_STEP_LOGS``, then every 100th."""
        self._slow_steps += 1
        if self._slow_steps > SLOW_STEP_LOGS and self._slow_steps % 100:
            return
        if r0 is None or r1 is None:
            usage = ""
        else:
            usage = (f": {1e3 * (r1.ru_utime - r0.ru_utime + r1.ru_stime - r0.ru_stime):.1f} ms of the solver "
                     f"thread's CPU, {r1.ru_minflt - r0.ru_minflt} page faults, {r1.ru_nvcsw - r0.ru_nvcsw} waits, "
                     f"{r1.ru_nivcsw - r0.ru_nivcsw} preemptions")
        n, label = _step_of(motion, ahead)
        self.log("warning", f"{label}: step {n} took {wall * 1e3:.1f} ms{usage} ({self._slow_steps} slow steps "
                            f"so far)")

    def _overrun_report(self, motion: Motion) -> str:
        """Why the step of this deadline is not ready (caller holds the lock): what the solver
        side is doing and for how long, or how long ago it last finished."""
        now = self.clock()
        busy = self._busy
        if busy is not None:
            what = busy[0]
            if isinstance(what, tuple):     # ("step", motion, ahead)
                n, label = _step_of(what[1], what[2])
                what = f"computing step {n} of {label}"
            doing = f"the solver has been {what} for {(now - busy[1]) * 1e3:.1f} ms"
        elif math.isfinite(self._last_work_end):
            doing = (f"the solver is waiting (last work ended {(now - self._last_work_end) * 1e3:.1f} ms ago: "
                     "it was not scheduled, or the interpreter lock was held elsewhere)")
        else:
            doing = "the solver has not run yet"
        return (f"{motion.label}: overrun at step {motion.steps + 1} (the last command goes out again): {doing}; "
                f"{len(self._pending)} commands queued"
                + ("" if motion.overruns < OVERRUN_LOGS_PER_MOTION else "; further overruns of this motion are "
                   "counted, not logged"))

    def _after_step(self, motion: Motion, res: StepOutcome) -> None:
        """Outcome of a published step (caller holds the lock)."""
        if motion is not self.motion:
            return
        if motion.kind == "sequential":
            if res.pair_done:
                motion.pairs_reached += int(res.ok)
                motion.pairs_skipped += int(not res.ok)
            if not res.done:
                return
            n = motion.sequential[0]
            self._finish(motion, C.SUCCESS, f"{n} random target pairs: {motion.pairs_reached} reached, "
                                            f"{motion.pairs_skipped} infeasible (skipped)")
        elif motion.kind == "dual":
            if not (res.done or not res.ok):
                return
            if res.ok:
                self._finish(motion, C.SUCCESS, "both hands at their targets")
            else:
                self._finish(motion, C.ABORTED, f"dual-arm step failed: {res.reason}; holding")
                self.engines["dual"].targets = None
        else:
            if not res.done:
                return
            conv = self.engines["executor"].converge_position_m
            if res.metrics.hand_error_m <= conv:
                self._finish(motion, C.SUCCESS, "trajectory executed, hand converged")
            else:
                self._finish(motion, C.TARGET_NOT_REACHED,
                             f"the reference ended and the hand stayed {res.metrics.hand_error_m * 1e3:.1f} mm off its "
                             f"end after the settle timeout (min distance {res.metrics.min_distance_m:.4f} m: a "
                             f"collision damper or a joint limit held it); holding here: plan again from here")
        self.motion = None
        self.mode = HOLD
        self.hold_since = self.clock()
        self._ready.clear()      # steps computed past the end are not sent: the hold repeats the end

    def missed(self, count: int) -> None:
        """The tick side skipped ``count`` deadlines (it fell more than a period behind)."""
        with self._cond:
            self.stats.missed_deadlines += count

    # ------------------------------------------------------------ outcomes
    def _finish(self, motion: Motion, code: int, message: str) -> None:
        """Record the outcome of ``motion`` once (caller holds the lock) and report it."""
        if motion.code is not None:
            return
        motion.code, motion.message, motion.ended = int(code), message, self.clock()
        self.last_finished = motion
        try:
            self.on_finish(motion)
        except Exception as exc:  # a reporting failure must not break the state machine
            self.log("error", f"on_finish failed: {type(exc).__name__}: {exc}")


__all__ = ["ExecutionSupervisor", "SupervisorConfig", "Motion", "LoopStats", "IDLE", "RUN", "SETTLE", "HOLD"]
