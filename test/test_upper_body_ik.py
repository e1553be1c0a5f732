"""Upper-body IK (dissertation Algorithm 1 with eq. 3-4, Algorithm 2 LM)."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from humanoid_reach_ros.dual_arm.targets import HandTargets, damped_pinv_apply
from humanoid_reach_ros.dual_arm.upper_body_ik import UpperBodyIK
from humanoid_reach_ros.robot.model import N_BASE_Q


@pytest.fixture(scope="module")
def ik(robot):
    return UpperBodyIK(robot)


def _targets_from(robot, q) -> HandTargets:
    r = robot.frame_pose(q, "r_hand_ee")
    l_ = robot.frame_pose(q, "l_hand_ee")
    return HandTargets.make(r.translation, r.rotation, l_.translation, l_.rotation)


def _reachable_cases(robot, ik, n=4, seed=3):
    """Targets from FK of random upper-body postures near half-sitting (reachable by construction)."""
    rng = np.random.default_rng(seed)
    q0 = robot.half_sitting()
    out = []
    for _ in range(n):
        q = q0.copy()
        q[ik.qcols] = np.clip(q[ik.qcols] + rng.uniform(-0.35, 0.35, len(ik.qcols)), ik.lower, ik.upper)
        out.append(_targets_from(robot, q))
    return q0, out


@pytest.mark.parametrize("weighted", [False, True])
def test_algorithm1_converges_on_fixed_targets(robot, ik, weighted):
    q0, cases = _reachable_cases(robot, ik)
    for t in cases:
        res = ik.solve_pinv(q0, t, weighted=weighted, tol=1e-9, max_iter=200)
        assert res.converged, res
        assert res.position_error < 1e-6
        j = res.q[N_BASE_Q:]
        assert np.all(np.isfinite(j)) and robot.in_limits(j, 1e-9)
        # legs, head, waist untouched
        untouched = np.setdiff1d(np.arange(robot.model.nq), ik.qcols)
        np.testing.assert_array_equal(res.q[untouched], q0[untouched])


def test_weighted_pinv_is_eq3(ik, robot):
    rng = np.random.default_rng(0)
    J = rng.normal(size=(12, 14))
    e = rng.normal(size=12)
    Winv = np.diag(ik.mobility)
    ref = Winv @ J.T @ np.linalg.solve(J @ Winv @ J.T, e)
    np.testing.assert_allclose(damped_pinv_apply(J, e, damping=0.0, mobility=ik.mobility), ref, atol=1e-9)
    np.testing.assert_allclose(damped_pinv_apply(J, e, damping=0.0), np.linalg.pinv(J) @ e, atol=1e-9)
    assert ik.mobility[0] == pytest.approx(0.1) and ik.mobility[1] == pytest.approx(0.1)
    assert np.all(ik.mobility[2:] == 1.0)


def test_weighted_moves_chest_less(robot, ik):
    """Sec. 5.1.3: the weighted pseudo-inverse restricts the chest."""
    q0 = robot.half_sitting()
    q = q0.copy()
    q[ik.qcols[:2]] = [0.3, 0.4]      # chest yaw / pitch used by the target posture
    t = _targets_from(robot, q)
    chest = {}
    for w in (False, True):
        res = ik.solve_pinv(q0, t, weighted=w, tol=1e-9, max_iter=300)
        assert res.converged
        chest[w] = np.linalg.norm(res.q[ik.qcols[:2]] - q0[ik.qcols[:2]])
    assert chest[True] < chest[False]


def test_lm_dataset_sample_and_unreachable(robot, ik):
    q0, cases = _reachable_cases(robot, ik, n=2, seed=11)
    for t in cases:
        chest, res = ik.generate_sample(q0, t)
        assert chest is not None and chest.shape == (2,) and res.converged
        assert res.position_error < 1e-5
    far = HandTargets.make([2.0, -0.3, 1.0], np.eye(3), [2.0, 0.3, 1.0], np.eye(3))
    chest, res = ik.generate_sample(q0, far, max_tries=2, max_iter=30)
    assert chest is None and not res.converged
    assert np.all(np.isfinite(res.q))
    assert res.omega == pytest.approx(2.0)       # omega increased once per failed try


@pytest.mark.parametrize("bad,msg", [
    (dict(p_right=[np.nan, 0, 1]), "finite"),
    (dict(p_right=[0, 1]), "shape"),
    (dict(R_left=np.ones((3, 3))), "rotation"),
    (dict(R_left=np.eye(2)), "shape"),
])
def test_bad_targets_raise(bad, msg):
    args = dict(p_right=[0.3, -0.2, 1.0], R_right=np.eye(3), p_left=[0.3, 0.2, 1.0], R_left=np.eye(3))
    args.update(bad)
    with pytest.raises(ValueError, match=msg):
        HandTargets.make(**args)


def test_bad_configuration_and_weight(robot, ik):
    t = HandTargets.make([0.3, -0.2, 1.0], np.eye(3), [0.3, 0.2, 1.0], np.eye(3))
    with pytest.raises(ValueError, match="q0"):
        ik.solve_pinv(np.zeros(5), t)
    q = robot.half_sitting()
    q[10] = np.nan
    with pytest.raises(ValueError, match="finite"):
        ik.solve_lm(q, t)
    with pytest.raises(ValueError, match="chest_weight"):
        UpperBodyIK(robot, chest_weight=0.0)


def test_rodrigues_interpolation_endpoints():
    from humanoid_reach_ros.dual_arm.targets import rodrigues_interpolate
    R0 = pin.utils.rpyToMatrix(0.1, -0.2, 0.3)
    R1 = pin.utils.rpyToMatrix(-0.5, 0.4, 1.0)
    np.testing.assert_allclose(rodrigues_interpolate(R0, R1, 0.0), R0, atol=1e-12)
    np.testing.assert_allclose(rodrigues_interpolate(R0, R1, 1.0), R1, atol=1e-12)
    Rm = rodrigues_interpolate(R0, R1, 0.5)
    # constant angular velocity: half the angle each way
    a = np.linalg.norm(pin.log3(R0.T @ Rm))
    b = np.linalg.norm(pin.log3(Rm.T @ R1))
    assert a == pytest.approx(b, abs=1e-12)
