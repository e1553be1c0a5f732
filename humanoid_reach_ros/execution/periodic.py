"""The periodic loop: a tick callback at absolute deadlines on a monotonic clock.

One primitive for the package's deadline loops (the executor's 5 ms tick thread,
:class:`~humanoid_reach_ros.execution.loop.ControlLoop`, and the simulated robot's 200 Hz
loop in ``nodes/joint_driver.py``), so that both keep the same rules:

* tick ``k`` is due at ``t_0 + k period_s`` (absolute: no drift; the loop sleeps until the
  deadline, or runs the tick at once when it is already past);
* the tick callback is given the deadline of the *following* tick (when its work is due);
* a loop that finished a tick more than one whole period behind its next deadline skips the
  missed deadlines (never bursts to catch up) and counts them (:attr:`PeriodicLoop.skipped`,
  :attr:`PeriodicLoop.overruns`, and ``on_missed(count)``);
* an optional ``idle`` callback, asked before every tick, may sleep while there is nothing to
  do; when it says it slept, the deadlines restart from then;
* the stop event is checked once per tick; a tick that raises goes to ``on_error`` (unless
  the loop is stopping, when the loop just ends).

It runs in the caller's thread (:meth:`PeriodicLoop.run`): the caller sets its thread up
(name, real-time priority) first. Nothing here imports ROS.
"""
from __future__ import annotations

import threading
import time
from typing import Callable


class PeriodicLoop:
    """Calls ``tick(next_deadline)`` every ``period_s`` at absolute deadlines until :meth:`stop`.

    ``sleep``: how to wait for a deadline; by default the stop event's wait (a stop wakes the
    loop at once); ``time.sleep`` where the wake-up precision matters more than the stop.
    ``first_tick_now``: the first tick runs at once (deadline ``t_0``), else one period after
    the start. ``clock``: the monotonic clock of the deadlines (tests may inject one).
    """

    def __init__(self, period_s: float, tick: Callable[[float], object], *,
                 on_error: Callable[[Exception], object] | None = None,
                 on_missed: Callable[[int], object] | None = None,
                 idle: Callable[[], bool] | None = None,
                 stop_event: threading.Event | None = None,
                 sleep: Callable[[float], object] | None = None,
                 clock: Callable[[], float] = time.monotonic,
                 first_tick_now: bool = True) -> None:
        if not period_s > 0:
            raise ValueError(f"period_s must be > 0, got {period_s!r}")
        self.period_s = float(period_s)
        self._tick = tick
        self._on_error = on_error
        self._on_missed = on_missed
        self._idle = idle
        self.stop_event = stop_event if stop_event is not None else threading.Event()
        self._sleep = sleep if sleep is not None else self.stop_event.wait
        self._clock = clock
        self._k0 = 0 if first_tick_now else 1
        self.ticks = 0          # ticks run
        self.late_ticks = 0     # ticks that found their deadline already past (ran without sleeping)
        self.overruns = 0       # times the loop fell more than a period behind and skipped
        self.skipped = 0        # deadlines skipped in all
        self.errors = 0         # ticks that raised

    @property
    def stopped(self) -> bool:
        return self.stop_event.is_set()

    def stop(self) -> None:
        """Ask the loop to end (it ends before its next tick; the thread running it is the caller's)."""
        self.stop_event.set()

    def run(self) -> None:
        """The loop, in the calling thread, until :meth:`stop` (or a tick raises while stopping)."""
        period, clock, stop = self.period_s, self._clock, self.stop_event
        t0 = clock()
        k = self._k0
        while not stop.is_set():
            if self._idle is not None and self._idle():   # nothing to do: no wake-up per period
                t0, k = clock(), self._k0
                continue
            delay = t0 + k * period - clock()
            if delay > 0:
                self._sleep(delay)
            elif k > 0:
                self.late_ticks += 1
            try:
                self._tick(t0 + (k + 1) * period)
            except Exception as exc:  # e.g. publishing while the process shuts down
                if stop.is_set():
                    return
                self.errors += 1
                if self._on_error is not None:
                    self._on_error(exc)
            self.ticks += 1
            k += 1
            behind = clock() - (t0 + k * period)
            if behind > period:  # more than a whole period late: skip the missed deadlines
                skipped = int(behind // period)
                k += skipped
                self.overruns += 1
                self.skipped += skipped
                if self._on_missed is not None:
                    self._on_missed(skipped)


__all__ = ["PeriodicLoop"]
