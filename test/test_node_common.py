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


def test_latest_on_demand_age_is_from_reception_not_from_the_take(ros_env) -> None:
    """A message received long before anybody asked is that old when first taken (the
    staleness checks of the planner and the executor need no periodic take)."""
    from std_msgs.msg import String

    from humanoid_reach_ros.io.endpoints import LatestOnDemand

    ctx = Context()
    rclpy.init(context=ctx)
    try:
        node = rclpy.create_node("latest_test", context=ctx)
        latest = LatestOnDemand(node, String, "latest_topic")
        pub = node.create_publisher(String, "latest_topic", 10)
        assert latest.latest() is None and latest.age_s() == float("inf")
        deadline = time.monotonic() + 20.0
        while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        pub.publish(String(data="a"))
        t_pub = time.monotonic()
        time.sleep(1.0)                                   # received meanwhile, taken by nobody
        age = latest.age_s()                              # the first take
        assert latest.latest().data == "a"
        assert 0.5 < age < time.monotonic() - t_pub + 0.05, age     # a take-based age would be ~0
        latest.put(String(data="b"), taken_at=time.monotonic() - 5.0)
        assert latest.latest().data == "b" and latest.age_s() >= 5.0
        latest.destroy()
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)
