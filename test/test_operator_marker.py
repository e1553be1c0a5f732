"""``reach_operator --marker`` when the marker is out of view (issue 22, point 5).

``marker_localizer`` publishes ``/target_pose`` only while the marker is in the camera's view,
and the planner takes it only while it is recent (1 s). With no ``/target_pose`` within 2 s the
operator turns the head (``/look``) toward the marker's last known position (the localizer's
diagnostics, aimed from the current posture) or, with none known, to the executor's
``marker_look_deg`` (the README's ``--look 2 40``), then waits for a fresh pose with a countdown
before it gives up (exit 6). No planner runs here: after the marker part the operator waits for
``/plan_reach`` (``--timeout 5``) and exits 3, which isolates what is tested.
"""
from __future__ import annotations

import json
import re
import subprocess
import sys

import pytest

from nodetools import REPO_ROOT

pytestmark = pytest.mark.node

MODULE = "humanoid_reach_ros.nodes.reach_operator"
VALVE = (0.71, 0.03, 0.90)
# a localizer that looks for marker 5, which the plant does not have: no /target_pose ever
NO_SUCH_MARKER = {"marker_ids": [5], "marker_sizes_m": [0.1], "target_marker_id": 5,
                  "marker_object_poses": [0.0, 0.0, 0.04, -0.5, 0.5, 0.5, 0.5]}


def operator(env, *args: str) -> tuple[int, dict, str]:
    r = subprocess.run([sys.executable, "-m", MODULE, *args, "--json"], cwd=REPO_ROOT, env=dict(env),
                       capture_output=True, text=True, timeout=180)
    lines = r.stdout.strip().splitlines()
    return r.returncode, (json.loads(lines[-1]) if lines else {}), r.stderr


def test_marker_out_of_view_the_head_turns_to_find_it(start_node, ros_env) -> None:
    # the four start together (each waits for its own inputs), then each is awaited
    nodes = [(start_node("joint_driver", params_file="config/joint_driver.yaml"), r"simulated hrp2"),
             (start_node("scene_sim", params_file="config/scene_sim.yaml"), r"scene sensors ready"),
             (start_node("marker_localizer", params_file="config/marker_localizer.yaml", params=NO_SUCH_MARKER),
              r"marker localizer ready"),
             (start_node("reach_executor", params_file="config/reach_executor.yaml"), r"reach executor ready")]
    for proc, ready in nodes:
        proc.wait_for_log(ready, 180.0)
    blind = nodes[2][0]

    # the marker never comes: the executor's marker look, a countdown, then the operator gives up (6)
    code, out, err = operator(ros_env, "--marker", "--timeout", "5", "--marker-wait", "6")
    assert code == 6 and out["marker"] == {"fresh": False, "looked_deg": [2.0, 40.0], "toward": None}, (out, err)
    left = [int(s) for s in re.findall(r"waiting for /target_pose \(marker_localizer\) \.\.\. (\d+) s left", err)]
    assert len(left) >= 2 and left == sorted(left, reverse=True), err
    assert "no /target_pose within 6 s after turning the head" in err and out["plan"] is None, err

    # a localizer that has never seen the marker, the head turned away: the executor's marker look finds it
    blind.stop()
    code, out, err = operator(ros_env, "--look", "40", "0")
    assert code == 0, err
    start_node("marker_localizer", params_file="config/marker_localizer.yaml", ready_log=r"marker localizer ready",
               timeout=60.0)
    code, out, err = operator(ros_env, "--marker", "--timeout", "5")
    assert out["marker"] == {"fresh": True, "looked_deg": [2.0, 40.0], "toward": None}, (out, err)
    assert "where the executor looks for it (marker_look_deg; no marker position known): yaw 2, pitch 40 deg" in err
    assert "marker seen at" in err
    assert code == 3 and "/plan_reach not available" in err, (code, err)   # no planner in this graph

    # seen once, then out of view: toward its last known position, aimed from the current posture
    code, out, err = operator(ros_env, "--look", "40", "0")
    assert code == 0, err
    code, out, err = operator(ros_env, "--marker", "--timeout", "5")
    m = out["marker"]
    assert m["fresh"] and m["toward"] is not None and "toward the marker's last known position" in err, \
        f"{out}\nstderr:\n{err}"   # whole, not cut
    assert max(abs(a - b) for a, b in zip(m["toward"], VALVE)) < 0.02, m
    assert abs(m["looked_deg"][0] - 2.0) <= 2.0 and abs(m["looked_deg"][1] - 40.0) <= 2.0, m   # half-sitting's aim
    assert code == 3, (code, err)

    # in view: nothing to do
    code, out, err = operator(ros_env, "--marker", "--timeout", "5")
    assert out["marker"] == {"fresh": True, "looked_deg": None, "toward": None} and "turning the head" not in err
