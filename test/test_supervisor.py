"""The execution supervisor without ROS and without threads: an injected clock, a recording
command sink and a scripted engine; the solver and tick sides are called by the test in the
order the loop would call them (or out of it, to make a step late)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from humanoid_reach_ros.codes import ExecuteCode as C
from humanoid_reach_ros.execution.engines import StepOutcome
from humanoid_reach_ros.execution.supervisor import (HOLD, IDLE, RUN, SETTLE, ExecutionSupervisor, Motion,
                                                    SupervisorConfig)

DT = 0.005
NQ = 7 + 3


@dataclass(frozen=True)
class M:
    """Metrics of the scripted engine (the fields the supervisor reads)."""

    t: float
    progress: float
    solve_time_s: float = 1e-4
    com_error_m: float = 0.0
    min_distance_m: float = 1.0
    hand_error_m: float = 0.0
    hand_error_rad: float = 0.0


class FakeEngine:
    """Joints = start joints + v * t (reference time); done at ``duration``; ``fail_at`` raises."""

    name = "executor"
    converge_position_m = 1e-3

    def __init__(self) -> None:
        self.q0 = None
        self.duration = 0.0
        self.t = 0.0
        self.holding = False
        self.times: list[float | None] = []
        self.fail_at: int | None = None
        self.maps = []
        self.v = 1.0
        self.final_hand_error_m = 0.0       # hand error reported once the reference has ended

    def start(self, q0, motion) -> None:
        if motion.spline == "refuse":
            raise ValueError("bad reference")
        self.q0, self.duration, self.t, self.holding = np.array(q0, float), float(motion.spline), 0.0, False

    def step(self, t):
        self.times.append(t)
        if self.fail_at is not None and len(self.times) >= self.fail_at:
            raise RuntimeError("boom")
        if not self.holding:
            self.t = self.t + DT if t is None else t
        q = self.q0.copy()
        q[7:] += self.v * min(self.t, self.duration)
        done = self.holding or self.t >= self.duration
        err = self.final_hand_error_m if done else 0.0
        return StepOutcome(q, q[7:].copy(), M(self.t, min(self.t / self.duration, 1.0) if self.duration else 1.0,
                                              hand_error_m=err, min_distance_m=0.004 if err else 1.0), done)

    def stop(self, brake_s) -> None:
        self.holding = True
        self.q0[7:] += self.v * min(self.t, self.duration)
        self.t = 0.0
        self.duration = 0.0

    def set_environment(self, tree) -> None:
        self.maps.append(tree)


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


class Harness:
    def __init__(self, **cfg) -> None:
        self.clock = Clock()
        self.engine = FakeEngine()
        self.sent: list[np.ndarray] = []
        self.finished: list[Motion] = []
        self.started: list[Motion] = []
        self.sup = ExecutionSupervisor(self.engine, None, SupervisorConfig(period_s=DT, **cfg), self.clock,
                                       lambda j, m, o: self.sent.append(np.array(j)), self.finished.append,
                                       self.started.append)
        self.k = 0

    def deadline(self) -> float:
        return 100.0 + self.k * DT

    def cycle(self, solve: bool = True) -> None:
        """One period as the loop runs it: the solver works (if ``solve``), then the tick at the deadline."""
        if solve:
            self.sup.work()
        self.k += 1
        self.clock.now = self.deadline()
        self.sup.tick(self.deadline() + DT)

    def motion(self, mid: int, duration: float = 0.1, q=None) -> Motion:
        q = np.zeros(NQ) if q is None else q
        return Motion(mid, f"m{mid}", "trajectory", spline=duration, arm="right", q_measured=q)


def test_runs_a_motion_to_success_and_holds_the_last_command() -> None:
    h = Harness()
    h.sup.tick(h.deadline() + DT)                 # the loop is ticking before anything is sent
    assert h.sup.mode == IDLE and not h.sent      # nothing commanded: nothing published
    h.sup.submit(h.motion(1, duration=0.1))
    for _ in range(40):
        h.cycle()
    assert [m.id for m in h.started] == [1]
    assert len(h.finished) == 1 and h.finished[0].code == C.SUCCESS
    m = h.finished[0]
    assert m.steps == pytest.approx(0.1 / DT, abs=1) and m.overruns == 0
    assert h.sup.mode == HOLD
    assert np.allclose(h.sent[-1], 0.1) and np.allclose(h.sent[-5], 0.1)   # held: the same command every period
    # the reference time of every step is that of the deadline it was sent at
    t = np.array([x for x in h.engine.times[:20]])
    assert np.allclose(np.diff(t), DT)


def test_a_hand_held_off_the_end_is_target_not_reached_not_success() -> None:
    """The reference ran out (settle timeout) with the hand 0.65 m off its end, as a damper held
    it behind a pipe: TARGET_NOT_REACHED naming the error and the distance, and the robot holds."""
    h = Harness()
    h.engine.final_hand_error_m = 0.65
    h.sup.submit(h.motion(1, duration=0.05))
    for _ in range(30):
        h.cycle()
    m = h.finished[0]
    assert m.code == C.TARGET_NOT_REACHED, m.message
    assert "650.0 mm off" in m.message and "0.0040 m" in m.message and "plan again" in m.message
    assert h.sup.mode == HOLD


def test_overrun_republishes_the_last_command_and_the_motion_is_not_stretched() -> None:
    h = Harness()
    h.sup.submit(h.motion(1, duration=0.2))
    for i in range(60):
        h.cycle(solve=(i % 10 != 5))          # every 10th period the solver misses its deadline
    m = h.finished[0]
    assert m.code == C.SUCCESS
    assert m.overruns >= 4 and h.sup.stats.overruns == m.overruns
    J = np.array(h.sent)
    repeats = int(np.sum(np.all(np.diff(J, axis=0) == 0.0, axis=1)))
    assert repeats >= m.overruns                     # a missed deadline re-sends the last command exactly
    # the reference follows the clock: finished at the same deadline as without overruns (not stretched)
    t = [x for x in h.engine.times if x is not None]
    assert max(t) == pytest.approx(0.2, abs=DT + 1e-9)
    assert m.steps < 0.2 / DT                        # fewer steps, not a longer motion


def test_late_solver_evaluates_at_the_deadline_it_will_be_sent_at() -> None:
    h = Harness()
    h.sup.submit(h.motion(1, duration=1.0))
    h.cycle()                                   # start
    h.cycle()
    t_before = h.engine.times[-1]
    # the solver runs 2.5 periods after the last tick's deadline: its step goes out at the 3rd deadline
    h.clock.now = h.deadline() + 2.5 * DT
    h.sup.work()
    assert h.engine.times[-1] == pytest.approx(t_before + 3 * DT)


def test_a_motion_started_while_the_tick_is_late_is_not_shortened() -> None:
    """The tick thread woke late (its next deadline already past when the motion starts): the
    reference's origin is the first deadline after the start, so the motion lasts its whole
    duration from its start (ci43: 2.3558 s of a 2.3610 s reference, 0.2 ms beyond a period)."""
    h = Harness()
    h.sup.tick(h.deadline() + DT)                 # ticking; its next deadline is 100.005
    h.clock.now = h.deadline() + 2.3 * DT         # the motion comes 1.3 periods after that deadline
    h.sup.submit(h.motion(1, duration=0.2))
    start = h.clock.now
    h.k += 3                                      # the next tick is the first deadline after now
    for _ in range(80):
        h.sup.work()
        h.clock.now = h.deadline()
        h.sup.tick(h.deadline() + DT)
        h.k += 1
    m = h.finished[0]
    assert m.code == C.SUCCESS
    assert m.ended - start >= 0.2 - DT - 1e-9, m.ended - start
    assert m.summary(h.clock.now)["duration_s"] >= 0.2 - DT - 1e-9


def fill(h: Harness) -> None:
    """The solver as the threaded loop runs it: it works while there is work (the queued
    commands, then steps until ``lookahead_steps`` are computed ahead)."""
    for _ in range(10):
        if not h.sup.has_work():
            return
        h.sup.work()


def test_lookahead_steps_absorb_a_solver_that_misses_a_period() -> None:
    """With two steps computed ahead, a solver that does not run for a whole period (a late
    wake-up) costs no overrun: the tick sends the step computed ahead, each step evaluated at
    the deadline it goes out at; with one step ahead the same pattern overruns."""
    for depth, overruns in ((2, 0), (1, 5)):
        h = Harness(lookahead_steps=depth)
        h.sup.tick(h.deadline() + DT)           # the loop is ticking when the motion comes
        h.sup.submit(h.motion(1, duration=0.3))
        for i in range(80):
            if i % 10 != 5:                     # every 10th period the solver does not run
                fill(h)
            h.k += 1
            h.clock.now = h.deadline()
            h.sup.tick(h.deadline() + DT)
        m = h.finished[0]
        assert m.code == C.SUCCESS and m.overruns >= overruns and (m.overruns == 0) == (overruns == 0), (depth, m)
        t = np.array([x for x in h.engine.times if x is not None])
        if depth == 2:
            assert np.allclose(np.diff(t[t <= 0.3]), DT)   # one step per deadline, none skipped or repeated
            J = np.array(h.sent)
            # the command at the k-th deadline is the reference at that deadline (joints = v t)
            moving = J[:, 0] < 0.3 - 1e-9
            assert np.allclose(np.diff(J[moving, 0]), DT)


def test_lookahead_a_start_drops_the_steps_computed_ahead_and_the_hold_repeats_the_end() -> None:
    """A preemption begins from the last *published* command (the steps computed ahead of it
    are dropped); steps computed past a motion's end are never sent: the hold repeats the end."""
    h = Harness(lookahead_steps=3)
    h.sup.submit(h.motion(1, duration=1.0))
    for _ in range(20):
        fill(h)
        h.cycle(solve=False)
    assert len(h.sup._ready) == 3 - 1           # computed ahead of the deadlines to come
    last = h.sent[-1].copy()
    h.sup.submit(h.motion(2, duration=0.05))
    fill(h)
    assert np.allclose(h.engine.q0[7:], last)  # from the last published command, not the computed ahead
    for _ in range(30):
        fill(h)
        h.cycle(solve=False)
    assert h.finished[-1].id == 2 and h.finished[-1].code == C.SUCCESS and h.sup.mode == HOLD
    end = last + 0.05
    assert np.allclose(h.sent[-1], end) and not h.sup._ready
    J = np.array(h.sent)
    assert J[:, 0].max() == pytest.approx(end[0])   # nothing computed past the end went out


def test_cancel_settles_then_holds_and_hold_timeout_goes_idle() -> None:
    h = Harness(hold_settle_s=0.02, hold_timeout_s=0.05)
    h.sup.submit(h.motion(1, duration=1.0))
    for _ in range(10):
        h.cycle()
    h.sup.stop(1, C.CANCELED, "canceled by the client")
    h.cycle()
    assert h.finished[0].code == C.CANCELED and "holding" in h.finished[0].message
    assert h.sup.mode == SETTLE and h.engine.holding
    for _ in range(8):
        h.cycle()
    assert h.sup.mode == HOLD
    n = len(h.sent)
    for _ in range(15):
        h.cycle()
    assert h.sup.mode == IDLE and len(h.sent) < n + 15   # stopped publishing after hold_timeout_s
    # a stop for a motion that is not running is a no-op
    h.sup.stop(7, C.CANCELED, "late")
    h.cycle()
    assert len(h.finished) == 1


def test_preemption_starts_from_the_last_command() -> None:
    h = Harness()
    h.sup.submit(h.motion(1, duration=1.0))
    for _ in range(20):
        h.cycle()
    last = h.sent[-1].copy()
    h.sup.submit(h.motion(2, duration=0.05, q=np.full(NQ, 9.0)))   # its measured start is ignored
    for _ in range(3):
        h.cycle()
    assert h.finished[0].id == 1 and h.finished[0].code == C.PREEMPTED
    assert h.started[-1].id == 2 and h.started[-1].source == "the last command"
    assert np.allclose(h.engine.q0[7:], last)      # continuity: from the last command, not the measured 9.0
    for _ in range(20):
        h.cycle()
    assert h.finished[-1].id == 2 and h.finished[-1].code == C.SUCCESS


def test_engine_error_aborts_and_holds_and_a_refused_start_aborts_only_itself() -> None:
    h = Harness()
    h.engine.fail_at = 5
    h.sup.submit(h.motion(1, duration=1.0))
    for _ in range(10):
        h.cycle()
    assert h.finished[0].code == C.ABORTED and "executor error: RuntimeError: boom" in h.finished[0].message
    assert h.sup.mode == HOLD
    h.engine.fail_at = None
    bad = h.motion(2)
    bad.spline = "refuse"
    h.sup.submit(bad)
    h.cycle()
    assert h.finished[-1].code == C.ABORTED and "refused the reference" in h.finished[-1].message
    h.sup.submit(h.motion(3, duration=0.02))
    for _ in range(10):
        h.cycle()
    assert h.finished[-1].id == 3 and h.finished[-1].code == C.SUCCESS


def test_idle_start_needs_a_measured_configuration_and_close_aborts() -> None:
    h = Harness()
    m = h.motion(1)
    m.q_measured = None
    h.sup.submit(m)
    h.cycle()
    assert h.finished[0].code == C.NO_JOINT_STATES and h.sup.mode == IDLE and not h.sent
    h.sup.submit(h.motion(2, duration=1.0))
    h.cycle()
    h.cycle()
    h.sup.close("shutting down")
    assert h.finished[-1].code == C.ABORTED
    st = h.sup.status()
    assert st["mode"] == RUN and st["motion_id"] is None and math.isfinite(st["step_p99_ms"])


def test_maps_reach_the_engine_before_the_next_step() -> None:
    h = Harness()
    h.sup.set_map("tree-1")
    h.sup.work()
    assert h.engine.maps == ["tree-1"]


def test_idle_tick_side_sleeps_and_a_later_start_takes_its_origin_from_its_start() -> None:
    """Idle (nothing commanded, or the hold timed out): the tick side may sleep, and forgets the
    next deadline, so a motion started long after the sleep begins at reference time one
    period, not at the time elapsed since the last deadline."""
    h = Harness(hold_timeout_s=0.02)
    for _ in range(3):
        h.cycle()
    assert h.sup.mode == IDLE and h.sup.sleep_while_idle(0.0)
    h.sup.submit(h.motion(1, duration=0.05))
    assert not h.sup.sleep_while_idle(0.0)                 # a queued start: no sleep
    h.k += 2000                                            # 10 s later
    h.clock.now = h.deadline()
    h.cycle()
    assert h.engine.times[0] == pytest.approx(DT)          # the first step at t = one period
    assert not h.sup.sleep_while_idle(0.0)                 # running
    while h.sup.mode != IDLE:                              # the motion, the hold, its timeout
        h.cycle()
    assert h.finished[0].code == C.SUCCESS and h.sup.sleep_while_idle(0.0)


def test_control_loop_sleeps_while_idle_and_runs_a_motion_promptly() -> None:
    """The threaded loop on the real clock: no tick per period while idle; a motion submitted
    then runs to its end and the loop goes back to sleep after the hold timeout."""
    import time

    from humanoid_reach_ros.execution.loop import ControlLoop

    engine, sent, finished = FakeEngine(), [], []
    sup = ExecutionSupervisor(engine, None, SupervisorConfig(period_s=DT, hold_timeout_s=0.1), time.monotonic,
                              lambda j, m, o: sent.append(np.array(j)), finished.append, lambda m: None)
    loop = ControlLoop(sup, DT)
    loop.start()
    try:
        t0 = time.monotonic()
        while time.monotonic() - t0 < 0.5:
            time.sleep(0.05)
        assert sup.stats.ticks <= 3                         # asleep, not 100 ticks
        sup.submit(Motion(1, "m1", "trajectory", spline=0.2, arm="right", q_measured=np.zeros(NQ)))
        deadline = time.monotonic() + 30.0
        while not finished and time.monotonic() < deadline:
            time.sleep(0.01)
        assert finished and finished[0].code == C.SUCCESS
        while sup.mode != IDLE and time.monotonic() < deadline:
            time.sleep(0.01)
        assert sup.mode == IDLE and len(sent) >= 40          # 0.2 s of steps, then 0.1 s of hold
        ticks = sup.stats.ticks
        t0 = time.monotonic()
        while time.monotonic() - t0 < 0.5:
            time.sleep(0.05)
        assert sup.stats.ticks - ticks <= 3                 # asleep again
    finally:
        loop.stop()


def test_an_overrun_says_what_the_solver_was_doing() -> None:
    """An overrun logs why (at most OVERRUN_LOGS_PER_MOTION lines a motion): the solver busy on a
    step for so long (the deadlines pass while it computes), or not running at all (not
    scheduled)."""
    from humanoid_reach_ros.execution.supervisor import OVERRUN_LOGS_PER_MOTION
    h = Harness()
    logs: list[tuple[str, str]] = []
    h.sup.log = lambda level, text: logs.append((level, text))
    engine_step = h.engine.step

    def slow_step(t):       # step 10 takes 2 periods: the tick thread meets the deadlines meanwhile
        if len(h.engine.times) == 9:
            for _ in range(2):
                h.k += 1
                h.clock.now = h.deadline()
                h.sup.tick(h.deadline() + DT)
        return engine_step(t)
    h.engine.step = slow_step
    h.sup.submit(h.motion(1, duration=0.3))
    for _ in range(30):
        h.cycle()
    busy = [text for level, text in logs if level == "warning"]
    assert 1 <= len(busy) < OVERRUN_LOGS_PER_MOTION and all("m1: overrun at step" in t for t in busy), logs
    assert "the solver has been computing step" in busy[0] and "of m1 for" in busy[0], busy[0]
    h.engine.step = engine_step
    for i in range(20):
        h.cycle(solve=(i % 2 == 0))                # the solver misses every other deadline
    waiting = [text for level, text in logs if level == "warning"][len(busy):]
    assert len(busy) + len(waiting) == OVERRUN_LOGS_PER_MOTION and "counted, not logged" in waiting[-1]
    assert any("the solver is waiting (last work ended" in t for t in waiting), waiting
    m = h.sup.motion or h.finished[0]
    assert m.overruns > OVERRUN_LOGS_PER_MOTION



def test_a_slow_step_is_logged_with_what_its_thread_did() -> None:
    """A step longer than SLOW_STEP_PERIODS periods is logged with the solver thread's CPU time,
    page faults, waits and preemptions: a step that computes (a first call) and one that waits
    (the interpreter lock, the CPU) read differently."""
    import time

    from humanoid_reach_ros.execution.supervisor import SLOW_STEP_PERIODS
    h = Harness()
    logs: list[str] = []
    h.sup.log = lambda level, text: logs.append(text)
    engine_step = h.engine.step

    def slow_step(t):
        if len(h.engine.times) == 4:
            time.sleep(SLOW_STEP_PERIODS * DT + 0.01)      # waits: little CPU
        return engine_step(t)
    h.engine.step = slow_step
    h.sup.submit(h.motion(1, duration=0.1))
    for _ in range(10):
        h.cycle()
    slow = [t for t in logs if "took" in t]
    assert len(slow) == 1 and "m1: step 5 took" in slow[0] and "ms of the solver thread's CPU" in slow[0], logs
    cpu = float(slow[0].split("took ")[1].split(" ms: ")[1].split(" ms")[0])
    assert cpu < SLOW_STEP_PERIODS * DT * 1e3, slow[0]     # it slept: the wall time is not CPU time


@pytest.mark.parametrize("offset, tol, source", [(0.01, 0.05, "the last command"), (0.2, 0.05, "/joint_states"),
                                                 (0.01, 0.0, "/joint_states")])
def test_an_idle_start_resumes_from_the_last_command_when_the_measured_joints_are_close(offset, tol, source) -> None:
    """After hold_timeout_s the executor is idle; the joint driver still holds its last command. A
    plant whose servos sit off it under gravity (the physics plant) reports measured joints a little
    off: within resume_tolerance_rad the next motion starts from the last command, else (someone
    moved the robot, or the tolerance is 0) from the measured joints."""
    h = Harness(hold_timeout_s=0.02, resume_tolerance_rad=tol)
    h.sup.submit(h.motion(1, duration=0.05))
    for _ in range(30):
        h.cycle()
    assert h.sup.mode == IDLE
    last = h.sent[-1].copy()
    q = np.zeros(NQ)
    q[7:] = last + offset                       # the measured joints
    h.sup.submit(h.motion(2, duration=0.05, q=q))
    h.cycle()
    assert h.started[-1].id == 2 and h.started[-1].source == source
    assert np.allclose(h.engine.q0[7:], last if source == "the last command" else q[7:])
