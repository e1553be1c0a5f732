"""The control loop: a tick thread at absolute deadlines and a solver thread.

* The **tick thread** wakes at ``t_0 + k period_s`` (no drift) and calls
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

:class:`Outbox` takes publishing off the tick thread (ros2_control's ``RealtimePublisher``
idea): the tick hands each command over and returns; a thread of its own publishes them, in
order. Why: a DDS write can block, most when a subscriber joins the topic (Fast DDS
documents it; measured in this graph: 2-6 ms waits several times a minute, once 335 ms in a
fresh graph's first motion, while the tick thread missed 67 deadlines and the solver's steps
lined up behind it). The deadlines now hold whatever DDS does; a blocked write delays the
commands behind it, which then go out as a burst (the simulated driver plays a burst
through; a real driver sees what any late delivery gives it).
"""
from __future__ import annotations

import threading
import time
from collections import deque
from typing import Any, Callable

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
        self._stop = False
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
        self._stop = True
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
        while not self._stop:
            if self.sup.wait_for_work(0.1):
                self.sup.work()

    def _run_ticks(self) -> None:
        self._set_priority("tick", self.rt_priority)
        period = self.period_s
        t0 = time.monotonic()
        k = 0
        while not self._stop:
            if self.sup.sleep_while_idle(0.5):     # nothing to publish: no wake-up per period
                t0, k = time.monotonic(), 0
                continue
            deadline = t0 + k * period
            delay = deadline - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            try:
                self.sup.tick(t0 + (k + 1) * period)
            except Exception as exc:  # e.g. publishing while the process shuts down
                if self._stop:
                    return
                self.on_error(f"tick failed: {type(exc).__name__}: {exc}")
            k += 1
            behind = time.monotonic() - (t0 + k * period)
            if behind > period:  # more than a whole period late: skip the missed deadlines
                skipped = int(behind // period)
                k += skipped
                self.sup.missed(skipped)


class Outbox:
    """Items handed over by a real-time thread (:meth:`put`, which never waits on ``publish``)
    and published in order by a thread of its own (module doc). At most ``capacity`` wait:
    beyond that the oldest is dropped and counted. A ``publish`` that takes longer than
    ``slow_s`` calls ``on_slow(seconds, backlog)`` from the publishing thread."""

    def __init__(self, publish: Callable[[Any], None], slow_s: float, capacity: int = 400,
                 on_slow: Callable[[float, int], None] | None = None,
                 set_priority: Callable[[], Any] | None = None) -> None:
        self.publish = publish
        self.slow_s = float(slow_s)
        self.capacity = int(capacity)
        self.on_slow = on_slow or (lambda seconds, backlog: None)
        self._set_priority = set_priority
        self._queue: deque = deque()
        self._cond = threading.Condition()
        self._closed = False
        self.published = 0
        self.dropped = 0
        self.slow = 0                 # publishes longer than slow_s
        self.max_publish_s = 0.0
        self.max_backlog = 0
        self._thread = threading.Thread(target=self._run, name="executor_outbox", daemon=True)
        self._thread.start()

    def put(self, item: Any) -> None:
        with self._cond:
            if len(self._queue) >= self.capacity:
                self._queue.popleft()
                self.dropped += 1
            self._queue.append(item)
            if len(self._queue) > self.max_backlog:
                self.max_backlog = len(self._queue)
            self._cond.notify()

    def close(self, timeout: float = 1.0) -> None:
        """Publish what is queued (within ``timeout``), then stop the thread."""
        with self._cond:
            self._closed = True
            self._cond.notify()
        self._thread.join(timeout)

    def _run(self) -> None:
        if self._set_priority is not None:
            self._set_priority()
        while True:
            with self._cond:
                while not self._queue and not self._closed:
                    self._cond.wait()
                if not self._queue:
                    return
                item = self._queue.popleft()
            t0 = time.perf_counter()
            try:
                self.publish(item)
            except Exception:  # e.g. publishing while the process shuts down
                if self._closed:
                    return
                raise
            took = time.perf_counter() - t0
            self.published += 1
            self.max_publish_s = max(self.max_publish_s, took)
            if took > self.slow_s:
                self.slow += 1
                self.on_slow(took, len(self._queue))     # the items that waited behind it


__all__ = ["ControlLoop", "Outbox"]
