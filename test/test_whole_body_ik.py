"""Lower-body IK (Algorithm 3), the proposed whole-body step and the full-body LM baseline."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from humanoid_reach_ros.reach.kinematics import HandTargets
from humanoid_reach_ros.reach.whole_body_ik import (
    FullBodyLMIK, LegTargets, LowerBodyIK, ProposedWholeBodyIK, lowered_initial_posture,
)
from humanoid_reach_ros.robot.model import N_BASE_Q, RobotModel


@pytest.fixture(scope="module")
def robot():
    return RobotModel()


@pytest.fixture(scope="module")
def q0(robot):
    return lowered_initial_posture(robot, 0.08)


def _legs(robot, com):
    _, l_ = robot.stance_soles
    return LegTargets(np.asarray(com, float), np.eye(3), l_.translation, l_.rotation)


@pytest.mark.parametrize("dcom", [(0, 0, 0.1), (0, 0, -0.1), (0.02, 0.01, -0.05)])
def test_algorithm3_reaches_com_keeps_feet(robot, q0, dcom):
    low = LowerBodyIK(robot, max_iter=100)
    r_sole, l_sole = robot.stance_soles
    com = robot.com(q0) + np.array(dcom)
    res = low.solve(q0, _legs(robot, com), r_sole)
    assert res.converged
    q = res.q
    assert np.linalg.norm(robot.com(q) - com) < 1e-6
    for frame, ref in (("r_sole", r_sole), ("l_sole", l_sole)):
        M = robot.frame_pose(q, frame)
        assert np.linalg.norm(pin.log6(ref.inverse() * M).vector) < 1e-6
    assert np.linalg.norm(pin.log3(RobotModel.base_pose(q).rotation)) < 1e-6   # waist upright
    upper = np.setdiff1d(np.arange(N_BASE_Q, robot.model.nq), N_BASE_Q + low.leg_index)
    np.testing.assert_array_equal(q[upper], q0[upper])


def _hands_from(robot, q):
    r = robot.frame_pose(q, "r_hand_ee")
    l_ = robot.frame_pose(q, "l_hand_ee")
    return HandTargets.make(r.translation, r.rotation, l_.translation, l_.rotation)


def test_proposed_step_exact_hands(robot, q0):
    """Targets from FK of a posture with the same chest: closed-form arms hit them exactly."""
    ik = ProposedWholeBodyIK(robot)
    rng = np.random.default_rng(4)
    r_sole, _ = robot.stance_soles
    for _ in range(3):
        q = q0.copy()
        cols = np.concatenate([ik.arm_cols["right"], ik.arm_cols["left"]])
        q[cols] += rng.uniform(-0.3, 0.3, len(cols))
        q[cols] = np.clip(q[cols], robot.lower[cols - N_BASE_Q], robot.upper[cols - N_BASE_Q])
        hands = _hands_from(robot, q)
        chest = np.array([q[ik.chest_pitch], q[ik.chest_yaw]])
        res = ik.step(q0, hands, chest, _legs(robot, robot.com(q0)), r_sole)
        assert res.ok, res.reason
        assert res.hand_error < 1e-9
        # Algorithm 3 places the CoM with the previous arms; a 0.3 rad arm jump then moves it by mm
        assert res.com_error < 2e-2
        assert res.com_error == pytest.approx(np.linalg.norm(robot.com(res.q) - robot.com(q0)), abs=1e-12)
        assert np.all(np.isfinite(res.q))


def test_proposed_unreachable_clear_failure_no_nan(robot, q0):
    ik = ProposedWholeBodyIK(robot)
    r_sole, _ = robot.stance_soles
    hands = HandTargets.make([1.5, -0.2, 1.0], np.eye(3), [0.3, 0.2, 1.0], np.eye(3))
    res = ik.step(q0, hands, np.zeros(2), _legs(robot, robot.com(q0)), r_sole)
    assert not res.ok and "right arm" in res.reason
    assert np.all(np.isfinite(res.q))
    np.testing.assert_array_equal(res.q[ik.arm_cols["right"]], q0[ik.arm_cols["right"]])


def test_full_body_lm_baseline_converges(robot, q0):
    lm = FullBodyLMIK(robot, max_iter=200)
    r_sole, _ = robot.stance_soles
    q = q0.copy()
    q[N_BASE_Q + np.array(robot.limbs["right_arm"].joint_index)] += 0.15
    q[N_BASE_Q + robot.joint_index["CHEST_JOINT1"]] = 0.1
    hands = _hands_from(robot, q)
    res = lm.step(q0, hands, _legs(robot, robot.com(q0)), r_sole)
    assert res.ok, res.reason
    assert res.hand_error < 1e-6 and res.com_error < 1e-6
    assert np.linalg.norm(pin.log6(r_sole.inverse() * robot.frame_pose(res.q, "r_sole")).vector) < 1e-9


def test_bad_arguments(robot):
    with pytest.raises(ValueError, match="support"):
        LowerBodyIK(robot, support="middle")
    with pytest.raises(ValueError, match="initial_com_drop_m"):
        lowered_initial_posture(robot, float("nan"))
