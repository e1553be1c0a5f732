"""``hr_graph`` (``make up``): the whole graph kept running where ``ros2 launch`` is absent
(issue 22, point 1).

As installed (``install/.../lib/humanoid_reach_ros/hr_graph``), in the test's own isolated
graph (``ros_env``: its ``ROS_DOMAIN_ID``, localhost discovery): a line per node as it comes
up, ``ready``, then SIGINT (Ctrl-C) stops every node, exit 0, no child left. A node that exits
by itself is named with the last lines of its log, and the exit code is then 1. Bad options are
refused before anything starts.
"""
from __future__ import annotations

import os
import re
import signal
import subprocess
import time
from pathlib import Path

import pytest

from humanoid_reach_ros import graph_up
from humanoid_reach_ros.graph import GRAPH_NODES
from nodetools import REPO_ROOT, wait_for

HR_GRAPH = REPO_ROOT / "install" / "humanoid_reach_ros" / "lib" / "humanoid_reach_ros" / "hr_graph"
READY_DEADLINE_S = 300.0   # six nodes warming up on a loaded 2-core machine
STOP_DEADLINE_S = 60.0


def children(pid: int) -> list[int]:
    """Processes whose parent is ``pid`` (from /proc)."""
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                stat = (d / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                out.append(int(d.name))
    return out


def gone(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return True
    return state == "Z"   # a zombie is finished (its parent reaps it)


def start(args: list[str], env, tmp_path: Path) -> tuple[subprocess.Popen, Path]:
    out = tmp_path / "hr_graph.out"
    with open(out, "w") as f:
        proc = subprocess.Popen([str(HR_GRAPH), "--log-dir", str(tmp_path / "logs"), *args], env=dict(env),
                                cwd=REPO_ROOT, stdout=f, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
    return proc, out


def ctrl_c(proc: subprocess.Popen) -> tuple[int, float]:
    t0 = time.monotonic()
    proc.send_signal(signal.SIGINT)
    try:
        code = proc.wait(STOP_DEADLINE_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise
    return code, time.monotonic() - t0


@pytest.mark.node
def test_hr_graph_runs_the_graph_until_ctrl_c(ros_env, tmp_path: Path) -> None:
    proc, out = start([], ros_env, tmp_path)
    kids: list[int] = []
    try:
        wait_for(lambda: "] ready: " in out.read_text() or proc.poll() is not None, READY_DEADLINE_S,
                 "hr_graph to say ready", on_timeout=out.read_text)
        text = out.read_text()
        assert proc.poll() is None, text
        assert f"ROS_DOMAIN_ID={ros_env['ROS_DOMAIN_ID']}" in text
        up = re.findall(r"\[hr_graph\] (\w+) up \(", text)
        assert sorted(up) == sorted(GRAPH_NODES), text
        assert "/plan_reach" in text and "/look (action)" in text and "ready: 6 nodes up" in text, text
        assert "exited" not in text, text
        kids = children(proc.pid)
        assert len(kids) == len(GRAPH_NODES), (kids, text)
        code, stop_s = ctrl_c(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
            for k in kids:
                if not gone(k):
                    os.kill(k, signal.SIGKILL)
    text = out.read_text()
    print(f"\n{text}\nstopped in {stop_s:.1f} s")
    assert code == 0, text
    assert "SIGINT: stopping 6 nodes" in text and "stopped 6 nodes cleanly" in text, text
    wait_for(lambda: all(gone(k) for k in kids), 5.0, "every node process to be gone")


@pytest.mark.node
def test_hr_graph_names_a_node_that_exits(ros_env, tmp_path: Path) -> None:
    """A scene file the nodes cannot read: ``scene_sim`` (and whoever else reads it) exits; its
    name and the last lines of its log are printed, the rest keep running, Ctrl-C ends with 1."""
    bad = tmp_path / "bad_scene.yaml"
    bad.write_text("this: is not a scene\n")
    proc, out = start(["--scene", str(bad)], ros_env, tmp_path)
    try:
        wait_for(lambda: "scene_sim exited with code" in out.read_text() or proc.poll() is not None, 120.0,
                 "hr_graph to report scene_sim's exit", on_timeout=out.read_text)
        assert proc.poll() is None, out.read_text()
        wait_for(lambda: "joint_driver up" in out.read_text(), 120.0, "joint_driver up", on_timeout=out.read_text)
        code, _ = ctrl_c(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
    text = out.read_text()
    print(f"\n{text}")
    assert code == 1, text
    report = text.split("scene_sim exited with code", 1)[1]
    assert "the last lines of its log" in report and "  | " in report and "cannot start" in report, text


@pytest.mark.parametrize("argv, message", [
    (["--scene", "/nonexistent/scene.yaml"], "no such file"),
    (["--robot", "nao"], "invalid choice"),
    (["--no-sim"], "unrecognized arguments: --no-sim"),   # no abbreviations
    (["--host", "laptop"], "argument --host: invalid choice: 'laptop'"),
    (["--enclave", "robot"], "--enclave robot: an enclave is an absolute name"),
    (["--console-port", "9000"], "--console-port 9000: needs --console"),
    (["--console", "--console-port", "70000"], "a port in 1..65535"),
])
def test_bad_options_are_refused(argv: list[str], message: str, capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit) as exc:
        graph_up.parse_args(argv)
    assert exc.value.code == 2 and message in capsys.readouterr().err


def test_the_console_port_is_the_flag_or_the_parameter_file() -> None:
    assert graph_up.console_port(graph_up.parse_args(["--console", "--console-port", "9000"])) == 9000
    assert graph_up.console_port(graph_up.parse_args(["--console"])) == 8765   # config/operator_console.yaml


def test_a_count_of_nodes_is_said_in_words() -> None:
    """"1 node up", "6 nodes up" (hr_graph's and the demo's lines; --host compute starts one node)."""
    from humanoid_reach_ros.graph import nodes_text
    assert (nodes_text(0), nodes_text(1), nodes_text(6)) == ("0 nodes", "1 node", "6 nodes")


def test_the_nodes_environment_keeps_security_and_discovery_and_sets_the_enclave() -> None:
    """hr_graph's nodes get the shell's ROS_SECURITY_* untouched, its domain and discovery
    settings, and --enclave as rcl's ROS_SECURITY_ENCLAVE_OVERRIDE (reach.launch.py's enclave:=)."""
    shell = {"ROS_DOMAIN_ID": "42", "ROS_SECURITY_ENABLE": "true", "ROS_SECURITY_STRATEGY": "Enforce",
             "ROS_SECURITY_KEYSTORE": "/etc/keystore", "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET", "PATH": "/bin"}
    env = graph_up.nodes_env(graph_up.parse_args(["--enclave", "/humanoid/robot"]), shell)
    assert {k: env[k] for k in shell} == shell
    assert env["ROS_SECURITY_ENCLAVE_OVERRIDE"] == "/humanoid/robot"
    plain = graph_up.nodes_env(graph_up.parse_args([]), {"ROS_DOMAIN_ID": "7"})
    assert plain["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST" and "ROS_SECURITY_ENCLAVE_OVERRIDE" not in plain
