"""A subscription that only publishers on this host can reach.

Across hosts (docs/deployment.md) any participant on the subnet could publish a topic a node
subscribes to. For the joint driver's ``/joint_command`` that means any machine on the
operator's network could move the robot. :class:`HostLocalSubscription` subscribes in a DDS
participant of its own whose discovery stays on this host: an rclpy ``Context`` initialised
with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and no ``ROS_STATIC_PEERS``, in the parent
node's domain, spun by a thread of its own. Publishers on the same host (the executor, whatever
its own discovery range) match it; a publisher on another host never discovers it. Measured
here with network namespaces: a LOCALHOST subscriber on hr_robot received the messages of a
SUBNET publisher on hr_robot and none of a SUBNET publisher on hr_operator.

This is no substitute for DDS-Security (docs/deployment.md): it keeps remote *hosts* out, not
a process on the robot's own host.
"""
from __future__ import annotations

import os
import threading
from typing import Any, Callable

_DISCOVERY_ENV = ("ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_STATIC_PEERS")
_ENV_LOCK = threading.Lock()


class HostLocalSubscription:
    """``topic`` (resolved by ``parent``: its namespace and remappings) subscribed in a
    host-local participant (module docstring); ``callback`` runs on this object's thread, after
    ``thread_setup()`` (e.g. real-time priority). :meth:`close` stops it."""

    def __init__(self, parent: Any, msg_type: type, topic: str, callback: Callable[[Any], None], qos: Any,
                 thread_setup: Callable[[], None] | None = None) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.topic = parent.resolve_topic_name(topic)
        self.context = rclpy.Context()
        with _ENV_LOCK:   # rcl reads the discovery settings from the environment when the context starts
            saved = {k: os.environ.get(k) for k in _DISCOVERY_ENV}
            os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
            os.environ.pop("ROS_STATIC_PEERS", None)
            try:
                rclpy.init(args=[], context=self.context, domain_id=parent.context.get_domain_id())
            finally:
                for k, v in saved.items():
                    if v is None:
                        os.environ.pop(k, None)
                    else:
                        os.environ[k] = v
        self.node = rclpy.create_node(f"{parent.get_name()}_host_local", namespace=parent.get_namespace(),
                                      context=self.context, start_parameter_services=False,
                                      use_global_arguments=False)
        self.subscription = self.node.create_subscription(msg_type, self.topic, callback, qos)
        self._executor = SingleThreadedExecutor(context=self.context)
        self._executor.add_node(self.node)
        self._stop = threading.Event()
        self._setup = thread_setup
        self._thread = threading.Thread(target=self._spin, name=f"{parent.get_name()}_host_local", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        if self._setup is not None:
            self._setup()
        while not self._stop.is_set() and self.context.ok():
            try:
                self._executor.spin_once(timeout_sec=0.1)
            except Exception:  # noqa: BLE001 -- the context shut down under the wait
                if self._stop.is_set() or not self.context.ok():
                    return
                raise

    def close(self, timeout: float = 2.0) -> None:
        import rclpy
        self._stop.set()
        self._thread.join(timeout)
        self._executor.remove_node(self.node)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


__all__ = ["HostLocalSubscription"]
