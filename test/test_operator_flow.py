"""The operator's whole flow from the command line against the graph as ``ros2 run`` starts
it (issue: the operator's flow): each of the six nodes a process with its own parameter file,
then exactly

    reach_operator --scan
    reach_operator --marker --execute

as separate processes, and at the end Ctrl-C stops every node with exit code 0 within
``STOP_DEADLINE_S`` (3 s). The head scan goes through the executor's ``/look`` action (feet and
COG held), the map and the marker come from the head sensors, the valve is reached. On the
way, bad head requests are refused with a reason and nothing stops (a pose outside the
head's limits from the command line; mismatched pose lists through the action), and a
target given before the scan is refused as ``UNOBSERVED_SPACE`` (the head has not seen it).
At the end ``/look`` takes gaze points (the balanced whole-body gaze): bad ones are refused,
good ones looked at, one beyond the camera's range reported as not in view.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys

import pytest
from geometry_msgs.msg import Point
from humanoid_reach_interfaces.action import Look
from rclpy.action import ActionClient

from humanoid_reach_ros.demo import SIM_JOINT_STATES_ABORT_S, SIM_JOINT_STATES_TIMEOUT_S
from humanoid_reach_ros.graph import STOP_DEADLINE_S
from humanoid_reach_ros.io import exec_msgs
from nodetools import REPO_ROOT

pytestmark = pytest.mark.node

NODES = [  # (node, ready log line)
    ("joint_driver", r"simulated hrp2"),
    ("scene_sim", r"scene sensors ready"),
    ("voxel_mapper", r"voxel mapper ready"),
    ("marker_localizer", r"marker localizer ready"),
    ("reach_planner", r"reach planner ready"),
    ("reach_executor", r"reach executor ready"),
]


def operator(env, *args: str, timeout: float = 300.0) -> tuple[int, dict, str]:
    proc = subprocess.run([sys.executable, "-m", "humanoid_reach_ros.nodes.reach_operator", *args, "--json"],
                          cwd=REPO_ROOT, env=dict(env), capture_output=True, text=True, timeout=timeout)
    lines = proc.stdout.strip().splitlines()
    return proc.returncode, (json.loads(lines[-1]) if lines else {}), proc.stderr


def look_result(ros_probe, client: ActionClient, goal: Look.Goal, timeout: float = 60.0) -> Look.Result:
    """Send a /look goal and wait for its result."""
    sent = client.send_goal_async(goal)
    ros_probe.spin_until(sent.done, 30.0, "the /look goal response")
    result = sent.result().get_result_async()
    ros_probe.spin_until(result.done, timeout, "the /look result")
    return result.result().result


def test_scan_then_reach_the_marker_from_the_command_line(start_node, ros_env, ros_probe) -> None:
    procs = []
    for name, _ready in NODES:
        params = {}
        if name in ("reach_planner", "reach_executor"):
            # a shared 2-core machine can starve a node of /joint_states for a second (as in the demo)
            params["joint_states_timeout_s"] = SIM_JOINT_STATES_TIMEOUT_S
        if name == "reach_executor":
            params["joint_states_abort_s"] = SIM_JOINT_STATES_ABORT_S
        procs.append(start_node(name, params_file=f"config/{name}.yaml", params=params))
    for proc, (_, ready) in zip(procs, NODES):
        proc.wait_for_log(ready, 180.0)

    # bad head requests: a reason, and the graph keeps running
    code, out, err = operator(ros_env, "--look", "0", "200")
    assert code == 7 and out["look"]["error_name"] == "INVALID_GOAL" and "HEAD_JOINT1" in err, (code, out, err)
    client = ActionClient(ros_probe.node, Look, "/look")
    ros_probe.spin_until(client.server_is_ready, 30.0, "/look")
    sent = client.send_goal_async(Look.Goal(yaw_rad=[0.1, 0.2], pitch_rad=[0.3]))
    ros_probe.spin_until(sent.done, 30.0, "the /look goal response")
    result = sent.result().get_result_async()
    ros_probe.spin_until(result.done, 30.0, "the /look result")
    res = result.result().result
    assert res.error_code == Look.Result.INVALID_GOAL and "one pitch per yaw" in res.message, res.message

    # before any scan the valve's space is unobserved: the planner says so instead of planning through it
    # (--no-auto-look: the operator would otherwise look there by itself and plan again)
    code, out, err = operator(ros_env, "--target", "0.71", "0.03", "0.90", "--no-auto-look")
    assert code == 6 and out["plan"]["error_name"] == "UNOBSERVED_SPACE" and "scan (--scan)" in err, (code, out, err)

    # the operator's flow, as the README gives it
    code, out, err = operator(ros_env, "--scan")
    assert code == 0, (out, err)
    look = out["look"]
    assert look["success"] and look["poses_done"] >= 5 and look["max_com_error_m"] < 1e-3, look
    assert out["plan"] is None and out["execution"] is None
    code, out, err = operator(ros_env, "--marker", "--execute", "--budget", "10")
    assert code == 0, (out, err)
    assert out["plan"]["success"] and out["plan"]["statistics"]["map_voxels"] > 1000, out["plan"]
    ex = out["execution"]
    assert ex["success"] and ex["min_distance_m"] >= 0.0 and ex["final_hand_error_m"] < 1e-3, ex

    # /look at gaze points (the balanced whole-body gaze, hand held at the valve): a NaN point and a goal
    # giving both points and angles are refused, nothing stops; the valve and a point beyond the camera's
    # range are looked at, the latter reported as not in view
    for goal, words in ((Look.Goal(gaze_points=[Point(x=math.nan, z=1.0)]), "gaze point 0 has NaN/inf"),
                        (Look.Goal(yaw_rad=[0.1], pitch_rad=[0.2], gaze_points=[Point(x=0.7, z=0.9)]), "not both")):
        res = look_result(ros_probe, client, goal)
        assert res.error_code == Look.Result.INVALID_GOAL and words in res.message, res.message
    res = look_result(ros_probe, client, exec_msgs.look_goal_at([[0.71, 0.03, 0.90], [6.0, 0.0, 1.3]], dwell_s=0.2))
    print(f"gaze: {res.message} [{res.duration_s:.1f} s, max COG error {res.max_com_error_m * 1e3:.3f} mm]")
    assert res.success and res.poses_done == 2 and res.max_com_error_m < 1e-3, res.message
    assert "point 1 [6.0, 0.0, 1.3] not in view (" in res.message and "point 0" not in res.message, res.message
    assert all(p.alive() for p in procs)

    # Ctrl-C: every node exits 0 within STOP_DEADLINE_S (after a motion, with the executor holding)
    for p in reversed(procs):
        p.stop()
    stops = {p.name: (p.proc.returncode, round(p.stop_s, 2)) for p in procs}
    print(f"exit code and seconds to stop after SIGINT: {stops}")
    assert all(code == 0 and s <= STOP_DEADLINE_S for code, s in stops.values()), stops
