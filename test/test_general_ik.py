"""General closed-form 6R IK (kinematics/general_ik.py): HRP-2's four limbs give the specialized
solver's answers; random chains of the solvable class, whatever their axis directions and
offsets, come back from FK; other chains are refused."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from humanoid_reach_ros.kinematics.general_ik import Chain6, GeneralLimbIK
from humanoid_reach_ros.kinematics.registry import LimbIKSet
from humanoid_reach_ros.robot.model import RobotModel


@pytest.fixture(scope="module")
def robot():
    return RobotModel()


@pytest.mark.parametrize("limb", ["right_leg", "left_leg", "right_arm", "left_arm"])
def test_hrp2_limbs_match_the_specialized_solver(robot, limb):
    spec = robot.limbs[limb]
    chain = Chain6.from_model(robot, spec.root, spec.joints, spec.tip)
    ik = GeneralLimbIK(chain, robot.half_sitting_joints[list(spec.joint_index)])
    assert ik.reversed   # HRP-2's three intersecting axes are at the root (hip, shoulder)
    rng = np.random.default_rng(1)
    q = rng.uniform(chain.lower, chain.upper, size=(1500, 6))
    p, R = chain.fk(q)
    # and poses a little beyond: some reachable, some not
    p_far = p * rng.uniform(1.0, 1.3, size=(1500, 1))
    special = LimbIKSet(robot)
    for P in (p, p_far):
        ours = ik.solve(P, R)
        theirs = special.solve(limb, np.zeros(3), np.eye(3), P, R)
        np.testing.assert_array_equal(ours.ok, theirs.ok)
        np.testing.assert_allclose(ours.q[ours.ok], theirs.q[ours.ok], atol=1e-6)
        p2, R2 = chain.fk(np.nan_to_num(ours.q))
        assert np.abs(p2 - P)[ours.ok].max() < 1e-9 and np.abs(R2 - R)[ours.ok].max() < 1e-9
    assert ik.solve(p, R).ok.all() and not ik.solve(p_far, R).ok.all()


def _random_chain(rng, wrist_at_tip: bool) -> Chain6:
    """Random axis directions and link rotations, offsets only where the class allows them."""
    R = Rotation.random(6, random_state=rng.integers(1 << 31)).as_matrix()
    t = rng.uniform(-0.3, 0.3, size=(6, 3))
    if wrist_at_tip:
        t[1] = t[4] = t[5] = 0.0
    else:
        t[1] = t[2] = t[5] = 0.0
    axes = rng.normal(size=(6, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    Re = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()
    return Chain6(R, t, axes, Re, rng.uniform(-0.1, 0.1, 3), np.full(6, -np.pi), np.full(6, np.pi))


@pytest.mark.parametrize("wrist_at_tip", [True, False])
def test_random_chains_of_the_class_come_back_from_fk(wrist_at_tip):
    rng = np.random.default_rng(7 + wrist_at_tip)
    for _ in range(20):
        chain = _random_chain(rng, wrist_at_tip)
        ik = GeneralLimbIK(chain, np.zeros(6))
        assert ik.reversed is not wrist_at_tip
        q = rng.uniform(-np.pi, np.pi, size=(200, 6))
        p, R = chain.fk(q)
        res = ik.solve(p, R, q_ref=q)
        assert res.ok.mean() > 0.97   # a few near-singular draws may miss FK_TOL
        p2, R2 = chain.fk(res.q[res.ok])
        assert np.abs(p2 - p[res.ok]).max() < 1e-8 and np.abs(R2 - R[res.ok]).max() < 1e-8
        # with the drawn joints as reference, the drawn solution itself comes back
        close = np.linalg.norm(np.angle(np.exp(1j * (res.q[res.ok] - q[res.ok]))), axis=1) < 1e-6
        assert close.mean() > 0.97


def test_chains_outside_the_class_are_refused():
    rng = np.random.default_rng(3)
    chain = _random_chain(rng, True)
    t = chain.t.copy()
    t[4] = [0.05, 0.0, 0.0]   # the wrist's axes no longer meet, and the root has only two
    with pytest.raises(ValueError, match="not solvable in closed form"):
        GeneralLimbIK(Chain6(chain.R, t, chain.axes, chain.Re, chain.te, chain.lower, chain.upper), np.zeros(6))


def test_from_model_refuses_what_is_not_a_serial_6r_chain(robot):
    legs = robot.limbs["right_leg"].joints
    with pytest.raises(ValueError, match="not a serial 6R chain"):
        Chain6.from_model(robot, robot.base_link, legs[:3] + robot.limbs["left_leg"].joints[:3],
                          robot.limbs["left_leg"].tip)
    with pytest.raises(ValueError, match="need 6 joints"):
        Chain6.from_model(robot, robot.base_link, legs[:5], robot.limbs["right_leg"].tip)


def test_a_limb_off_the_hand_derived_patterns_gets_the_general_closed_form(tmp_path):
    """HRP-2 with its right shoulder's first axis tilted (a robot the hand-derived arm pattern
    refuses): the limb set gives it the general solver, behind the same protocol, and the goal
    sampler's projector reaches through it."""
    from humanoid_reach_ros.kinematics.general_limb import GeneralLimb
    from humanoid_reach_ros.robot.spec import robot_config_path

    src = robot_config_path("hrp2").parent
    urdf = (src / "hrp2.urdf").read_text()
    anchor = '<joint name="RARM_JOINT0" type="revolute">'
    i = urdf.index(anchor)
    j = urdf.index('<axis xyz="0 1 0"/>', i)
    urdf = urdf[:j] + '<axis xyz="0.2 0.9797958971 0"/>' + urdf[j + len('<axis xyz="0 1 0"/>'):]
    (tmp_path / "hrp2.urdf").write_text(urdf)
    for f in ("collision.yaml", "robot.yaml", "dual_arm_workspace.yaml", "torso_svr.yaml", "torso_svr.npz"):
        (tmp_path / f).write_bytes((src / f).read_bytes())
    # HRP-2's reach map is not this robot's (its right shoulder differs): without one it plans as before
    doc = (tmp_path / "robot.yaml").read_text()
    (tmp_path / "robot.yaml").write_text("\n".join(line for line in doc.splitlines()
                                                  if not line.startswith("reach_map:")) + "\n")
    robot = RobotModel(tmp_path / "robot.yaml")
    ik = LimbIKSet(robot)
    assert isinstance(ik["right_arm"], GeneralLimb) and not isinstance(ik["left_arm"], GeneralLimb)
    arm = ik["right_arm"]
    rng = np.random.default_rng(4)
    q = rng.uniform(arm.lower, arm.upper, size=(500, 6))
    root_p, root_R = np.array([0.1, -0.2, 1.0]), Rotation.from_euler("z", 0.3).as_matrix()
    p, R = arm.fk(root_p, root_R, q)
    res = ik.solve("right_arm", root_p, root_R, p, R)
    assert res.ok.all()
    p2, R2 = arm.fk(root_p, root_R, res.q)
    assert np.abs(p2 - p).max() < 1e-9 and np.abs(R2 - R).max() < 1e-9
    assert arm.maybe_reachable(root_p, root_R, p, R).all()
    far = arm.maybe_reachable(root_p, root_R, p + 5.0, R)
    assert not far.any() and not ik.solve("right_arm", root_p, root_R, p + 5.0, R).ok.any()
    # the planner plans a right-arm reach through it (goal sampling: the projector's arm IK)
    from humanoid_reach_ros.planning.reach import PlanRequest, ReachPlanner
    from humanoid_reach_ros.planning.wgr import valve_region

    planner = ReachPlanner(robot)
    planner.set_map(np.zeros((0, 3)))
    out = planner.plan(robot.half_sitting_joints, PlanRequest(valve_region(), arm="right", seed=0, time_budget_s=10.0))
    assert out.success, out.message
    hand = robot.frame_pose(out.waypoints[-1], robot.hand_frames["right"])
    np.testing.assert_allclose(hand.translation, valve_region().target_p, atol=1e-6)
    # the collision model's FK follows the tilted axis (its kernels turn the joint frame)
    cm, col = planner.collision_model, planner.collision
    for q_full in out.waypoints:
        P0, P1 = col.world_shapes(q_full)
        for s, link in enumerate(cm.shape_link):
            pose = robot.frame_pose(q_full, cm.links[link])
            np.testing.assert_allclose(P0[s], pose.act(cm.p0_local[s]), atol=1e-9)
            np.testing.assert_allclose(P1[s], pose.act(cm.p1_local[s]), atol=1e-9)


def test_seven_dof_arm_closed_form_on_a_subchain_with_the_first_joint_sampled():
    """A random 7R arm of Talos's form (shoulder joints 2-3 intersecting, spherical wrist
    5-6-7, offsets elsewhere): poses of random joints are reached; with the drawn joints as
    reference the drawn solution comes back."""
    from humanoid_reach_ros.kinematics.general_ik import RedundantLimbIK

    rng = np.random.default_rng(11)
    R = Rotation.random(7, random_state=5).as_matrix()
    t = rng.uniform(-0.25, 0.25, size=(7, 3))
    t[2] = t[5] = t[6] = 0.0
    axes = rng.normal(size=(7, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    lim = np.full(7, np.pi)
    chain = Chain6(R, t, axes, np.eye(3), np.array([0.0, 0.0, 0.1]), -lim, lim)   # seven rows
    ik = RedundantLimbIK(chain, np.zeros(7), samples=64)   # random axes: narrow self-motion ranges
    q = rng.uniform(-np.pi, np.pi, size=(300, 7))
    p, Rt = chain.fk(q)
    res = ik.solve(p, Rt)
    assert res.ok.mean() > 0.9
    p2, R2 = chain.fk(res.q[res.ok])
    assert np.abs(p2 - p[res.ok]).max() < 1e-8 and np.abs(R2 - Rt[res.ok]).max() < 1e-8
    exact = ik.solve(p, Rt, q_ref=q)
    assert exact.ok.all()
    np.testing.assert_allclose(np.angle(np.exp(1j * (exact.q - q))), 0.0, atol=1e-6)
    t_bad = t.copy()
    t_bad[6] = [0.03, 0.0, 0.0]
    with pytest.raises(ValueError, match="not solvable in closed form"):
        RedundantLimbIK(Chain6(R, t_bad, axes, np.eye(3), np.zeros(3), -lim, lim), np.zeros(7))
