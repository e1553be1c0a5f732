"""The dual-arm whole-body reaching method (dual_arm/) on the second robot, Talos: 7-DOF arms
(RedundantLimbIK behind the limb protocol, RedundantArmTracker in the control steps), its own
workspace file (config/robots/talos/dual_arm_workspace.yaml) and torso regression model."""
from __future__ import annotations

import numpy as np
import pytest
import yaml

from humanoid_reach_ros.paths import config_path
from humanoid_reach_ros.dual_arm.balance import com_projection, polygon_margin, support_polygon, zmp_trajectory
from humanoid_reach_ros.dual_arm.controller import DualArmReachController
from humanoid_reach_ros.dual_arm.targets import HandTargets
from humanoid_reach_ros.dual_arm.torso_regression import WORKSPACE_YAML, ReachWorkspace
from humanoid_reach_ros.robot.model import N_BASE_Q, RobotModel

MARGIN_M = 0.02
#: (right, left) hand targets [m] in Talos's workspace boxes, reached by the method
PAIR = ((0.332, -0.097, 0.892), (0.225, 0.214, 0.716))


@pytest.fixture(scope="module")
def ctl():
    return DualArmReachController(RobotModel("talos"))


def test_each_robot_reads_its_own_workspace(ctl):
    assert ctl.robot.spec.dual_arm_workspace == str(config_path("robots/talos/dual_arm_workspace.yaml"))
    assert not np.allclose(ctl.ws.right_lower, ReachWorkspace.load(WORKSPACE_YAML).right_lower)
    hrp2 = RobotModel()
    assert (ReachWorkspace.for_robot(hrp2).right_lower.tolist()
            == ReachWorkspace.load(WORKSPACE_YAML).right_lower.tolist())
    # the initial posture: the arms set by initial_joints_deg, the CoM lowered
    for name, v in ctl.ws.initial_joints.items():
        assert ctl.q_init[N_BASE_Q + ctl.robot.joint_index[name]] == pytest.approx(v)
    drop = ctl.robot.com(ctl.robot.half_sitting())[2] - ctl.robot.com(ctl.q_init)[2]
    assert drop == pytest.approx(ctl.ws.initial_com_drop_m, abs=1e-6)


def test_bad_initial_joints_are_refused(tmp_path, ctl):
    doc = yaml.safe_load(config_path(ctl.robot.spec.dual_arm_workspace).read_text())
    doc["initial_joints_deg"] = {"no_such_joint": 10.0}
    (tmp_path / "ws.yaml").write_text(yaml.safe_dump(doc))
    with pytest.raises(ValueError, match="no joint 'no_such_joint'"):
        ReachWorkspace.load(tmp_path / "ws.yaml").initial_posture(ctl.robot)


def test_proposed_step_takes_seven_dof_arms_through_the_protocol(ctl):
    ik = ctl.ik
    assert ik.arm_ik == {"right": None, "left": None}        # CompiledArmIK: HRP-2's pattern only
    assert set(ik.arm_track) == {"right", "left"}
    q0 = ctl.q_init
    M = {s: ctl.robot.frame_pose(q0, ctl.robot.hand_frames[s]) for s in ("right", "left")}
    d = np.array([0.002, 0.0, -0.002])
    hands = HandTargets(M["right"].translation + d, M["right"].rotation, M["left"].translation + d, M["left"].rotation)
    chest = np.array([q0[c] for c in ctl._chest_cols])
    for tracking in (True, False):
        res = ik.step(q0, hands, chest, ctl.leg_targets(ctl.robot.com(q0)), ctl.sole_support, tracking=tracking)
        assert res.ok, res.reason
        # Algorithm 3 places the CoM with the arms of q_prev; the arms' move then shifts it
        assert res.hand_error < 1e-9 and res.com_error < 1e-3
    # a step of a motion moves the first (redundant) joint at most its velocity limit x period
    res = ik.step(q0, hands, chest, ctl.leg_targets(ctl.robot.com(q0)), ctl.sole_support)
    for s in ("right", "left"):
        first = N_BASE_Q + ctl.robot.joint_index[ctl.robot.limbs[f"{s}_arm"].joints[0]]
        v = ctl.robot.model.velocityLimit[first - 1]
        assert abs(res.q[first] - q0[first]) <= v * ctl.config.period_s + 1e-12


def test_a_reach_converges_with_balance_and_no_jump(ctl):
    ctl.reset()
    t = ctl.ws.targets(np.array(PAIR[0]), np.array(PAIR[1]))
    plan = ctl.set_targets(t.p_right, t.R_right, t.p_left, t.R_left)
    assert plan.feasible, plan.reason
    steps = ctl.run()
    assert len(steps) == plan.n_steps and all(s.ok for s in steps), [s.reason for s in steps if not s.ok][:3]
    qs = np.array([s.q for s in steps])
    r = ctl.robot
    errs = [np.linalg.norm(r.frame_pose(qs[-1], r.hand_frames[s]).translation - p)
            for s, p in (("right", t.p_right), ("left", t.p_left))]
    assert max(errs) <= 1e-3
    assert max(s.com_error for s in steps) < 2e-3
    traj = np.vstack([ctl.q_init[None], qs, qs[-1:]])
    # continuity: no joint moves faster than its velocity limit (the grid of RedundantLimbIK
    # jumped up to 1.4 rad in one step here)
    v = np.abs(np.diff(traj[:, N_BASE_Q:], axis=0)) / ctl.config.period_s
    assert np.all(v <= r.model.velocityLimit[6:] + 1e-9)
    poly = support_polygon(r)
    assert polygon_margin(poly, zmp_trajectory(r, traj, ctl.config.period_s)).min() >= MARGIN_M
    assert polygon_margin(poly, com_projection(r, traj)).min() >= MARGIN_M


def test_the_compiled_tracker_step_gives_the_references_answers(ctl):
    """``RedundantArmTracker.solve`` (one numba call, ``track_step``) against its numpy reference
    ``solve_reference`` on the steps of a reach and on perturbed, unreachable and non-finite
    poses: the same outcome, the same joints to 1e-9 rad."""
    rng = np.random.default_rng(3)
    ctl.reset()
    t = ctl.ws.targets(np.array(PAIR[0]), np.array(PAIR[1]))
    assert ctl.set_targets(t.p_right, t.R_right, t.p_left, t.R_left).feasible
    steps = ctl.run()
    r = ctl.robot
    compared = {"ok": 0, "failed": 0}
    for s in ("right", "left"):
        tracker, limb = ctl.ik.arm_track[s], r.limbs[f"{s}_arm"]
        cols = [N_BASE_Q + r.joint_index[j] for j in limb.joints]
        for k in range(0, len(steps) - 1, 7):
            q, q_next = steps[k].q, steps[k + 1].q
            root = r.frame_pose(q_next, limb.root)
            tip = r.frame_pose(q_next, r.hand_frames[s])
            for dp, q_prev in ((np.zeros(3), q[cols]), (rng.normal(0, 0.01, 3), q[cols] + rng.normal(0, 0.05, 7)),
                               (np.array([2.0, 0.0, 0.0]), q[cols])):
                args = (root.translation, root.rotation, tip.translation + dp, tip.rotation, q_prev)
                (code, qc), (code_ref, q_ref) = tracker.solve(*args), tracker.solve_reference(*args)
                assert code == code_ref, (s, k, dp)
                if code == 0:
                    np.testing.assert_allclose(qc, q_ref, atol=1e-9, rtol=0)
                compared["ok" if code == 0 else "failed"] += 1
        bad = (root.translation, root.rotation, np.array([np.nan, 0.0, 0.0]), tip.rotation, q[cols])
        assert tracker.solve(*bad)[0] == tracker.solve_reference(*bad)[0] != 0
    assert compared["ok"] > 40 and compared["failed"] > 10, compared
