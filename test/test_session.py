"""A session of reaches from the command line (issue 21): the operator's whole sequence against
the graph as ``ros2 run`` starts it (the six nodes, each with its parameter file; plant scene):

    reach_operator --scan
    reach_operator --marker --execute                 # the hand ends at the valve, on its rim
    reach_operator --target 0.35 -0.15 0.78 --execute # starts at the valve: a retreat first;
                                                      # ends resting on the passage pipe's top
    reach_operator --target 0.50 0.20 1.08 --execute  # starts on the pipe: a retreat first
    reach_operator --home --execute                   # back to half-sitting

each a separate process (``--json``). Every step succeeds; the two that start with the hand on
something plan a retreat first (the planner's message: "first a retreat ..."); no execution or
look is refused (INVALID_GOAL); at the end the measured joints are at half-sitting.
bench/session.py runs the same sequence on more scenes, with more sessions, and measures it.
"""
from __future__ import annotations

import time

import numpy as np
import pytest
from sensor_msgs.msg import JointState

from humanoid_reach_ros.demo import SIM_JOINT_STATES_ABORT_S, SIM_JOINT_STATES_TIMEOUT_S
from humanoid_reach_ros.io import msgs
from humanoid_reach_ros.robot.model import RobotModel
from test_operator_flow import NODES, operator

pytestmark = pytest.mark.node

TOUCH = ("0.35", "-0.15", "0.78")    # 1 cm above the passage pipe's top (axis x 0.35, z 0.72, radius 0.05)
UNDER_PIPE = ("0.50", "0.20", "1.08")   # under the left shoulder pipe (bench/graph.py's target)
HOME_TOL_RAD = 0.01   # measured joints at half-sitting within this (the legs keep the exact COG: up to 7 mrad off)


def refused(out: dict) -> list[str]:
    """Every refused execution or look of one reach_operator summary."""
    results = [out.get("execution"), out.get("look"), *(out.get("auto_looks") or [])]
    return [f"{r.get('error_name')}: {r.get('message')}" for r in results
            if r and (r.get("error_name") == "INVALID_GOAL" or r.get("outcome") == "rejected")]


def test_a_session_of_reaches_ends_at_half_sitting(start_node, ros_env, ros_probe) -> None:
    t0 = time.monotonic()
    procs = []
    for name, _ in NODES:
        params = {}
        if name in ("reach_planner", "reach_executor"):
            # a shared 2-core machine can starve a node of /joint_states for a second (as in the demo)
            params["joint_states_timeout_s"] = SIM_JOINT_STATES_TIMEOUT_S
        if name == "reach_executor":
            params["joint_states_abort_s"] = SIM_JOINT_STATES_ABORT_S
        procs.append(start_node(name, params_file=f"config/{name}.yaml", params=params))
    for proc, (_, ready) in zip(procs, NODES):
        proc.wait_for_log(ready, 180.0)
    states = ros_probe.collect(JointState, "/joint_states")
    steps: list[tuple[str, dict]] = []

    def step(label: str, *args: str) -> dict:
        code, out, err = operator(ros_env, *args)
        steps.append((label, out))
        assert code == 0 and out.get("exit_code") == 0, f"{label}: exit {code}\n{out}\n{err[-3000:]}"
        assert not refused(out), (label, refused(out))
        if "--execute" in args:
            ex = out["execution"]
            assert ex["success"] and ex["error_name"] == "SUCCESS", (label, ex, err[-2000:])
        print(f"{label}: {(out.get('plan') or {}).get('message') or out['look']['message']}")
        return out

    out = step("scan", "--scan")
    assert out["look"]["success"] and out["look"]["poses_done"] >= 5, out["look"]

    out = step("marker", "--marker", "--execute", "--budget", "10")
    assert out["execution"]["final_hand_error_m"] < 2e-3, out["execution"]

    # the hand rests at the valve: the next plan leaves it first
    out = step("touch", "--target", *TOUCH, "--execute", "--budget", "10")
    assert "first a retreat" in out["plan"]["message"], out["plan"]["message"]

    # ... and now on the passage pipe: again a retreat first
    out = step("under the shoulder pipe", "--target", *UNDER_PIPE, "--execute", "--budget", "10")
    assert "first a retreat" in out["plan"]["message"], out["plan"]["message"]

    out = step("home", "--home", "--execute", "--budget", "10")
    assert "way home" in out["plan"]["message"], out["plan"]["message"]

    # the measured joints settle at half-sitting
    robot = RobotModel()

    def error_rad() -> float:
        j, why = msgs.model_joints(states.last, robot)
        assert j is not None, why
        return float(np.max(np.abs(j - robot.half_sitting_joints)))

    def at_home() -> bool:
        return states.last is not None and error_rad() < HOME_TOL_RAD
    ros_probe.spin_until(at_home, 30.0, f"the measured joints within {HOME_TOL_RAD} rad of half-sitting",
                         on_timeout=lambda: f"max joint error {error_rad():.4f} rad")
    print(f"home: max joint error {error_rad() * 1e3:.2f} mrad; session {time.monotonic() - t0:.0f} s")
    assert all(p.alive() for p in procs)
