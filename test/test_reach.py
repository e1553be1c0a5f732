"""ReachPlanner: request -> goals -> path -> trajectory on the plant scene (valve WGR, eq. 3)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from humanoid_reach_ros.planning.path import interpolate_path
from humanoid_reach_ros.planning.reach import (
    STAT_KEYS, PlanError, PlannerParams, PlanRequest, ReachPlanner,
)
from humanoid_reach_ros.planning.wgr import WorkspaceGoalRegion, valve_region
from humanoid_reach_ros.robot.model import N_BASE_Q
from humanoid_reach_ros.sim.scene import load_scene

LEFT_ONLY_TARGET = (0.45, 0.5, 0.9)    # beyond the right arm's reach
RIGHT_ONLY_TARGET = (0.45, -0.5, 0.9)  # beyond the left arm's reach


@pytest.fixture(scope="module")
def scene():
    return load_scene("scenes/plant.yaml")


@pytest.fixture(scope="module")
def voxels(scene):
    return scene.voxelize(0.02, exclude_groups=("valve",))


@pytest.fixture(scope="module")
def planner(voxels):
    rp = ReachPlanner(params=PlannerParams(time_budget_s=5.0))
    rp.set_map(voxels)
    return rp


@pytest.fixture(scope="module")
def region(scene):
    return valve_region(scene.target.pose)


@pytest.fixture(scope="module")
def outcomes(planner, region):
    hs = planner.robot.half_sitting_joints
    return {arm: planner.plan(hs, PlanRequest(region, arm=arm, seed=3)) for arm in ("right", "left", "auto")}


def _check_outcome(rp: ReachPlanner, o, region: WorkspaceGoalRegion) -> None:
    assert o.success and o.error is PlanError.SUCCESS, o.message
    assert o.arm in ("right", "left")
    assert set(o.stats) == set(STAT_KEYS)
    robot = rp.robot
    col = rp.collision
    # waypoints: collision-free, within limits, feet at the stance
    W = o.waypoints
    assert W.shape[1] == robot.model.nq and len(W) == o.stats["path_waypoints"] >= 2
    assert np.all(col.check_batch(W))
    J = W[:, N_BASE_Q:]
    assert np.all((J >= robot.lower - 1e-9) & (J <= robot.upper + 1e-9))
    soles = robot.stance_soles
    for q in W:
        for frame, ref in zip(("r_sole", "l_sole"), soles):
            M = robot.frame_pose(q, frame)
            assert np.allclose(M.translation, ref.translation, atol=1e-9)
            assert np.allclose(M.rotation, ref.rotation, atol=1e-9)
    # the start is the true start; the rest are projections of the planned q_plan
    assert np.allclose(W[0], rp.start_config(robot.half_sitting_joints), atol=1e-12)
    # every interpolated configuration at the check resolution (in q_plan, through the projector)
    space = rp.planning_space(o.arm, o.waypoints_plan)
    Q = interpolate_path(o.waypoints_plan, space)
    assert len(Q) > len(o.waypoints_plan)
    res = rp.projector.project_plan_config(Q, o.arm)
    assert np.all(res.ok)
    assert np.all(col.check_batch(res.q))
    assert np.all((res.q[:, N_BASE_Q:] >= robot.lower - 1e-9) & (res.q[:, N_BASE_Q:] <= robot.upper + 1e-9))
    # the final hand pose lies in the WGR; it is one of the sampled goals
    hand = robot.frame_pose(W[-1], "r_hand_ee" if o.arm == "right" else "l_hand_ee")
    assert region.contains(hand.translation, hand.rotation, tol=1e-6)
    assert np.allclose(W[-1], o.goals[o.goal_index], atol=1e-9)


@pytest.mark.parametrize("arm", ["right", "left", "auto"])
def test_plans_valve_reach(planner, outcomes, region, arm):
    o = outcomes[arm]
    _check_outcome(planner, o, region)
    if arm != "auto":
        assert o.arm == arm
    s = o.stats
    assert s["goals_found"] == s["goals_requested"] == planner.params.goal_count
    assert s["goals_right_arm"] + s["goals_left_arm"] == s["goals_found"]
    assert s["map_voxels"] == planner.map_voxels > 20_000
    assert s["collision_checks"] > 0 and s["tree_nodes"] >= 2 and s["samples"] >= s["goals_found"]
    assert s["total_time_s"] >= s["goal_sampling_time_s"] + s["path_planning_time_s"] - 1e-6
    assert o.message.startswith(f"planned {o.arm}-arm reach: {len(o.waypoints)} waypoints")


def test_trajectory_is_clamped_spline_through_waypoints(planner, outcomes):
    o = outcomes["right"]
    t = o.times
    assert t[0] == 0.0 and np.all(np.diff(t) > 0)
    assert np.all(np.diff(t) <= planner.params.output_period_s + 1e-9)
    assert o.positions.shape == o.velocities.shape == o.accelerations.shape == (len(t), 30)
    assert np.allclose(o.velocities[0], 0, atol=1e-12) and np.allclose(o.velocities[-1], 0, atol=1e-12)
    # every waypoint is a sample, at its waypoint time
    idx = np.searchsorted(t, o.waypoint_times)
    assert np.allclose(t[idx], o.waypoint_times, atol=0)
    assert np.allclose(o.positions[idx], o.waypoints[:, N_BASE_Q:], atol=1e-12)
    # durations rule: T_i = max_j |dq_j| / v
    dq = np.abs(np.diff(o.waypoints[:, N_BASE_Q:], axis=0)).max(axis=1)
    assert np.allclose(np.diff(o.waypoint_times), np.maximum(dq / planner.params.joint_velocity_rad_s, 0.01))
    assert np.allclose(o.waist_start.homogeneous, planner.robot.base_pose(o.waypoints[0]).homogeneous)


def test_deterministic_for_a_seed(planner, region, outcomes):
    o = planner.plan(planner.robot.half_sitting_joints, PlanRequest(region, arm="right", seed=3))
    ref = outcomes["right"]
    assert np.array_equal(o.waypoints, ref.waypoints)
    assert np.array_equal(o.positions, ref.positions) and np.array_equal(o.goals, ref.goals)
    other = planner.plan(planner.robot.half_sitting_joints, PlanRequest(region, arm="right", seed=4))
    assert other.success and not np.array_equal(other.goals, ref.goals)


def test_both_arms_used_when_one_cannot_reach(planner):
    hs = planner.robot.half_sitting_joints
    left = planner.plan(hs, PlanRequest(valve_region(LEFT_ONLY_TARGET), arm="auto", seed=1))
    _check_outcome(planner, left, valve_region(LEFT_ONLY_TARGET))
    assert left.arm == "left" and left.stats["goals_right_arm"] == 0
    right = planner.plan(hs, PlanRequest(valve_region(RIGHT_ONLY_TARGET), arm="auto", seed=1))
    _check_outcome(planner, right, valve_region(RIGHT_ONLY_TARGET))
    assert right.arm == "right" and right.stats["goals_left_arm"] == 0
    # the right arm alone finds no goal for the left target; the geometric bound does not
    # rule it out (a yawed, leaning trunk brings the right shoulder within the arm's length)
    o = planner.plan(hs, PlanRequest(valve_region(LEFT_ONLY_TARGET), arm="right", seed=1, time_budget_s=0.3))
    assert o.error is PlanError.NO_GOAL_FOUND, o.message
    assert "not proven out of reach" in o.message and o.stats["samples"] > 0
    assert o.stats["total_time_s"] >= 0.3   # the whole budget went to the search


def test_start_away_from_half_sitting_gets_a_pre_segment(planner, region):
    """A start whose other arm and trunk differ from the planning manifold's reference."""
    robot = planner.robot
    j = robot.half_sitting_joints.copy()
    li = robot.limbs["left_arm"].joint_index
    j[li[3]] += 0.3   # left elbow: not at the reference (the planning manifold's value)
    o = planner.plan(j, PlanRequest(region, arm="right", seed=3))
    assert o.success, o.message
    assert np.allclose(o.positions[0], j) and np.allclose(o.waypoints[0, N_BASE_Q:], j)
    assert len(o.waypoints) >= 3
    assert np.all(planner.collision.check_batch(o.waypoints))


# ------------------------------------------------------------------ error codes
def test_error_codes_for_invalid_input(planner, region):
    hs = planner.robot.half_sitting_joints
    bad = hs.copy()
    bad[3] = np.nan
    o = planner.plan(bad, PlanRequest(region))
    assert o.error is PlanError.INVALID_REQUEST and not o.success and "NaN" in o.message
    assert planner.plan(hs[:10], PlanRequest(region)).error is PlanError.INVALID_REQUEST
    nan_region = valve_region()
    object.__setattr__(nan_region, "target_p", np.array([np.nan, 0.0, 0.9]))
    o = planner.plan(hs, PlanRequest(nan_region))
    assert o.error is PlanError.INVALID_REQUEST and "NaN" in o.message
    assert planner.plan(hs, PlanRequest(region, arm="both")).error is PlanError.INVALID_REQUEST
    assert planner.plan(hs, PlanRequest(region, planner="rrt_star")).error is PlanError.INVALID_REQUEST
    assert planner.plan(hs, PlanRequest(region, time_budget_s=math.inf)).error is PlanError.INVALID_REQUEST
    assert planner.plan(hs, "not a request").error is PlanError.INVALID_REQUEST
    for o in (planner.plan(bad, PlanRequest(region)),):
        assert o.message and o.joint_names == planner.robot.joint_names and set(o.stats) == set(STAT_KEYS)


def test_no_map(region):
    rp = ReachPlanner()
    assert not rp.has_map
    o = rp.plan(rp.robot.half_sitting_joints, PlanRequest(region))
    assert o.error is PlanError.NO_MAP
    assert rp.check_start(rp.robot.half_sitting_joints)[0] is False


def test_set_map_validation_and_empty_map(region):
    rp = ReachPlanner()
    with pytest.raises(ValueError):
        rp.set_map(np.zeros((4, 2)))
    with pytest.raises(ValueError):
        rp.set_map(np.array([[0.0, np.nan, 1.0]]))
    assert rp.set_map(np.zeros((0, 3))) >= 0 and rp.has_map and rp.map_voxels == 0
    o = rp.plan(rp.robot.half_sitting_joints, PlanRequest(region, arm="right", seed=0))
    assert o.success, o.message


def test_start_in_collision_names_the_shapes(planner, voxels, region):
    rp = ReachPlanner(robot=planner.robot)
    waist = rp.start_config(rp.robot.half_sitting_joints)[:3]
    rp.set_map(np.vstack([voxels, waist[None]]))
    ok, why = rp.check_start(rp.robot.half_sitting_joints)
    assert not ok and "collision" in why
    o = rp.plan(rp.robot.half_sitting_joints, PlanRequest(region))
    assert o.error is PlanError.START_IN_COLLISION
    assert any(n in o.message for n in rp.collision_model.names), o.message
    assert planner.check_start(planner.robot.half_sitting_joints) == (True, "start posture valid")


@pytest.mark.parametrize("target, arm", [((2.0, 0.03, 0.9), "auto"), ((0.3, 0.0, 2.2), "auto"),
                                         ((0.45, 0.5, 2.0), "right")])
def test_target_out_of_reach_is_proven_at_once(planner, target, arm):
    o = planner.plan(planner.robot.half_sitting_joints, PlanRequest(valve_region(target), arm=arm, seed=0))
    assert o.error is PlanError.TARGET_OUT_OF_REACH, o.message
    assert "short" in o.message and "move the target closer" in o.message
    assert o.stats["samples"] == 0 and o.stats["total_time_s"] < 0.05   # no sampling: the bound decided


def test_tiny_time_budget(planner, region):
    o = planner.plan(planner.robot.half_sitting_joints, PlanRequest(region, time_budget_s=1e-4, seed=0))
    assert o.error in (PlanError.NO_GOAL_FOUND, PlanError.NO_PATH) and not o.success, o.message


@pytest.mark.parametrize("name", ["prm", "modified_prm"])
def test_prm_planners(planner, region, name):
    """Both roadmap planners, by the names the /plan_reach service accepts. (The budget is
    for correctness on a loaded machine: the plain PRM needs ~4 s of CPU here, which the
    fixture's 5 s did not always cover while other jobs shared the cores.)"""
    from humanoid_reach_ros.planning.space import PLANNER_NAMES as PLANNERS

    assert name in PLANNERS
    o = planner.plan(planner.robot.half_sitting_joints,
                     PlanRequest(region, arm="right", planner=name, seed=2, time_budget_s=60.0))
    _check_outcome(planner, o, region)


def test_fast_paths_plan_like_the_reference(planner, voxels, region):
    """The compiled kinematics and early-exit edge checks change speed only: a planner on
    the numpy reference leg IK checking every edge point plans the same path for a seed;
    the validity function's first_invalid agrees with its batch answer."""
    ref = ReachPlanner(planner.robot, planner.params, compiled_kinematics=False, early_exit_checks=False)
    ref.set_map(voxels)
    hs = planner.robot.half_sitting_joints
    for arm in ("right", "left"):
        a = planner.plan(hs, PlanRequest(region, arm=arm, seed=5))
        b = ref.plan(hs, PlanRequest(region, arm=arm, seed=5))
        assert a.success and b.success, (a.message, b.message)
        assert a.waypoints_plan.shape == b.waypoints_plan.shape
        np.testing.assert_allclose(a.waypoints_plan, b.waypoints_plan, rtol=0, atol=1e-9)
        np.testing.assert_allclose(a.positions, b.positions, rtol=0, atol=1e-9)
    is_valid = planner.validity_fn("right", planner.collision)
    assert not hasattr(ref.validity_fn("right", ref.collision), "first_invalid")
    space = planner.planning_space("right")
    Q = space.sample(np.random.default_rng(8), 300)
    ok = is_valid(Q)
    assert 0 < ok.sum() < len(ok)
    for s in range(0, 300, 11):
        rows = Q[s:s + 30]
        v = is_valid(rows)
        assert is_valid.first_invalid(rows) == (len(rows) if v.all() else int(np.argmin(v)))


@pytest.mark.parametrize("kwargs, text", [
    ({"trunk_z_m": (0.8, 0.5)}, "trunk_z_m"), ({"trunk_pitch_rad": (0.0, float("nan"))}, "trunk_pitch_rad"),
    ({"trunk_space_margin": (-0.1, 0.3)}, "trunk_space_margin"), ({"trunk_space_margin": (0.1,)}, "trunk_space_margin"),
])
def test_trunk_parameters_are_validated(kwargs, text):
    with pytest.raises(ValueError, match=text):
        PlannerParams(**kwargs)


def test_trunk_ranges_narrow_the_search(region):
    """A given trunk_z_m bounds the leg grid: goals stay inside it."""
    rp = ReachPlanner(params=PlannerParams(trunk_z_m=(0.60, 0.70)))
    rp.set_map(np.zeros((0, 3)))
    o = rp.plan(rp.robot.half_sitting_joints, PlanRequest(region, seed=0))
    assert o.success, o.message
    assert np.all((o.goals[:, 2] >= 0.60 - 1e-9) & (o.goals[:, 2] <= 0.70 + 1e-9))
