"""What every node of the package shares: declared parameters and a clean ``main``.

* ``declare_parameters`` (of ``params.ParamSpec`` tables): a table of parameters with defaults, descriptions,
  ranges and read-only flags, declared with ROS parameter descriptors (so ``ros2 param
  describe`` shows them and out-of-range values are refused by rclpy).
* ``run_node``: ``rclpy.init``, construct, spin, and stop cleanly on Ctrl-C / SIGTERM
  (exit 0, no traceback); a configuration error exits 2 with one FATAL log line.
"""
from __future__ import annotations

import threading
import time
from typing import Any, Callable, Mapping

import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import ParameterException
from rclpy.executors import Executor, ExternalShutdownException
from rclpy.logging import get_logger
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from humanoid_reach_ros.params import ParamSpec  # noqa: F401  (the nodes' parameter tables)


# Latched topics (robot description, maps, planning markers): the last message reaches late joiners.
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
# One message at a time that must not be lost once matched (trajectories).
RELIABLE_LATEST = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)

def descriptor(spec: ParamSpec) -> ParameterDescriptor:
    """The ROS parameter descriptor of ``spec`` (``ros2 param describe``; rclpy refuses a value
    out of its range)."""
    d = ParameterDescriptor(description=spec.description, read_only=spec.read_only,
                            additional_constraints=spec.constraints)
    if spec.range is not None and isinstance(spec.default, int) and not isinstance(spec.default, bool):
        d.integer_range = [IntegerRange(from_value=int(spec.range[0]), to_value=int(spec.range[1]), step=1)]
    elif spec.range is not None:
        d.floating_point_range = [FloatingPointRange(from_value=spec.range[0], to_value=spec.range[1], step=0.0)]
    return d


def declare_parameters(node: Node, table: Mapping[str, ParamSpec]) -> dict[str, Any]:
    """Declare every parameter of ``table`` with its descriptor; returns the values in effect."""
    for name, spec in table.items():
        node.declare_parameter(name, spec.default, descriptor(spec))
    return {name: node.get_parameter(name).value for name in table}


def context_shutting_down(wait_s: float = 1.0, context=None) -> bool:
    """Whether the rclpy context is shut down or becomes so within ``wait_s`` (a signal
    handler shuts it down asynchronously, so an exception raised by that shutdown can
    precede ``rclpy.ok()`` turning false)."""
    deadline = time.monotonic() + wait_s
    while rclpy.ok(context=context):
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.01)
    return True


def run_node(make_node: Callable[[], Node], name: str, args: list[str] | None = None,
             executor: Callable[[], Executor] | None = None) -> int:
    """Run a node until Ctrl-C / SIGTERM; returns the process exit code.

    rclpy's signal handlers shut the context down asynchronously, so the executor can
    fail with an ``RCLError`` ("context is not valid") instead of raising
    ``ExternalShutdownException`` when the signal lands while it builds its wait set;
    any exception after the context is shut down therefore counts as a clean stop. The
    exception can come a moment before ``rclpy.ok()`` turns false (seen: a subscription's
    ``take_message`` failing while the context was shut down), hence
    :func:`context_shutting_down`.
    """
    rclpy.init(args=args)
    try:
        try:
            node = make_node()
        except (ParameterException, ValueError, OSError, KeyError) as exc:  # bad parameters or files
            get_logger(name).fatal(f"cannot start: {type(exc).__name__}: {exc}")
            return 2
        try:
            if executor is None:
                rclpy.spin(node)
            else:
                ex = executor()
                ex.add_node(node)
                ex.spin()
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        except Exception:
            if not context_shutting_down():
                raise
        finally:
            node.destroy_node()
    except KeyboardInterrupt:  # Ctrl-C during start-up
        pass
    finally:
        rclpy.try_shutdown()
    return 0


class LatestOnDemand:
    """The latest message of a topic, taken when asked for, never delivered by an executor.

    A depth-1 subscription on a hidden helper node (``_<node>_<topic>``) that no executor
    spins: the middleware keeps the newest message and :meth:`latest` takes it. A node that
    needs the current joint state only now and then (a start posture, a staleness check)
    then costs nothing per message, instead of a wake-up per 200 Hz ``/joint_states``.
    ``age_s()`` is the time since the newest message was *received* by the middleware (its
    reception timestamp), exact whenever it is asked: no periodic take is needed to keep
    a staleness check honest. Thread-safe.
    """

    def __init__(self, node: Node, msg_type, topic: str, qos: QoSProfile | None = None) -> None:
        qos = qos or QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)
        name = "_" + (node.get_name() + "_" + topic.strip("/").replace("/", "_"))
        self._node = rclpy.create_node(name, namespace=node.get_namespace(), context=node.context,
                                       start_parameter_services=False, enable_rosout=False)
        self._sub = self._node.create_subscription(msg_type, node.resolve_topic_name(topic), lambda _m: None, qos)
        self._msg_type = msg_type
        self._lock = threading.Lock()
        self._msg = None
        self._time = -float("inf")        # monotonic time of the newest message's reception
        self.received = 0

    def _take(self) -> list:
        """Take what waits (caller holds the lock); stamps the newest with its reception time."""
        out, info = [], None
        while True:
            taken = self._sub.handle.take_message(self._msg_type, False)
            if taken is None:
                break
            out.append(taken[0])
            info = taken[1]
        if out:
            self._msg, self._time = out[-1], _reception_monotonic(info)
            self.received += len(out)
        return out

    def latest(self):
        """The newest message (taken now if one arrived since the last call), or None."""
        with self._lock:
            self._take()
            return self._msg

    def take_all(self) -> list:
        """Every message queued since the last take, oldest first (up to the QoS depth: a node
        that needs a history, e.g. the head pose at a sensor stamp, takes them in its worker)."""
        with self._lock:
            return self._take()

    def age_s(self) -> float:
        """Seconds since the newest message was received (inf: none yet)."""
        with self._lock:
            self._take()
            return time.monotonic() - self._time

    def put(self, msg, taken_at: float | None = None) -> None:
        """Use ``msg`` as the newest message, received at ``taken_at`` (monotonic; default now):
        for a node driven in process (tests), as if it had arrived."""
        with self._lock:
            self._msg, self._time = msg, time.monotonic() if taken_at is None else float(taken_at)

    def destroy(self) -> None:
        self._node.destroy_node()


def _reception_monotonic(info: Any) -> float:
    """The monotonic time at which the middleware received a message (its ``received_timestamp``,
    system clock ns), or now when the middleware gives none."""
    now = time.monotonic()
    try:
        received_ns = int(info["received_timestamp"])
    except (TypeError, KeyError, ValueError):
        return now
    if received_ns <= 0:
        return now
    return min(now, now - (time.time_ns() - received_ns) * 1e-9)


def current_joints(joint_states: LatestOnDemand, timeout_s: float, robot) -> tuple[Any, str]:
    """The robot's joint angles of the newest ``/joint_states`` (``io.msgs.model_joints``: unknown
    names ignored, a missing model joint refused), or None and the reason: none received, or
    older than ``timeout_s``."""
    from humanoid_reach_ros.io import msgs

    msg = joint_states.latest()
    if msg is None:
        return None, "no /joint_states received"
    age = joint_states.age_s()
    if age > timeout_s:
        return None, f"/joint_states is stale ({age:.2f} s > {timeout_s:g} s)"
    return msgs.model_joints(msg, robot)


def scene_file_voxels(path: str, resolution_m: float, exclude_groups) -> Any:
    """A scene file's voxels (N, 3), the map until a /voxel_map arrives: the nodes read the
    file, the planning scene (scene/planning_scene.py) only ever gets points."""
    from humanoid_reach_ros.sim.scene import load_scene
    return load_scene(str(path)).voxelize(resolution_m, exclude_groups=tuple(exclude_groups))

