"""reach_operator CLI: argument handling, messages and progress as units; planning (and,
when the reach_executor node is present, execution and Ctrl-C cancel) against real nodes."""
from __future__ import annotations

import io
import json
import math
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from humanoid_reach_interfaces.action import ExecuteReach
from humanoid_reach_interfaces.srv import PlanReach

from humanoid_reach_ros.codes import CODE_INFO, ErrorCode
from humanoid_reach_ros.io import msgs
from humanoid_reach_ros.nodes import reach_operator as op
from humanoid_reach_ros.planning.wgr import matrix_rpy, valve_region
from nodetools import REPO_ROOT, wait_for

MODULE = "humanoid_reach_ros.nodes.reach_operator"


# ---------------------------------------------------------------- units
def test_every_error_code_has_a_name_class_and_hint() -> None:
    """One numbering (msg/ErrorCode, codes.ErrorCode): every code has an exit class and a hint in
    codes.CODE_INFO, none of the operator's own where the server's message says what to do."""
    from humanoid_reach_interfaces.msg import ErrorCode as ErrorCodeMsg
    generated = {getattr(ErrorCodeMsg, n): n for n in dir(ErrorCodeMsg)
                 if n.isupper() and isinstance(getattr(ErrorCodeMsg, n), int)}
    assert {int(c): c.name for c in ErrorCode} == generated
    assert set(CODE_INFO) == set(ErrorCode)
    own_words = {ErrorCode.NO_GOAL_FOUND, ErrorCode.CANCELED, ErrorCode.START_IN_COLLISION, ErrorCode.UNOBSERVED_SPACE,
                 ErrorCode.UNOBSERVABLE_SPACE, ErrorCode.TARGET_OUT_OF_REACH}
    for code, (cls, hint) in CODE_INFO.items():
        assert cls in op.EXIT, code.name
        assert not hint or code not in own_words, (code.name, hint)
        text = op.code_text(code, "server says why")
        assert text.startswith(f"{code.name} ({int(code)}): server says why")
        assert (" -- " in text) == bool(hint and code != 0)
        assert (op.exit_class(code) == 0) == (code == 0)
    cancel = op.code_text(ErrorCode.CANCELED, "canceled by the client; holding the last command")
    assert cancel == "CANCELED (21): canceled by the client; holding the last command"
    # failure classes are told apart by the exit code
    assert op.exit_class(ErrorCode.INVALID_BOUNDS) == op.exit_class(ErrorCode.INVALID_REQUEST) == 4
    assert op.exit_class(ErrorCode.NO_PATH) == 5
    assert op.exit_class(ErrorCode.NO_TARGET) == op.exit_class(ErrorCode.NO_JOINT_STATES) == 6
    assert op.exit_class(ErrorCode.INTERNAL_ERROR) == 1
    assert op.exit_class(ErrorCode.ABORTED) == op.exit_class(ErrorCode.TARGET_NOT_REACHED) == 7
    assert op.exit_class(ErrorCode.CANCELED) == 130
    assert "UNKNOWN_CODE_42" in op.code_text(42, "") and op.exit_class(42) == 1


def test_progress_bar_and_printer() -> None:
    p = op.Progress(0.5, 1.234, 0.0521, 0.0003, 0.012)
    assert op.progress_bar(p, width=10) == ("[#####.....]  50%  t  1.23 s  min dist 52.1 mm  COG 0.3 mm  "
                                            "hand 12.0 mm")
    assert op.progress_bar(op.Progress(1.7, 0, 0, 0, 0), width=4).startswith("[####] 100%")
    assert op.progress_bar(op.Progress(-1.0, 0, math.inf, 0, 0), width=4).startswith("[....]   0%")
    assert "min dist -" in op.progress_bar(op.Progress(math.nan, 0, math.nan, 0, 0), width=4)
    fb = ExecuteReach.Feedback(progress=0.25, time_from_start_s=0.5, min_distance_m=0.1, com_error_m=0.0,
                               hand_error_m=0.002)
    assert op.Progress.from_feedback(fb) == op.Progress(0.25, 0.5, 0.1, 0.0, 0.002)

    out = io.StringIO()  # not a terminal: a line per 10 %
    printer = op.ProgressPrinter(out)
    for k in range(101):
        printer.update(op.Progress(k / 100, k / 100, 0.1, 0.0, 0.0))
    printer.close()
    lines = out.getvalue().splitlines()
    assert [line.split("]")[1].split("%")[0].strip() for line in lines] == [str(10 * i) for i in range(11)]

    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    tty = Tty()
    printer = op.ProgressPrinter(tty)
    for k in range(5):
        printer.update(op.Progress(k / 4, 0, 0, 0, 0))
    printer.close()
    assert tty.getvalue().count("\r") == 5 and tty.getvalue().endswith("\n") and tty.getvalue().count("\n") == 1


@pytest.mark.parametrize("argv, message", [
    (["--rpy", "0", "0", "1"], "--rpy/--rpy-deg and --frame need --target"),
    (["--rpy-deg", "0", "0", "90"], "--rpy/--rpy-deg and --frame need --target"),
    (["--frame", "base_link"], "--rpy/--rpy-deg and --frame need --target"),
    (["--target", "1", "2", "3", "--rpy", "0", "0", "1", "--rpy-deg", "0", "0", "1"], "not allowed with argument"),
    (["--wgr", *["0"] * 12, "--wgr-deg", *["0"] * 12], "not allowed with argument"),
    (["--wgr-deg", *["0"] * 11], "expected 12 arguments"),
    (["--wgr-deg", "0", "0", "0", "-90", "-90", "-181", "0", "0", "0", "90", "90", "180"],
     "--wgr-deg: lower yaw -181 deg lies outside [-180, 180]"),
    (["--wgr-deg", "0", "0", "0", "-90", "-90", "-180", "0", "0", "0", "90", "inf", "180"], "not a finite number"),
    (["--target", "1", "2", "nan"], "'nan' is not a finite number"),
    (["--target", "1", "2"], "expected 3 arguments"),
    (["--target", "1", "2", "3", "--marker"], "not allowed with argument"),
    (["--wgr", "0", "0", "0"], "expected 12 arguments"),
    (["--arm", "both"], "invalid choice: 'both'"),
    (["--planner", "astar"], "invalid choice: 'astar'"),
    (["--goals", "0"], "must be in 1..4294967295"),
    (["--budget", "-1"], "must be > 0"),
    (["--seed", "x"], "'x' is not an integer"),
    (["--timeout", "0"], "must be > 0"),
    (["--no-com-compensation"], "need --execute"),
    (["--scan", "--look", "0", "20"], "not allowed with argument"),
    (["--look", "0"], "expected 2 arguments"),
    (["--look", "nan", "20"], "'nan' is not a finite number"),
    (["--dwell", "1"], "--dwell needs --scan or --look"),
    (["--scan", "--dwell", "0"], "must be > 0"),
    (["--marker", "--marker-wait", "0"], "must be > 0"),
    (["--target", "0.7", "0", "0.9", "--marker-wait", "5"], "--marker-wait needs --marker"),
    # no abbreviations on a command that moves a robot
    (["--target", "0.7", "0", "0.9", "--exec"], "unrecognized arguments: --exec"),
    (["--tar", "0.7", "0", "0.9"], "unrecognized arguments: --tar"),
])
def test_bad_arguments(argv, message, capsys) -> None:
    """One line of error and one pointing to --help on stderr (no usage block); with --json also the
    summary object as the only line on stdout."""
    with pytest.raises(SystemExit) as exc:
        op.parse_args(argv)
    assert exc.value.code == 2
    out, err = capsys.readouterr()
    lines = err.splitlines()
    assert len(lines) == 2 and message in lines[0] and lines[0].startswith("reach_operator: error: "), err
    assert lines[1] == "reach_operator: --help lists every flag" and out == ""
    with pytest.raises(SystemExit) as exc:
        op.parse_args([*argv, "--json"])
    assert exc.value.code == 2
    out, err = capsys.readouterr()
    summary = json.loads(out)
    assert out.count("\n") == 1 and summary["exit_code"] == 2 and message in summary["error"]
    assert summary["plan"] is None and len(err.splitlines()) == 2


def test_requests_from_the_command_line() -> None:
    req = op.plan_request(op.parse_args([]))
    assert req.use_marker_target and not req.execute and req.arm == 0 and req.seed == -1
    v = valve_region()
    np.testing.assert_array_equal(req.region.lower, v.lower)  # eq. 3
    np.testing.assert_array_equal(req.region.upper, v.upper)
    assert req.time_budget_s == 0.0 and req.goal_count == 0 and req.planner == ""

    req = op.plan_request(op.parse_args(["--target", "0.5", "-0.2", "1.0", "--rpy", "0.1", "-0.2", "0.3", "--frame",
                                         "base_link", "--arm", "left", "--planner", "prm", "--goals", "4",
                                         "--budget", "2.5", "--seed", "7", "--execute",
                                         "--wgr", *map(str, range(-6, 0)), *map(str, range(1, 7))]))
    assert not req.use_marker_target and not req.execute  # --execute goes through the action, not the planner
    assert req.region.target.header.frame_id == "base_link"
    pose = msgs.se3_from_pose(req.region.target)
    np.testing.assert_allclose(pose.translation, [0.5, -0.2, 1.0])
    np.testing.assert_allclose(matrix_rpy(pose.rotation), [0.1, -0.2, 0.3], atol=1e-12)
    assert (req.arm, req.planner, req.goal_count, req.time_budget_s, req.seed) == (2, "prm", 4, 2.5, 7)
    assert list(req.region.lower) == list(range(-6, 0)) and list(req.region.upper) == list(range(1, 7))


def test_head_flags_alone_move_the_head_only() -> None:
    """--scan / --look alone: the head only; with --marker, --target or --execute a plan follows."""
    assert not op.parse_args(["--scan"]).plan and not op.parse_args(["--look", "10", "-5", "--dwell", "2"]).plan
    assert op.parse_args(["--scan", "--marker"]).plan and op.parse_args(["--scan", "--execute"]).plan
    assert op.parse_args(["--look", "0", "25", "--target", "0.7", "0", "0.9"]).plan
    assert op.parse_args([]).plan


def test_degree_flags_give_the_same_request_as_radians() -> None:
    """--rpy-deg / --wgr-deg are the operator's units; the request carries radians."""
    deg = op.plan_request(op.parse_args(["--target", "0.5", "-0.2", "1.0", "--rpy-deg", "10", "-20", "30",
                                         "--wgr-deg", "0", "0", "-0.05", "-90", "-45", "-180",
                                         "0", "0", "0.05", "90", "45", "180"]))
    rad = op.plan_request(op.parse_args(["--target", "0.5", "-0.2", "1.0", "--rpy",
                                         *map(str, np.radians([10, -20, 30])), "--wgr", "0", "0", "-0.05",
                                         *map(str, np.radians([-90, -45, -180])), "0", "0", "0.05",
                                         *map(str, np.radians([90, 45, 180]))]))
    pose = msgs.se3_from_pose(deg.region.target)
    np.testing.assert_allclose(matrix_rpy(pose.rotation), np.radians([10, -20, 30]), atol=1e-12)
    np.testing.assert_allclose(list(deg.region.lower), [0, 0, -0.05, -math.pi / 2, -math.pi / 4, -math.pi])
    np.testing.assert_allclose(list(deg.region.upper), [0, 0, 0.05, math.pi / 2, math.pi / 4, math.pi])
    np.testing.assert_allclose(list(deg.region.lower), list(rad.region.lower), atol=1e-12)
    np.testing.assert_allclose(list(deg.region.upper), list(rad.region.upper), atol=1e-12)
    # the valve WGR of eq. 3 in degrees is exactly the default
    v = op.plan_request(op.parse_args(["--wgr-deg", "0", "0", "0", "-90", "-90", "-180", "0", "0", "0", "90", "90",
                                       "180"]))
    np.testing.assert_allclose(list(v.region.lower), valve_region().lower, atol=1e-15)
    np.testing.assert_allclose(list(v.region.upper), valve_region().upper, atol=1e-15)
    # a typed 180.05 deg (within the planner's tolerance) passes the CLI and is clamped by the planner
    near = op.parse_args(["--wgr-deg", *["0"] * 5, "-180.05", *["0"] * 5, "180.05"])
    assert near.wgr[5] == pytest.approx(-math.radians(180.05))
    assert msgs.reach_request(op.plan_request(near)).region.upper[5] == math.pi


def test_help_documents_the_degree_flags(capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        op.parse_args(["--help"])
    assert exc.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "--rpy-deg R P Y" in text and "--wgr-deg B B B" in text
    assert "roll pitch yaw in DEGREES" in text and "radians" in text


def test_execution_summary_handles_non_finite() -> None:
    r = ExecuteReach.Result(success=False, error_code=msgs.error_code(ErrorCode.ABORTED), message="stale",
                            duration_s=1.0, steps=3,
                            min_distance_m=math.inf)
    s = op.execution_summary("done", r)
    assert s["error_name"] == "ABORTED" and s["min_distance_m"] is None
    json.dumps(s, allow_nan=False)
    assert "min distance -" in op.execution_report(s)


# ---------------------------------------------------------------- real processes
def run_operator(args: list[str], env, timeout: float = 120.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", MODULE, *args], env=dict(env), cwd=REPO_ROOT,
                          capture_output=True, text=True, timeout=timeout)


def test_no_planner_is_unavailable(ros_env) -> None:
    r = run_operator(["--target", "0.71", "0.03", "0.9", "--timeout", "2"], ros_env)
    assert r.returncode == 3, (r.stdout, r.stderr)
    assert "/plan_reach not available after 2 s" in r.stderr


def test_waiting_for_a_server_is_visible_and_ctrl_c_ends_it(ros_env, tmp_path: Path) -> None:
    """Before the graph is up: a line on stderr after 2 s and every 5 s names what is awaited,
    with the seconds left; Ctrl-C ends the wait at once with 130 (issue 22, point 4)."""
    r = run_operator(["--scan", "--timeout", "7"], ros_env)
    assert r.returncode == 3, (r.stdout, r.stderr)
    notes = re.findall(r"waiting for /look \(reach_executor\) \.\.\. (\d+) s left", r.stderr)
    assert notes == ["5", "2"], r.stderr
    assert "/look not available after 7 s" in r.stderr and "scanning with the head" in r.stdout

    err = tmp_path / "operator.err"
    with open(err, "w") as e:
        proc = subprocess.Popen([sys.executable, "-m", MODULE, "--target", "0.71", "0.03", "0.9", "--json"],
                                env=dict(ros_env), cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=e, text=True)
    try:
        wait_for(lambda: "waiting for /plan_reach (reach_planner)" in err.read_text() or proc.poll() is not None,
                 30.0, "the waiting line", on_timeout=err.read_text)
        t0 = time.monotonic()
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=10.0)
        stop_s = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err.read_text()
    assert stop_s < 3.0 and json.loads(out)["exit_code"] == 130, (stop_s, out)


@pytest.mark.node
def test_plan_and_bad_requests_against_reach_planner(start_node, ros_env) -> None:
    started = [(start_node("joint_driver", params_file="config/joint_driver.yaml"), r"simulated hrp2"),
               (start_node("reach_planner", params_file="config/reach_planner.yaml"), r"reach planner ready")]
    for proc, ready in started:   # started together, awaited in turn
        proc.wait_for_log(ready, 60.0)

    def planned():  # the planner may not have /joint_states yet right after start
        r = run_operator(["--target", "0.71", "0.03", "0.90", "--budget", "20", "--seed", "1"], ros_env)
        return None if r.returncode == 6 and "NO_JOINT_STATES" in r.stderr else r

    r = wait_for(planned, 60.0, "a plan from reach_planner")
    assert r.returncode == 0, (r.stdout, r.stderr)
    assert "plan: " in r.stdout and " arm, " in r.stdout and "goal sampling" in r.stdout and "total" in r.stdout

    # bad bounds: the planner's code by name, with its message, exit class "invalid"
    r = run_operator(["--target", "0.71", "0.03", "0.90", "--json", "--wgr", "0.1", *["0"] * 11], ros_env)
    assert r.returncode == 4
    assert "plan failed: INVALID_BOUNDS (2): " in r.stderr and "lower > upper" in r.stderr
    summary = json.loads(r.stdout)
    assert summary["exit_code"] == 4 and summary["plan"]["error_name"] == "INVALID_BOUNDS"
    assert summary["plan"]["success"] is False and summary["execution"] is None

    # a target 1e308 m away: one short line, numbers in sane precision, the advice once
    r = run_operator(["--target", "1e308", "0", "1", "--json"], ros_env)
    failed = [line for line in r.stderr.splitlines() if line.startswith("plan failed")]
    assert r.returncode == 5 and len(failed) == 1, r.stderr
    assert "TARGET_OUT_OF_REACH (4)" in failed[0] and len(failed[0]) < 320 and not re.search(r"\d{8}", r.stderr)
    assert r.stderr.count("closer") == 1 and json.loads(r.stdout)["plan"]["error_name"] == "TARGET_OUT_OF_REACH"

    # the marker (default) without a /target_pose: an input is missing
    r = run_operator(["--json"], ros_env)
    assert r.returncode == 6 and "plan failed: NO_TARGET (9)" in r.stderr
    assert json.loads(r.stdout)["plan"]["error_name"] == "NO_TARGET"


@pytest.mark.node
def test_execute_with_progress_and_cancel(start_node, ros_env, tmp_path: Path) -> None:
    started = [(start_node("joint_driver", params_file="config/joint_driver.yaml"), r"simulated hrp2"),
               (start_node("reach_planner", params_file="config/reach_planner.yaml"), r"reach planner ready"),
               (start_node("reach_executor", params_file="config/reach_executor.yaml"), r"reach executor ready")]
    for proc, ready in started:   # started together, awaited in turn
        proc.wait_for_log(ready, 90.0)
    args = ["--target", "0.71", "0.03", "0.90", "--budget", "20", "--execute", "--json"]

    def executed():
        r = run_operator([*args, "--seed", "1"], ros_env)
        return None if "NO_JOINT_STATES" in r.stderr else r

    r = wait_for(executed, 90.0, "a plan executed")
    summary = json.loads(r.stdout)
    e = summary["execution"]
    assert summary["plan"]["success"] and e["outcome"] == "done" and e["steps"] > 0, r.stderr
    bars = [line for line in r.stderr.splitlines() if line.startswith("[") and "%" in line]
    assert bars and "execution: " in r.stderr
    if e["success"]:
        assert r.returncode == 0 == summary["exit_code"] and e["error_name"] == "SUCCESS", r.stderr
    else:  # the executor's verdict (e.g. ABORTED on an overloaded machine), reported by name and class
        assert r.returncode == op.exit_class(e["error_code"]) == summary["exit_code"] == 7
        assert f"execution failed: {e['error_name']} ({e['error_code']}): {e['message']}" in r.stderr
        print(f"\nNOTE: the executor did not succeed: {e['error_name']}: {e['message']}")
    print(f"\n{bars[-1]}\nexecution: {e}")

    # Ctrl-C while executing cancels the goal: CANCELED, exit 130
    log = tmp_path / "operator.err"
    with open(log, "w") as err, open(tmp_path / "operator.out", "w") as out:
        proc = subprocess.Popen([sys.executable, "-m", MODULE, *args, "--seed", "2"], env=dict(ros_env),
                                cwd=REPO_ROOT, stdout=out, stderr=err, text=True)
    try:
        wait_for(lambda: "%" in log.read_text() or proc.poll() is not None, 90.0, "execution progress",
                 on_timeout=log.read_text)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(30.0) == 130, log.read_text()
    finally:
        if proc.poll() is None:
            proc.kill()
    text = log.read_text()
    assert "Ctrl-C: canceling the goal" in text and "execution canceled: CANCELED (21)" in text
    summary = json.loads((tmp_path / "operator.out").read_text())
    assert summary["exit_code"] == 130 and summary["execution"]["error_name"] == "CANCELED"


class _SlowLookGraph:
    """An operator whose planner answers UNOBSERVED_SPACE and whose /look is discovered only
    ``look_after_s`` after the request (None: never); the real waiting code (``spin_until``,
    ``wait_for_server``, ``wait_for_look``) runs on it."""
    spin_until = op.Operator.spin_until
    wait_for_server = op.Operator.wait_for_server
    wait_for_look = op.Operator.wait_for_look

    def __init__(self, look_after_s: float | None, timeout_s: float) -> None:
        self.t0 = time.monotonic()
        self.look_after_s, self.timeout_s, self.interrupted = look_after_s, timeout_s, False
        self.err = io.StringIO()
        self.looks: list[np.ndarray] = []
        self.executor = type("Exec", (), {"spin_once": staticmethod(lambda timeout_sec: time.sleep(timeout_sec))})()
        self.look_client = type("Client", (), {"server_is_ready": lambda _: self.look_after_s is not None and (
            time.monotonic() - self.t0 >= self.look_after_s)})()

    def plan(self, req):
        resp = PlanReach.Response(error_code=msgs.error_code(ErrorCode.UNOBSERVED_SPACE))
        resp.unobserved_points = msgs.points_list(np.array([[0.25, -0.29, 0.66]])) if not self.looks else []
        if self.looks:
            resp.error_code.val = ErrorCode.SUCCESS
        return resp


def test_an_automatic_look_waits_for_a_slowly_discovered_look_server(monkeypatch) -> None:
    """An automatic look waits for /look like every server, up to --timeout, with the waiting
    lines on stderr (bench/session: a fresh CLI on a busy machine took over 3 s to discover the
    action; a 3 s guess then planned without looking). Without any /look it says so after
    --timeout and returns the planner's answer; --no-auto-look never waits."""
    # the look itself (the /look action's feedback and result) is tested against the real executor elsewhere
    monkeypatch.setattr(op.OperatorSession, "look", lambda session, gaze_points=None, come_back=False: (
        session.client.looks.append(gaze_points), op.EXIT["success"])[1])
    args = op.parse_args(["--target", "0.45", "-0.35", "0.50"])
    slow = _SlowLookGraph(look_after_s=4.0, timeout_s=20.0)
    text = io.StringIO()
    resp, code = op.OperatorSession(slow, args, text, slow.err, {}).plan_with_looks(PlanReach.Request())
    assert code == 0 and resp.error_code.val == ErrorCode.SUCCESS, slow.err.getvalue()
    assert len(slow.looks) == 1 and np.allclose(slow.looks[0], [[0.25, -0.29, 0.66]])
    assert "automatic look 1/3" in text.getvalue()
    assert "waiting for /look (reach_executor, for an automatic look; --no-auto-look skips it) ... 1" in (
        slow.err.getvalue()), slow.err.getvalue()

    never = _SlowLookGraph(look_after_s=None, timeout_s=2.5)
    resp, code = op.OperatorSession(never, args, io.StringIO(), never.err, {}).plan_with_looks(PlanReach.Request())
    assert code == 0 and resp.error_code.val == ErrorCode.UNOBSERVED_SPACE and not never.looks
    assert "/look not available after 2.5 s (is reach_executor running? --no-auto-look plans without looking): " \
           "no automatic look at [0.25, -0.29, 0.66]" in never.err.getvalue(), never.err.getvalue()

    t0 = time.monotonic()
    off = _SlowLookGraph(look_after_s=None, timeout_s=30.0)
    resp, code = op.OperatorSession(off, op.parse_args(["--target", "0.45", "-0.35", "0.50", "--no-auto-look"]),
                                    io.StringIO(), off.err, {}).plan_with_looks(PlanReach.Request())
    assert resp.error_code.val == ErrorCode.UNOBSERVED_SPACE and not off.looks and time.monotonic() - t0 < 5.0


def test_a_lost_goal_response_is_recovered_from_the_goal_status(ros_env) -> None:
    """A goal response lost on the way (the server's response writer had not matched this fresh
    client yet: "failed to send response (timeout): client will not receive response"; bench/session
    once ran a whole scan while the CLI waited for it and timed out): the goal's status says it
    was accepted, and the operator waits for its result instead of timing out."""
    import threading

    import rclpy
    from humanoid_reach_interfaces.action import Look
    from rclpy.action import ActionServer
    from rclpy.executors import SingleThreadedExecutor

    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("lossy_look_server", context=ctx)
    dropped: list = []

    def execute(goal_handle):
        goal_handle.succeed()
        return Look.Result(error_code=msgs.error_code(ErrorCode.SUCCESS), message="looked")
    server = ActionServer(node, Look, "/look", execute_callback=execute)

    class DropGoalResponses:   # the server's handle, but its goal responses are lost
        def __init__(self, handle) -> None:
            self._h = handle

        def __getattr__(self, name):
            return getattr(self._h, name)

        def __enter__(self):
            return self._h.__enter__()

        def __exit__(self, *exc):
            return self._h.__exit__(*exc)

        def send_goal_response(self, header, response) -> None:
            dropped.append(response.accepted)
    server._handle = DropGoalResponses(server._handle)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    spinning = threading.Thread(target=executor.spin, daemon=True)
    spinning.start()
    err = io.StringIO()
    operator = op.Operator(timeout_s=30.0, err=err)
    try:
        outcome, result = operator.look([0.1], [0.2], 0.0, lambda fb: None)
    finally:
        operator.close()
        executor.shutdown()
        server.destroy()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    assert dropped == [True], dropped
    assert outcome == "done" and result.message == "looked", (outcome, result, err.getvalue())
    assert "the goal's acceptance never arrived" in err.getvalue()
