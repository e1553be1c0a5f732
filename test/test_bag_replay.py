"""Recorded sensor data, no simulator: ``bags/plant_head_scan.mcap`` replayed into the
perception nodes and the planner (issue #6, item 5).

The bag (written by ``tools/record_bags.py``; see ``bags/README.md``) holds the head scan of
the plant: ``/joint_states``, ``/head_camera/image_raw`` + ``camera_info``,
``/head_camera/points`` (optical frame) and ``/robot_description``; its side file
``bags/plant_head_scan.yaml`` holds the ground truth (valve and marker poses from
``config/scenes/plant.yaml``). ``bag_play --stamps-now`` replays it (one affine stamp map:
each sensor frame keeps the stamp of the joint state that placed the camera) into real
``voxel_mapper``, ``marker_localizer`` and ``reach_planner`` processes -- ``scene_sim`` and
``joint_driver`` are NOT running.
Checks:

* ``/voxel_map`` against the scene's own voxelization (``Scene.voxelize`` on the mapper's
  grid): every occupied voxel lies within one voxel (26-neighbourhood) of a true surface
  voxel, and the true surface voxels the sensor saw (noise-free ray cast of the scene from
  each recorded camera pose, FK of the recorded joint states) are covered within one voxel;
* every ``/target_pose`` within 1 cm (and 3 deg) of the ground-truth valve pose;
* docs/operator.md's recipe (mapper, planner, ``hr_play --loop``, ``reach_operator``) run as
  written: the plan succeeds on the measured map (the planner's ``/voxel_map`` replaced its
  scene file). One graph for all three (it was two, 55 s + 71 s of the suite).
"""
from __future__ import annotations

import importlib.util
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState, PointCloud2

from humanoid_reach_ros.io import msgs
from humanoid_reach_ros.io.mcap_bag import BagReader
from nodetools import REPO_ROOT, wait_for

BAG = REPO_ROOT / "bags" / "plant_head_scan.mcap"
SIDE = REPO_ROOT / "bags" / "plant_head_scan.yaml"
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
MAPPER_PARAMS = "config/voxel_mapper.yaml"
SEEN_COVERAGE_MIN = 0.85  # fraction of the seen true surface voxels with a map voxel within one voxel
SEEN_MAX_RANGE_M = 3.0    # seen = noise-free hits nearer than this (farther, the range noise exceeds a voxel)


def voxel_keys(centres: np.ndarray, h: float) -> set[tuple[int, int, int]]:
    return set(map(tuple, np.floor(np.asarray(centres) / h).astype(np.int64).tolist()))


def dilate(keys: set[tuple[int, int, int]]) -> set[tuple[int, int, int]]:
    """The 26-neighbourhood closure of a voxel set (within one voxel, Chebyshev)."""
    offsets = [(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1)]
    return {(x + a, y + b, z + c) for x, y, z in keys for a, b, c in offsets}


def mapper_inputs(diagnostics) -> dict[str, str]:
    """The newest ``voxel_mapper: inputs`` diagnostic values (what happened to the clouds)."""
    for array in reversed(diagnostics.messages):
        for status in array.status:
            if status.name.endswith("voxel_mapper: inputs"):
                return {kv.key: kv.value for kv in status.values if kv.key.startswith(("clouds", "no_pose", "problem"))}
    return {}


def seen_surface_voxels(h: float, extent: tuple[np.ndarray, np.ndarray]) -> tuple[set, int]:
    """Voxels of the scene's surfaces (floor excluded) hit by noise-free rays from every
    recorded cloud's camera pose (the depth sensor's pixel grid, its range gate)."""
    from humanoid_reach_ros.paths import config_path
    from humanoid_reach_ros.perception.markers import JointStateBuffer, camera_pose
    from humanoid_reach_ros.robot.model import RobotModel
    from humanoid_reach_ros.sim import camera as cam
    from humanoid_reach_ros.sim.scene import load_scene

    model = RobotModel("hrp2")
    scene = load_scene(config_path("scenes/plant.yaml"))
    floor = np.array([p.floor for p in scene.primitives])
    buffer = JointStateBuffer(window_s=3600.0, max_items=100_000)
    clouds = []
    with BagReader(BAG) as r:
        for m in r.messages(["/joint_states", "/head_camera/points"]):
            if m.topic == "/joint_states":
                js = deserialize_message(m.data, JointState)
                joints, _ = msgs.model_joints(js, model)
                buffer.push(msgs.seconds_from_time(js.header.stamp), joints)
            else:
                pc = deserialize_message(m.data, PointCloud2)
                clouds.append((msgs.seconds_from_time(pc.header.stamp), pc.width * pc.height))
    camera = cam.PinholeCamera.from_fov(320, 240, 1.0471975511965976)  # the depth sensor's grid (stride 2)
    seen: set = set()
    lo, hi = extent
    for stamp, _ in clouds:
        joints, reason = buffer.at(stamp, 0.05)
        assert joints is not None, reason
        hits = cam.cast(scene, camera, camera_pose(model, joints, "head_camera_optical_frame"), max_range_m=100.0)
        ok = hits.hit & (hits.range_m >= 0.1) & (hits.range_m <= SEEN_MAX_RANGE_M)
        ok &= ~floor[np.maximum(hits.primitive, 0)]
        p = hits.points_world()[ok]
        p = p[np.all((p >= lo) & (p < hi), axis=1)]
        seen |= voxel_keys(p, h)
    return seen, len(clouds)


def test_side_file_matches_scene() -> None:
    """The ground truth in the side file is the scene's (a regenerated scene needs new bags)."""
    from humanoid_reach_ros.paths import config_path
    from humanoid_reach_ros.sim.scene import load_scene

    assert BAG.is_file() and SIDE.is_file(), "bags/ is missing: run tools/record_bags.py"
    truth = yaml.safe_load(SIDE.read_text())["ground_truth"]
    scene = load_scene(config_path("scenes/plant.yaml"))
    assert np.allclose(truth["valve"]["position"], scene.target.pose[:3, 3])
    assert np.allclose(truth["marker"]["position"], scene.target.marker_pose[:3, 3])
    assert truth["marker"]["id"] == scene.target.aruco.marker_id
    with BagReader(BAG) as r:
        assert {"/joint_states", "/head_camera/image_raw", "/head_camera/camera_info", "/head_camera/points",
                "/robot_description"} <= set(r.topics)
        assert r.topics["/robot_description"].qos.transient_local
    total = sum(f.stat().st_size for f in BAG.parent.iterdir() if f.is_file())
    assert total < 30e6, f"bags/ holds {total / 1e6:.1f} MB (limit 30 MB)"


def load_record_tool():
    spec = importlib.util.spec_from_file_location("record_bags", REPO_ROOT / "tools" / "record_bags.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_joint_state_thinning() -> None:
    """At most one state per period, plus every state a sensor frame is stamped with."""
    thin = load_record_tool().thin_joint_states
    stamps = list(range(0, 100, 5))  # 200 Hz in "ms"
    assert thin(stamps, set(), 20) == [s % 20 == 0 for s in stamps]
    keep = thin(stamps, {35, 55}, 20)
    assert [s for s, k in zip(stamps, keep) if k] == [0, 20, 35, 40, 55, 60, 80]
    assert thin([], {1}, 20) == []


@pytest.mark.parametrize("args, message", [
    (["--sensor-period", "0"], "--sensor-period must be within"),
    (["--frames-per-pose", "0"], "--frames-per-pose and --valve-frames"),
    (["--joint-states-hz", "nan"], "--joint-states-hz must be within"),
    (["--limit-mb", "-1"], "--limit-mb > 0"),
])
def test_record_tool_bad_arguments(args: list[str], message: str, capsys: pytest.CaptureFixture) -> None:
    """Bad options exit 2 with a reason before anything is started or written."""
    with pytest.raises(SystemExit) as exc:
        load_record_tool().main(args + ["--out", "/nonexistent/never/created"])
    assert exc.value.code == 2 and message in capsys.readouterr().err
    assert not Path("/nonexistent/never/created").exists()


def test_frames_carry_recorded_joint_state_stamps() -> None:
    """Every image, camera_info and cloud in the bag is stamped with a joint state the bag
    holds (what makes the replayed camera pose the recorded one)."""
    from sensor_msgs.msg import CameraInfo, Image

    stamps: dict[str, set[int]] = {}
    types = {"/joint_states": JointState, "/head_camera/image_raw": Image, "/head_camera/camera_info": CameraInfo,
             "/head_camera/points": PointCloud2}
    with BagReader(BAG) as r:
        for m in r.messages(list(types)):
            h = deserialize_message(m.data, types[m.topic]).header.stamp
            stamps.setdefault(m.topic, set()).add(h.sec * 1_000_000_000 + h.nanosec)
    for topic in types:
        assert len(stamps.get(topic, ())) >= 10, topic
        if topic != "/joint_states":
            assert stamps[topic] <= stamps["/joint_states"], topic


@pytest.mark.node
def test_replay_beside_a_live_publisher_is_refused_unless_into_live(start_node, ros_env, tmp_path: Path) -> None:
    """``hr_play`` beside a running ``joint_driver`` (issue 33): refused by default (exit 3, the
    publisher named, nothing published); ``--into-live`` plays and names the two sources."""
    start_node("joint_driver", params_file="config/joint_driver.yaml", ready_log=r"simulated hrp2")
    play = [sys.executable, "-m", "humanoid_reach_ros.nodes.bag_play", str(BAG), "--stamps-now",
            "--topics", "/joint_states", "--start-offset", "14"]
    r = subprocess.run(play, env=dict(ros_env), cwd=REPO_ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 3, (r.returncode, r.stderr)
    assert "not playing: a live graph publishes the topics of this replay (/joint_states by /joint_driver)" in \
        r.stderr and "--namespace /replay" in r.stderr and "--into-live" in r.stderr, r.stderr
    assert "published 0 messages" in r.stdout, r.stdout
    r = subprocess.run(play + ["--into-live"], env=dict(ros_env), cwd=REPO_ROOT, capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0, r.stderr
    assert "--into-live: playing INTO THE LIVE GRAPH" in r.stderr, r.stderr
    assert "/joint_states is also published by /joint_driver: the replay mixes two sources" in r.stderr, r.stderr


def joint_value(msg: JointState, name: str) -> float:
    return float(msg.position[list(msg.name).index(name)])


@pytest.mark.node
def test_replay_beside_a_live_graph_leaves_its_map_and_joint_states_alone(start_node, ros_env, ros_probe,
                                                                           tmp_path: Path) -> None:
    """Issue 33, point 1: the head scan replayed beside a live graph (``joint_driver``,
    ``scene_sim``, ``voxel_mapper``). Once the live map is built, ``scene_sim`` is stopped (the
    live map then changes only if something else feeds the mapper). ``hr_play --stamps-now``
    as the README's tour had it is refused (exit 3); ``--namespace /replay`` plays every message
    under ``/replay`` while the live ``/joint_states`` (what the planner, the executor and the
    mapper read) carry only the driver's posture, the mapper receives no cloud and the live
    map keeps its voxel count. (Before: 6,585 -> 8,625 voxels, the recording's clouds fused.)"""
    from humanoid_reach_ros.robot.model import RobotModel

    head_yaw = RobotModel("hrp2").spec.neck_joints[0]
    maps = ros_probe.collect(PointCloud2, "/voxel_map", LATCHED)
    diagnostics = ros_probe.collect(DiagnosticArray, "/diagnostics")
    live_states = ros_probe.collect(JointState, "/joint_states", QoSProfile(depth=5000,
                                                                            reliability=ReliabilityPolicy.RELIABLE))
    replay_states = ros_probe.collect(JointState, "/replay/joint_states",
                                      QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE))
    replay_clouds = ros_probe.collect(PointCloud2, "/replay/head_camera/points", qos_profile_sensor_data)
    start_node("joint_driver", params_file="config/joint_driver.yaml", ready_log=r"simulated hrp2")
    sensors = start_node("scene_sim", params_file="config/scene_sim.yaml", ready_log="scene sensors ready",
                         timeout=120.0)
    start_node("voxel_mapper", params_file=MAPPER_PARAMS, ready_log="voxel mapper ready", timeout=120.0)

    def voxels() -> int:
        return maps.last.width * maps.last.height if len(maps) else 0
    ros_probe.spin_until(lambda: voxels() > 500, 120.0, "a live map of > 500 voxels",
                         on_timeout=lambda: str(mapper_inputs(diagnostics)))
    assert sensors.stop() == 0   # the live map is now frozen: only a replay's clouds could change it
    received = lambda: int(mapper_inputs(diagnostics).get("clouds_received", -1))  # noqa: E731
    settled = {"clouds": -2, "since": time.monotonic()}

    def mapper_settled() -> bool:   # the same clouds_received in diagnostics for 3 s: nothing in flight
        n = received()
        if n != settled["clouds"]:
            settled.update(clouds=n, since=time.monotonic())
        return n >= 0 and time.monotonic() - settled["since"] > 3.0
    ros_probe.spin_until(mapper_settled, 60.0, "the mapper's last live cloud")
    before_voxels, before_clouds, before_maps = voxels(), received(), len(maps)
    live_yaw = joint_value(live_states.last, head_yaw)

    play = [sys.executable, "-m", "humanoid_reach_ros.nodes.bag_play", str(BAG), "--stamps-now"]
    r = subprocess.run(play, env=dict(ros_env), cwd=REPO_ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 3 and "/joint_states by /joint_driver" in r.stderr, (r.returncode, r.stderr)
    assert "published 0 messages" in r.stdout, r.stdout

    live_states.clear()
    t_play = time.monotonic()
    log = tmp_path / "play.log"
    with open(log, "wb") as f:
        proc = subprocess.Popen(play + ["--namespace", "/replay", "--rate", "4", "--wait-subscribers", "20"],
                                env=dict(ros_env), cwd=REPO_ROOT, stdout=f, stderr=subprocess.STDOUT)
    try:
        ros_probe.spin_until(lambda: proc.poll() is not None, 120.0, "the namespaced replay to end",
                             on_timeout=log.read_text)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, log.read_text()
    with BagReader(BAG) as bag:
        n_states = bag.topics["/joint_states"].message_count
    ros_probe.spin_until(lambda: len(replay_states) >= n_states, 30.0, "every replayed joint state under /replay")
    assert len(replay_clouds) > 0, log.read_text()
    replayed_yaw = [joint_value(m, head_yaw) for m in replay_states.messages]
    assert max(abs(y - live_yaw) for y in replayed_yaw) > 0.3   # the recording turns the head: told apart
    # two more mapper diagnostics after the replay ended: whatever it sent has been counted
    t_end = time.monotonic()
    def mapper_reports_since_end() -> int:
        return sum(any(st.name.endswith("voxel_mapper: inputs") for st in a.status) for a in diagnostics.since(t_end))
    ros_probe.spin_until(lambda: mapper_reports_since_end() >= 2, 30.0, "two mapper diagnostics after the replay")
    live = [joint_value(m, head_yaw) for m in live_states.since(t_play)]
    assert live and max(abs(y - live_yaw) for y in live) < 1e-6, "a replayed joint state reached /joint_states"
    assert received() == before_clouds, (before_clouds, mapper_inputs(diagnostics))
    assert voxels() == before_voxels and len(maps) == before_maps, (before_voxels, voxels())
    print(f"\nlive map {before_voxels} voxels before and {voxels()} after; {len(replay_states)} joint states and "
          f"{len(replay_clouds)} clouds replayed under /replay; {len(live)} live joint states, none of them replayed")

    # the same measurements see a replay that does reach the live graph (--into-live, asked for):
    # the mapper counts the recording's clouds and the live /joint_states carry its head angles
    # (looped until both are seen: on a loaded machine the probe's subscription matched the player's
    # publisher only after a short pass had ended)
    live_states.clear()

    def leaked() -> bool:
        return received() > before_clouds and any(abs(joint_value(m, head_yaw) - live_yaw) > 0.3
                                                  for m in live_states.messages)
    with open(log, "wb") as f:
        proc = subprocess.Popen(play + ["--into-live", "--loop", "--rate", "4", "--topics", "/joint_states",
                                        "/head_camera/points", "--start-offset", "10"],
                                env=dict(ros_env), cwd=REPO_ROOT, stdout=f, stderr=subprocess.STDOUT)
    try:
        ros_probe.spin_until(lambda: leaked() or proc.poll() is not None, 120.0,
                             "the recording's clouds at the mapper and its joint states on /joint_states",
                             on_timeout=lambda: f"{mapper_inputs(diagnostics)}\n{log.read_text()}")
        assert proc.poll() is None, log.read_text()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(30.0) == 0, log.read_text()
    finally:
        if proc.poll() is None:
            proc.kill()
    assert "--into-live: playing INTO THE LIVE GRAPH" in log.read_text(), log.read_text()
    print(f"--into-live: the mapper received {received() - before_clouds} clouds of the recording; live map "
          f"{voxels()} voxels")


def operator_md_replay_recipe() -> list[list[str]]:
    """The commands of docs/operator.md's "To replay the shipped head scan into a planner" block."""
    from test_readme_commands import OPERATOR_MD, shell_blocks, shell_commands

    after = OPERATOR_MD.read_text().split("To replay the shipped head scan into a planner", 1)[1]
    return shell_commands(f"```bash\n{shell_blocks(after)[0]}```\n")


@pytest.mark.node
def test_operator_md_replay_recipe_maps_localizes_and_plans(start_node, ros_env, ros_probe, tmp_path: Path) -> None:
    """docs/operator.md's replay into a planner, command by command as written (the installed
    executables on PATH, from the repository's root), with the waits its comments name: the
    nodes' "ready", then one pass of the bag (``--loop``: the replayed ``/joint_states`` stay
    recent; a single pass ended in NO_JOINT_STATES). A ``marker_localizer`` runs beside it
    (not in the recipe). Checked: the map against the scene, the marker against the ground
    truth, then the recipe's ``reach_operator`` plans on the measured map."""
    from humanoid_reach_ros.paths import config_path
    from humanoid_reach_ros.sim.scene import load_scene

    cmds = operator_md_replay_recipe()
    assert [c[0] for c in cmds] == ["voxel_mapper", "reach_planner", "hr_play", "reach_operator"], cmds
    assert cmds[0][-1] == cmds[1][-1] == cmds[2][-1] == "&" and "--loop" in cmds[2] and cmds[3][-1] != "&"
    assert "--no-auto-look" in cmds[3]   # no executor in this graph: nobody to look (else a --timeout wait for /look)
    assert cmds[0][-2] == MAPPER_PARAMS, cmds[0]
    side = yaml.safe_load(SIDE.read_text())
    truth = side["ground_truth"]["valve"]
    mapper_cfg = yaml.safe_load((REPO_ROOT / MAPPER_PARAMS).read_text())["/**"]["ros__parameters"]
    h = float(mapper_cfg["resolution_m"])
    with BagReader(BAG) as bag:
        bag_s = (bag.end_ns - bag.start_ns) / 1e9   # one pass
    maps = ros_probe.collect(PointCloud2, "/voxel_map", LATCHED)
    diagnostics = ros_probe.collect(DiagnosticArray, "/diagnostics")
    targets = ros_probe.collect(PoseStamped, "/target_pose", qos_profile_sensor_data)
    procs: list[tuple[str, subprocess.Popen, Path]] = []

    def background(argv: list[str]) -> tuple[str, subprocess.Popen, Path]:
        log = tmp_path / f"{argv[0]}.log"
        with open(log, "wb") as f:
            p = subprocess.Popen(argv[:-1], env=dict(ros_env), cwd=REPO_ROOT, stdout=f, stderr=subprocess.STDOUT,
                                 stdin=subprocess.DEVNULL)
        procs.append((argv[0], p, log))
        return procs[-1]

    def logs() -> str:
        return "\n".join(f"--- {n}:\n" + log.read_text()[-3000:] for n, _, log in procs)
    try:
        t0 = time.monotonic()
        for argv in cmds[:2]:   # the two nodes, then "once both nodes say ready"
            background(argv)
        localizer = start_node("marker_localizer", params_file="config/marker_localizer.yaml")
        for (_name, p, log), ready in zip(procs, ("voxel mapper ready", "reach planner ready")):
            wait_for_text(log, ready, p, 180.0, logs)
        localizer.wait_for_log(r"marker localizer ready", 120.0)
        t_ready = time.monotonic()
        _, play, play_log = background(cmds[2])
        wait_for_text(play_log, "playing ", play, 60.0, logs)
        t_play = time.monotonic()
        ros_probe.spin_until(lambda: time.monotonic() - t_play > bag_s + 3.0 and len(maps) > 0, bag_s + 90.0,
                             "one pass of the bag and a /voxel_map", on_timeout=logs)

        # ---- the map against the scene's voxelization, where seen (the loop goes on: the newest map)
        extent = (np.array(mapper_cfg["extent_min_m"], float), np.array(mapper_cfg["extent_max_m"], float))
        scene = load_scene(config_path("scenes/plant.yaml"))
        true_keys = voxel_keys(scene.voxelize(h, extent), h)
        # false occupancy is judged against every surface, the floor's included: the mapper drops points
        # below floor_z_m, but range noise lifts a few floor points into the first voxel layer above it
        near_truth = dilate(true_keys | voxel_keys(scene.voxelize(h, extent, include_floor=True), h))
        seen, n_clouds = seen_surface_voxels(h, extent)
        assert len(seen & true_keys) >= 0.99 * len(seen)  # the seen set is made of true surface voxels

        def coverage() -> float:
            return len(seen & dilate(voxel_keys(msgs.points_from_cloud(maps.last).points, h))) / max(1, len(seen))
        # the mapper may still be integrating the first pass (its mailbox): wait for the coverage, generously
        ros_probe.spin_until(lambda: coverage() >= SEEN_COVERAGE_MIN, 90.0, "the seen surface mapped",
                             on_timeout=lambda: f"coverage {coverage():.1%}; inputs {mapper_inputs(diagnostics)}")
        map_keys = voxel_keys(msgs.points_from_cloud(maps.last).points, h)
        assert len(map_keys) > 1000, f"only {len(map_keys)} voxels mapped"
        false = [k for k in map_keys if k not in near_truth]
        assert not false, (f"{len(false)} of {len(map_keys)} map voxels are more than one voxel from the scene's "
                           f"surfaces, e.g. {[tuple(np.multiply(k, h) + h / 2) for k in false[:5]]}")
        # large messages arrive (config/fastdds.xml): without the profile 10-24 of the 31 clouds did
        ros_probe.spin_until(lambda: int(mapper_inputs(diagnostics).get("clouds_received", 0)) >= n_clouds - 2,
                             30.0, "the mapper's clouds_received", on_timeout=lambda: str(mapper_inputs(diagnostics)))
        print(f"\n/voxel_map: {len(map_keys)} voxels; {len(seen)} true surface voxels seen from {n_clouds} recorded "
              f"clouds, {coverage():.1%} covered within one voxel; no false voxel; mapper inputs "
              f"{mapper_inputs(diagnostics)}")

        # ---- the marker target within 1 cm of the ground truth
        assert len(targets) >= 1, "no /target_pose from the replayed images:\n" + localizer.log_tail(30)
        q = truth["quaternion_xyzw"]
        R_true = pin.Quaternion(q[3], q[0], q[1], q[2]).toRotationMatrix()
        errors = []
        for t in targets.messages:
            assert t.header.frame_id == "world"
            T = msgs.se3_from_pose(t.pose)
            dp = float(np.linalg.norm(T.translation - np.asarray(truth["position"])))
            da = float(np.degrees(np.linalg.norm(pin.log3(R_true.T @ T.rotation))))
            errors.append((dp, da))
        worst_p, worst_a = max(e[0] for e in errors), max(e[1] for e in errors)
        print("\n".join(localizer.log_lines("skip")[:5]))
        print(f"/target_pose: {len(errors)} poses, worst error {worst_p * 1e3:.1f} mm, {worst_a:.2f} deg")
        assert worst_p <= 0.01 and worst_a <= 3.0, errors
        # the recipe's target is the valve's, within 1 cm of the marker's measure
        assert np.linalg.norm(np.asarray(cmds[3][2:5], float) - np.asarray(truth["position"])) <= 0.01, cmds[3]

        # ---- the recipe's plan, on the measured map
        # A plan takes ~0.65 s here when quiet; beside the other xdist worker's graph it may spend the
        # planner's 2 s budget (fresh clone, CI: three tries in a row NO_PATH, both arms out of time).
        # Asked again until a generous deadline: exit 5 (no motion: NO_PATH / NO_GOAL_FOUND) or 6
        # (a budget spent with the frontier as an obstacle, then a 1 s plan through it, is answered
        # UNOBSERVED_SPACE; with no executor in this graph, --no-auto-look).
        t_checked = time.monotonic()
        tries: list[subprocess.CompletedProcess] = []
        deadline = time.monotonic() + 240.0
        while not tries or (tries[-1].returncode in (5, 6) and time.monotonic() < deadline):
            tries.append(subprocess.run(cmds[3], env=dict(ros_env), cwd=REPO_ROOT, capture_output=True, text=True,
                                        timeout=180))
        r = tries[-1]
        assert r.returncode == 0, ([(t.returncode, t.stdout[-300:]) for t in tries], r.stderr, logs())
        assert "NO_JOINT_STATES" not in r.stderr and "plan: " in r.stdout, r.stderr
        planner_log = procs[1][2].read_text()
        assert "map source: /voxel_map (" in planner_log, planner_log[-3000:]   # the measured map replaced the file
        assert "also published by" not in play_log.read_text()   # the bag is the only source
        print(f"\n{r.stdout}\nnodes ready in {t_ready - t0:.1f} s, one pass and checks {t_checked - t_play:.1f} s, "
              f"plan {time.monotonic() - t_checked:.1f} s ({len(tries)} tries)")
    finally:
        codes = {}
        for name, p, _ in reversed(procs):
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
            try:
                codes[name] = p.wait(20.0)
            except subprocess.TimeoutExpired:
                p.kill()
                codes[name] = "killed"
    assert all(c == 0 for c in codes.values()), (codes, logs())


def wait_for_text(log: Path, text: str, proc: subprocess.Popen, timeout: float, on_timeout) -> None:
    def found() -> bool:
        if text in log.read_text():
            return True
        assert proc.poll() is None, f"exited with {proc.returncode} before {text!r}\n{on_timeout()}"
        return False
    wait_for(found, timeout, repr(text), on_timeout=on_timeout)
