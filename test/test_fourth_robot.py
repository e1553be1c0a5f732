"""A fourth humanoid, any humanoid (issue 23 part 4): the iCub of example-robot-data
(icub_reduced.urdf, referenced, not copied), described by test/data/robots/icub/robot.yaml and a
coarse collision.yaml -- a test fixture, not a robot of config/robots -- loads through
``RobotModel(path)``, passes the loader's checks, gets a solver answering ``LimbSolver`` for each
limb from the registry (legs: the general closed form; arms: the numerical solver), stands
balanced, and the planner plans a reach with each arm and the way home. No code of the package
names it.

iCub's floating base (root_link) has x backward: the loader takes the stance frame's axes from
it, so in the stance frame this robot faces -x; "forward" below is the soles' x axis."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from humanoid_reach_ros.dual_arm.balance import polygon_margin, support_polygon
from humanoid_reach_ros.kinematics import LimbIKSet, LimbSolver
from humanoid_reach_ros.robot.model import N_BASE_Q, RobotModel
from humanoid_reach_ros.robot.shapes import load_collision_model
from humanoid_reach_ros.robot.spec import robots

ICUB = Path(__file__).resolve().parent / "data" / "robots" / "icub" / "robot.yaml"
URDF = "package://example-robot-data/robots/icub_description/robots/icub_reduced.urdf"
#: the URDF's mounting angles are rounded (1.5708, 3.1416 rad): the soles are level to this [rad]
LEVEL_TOL = 5e-5


@pytest.fixture(scope="module")
def icub():
    return RobotModel(ICUB)


@pytest.fixture(scope="module")
def ik(icub):
    return LimbIKSet(icub)


def _forward(icub) -> np.ndarray:
    """The robot's forward direction in the stance frame: the soles' x axis."""
    return icub.stance_soles[0].rotation[:, 0]


def _urdf_entry(path: Path) -> str:
    """The description's ``urdf`` entry as written."""
    return yaml.safe_load(path.read_text())["urdf"]


def test_the_icub_loads_from_the_packaged_urdf_and_passes_the_spec_checks(icub):
    spec = icub.spec
    assert icub.name == "icub" and "icub" not in robots()          # a fixture, not a robot of config/robots
    assert _urdf_entry(ICUB) == URDF and spec.urdf_path.name == "icub_reduced.urdf"
    assert spec.urdf_path.is_file() and "example-robot-data" in str(spec.urdf_path)
    assert icub.n_joints == 29 and icub.model.nq == 36
    # no neck (the reduced URDF's neck joints are fixed), the chest's roll present, 7-joint arms
    assert not spec.has_neck and spec.neck_joints == ()
    with pytest.raises(ValueError, match="has no neck"):
        spec.require_neck("a look at head angles")
    assert spec.chest_joints == ("torso_yaw", "torso_pitch")
    assert spec.torso_joints == ("torso_yaw", "torso_pitch", "torso_roll")
    assert [len(icub.limbs[n].joints) for n in ("right_leg", "left_leg", "right_arm", "left_arm")] == [6, 6, 7, 7]
    assert spec.chest_link == "chest" and icub.base_link == "root_link"
    # every name of the description is a joint or frame of the model (the loader checked it)
    for n in spec.names():
        assert n in icub.joint_index or icub.model.existFrame(n), n
    # the added frames hang from the last arm joints, the URDF's soles from the last leg joints
    for limb in icub.limbs.values():
        tip = icub.model.frames[icub.frame_id(limb.tip)]
        assert icub.model.names[tip.parentJoint] == limb.joints[-1], limb.name
    assert "eyes_optical_frame" in icub.description_xml
    # the camera's optical frame looks forward (z), x to the robot's right, y down
    C = icub.frame_pose(icub.half_sitting(), icub.camera_frame).rotation
    fwd = _forward(icub)
    right = icub.stance_soles[0].translation - icub.stance_soles[1].translation
    assert C[:, 2] @ fwd > 0.999 and C[:, 0] @ right / np.linalg.norm(right) > 0.999 and C[:, 1] @ [0, 0, -1] > 0.999


def test_every_limb_gets_a_solver_answering_the_protocol(icub, ik):
    """Legs: the three hip joints share an origin, so do the two ankle joints: the general
    closed form. Arms: the wrist is spherical (the pronosupination axis runs along the forearm
    through the pitch/yaw point) but the wrist pitch joint's origin lies 0.1373 m down that
    axis from the pronosupination joint's; the closed forms' class test (general_ik.py) takes
    the offsets between joint origins, not where the axis lines meet, so joints 2..7 are not
    of its class: the numerical solver."""
    kinds = {n: ik[n].kind for n in ik.names}
    assert all(isinstance(ik[n], LimbSolver) for n in ik.names)
    assert kinds == {"right_leg": "general", "left_leg": "general", "right_arm": "numerical",
                     "left_arm": "numerical"}, kinds
    for n in ik.names:
        assert ik[n].joint_names == icub.limbs[n].joints
        assert not ik[n].compiled      # no hand-derived leg kernel: the projection goes through the protocol


@pytest.mark.parametrize("limb", ["right_leg", "left_leg", "right_arm", "left_arm"])
def test_each_limb_round_trips_its_half_sitting_tip_pose(icub, ik, limb):
    q = icub.half_sitting()
    spec = icub.limbs[limb]
    root = icub.frame_pose(q, spec.root)
    tip = icub.frame_pose(q, spec.tip)
    solver = ik[limb]
    q_limb = q[N_BASE_Q:][list(spec.joint_index)]
    p, R = solver.fk(root.translation, root.rotation, q_limb)   # the protocol's FK is the model's
    np.testing.assert_allclose(p.reshape(3), tip.translation, atol=1e-9)
    np.testing.assert_allclose(R.reshape(3, 3), tip.rotation, atol=1e-9)
    # solved back from a reference away from the answer (the middle of the joint ranges)
    for q_ref in (None, 0.5 * (solver.lower + solver.upper)):
        res = solver.solve(root.translation, root.rotation, tip.translation, tip.rotation, q_ref=q_ref)
        assert np.all(res.ok), (limb, res)
        qs = np.asarray(res.q).reshape(-1, len(spec.joints))
        assert np.all(qs >= solver.lower - 1e-9) and np.all(qs <= solver.upper + 1e-9)
        p2, R2 = solver.fk(root.translation, root.rotation, qs)
        assert np.abs(p2.reshape(3) - tip.translation).max() < 1e-8, limb
        assert np.abs(R2.reshape(3, 3) - tip.rotation).max() < 1e-8, limb


def test_half_sitting_is_level_balanced_and_free_of_self_collision(icub):
    q = icub.half_sitting()
    r, l_ = (icub.frame_pose(q, f) for f in icub.sole_frames)
    for s in (r, l_):
        assert abs(s.translation[2]) < 1e-6
        assert s.rotation[2, 2] > np.cos(LEVEL_TOL)                 # the sole's z is the world's up
    np.testing.assert_allclose(r.translation * [1, -1, 1], l_.translation, atol=1e-5)   # mirror images
    assert abs(l_.translation[1] - r.translation[1]) == pytest.approx(0.136, abs=1e-3)   # as the URDF places them
    # knees bent: the waist lower than on straight legs
    straight = icub.base_on_feet(np.zeros(icub.n_joints)).translation[2]
    assert 0.02 < straight - q[2] < 0.04, straight - q[2]
    poly = support_polygon(icub)
    x0, x1, y0, y1 = icub.spec.sole_rectangle
    assert np.ptp(poly, axis=0)[0] == pytest.approx(x1 - x0, abs=1e-4)
    margin = polygon_margin(poly, icub.com(q)[:2])[0]
    assert margin > 0.04, margin
    cm = load_collision_model(None, icub)
    P0, P1, rad = cm.world_shapes(icub.forward(q))
    assert not cm.in_self_collision(P0, P1, rad), cm.colliding_pairs(P0, P1, rad)


@pytest.fixture(scope="module")
def planner(icub):
    from humanoid_reach_ros.planning.reach import ReachPlanner

    p = ReachPlanner(RobotModel(ICUB))
    p.set_map(np.zeros((0, 3)))
    return p


@pytest.mark.parametrize("arm", ["right", "left"])
def test_the_planner_reaches_in_front_of_a_hand_and_plans_the_way_home(icub, planner, arm):
    """Free space: a target 0.12 m ahead of and 0.05 m above the half-sitting grasp point; the
    final grasp point at the target, the soles on their stance at every waypoint; then the way
    home from the reached posture."""
    from humanoid_reach_ros.planning.reach import PlanRequest
    from humanoid_reach_ros.planning.wgr import valve_region

    robot = planner.robot      # ReachPlanner(RobotModel(path)): its own model of the description
    q = robot.half_sitting()
    hand0 = robot.frame_pose(q, robot.hand_frames[arm]).translation
    target = hand0 + 0.12 * _forward(robot) + [0.0, 0.0, 0.05]
    t = time.perf_counter()
    out = planner.plan(robot.half_sitting_joints, PlanRequest(valve_region(target_p=target), arm=arm, seed=0,
                                                               time_budget_s=10.0))
    reach_s = time.perf_counter() - t
    assert out.success, out.message
    assert out.arm == arm
    final = robot.frame_pose(out.waypoints[-1], robot.hand_frames[arm]).translation
    np.testing.assert_allclose(final, target, atol=1e-6)
    cm = planner.collision_model
    for w in out.waypoints:
        for s, stance in zip(robot.sole_frames, robot.stance_soles):   # the feet stay where they stand
            np.testing.assert_allclose(robot.frame_pose(w, s).homogeneous, stance.homogeneous, atol=1e-6)
        P0, P1, rad = cm.world_shapes(robot.forward(w))
        assert not cm.in_self_collision(P0, P1, rad)
    t = time.perf_counter()
    home = planner.plan(out.waypoints[-1][N_BASE_Q:], PlanRequest(None, home=True, seed=0, time_budget_s=10.0))
    home_s = time.perf_counter() - t
    assert home.success, home.message
    np.testing.assert_allclose(home.waypoints[-1][N_BASE_Q:], robot.half_sitting_joints, atol=1e-6)
    for w in home.waypoints:
        for s, stance in zip(robot.sole_frames, robot.stance_soles):
            np.testing.assert_allclose(robot.frame_pose(w, s).homogeneous, stance.homogeneous, atol=1e-6)
    print(f"icub {arm}: reach {reach_s:.2f} s ({len(out.waypoints)} waypoints), home {home_s:.2f} s")
