"""Lower-body IK (Algorithm 3), the proposed whole-body step and the full-body LM baseline."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from humanoid_reach_ros.dual_arm.targets import HandTargets
from humanoid_reach_ros.dual_arm.whole_body_ik import (
    FullBodyLMIK, LegTargets, LowerBodyIK, ProposedWholeBodyIK, lowered_initial_posture,
)
from humanoid_reach_ros.robot.model import N_BASE_Q, RobotModel


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


# ---------------------------------------------------------------- fast paths == reference
def test_closed_form_legs_equal_algorithm3(robot, q0):
    """ClosedFormLowerBodyIK (closed-form legs + Newton on the waist) returns Algorithm 3's
    solution: same configuration (to the LM tolerance), CoM, waist orientation and soles."""
    from humanoid_reach_ros.dual_arm.fast_legs import ClosedFormLowerBodyIK

    ref = LowerBodyIK(robot, max_iter=100)
    fast = ClosedFormLowerBodyIK(robot, max_iter=100)
    rng = np.random.default_rng(3)
    r_sole, l_sole = robot.stance_soles
    upper = np.arange(robot.model.nq - N_BASE_Q) < 18          # chest, head, arms
    compared = 0
    for _ in range(40):
        q = q0.copy()
        q[N_BASE_Q:] += np.where(upper, rng.uniform(-0.1, 0.1, robot.model.nq - N_BASE_Q), 0.0)
        com = robot.com(q0) + rng.uniform([-0.03, -0.03, -0.1], [0.03, 0.03, 0.1])
        a = ref.solve(q, _legs(robot, com), r_sole)
        b = fast.solve(q, _legs(robot, com), r_sole)
        assert np.all(np.isfinite(b.q))
        if not a.converged:
            continue
        compared += 1
        assert b.converged
        assert np.abs(pin.difference(robot.model, a.q, b.q)).max() < 1e-5
        assert np.linalg.norm(robot.com(b.q) - com) < 1e-7
        assert np.allclose(robot.frame_pose(b.q, "base_link").rotation, np.eye(3), atol=1e-9)
        for frame, sole in (("r_sole", r_sole), ("l_sole", l_sole)):
            M = robot.frame_pose(b.q, frame)
            assert np.linalg.norm(M.translation - sole.translation) < 1e-9
            assert np.abs(M.rotation - sole.rotation).max() < 1e-9
    assert compared >= 30
    assert fast.fallbacks == 0


def test_closed_form_legs_fall_back_when_out_of_reach(robot, q0):
    """A CoM the legs cannot reach: the closed form fails and the numerical reference
    answers (not converged, finite angles) -- the same report as Algorithm 3."""
    from humanoid_reach_ros.dual_arm.fast_legs import ClosedFormLowerBodyIK

    fast = ClosedFormLowerBodyIK(robot)
    r_sole, _ = robot.stance_soles
    res = fast.solve(q0, _legs(robot, robot.com(q0) + [0.0, 0.0, 0.5]), r_sole)
    assert not res.converged and fast.fallbacks == 1
    assert np.all(np.isfinite(res.q))


@pytest.mark.parametrize("side", ["right_arm", "left_arm"])
def test_compiled_arm_ik_equals_reference(robot, side):
    """fast_arms.arm_ik_pose == LimbIK.solve_reference: same reason code and, when solved,
    the same angles to 1e-12 -- random reachable, perturbed (unreachable), random-orientation
    (joint-limit) poses and exact singular ones (stretched arm, shoulder roll at +-90 deg)."""
    from humanoid_reach_ros.kinematics.hand_derived_compiled import CompiledArmIK
    from humanoid_reach_ros.kinematics.hand_derived import LimbIK

    limb = LimbIK(robot, side)
    fast = CompiledArmIK(limb)
    rng = np.random.default_rng(11)
    codes = set()
    cases = []
    for i in range(600):
        q = rng.uniform(limb.lower, limb.upper)
        if i % 7 == 0:
            q[3] = 0.0                                         # stretched arm
        if i % 11 == 0:
            q[1] = np.clip(np.copysign(np.pi / 2, q[1]), limb.lower[1], limb.upper[1])   # shoulder roll +-90 deg
        root_p, root_R = rng.normal(size=3) * 0.1, pin.exp3(rng.normal(size=3))
        p, R = limb.fk(root_p, root_R, q)
        p, R = p[0], R[0]
        if i % 3 == 0:
            p = p + rng.normal(size=3) * 0.2
        if i % 5 == 0:
            R = pin.exp3(rng.normal(size=3))
        ref = limb.q_default if i % 2 else rng.uniform(limb.lower, limb.upper)
        cases.append((root_p, root_R, p, R, ref))
    cases.append((np.zeros(3), np.eye(3), np.array([np.nan, 0.0, 0.0]), np.eye(3), limb.q_default))
    cases.append((np.zeros(3), np.eye(3), np.zeros(3), 2.0 * np.eye(3), limb.q_default))
    for root_p, root_R, p, R, ref in cases:
        a = limb.solve_reference(root_p, root_R, p, R, ref)
        code, q = fast.solve(root_p, root_R, p, R, ref)
        codes.add(code)
        assert code == int(a.reason[0])
        if code == 0:
            assert np.abs(q - a.q[0]).max() < 1e-12
        else:
            assert np.all(np.isnan(q))
    assert codes == {0, 1, 2, 3}


def test_proposed_step_fast_equals_reference_path(robot, q0):
    """ProposedWholeBodyIK with compiled legs + arms == with the numerical Algorithm 3 and
    the Python arm IK, along a short reaching motion."""
    fast = ProposedWholeBodyIK(robot)
    slow = ProposedWholeBodyIK(robot, closed_form_legs=False, compiled_arms=False)
    r_sole, _ = robot.stance_soles
    hands0 = _hands_from(robot, q0)
    qf, qs = q0.copy(), q0.copy()
    com0 = robot.com(q0)
    for k in range(1, 21):
        s = k / 20
        hands = HandTargets(hands0.p_right + s * np.array([0.05, 0.0, 0.04]), hands0.R_right,
                            hands0.p_left + s * np.array([0.04, 0.02, 0.03]), hands0.R_left)
        chest = s * np.array([0.05, 0.02])
        legs = _legs(robot, com0 + s * np.array([0.0, 0.0, -0.03]))
        a = fast.step(qf, hands, chest, legs, r_sole)
        b = slow.step(qs, hands, chest, legs, r_sole)
        assert a.ok and b.ok
        assert np.abs(pin.difference(robot.model, a.q, b.q)).max() < 1e-5
        assert a.hand_error < 1e-9
        qf, qs = a.q, b.q
