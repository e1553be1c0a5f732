"""The generality suite (config/scenes/suite.yaml): every case and arm once, through the
library API, answers what the suite expects; the suite file is validated."""
from __future__ import annotations

import numpy as np
import pytest
import yaml

from humanoid_reach_ros.planning.reach import PlanError, PlannerParams, PlanRequest, ReachPlanner
from humanoid_reach_ros.planning.suite import load_suite

CASES = load_suite()
NO_GOAL_BUDGET_S = 0.3      # a no_goal case spends its whole budget: keep it short here
BUDGET_S = 4.0              # generous for a loaded machine (the bench uses 2 s)


@pytest.fixture(scope="module")
def planner():
    rp = ReachPlanner(params=PlannerParams(safety_margin_m=0.01))
    rp.warm_up()
    return rp


def test_the_suite_covers_the_scene_classes():
    names = {c.name for c in CASES}
    assert len({c.scene_path for c in CASES}) >= 8
    assert {"low_valve", "overhead_valve", "wall_switch", "behind_pipe", "narrow_pipes"} <= names
    assert any(c.expect == {"right": "reachable", "left": "no_goal"} for c in CASES)
    assert any(c.expect == {"right": "no_goal", "left": "reachable"} for c in CASES)
    assert sum(c.scene_class != "reachable" for c in CASES) >= 2
    assert any(c.scene_class == "out_of_reach" for c in CASES) and any(c.scene_class == "no_goal" for c in CASES)


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_each_case_answers_as_expected(planner, case):
    planner.set_map(case.voxels(planner.params.resolution_m))
    ok, why = planner.check_start(planner.robot.half_sitting_joints)
    assert ok, why
    for arm in ("right", "left"):
        expected = case.expected_code(arm)
        budget = NO_GOAL_BUDGET_S if expected == "NO_GOAL_FOUND" else BUDGET_S
        o = planner.plan(planner.robot.half_sitting_joints,
                         PlanRequest(case.region(), arm=arm, seed=0, time_budget_s=budget))
        assert o.error.name == expected, f"{case.name} {arm}: {o.message}"
        if o.success:
            assert o.arm == arm
            hand = planner.robot.frame_pose(o.waypoints[-1], f"{arm[0]}_hand_ee")
            np.testing.assert_allclose(hand.translation, case.target_pose[:3, 3], atol=1e-6)
        elif expected == "TARGET_OUT_OF_REACH":
            assert o.stats["samples"] == 0 and o.stats["total_time_s"] < 0.05
        else:
            assert o.stats["samples"] > 0 and "not proven out of reach" in o.message


@pytest.mark.parametrize("edit, text", [
    (lambda c: c.update(expect={"right": "reachable"}), "expect must give each of"),
    (lambda c: c.update(expect={"right": "maybe", "left": "reachable"}), "expect must give each of"),
    (lambda c: c.update(colour="red"), "unknown key"),
    (lambda c: c.update(scene="scenes/nowhere.yaml"), "does not exist"),
    (lambda c: c.update(region="sphere"), "region must be one of"),
    (lambda c: c.update(cone_deg=120), "cone_deg"),
    (lambda c: c.update(target={"position": [0.1, float("nan"), 1.0]}), "target.position"),
])
def test_bad_suite_files_are_refused(tmp_path, edit, text):
    case = {"name": "x", "scene": "scenes/low_valve.yaml", "expect": {"right": "reachable", "left": "reachable"}}
    edit(case)
    path = tmp_path / "suite.yaml"
    path.write_text(yaml.safe_dump({"cases": [case]}))
    with pytest.raises(ValueError, match=text):
        load_suite(path)

