"""``execution/periodic.py`` without ROS: deadlines, overrun counting, idle restarts, errors, stop.

Most cases run on a fake clock (the sleeps and the ticks' costs advance it), so the deadline
arithmetic is checked exactly; the real-clock cases only check what a loaded machine still
guarantees (ticks happen, deadlines advance by the period, a stop ends the loop), never tight
timing.
"""
from __future__ import annotations

import threading
import time

import pytest

from humanoid_reach_ros.execution.periodic import PeriodicLoop


class FakeTime:
    """A clock that only moves when the loop sleeps or a tick says what it cost."""

    def __init__(self) -> None:
        self.now = 100.0
        self.sleeps: list[float] = []

    def clock(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.sleeps.append(seconds)
        self.now += seconds


def fake_loop(costs: list[float], period: float = 1.0, **kwargs) -> tuple[PeriodicLoop, FakeTime, list]:
    """A loop whose tick ``i`` costs ``costs[i]`` seconds; it stops after the last one.
    Returns the loop, the clock and the ticks' ``(start time, next deadline)``."""
    ft = FakeTime()
    seen: list[tuple[float, float]] = []

    def tick(due: float) -> None:
        seen.append((ft.now, due))
        ft.now += costs[len(seen) - 1]
        if len(seen) == len(costs):
            loop.stop()

    loop = PeriodicLoop(period, tick, clock=ft.clock, sleep=ft.sleep, **kwargs)
    return loop, ft, seen


def test_ticks_at_absolute_deadlines_without_drift():
    loop, ft, seen = fake_loop([0.25] * 5)
    loop.run()
    starts = [t - 100.0 for t, _ in seen]
    assert starts == pytest.approx([0, 1, 2, 3, 4])          # the tick's cost does not shift the next one
    assert [d - 100.0 for _, d in seen] == pytest.approx([1, 2, 3, 4, 5])   # each told the next deadline
    assert ft.sleeps == pytest.approx([0.75] * 4)
    assert (loop.ticks, loop.late_ticks, loop.overruns, loop.skipped) == (5, 0, 0, 0)


def test_first_tick_one_period_after_the_start():
    loop, ft, seen = fake_loop([0.0] * 3, period=0.5, first_tick_now=False)
    loop.run()
    assert [t - 100.0 for t, _ in seen] == pytest.approx([0.5, 1.0, 1.5])
    assert seen[0][1] - 100.0 == pytest.approx(1.0)


def test_overrun_skips_missed_deadlines_and_counts_them():
    missed: list[int] = []
    # tick 0 takes 3.5 periods: deadlines 1 and 2 are skipped, deadline 3 (already past) runs at once
    loop, ft, seen = fake_loop([3.5, 0.1, 0.1, 0.1], on_missed=missed.append)
    loop.run()
    assert [t - 100.0 for t, _ in seen] == pytest.approx([0.0, 3.5, 4.0, 5.0])
    assert [d - 100.0 for _, d in seen] == pytest.approx([1.0, 4.0, 5.0, 6.0])
    assert missed == [2]
    assert (loop.overruns, loop.skipped, loop.late_ticks, loop.ticks) == (1, 2, 1, 4)


def test_late_by_less_than_a_period_runs_at_once_without_skipping():
    loop, ft, seen = fake_loop([1.5, 0.1, 0.1])
    loop.run()
    assert [t - 100.0 for t, _ in seen] == pytest.approx([0.0, 1.5, 2.0])
    assert (loop.overruns, loop.skipped, loop.late_ticks) == (0, 0, 1)


def test_idle_restarts_the_deadlines():
    ft = FakeTime()
    seen: list[float] = []
    idle_answers = iter([False, False, True, False, False])

    def idle() -> bool:
        slept = next(idle_answers)
        if slept:
            ft.now += 7.3          # slept while idle
        return slept

    def tick(due: float) -> None:
        seen.append(ft.now - 100.0)
        if len(seen) == 4:
            loop.stop()

    loop = PeriodicLoop(1.0, tick, idle=idle, clock=ft.clock, sleep=ft.sleep)
    loop.run()
    assert seen == pytest.approx([0.0, 1.0, 8.3, 9.3])     # after the idle sleep: deadlines from then
    assert loop.overruns == 0


def test_errors_go_to_on_error_and_the_loop_goes_on():
    ft = FakeTime()
    errors: list[Exception] = []
    calls = []

    def tick(due: float) -> None:
        calls.append(due)
        if len(calls) == 3:
            loop.stop()
        if len(calls) == 2:
            raise RuntimeError("boom")

    loop = PeriodicLoop(1.0, tick, on_error=errors.append, clock=ft.clock, sleep=ft.sleep)
    loop.run()
    assert len(calls) == 3 and loop.errors == 1
    assert [str(e) for e in errors] == ["boom"]


def test_an_error_while_stopping_ends_the_loop_quietly():
    ft = FakeTime()
    errors: list[Exception] = []

    def tick(due: float) -> None:
        loop.stop()
        raise RuntimeError("context shut down")

    loop = PeriodicLoop(1.0, tick, on_error=errors.append, clock=ft.clock, sleep=ft.sleep)
    loop.run()
    assert errors == [] and loop.ticks == 0


def test_period_must_be_positive():
    with pytest.raises(ValueError):
        PeriodicLoop(0.0, lambda due: None)


# ---------------------------------------------------------------- real clock (generous tolerances)
def _run_in_thread(loop: PeriodicLoop) -> threading.Thread:
    thread = threading.Thread(target=loop.run, name="test_periodic", daemon=True)
    thread.start()
    return thread


def test_real_clock_ticks_advance_by_the_period_and_stop_ends_the_thread():
    period = 0.005
    dues: list[float] = []
    loop = PeriodicLoop(period, dues.append)
    thread = _run_in_thread(loop)
    time.sleep(0.3)
    loop.stop()
    thread.join(5.0)
    assert not thread.is_alive()
    assert len(dues) >= 5                        # at 200 Hz, 0.3 s: ~60; a loaded machine still gets a few
    assert len(dues) <= 0.3 / period * 3 + 10    # never a burst
    steps = [b - a for a, b in zip(dues, dues[1:])]
    # consecutive deadlines are whole periods apart (more than one when deadlines were skipped)
    assert all(s >= period * 0.999 and abs(s / period - round(s / period)) < 1e-6 for s in steps)
    assert loop.ticks == len(dues)


def test_real_clock_stop_interrupts_a_long_sleep():
    loop = PeriodicLoop(30.0, lambda due: None, first_tick_now=False)
    thread = _run_in_thread(loop)
    time.sleep(0.05)
    t = time.monotonic()
    loop.stop()
    thread.join(10.0)
    assert not thread.is_alive()
    assert time.monotonic() - t < 10.0           # far less than the 30 s period
    assert loop.ticks <= 1


def test_real_clock_counts_overruns_of_a_slow_tick():
    period = 0.002
    loop = PeriodicLoop(period, lambda due: time.sleep(0.02))   # each tick ~10 periods
    thread = _run_in_thread(loop)
    time.sleep(0.2)
    loop.stop()
    thread.join(5.0)
    assert not thread.is_alive()
    assert loop.ticks >= 1
    assert loop.overruns >= 1 and loop.skipped >= 5 * loop.overruns
