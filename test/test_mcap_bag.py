"""MCAP record and replay (io/mcap_bag.py, nodes/bag_record.py, nodes/bag_play.py).

Unit tests write and read files in process; node tests run hr_record / hr_play as real
processes against a real joint_driver and check the file with mcap's own reader and the
mcap_ros2 decoder (another MCAP reader than ours)."""
from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from humanoid_reach_interfaces.action import ExecuteReach
from mcap.reader import make_reader
from mcap.writer import Writer as McapWriter
from mcap_ros2.decoder import DecoderFactory
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from humanoid_reach_ros.io import msgs
from humanoid_reach_ros.io.mcap_bag import (SEPARATOR, BagError, BagReader, BagWriter, QosInfo, message_class,
                                            message_definition, parse_qos_yaml, playback_schedule, qos_yaml,
                                            replay_qos)
from nodetools import REPO_ROOT

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
RECORD = "humanoid_reach_ros.nodes.bag_record"
PLAY = "humanoid_reach_ros.nodes.bag_play"


def sections(definition: str) -> dict[str, str]:
    """{type name (root = ""): text} of a full ros2msg definition."""
    out = {}
    for i, part in enumerate(definition.split(SEPARATOR + "\n")):
        if i == 0:
            out[""] = part
        else:
            first, _, rest = part.partition("\n")
            assert first.startswith("MSG: ")
            out[first[5:]] = rest
    return out


def decode_all(path: Path) -> list[tuple[str, str, int, object]]:
    """Every message decoded by mcap's reader + mcap_ros2, CRCs checked, structure validated."""
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.chunk_indexes and all(c.compression == "zstd" for c in summary.chunk_indexes)
        assert all(s.encoding == "ros2msg" for s in summary.schemas.values())
        assert all(c.message_encoding == "cdr" for c in summary.channels.values())
        out = [(c.topic, s.name, m.log_time, d) for s, c, m, d in reader.iter_decoded_messages(log_time_order=True)]
        assert len(out) == summary.statistics.message_count
        for cid, n in summary.statistics.channel_message_counts.items():
            assert n == sum(1 for t, *_ in out if t == summary.channels[cid].topic)
        assert [t for _, _, t, _ in out] == sorted(t for _, _, t, _ in out)
    return out


# ---------------------------------------------------------------- unit
def test_full_definitions_with_nested_types() -> None:
    js = sections(message_definition("sensor_msgs/msg/JointState"))
    assert set(js) == {"", "std_msgs/msg/Header", "builtin_interfaces/msg/Time"}
    assert "std_msgs/Header header" in js[""] and "float64[] position" in js[""]
    assert "builtin_interfaces/Time stamp" in js["std_msgs/msg/Header"]
    assert "uint32 nanosec" in js["builtin_interfaces/msg/Time"]
    # same-package references (geometry_msgs/Pose -> Point, Quaternion), each type once
    ps = sections(message_definition("geometry_msgs/PoseStamped"))
    assert {"geometry_msgs/msg/Pose", "geometry_msgs/msg/Point", "geometry_msgs/msg/Quaternion",
            "std_msgs/msg/Header", "builtin_interfaces/msg/Time"} == set(ps) - {""}
    # our own interfaces from install/, action parts from the .action file, wrappers generated
    fb = sections(message_definition("humanoid_reach_interfaces/action/ExecuteReach_FeedbackMessage"))
    assert "unique_identifier_msgs/msg/UUID" in fb
    assert "float64 progress" in fb["humanoid_reach_interfaces/action/ExecuteReach_Feedback"]
    res = sections(message_definition("humanoid_reach_interfaces/srv/PlanReach_Response"))
    assert "ErrorCode error_code" in res[""] and "int32 NO_TARGET=9" in res["humanoid_reach_interfaces/msg/ErrorCode"]
    assert "humanoid_reach_interfaces/msg/PlanningStatistics" in res
    assert "trajectory_msgs/msg/JointTrajectoryPoint" in res and "builtin_interfaces/msg/Duration" in res


def test_unknown_and_malformed_types() -> None:
    with pytest.raises(BagError, match="unknown message type 'no_such_msgs/msg/Foo'"):
        message_class("no_such_msgs/msg/Foo")
    with pytest.raises(BagError, match="has no message Nope"):
        message_class("std_msgs/msg/Nope")
    with pytest.raises(BagError, match="malformed message type"):
        message_definition("std_msgs/msg/String/x")
    assert message_class("humanoid_reach_interfaces/action/ExecuteReach_FeedbackMessage") is \
        ExecuteReach.Impl.FeedbackMessage


def test_qos_yaml_and_schedule() -> None:
    profiles = [QosInfo(reliable=True, transient_local=True, depth=1), QosInfo(reliable=False, depth=5)]
    assert parse_qos_yaml(qos_yaml(profiles)) == profiles
    # older rosbag2 wrote rmw enum integers
    old = "- {history: 1, depth: 1, reliability: 1, durability: 1}\n"
    assert parse_qos_yaml(old) == [QosInfo(True, True, 1)]
    assert parse_qos_yaml("") == [] and parse_qos_yaml(": : bad [") == []
    assert replay_qos([QosInfo(True, True, 1)]).transient_local
    assert not replay_qos(profiles).transient_local and not replay_qos(profiles).reliable
    assert replay_qos([]) == QosInfo()
    assert playback_schedule([10**9, 2 * 10**9, 4 * 10**9], 2.0) == [0.0, 0.5, 1.5]
    assert playback_schedule([], 1.0) == []
    from humanoid_reach_ros.io.endpoints import restamp_ns
    # rate 1: one constant shift (equal stamps stay equal); rate 2: spacing halved; 0 = unstamped stays 0
    assert [restamp_ns(s, 10**9, 5 * 10**9, 1.0) for s in (10**9 - 3, 10**9, 10**9, 2 * 10**9)] == \
        [5 * 10**9 - 3, 5 * 10**9, 5 * 10**9, 6 * 10**9]
    assert restamp_ns(3 * 10**9, 10**9, 5 * 10**9, 2.0) == 6 * 10**9
    assert restamp_ns(0, 10**9, 5 * 10**9, 1.0) == 0
    with pytest.raises(BagError, match="rate"):
        playback_schedule([1], 0.0)


def test_replay_topic_names() -> None:
    """Where a replay publishes (issue 33): as recorded, under a namespace, or remapped one by one
    (``ros2 bag play --remap``'s OLD:=NEW; a remap wins over the namespace); bad names refused."""
    from humanoid_reach_ros.io.mcap_bag import replay_topic_names as names
    topics = ["/joint_states", "/head_camera/points"]
    assert names(topics) == {t: t for t in topics}
    assert names(topics, "/replay") == {"/joint_states": "/replay/joint_states",
                                        "/head_camera/points": "/replay/head_camera/points"}
    assert names(topics, "/replay/", ["/joint_states:=/old/js"])["/joint_states"] == "/old/js"
    assert names(topics, "", ["/joint_states:=/js"]) == {"/joint_states": "/js", "/head_camera/points":
                                                         "/head_camera/points"}
    for ns, remaps, message in [("replay", [], "--namespace 'replay' is not an absolute ROS name"),
                                ("/2x", [], "is not an absolute ROS name"),
                                ("/a b", [], "is not an absolute ROS name"),
                                ("", ["/joint_states=/js"], "give OLD:=NEW"),
                                ("", ["/joint_states:="], "give OLD:=NEW"),
                                ("", ["/nope:=/x"], "/nope is not a played topic"),
                                ("", ["/joint_states:=js"], "--remap target 'js' is not an absolute"),
                                ("", ["/joint_states:=/head_camera/points"], "would both be played on")]:
        with pytest.raises(BagError, match=message):
            names(topics, ns, remaps)


def test_refusal_names_the_live_publishers_and_the_ways_on() -> None:
    from humanoid_reach_ros.io.mcap_bag import LiveGraph, refusal
    live = LiveGraph({"/joint_states": ["/joint_driver"], "/head_camera/points": ["/scene_sim", "/x"]})
    text = refusal(live, 0)
    assert text.startswith("hr_play: not playing: a live graph publishes the topics of this replay "
                           "(/head_camera/points by /scene_sim, /x; /joint_states by /joint_driver)"), text
    assert all(w in text for w in ("--namespace /replay", "--remap OLD:=NEW", "--into-live", "the live map"))
    assert "stopped after 62 messages:" in refusal(live, 62)
    assert "played 900 messages, then saw:" in refusal(live, 900, finished=True)


def test_recorder_topic_choice_and_qos_matching() -> None:
    from humanoid_reach_ros.io.endpoints import recording_qos as subscription_qos
    from humanoid_reach_ros.nodes.bag_record import is_hidden

    assert is_hidden("/execute_reach/_action/feedback") and is_hidden("/_x")
    assert not is_hidden("/joint_states") and not is_hidden("/head_camera/points")
    latched = QosInfo(transient_local=True, depth=1)
    sensor = QosInfo(reliable=False)
    q = subscription_qos([latched])
    assert q.durability == DurabilityPolicy.TRANSIENT_LOCAL and q.reliability == ReliabilityPolicy.RELIABLE
    q = subscription_qos([latched, QosInfo()])  # one volatile publisher: a latched reader would not match it
    assert q.durability == DurabilityPolicy.VOLATILE
    q = subscription_qos([QosInfo(), sensor])
    assert q.reliability == ReliabilityPolicy.BEST_EFFORT


def write_sample(path: Path, n: int = 50, feedback: bool = False) -> list[JointState]:
    states = [msgs.joint_state(["a", "b"], [0.1 * i, -0.1 * i], stamp=msgs.time_from_seconds(100 + 0.01 * i))
              for i in range(n)]
    with BagWriter(path) as w:
        w.add_topic("/joint_states", "sensor_msgs/msg/JointState", [QosInfo()])
        w.add_topic("/robot_description", "std_msgs/String", [QosInfo(transient_local=True, depth=1)])
        w.write("/robot_description", serialize_message(String(data="<robot/>")), 1_000_000_000)
        if feedback:
            w.add_topic("/fb", "humanoid_reach_interfaces/action/ExecuteReach_FeedbackMessage", [QosInfo()])
            fb = ExecuteReach.Impl.FeedbackMessage()
            fb.feedback.progress = 0.5
            w.write("/fb", serialize_message(fb), 1_000_000_001)
        for i, s in enumerate(states):
            w.write("/joint_states", serialize_message(s), 1_000_000_002 + i * 10_000_000)
    return states


def test_writer_reader_round_trip_other_reader(tmp_path: Path) -> None:
    path = tmp_path / "sample.mcap"
    states = write_sample(path)
    decoded = decode_all(path)
    assert decoded[0][0] == "/robot_description" and decoded[0][3].data == "<robot/>"
    js = [d for t, _, _, d in decoded if t == "/joint_states"]
    assert [list(d.position) for d in js] == [list(s.position) for s in states]
    assert js[7].header.stamp.sec == 100 and js[7].header.stamp.nanosec == states[7].header.stamp.nanosec

    with BagReader(path) as r:
        assert r.topics["/robot_description"].qos.transient_local
        assert not r.topics["/joint_states"].qos.transient_local
        assert r.topics["/joint_states"].message_count == len(states) and r.message_count == len(states) + 1
        meta = r.rosbag2_metadata()["rosbag2_bagfile_information"]
        assert meta["message_count"] == r.message_count and meta["storage_identifier"] == "mcap"
        counts = {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]}
        assert counts == {"/joint_states": 50, "/robot_description": 1}
        assert yaml.safe_load(meta["topics_with_message_count"][1]["topic_metadata"]["offered_qos_profiles"])[0][
            "durability"] == "transient_local"
        # start offset and topic filter
        late = list(r.messages(["/joint_states"], start_offset_s=0.25))
        assert [m.log_time_ns for m in late] == [1_000_000_002 + i * 10_000_000 for i in range(25, 50)]
        with pytest.raises(BagError, match=r"topic\(s\) /nope not in sample.mcap; "
                                           r"it has: /joint_states, /robot_description"):
            r.select(["/joint_states", "/nope"])


def test_generated_wrapper_types(tmp_path: Path) -> None:
    """Action feedback wrappers (hidden topics, recorded only on request) round-trip as bytes;
    their generated definition is not decodable by mcap_ros2, whose .msg grammar has no
    underscores in type names (rosbag2 stores ros2idl for these)."""
    path = tmp_path / "fb.mcap"
    write_sample(path, 3, feedback=True)
    with BagReader(path) as r:
        fb = [m for m in r.messages(["/fb"])]
        assert r.topics["/fb"].type == "humanoid_reach_interfaces/action/ExecuteReach_FeedbackMessage"
    assert deserialize_message(fb[0].data, ExecuteReach.Impl.FeedbackMessage).feedback.progress == 0.5


def test_bad_files(tmp_path: Path) -> None:
    with pytest.raises(BagError, match="does not exist"):
        BagReader(tmp_path / "missing.mcap")
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"this is not an mcap file at all" * 10)
    with pytest.raises(BagError, match="not a readable MCAP file"):
        BagReader(junk)
    good = tmp_path / "good.mcap"
    write_sample(good, 2000)
    data = good.read_bytes()
    truncated = tmp_path / "truncated.mcap"
    truncated.write_bytes(data[: len(data) // 2])
    with pytest.raises(BagError, match="truncated|not a readable"):
        BagReader(truncated)
    # a damaged chunk: the summary reads, the messages do not
    with BagReader(good) as r:
        chunk = r.summary.chunk_indexes[0]
    damaged = bytearray(data)
    for k in range(64):
        damaged[chunk.chunk_start_offset + chunk.chunk_length // 2 + k] ^= 0xFF
    bad = tmp_path / "damaged.mcap"
    bad.write_bytes(bytes(damaged))
    with BagReader(bad) as r, pytest.raises(BagError, match="corrupt data"):
        list(r.messages())
    with pytest.raises(BagError, match="directory"):
        BagWriter(tmp_path)


# ---------------------------------------------------------------- processes
def run_tool(module: str, args: list[str], env, timeout: float = 60.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", module, *args], env=dict(env), cwd=REPO_ROOT, capture_output=True,
                          text=True, timeout=timeout)


def start_tool(module: str, args: list[str], env, log: Path) -> subprocess.Popen:
    with open(log, "wb") as f:
        return subprocess.Popen([sys.executable, "-m", module, *args], env=dict(env), cwd=REPO_ROOT, stdout=f,
                                stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)


def test_cli_bad_inputs(tmp_path: Path, ros_env) -> None:
    r = run_tool(PLAY, [str(tmp_path / "missing.mcap")], ros_env)
    assert r.returncode == 2 and "does not exist" in r.stderr
    (tmp_path / "junk.mcap").write_bytes(b"\x00" * 100)
    r = run_tool(PLAY, [str(tmp_path / "junk.mcap")], ros_env)
    assert r.returncode == 2 and "not a readable MCAP file" in r.stderr
    write_sample(tmp_path / "s.mcap")
    r = run_tool(PLAY, [str(tmp_path / "s.mcap"), "--topics", "/nope"], ros_env)
    assert r.returncode == 2 and "/nope not in s.mcap" in r.stderr
    r = run_tool(PLAY, [str(tmp_path / "s.mcap"), "--rate", "0"], ros_env)
    assert r.returncode == 2 and "--rate must be" in r.stderr
    r = run_tool(PLAY, [str(tmp_path / "s.mcap"), "--namespace", "replay"], ros_env)
    assert r.returncode == 2 and "not an absolute ROS name" in r.stderr, r.stderr
    r = run_tool(PLAY, [str(tmp_path / "s.mcap"), "--remap", "/nope:=/x"], ros_env)
    assert r.returncode == 2 and "/nope is not a played topic" in r.stderr, r.stderr
    r = run_tool(PLAY, [str(tmp_path / "s.mcap"), "--info"], ros_env)
    assert r.returncode == 0 and "/robot_description [std_msgs/msg/String] 1 msgs, transient local" in r.stdout

    # a bag (written by mcap's plain writer) with a type this machine does not have
    unknown = tmp_path / "unknown.mcap"
    with open(unknown, "wb") as f:
        w = McapWriter(f)
        w.start(profile="ros2", library="test")
        sid = w.register_schema("no_such_msgs/msg/Foo", "ros2msg", b"int32 x\n")
        cid = w.register_channel("/foo", "cdr", sid)
        w.add_message(cid, log_time=1, data=b"\x00\x01\x00\x00\x07\x00\x00\x00", publish_time=1)
        w.finish()
    r = run_tool(PLAY, [str(unknown)], ros_env)
    assert r.returncode == 2 and "unknown message type 'no_such_msgs/msg/Foo'" in r.stderr, r.stderr

    r = run_tool(RECORD, ["-o", str(tmp_path / "x.mcap")], ros_env)
    assert r.returncode == 2 and "give topics to record or --all" in r.stderr
    r = run_tool(RECORD, ["-o", str(tmp_path / "x.txt"), "/a"], ros_env)
    assert r.returncode == 2 and "must end in .mcap" in r.stderr
    r = run_tool(RECORD, ["-o", str(tmp_path / "x.mcap"), "joint_states"], ros_env)
    assert r.returncode == 2 and "must be absolute" in r.stderr


def test_record_default_output_is_recordings_and_git_ignores_bags(tmp_path: Path, ros_env) -> None:
    """Without -o: ``recordings/hr_record_<date>_<time>.mcap`` under the current directory, never
    the repository's root (issue 22); git ignores it and every *.mcap outside bags/; no flag
    abbreviations (``--dur`` is not ``--duration``)."""
    import re

    from humanoid_reach_ros.nodes import bag_record

    out = bag_record.parse_args(["/joint_states"]).output
    assert re.fullmatch(r"recordings/hr_record_\d{8}_\d{6}\.mcap", out), out
    assert bag_record.parse_args(["-o", "x/run.mcap", "/a"]).output == "x/run.mcap"
    r = subprocess.run([sys.executable, "-m", RECORD, "/no_such_topic", "--duration", "0.5"], env=dict(ros_env),
                       cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert r.returncode == 1, r.stderr   # nothing recorded, the file written all the same
    written = list((tmp_path / "recordings").glob("hr_record_*.mcap"))
    assert len(written) == 1 and f"to recordings/{written[0].name}" in r.stdout, (written, r.stdout)
    r = run_tool(RECORD, ["--dur", "1", "/a"], ros_env)
    assert r.returncode == 2 and "unrecognized arguments: --dur" in r.stderr, r.stderr
    ignored = subprocess.run(["git", "check-ignore", "--no-index", "run.mcap", "recordings/x.mcap", "test/y.mcap",
                              "bags/plant_head_scan.mcap"], cwd=REPO_ROOT, capture_output=True, text=True).stdout
    assert ignored.split() == ["run.mcap", "recordings/x.mcap", "test/y.mcap"], ignored


@pytest.mark.node
def test_record_and_replay_round_trip(start_node, ros_probe, ros_env, tmp_path: Path) -> None:
    driver = start_node("joint_driver", params_file="config/joint_driver.yaml", ready_log=r"simulated hrp2")
    bag = tmp_path / "run.mcap"
    log = tmp_path / "record.log"
    rec = start_tool(RECORD, ["-o", str(bag), "/joint_states", "/robot_description", "/diagnostics"], ros_env, log)
    try:
        ros_probe.spin_until(lambda: len([x for x in log.read_text().splitlines() if "recording /" in x]) == 3,
                             30.0, "the recorder to subscribe to 3 topics", on_timeout=log.read_text)
        ros_probe.spin_for(2.0)  # a recording window
        rec.send_signal(signal.SIGINT)  # Ctrl-C: the file must still be finished
        assert rec.wait(30.0) == 0, log.read_text()
    finally:
        if rec.poll() is None:
            rec.kill()
    text = log.read_text()
    assert "(reliable, transient_local)" in [x for x in text.splitlines() if "/robot_description" in x][0]

    decoded = decode_all(bag)
    by_topic: dict[str, list] = {}
    for topic, schema, t, d in decoded:
        by_topic.setdefault(topic, []).append((schema, t, d))
    assert set(by_topic) == {"/joint_states", "/robot_description", "/diagnostics"}
    assert len(by_topic["/robot_description"]) == 1 and "<robot" in by_topic["/robot_description"][0][2].data
    assert len(by_topic["/joint_states"]) > 50 and len(by_topic["/joint_states"][0][2].name) == 30
    with BagReader(bag) as r:
        js = sections(r.schema_text("/joint_states"))
        assert {"std_msgs/msg/Header", "builtin_interfaces/msg/Time"} <= set(js)
        assert "diagnostic_msgs/msg/KeyValue" in sections(r.schema_text("/diagnostics"))
        assert r.topics["/robot_description"].qos.transient_local
        recorded = [m.log_time_ns for m in r.messages(["/joint_states"])]
        stamps = [msgs.nanoseconds_from_time(d.header.stamp) for _, _, d in by_topic["/joint_states"]]
        bag_duration = (recorded[-1] - recorded[0]) / 1e9
        late = [m for m in r.messages(["/joint_states"], start_offset_s=1.0)]
        n_late = len(late)

    # replay /joint_states + the latched description at rate 2 (the driver stopped: nothing else publishes)
    assert driver.stop() == 0
    states = ros_probe.collect(JointState, "/joint_states",
                               QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE))
    desc = ros_probe.collect(String, "/robot_description", LATCHED)
    diags = ros_probe.collect(DiagnosticArray, "/diagnostics")
    play_log = tmp_path / "play.log"
    t_start = time.monotonic()
    play = start_tool(PLAY, [str(bag), "--rate", "2", "--topics", "/joint_states", "/robot_description",
                             "--wait-subscribers", "20"], ros_env, play_log)
    ros_probe.spin_until(lambda: play.poll() is not None and len(states) >= len(recorded), 60.0,
                         "the replay to finish", on_timeout=play_log.read_text)
    assert play.returncode == 0, play_log.read_text()
    ros_probe.spin_until(lambda: len(desc) == 1, 10.0, "the latched /robot_description")
    assert desc.last.data == by_topic["/robot_description"][0][2].data
    got = [msgs.nanoseconds_from_time(m.header.stamp) for m in states.messages]
    assert got == stamps  # every message, in the recorded order, stamps untouched
    assert len(diags) == 0  # filtered out
    # rough timing: the player never runs ahead of the schedule (recorded span / rate)
    span = states.times[-1] - states.times[0]
    assert span >= 0.8 * bag_duration / 2.0, (span, bag_duration)
    assert f"published {len(recorded) + 1} messages" in play_log.read_text()

    # --stamps-now and --start-offset: only the last part, stamped at replay time
    states.clear()
    before_ns = time.time_ns()
    r = run_tool(PLAY, [str(bag), "--rate", "4", "--topics", "/joint_states", "--start-offset", "1.0",
                        "--stamps-now", "--wait-subscribers", "20"], ros_env)
    assert r.returncode == 0, r.stderr
    ros_probe.spin_until(lambda: len(states) >= n_late, 20.0, f"{n_late} replayed joint states")
    ros_probe.spin_for(0.2)
    assert len(states) == n_late
    new = [msgs.nanoseconds_from_time(m.header.stamp) for m in states.messages]
    assert all(t >= before_ns for t in new) and new == sorted(new)
    # one affine map for the whole pass (stamp' = t_pass + (stamp - log_time_first) / rate): the
    # recorded spacing of the stamps, divided by the rate, is kept exactly (to rounding)
    old = [msgs.nanoseconds_from_time(deserialize_message(m.data, JointState).header.stamp) for m in late]
    assert all(abs((n - new[0]) - (o - old[0]) / 4.0) <= 1.0 for n, o in zip(new, old)), (new[:5], old[:5])
    assert [list(m.position) for m in states.messages] == [list(deserialize_message(m.data, JointState).position)
                                                            for m in late]

    # a topic that appears after the recorder started is picked up; --max-messages stops it
    late_bag, late_log = tmp_path / "late.mcap", tmp_path / "late.log"
    rec = start_tool(RECORD, ["-o", str(late_bag), "/late", "--max-messages", "3"], ros_env, late_log)
    try:
        ros_probe.spin_until(lambda: "recording to" in late_log.read_text(), 30.0, "the recorder to start",
                             on_timeout=late_log.read_text)
        pub = ros_probe.node.create_publisher(String, "/late", 10)
        sent = []

        def published_until_done() -> bool:
            sent.append(len(sent))
            pub.publish(String(data=f"late {len(sent)}"))
            return rec.poll() is not None

        ros_probe.spin_until(published_until_done, 30.0, "the recorder to stop after 3 messages",
                             on_timeout=late_log.read_text)
        assert rec.returncode == 0, late_log.read_text()
    finally:
        if rec.poll() is None:
            rec.kill()
    got_late = [(t, d.data) for t, _, _, d in decode_all(late_bag)]
    assert len(got_late) == 3 and all(t == "/late" and d.startswith("late ") for t, d in got_late)
    print(f"\nrecorded {len(recorded)} joint states over {bag_duration:.2f} s; replayed at rate 2 in {span:.2f} s "
          f"(started {time.monotonic() - t_start:.1f} s ago)")


def test_loop_until_ctrl_c(tmp_path: Path, ros_env, ros_probe) -> None:
    """--loop replays the bag again and again (every pass in recorded order) until SIGINT."""
    bag = tmp_path / "s.mcap"
    states = write_sample(bag, 20)
    got = ros_probe.collect(JointState, "/joint_states", QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE))
    log = tmp_path / "play.log"
    play = start_tool(PLAY, [str(bag), "--loop", "--rate", "5", "--topics", "/joint_states", "--wait-subscribers",
                             "20"], ros_env, log)
    try:
        ros_probe.spin_until(lambda: len(got) >= 3 * len(states) or play.poll() is not None, 60.0,
                             "three passes", on_timeout=log.read_text)
        play.send_signal(signal.SIGINT)
        assert play.wait(20.0) == 0, log.read_text()
    finally:
        if play.poll() is None:
            play.kill()
    first = [m.position[0] for m in got.messages[:3 * len(states)]]
    assert first == [s.position[0] for s in states] * 3
