"""io/gil_free.py: the executor's and joint_driver's loop writes, through rcl without the
interpreter lock; the subscribers see the very bytes rclpy's own ``publish`` sends."""
from __future__ import annotations

import ctypes
import time

import numpy as np
import pytest
import rclpy
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState

from humanoid_reach_ros.io import gil_free, msgs


@pytest.fixture
def node(ros_env, monkeypatch):
    for k, v in ros_env.items():
        monkeypatch.setenv(k, v)
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    n = rclpy.create_node("gil_free_test", context=ctx)
    yield n
    n.destroy_node()
    rclpy.try_shutdown(context=ctx)


def receive(node, publisher, send, count: int) -> list[bytes]:
    """Raw (serialized) messages on the publisher's topic once ``send(i)`` published ``count``
    of them (after the subscription matched)."""
    got: list[bytes] = []
    node.create_subscription(JointState, publisher.topic_name, got.append, 50, raw=True)
    executor = rclpy.executors.SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    try:
        deadline = time.monotonic() + 30.0
        while publisher.get_subscription_count() < 1 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        for i in range(count):
            send(i)
        while len(got) < count and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
    finally:
        executor.remove_node(node)
    return got


def test_the_write_releases_the_interpreter_lock() -> None:
    found = gil_free._functions()
    assert not isinstance(found, str), found
    publish, get_error, reset_error = found
    assert gil_free.releases_the_gil(publish)
    create, convert, destroy = gil_free._message_functions(JointState)
    assert not gil_free.releases_the_gil(convert)   # it builds from Python objects: under the lock
    assert not gil_free.releases_the_gil(ctypes.pythonapi.Py_IsInitialized)   # the check can fail


def test_subscribers_receive_what_rclpy_would_send(node) -> None:
    names = [f"joint_{i}" for i in range(30)]
    pub = gil_free.GilFreePublisher(node.create_publisher(JointState, "gil_free_js", 10))
    assert pub.mode == "gil-free" and pub.topic_name == "/gil_free_js"
    sent = [msgs.joint_state(names, np.linspace(-1, 1, 30) * k, np.full(30, 0.1 * k)) for k in range(5)]
    for k, m in enumerate(sent):
        m.header.stamp.sec, m.header.frame_id = k, "world"
    got = receive(node, pub.publisher, lambda i: pub.publish(sent[i]), len(sent))
    rclpy_pub = node.create_publisher(JointState, "gil_free_js_rclpy", 10)
    by_rclpy = receive(node, rclpy_pub, lambda i: rclpy_pub.publish(sent[i]), len(sent))
    assert len(by_rclpy) == len(sent) and got == by_rclpy   # in order, byte for byte what rclpy sends


def test_without_librcl_it_publishes_through_rclpy(node, monkeypatch) -> None:
    monkeypatch.setattr(gil_free, "_functions", lambda: "not found in this process: librcl.so")
    pub = gil_free.GilFreePublisher(node.create_publisher(JointState, "gil_free_fallback", 10))
    assert pub.mode == "rclpy (not found in this process: librcl.so)"
    m = msgs.joint_state(["a", "b"], np.array([0.5, -0.5]))
    got = receive(node, pub.publisher, lambda i: pub.publish(m), 2)
    assert len(got) == 2 and all(deserialize_message(g, JointState) == m for g in got)


def test_a_wrong_message_or_a_destroyed_publisher_is_a_clear_error(node) -> None:
    from std_msgs.msg import String
    pub = gil_free.GilFreePublisher(node.create_publisher(JointState, "gil_free_typed", 10))
    with pytest.raises(TypeError, match="/gil_free_typed takes JointState, not String"):
        pub.publish(String(data="x"))
    raw = node.create_publisher(JointState, "gil_free_gone", 10)
    pub = gil_free.GilFreePublisher(raw)
    node.destroy_publisher(raw)
    with pytest.raises(Exception, match="(?i)destroy|invalid"):
        pub.publish(msgs.joint_state(["a"], np.zeros(1)))
