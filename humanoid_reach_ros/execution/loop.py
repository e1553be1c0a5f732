"""The control loop: a tick thread at absolute deadlines and a solver thread.

* The **tick thread** runs a :class:`~humanoid_reach_ros.execution.periodic.PeriodicLoop`:
  it wakes at ``t_0 + k period_s`` (no drift, ``time.sleep`` for the finest wake-up) and calls
  :meth:`ExecutionSupervisor.tick` (publish the finished step or the last safe command).
  When it falls more than one period behind, the missed deadlines are skipped and counted
  (:meth:`ExecutionSupervisor.missed`), never burst. While the supervisor is idle (nothing
  commanded yet, or the hold timed out) it sleeps until a command arrives
  (:meth:`ExecutionSupervisor.sleep_while_idle`) and restarts its deadlines from then.
* The **solver thread** calls :meth:`ExecutionSupervisor.work` whenever there is work: the
  queued commands and the next step, computed as soon as the previous one was consumed.

Both threads ask for ``SCHED_FIFO`` (tick ``rt_priority``, solver one below) where the OS
allows it (:mod:`humanoid_reach_ros.execution.realtime`); the outcome is in
:attr:`ControlLoop.realtime`.
"""
from __future__ import annotations

import threading
import time
from typing import Callable

from humanoid_reach_ros.execution.periodic import PeriodicLoop
from humanoid_reach_ros.execution.realtime import make_thread_realtime
from humanoid_reach_ros.execution.supervisor import ExecutionSupervisor


class ControlLoop:
    def __init__(self, supervisor: ExecutionSupervisor, period_s: float, rt_priority: int = 0,
                 on_error: Callable[[str], None] | None = None) -> None:
        self.sup = supervisor
        self.period_s = float(period_s)
        self.rt_priority = int(rt_priority)
        self.on_error = on_error or (lambda text: None)
        self.realtime: dict[str, str] = {}
        self._ticks = PeriodicLoop(self.period_s, supervisor.tick, on_error=self._tick_failed,
                                   on_missed=supervisor.missed, idle=lambda: supervisor.sleep_while_idle(0.5),
                                   sleep=time.sleep)
        self._tick_thread = threading.Thread(target=self._run_ticks, name="executor_ticks", daemon=True)
        self._solver_thread = threading.Thread(target=self._run_solver, name="executor_solver", daemon=True)
        self._rt_ready = threading.Barrier(3)

    def start(self) -> dict[str, str]:
        """Start both threads; returns what real-time scheduling each got."""
        self._tick_thread.start()
        self._solver_thread.start()
        self._rt_ready.wait(10.0)
        return dict(self.realtime)

    def stop(self, timeout: float = 2.0) -> None:
        self._ticks.stop()
        self.sup.wake()
        for t in (self._tick_thread, self._solver_thread):
            if t.is_alive():
                t.join(timeout)

    def _set_priority(self, name: str, priority: int) -> None:
        ok, message = make_thread_realtime(priority)
        self.realtime[name] = message
        try:
            self._rt_ready.wait(10.0)
        except threading.BrokenBarrierError:
            pass

    def _run_solver(self) -> None:
        self._set_priority("solver", self.rt_priority - 1 if self.rt_priority > 1 else self.rt_priority)
        while not self._ticks.stopped:
            if self.sup.wait_for_work(0.1):
                self.sup.work()

    def _run_ticks(self) -> None:
        self._set_priority("tick", self.rt_priority)
        self._ticks.run()

    def _tick_failed(self, exc: Exception) -> None:
        self.on_error(f"tick failed: {type(exc).__name__}: {exc}")


__all__ = ["ControlLoop"]
