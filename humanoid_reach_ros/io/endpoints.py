"""rclpy-side helpers the nodes and the bag tools share: the QoS profiles of latched and
one-at-a-time topics, the latest message of a topic taken on demand (:class:`LatestOnDemand`,
:func:`current_joints`), and the QoS of recording and replaying a topic (``hr_record``
matches every publisher; ``hr_play`` offers what was recorded, and moves header stamps to
replay time with :func:`restamp_ns`)."""
from __future__ import annotations

import threading
import time
from typing import Any

import rclpy
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from humanoid_reach_ros.io.mcap_bag import QosInfo

# Latched topics (robot description, maps, planning markers): the last message reaches late joiners.
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
# One message at a time that must not be lost once matched (trajectories).
RELIABLE_LATEST = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
#: the queue of a recording subscription
SUBSCRIPTION_DEPTH = 100


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


def offered_qos(infos: list[Any]) -> list[QosInfo]:
    """What each publisher of a topic offers (from ``TopicEndpointInfo.qos_profile``)."""
    return [QosInfo(reliable=i.qos_profile.reliability != ReliabilityPolicy.BEST_EFFORT,
                    transient_local=i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL,
                    depth=max(1, int(i.qos_profile.depth or 1))) for i in infos]


def recording_qos(offered: list[QosInfo]) -> QoSProfile:
    """A subscription that matches every publisher: best effort if any publisher is, transient
    local only if all are (a transient-local subscription does not match volatile publishers)."""
    reliable = all(p.reliable for p in offered)
    latched = bool(offered) and all(p.transient_local for p in offered)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=SUBSCRIPTION_DEPTH,
                      reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


def replay_publisher_qos(q: QosInfo) -> QoSProfile:
    """The publisher of a replayed topic, as recorded (``hr_play``)."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=max(1, q.depth) if q.transient_local else max(10, q.depth),
                      reliability=ReliabilityPolicy.RELIABLE if q.reliable else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if q.transient_local else DurabilityPolicy.VOLATILE)


def restamp_ns(stamp_ns: int, first_log_ns: int, pass_start_ns: int, rate: float) -> int:
    """``--stamps-now``: a recorded stamp [ns] on the replay clock, ``pass_start_ns +
    (stamp_ns - first_log_ns) / rate`` (an affine map: equal stamps stay equal, order and
    relative spacing are kept); a zero stamp (unstamped) stays zero."""
    if stamp_ns == 0:
        return 0
    return pass_start_ns + int(round((stamp_ns - first_log_ns) / rate))


def has_header(cls: type) -> bool:
    """Whether a message class has a top-level ``std_msgs/Header header``."""
    return cls.get_fields_and_field_types().get("header") == "std_msgs/Header"


__all__ = ["LATCHED", "RELIABLE_LATEST", "LatestOnDemand", "current_joints", "offered_qos", "recording_qos",
           "replay_publisher_qos", "restamp_ns", "has_header", "SUBSCRIPTION_DEPTH"]
