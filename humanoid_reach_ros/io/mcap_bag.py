"""rosbag2-compatible MCAP files: message definitions, writing, reading, validation.

The ROS-free half of the bag tools (``nodes/bag_record.py`` and ``nodes/bag_play.py`` hold
the rclpy half). A file written here is what ``ros2 bag record -s mcap`` writes:

* header profile ``ros2``; one Schema per message type, named ``pkg/msg/Type``, encoding
  ``ros2msg``, whose data is the FULL definition text: the type's ``.msg`` file followed,
  for every nested type (recursively, each once), by a separator line of 80 ``=``, a line
  ``MSG: pkg/msg/Type`` and that type's ``.msg`` text (rosbag2's
  ``LocalMessageDefinitionSource`` format). The ``.msg`` files are found through the ament
  index (``share/<pkg>/msg/`` under ``AMENT_PREFIX_PATH``: the venv and ``install/``).
  The ``_Request``/``_Response``/``_Goal``/``_Result``/``_Feedback`` types take their part
  of the ``.srv`` / ``.action`` file; types without any file (the ``_FeedbackMessage`` /
  ``_Event`` wrappers generated for actions and services) get a definition generated from
  the Python class' ``SLOT_TYPES`` (fields only: constants and comments are not available
  there, a simplification of rosbag2, which stores the IDL text for them);
* one Channel per topic, message encoding ``cdr``, channel metadata
  ``offered_qos_profiles`` (rosbag2's YAML list of the publishers' QoS) so that a player
  can offer the same durability (transient local for latched topics);
* Message records with the raw CDR bytes, ``log_time`` = ``publish_time`` = receive time
  (ns since the Unix epoch); zstd-compressed chunks, chunk indexes, statistics and summary
  offsets; a Metadata record ``rosbag2`` with ``serialized_metadata`` (the bag's
  ``metadata.yaml`` content: topics, types, counts, start and duration).

``BagReader`` opens a file (clear ``BagError`` for a missing, truncated or corrupt file or
one that is not a ros2/cdr bag), lists its topics, and iterates messages with a topic filter
and a start offset, checking chunk CRCs. ``playback_schedule`` is the player's timing.
"""
from __future__ import annotations

import importlib
import os
import re
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO, Iterable, Iterator, Mapping, Sequence

import yaml

SEPARATOR = "=" * 80
PROFILE = "ros2"
SCHEMA_ENCODING = "ros2msg"
MESSAGE_ENCODING = "cdr"
METADATA_NAME = "rosbag2"
ROSBAG2_VERSION = 9  # metadata.yaml version of rosbag2 Jazzy

_PRIMITIVES = {"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32",
               "uint32", "int64", "uint64", "string", "wstring"}
_FIELD_TYPE = re.compile(r"^([A-Za-z_][\w/]*)(?:<=\d+)?(?:\[[^\]]*\])?$")
_IDL_BASIC = {"boolean": "bool", "octet": "byte", "float": "float32", "double": "float64", "char": "char",
              "wchar": "wchar"}


class BagError(RuntimeError):
    """A bag file or message type that cannot be used; the message says why."""


# ---------------------------------------------------------------- type names and classes
def split_type(type_name: str) -> tuple[str, str, str]:
    """``pkg/msg/Type`` or ``pkg/Type`` -> (pkg, interface kind, Type); ``BagError`` otherwise."""
    parts = type_name.strip().split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3 or not all(re.fullmatch(r"[A-Za-z_]\w*", p) for p in parts):
        raise BagError(f"malformed message type name {type_name!r} (expected pkg/msg/Type)")
    return parts[0], parts[1], parts[2]


def full_type_name(type_name: str) -> str:
    pkg, kind, name = split_type(type_name)
    return f"{pkg}/{kind}/{name}"


def message_class(type_name: str) -> type:
    """The Python class of a message type (``pkg/msg/Type``, also the generated
    ``pkg/action/Action_FeedbackMessage`` / ``pkg/srv/Service_Event`` types).
    ``BagError`` naming the type if its package is not installed or has no such type."""
    pkg, kind, name = split_type(type_name)
    try:
        module = importlib.import_module(f"{pkg}.{kind}")
    except ImportError as exc:
        raise BagError(f"unknown message type {type_name!r}: cannot import {pkg}.{kind} ({exc}); "
                       "is its package installed and sourced?") from None
    cls = getattr(module, name, None)
    if cls is None and "_" in name:  # Action_FeedbackMessage, Service_Request, ...
        base, _, suffix = name.partition("_")
        parent = getattr(module, base, None)
        cls = getattr(parent, suffix, None) or getattr(getattr(parent, "Impl", None), suffix, None)
    if cls is None or not hasattr(cls, "get_fields_and_field_types"):
        raise BagError(f"unknown message type {type_name!r}: {pkg}.{kind} has no message {name}")
    return cls


# ---------------------------------------------------------------- message definitions
def _share_dirs(pkg: str) -> list[Path]:
    """``share/<pkg>`` under every ament prefix (the ament index), then ament_index_python."""
    dirs = []
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix and (Path(prefix) / "share" / pkg).is_dir():
            dirs.append(Path(prefix) / "share" / pkg)
    if not dirs:
        try:
            from ament_index_python.packages import get_package_share_directory
            dirs.append(Path(get_package_share_directory(pkg)))
        except Exception:  # noqa: BLE001 - PackageNotFoundError, or no ament_index_python at all
            pass
    return dirs


def _msg_file(pkg: str, kind: str, name: str) -> Path | None:
    for share in _share_dirs(pkg):
        f = share / kind / f"{name}.msg"
        if f.is_file():
            return f
    return None


def _msg_file_dependencies(pkg: str, text: str) -> list[str]:
    """Nested (non-primitive) types named by the fields of a ``.msg`` text, as ``pkg/msg/Type``."""
    deps: list[str] = []
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        tokens = line.split()
        if len(tokens) < 2 or "=" in tokens[1]:  # blank, or a constant "type NAME=value"
            continue
        m = _FIELD_TYPE.match(tokens[0])
        if m is None or m.group(1) in _PRIMITIVES:
            continue
        base = m.group(1)
        if "/" in base:
            dep = full_type_name(base)
        elif base == "Header" and _msg_file(pkg, "msg", "Header") is None:
            dep = "std_msgs/msg/Header"
        else:
            dep = f"{pkg}/msg/{base}"
        if dep not in deps:
            deps.append(dep)
    return deps


def _idl_type_text(t: Any, deps: list[str]) -> str:
    """``.msg`` spelling of a rosidl_parser type object (from a class' ``SLOT_TYPES``)."""
    from rosidl_parser import definition as d

    if isinstance(t, d.Array):
        return f"{_idl_type_text(t.value_type, deps)}[{t.size}]"
    if isinstance(t, d.BoundedSequence):
        return f"{_idl_type_text(t.value_type, deps)}[<={t.maximum_size}]"
    if isinstance(t, d.UnboundedSequence):
        return f"{_idl_type_text(t.value_type, deps)}[]"
    if isinstance(t, d.BoundedString):
        return f"string<={t.maximum_size}"
    if isinstance(t, d.UnboundedString):
        return "string"
    if isinstance(t, d.BoundedWString):
        return f"wstring<={t.maximum_size}"
    if isinstance(t, d.UnboundedWString):
        return "wstring"
    if isinstance(t, d.NamespacedType):
        dep = "/".join([*t.namespaces, t.name])
        if dep not in deps:
            deps.append(dep)
        return f"{t.namespaces[0]}/{t.name}"
    if isinstance(t, d.BasicType):
        return _IDL_BASIC.get(t.typename, t.typename)
    raise BagError(f"cannot spell field type {t!r} as .msg")


def _generated_definition(type_name: str) -> tuple[str, list[str]]:
    cls = message_class(type_name)
    deps: list[str] = []
    lines = [f"{_idl_type_text(t, deps)} {field}"
             for field, t in zip(cls.get_fields_and_field_types(), cls.SLOT_TYPES)]
    return "\n".join(lines) + "\n", deps


def _own_definition(type_name: str) -> tuple[str, list[str]]:
    """(definition text of this type alone, its nested types)."""
    pkg, kind, name = split_type(type_name)
    f = _msg_file(pkg, kind, name)
    if f is not None:
        text = f.read_text()
        return text, _msg_file_dependencies(pkg, text)
    section = _interface_section(pkg, kind, name)
    if section is not None:
        return section, _msg_file_dependencies(pkg, section)
    return _generated_definition(type_name)


_SECTIONS = {"srv": ("Request", "Response"), "action": ("Goal", "Result", "Feedback")}


def _interface_section(pkg: str, kind: str, name: str) -> str | None:
    """The ``Request``/``Response`` part of a ``.srv`` or ``Goal``/``Result``/``Feedback``
    part of a ``.action`` file (sections split by ``---``) for ``Service_Request`` etc."""
    base, _, suffix = name.rpartition("_")
    if kind not in _SECTIONS or suffix not in _SECTIONS[kind]:
        return None
    for share in _share_dirs(pkg):
        f = share / kind / f"{base}.{kind}"
        if f.is_file():
            sections = re.split(r"^---\s*$", f.read_text(), flags=re.MULTILINE)
            i = _SECTIONS[kind].index(suffix)
            if len(sections) == len(_SECTIONS[kind]):
                return sections[i].strip("\n") + "\n"
    return None


def message_definition(type_name: str) -> str:
    """The full ``ros2msg`` definition of a type: its own text, then every nested type
    (depth first, each once) after ``SEPARATOR`` and ``MSG: pkg/msg/Type`` lines."""
    root = full_type_name(type_name)
    text, pending = _own_definition(root)
    parts = [text.rstrip("\n")]
    seen = {root}
    pending = list(pending)
    while pending:
        dep = pending.pop(0)
        if dep in seen:
            continue
        seen.add(dep)
        dep_text, dep_deps = _own_definition(dep)
        parts.append(f"{SEPARATOR}\nMSG: {dep}\n{dep_text.rstrip(chr(10))}")
        pending[:0] = [x for x in dep_deps if x not in seen]
    return "\n".join(parts) + "\n"


# ---------------------------------------------------------------- QoS as rosbag2 writes it
@dataclass(frozen=True)
class QosInfo:
    """The QoS a bag records for a topic (what matters for replay)."""

    reliable: bool = True
    transient_local: bool = False
    depth: int = 10


_MAX_DURATION = {"sec": 2147483647, "nsec": 4294967295}


def qos_yaml(profiles: Sequence[QosInfo]) -> str:
    """rosbag2's ``offered_qos_profiles`` YAML (Jazzy spelling: policy names as strings)."""
    return yaml.safe_dump([{
        "history": "keep_last", "depth": int(p.depth),
        "reliability": "reliable" if p.reliable else "best_effort",
        "durability": "transient_local" if p.transient_local else "volatile",
        "deadline": dict(_MAX_DURATION), "lifespan": dict(_MAX_DURATION), "liveliness": "automatic",
        "liveliness_lease_duration": dict(_MAX_DURATION), "avoid_ros_namespace_conventions": False,
    } for p in profiles], sort_keys=False)


def parse_qos_yaml(text: str) -> list[QosInfo]:
    """Profiles from ``offered_qos_profiles`` (strings as in Jazzy, or rmw enum integers as
    older rosbag2 wrote them); an empty or unreadable text gives no profiles."""
    try:
        doc = yaml.safe_load(text) if text else None
    except yaml.YAMLError:
        return []
    out = []
    for p in doc if isinstance(doc, list) else []:
        if not isinstance(p, Mapping):
            continue
        rel, dur = p.get("reliability", "reliable"), p.get("durability", "volatile")
        out.append(QosInfo(reliable=rel not in ("best_effort", 2),
                           transient_local=dur in ("transient_local", 1),
                           depth=int(p.get("depth", 10) or 10)))
    return out


def replay_qos(profiles: Sequence[QosInfo]) -> QosInfo:
    """The QoS to offer on replay: transient local if every recorded publisher was
    (latched topics: /robot_description, /voxel_map), reliable unless one was best effort."""
    if not profiles:
        return QosInfo()
    return QosInfo(reliable=all(p.reliable for p in profiles),
                   transient_local=all(p.transient_local for p in profiles),
                   depth=max(p.depth for p in profiles))


# ---------------------------------------------------------------- writing
@dataclass
class _TopicStats:
    name: str
    type: str
    qos: str
    channel_id: int
    count: int = 0


class BagWriter:
    """Writes a rosbag2-compatible MCAP file (see the module docstring).

    ``add_topic(name, type, qos_profiles)`` once per topic, ``write(name, cdr_bytes,
    receive_time_ns)`` per message, ``close()`` at the end (writes the summary; a file that
    was not closed has no summary and most readers refuse it)."""

    def __init__(self, path: str | Path, chunk_size: int = 1 << 20) -> None:
        from mcap.writer import CompressionType, Writer

        self.path = Path(path)
        if self.path.is_dir():
            raise BagError(f"output {self.path} is a directory; give a file name ending in .mcap")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file: BinaryIO = open(self.path, "wb")
        self._writer = Writer(self._file, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        self._writer.start(profile=PROFILE, library="humanoid_reach_ros.io.mcap_bag")
        self._schemas: dict[str, int] = {}
        self.topics: dict[str, _TopicStats] = {}
        self.start_ns: int | None = None
        self.end_ns: int | None = None
        self.closed = False

    @property
    def message_count(self) -> int:
        return sum(t.count for t in self.topics.values())

    def add_topic(self, topic: str, type_name: str, qos_profiles: Sequence[QosInfo] = ()) -> None:
        type_name = full_type_name(type_name)
        if topic in self.topics:
            if self.topics[topic].type != type_name:
                raise BagError(f"topic {topic} already recorded as {self.topics[topic].type}, not {type_name}")
            return
        if type_name not in self._schemas:
            self._schemas[type_name] = self._writer.register_schema(
                name=type_name, encoding=SCHEMA_ENCODING, data=message_definition(type_name).encode())
        qos = qos_yaml(qos_profiles)
        channel_id = self._writer.register_channel(
            topic=topic, message_encoding=MESSAGE_ENCODING, schema_id=self._schemas[type_name],
            metadata={"offered_qos_profiles": qos, "topic_type_hash": ""})
        self.topics[topic] = _TopicStats(topic, type_name, qos, channel_id)

    def write(self, topic: str, data: bytes, receive_time_ns: int | None = None) -> None:
        if self.closed:
            raise BagError("bag already closed")
        t = self.topics[topic]
        stamp = time.time_ns() if receive_time_ns is None else int(receive_time_ns)
        self._writer.add_message(channel_id=t.channel_id, log_time=stamp, data=bytes(data),
                                 publish_time=stamp, sequence=t.count)
        t.count += 1
        self.start_ns = stamp if self.start_ns is None else min(self.start_ns, stamp)
        self.end_ns = stamp if self.end_ns is None else max(self.end_ns, stamp)

    def rosbag2_metadata(self) -> dict[str, Any]:
        """The bag's ``metadata.yaml`` content as rosbag2 would write it for this file."""
        start = self.start_ns or 0
        duration = (self.end_ns - start) if self.end_ns is not None else 0
        return {"rosbag2_bagfile_information": {
            "version": ROSBAG2_VERSION, "storage_identifier": "mcap",
            "duration": {"nanoseconds": duration}, "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": self.message_count,
            "topics_with_message_count": [{
                "topic_metadata": {"name": t.name, "type": t.type, "serialization_format": MESSAGE_ENCODING,
                                   "offered_qos_profiles": t.qos, "type_description_hash": ""},
                "message_count": t.count} for t in self.topics.values()],
            "compression_format": "", "compression_mode": "",
            "relative_file_paths": [self.path.name],
            "files": [{"path": self.path.name, "starting_time": {"nanoseconds_since_epoch": start},
                       "duration": {"nanoseconds": duration}, "message_count": self.message_count}],
            "custom_data": {}, "ros_distro": "jazzy"}}

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            self._writer.add_metadata(METADATA_NAME, {"serialized_metadata": yaml.safe_dump(
                self.rosbag2_metadata(), sort_keys=False)})
            self._writer.finish()
        finally:
            self._file.close()

    def __enter__(self) -> "BagWriter":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


# ---------------------------------------------------------------- reading
@dataclass(frozen=True)
class TopicInfo:
    name: str
    type: str
    message_count: int
    qos: QosInfo


@dataclass(frozen=True)
class BagMessage:
    topic: str
    type: str
    log_time_ns: int
    data: bytes


class BagReader:
    """A rosbag2-style MCAP file opened for reading (``BagError`` with the reason if it
    is missing, not MCAP, truncated (no summary: the recorder did not finish), corrupt,
    or not a ``ros2`` / ``cdr`` bag)."""

    def __init__(self, path: str | Path) -> None:
        from mcap.exceptions import McapError
        from mcap.reader import make_reader

        self.path = Path(path)
        if not self.path.exists():
            raise BagError(f"bag file {self.path} does not exist")
        if self.path.is_dir():
            mcaps = sorted(self.path.glob("*.mcap"))
            if len(mcaps) != 1:
                raise BagError(f"{self.path} is a directory with {len(mcaps)} .mcap files; give one file")
            self.path = mcaps[0]
        self._file = open(self.path, "rb")
        try:
            self._reader = make_reader(self._file, validate_crcs=True)
            header = self._reader.get_header()
            summary = self._reader.get_summary()
        except (McapError, Exception) as exc:  # noqa: BLE001 - any failure to parse means "not readable"
            self._file.close()
            raise BagError(f"{self.path} is not a readable MCAP file ({type(exc).__name__}: {exc})") from None
        if summary is None or summary.statistics is None:
            self._file.close()
            raise BagError(f"{self.path} has no summary section (truncated, or the recording was not "
                           "finished cleanly)")
        self.profile = header.profile
        self.summary = summary
        bad = [c.topic for c in summary.channels.values() if c.message_encoding != MESSAGE_ENCODING]
        if bad:
            self._file.close()
            raise BagError(f"{self.path}: topics {', '.join(sorted(bad))} are not CDR-encoded")
        self.topics: dict[str, TopicInfo] = {}
        counts = summary.statistics.channel_message_counts
        for cid, ch in summary.channels.items():
            schema = summary.schemas.get(ch.schema_id)
            if schema is None:
                self._file.close()
                raise BagError(f"{self.path}: topic {ch.topic} has no schema")
            qos = replay_qos(parse_qos_yaml(ch.metadata.get("offered_qos_profiles", "")))
            self.topics[ch.topic] = TopicInfo(ch.topic, schema.name, int(counts.get(cid, 0)), qos)

    @property
    def start_ns(self) -> int:
        return int(self.summary.statistics.message_start_time)

    @property
    def end_ns(self) -> int:
        return int(self.summary.statistics.message_end_time)

    @property
    def message_count(self) -> int:
        return int(self.summary.statistics.message_count)

    def schema_text(self, topic: str) -> str:
        ch = next(c for c in self.summary.channels.values() if c.topic == topic)
        return self.summary.schemas[ch.schema_id].data.decode()

    def select(self, topics: Iterable[str] | None) -> list[str]:
        """The topics to read: all, or the given ones (``BagError`` naming any not in the bag)."""
        if topics is None:
            return sorted(self.topics)
        wanted = list(dict.fromkeys(topics))
        missing = [t for t in wanted if t not in self.topics]
        if missing:
            raise BagError(f"topic(s) {', '.join(missing)} not in {self.path.name}; it has: "
                           f"{', '.join(sorted(self.topics)) or 'no topics'}")
        return wanted

    def messages(self, topics: Iterable[str] | None = None, start_offset_s: float = 0.0) -> Iterator[BagMessage]:
        """Messages in log-time order, optionally only ``topics`` and from ``start_offset_s``
        after the bag's first message. Chunk CRCs are checked (``BagError`` if corrupt)."""
        selected = self.select(topics)
        start = self.start_ns + int(round(max(0.0, start_offset_s) * 1e9))
        try:
            for schema, channel, message in self._reader.iter_messages(topics=selected, starting_at=start,
                                                                       log_time_order=True):
                yield BagMessage(channel.topic, schema.name if schema else "", int(message.log_time),
                                 bytes(message.data))
        except Exception as exc:  # noqa: BLE001 - McapError, CRC, zstd/lz4 errors, struct errors: all "corrupt"
            raise BagError(f"{self.path}: corrupt data ({type(exc).__name__}: {exc})") from None

    def rosbag2_metadata(self) -> dict[str, Any] | None:
        for m in self._reader.iter_metadata():
            if m.name == METADATA_NAME and "serialized_metadata" in m.metadata:
                return yaml.safe_load(m.metadata["serialized_metadata"])
        return None

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> "BagReader":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def describe(reader: BagReader) -> str:
    """A ``ros2 bag info``-like text."""
    dur = (reader.end_ns - reader.start_ns) / 1e9
    lines = [f"file: {reader.path}", f"profile: {reader.profile}", f"duration: {dur:.3f} s",
             f"messages: {reader.message_count}", "topics:"]
    for t in sorted(reader.topics.values(), key=lambda t: t.name):
        latched = ", transient local" if t.qos.transient_local else ""
        lines.append(f"  {t.name} [{t.type}] {t.message_count} msgs{latched}")
    return "\n".join(lines)


# ---------------------------------------------------------------- playback timing
def playback_schedule(log_times_ns: Sequence[int], rate: float) -> list[float]:
    """Seconds after playback start at which each message is due: recorded gaps divided by
    ``rate`` (2.0 = twice as fast), counted from the first message played."""
    if not rate > 0.0:
        raise BagError(f"rate must be > 0, got {rate}")
    if not log_times_ns:
        return []
    t0 = log_times_ns[0]
    return [(t - t0) / 1e9 / rate for t in log_times_ns]


# ---------------------------------------------------------------- where a replay publishes
_TOPIC_NAME = re.compile(r"^(/[A-Za-z_][A-Za-z0-9_]*)+$")


def _absolute_name(name: str, what: str) -> str:
    """``name`` if it is an absolute ROS name (``/a/b_2``; tokens of letters, digits and ``_``,
    none starting with a digit), else ``BagError`` naming ``what``."""
    if not _TOPIC_NAME.match(name):
        raise BagError(f"{what} {name!r} is not an absolute ROS name (like /replay or /replay/joint_states: "
                       f"'/'-separated tokens of letters, digits and '_', none starting with a digit)")
    return name


def replay_topic_names(topics: Sequence[str], namespace: str = "", remaps: Sequence[str] = ()) -> dict[str, str]:
    """Recorded topic -> the topic a replay publishes it on. ``remaps``: ``OLD:=NEW`` pairs as
    ``ros2 bag play --remap`` takes them (``OLD`` a played topic); every other topic goes under
    ``namespace`` (``/replay``: ``/joint_states`` -> ``/replay/joint_states``), or stays where it
    was recorded when ``namespace`` is empty. ``BagError`` for a malformed pair or name, a remap
    of a topic that is not played, or two topics sent to one name."""
    ns = _absolute_name(namespace.rstrip("/"), "--namespace") if namespace not in ("", "/") else ""
    explicit: dict[str, str] = {}
    for pair in remaps:
        old, sep, new = pair.partition(":=")
        if not sep or not old or not new:
            raise BagError(f"--remap {pair!r}: give OLD:=NEW, e.g. /joint_states:=/replay/joint_states")
        _absolute_name(old, "--remap topic")
        _absolute_name(new, "--remap target")
        if old not in topics:
            raise BagError(f"--remap {pair!r}: {old} is not a played topic (played: {', '.join(topics)})")
        explicit[old] = new
    out = {t: explicit.get(t, ns + t) for t in topics}
    seen: dict[str, str] = {}
    for t, name in out.items():
        if name in seen:
            raise BagError(f"{seen[name]} and {t} would both be played on {name}")
        seen[name] = t
    return out


# ---------------------------------------------------------------- a replay beside a live graph
_UNNAMED = "_NODE_NAME_UNKNOWN_"   # rmw's node name of an endpoint whose node is not discovered yet
UNNAMED_NODE = "a node discovery has not named yet"


def other_nodes(publishers: Sequence[str], me: str) -> list[str]:
    """The nodes (``/ns/name``) of a topic's ``publishers`` other than ``me``, sorted, each once.
    An endpoint whose node discovery has not named yet (the player's own, early on) shows as
    ``_NODE_NAME_UNKNOWN_``: ``me`` is taken out by name, else as one unnamed endpoint; the other
    unnamed ones are ``UNNAMED_NODE`` (named at a later look)."""
    nodes = list(publishers)
    unnamed = [n for n in nodes if _UNNAMED in n]
    if me in nodes:
        nodes.remove(me)
    elif unnamed:
        nodes.remove(unnamed[0])
    return sorted({UNNAMED_NODE if _UNNAMED in n else n for n in nodes})


class LiveGraph(Exception):
    """Other nodes publish topics a replay would publish: ``found`` {topic: [nodes]}."""

    def __init__(self, found: Mapping[str, Sequence[str]]) -> None:
        super().__init__(dict(found))
        self.found = dict(found)

    def describe(self) -> str:
        return "; ".join(f"{t} by {', '.join(n)}" for t, n in sorted(self.found.items()))


def refusal(exc: LiveGraph, published: int, finished: bool = False) -> str:
    """What ``hr_play`` says when a live graph publishes topics it would publish (seen before it
    played, while it played, or at its last look after ``finished``)."""
    what = ("not playing" if published == 0 else f"played {published} messages, then saw" if finished
            else f"stopped after {published} messages")
    return (f"hr_play: {what}: a live graph publishes the topics of this replay ({exc.describe()}). Played "
            "there, the recording would feed the live nodes: its clouds into the live map the next plan "
            "trusts, its /joint_states and /robot_description to the planner and the executor. To look at it "
            "beside the graph: --namespace /replay (every topic under /replay; or --remap OLD:=NEW); to replay "
            "into the live graph on purpose: --into-live; to reproduce a run: stop the graph's publishers of "
            "these topics first.")


def split_ros_args(argv: Sequence[str]) -> tuple[list[str], list[str]]:
    """``(own, ros)``: a tool's arguments, and ``--ros-args ... [--]`` (rclpy's). Not rclpy's
    ``remove_ros_args``: it would take ``--remap``'s ``OLD:=NEW`` for a legacy node remapping rule."""
    argv = list(argv)
    if "--ros-args" not in argv:
        return argv, []
    i = argv.index("--ros-args")
    j = argv.index("--", i) if "--" in argv[i:] else len(argv)
    return argv[:i] + argv[j + 1:], argv[i:j + 1]


__all__ = ["BagError", "BagMessage", "BagReader", "BagWriter", "LiveGraph", "QosInfo", "TopicInfo", "UNNAMED_NODE",
           "describe", "full_type_name", "message_class", "message_definition", "other_nodes", "parse_qos_yaml",
           "playback_schedule", "qos_yaml", "refusal", "replay_qos", "replay_topic_names", "split_ros_args",
           "split_type"]
