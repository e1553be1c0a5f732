#!/usr/bin/env python3
"""Regenerate ``bags/``: the recorded head scan of the plant used by ``test/test_bag_replay.py``.

Usage (from the repository root, after ``. tools/env.sh``)::

    python tools/record_bags.py            # writes bags/plant_head_scan.mcap + .yaml
    python tools/record_bags.py --out /tmp/bags --sensor-period 0.5 --frames-per-pose 3

What it does:

1. starts ``joint_driver`` (the simulated HRP-2, 200 Hz ``/joint_states``) and ``scene_sim``
   (``config/scene_sim.yaml``: 640x480 rgb8 head camera + ``/head_camera/points`` in
   ``head_camera_optical_frame``) with ONE change, ``period_s`` = ``--sensor-period``
   (0.5 s: 2 Hz instead of 10 Hz; a point cloud of the depth sensor is ~0.7 MB even
   zstd-compressed, its float noise does not compress, so the rate is what keeps the bag
   small), plus the MCAP recorder (``nodes/bag_record.py``) on ``/joint_states``,
   ``/head_camera/image_raw``, ``/head_camera/camera_info``, ``/head_camera/points`` and
   ``/robot_description``, in an isolated ROS graph (own domain id, localhost discovery);
2. commands the head scan of the demo (``demo.HEAD_SCAN_DEG`` yaw/pitch poses on
   ``/joint_command``, HEAD_JOINT0 / HEAD_JOINT1 only; the joint driver holds them), waiting at
   each pose for ``--frames-per-pose`` point clouds stamped after the head arrived, then looks
   at the valve (``LOOK_AT_VALVE_DEG``, the marker centred) for ``--valve-frames`` (8) frames;
3. post-processes the raw recording into ``bags/plant_head_scan.mcap``: every sensor frame and
   ``/robot_description`` as recorded, the seconds before scene_sim's first frame cut to
   ``LEAD_S`` (the latched ``/robot_description`` kept, its log time moved to the new start);
   ``/joint_states`` thinned from 200 Hz to at most
   ``--joint-states-hz`` (50 Hz), always KEEPING the joint states whose stamps the sensor
   frames carry (scene_sim stamps each frame with the joint state it rendered from), so a
   replay looks up exactly the recorded camera pose; log times and stamps are untouched;
4. writes the side file ``bags/plant_head_scan.yaml``: ground truth (valve pose R_T_O = the
   scene's target frame, which ``/target_pose`` estimates, and the ArUco marker's world pose,
   both from ``config/scenes/plant.yaml``), the scan poses with their time windows (seconds
   from the bag's first message), the sensor settings, topic counts, the tool, its command
   line and the git commit;
5. checks the size: the whole ``--out`` directory must stay under ``--limit-mb`` (30 MB) --
   exit 1 otherwise.

Exit codes: 0 written, 1 recording failed or the size limit was exceeded, 2 bad arguments.
"""
from __future__ import annotations

import argparse
import datetime as _dt
import hashlib
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import yaml

REPO_ROOT = Path(__file__).resolve().parent.parent
if str(REPO_ROOT) not in sys.path:
    sys.path.insert(0, str(REPO_ROOT))

BAG_NAME = "plant_head_scan"
TOPICS = ("/joint_states", "/head_camera/image_raw", "/head_camera/camera_info", "/head_camera/points",
          "/robot_description")
SENSOR_TOPICS = ("/head_camera/image_raw", "/head_camera/camera_info", "/head_camera/points")
LATCHED = ("/robot_description",)  # kept even if published before the trimmed start (log time moved to it)
LEAD_S = 0.5  # joint states kept before the first sensor frame [s]
LOOK_AT_VALVE_DEG = (0.0, 30.0)  # head yaw, pitch [deg]: the valve marker near the image centre
SCENE_FILE = "scenes/plant.yaml"


# ---------------------------------------------------------------- ROS-free helpers
def thin_joint_states(stamps_ns: Sequence[int], keep_stamps: set[int], min_period_ns: int) -> list[bool]:
    """Which joint states to keep: one at most every ``min_period_ns`` (the first always), and
    every one whose stamp is in ``keep_stamps`` (the stamps the sensor frames carry)."""
    keep: list[bool] = []
    last: int | None = None
    for s in stamps_ns:
        if last is None or s - last >= min_period_ns:
            keep.append(True)
            last = s
        else:
            keep.append(s in keep_stamps)
    return keep


def rpy_to_quaternion_xyzw(rpy: Sequence[float]) -> list[float]:
    import pinocchio as pin

    q = pin.Quaternion(pin.rpy.rpyToMatrix(*[float(v) for v in rpy]))
    return [float(q.x), float(q.y), float(q.z), float(q.w)]


def matrix_to_pose(T: np.ndarray) -> dict[str, list[float]]:
    import pinocchio as pin

    q = pin.Quaternion(np.asarray(T[:3, :3], dtype=float))
    return {"position": [round(float(v), 9) for v in T[:3, 3]],
            "quaternion_xyzw": [round(float(v), 9) for v in (q.x, q.y, q.z, q.w)],
            "rpy": [round(float(v), 9) for v in pin.rpy.matrixToRpy(np.asarray(T[:3, :3], dtype=float))]}


def ground_truth() -> dict[str, Any]:
    """The valve (target frame) and marker poses in the world frame, from the scene file."""
    from humanoid_reach_ros.paths import config_path
    from humanoid_reach_ros.sim.scene import load_scene

    path = config_path(SCENE_FILE)
    scene = load_scene(path)
    t = scene.target
    if t is None or t.aruco is None:
        raise RuntimeError(f"{path} has no target with an ArUco marker")
    return {
        "frame_id": scene.frame_id,
        "scene_file": f"config/{SCENE_FILE}",
        "scene_sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
        "valve": {"name": t.name, "description": "target frame R_T_O (what /target_pose estimates): origin at "
                  "the handwheel centre, x along the valve axis away from the robot, z up",
                  **matrix_to_pose(t.pose)},
        "marker": {"id": int(t.aruco.marker_id), "dictionary": t.aruco.dictionary, "size_m": float(t.aruco.size_m),
                   "description": "OpenCV marker frame (z out of the face, y up, x right seen from the robot)",
                   **matrix_to_pose(t.marker_pose)},
    }


def git_state() -> dict[str, Any]:
    def git(*args: str) -> str:
        return subprocess.run(["git", *args], cwd=REPO_ROOT, capture_output=True, text=True, check=True).stdout.strip()
    try:
        return {"commit": git("rev-parse", "HEAD"), "dirty": bool(git("status", "--porcelain", "--untracked-files=no"))}
    except (OSError, subprocess.CalledProcessError):
        return {"commit": "unknown", "dirty": None}


def dir_size(path: Path) -> int:
    return sum(f.stat().st_size for f in path.iterdir() if f.is_file())


def postprocess(raw: Path, out: Path, joint_states_hz: float) -> dict[str, Any]:
    """Copy ``raw`` into ``out`` with /joint_states thinned (``thin_joint_states``); returns
    per-topic counts and the bag's start / end log times."""
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState

    from humanoid_reach_ros.io.mcap_bag import BagReader, BagWriter, message_class

    with BagReader(raw) as r:
        missing = [t for t in TOPICS if t not in r.topics]
        if missing:
            raise RuntimeError(f"the recording has no {', '.join(missing)}")
        messages = list(r.messages())
        topics = {t: r.topics[t] for t in TOPICS}
    by_topic: dict[str, set[int]] = {t: set() for t in SENSOR_TOPICS}
    for m in messages:
        if m.topic in SENSOR_TOPICS:
            h = deserialize_message(m.data, message_class(topics[m.topic].type)).header.stamp
            by_topic[m.topic].add(h.sec * 1_000_000_000 + h.nanosec)
    sensor_stamps = set().union(*by_topic.values())
    complete = set.intersection(*by_topic.values())
    js = [m for m in messages if m.topic == "/joint_states"]
    js_stamps = []
    for m in js:
        h = deserialize_message(m.data, JointState).header.stamp
        js_stamps.append(h.sec * 1_000_000_000 + h.nanosec)
    keep_js = thin_joint_states(js_stamps, sensor_stamps, int(round(1e9 / joint_states_hz)))
    # the recording starts before scene_sim's first frame: keep LEAD_S of joint states before it
    # (a frame's stamp is its joint state's, which precedes its receipt by the render time)
    first = min(min(m.log_time_ns for m in messages if m.topic in SENSOR_TOPICS), min(sensor_stamps))
    start_ns = first - int(LEAD_S * 1e9)
    dropped = {id(m) for m, k in zip(js, keep_js) if not k or m.log_time_ns < start_ns}
    counts = {t: 0 for t in TOPICS}
    with BagWriter(out) as w:
        for t in TOPICS:
            w.add_topic(t, topics[t].type, [topics[t].qos])
        for m in sorted(messages, key=lambda m: max(m.log_time_ns, start_ns)):
            if m.topic in counts and id(m) not in dropped and (m.log_time_ns >= start_ns or m.topic in LATCHED):
                w.write(m.topic, m.data, max(m.log_time_ns, start_ns))
                counts[m.topic] += 1
    frames_without_js = len(sensor_stamps - set(js_stamps))
    return {"counts": counts, "start_ns": start_ns, "end_ns": messages[-1].log_time_ns,
            "joint_states_recorded": len(js), "sensor_stamps": len(sensor_stamps), "complete_frames": len(complete),
            "sensor_stamps_without_recorded_joint_state": frames_without_js}


# ---------------------------------------------------------------- recording
def command_head(op, pub, yaw_deg: float, pitch_deg: float, timeout: float) -> None:
    """The head to (yaw, pitch) straight through the driver's /joint_command (``pub``; head joints
    only, the driver holds them). Recording needs no executor: only joint_driver and scene_sim run."""
    from humanoid_reach_ros.io import msgs
    from humanoid_reach_ros.robot.spec import load_robot_spec

    head_joints = load_robot_spec()[0].head_joints

    goal = np.radians([yaw_deg, pitch_deg])
    cmd = msgs.joint_state(list(head_joints), goal)

    def there() -> bool:
        pub.publish(cmd)
        js = op.joint_states
        pos = np.array([js.position[list(js.name).index(n)] for n in head_joints])
        return bool(np.all(np.abs(pos - goal) < 0.01))
    op.spin_until(there, timeout, f"the head at yaw {yaw_deg:g}, pitch {pitch_deg:g} deg")


def record(args: argparse.Namespace, work: Path) -> tuple[Path, list[dict[str, Any]]]:
    """Run the graph, command the scan, return the raw bag and the scan log."""
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import JointState, PointCloud2

    from humanoid_reach_ros import demo
    from humanoid_reach_ros.graph import allocate_domain, graph_env

    lease = allocate_domain()
    env = graph_env(lease.domain_id)
    graph = demo.Graph(work, env)
    op = None
    raw = work / "raw.mcap"
    scan: list[dict[str, Any]] = []
    try:
        graph.start("joint_driver")
        graph.start("scene_sim", {"period_s": float(args.sensor_period), "scene_file": SCENE_FILE})
        rec = graph.start_command("bag_record", [sys.executable, "-m", "humanoid_reach_ros.nodes.bag_record",
                                                 "-o", str(raw), *TOPICS])
        op = demo.DemoClient(lease.domain_id, graph)
        head_pub = op.node.create_publisher(JointState, "/joint_command", 10)
        clouds: list[int] = []
        op.node.create_subscription(
            PointCloud2, "/head_camera/points",
            lambda m: clouds.append(m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec),
            qos_profile_sensor_data)
        op.spin_until(lambda: op.joint_states is not None and len(clouds) > 0, 120.0,
                      "/joint_states and the first point cloud")
        op.spin_until(lambda: len([x for x in rec.log().splitlines() if "recording /" in x]) == len(TOPICS), 60.0,
                      f"the recorder to subscribe to {len(TOPICS)} topics")
        poses = [(y, p, args.frames_per_pose, "scan") for y, p in demo.HEAD_SCAN_DEG]
        poses.append((*LOOK_AT_VALVE_DEG, args.valve_frames, "look_at_valve"))
        for yaw, pitch, frames, kind in poses:
            command_head(op, head_pub, yaw, pitch, timeout=30.0)
            js = op.joint_states
            arrived = js.header.stamp.sec * 1_000_000_000 + js.header.stamp.nanosec
            op.spin_until(lambda arrived=arrived, frames=frames: sum(1 for s in clouds if s >= arrived) >= frames, 60.0,
                          f"{frames} point clouds at head yaw {yaw:g}, pitch {pitch:g} deg")
            left = clouds[-1]
            scan.append({"kind": kind, "yaw_deg": float(yaw), "pitch_deg": float(pitch),
                         "arrived_stamp_ns": int(arrived), "last_frame_stamp_ns": int(left),
                         "frames": int(sum(1 for s in clouds if arrived <= s <= left))})
            print(f"[record_bags] {kind}: head yaw {yaw:+5.1f} pitch {pitch:+5.1f} deg, "
                  f"{scan[-1]['frames']} frames")
        op.spin_for(0.3)
    finally:
        if op is not None:
            op.close()
        codes = graph.stop()
        lease.release()
    if codes.get("bag_record") not in (0, None) or not raw.is_file():
        raise RuntimeError(f"the recorder failed (exit codes {codes})\n{graph.log_tails()}")
    return raw, scan


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=str(REPO_ROOT / "bags"), help="output directory (default: bags/)")
    ap.add_argument("--sensor-period", type=float, default=0.5,
                    help="scene_sim period_s while recording [s] (default 0.5: 2 Hz)")
    ap.add_argument("--frames-per-pose", type=int, default=3, help="point clouds per scan pose after arrival")
    ap.add_argument("--valve-frames", type=int, default=8, help="frames while looking at the valve")
    ap.add_argument("--joint-states-hz", type=float, default=50.0, help="keep /joint_states at most at this rate")
    ap.add_argument("--limit-mb", type=float, default=30.0, help="size limit of the output directory [MB]")
    args = ap.parse_args(argv)
    if not (0.05 <= args.sensor_period <= 5.0):
        ap.error("--sensor-period must be within [0.05, 5] s")
    if not (1 <= args.frames_per_pose <= 50 and 1 <= args.valve_frames <= 50):
        ap.error("--frames-per-pose and --valve-frames must be within 1..50")
    if not (1.0 <= args.joint_states_hz <= 1000.0) or not args.limit_mb > 0:
        ap.error("--joint-states-hz must be within [1, 1000] and --limit-mb > 0")
    out_dir = Path(args.out).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    bag, side = out_dir / f"{BAG_NAME}.mcap", out_dir / f"{BAG_NAME}.yaml"
    truth = ground_truth()
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="record_bags.") as tmp:
        try:
            raw, scan = record(args, Path(tmp))
            info = postprocess(raw, bag, args.joint_states_hz)
        except (RuntimeError, TimeoutError, AssertionError) as exc:
            print(f"[record_bags] error: {exc}", file=sys.stderr)
            return 1
        raw_size = raw.stat().st_size
    start = info["start_ns"]
    for s in scan:  # windows relative to the bag's first message (stamps ~ log times; survives restamping)
        s["arrived_s"] = round((s.pop("arrived_stamp_ns") - start) / 1e9, 3)
        s["last_frame_s"] = round((s.pop("last_frame_stamp_ns") - start) / 1e9, 3)
    doc = {
        "bag": bag.name,
        "description": "HRP-2 head scan of the plant scene (scene_sim, no robot motion but the head), for "
                       "replay into voxel_mapper, marker_localizer and reach_planner without scene_sim",
        "generated": {"tool": "tools/record_bags.py",
                      "command": " ".join(["tools/record_bags.py", *(argv or sys.argv[1:])]),
                      **git_state(), "date_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")},
        "ground_truth": truth,
        "sensors": {"node": "scene_sim", "params_file": "config/scene_sim.yaml",
                    "overrides": {"period_s": float(args.sensor_period)},
                    "camera": "640x480 rgb8, 60 deg horizontal FOV, frame head_camera_optical_frame",
                    "points": "depth sensor every 2nd pixel, range noise 0.0025 r^2, 2 % dropouts, frame "
                              "head_camera_optical_frame"},
        "joint_states": {"recorded": info["joint_states_recorded"], "kept": info["counts"]["/joint_states"],
                         "thinning": f"at most {args.joint_states_hz:g} Hz plus every joint state a sensor frame's "
                                     "stamp names (scene_sim stamps frames with the joint state it rendered from)",
                         "sensor_stamps_without_recorded_joint_state":
                             info["sensor_stamps_without_recorded_joint_state"]},
        "scan": scan,
        "duration_s": round((info["end_ns"] - start) / 1e9, 3),
        "topics": info["counts"],
        "frames": {"stamps": info["sensor_stamps"], "complete": info["complete_frames"],
                   "note": "a frame = image + camera_info + points with one stamp; the recorder subscribes best "
                           "effort (sensor-data QoS), so under load a large image or cloud can be lost"},
        "size_bytes": bag.stat().st_size,
        "raw_recording_bytes": raw_size,
    }
    side.write_text("# Generated by tools/record_bags.py -- do not edit; regenerate instead.\n"
                    + yaml.safe_dump(doc, sort_keys=False, width=110, default_flow_style=None))
    total = dir_size(out_dir)
    print(f"[record_bags] wrote {bag} ({bag.stat().st_size / 1e6:.1f} MB, raw recording {raw_size / 1e6:.1f} MB, "
          f"{doc['duration_s']:.1f} s) and {side.name} in {time.monotonic() - t0:.0f} s; {out_dir} holds "
          f"{total / 1e6:.1f} MB")
    for t, n in info["counts"].items():
        print(f"  {t}: {n}")
    if total > args.limit_mb * 1e6:
        print(f"[record_bags] error: {out_dir} is {total / 1e6:.1f} MB > {args.limit_mb:g} MB; use a longer "
              "--sensor-period or fewer frames", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
