"""``hr_record``: record ROS topics raw into a rosbag2-compatible MCAP file.

Usage::

    python -m humanoid_reach_ros.nodes.bag_record /joint_states /robot_description   # -> recordings/<time>.mcap
    python -m humanoid_reach_ros.nodes.bag_record -o recordings/run.mcap --all --duration 10

* Output: ``-o FILE.mcap`` (its directory is created), by default
  ``recordings/hr_record_<date>_<time>.mcap`` under the current directory (``recordings/`` and
  ``*.mcap`` outside ``bags/`` are ignored by git: a recording never lands among the sources).

* Topics and their types come from the graph (``get_topic_names_and_types``), polled every
  ``--poll-period`` s so that topics appearing later are picked up. A topic is subscribed
  once it has a publisher (its QoS is needed) and its type imports.
* The subscription's QoS matches the publishers (``get_publishers_info_by_topic``):
  transient local when every publisher is (latched ``/robot_description``, ``/voxel_map``:
  the last message is received even if published before the recorder started), best effort
  when any publisher is best effort (sensor data), else reliable volatile.
* Messages arrive raw (``raw=True``: serialized CDR bytes, never deserialized) and are
  written with ``log_time`` = ``publish_time`` = receive time (``io.mcap_bag.BagWriter``).
* Stops after ``--duration`` s or ``--max-messages`` messages, or on Ctrl-C / SIGTERM; the
  file is always finished (summary, indexes, statistics) and a summary is printed.
* Every ``--report-every`` s (5; 0: never) a line says how much it has taken in and its rate, and
  the file's size (``--all`` on the demo's graph takes in about 6 MB/s); the summary at the end too.
* With ``--all`` hidden topics (a name part starting with ``_``: action and service
  internals) are left out unless ``--include-hidden`` (as ``ros2 bag record -a``).

Exit codes: 0 recorded, 2 bad arguments or output file, 1 nothing recorded.
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import time
from typing import Any, Callable

import rclpy
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args

from humanoid_reach_ros.io.endpoints import offered_qos, recording_qos
from humanoid_reach_ros.io.mcap_bag import BagError, BagWriter, message_class

NODE_NAME = "bag_record"


class StopSignals:
    """Ctrl-C / SIGTERM set ``signal`` (checked by the tool's own loop) instead of raising
    in the middle of a write; the previous handlers come back on ``restore``."""

    def __init__(self) -> None:
        self.signal: int | None = None
        self._old = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)}

    def _on_signal(self, signum: int, _frame: Any) -> None:
        self.signal = signum

    def restore(self) -> None:
        for s, h in self._old.items():
            signal.signal(s, h)


def is_hidden(topic: str) -> bool:
    return any(part.startswith("_") for part in topic.split("/") if part)


class BagRecorderNode(Node):
    """Subscribes raw to the chosen topics as they appear and writes every message."""

    def __init__(self, writer: BagWriter, topics: list[str] | None, include_hidden: bool = False,
                 poll_period_s: float = 0.5, max_messages: int = 0, **kw: Any) -> None:
        super().__init__(NODE_NAME, **kw)
        self.writer = writer
        self.wanted = None if topics is None else list(dict.fromkeys(topics))
        self.include_hidden = include_hidden
        self.max_messages = max_messages
        self.done = False
        self.bytes_in = 0              # serialized bytes received (before the file's compression)
        self._skipped: set[str] = set()
        self._recorded: dict[str, Any] = {}
        self.discover()
        self.create_timer(poll_period_s, self.discover)

    def _want(self, topic: str) -> bool:
        if self.wanted is not None:
            return topic in self.wanted
        return self.include_hidden or not is_hidden(topic)

    def _skip_once(self, topic: str, why: str) -> None:
        if topic not in self._skipped:
            self._skipped.add(topic)
            self.get_logger().warning(f"not recording {topic}: {why}")

    def discover(self) -> None:
        """Subscribe to every wanted topic of the graph not yet subscribed."""
        for topic, types in self.get_topic_names_and_types():
            if topic in self._recorded or not self._want(topic):
                continue
            if len(types) != 1:
                self._skip_once(topic, f"published with several types {types}")
                continue
            try:
                cls = message_class(types[0])
            except BagError as exc:
                self._skip_once(topic, str(exc))
                continue
            offered = offered_qos(self.get_publishers_info_by_topic(topic))
            if not offered:
                continue  # only subscribers so far: wait for a publisher to know its QoS
            try:
                self.writer.add_topic(topic, types[0], offered)
            except BagError as exc:
                self._skip_once(topic, str(exc))
                continue
            qos = recording_qos(offered)
            self._recorded[topic] = self.create_subscription(cls, topic, self._writer_for(topic), qos, raw=True)
            self.get_logger().info(f"recording {topic} [{types[0]}] ({qos.reliability.name.lower()}, "
                                   f"{qos.durability.name.lower()})")

    def _writer_for(self, topic: str) -> Callable[[bytes], None]:
        def on_message(data: bytes) -> None:
            if self.done:
                return
            self.writer.write(topic, data, time.time_ns())
            self.bytes_in += len(data)
            if self.max_messages and self.writer.message_count >= self.max_messages:
                self.done = True
        return on_message

    def missing(self) -> list[str]:
        return [t for t in (self.wanted or []) if t not in self._recorded]


def volume_text(elapsed_s: float, messages: int, bytes_in: int, file_bytes: int | None) -> str:
    """``12.0 s, 3,210 messages, 71.8 MB (6.0 MB/s), file 9.4 MB``: what a recording has taken in,
    its mean rate and the file's size on disk so far (None: not known)."""
    rate = bytes_in / elapsed_s if elapsed_s > 0 else 0.0
    file = "" if file_bytes is None else f", file {file_bytes / 1e6:.1f} MB"
    return f"{elapsed_s:.1f} s, {messages:,} messages, {bytes_in / 1e6:.1f} MB ({rate / 1e6:.1f} MB/s){file}"


def file_size(path: str) -> int | None:
    try:
        return os.path.getsize(path)
    except OSError:
        return None


RECORDINGS_DIR = "recordings"   # default output directory (relative to the current one; git ignores it)


def default_output(now: float | None = None) -> str:
    """``recordings/hr_record_<YYYYmmdd>_<HHMMSS>.mcap`` (local time)."""
    return f"{RECORDINGS_DIR}/hr_record_{time.strftime('%Y%m%d_%H%M%S', time.localtime(now))}.mcap"


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="hr_record", allow_abbrev=False,
                                description="Record ROS 2 topics into a rosbag2-compatible MCAP file (profile "
                                "ros2, ros2msg schemas, cdr messages, zstd chunks).")
    p.add_argument("topics", nargs="*", help="topics to record (e.g. /joint_states)")
    p.add_argument("-a", "--all", action="store_true", help="record every topic (hidden ones only with "
                   "--include-hidden)")
    p.add_argument("-o", "--output", help=f"output .mcap file (overwritten; its directory is created); default "
                   f"{RECORDINGS_DIR}/hr_record_<date>_<time>.mcap")
    p.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0 = until Ctrl-C)")
    p.add_argument("--max-messages", type=int, default=0, help="stop after this many messages (0 = no limit)")
    p.add_argument("--include-hidden", action="store_true", help="with --all, also hidden topics")
    p.add_argument("--poll-period", type=float, default=0.5, help="graph polling period for new topics [s]")
    p.add_argument("--report-every", type=float, default=5.0, help="print what was recorded, its rate and the "
                   "file's size every this many seconds (0 = only at the end; default 5)")
    a = p.parse_args(argv)
    if bool(a.topics) == bool(a.all):
        p.error("give topics to record or --all (not both)")
    bad = [t for t in a.topics if not t.startswith("/")]
    if bad:
        p.error(f"topic names must be absolute (start with '/'): {', '.join(bad)}")
    if a.duration < 0 or a.max_messages < 0 or not a.poll_period > 0 or not a.report_every >= 0:
        p.error("--duration, --max-messages and --report-every must be >= 0 and --poll-period > 0")
    if a.output is None:
        a.output = default_output()
    if not a.output.endswith(".mcap"):
        p.error(f"output file {a.output!r} must end in .mcap")
    return a


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv if argv is None else argv
    args = parse_args(remove_ros_args(argv)[1:])
    try:
        writer = BagWriter(args.output)
    except (BagError, OSError) as exc:
        print(f"hr_record: cannot write {args.output}: {exc}", file=sys.stderr)
        return 2
    stop = StopSignals()
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    try:
        node = BagRecorderNode(writer, None if args.all else args.topics, args.include_hidden,
                               args.poll_period, args.max_messages)
        t0 = time.monotonic()
        deadline = t0 + args.duration if args.duration > 0 else None
        next_report = t0 + args.report_every if args.report_every > 0 else None
        node.get_logger().info(f"recording to {args.output}")
        while stop.signal is None and not node.done and (deadline is None or time.monotonic() < deadline):
            rclpy.spin_once(node, timeout_sec=0.05)
            if next_report is not None and time.monotonic() >= next_report:
                next_report += args.report_every
                so_far = volume_text(time.monotonic() - t0, writer.message_count, node.bytes_in,
                                     file_size(args.output))
                print(f"hr_record: {so_far}", flush=True)
        elapsed = time.monotonic() - t0
        missing = node.missing()
    finally:
        writer.close()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        stop.restore()
    dur = ((writer.end_ns or 0) - (writer.start_ns or 0)) / 1e9
    print(f"hr_record: wrote {writer.message_count} messages on {len(writer.topics)} topics "
          f"({dur:.2f} s) to {args.output}")
    if node is not None:
        print(f"hr_record: {volume_text(elapsed, writer.message_count, node.bytes_in, file_size(args.output))}")
    for t in writer.topics.values():
        print(f"  {t.name} [{t.type}] {t.count}")
    if missing:
        print(f"hr_record: never appeared on the graph: {', '.join(missing)}", file=sys.stderr)
    return 0 if writer.message_count > 0 else 1


if __name__ == "__main__":
    sys.exit(main())
