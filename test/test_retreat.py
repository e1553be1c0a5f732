"""A session from wherever the robot stands: retreat from a contact, the way home
(planning/retreat.py, ReachPlanner with ``home``)."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from humanoid_reach_ros.codes import PlanError
from humanoid_reach_ros.geometry.sphere_tree import SphereTree
from humanoid_reach_ros.nodes.common import scene_file_voxels
from humanoid_reach_ros.paths import config_path
from humanoid_reach_ros.planning.reach import PlannerParams, PlanRequest, ReachPlanner
from humanoid_reach_ros.planning.wgr import valve_region
from humanoid_reach_ros.robot.model import N_BASE_Q, RobotModel
from humanoid_reach_ros.scene.planning_scene import PlanningScene, SceneParams


@pytest.fixture(scope="module")
def planner() -> ReachPlanner:
    robot = RobotModel()
    pl = ReachPlanner(robot, PlannerParams(safety_margin_m=0.01))
    pl.scene = PlanningScene(robot, SceneParams(safety_margin_m=0.01, target_exclusion_radius_m=0.15),
                             pl.collision_model)
    # a measured map holds the valve itself: the planner leaves it out around the target only
    pl.scene.set_occupied(scene_file_voxels(config_path("scenes/plant.yaml"), 0.02, ()), "set_map")
    return pl


@pytest.fixture(scope="module")
def at_valve(planner) -> np.ndarray:
    out = planner.plan(planner.robot.half_sitting_joints, PlanRequest(valve_region(), seed=1, time_budget_s=5.0))
    assert out.success, out.message
    return out.positions[-1]


def test_from_the_valve_a_retreat_comes_first(planner, at_valve) -> None:
    region = dataclasses.replace(valve_region(), target_p=np.array([0.45, -0.22, 0.86]))
    out = planner.plan(at_valve, PlanRequest(region, seed=2, time_budget_s=5.0))
    assert out.success, out.message
    assert out.retreat.startswith("retreat") and "first a retreat" in out.message
    np.testing.assert_allclose(out.positions[0], at_valve, atol=1e-9)
    # the hand leaves the valve first: its distance to where it rested grows over the first samples
    arm = "right" if planner.robot.frame_pose(planner.start_config(at_valve), planner.robot.hand_frames["right"]
                                              ).translation[0] > 0.5 else "left"
    hand = [planner.robot.frame_pose(planner.start_config(j), planner.robot.hand_frames[arm]).translation
            for j in out.positions[:4]]
    d = [np.linalg.norm(h - hand[0]) for h in hand]
    assert d[1] > 0 and d[2] > d[1] and d[3] > d[2], d
    # and every sample keeps clear of the map but the two objects (the valve it leaves, the new target's)
    snap = planner.scene.snapshot()
    check, _ = snap.collision(planner.robot, planner.collision_model, np.vstack([hand[0], region.target_p]))
    assert all(check.check(planner.start_config(j)) for j in out.positions)


def test_home_from_the_valve_ends_at_half_sitting(planner, at_valve) -> None:
    out = planner.plan(at_valve, PlanRequest(None, home=True, seed=3, time_budget_s=5.0))
    assert out.success, out.message
    np.testing.assert_allclose(out.positions[-1], planner.robot.half_sitting_joints, atol=1e-9)
    assert out.retreat and out.positions[-1].shape == (planner.robot.n_joints,)
    lo, hi = planner.robot.lower, planner.robot.upper
    assert np.all((out.positions >= lo - 1e-9) & (out.positions <= hi + 1e-9))


def test_home_from_home_is_a_trajectory_at_rest(planner) -> None:
    out = planner.plan(planner.robot.half_sitting_joints, PlanRequest(None, home=True))
    assert out.success and "already at the rest posture" in out.message, out.message
    np.testing.assert_allclose(out.positions, planner.robot.half_sitting_joints[None].repeat(len(out.positions), 0))


def test_a_body_in_collision_is_refused_with_links_and_voxels(planner) -> None:
    robot = planner.robot
    q = planner.start_config(robot.half_sitting_joints)
    chest = robot.frame_pose(q, robot.spec.chest_link).translation
    saved = planner.scene.snapshot().occupied
    try:
        planner.scene.set_occupied(np.vstack([saved, chest[None]]), "set_map")
        out = planner.plan(robot.half_sitting_joints, PlanRequest(None, home=True))
        assert out.error == PlanError.START_IN_COLLISION, out.message
        assert "mm from the voxel at" in out.message and "chest" in out.message, out.message
    finally:
        planner.scene.set_occupied(saved, "set_map")


def test_bad_requests(planner) -> None:
    out = planner.plan(planner.robot.half_sitting_joints, PlanRequest(None))
    assert out.error == PlanError.INVALID_REQUEST and "region" in out.message
    out = planner.plan(planner.robot.half_sitting_joints,
                       PlanRequest(valve_region(), approach=np.array([np.nan, 0.0, 0.0])))
    assert out.error == PlanError.INVALID_REQUEST and "approach" in out.message


def test_the_retreat_does_not_depend_on_the_next_target(planner, at_valve) -> None:
    """The contact is the start's, in the map as it is: a target whose object (the 15 cm left out
    around it) overlaps the contact's voxels does not change the contact's normal, its allowed
    voxels or the retreat (bench/session, dense_pipes: a target 26 cm from the hand left part of
    the pipe under the forearm out and every retreat failed, while the way home, on the whole
    map, found one). Was: another direction for each of these two targets."""
    home = planner.plan(at_valve, PlanRequest(None, home=True, seed=3, time_budget_s=5.0))
    assert home.success and home.retreat, home.message
    v = valve_region().target_p
    for offset in ([0.0, 0.2, 0.0], [0.0, -0.15, -0.1]):
        region = dataclasses.replace(valve_region(), target_p=v + np.array(offset))
        out = planner.plan(at_valve, PlanRequest(region, seed=2, time_budget_s=5.0))
        assert out.success, (offset, out.message)
        assert out.retreat == home.retreat, (offset, out.retreat, home.retreat)


def test_a_start_off_the_manifold_goes_by_home_whatever_the_longer_retreats_say(planner, monkeypatch) -> None:
    """The pre-segment fails, then no longer retreat exists ("no retreat ... frees it"): the reach
    still goes by the rest posture (bench/session, dense_pipes: that answer ended the reach while
    the way home from the same posture planned)."""
    from humanoid_reach_ros.planning import reach as reach_mod

    calls, home_calls = [], []

    def fake_plan(joints, request, stats, t0, snap, collisions=None, force_retreat=False, min_retreat_m=None):
        calls.append(min_retreat_m)
        if min_retreat_m is None:
            raise reach_mod._failure(PlanError.START_IN_COLLISION, "the start posture cannot be moved to the "
                                     "planning manifold without collision (right arm: pre_segment)")
        raise reach_mod._failure(PlanError.START_IN_COLLISION, "the right hand touches the map and no retreat "
                                 "of 120-250 mm frees it")

    def fake_via_home(joints, request, snap, t0, failed):
        home_calls.append(failed.message)
        return dataclasses.replace(failed, success=True, error=PlanError.SUCCESS, message="by the rest posture")

    monkeypatch.setattr(planner, "_plan", fake_plan)
    monkeypatch.setattr(planner, "_via_home", fake_via_home)
    monkeypatch.setattr(planner, "_unobserved_check", lambda outcome, *a, **k: outcome)
    monkeypatch.setattr(planner, "_remember_end", lambda outcome: None)
    out = planner.plan(planner.robot.half_sitting_joints, PlanRequest(valve_region(), seed=1))
    assert calls == [None, 0.12] and len(home_calls) == 1, (calls, home_calls)
    assert out.success and out.message == "by the rest posture"
    # a home request is not sent home again
    calls.clear(), home_calls.clear()
    out = planner.plan(planner.robot.half_sitting_joints, PlanRequest(None, home=True))
    assert not out.success and not home_calls


def test_a_refused_retreat_lists_every_retreat_tried(planner, at_valve) -> None:
    """When no retreat frees a start in contact, the answer keeps six reasons and the outcome
    every one (``retreats_tried``; the planner node logs them: bench/session's refused retreat in
    dense_pipes could not be explained from the six)."""
    saved = planner.retreat_planner.params
    planner.retreat_planner.params = dataclasses.replace(saved, end_clearance_m=10.0)   # no retreat can end
    try:
        out = planner.plan(at_valve, PlanRequest(None, home=True, seed=3, time_budget_s=5.0))
    finally:
        planner.retreat_planner.params = saved
    assert out.error == PlanError.START_IN_COLLISION and "no retreat of" in out.message, out.message
    tried = out.retreats_tried
    assert len(tried) > 6 and f"... {len(tried) - 6} more lines" in out.message, (len(tried), out.message)
    assert out.message.endswith("; ".join(tried[:6]) + f"; ... {len(tried) - 6} more lines")
    assert any("no clearance of 10000 mm" in why for why in tried), tried
    ok = planner.plan(at_valve, PlanRequest(None, home=True, seed=3, time_budget_s=5.0))
    assert ok.success and ok.retreats_tried == (), ok.message


def test_the_way_back_along_the_last_plan_from_a_posture_off_its_end(planner, at_valve) -> None:
    """The executor ends a reach with the hand where the plan put it and the other joints where
    its own tasks took them (0.19 rad off the plan's end in bench/session's dense_pipes, where
    every Cartesian retreat then failed). The last plan's reverse is still the first retreat
    tried: the offset is blended out along it, every sample checked; a robot elsewhere gets none.
    The last plan here came in along the valve's contact normal (the reverse of a retreat from
    there): a real reach's way in often passes the object's voxels, which the planner left out
    around its target, and its reverse is then refused (the next test)."""
    robot = planner.robot
    away = planner.plan(at_valve, PlanRequest(None, home=True, seed=3, time_budget_s=5.0))
    assert away.success and "retreat" in away.message, away.message
    arm = "right" if planner.robot.frame_pose(planner.start_config(at_valve), robot.hand_frames["right"]
                                              ).translation[0] > 0.5 else "left"
    tip = robot.limbs[f"{arm}_arm"].tip
    hand = np.array([robot.frame_pose(planner.start_config(j), tip).translation for j in away.positions])
    k = int(np.argmax(np.linalg.norm(hand - hand[0], axis=1) > 0.08)) + 1
    planner._last_positions, planner._last_arm = away.positions[:k][::-1].copy(), arm   # came in along it
    end = planner._last_positions[-1]
    other = "left" if arm == "right" else "right"
    cols = list(robot.limbs[f"{other}_arm"].joint_index)
    q = end.copy()
    q[cols] = np.clip(q[cols] + 0.15, robot.lower[cols], robot.upper[cols])   # the hand stays, 0.15 rad off
    R = planner._reverse_of_last(q)
    assert R is not None and np.array_equal(R[0], q)
    assert np.all(R >= robot.lower - 1e-12) and np.all(R <= robot.upper + 1e-12)
    off = np.abs(R - planner._last_positions[::-1])[:, cols].max(axis=1)
    assert off[0] == pytest.approx(0.15, abs=1e-9) and np.all(np.diff(off) <= 1e-12), off
    home = planner.plan(q, PlanRequest(None, home=True, seed=4, time_budget_s=5.0))
    assert home.success and "back along the approach" in home.message, home.message
    np.testing.assert_allclose(home.positions[0], q, atol=1e-9)
    far = end.copy()
    far[cols] = np.clip(far[cols] + 0.8, robot.lower[cols], robot.upper[cols])
    assert planner._reverse_of_last(far) is None                       # too far from the plan's end
    moved = end.copy()
    moved[list(robot.limbs[f"{arm}_arm"].joint_index)] += 0.1          # the hand 3+ cm from the plan's
    assert planner._reverse_of_last(moved) is None


def _unchecked_planner(robot: RobotModel) -> ReachPlanner:
    """The fixture's planner without the target object's depth check (planning/approach.py):
    paths as they were before it, an approach free to pass through the object."""
    pl = ReachPlanner(robot, PlannerParams(safety_margin_m=0.01, object_depth_tolerance_m=math.inf))
    pl.scene = PlanningScene(robot, SceneParams(safety_margin_m=0.01, target_exclusion_radius_m=0.15),
                             pl.collision_model)
    pl.scene.set_occupied(scene_file_voxels(config_path("scenes/plant.yaml"), 0.02, ()), "set_map")
    return pl


def test_a_way_in_through_the_object_is_not_a_way_out(planner) -> None:
    """Without the object's depth check the reach onto the passage pipe's top came down through
    voxels the planner left out around its target: its reverse presses into the pipe and is
    refused; a Cartesian retreat frees the hand instead."""
    pl = _unchecked_planner(planner.robot)
    top = dataclasses.replace(valve_region(), target_p=np.array([0.35, -0.15, 0.78]))
    reach = pl.plan(pl.robot.half_sitting_joints, PlanRequest(top, seed=1, time_budget_s=5.0))
    assert reach.success, reach.message
    assert pl._reverse_of_last(reach.positions[-1]) is not None
    home = pl.plan(reach.positions[-1], PlanRequest(None, home=True, seed=4, time_budget_s=5.0))
    assert home.success and "retreat" in home.message and "back along" not in home.message, home.message


def _deepest_beyond_the_end(pl: ReachPlanner, positions: np.ndarray, target: np.ndarray) -> float:
    """How much deeper [m] than at the path's end any shape goes into the target's object (the
    voxels within 0.15 m of the target, the planner's exclusion) along the path's samples."""
    V = pl.scene.snapshot().occupied
    obj = SphereTree.from_voxels(V[np.linalg.norm(V - target, axis=1) <= 0.15], 0.02, 0.0)
    D = np.array([obj.nearest_batch(*pl.collision_model.world_shapes(pl.start_config(j)))[0] for j in positions])
    return float(np.max(np.minimum(0.0, D[-1])[None] - D))


@pytest.mark.parametrize("target, arm, seed", [([0.35, -0.15, 0.78], "auto", 1),      # the passage pipe's top
                                               ([0.741, 0.077, 0.883], "left", 3)])   # the valve's hub, inside the rim
def test_the_way_in_comes_to_the_object_from_outside(planner, target, arm, seed) -> None:
    """The planner leaves the object at the target out of its map (a hand must touch it), but a
    path's shapes go no deeper into it than at the path's ends (planning/approach.py): the hand
    comes to the object from outside, and the way back along the approach is a way out. Was
    (the check off): through the pipe's top 21 mm deeper than the hand rests, and the left hand
    to the hub through the rim 20 mm deeper -- the operator console's Home after such a reach
    failed START_IN_COLLISION ("back along the approach: the hand would press into the
    contact's voxels at sample 5")."""
    target = np.array(target)
    region = dataclasses.replace(valve_region(), target_p=target)
    # the planner's object_depth_tolerance_m (12 mm, within the way back's 15 mm) and 2 mm for the spline
    # between the checked points
    tolerance = planner.params.object_depth_tolerance_m + 0.002
    assert tolerance < 0.015
    old = _unchecked_planner(planner.robot).plan(planner.robot.half_sitting_joints,
                                                 PlanRequest(region, arm=arm, seed=seed, time_budget_s=5.0))
    assert old.success and _deepest_beyond_the_end(planner, old.positions, target) > 0.015, old.message
    reach = planner.plan(planner.robot.half_sitting_joints, PlanRequest(region, arm=arm, seed=seed, time_budget_s=5.0))
    assert reach.success, reach.message
    assert _deepest_beyond_the_end(planner, reach.positions, target) <= tolerance
    home = planner.plan(reach.positions[-1], PlanRequest(None, home=True, seed=4, time_budget_s=5.0))
    assert home.success and "back along the approach" in home.message, home.message
    np.testing.assert_allclose(home.positions[-1], planner.robot.half_sitting_joints, atol=1e-9)


# Where bench/session s15 (plant, seed 1) left HRP-2: the right hand on the passage pipe after a
# touch, the lower body crouched and turned, the left forearm 1 cm from the waist. The retreat
# that brought the chest home swung that forearm into the waist; the planner refused the
# retreat's end and both the next reach and the way home failed (START_IN_COLLISION).
ON_THE_PASSAGE_PIPE = [0.0528, -0.0873, -0.0159, -0.01, 0.2299, -0.1351, -0.102, -0.6008, -0.0005, -0.0208, -0.1745,
                       0.2307, 0.1353, 0.2461, -1.641, 0.1033, 0.2827, 0.1745, 0.1385, 0.2201, -1.0437, 1.8993,
                       -0.8842, -0.1055, 0.1381, 0.2051, -1.0566, 1.7927, -0.7647, -0.0905]


def test_a_retreat_never_brings_the_robot_into_itself() -> None:
    planner = ReachPlanner(params=PlannerParams(time_budget_s=10.0))
    planner.set_map(scene_file_voxels(str(config_path("scenes/plant.yaml")), 0.02, ("valve",)))
    j = np.array(ON_THE_PASSAGE_PIPE)
    out = planner.plan(j, PlanRequest(None, arm="auto", home=True, seed=105))
    assert out.success and "first a retreat" in out.message, out.message
    cm, margin = planner.collision_model, planner.collision.self_margin_m
    for joints in out.positions:                     # the whole way, the retreat first
        P0, P1, _ = cm.world_shapes(planner.start_config(joints))
        assert not cm.colliding_pairs(P0, P1, margin=margin - 1e-9)
    # the retreat planner names the pair it refused
    contact, _ = planner.retreat_planner.classify_start(planner.start_config(j), planner.collision.tree, 0.0)
    _, reasons = planner.retreat_planner.plan(j, contact, planner.collision.tree, 0.0, self_margin_m=margin)
    assert any("chest home: l_hand<->l_thigh would come within the self-collision margin" in r for r in reasons), \
        reasons


def test_back_along_a_way_in_that_grazed_the_object_a_little_deeper() -> None:
    """Talos's gripper at the valve's rim, 38 mm into the rim's voxels (the planner left them out
    around the target): the way in grazed the rim 2.4 mm deeper at its second sample back. The
    way back along it may go ``way_back_depth_m`` deeper than the start; with no allowance at all
    (``clearance_tolerance_m`` only) it is refused, and in the measured map nothing else freed the hand."""
    robot = RobotModel("talos")
    # the way in as it was before the object's depth check (planning/approach.py): it grazed the rim
    pl = ReachPlanner(robot, PlannerParams(safety_margin_m=0.01, object_depth_tolerance_m=math.inf))
    pl.scene = PlanningScene(robot, SceneParams(safety_margin_m=0.01, target_exclusion_radius_m=0.15),
                             pl.collision_model)
    pl.scene.set_occupied(scene_file_voxels(str(robot.spec.demo_scene), 0.02, ()), "set_map")
    reach = pl.plan(robot.half_sitting_joints, PlanRequest(valve_region(), seed=0, time_budget_s=5.0))
    assert reach.success, reach.message
    end = reach.positions[-1]
    reverse = pl._reverse_of_last(end)
    assert reverse is not None
    contact, hit = pl.retreat_planner.classify_start(pl.start_config(end), pl.collision.tree, 0.01)
    assert contact is not None and hit is None and contact.distance_m < -0.02, contact
    back, _ = pl.retreat_planner.plan(end, contact, pl.collision.tree, 0.01, reverse_path=reverse)
    assert back is not None and back.label == "back along the approach", back
    params = pl.retreat_planner.params
    strict = dataclasses.replace(params, way_back_depth_m=params.clearance_tolerance_m)
    old, pl.retreat_planner.params = pl.retreat_planner.params, strict
    try:
        refused, reasons = pl.retreat_planner.plan(end, contact, pl.collision.tree, 0.01, reverse_path=reverse)
    finally:
        pl.retreat_planner.params = old
    assert refused is None or refused.label != "back along the approach"
    assert any("back along the approach: the hand would press into the contact's voxels" in r for r in reasons), reasons


def test_the_way_home_is_the_way_in_reversed_where_it_is_clear(planner) -> None:
    """After a reach from the rest posture the way home goes back the way the hand came in (a
    retreat back along it, then the rest of it): the body swept it, so it is observed free where a
    new search would need a tube of swept space. Every edge is checked, and it ends at the rest
    posture; a plan that did not begin at the rest posture has no such way home."""
    rest = planner.robot.half_sitting_joints
    reach = planner.plan(rest, PlanRequest(valve_region(), seed=2, time_budget_s=5.0))
    assert reach.success, reach.message
    home = planner.plan(reach.positions[-1], PlanRequest(None, home=True, seed=2, time_budget_s=5.0))
    assert home.success and "the way in reversed" in home.message, home.message
    np.testing.assert_allclose(home.positions[-1], rest, atol=1e-9)
    way = np.asarray(home.waypoints)
    # the way home's joints pass the reach's own samples, backwards (within the offset blended out)
    reach_samples = np.asarray(reach.positions)
    near = [float(np.min(np.max(np.abs(reach_samples - w[N_BASE_Q:]), axis=1))) for w in way[len(way) // 2:]]
    assert max(near) < 1e-6, max(near)
    # a reach that began with the head pitched down (a scan ends so: the console's Home, ci42)
    # goes home the same way, the last edge turning the head to the rest posture's
    neck = [planner.robot.joint_index[n] for n in planner.robot.spec.neck_joints]
    assert neck
    looking = rest.copy()
    looking[neck[-1]] = np.clip(0.6, planner.robot.lower[neck[-1]], planner.robot.upper[neck[-1]])
    reach2 = planner.plan(looking, PlanRequest(valve_region(), seed=2, time_budget_s=5.0))
    assert reach2.success, reach2.message
    home2 = planner.plan(reach2.positions[-1], PlanRequest(None, home=True, seed=2, time_budget_s=5.0))
    assert home2.success and "the way in reversed" in home2.message, home2.message
    np.testing.assert_allclose(home2.positions[-1], rest, atol=1e-9)
    # from a posture no plan ended at: a searched way home
    elsewhere = reach.positions[-1] + 0.05
    other = planner.plan(np.clip(elsewhere, planner.robot.lower, planner.robot.upper),
                         PlanRequest(None, home=True, seed=2, time_budget_s=5.0))
    assert "the way in reversed" not in other.message, other.message
