"""Helpers for node-level tests: isolated ROS graphs, node processes, and a probe node.

Process orchestration lives in ``humanoid_reach_ros.graph`` (the demo uses it too) and is
re-exported here:

* ``allocate_domain`` gives a ``ROS_DOMAIN_ID`` (1..101) that no other test process on
  this machine holds (an exclusive lock file per id), and ``graph_env`` the environment
  for it with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``.
* ``NodeProcess.start`` runs ``python -m humanoid_reach_ros.nodes.<name> --ros-args ...``
  as a real process with its output in a log file; ``stop`` sends SIGINT, waits, kills.
* ``RosProbe`` is the test's own rclpy context + node in the same domain, with
  ``spin_until(condition, timeout)`` and message ``collect``ors.
* ``wait_for`` polls a condition with a timeout (no bare sleeps in tests).

The fixtures wrapping these live in ``conftest.py``.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Callable, TypeVar

from humanoid_reach_ros.graph import (  # noqa: F401  (re-exported for the tests)
    DomainLease, NodeProcess, allocate_domain, graph_env, node_command, wait_for)

REPO_ROOT = Path(__file__).resolve().parent.parent

T = TypeVar("T")


# ---------------------------------------------------------------- the test's own ROS node
class Collector:
    """Messages of one subscription with their receipt times (``time.monotonic``)."""

    def __init__(self) -> None:
        self.messages: list[Any] = []
        self.times: list[float] = []

    def __call__(self, msg: Any) -> None:
        self.messages.append(msg)
        self.times.append(time.monotonic())

    def __len__(self) -> int:
        return len(self.messages)

    @property
    def last(self) -> Any:
        return self.messages[-1] if self.messages else None

    def clear(self) -> None:
        self.messages.clear()
        self.times.clear()

    def since(self, t: float) -> list[Any]:
        return [m for m, tm in zip(self.messages, self.times) if tm >= t]


class RosProbe:
    """The test process' rclpy context and node in the graph's domain (no signal handlers)."""

    def __init__(self, domain_id: int, name: str = "test_probe") -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def collect(self, msg_type: Any, topic: str, qos: Any = 10) -> Collector:
        c = Collector()
        self.node.create_subscription(msg_type, topic, c, qos)
        return c

    def spin_once(self, timeout_sec: float = 0.01) -> None:
        self.executor.spin_once(timeout_sec=timeout_sec)

    def spin_until(self, condition: Callable[[], T], timeout: float, what: str = "condition",
                   on_timeout: Callable[[], str] | None = None) -> T:
        """Spin until ``condition()`` is truthy; its value is returned. ``AssertionError`` on timeout."""
        return wait_for(condition, timeout, what, on_timeout, step=lambda: self.executor.spin_once(timeout_sec=0.005))

    def spin_for(self, duration: float) -> None:
        """Spin for a measurement window of ``duration`` s (collecting, not waiting for a condition)."""
        end = time.monotonic() + duration
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=min(0.005, max(0.0, end - time.monotonic())))

    def close(self) -> None:
        import rclpy

        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
