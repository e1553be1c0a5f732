"""nodes/common.py: the shutdown check of run_node."""
from __future__ import annotations

import threading
import time

import rclpy
from rclpy.context import Context

from humanoid_reach_ros.nodes.common import context_shutting_down


def test_context_shutting_down_waits_for_an_asynchronous_shutdown(ros_env) -> None:
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        t0 = time.monotonic()
        assert not context_shutting_down(0.2, ctx)            # running, nobody stops it: a real error
        assert time.monotonic() - t0 >= 0.2
        # a signal handler shutting the context down a moment after the exception
        timer = threading.Timer(0.1, rclpy.shutdown, kwargs={"context": ctx})
        timer.start()
        assert context_shutting_down(5.0, ctx)
        timer.join()
    finally:
        rclpy.try_shutdown(context=ctx)
    assert context_shutting_down(0.0, ctx)                      # already shut down: at once
