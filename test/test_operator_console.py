"""The operator console (issue 34): its frames and controls without ROS, its server's answers to
bad input, and the whole flow in a real browser (Debian's chromium through Playwright) against a
launched graph: the page draws, a click near the valve sets the target, Plan shows the ghost
without moving the robot, Execute moves the hand there (read from /joint_states), Home goes back.
The long form (a scan first, the CPU and bandwidth at idle) is bench/console.py."""
from __future__ import annotations

import asyncio
import json
import math
import threading
import time
from pathlib import Path
from types import SimpleNamespace as NS

import numpy as np
import pytest

from humanoid_reach_ros.operator.console.control import ConsoleControl
from humanoid_reach_ros.operator.console.server import ConsoleConfig, ConsoleFeed, ConsoleServer
from humanoid_reach_ros.operator.console.views import RobotView, VoxelLayer, unpack, voxel_keys
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.shapes import load_collision_model
from humanoid_reach_ros.robot.spec import robots
from humanoid_reach_ros.testing.console_page import VALVE, free_port
from nodetools import wait_for
from test_operator_core import FakeClient, plan_response

JOINTS = np.zeros(3)
SHORT_SCAN_DEG = [0.0, 35.0, 0.0, 45.0]   # yaw pitch pairs: two head poses down at the valve


# ---------------------------------------------------------------- frames
def test_voxel_layers_go_out_as_changes_and_a_joining_page_gets_them_all() -> None:
    import zlib
    layer = VoxelLayer("occupied", 0.02)
    pts = np.array([[0.01, 0.01, 0.01], [0.71, 0.03, 0.91], [0.711, 0.031, 0.909], [math.nan, 0.0, 0.0]])
    assert voxel_keys(pts, 0.02).tolist() == [[0, 0, 0], [35, 1, 45]]   # duplicates and NaN dropped
    layer.update(pts)
    h, payload = unpack(layer.delta())
    assert (h["added"], h["removed"], h["full"], h["total"]) == (2, 0, False, 2)
    assert np.frombuffer(zlib.decompress(payload), "<i2").reshape(-1, 3).tolist() == [[0, 0, 0], [35, 1, 45]]
    layer.update(pts[:2])
    assert layer.delta() is None                      # the same map: nothing to send
    layer.update(np.array([[0.71, 0.03, 0.91], [0.05, 0.05, 0.05]]))
    h, payload = unpack(layer.delta())
    keys = np.frombuffer(zlib.decompress(payload), "<i2").reshape(-1, 3).tolist()
    assert (h["added"], h["removed"]) == (1, 1) and keys == [[2, 2, 2], [0, 0, 0]]
    h, payload = unpack(layer.snapshot())
    assert h["full"] and h["added"] == 2 and len(layer) == 2
    with pytest.raises(ValueError, match="resolution"):
        VoxelLayer("x", 0.0)


@pytest.mark.parametrize("name", robots())
def test_every_robot_is_drawn_from_its_collision_capsules(name: str) -> None:
    """No robot-specific code: each of config/robots/ draws, moves and previews a plan."""
    model = RobotModel(name)
    view = RobotView(model, load_collision_model(None, model))
    info = view.model_info()
    assert info["name"] == model.name and len(info["radii"]) == view.cm.n_shapes > 5
    q0 = model.half_sitting_joints
    h, payload = unpack(view.frame(q0))
    ends = np.frombuffer(payload, "<f4").reshape(2, -1, 3)
    assert h["shapes"] == view.cm.n_shapes and ends.shape[1] == view.cm.n_shapes
    assert np.all(np.isfinite(ends)) and ends[..., 2].max() > 0.8      # standing: the head well above the floor
    assert view.frame(q0) is None                                      # not moved: nothing sent
    arm = next(limb for limb in model.limbs.values() if limb.tip in model.hand_frames.values())
    q1 = q0.copy()
    q1[arm.joint_index[0]] += 0.3
    assert view.frame(q1) is not None
    names = [model.joint_names[i] for i in arm.joint_index]
    idx = list(arm.joint_index)
    traj = NS(joint_names=names, points=[NS(positions=list(q0[idx]), time_from_start=NS(sec=0, nanosec=0)),
                                         NS(positions=list(q1[idx]), time_from_start=NS(sec=2, nanosec=0))])
    frame, summary = view.ghost(traj, q0, 10)
    h, payload = unpack(frame)
    data = np.frombuffer(payload, "<f4").reshape(h["frames"], 2 * view.cm.n_shapes, 3)
    assert h["frames"] == summary["frames"] == 8 and summary["duration_s"] == 2.0 and h["times"][-1] == 2.0
    assert np.allclose(data[0], view.ends(q0), atol=1e-5) and np.allclose(data[-1], view.ends(q1), atol=1e-5)
    with pytest.raises(ValueError, match="does not have"):
        view.ghost(NS(joint_names=["no_such_joint"], points=traj.points), q0, 10)


def test_the_camera_image_goes_out_scaled_with_the_marker_outlined() -> None:
    import cv2

    from humanoid_reach_ros.operator.console.server import marker_detector
    from humanoid_reach_ros.operator.console.views import image_frame
    gray = np.full((480, 640), 200, np.uint8)
    gray[140:340, 220:420] = cv2.aruco.generateImageMarker(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50),
                                                           7, 200)
    h, jpeg = unpack(image_frame(gray, marker_detector("DICT_4X4_50"), 60, 320))
    assert (h["w"], h["h"]) == (320, 240) and jpeg[:2] == b"\xff\xd8"        # a JPEG, half size
    (outline,) = h["markers"]
    assert np.allclose(sorted(map(tuple, outline)), [(110, 70), (110, 170), (210, 70), (210, 170)], atol=2.0), outline
    h, _ = unpack(image_frame(np.full((480, 640), 90, np.uint8), marker_detector("DICT_4X4_50"), 60, 1000))
    assert h["markers"] == [] and h["w"] == 640                               # none in view; never scaled up
    with pytest.raises(ValueError, match="unknown ArUco dictionary"):
        marker_detector("DICT_NOPE")


# ---------------------------------------------------------------- controls
class Pages:
    """What the control sends, per page (None: to all)."""

    def __init__(self) -> None:
        self.messages: list[tuple[dict, object]] = []
        self.frames: list[bytes] = []

    def emit(self, m: dict, to: object) -> None:
        json.dumps(m, allow_nan=False)     # every message is valid JSON
        self.messages.append((m, to))

    def of(self, kind: str, to: object = "any") -> list[dict]:
        return [m for m, t in self.messages if m["t"] == kind and (to == "any" or t == to)]


def control_with(client: FakeClient, joints: np.ndarray | None = JOINTS, distance: float = 0.01):
    pages = Pages()
    state = {"joints": joints}
    control = ConsoleControl(client, lambda args: NS(args=args), lambda: state["joints"], lambda p: distance,
                             lambda traj, start: (b"ghost", {"frames": 2}), pages.emit, pages.frames.append, 0.06)
    return control, pages, state


def finish(control: ConsoleControl) -> None:
    wait_for(lambda: control.busy is None, 10.0, "the action to end")
    control.worker.join(5.0)


def test_one_operator_at_a_time_and_every_bad_request_answered() -> None:
    control, pages, _ = control_with(FakeClient(plans=[plan_response()]))
    for page, request, words in [
            (1, "plan", "a JSON object"), (1, {"op": "fly"}, "unknown op 'fly'"),
            (1, {"op": "plan", "target": [0.7, 0, 0.9]}, "nobody holds them"),
            (1, {"op": "release"}, "does not hold")]:
        control.handle(page, request)
        assert words in pages.of("error", page)[-1]["text"], (request, pages.of("error", page)[-1])
    control.handle(1, {"op": "take"})
    control.handle(2, {"op": "take"})
    assert "another page holds the controls" in pages.of("error", 2)[-1]["text"]
    control.handle(2, {"op": "scan"})
    assert "another page holds them" in pages.of("error", 2)[-1]["text"]
    for request, words in [({"op": "plan", "target": [0.7, None, 0.9]}, "three finite numbers"),
                           ({"op": "plan", "target": [0.7, 0.0]}, "[x, y, z]"),
                           ({"op": "plan", "target": [1e6, 0.0, 0.0]}, "not a point of the map"),
                           ({"op": "plan", "target": [0.7, 0.0, 0.9], "arm": "third"}, "arm must be one of"),
                           ({"op": "look", "point": "valve"}, "[x, y, z]"),
                           ({"op": "execute"}, "no plan to execute"),
                           ({"op": "cancel"}, "nothing is running")]:
        control.handle(1, request)
        assert words in pages.of("error", 1)[-1]["text"], (request, pages.of("error", 1)[-1])
    assert control.busy is None and control.holder == 1
    control.left(2)                      # a view-only page closing changes nothing
    assert control.holder == 1
    control.left(1)                      # the holder closing frees the controls
    control.handle(2, {"op": "take"})
    assert control.holder == 2


def test_a_click_off_the_map_is_refused() -> None:
    control, pages, _ = control_with(FakeClient(), distance=0.5)
    control.handle(1, {"op": "take"})
    control.handle(1, {"op": "plan", "target": [0.7, 0.0, 0.9]})
    assert "is not on the map: the nearest occupied voxel is 500 mm away" in pages.of("error", 1)[-1]["text"]
    control, pages, _ = control_with(FakeClient(), distance=math.inf)
    control.handle(1, {"op": "take"})
    control.handle(1, {"op": "look", "point": [0.7, 0.0, 0.9]})
    assert "the map is empty" in pages.of("error", 1)[-1]["text"]


def test_plan_previews_and_execute_runs_that_plan_only_from_where_it_started() -> None:
    client = FakeClient(plans=[plan_response(), plan_response()])
    control, pages, state = control_with(client)
    control.handle(1, {"op": "take"})
    control.handle(1, {"op": "plan", "target": [0.7, 0.03, 0.9], "arm": "left"})
    finish(control)
    res = pages.of("result")[-1]
    assert res["op"] == "plan" and res["ok"] and res["plan"]["arm"] and pages.frames == [b"ghost"], res
    assert client.executed == [] and control.preview is not None and control.target == [0.7, 0.03, 0.9]
    req = client.requests[-1].args
    assert req.target == [0.7, 0.03, 0.9] and req.arm == "left" and not req.execute
    state["joints"] = JOINTS + 0.05           # the robot moved since: plan again
    control.handle(1, {"op": "execute"})
    assert "moved 0.050 rad since the plan" in pages.of("error", 1)[-1]["text"]
    state["joints"] = JOINTS
    control.handle(1, {"op": "execute"})
    finish(control)
    res = pages.of("result")[-1]
    assert res["op"] == "execute" and res["ok"] and len(client.executed) == 1, res
    assert client.executed[0][0] is TRAJECTORY_OF(plan_response())
    assert [m["fraction"] for m in pages.of("progress")] == [0.0, 0.5, 1.0]
    assert control.preview is None and pages.of("ghost_clear")
    control.handle(1, {"op": "execute"})     # executed: no plan left
    assert "no plan to execute" in pages.of("error", 1)[-1]["text"]


def TRAJECTORY_OF(resp):   # noqa: N802 - the one trajectory every fake response carries
    return resp.trajectory


def test_failures_are_reported_with_their_code_and_the_console_goes_on() -> None:
    from humanoid_reach_ros.codes import PlanError
    client = FakeClient(plans=[plan_response(PlanError.NO_PATH, message="no path"), None, RuntimeError("boom")])
    control, pages, _ = control_with(client)
    control.handle(1, {"op": "take"})
    for expected in ("plan failed: NO_PATH", "the planner did not answer", "RuntimeError: boom"):
        control.handle(1, {"op": "plan", "target": [0.7, 0.03, 0.9]})
        finish(control)
        res = pages.of("result")[-1]
        assert not res["ok"] and expected in res["text"], res
    assert control.state()["last_error"]["name"] == "INTERNAL_ERROR"
    # the scan and a look at a point: the look's points shown, its result reported
    control.handle(1, {"op": "look", "point": [0.7, 0.03, 0.9]})
    finish(control)
    assert pages.of("looked")[-1]["points"] == [[0.7, 0.03, 0.9]] and pages.of("result")[-1]["ok"]
    assert client.looks[-1][3].tolist() == [[0.7, 0.03, 0.9]]
    # the CLI's own lines reach the page
    assert "look: looked [1.5 s, max COG drift 0.10 mm]" in [m["text"] for m in pages.of("log")]
    control.handle(1, {"op": "scan"})
    finish(control)
    assert pages.of("result")[-1]["op"] == "scan" and pages.of("result")[-1]["ok"]


def test_cancel_interrupts_the_running_action() -> None:
    class Slow(FakeClient):
        interrupted = False

        def plan(self, req):
            wait_for(lambda: self.interrupted, 10.0, "the cancel")
            from humanoid_reach_ros.operator.session import Canceled
            raise Canceled()
    client = Slow()
    control, pages, _ = control_with(client)
    control.handle(1, {"op": "take"})
    control.handle(1, {"op": "plan", "target": [0.7, 0.03, 0.9]})
    wait_for(lambda: control.busy == "plan", 5.0, "planning")
    control.handle(1, {"op": "scan"})
    assert "scan: busy with plan (Cancel stops it)" in pages.of("error", 1)[-1]["text"]
    control.handle(1, {"op": "cancel"})
    finish(control)
    res = pages.of("result")[-1]
    assert not res["ok"] and "canceled" in res["text"], res


# ---------------------------------------------------------------- the server's answers
def test_the_server_answers_bad_input_and_keeps_serving(tmp_path: Path) -> None:
    import aiohttp
    model = RobotModel()
    view = RobotView(model, load_collision_model(None, model))
    feed = ConsoleFeed(VoxelLayer("occupied", 0.02), VoxelLayer("unobserved", 0.02))
    feed.joints = lambda: model.half_sitting_joints
    feed.set_layer("occupied", np.array([[0.71, 0.03, 0.9]]))
    pages = Pages()
    control = ConsoleControl(FakeClient(), lambda a: a, feed.current_joints, feed.map_distance,
                             lambda t, s: (b"", {}), lambda m, to: server.emit(m, to), lambda f: None, 0.06)
    port = free_port()
    server = ConsoleServer(ConsoleConfig(port=port, update_period_s=0.05, map_period_s=0.05), feed, view, control,
                           log=lambda s: pages.messages.append(({"t": "log", "text": s}, None)))
    server.start()
    try:
        async def talk() -> dict:
            got: dict = {"text": [], "binary": []}
            async with aiohttp.ClientSession() as s:
                async with s.get(f"http://127.0.0.1:{port}/") as r:
                    got["index"] = r.status, "console.js" in await r.text()
                async with s.get(f"http://127.0.0.1:{port}/three/build/three.module.js") as r:
                    got["three"] = r.status
                async with s.get(f"http://127.0.0.1:{port}/static/../../../../etc/passwd") as r:
                    got["traversal"] = r.status
                async with s.ws_connect(f"http://127.0.0.1:{port}/ws") as ws:
                    await ws.send_str("{not json")
                    await ws.send_bytes(b"\x00\x01")
                    await ws.send_str(json.dumps({"op": "plan", "target": [0.7, 0.0, 0.9]}))
                    await ws.send_str(json.dumps({"op": "take"}))
                    await ws.send_str(json.dumps({"op": "plan", "target": [5.0, 5.0, 5.0]}))
                    deadline = time.monotonic() + 20.0
                    while time.monotonic() < deadline:
                        msg = await ws.receive(timeout=20.0)
                        if msg.type == aiohttp.WSMsgType.TEXT:
                            got["text"].append(json.loads(msg.data))
                        elif msg.type == aiohttp.WSMsgType.BINARY:
                            got["binary"].append(unpack(msg.data)[0]["t"])
                        errors = [m for m in got["text"] if m["t"] == "error"]
                        if len(errors) >= 4 and any(m["t"] == "status" and m["holder"] for m in got["text"]):
                            break
                async with s.ws_connect(f"http://127.0.0.1:{port}/ws") as ws:   # too large: closed, server on
                    await ws.send_str("x" * 10000)
                    kinds = []
                    while len(kinds) < 100 and (not kinds or kinds[-1] in (aiohttp.WSMsgType.TEXT,
                                                                           aiohttp.WSMsgType.BINARY)):
                        kinds.append((await ws.receive(timeout=10.0)).type)
                    got["large"] = kinds[-1]
                async with s.ws_connect(f"http://127.0.0.1:{port}/ws") as ws:
                    got["after"] = json.loads((await ws.receive(timeout=10.0)).data)["t"]
            return got
        got = asyncio.run(talk())
    finally:
        server.stop()
    assert got["index"] == (200, True) and got["three"] == 200 and got["traversal"] in (403, 404)
    errors = [m["text"] for m in got["text"] if m["t"] == "error"]
    assert any(e.startswith("not JSON") for e in errors) and "requests are JSON text" in errors, errors
    assert any("nobody holds them" in e for e in errors) and any("not on the map" in e for e in errors), errors
    assert got["text"][0]["t"] == "hello" and {"voxels", "robot"} <= set(got["binary"]), got["binary"]
    assert got["large"] in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED, aiohttp.WSMsgType.CLOSING,
                            aiohttp.WSMsgType.ERROR)
    assert got["after"] == "hello"
    assert not threading.active_count() > 50


def test_a_port_in_use_is_said(tmp_path: Path) -> None:
    import socket
    model = RobotModel()
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        feed = ConsoleFeed(VoxelLayer("occupied", 0.02), VoxelLayer("unobserved", 0.02))
        server = ConsoleServer(ConsoleConfig(port=port), feed, RobotView(model, load_collision_model(None, model)),
                               None, log=lambda s: None)
        with pytest.raises(OSError, match=f"cannot serve on 127.0.0.1:{port}"):
            server.start()


# ---------------------------------------------------------------- the browser against a launched graph
@pytest.mark.node
def test_the_console_in_a_browser_plans_executes_and_goes_home(ros_env, ros_probe, tmp_path: Path) -> None:
    """Short form (<= 60 s here): one graph, one browser, two pages."""
    from sensor_msgs.msg import JointState

    from humanoid_reach_ros.io import msgs
    from humanoid_reach_ros.testing.console_page import Browser, canvas_variance, start_graph

    t0 = time.monotonic()
    port = free_port()
    # the short form: a scan of two head poses down at the valve (five clouds each), then the scan's gazes
    # around the body (without them the plan needs three automatic looks there); bench/console.py scans all
    # ten poses. A planning budget for a loaded machine
    graph = start_graph(tmp_path, dict(ros_env), port, {"scan_dwell_s": 0.5, "plan_budget_s": 10.0},
                        node_params={"reach_executor": {"scan_poses_deg": SHORT_SCAN_DEG}})
    phases: dict[str, float] = {}

    def phase(name: str) -> None:
        phases[name] = round(time.monotonic() - t0 - sum(phases.values()), 1)
    browser = None
    try:
        procs = {p.name: p for p in graph.procs}
        for name, line in (("operator_console", "operator console ready"), ("reach_planner", "reach planner ready"),
                           ("reach_executor", "reach executor ready")):
            procs[name].wait_for_log(line, 180.0)
        states = ros_probe.collect(JointState, "/joint_states")
        model = RobotModel()
        phase("graph up")

        def joints() -> np.ndarray:
            ros_probe.spin_until(lambda: states.last is not None, 30.0, "/joint_states")
            j, why = msgs.model_joints(states.last, model)
            assert j is not None, why
            return j

        browser = Browser()
        url = f"http://127.0.0.1:{port}/"
        page = browser.page(url)
        viewer = browser.page(url, 800, 600)

        def counts(p=page) -> dict:
            return p.evaluate("window.hr.counts")

        wait_for(lambda: (c := counts())["occupied"] > 200 and c["robotFrames"] and c["images"], 60.0,
                 "the page to show the map, the robot and the camera",
                 on_timeout=lambda: f"{counts()} {browser.console}")
        wait_for(lambda: canvas_variance(page) > 100.0, 20.0, "a drawn 3D view (pixel variance)")
        phase("pages drawn")

        # one operator at a time: the first page takes the controls, the second stays view-only
        page.click("#take")
        wait_for(lambda: page.evaluate("hr.holder === hr.page"), 20.0, "the controls taken")
        wait_for(lambda: viewer.evaluate("hr.holder !== null && hr.holder !== hr.page"), 20.0, "the viewer told")
        assert viewer.is_disabled("#take") and viewer.is_disabled("#scan")
        viewer.evaluate("hr.send({op: 'take'})")
        wait_for(lambda: viewer.evaluate("hr.errors.length"), 20.0, "the viewer's take refused")
        assert "another page holds the controls" in viewer.evaluate("hr.errors[0].text")

        # a click on nothing and a malformed request: answered, the page goes on
        page.mouse.click(640, 20)   # the sky above the scene
        assert "no map voxel under the cursor" in page.inner_text("#result")
        page.evaluate("hr.send({op: 'plan', target: [NaN, 0, 1]})")
        wait_for(lambda: page.evaluate("hr.errors.length"), 20.0, "the bad target refused")
        assert "three finite numbers" in page.evaluate("hr.errors[0].text")

        # Scan: the head sees the valve and its marker (at half-sitting it looks over them)
        page.click("#scan")
        wait_for(lambda: any(r["op"] == "scan" for r in page.evaluate("hr.results")), 120.0, "the scan's result",
                 on_timeout=lambda: page.inner_text("#log"))
        scan = page.evaluate("hr.results")[-1]
        assert scan["ok"] and scan["look"]["poses_done"] >= len(SHORT_SCAN_DEG) // 2, scan
        assert counts()["markerImages"] > 0, counts()      # the marker outlined in the images it was in
        phase("scan")

        # click near the valve: the target is a map point there
        at = page.evaluate(f"hr.project({VALVE[0]}, {VALVE[1]}, {VALVE[2]})")
        page.mouse.click(at["x"], at["y"])
        picked = page.evaluate("hr.picked")
        assert picked is not None and np.linalg.norm(np.subtract(picked, VALVE)) < 0.08, picked
        print(f"\npicked {picked} (the valve centre {VALVE})")

        # Plan: a ghost and statistics, and the robot stays where it is
        before = joints()
        page.click("#plan")
        results = lambda: page.evaluate("hr.results")   # noqa: E731
        wait_for(lambda: any(r["op"] == "plan" for r in results()), 120.0, "the plan's result",
                 on_timeout=lambda: page.inner_text("#log"))
        plan = [r for r in results() if r["op"] == "plan"][-1]
        assert plan["ok"], f"{plan['text']}\nlog:\n{page.inner_text('#log')}"   # whole, not truncated
        assert counts()["ghostFrames"] >= 2 and "goals" in page.inner_text("#stats")
        assert float(np.max(np.abs(joints() - before))) < 1e-3, "planning moved the robot"
        assert viewer.evaluate("hr.counts.ghostFrames") >= 2       # the viewer sees the preview too
        phase("plan")

        # Execute that preview: the hand ends at the clicked target (from /joint_states)
        wait_for(lambda: not page.is_disabled("#execute"), 20.0, "Execute enabled")
        page.click("#execute")
        wait_for(lambda: any(r["op"] == "execute" for r in results()), 90.0, "the execution's result",
                 on_timeout=lambda: page.inner_text("#log"))
        ex = [r for r in results() if r["op"] == "execute"][-1]
        assert ex["ok"], f"{ex['text']}\nlog:\n{page.inner_text('#log')}"   # whole, not truncated
        frame = model.hand_frames[plan["plan"]["arm"]]

        def hand_error() -> float:
            j = joints()
            return float(np.linalg.norm(model.frame_pose(model.config(j, model.base_on_feet(j)), frame).translation
                                        - np.asarray(picked)))
        ros_probe.spin_until(lambda: hand_error() < 0.03, 20.0, "the hand at the target",
                             on_timeout=lambda: f"{hand_error():.3f} m away")
        phase("execute")

        # Home
        wait_for(lambda: not page.is_disabled("#home"), 20.0, "Home enabled")
        page.click("#home")
        wait_for(lambda: any(r["op"] == "home" for r in results()), 120.0, "home's result",
                 on_timeout=lambda: page.inner_text("#log"))
        home = [r for r in results() if r["op"] == "home"][-1]
        assert home["ok"], f"{home['text']}\nlog:\n{page.inner_text('#log')}"   # whole, not truncated
        ros_probe.spin_until(lambda: float(np.max(np.abs(joints() - model.half_sitting_joints))) < 0.02, 30.0,
                             "the joints at half-sitting")
        assert not [c for c in browser.console if c.startswith("pageerror")], browser.console
        phase("home")
        print(f"\nconsole test: {time.monotonic() - t0:.1f} s wall; phases [s]: {phases}")
    finally:
        if browser is not None:
            browser.close()
        codes = graph.stop()
    assert all(c == 0 for c in codes.values()), codes


def test_the_parameter_file_matches_the_declared_defaults() -> None:
    import yaml

    from humanoid_reach_ros.nodes.operator_console import PARAMETERS
    from nodetools import REPO_ROOT
    values = yaml.safe_load((REPO_ROOT / "config" / "operator_console.yaml").read_text())["/**"]["ros__parameters"]
    assert values == {k: spec.default for k, spec in PARAMETERS.items()}


@pytest.mark.node
def test_a_bad_parameter_stops_the_node_with_one_line(start_node) -> None:
    proc = start_node("operator_console", params_file="config/operator_console.yaml",
                      params={"marker_dictionary": "DICT_NOPE", "port": free_port()})
    wait_for(lambda: not proc.alive(), 60.0, "operator_console to stop", on_timeout=proc.log_tail)
    assert proc.proc.returncode == 2 and "cannot start: ValueError: marker_dictionary: unknown ArUco dictionary " \
        "'DICT_NOPE'" in proc.log(), proc.log_tail()
    proc.ok_exit_codes = (2,)
