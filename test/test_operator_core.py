"""reach_operator's ROS-free core (``humanoid_reach_ros.operator``), driven with a fake client.

The flow (``session.OperatorSession``: scan or look -> marker -> plan with automatic looks ->
execute), its lines, its --json summary and its exit codes, without rclpy: the client's
answers are stand-ins read by attribute as the messages are. The real CLI against real nodes
is tested in test_reach_operator.py, test_operator_marker.py and test_session.py.
"""
from __future__ import annotations

import contextlib
import io
import json
import math
import time
from types import SimpleNamespace as NS
from typing import Any

import numpy as np
import pytest

from humanoid_reach_ros.codes import ExecuteCode, PlanError, code_name
from humanoid_reach_ros.operator import session as sess
from humanoid_reach_ros.operator.cli import parse_args, plan_inputs
from humanoid_reach_ros.operator.goal_status import GOAL_DONE, GOAL_KNOWN, LOST_RESPONSE_GRACE_S, GoalStatuses
from humanoid_reach_ros.operator.marker import MarkerSightings
from humanoid_reach_ros.operator.report import EXIT, Progress, exit_class
from humanoid_reach_ros.operator.session import Canceled, Countdown, OperatorSession

STATS = {"goal_sampling_time_s": 0.1, "goals_found": 3, "goals_requested": 4, "path_planning_time_s": 0.2,
         "path_waypoints": 5, "tree_nodes": 60, "total_time_s": 0.35, "collision_checks": 700,
         "collision_time_s": 0.05, "map_voxels": 800}
TRAJECTORY = NS(points=[NS(time_from_start=NS(sec=0, nanosec=0)), NS(time_from_start=NS(sec=1, nanosec=500_000_000))],
                joint_names=["a", "b", "c"])


def plan_response(code: int = PlanError.SUCCESS, unobserved: list[list[float]] = (), message: str = "the planner says"):
    return NS(success=code == PlanError.SUCCESS, error_code=NS(val=int(code)), message=message, arm=1,
              trajectory=TRAJECTORY,
              statistics=dict(STATS), unobserved_points=[NS(x=p[0], y=p[1], z=p[2]) for p in unobserved])


def result(code: int = ExecuteCode.SUCCESS, message: str = "the executor says", steps: int = 10,
           contact: tuple[bool, float, str] = (False, 0.0927, "")):
    return NS(success=code == ExecuteCode.SUCCESS, error_code=NS(val=int(code)), message=message, duration_s=1.5,
              steps=steps, overruns=0, max_com_error_m=1e-4, min_distance_m=0.05, final_hand_error_m=0.002,
              final_hand_error_rad=0.01, poses_done=1, hand_in_contact=contact[0], contact_distance_m=contact[1],
              contact_with=contact[2])


class FakeClient:
    """An ``OperatorClient``: plan answers in turn (a response, None: no planner, an exception:
    raised), one execution outcome, one look outcome, a /look server that is up or not, and a
    marker that a look may bring into view."""

    def __init__(self, plans: list[Any] = (), execution: tuple[str, Any] = ("done", None),
                 look: tuple[str, Any] = ("done", None), look_up: bool = True, publishers: int = 1,
                 marker_after_look: bool = True, mapper_voxels: int | None = 6585) -> None:
        self.timeout_s = 1.0
        self.mapper_voxels = mapper_voxels
        self.plans = list(plans)
        self.execution = execution if execution[1] is not None or execution[0] != "done" else ("done", result())
        self.look_outcome = look if look[1] is not None or look[0] != "done" else ("done", result(message="looked"))
        self.look_up, self.marker_after_look, self.marker_in_view = look_up, marker_after_look, False
        self.sightings = MarkerSightings(lambda: publishers)
        self.requests: list[Any] = []
        self.looks: list[tuple[list[float], list[float], float, Any]] = []
        self.came_back: list[bool] = []
        self.executed: list[Any] = []

    def spin_until(self, done, timeout_s, cancelable: bool = True) -> bool:
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while not done():
            if deadline is not None and time.monotonic() > deadline:
                return False
            time.sleep(0.002)
            if self.marker_in_view:
                self.sightings.on_pose(NS(pose=NS(position=NS(x=0.71, y=0.03, z=0.9))))
        return True

    def plan(self, req: Any) -> Any:
        self.requests.append(req)
        answer = self.plans.pop(0)
        if isinstance(answer, BaseException):
            raise answer
        return answer

    def execute(self, trajectory, arm, args, on_feedback):
        self.executed.append((trajectory, arm, args.no_collision_avoidance))
        for p in (0.0, 0.5, 1.0):
            on_feedback(Progress(p, 1.5 * p, 0.05, 1e-4, 0.01))
        return self.execution

    def look(self, yaw_rad, pitch_rad, dwell_s, on_feedback, gaze_points=None, come_back=False):
        self.looks.append((list(yaw_rad), list(pitch_rad), dwell_s, gaze_points))
        self.came_back.append(come_back)
        on_feedback(NS(holding=True, pose_index=0, pose_count=1, yaw_rad=0.1, pitch_rad=0.2))
        self.marker_in_view = self.marker_after_look   # marker_localizer publishes from now on
        return self.look_outcome

    def wait_for_look(self, owner: str) -> bool:
        return self.look_up

    def watch_marker(self):
        return contextlib.nullcontext(self.sightings)

    def watch_map(self):
        w = MarkerSightings(lambda: 0)
        if self.mapper_voxels is not None:   # the voxel mapper's diagnostics, as they arrive
            w.on_diagnostics(NS(status=[NS(name="voxel_mapper: map", values=[NS(key="occupied_voxels",
                                                                               value=str(self.mapper_voxels))])]))
        return contextlib.nullcontext(w)

    def executor_parameters(self, names: list[str]) -> dict[str, Any]:
        return {"marker_look_deg": [2.0, 40.0], "robot_config": "unused"}


def run(client: FakeClient, *argv: str) -> tuple[int, dict[str, Any], str, str]:
    """The flow with --json: (exit code, summary, text lines (stderr with --json), err)."""
    out, err = io.StringIO(), io.StringIO()
    args = parse_args([*argv, "--json"])
    code = OperatorSession(client, args, err, err).run("the request", out)
    lines = out.getvalue().splitlines()
    assert len(lines) == 1, out.getvalue()   # with --json, stdout holds only the JSON line
    summary = json.loads(lines[0])
    assert summary["exit_code"] == code
    return code, summary, err.getvalue(), err.getvalue()


TARGET = ("--target", "0.45", "-0.35", "0.50")


# ---------------------------------------------------------------- automatic looks
def test_the_automatic_look_loop_looks_where_the_plan_needs_to_see_then_plans_again() -> None:
    c = FakeClient([plan_response(PlanError.UNOBSERVED_SPACE, [[0.25, -0.29, 0.66]]),
                    plan_response(PlanError.UNOBSERVED_SPACE, [[0.3, 0.0, 1.0], [0.31, 0.0, 1.0]]),
                    plan_response()])
    code, summary, text, _ = run(c, *TARGET, "--execute")
    assert code == EXIT["success"] and len(c.requests) == 3 and c.requests == ["the request"] * 3, text
    assert [g.shape for *_, g in c.looks] == [(1, 3), (2, 3)] and np.allclose(c.looks[0][3], [[0.25, -0.29, 0.66]])
    assert all(yaw == [] and pitch == [] for yaw, pitch, _, _ in c.looks)   # a whole-body gaze, no head angles
    assert c.came_back == [True, True]   # and back to where it stood: the next plan starts there
    assert "the plan needs to see [0.25, -0.29, 0.66] m (unobserved): looking there, automatic look 1/3" in text
    assert "automatic look 2/3" in text and text.count("planning again ...") == 2
    assert len(summary["auto_looks"]) == 2 and summary["auto_looks"][0]["outcome"] == "done"
    assert summary["plan"]["success"] and summary["plan"]["trajectory"] == {"points": 2, "duration_s": 1.5,
                                                                            "joints": 3}
    assert summary["execution"]["error_name"] == "SUCCESS" and "executing ..." in text and "execution: 1.50 s" in text
    assert text.count("%") == 3   # one progress line per tenth (not a terminal)


def test_looks_run_out_are_off_or_have_no_server_then_the_planner_answer_stands() -> None:
    unobserved = [plan_response(PlanError.UNOBSERVED_SPACE, [[0.3, 0.0, 1.0]], "look there")] * 3
    c = FakeClient(unobserved)
    code, summary, text, err = run(c, *TARGET, "--max-looks", "2")
    assert code == EXIT["no_input"] == exit_class(PlanError.UNOBSERVED_SPACE) and len(c.looks) == 2
    assert "still unobserved after 2 automatic look(s) at [0.3, 0.0, 1.0]" in err
    assert "plan failed: UNOBSERVED_SPACE (12): look there\n" in err and summary["plan"]["error_name"] == \
        "UNOBSERVED_SPACE"

    c = FakeClient(unobserved)
    code, _, err, _ = run(c, *TARGET, "--no-auto-look")
    assert code == 6 and not c.looks and len(c.requests) == 1 and "still unobserved" not in err

    c = FakeClient(unobserved, look_up=False)
    code, _, err, _ = run(c, *TARGET)
    assert code == 6 and not c.looks
    assert "/look not available after 1 s (is reach_executor running? --no-auto-look plans without looking): " \
           "no automatic look at [0.3, 0.0, 1.0]" in err


def test_a_failed_automatic_look_stops_with_its_exit_code() -> None:
    c = FakeClient([plan_response(PlanError.UNOBSERVED_SPACE, [[0.3, 0.0, 1.0]])],
                   look=("done", result(ExecuteCode.ABORTED, "stale joint states")))
    code, summary, _, err = run(c, *TARGET)
    assert code == EXIT["execution"] and summary["plan"] is None
    assert "look failed: ABORTED (22): stale joint states" in err
    assert summary["auto_looks"][0]["error_name"] == "ABORTED"


# ---------------------------------------------------------------- exit codes
@pytest.mark.parametrize("code, exit_code", [(PlanError.NO_PATH, 5), (PlanError.INVALID_BOUNDS, 4),
                                             (PlanError.NO_TARGET, 6), (PlanError.INTERNAL_ERROR, 1), (99, 1)])
def test_a_refused_plan_exits_with_its_class(code: int, exit_code: int) -> None:
    c = FakeClient([plan_response(code, message="why")])
    got, summary, _, err = run(c, *TARGET, "--execute")
    assert got == exit_code and not c.executed and summary["execution"] is None
    name = code_name(code)
    assert f"plan failed: {name} ({code}): why -- " in err and summary["plan"]["error_name"] == name


@pytest.mark.parametrize("outcome, res, exit_code, line", [
    ("done", result(), 0, "execution: 1.50 s, 10 steps (0 overruns)"),
    ("unavailable", None, 3, None),
    ("timeout", None, 3, "execution: no answer from /execute_reach within the trajectory duration + 60 s"),
    ("rejected", None, 7, "execution failed: the goal was rejected by /execute_reach"),
    ("done", result(ExecuteCode.ABORTED, "held"), 7, "execution failed: ABORTED (22): held -- the executor stopped"),
    ("done", result(ExecuteCode.TARGET_NOT_REACHED, "off", steps=0), 7, "execution failed: TARGET_NOT_REACHED"),
    ("canceled", result(ExecuteCode.CANCELED, "holding"), 130, "execution canceled: CANCELED (21): holding\n"),
    ("canceled", None, 130, None),
])
def test_an_execution_exits_with_its_class(outcome: str, res: Any, exit_code: int, line: str | None) -> None:
    c = FakeClient([plan_response()], execution=(outcome, res))
    code, summary, text, _ = run(c, *TARGET, "--execute", "--no-collision-avoidance")
    assert code == exit_code and c.executed == [(TRAJECTORY, 1, True)], text
    assert summary["execution"]["outcome"] == outcome
    assert line is None or line in text, text


def test_a_touch_is_visible_in_the_text_and_the_json() -> None:
    """Issue 33, point 4: the end of a reach says whether a hand is in contact, with what and how near."""
    touch = (True, -0.004, "the right hand (r_hand) on the target object (57 voxels within 150 mm of the target)")
    for contact, line in [(touch, "hand IN CONTACT (-4.0 mm): the right hand (r_hand) on the target object (57 "
                                  "voxels within 150 mm of the target)"),
                          ((False, 0.0927, ""), "hand not in contact: the nearest voxel, the target's object "
                                                "included, is 92.7 mm away"),
                          ((False, math.inf, "no map"), "hand contact: no map")]:
        c = FakeClient([plan_response()], execution=("done", result(contact=contact)))
        code, summary, text, _ = run(c, *TARGET, "--execute")
        assert code == 0 and line in text, text
        e = summary["execution"]
        assert (e["hand_in_contact"], e["contact_with"]) == (contact[0], contact[2])
        assert e["contact_distance_m"] == (contact[1] if math.isfinite(contact[1]) else None)   # JSON: inf -> null
        json.dumps(summary, allow_nan=False)


def test_a_lost_planner_exits_3_and_the_summary_says_so() -> None:
    code, summary, _, _ = run(FakeClient([None]), *TARGET, "--execute")
    assert code == EXIT["unavailable"] and summary == {"look": None, "plan": None, "execution": None,
                                                       "exit_code": 3}


def test_ctrl_c_while_planning_exits_130() -> None:
    code, summary, _, err = run(FakeClient([Canceled()]), *TARGET)
    assert code == EXIT["canceled"] and "reach_operator: canceled while planning" in err and summary["plan"] is None


def test_scan_and_look_alone_move_the_head_only() -> None:
    c = FakeClient([])
    code, summary, text, _ = run(c, "--scan")
    assert code == 0 and not c.requests and c.looks == [([], [], 0.0, None)]
    assert "scanning with the head" in text and "  head pose 1/1: yaw +5.7, pitch +11.5 deg (holding)" in text
    assert summary["look"]["message"] == "looked" and "look: looked [1.5 s, max COG drift 0.10 mm]" in text
    assert summary["map_voxels"] == 6585 and "map: 6,585 occupied voxels" in text   # how big the map now is
    code, summary, text, _ = run(FakeClient([], mapper_voxels=None), "--scan", "--no-auto-look")
    assert code == 0 and summary["map_voxels"] is None and "map: size unknown (no voxel_mapper diagnostics" in text
    c = FakeClient([])
    code, _, _, _ = run(c, "--look", "10", "20", "--dwell", "2")
    assert code == 0 and c.looks == [([math.radians(10)], [math.radians(20)], 2.0, None)] and c.came_back == [False]
    for look, exit_code in ((("rejected", None), 7), (("canceled", None), 130), (("timeout", None), 3),
                            (("unavailable", None), 3), (("canceled", result(ExecuteCode.CANCELED)), 130)):
        code, summary, _, _ = run(FakeClient([plan_response()], look=look), "--scan", "--execute")
        assert code == exit_code and summary["plan"] is None, look


# ---------------------------------------------------------------- the marker
@pytest.fixture
def quick_marker(monkeypatch):
    monkeypatch.setattr(sess, "MARKER_FRESH_WAIT_S", 0.05)
    monkeypatch.setattr(sess, "MARKER_DISCOVERY_S", 0.05)
    monkeypatch.setattr(sess, "MARKER_DIAGNOSTICS_WAIT_S", 0.05)


def test_a_marker_out_of_view_turns_the_head_to_find_it(quick_marker) -> None:
    c = FakeClient([plan_response()])
    code, summary, text, _ = run(c, "--marker")
    assert code == 0 and summary["marker"] == {"fresh": True, "looked_deg": [2.0, 40.0], "toward": None}
    assert c.looks == [([math.radians(2.0)], [math.radians(40.0)], sess.MARKER_LOOK_DWELL_S, None)]
    assert "(marker_look_deg; no diagnostics from marker_localizer): yaw 2, pitch 40 deg ..." in text
    assert "marker seen at (0.710, 0.030, 0.900) m" in text and "planning to the marker's /target_pose" in text

    c = FakeClient([plan_response()], marker_after_look=False)
    code, summary, _, err = run(c, "--marker", "--marker-wait", "0.3")
    assert code == EXIT["no_input"] and summary["marker"]["fresh"] is False and not c.requests
    assert "reach_operator: waiting for /target_pose (marker_localizer) ... 0 s left" in err
    assert "no /target_pose within 0.3 s after turning the head where the executor looks for it" in err

    c = FakeClient([plan_response()], look=("done", result(ExecuteCode.CANCELED)))
    assert run(c, "--marker")[0] == EXIT["canceled"]
    c = FakeClient([plan_response()], look=("unavailable", None))
    code, _, _, err = run(c, "--marker")
    assert code == EXIT["unavailable"] and "look toward the marker failed: unavailable" in err


def test_a_marker_in_view_or_no_localizer_goes_straight_to_planning(quick_marker) -> None:
    c = FakeClient([plan_response()])
    c.sightings.pose_t = math.inf   # a /target_pose has just come
    code, summary, _, _ = run(c, "--marker")
    assert code == 0 and summary["marker"] == {"fresh": True, "looked_deg": None, "toward": None} and not c.looks
    c = FakeClient([plan_response(PlanError.NO_TARGET)], publishers=0)
    code, summary, _, err = run(c, "--marker")
    assert code == EXIT["no_input"] and not c.looks and summary["marker"]["fresh"] is False
    assert f"plan failed: NO_TARGET ({int(PlanError.NO_TARGET)})" in err


def test_an_automatic_look_with_the_marker_finds_the_marker_again(quick_marker) -> None:
    c = FakeClient([plan_response(PlanError.UNOBSERVED_SPACE, [[0.3, 0.0, 1.0]]), plan_response()])
    c.sightings.pose_t = math.inf
    code, _, text, _ = run(c, "--marker")
    assert code == 0 and len(c.looks) == 1 and text.index("automatic look 1/3") < text.index("planning again")


def test_marker_sightings_read_the_messages() -> None:
    s = MarkerSightings(lambda: 2)
    s.on_diagnostics(NS(status=[NS(name="voxel_mapper", values=[NS(key="target_x_m", value="9")]),
                                NS(name="marker_localizer: marker", values=[NS(key=k, value=v) for k, v in (
                                    ("target_x_m", "0.7"), ("target_y_m", "0.1"), ("target_z_m", "0.9"))])]))
    s.on_joint_state(NS(name=["j1", "j2"], position=[0.5, -0.25]))
    assert s.diagnostics and s.last == [0.7, 0.1, 0.9] and s.joints == {"j1": 0.5, "j2": -0.25}
    assert s.publishers() == 2 and s.pose_t == -math.inf


# ---------------------------------------------------------------- pieces
def test_countdown_lines_count_down() -> None:
    err = io.StringIO()
    c = Countdown(err, "/look (reach_executor)", 30.0, first_s=0.0)
    c.tick()
    c.tick()   # not again before the next multiple of WAIT_NOTE_EVERY_S
    assert err.getvalue() == "reach_operator: waiting for /look (reach_executor) ... 30 s left\n"


def test_goal_statuses_stand_in_after_the_grace() -> None:
    g = GoalStatuses()
    g.update(b"id", 2, now=10.0)            # EXECUTING
    assert not g.says(b"id", GOAL_KNOWN, now=10.0 + LOST_RESPONSE_GRACE_S / 2)
    assert g.says(b"id", GOAL_KNOWN, now=10.1 + LOST_RESPONSE_GRACE_S) and not g.says(b"id", GOAL_DONE, now=99.0)
    g.update(b"id", 4, now=20.0)            # SUCCEEDED: a new status starts its own grace
    g.update(b"id", 4, now=20.5)
    assert not g.says(b"id", GOAL_DONE, now=20.5) and g.says(b"id", GOAL_DONE, now=20.1 + LOST_RESPONSE_GRACE_S)
    assert not g.says(b"other", GOAL_KNOWN, now=99.0)


def test_plan_inputs_are_plain_values() -> None:
    p = plan_inputs(parse_args([*TARGET, "--rpy-deg", "0", "90", "0", "--frame", "base_link", "--seed", "3",
                                "--goals", "7", "--budget", "2.5", "--arm", "left", "--wgr-deg", *["0"] * 12]))
    assert p.frame == "base_link" and p.seed == 3 and p.goal_count == 7 and p.time_budget_s == 2.5 and not p.home
    assert np.allclose(p.target[0], [0.45, -0.35, 0.5]) and np.allclose(p.target[1] @ [1, 0, 0], [0, 0, -1])
    assert np.allclose(p.lower, 0) and np.allclose(p.upper, 0) and not p.use_marker_target
    d = plan_inputs(parse_args(["--home"]))
    assert d.home and d.target is None and d.seed == -1 and d.planner == "" and d.frame == "world"
    assert np.allclose(d.upper[3:], [math.pi / 2, math.pi / 2, math.pi])


def test_the_core_needs_no_ros() -> None:
    """No module of the unit imports rclpy, messages or io/ (test_layering checks the units)."""
    import ast
    from pathlib import Path

    import humanoid_reach_ros.operator as pkg
    for path in Path(pkg.__file__).parent.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            assert not [n for n in names if n.split(".")[0] in ("rclpy", "humanoid_reach_interfaces")
                        or n.endswith("_msgs") or n.startswith("humanoid_reach_ros.io")], (path, names)
