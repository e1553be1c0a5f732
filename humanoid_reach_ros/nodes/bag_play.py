"""``hr_play``: republish a rosbag2-style MCAP file with its recorded timing.

Usage::

    python -m humanoid_reach_ros.nodes.bag_play run.mcap --rate 2 --topics /joint_states --loop
    python -m humanoid_reach_ros.nodes.bag_play run.mcap --info
    python -m humanoid_reach_ros.nodes.bag_play run.mcap --namespace /replay   # beside a live graph

* **A replay never changes a live graph unless asked to** (docs/operator.md, bags): when other
  nodes publish a topic it would publish, it refuses (exit 3, naming them; ``LiveGraph``);
  ``--namespace /replay`` plays every topic under ``/replay``, ``--remap OLD:=NEW`` moves
  single topics (``replay_topic_names``), ``--into-live`` plays into the live graph and says
  loudly what that does. Into an empty graph it plays as recorded, as ``ros2 bag play``.

* One publisher per topic with the recorded type (the message class is imported from the
  type name: ``pkg/msg/Type`` -> ``pkg.msg.Type``); messages go out as their recorded
  serialized CDR bytes (``Publisher.publish(bytes)``), never decoded, unless
  ``--stamps-now``.
* QoS: what the bag's ``offered_qos_profiles`` say (``io.mcap_bag.replay_qos``): latched
  topics (``/robot_description``, ``/voxel_map``) are republished transient local, so a
  node that starts later still gets their last message; the rest reliable (or best effort
  if recorded so) volatile.
* Timing: message ``i`` is due ``(log_time_i - log_time_first) / rate`` s after playback
  starts (``playback_schedule``); ``--start-offset`` skips the bag's first seconds;
  ``--loop`` starts over (each pass keeps the recorded gaps); ``--topics`` plays a subset.
* ``--stamps-now``: messages with a top-level ``std_msgs/Header header`` are decoded and
  their ``header.stamp`` moved to replay time by ONE map per pass,
  ``stamp' = t_pass + (stamp - log_time_first) / rate`` (``restamp_ns``; ``t_pass`` = wall
  clock when the pass starts, ``log_time_first`` = the first played message's receive
  time): at rate 1 every stamp is shifted by the same constant, so stamps that were equal
  stay equal and their order and spacing are kept -- an image and its point cloud still
  carry the stamp of the ``/joint_states`` message that placed the camera, and nodes that
  look the camera pose up by the image stamp (``voxel_mapper``, ``marker_localizer``) find
  the same joint angles as live (setting each stamp to its own publish time would not:
  an image is published one render time after the joint state it is stamped with).
  Stamped replay time then matches the wall clock, so nodes that reject stale input
  accept the replayed ``/joint_states``. Unstamped headers (stamp 0) stay 0. Each
  ``--loop`` pass gets a new ``t_pass`` (stamps keep increasing). Without the flag stamps
  stay as recorded (the default of ``ros2 bag play``). There is no ``/clock`` (simulated
  time is not used by this package).
* ``--wait-subscribers S``: before playing, wait up to S s until every played topic has a
  subscriber (so that the first messages are not lost to discovery).
* Other publishers of a played topic are looked for (``get_publishers_info_by_topic``, its own
  left out) for ``DISCOVERY_WAIT_S`` before it starts and every ``PUBLISHER_CHECK_PERIOD_S``
  while playing (one appearing then stops the replay); with ``--into-live`` each is named.
* Replaying into running nodes: a node that rejects stale input (the planner's 0.5 s
  ``/joint_states``) fails once a single pass has ended; ``--loop`` keeps the stream going.
* At the end the player waits up to ``ACK_TIMEOUT_S`` (5 s) until the subscribers of its
  reliable topics have acknowledged every message (``Publisher.wait_for_all_acked``), so a
  short replay is not lost when the process exits; a warning names the topics that did not.

Exit codes: 0 played, 1 stopped by a bag error while playing, 2 bad arguments, missing or
corrupt bag, unknown topic filter or message type, 3 refused or stopped: a live graph publishes
a played topic (without ``--into-live``).
"""
from __future__ import annotations

import argparse
import sys
import time
from typing import Any

import rclpy
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from rclpy.signals import SignalHandlerOptions

from humanoid_reach_ros.io.endpoints import has_header, replay_publisher_qos, restamp_ns
from humanoid_reach_ros.io.mcap_bag import (UNNAMED_NODE, BagError, BagReader, LiveGraph, describe, message_class,
                                            other_nodes, playback_schedule, refusal, replay_topic_names,
                                            split_ros_args)
from humanoid_reach_ros.nodes.bag_record import StopSignals

NODE_NAME = "bag_play"
EXIT_LIVE_GRAPH = 3


class BagPlayerNode(Node):
    """Publishers for the played topics (on ``out_topics[t]``: the recorded name by default);
    ``play`` runs one pass over the bag. Unless ``into_live``, another publisher of a played
    topic raises :class:`LiveGraph` (module doc)."""

    def __init__(self, reader: BagReader, topics: list[str], stamps_now: bool = False,
                 out_topics: dict[str, str] | None = None, into_live: bool = False, **kw: Any) -> None:
        super().__init__(NODE_NAME, **kw)
        self.reader = reader
        self.topics = topics
        self.out_topics = out_topics or {t: t for t in topics}
        self.into_live = into_live
        self.stamps_now = stamps_now
        self.classes = {t: message_class(reader.topics[t].type) for t in topics}  # BagError if unknown
        self.publishers_ = {t: self.create_publisher(self.classes[t], self.out_topics[t],
                                                     replay_publisher_qos(reader.topics[t].qos))
                            for t in topics}
        self.restamp = {t for t in topics if stamps_now and has_header(self.classes[t])}
        self.published = 0
        self._warned: set[tuple[str, str]] = set()
        self._next_check = 0.0
        self._first_log_ns = 0
        self._pass_start_ns = 0
        self._rate = 1.0

    def wait_for_subscribers(self, timeout_s: float, stop: StopSignals) -> list[str]:
        """Topics still without a subscriber after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while stop.signal is None:
            lonely = [self.out_topics[t] for t, p in self.publishers_.items() if p.get_subscription_count() == 0]
            if not lonely or time.monotonic() > deadline:
                return lonely
            time.sleep(0.02)
        return []

    def other_publishers(self) -> dict[str, list[str]]:
        """Topics this player publishes that other nodes publish too -> those nodes (``/ns/name``;
        ``UNNAMED_NODE`` for one discovery has not named yet), as discovery shows them now (this
        player's own publisher left out)."""
        me = f"{self.get_namespace().rstrip('/')}/{self.get_name()}"
        found = {t: other_nodes([f"{i.node_namespace.rstrip('/')}/{i.node_name}"
                                 for i in self.get_publishers_info_by_topic(t)], me) for t in self.out_topics.values()}
        return {t: nodes for t, nodes in found.items() if nodes}

    def check_live_graph(self, found: dict[str, list[str]] | None = None) -> None:
        """Other publishers of the played topics (``found``, or as discovery shows them now):
        :class:`LiveGraph` unless ``into_live``; with it, a warning per (topic, node) newly seen
        (two sources mixed)."""
        found = self.other_publishers() if found is None else found
        if found and not self.into_live:
            raise LiveGraph(found)
        for topic, nodes in found.items():
            new = [n for n in nodes if (topic, n) not in self._warned and n != UNNAMED_NODE]
            if new:
                self._warned.update((topic, n) for n in new)
                self.get_logger().warning(
                    f"--into-live: {topic} is also published by {', '.join(new)}: the replay mixes two sources of "
                    f"{topic} (stop {'them' if len(new) > 1 else 'it'}, or leave the topic out with --topics)")

    def wait_for_acks(self, timeout_s: float) -> list[str]:
        """Reliable topics whose subscribers have not acknowledged every message within
        ``timeout_s`` (a short replay is not lost when the player exits right after it)."""
        deadline = time.monotonic() + timeout_s
        late = []
        for topic, pub in self.publishers_.items():
            if pub.qos_profile.reliability != ReliabilityPolicy.RELIABLE:
                continue
            left = max(0.0, deadline - time.monotonic())
            if not pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9))):
                late.append(topic)
        return late

    def publish(self, topic: str, data: bytes) -> None:
        if topic in self.restamp:
            msg = deserialize_message(data, self.classes[topic])
            stamp = msg.header.stamp
            ns = restamp_ns(stamp.sec * 1_000_000_000 + stamp.nanosec, self._first_log_ns, self._pass_start_ns,
                            self._rate)
            stamp.sec, stamp.nanosec = divmod(max(ns, 0), 1_000_000_000)
            data = serialize_message(msg)
        self.publishers_[topic].publish(data)
        self.published += 1

    def play(self, rate: float, start_offset_s: float, stop: StopSignals) -> bool:
        """One pass; False if stopped by a signal."""
        messages = list(self.reader.messages(self.topics, start_offset_s))
        due = playback_schedule([m.log_time_ns for m in messages], rate)
        self._rate = rate
        self._first_log_ns = messages[0].log_time_ns if messages else 0
        self._pass_start_ns = time.time_ns()
        t0 = time.monotonic()
        for m, t in zip(messages, due):
            while stop.signal is None and (wait := t0 + t - time.monotonic()) > 0:
                time.sleep(min(wait, 0.05))
            if time.monotonic() > self._next_check:   # another publisher may appear at any time
                self._next_check = time.monotonic() + PUBLISHER_CHECK_PERIOD_S
                self.check_live_graph()
            if stop.signal is not None:
                return False
            self.publish(m.topic, m.data)
        return True


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="hr_play", allow_abbrev=False,   # what it publishes can move a robot
                                description="Republish a rosbag2-compatible MCAP file with the recorded timing.")
    p.add_argument("bag", help=".mcap file (or a rosbag2 directory holding one)")
    p.add_argument("--topics", nargs="+", metavar="TOPIC", help="play only these topics (default: all)")
    p.add_argument("-r", "--rate", type=float, default=1.0, help="rate factor (2 = twice as fast)")
    p.add_argument("-l", "--loop", action="store_true", help="play again and again until Ctrl-C")
    p.add_argument("--start-offset", type=float, default=0.0, help="skip the first S seconds of the bag")
    p.add_argument("--stamps-now", action="store_true", help="move header.stamp of stamped messages to the "
                   "replay clock by one affine map per pass (keeps equal stamps equal; for nodes that "
                   "reject stale input)")
    p.add_argument("--wait-subscribers", type=float, default=0.0, metavar="S",
                   help="wait up to S s for a subscriber on every played topic before starting")
    p.add_argument("--namespace", default="", metavar="NS",
                   help="play every topic under NS (/replay: /joint_states -> /replay/joint_states), e.g. beside "
                        "a live graph")
    p.add_argument("--remap", nargs="+", default=[], metavar="OLD:=NEW",
                   help="play topic OLD on NEW (as ros2 bag play --remap)")
    p.add_argument("--into-live", action="store_true",
                   help="play even where a live graph publishes the same topics: the recording then feeds the "
                        "live nodes (its clouds into the live map, its joint states to the planner and executor)")
    p.add_argument("--info", action="store_true", help="print what the bag holds and exit")
    a = p.parse_args(argv)
    if not (a.rate > 0 and a.rate < float("inf")):
        p.error(f"--rate must be a finite number > 0, got {a.rate}")
    if a.start_offset < 0 or a.wait_subscribers < 0:
        p.error("--start-offset and --wait-subscribers must be >= 0")
    return a


ACK_TIMEOUT_S = 5.0   # at the end, reliable subscribers get this long to acknowledge what was played
# before playing, other publishers of the played topics are looked for this long (a live graph is
# refused) ... Fast DDS announces a participant in a burst, then every 3 s: a burst missed on a busy
# machine is heard at the next (a running joint_driver was seen after 1.8 s, once after 2 s: too late)
DISCOVERY_WAIT_S = 3.5
PUBLISHER_CHECK_PERIOD_S = 0.5   # ... and while playing, those that appear, looked for this often


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv if argv is None else argv
    own, ros_args = split_ros_args(argv)
    args = parse_args(own[1:])
    try:
        reader = BagReader(args.bag)
        if args.info:
            print(describe(reader))
            return 0
        topics = reader.select(args.topics)
        for t in topics:
            message_class(reader.topics[t].type)
        out_topics = replay_topic_names(topics, args.namespace, args.remap)
    except BagError as exc:
        print(f"hr_play: {exc}", file=sys.stderr)
        return 2
    stop = StopSignals()
    rclpy.init(args=argv[:1] + ros_args, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    code = 0
    finished = False
    try:
        node = BagPlayerNode(reader, topics, args.stamps_now, out_topics, args.into_live)
        deadline = time.monotonic() + DISCOVERY_WAIT_S   # discovery shows the other publishers first
        found: dict[str, list[str]] = {}
        while stop.signal is None and time.monotonic() < deadline:
            found = node.other_publishers()
            if found and all(UNNAMED_NODE not in nodes for nodes in found.values()):
                break     # a live graph, named (an unnamed one is named within the wait, mostly)
            time.sleep(0.05)
        node.check_live_graph(found)
        if args.wait_subscribers > 0:
            lonely = node.wait_for_subscribers(args.wait_subscribers, stop)
            if lonely:
                node.get_logger().warning(f"no subscriber after {args.wait_subscribers:g} s on {', '.join(lonely)}; "
                                          "playing anyway")
            node.check_live_graph()
        if args.into_live:
            live = node.other_publishers()
            node.get_logger().warning("--into-live: playing INTO THE LIVE GRAPH: " + (
                f"{LiveGraph(live).describe()} publish the same topics; the recording mixes with them: its clouds "
                "go into the live map, its joint states and robot description to the planner and the executor"
                if live else "no other publisher of these topics seen yet; their subscribers get the recording"))
        moved = [f"{t} -> {out_topics[t]}" for t in topics if out_topics[t] != t]
        node.get_logger().info(f"playing {reader.path} ({', '.join(moved if moved else topics)}"
                               f"{', the rest as recorded' if moved and len(moved) < len(topics) else ''}) "
                               f"at rate {args.rate:g}{', looping' if args.loop else ''}")
        while node.play(args.rate, args.start_offset, stop) and args.loop:
            pass
        finished = True
        if stop.signal is None:
            unacked = node.wait_for_acks(ACK_TIMEOUT_S)
            if unacked:
                node.get_logger().warning(f"not every reliable subscriber acknowledged the last messages within "
                                          f"{ACK_TIMEOUT_S:g} s on {', '.join(unacked)}")
            node.check_live_graph()   # a last look: on a busy machine discovery names a node late
        if any(reader.topics[t].qos.transient_local for t in topics) and stop.signal is None:
            time.sleep(0.2)  # let late-joining readers of latched topics fetch before the publisher goes
    except BagError as exc:
        print(f"hr_play: {exc}", file=sys.stderr)
        code = 1
    except LiveGraph as exc:
        print(refusal(exc, node.published if node is not None else 0, finished), file=sys.stderr)
        code = EXIT_LIVE_GRAPH
    finally:
        published = node.published if node is not None else 0
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        reader.close()
        stop.restore()
    print(f"hr_play: published {published} messages")
    return code


if __name__ == "__main__":
    sys.exit(main())
