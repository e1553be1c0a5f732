"""Algorithm 1 (batched): feet on the stance, hand in the WGR, limits, COG_approx fixed."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from humanoid_reach_ros.planning.goal_sampler import TrunkSampling
from humanoid_reach_ros.codes import ARM_LEFT as LEFT, ARM_NONE as NONE, ARM_RIGHT as RIGHT
from humanoid_reach_ros.planning.projector import Projector, quat_xyzw_from_rpy
from humanoid_reach_ros.planning.wgr import rpy_matrix, valve_region


@pytest.fixture(scope="module")
def projector(robot):
    return Projector(robot)


@pytest.fixture(scope="module")
def projected(projector):
    rng = np.random.default_rng(0)
    reg = valve_region()
    p, R = reg.sample(rng, 6000)
    z, rpy = TrunkSampling().sample(rng, 6000)
    return reg, p, R, z, rpy, projector.project_config(p, R, z, rpy)


def test_reference_posture(robot, projector):
    q0 = robot.half_sitting()
    np.testing.assert_allclose(projector.cog_approx(q0), robot.com(q0), atol=1e-12)
    p_t, R_t = projector.trunk_pose(q0[2], np.zeros(3))
    np.testing.assert_allclose(p_t[0], q0[:3], atol=1e-12)


def test_quaternion_matches_rpy():
    rpy = np.array([0.1, -0.3, 0.7])
    qx = quat_xyzw_from_rpy(rpy)
    R = pin.Quaternion(qx[3], *qx[:3]).toRotationMatrix()
    np.testing.assert_allclose(R, rpy_matrix(rpy), atol=1e-14)


def test_ok_goals_are_consistent(robot, projector, projected):
    reg, p, R, z, rpy, res = projected
    ok = np.flatnonzero(res.ok)
    assert len(ok) > 20
    assert set(np.unique(res.arm[ok])) <= {RIGHT, LEFT} and np.all(res.arm[~res.ok] == NONE)
    r_sole, l_sole = robot.stance_soles
    for k in ok[:60]:
        q = res.q[k]
        assert robot.in_limits(q[7:], tol=1e-9)
        np.testing.assert_allclose(robot.frame_pose(q, "r_sole").homogeneous, r_sole.homogeneous, atol=1e-9)
        np.testing.assert_allclose(robot.frame_pose(q, "l_sole").homogeneous, l_sole.homogeneous, atol=1e-9)
        hand = robot.frame_pose(q, "r_hand_ee" if res.arm[k] == RIGHT else "l_hand_ee")
        np.testing.assert_allclose(hand.translation, p[k], atol=1e-9)
        np.testing.assert_allclose(hand.rotation, R[k], atol=1e-9)
        assert reg.contains(hand.translation, hand.rotation, tol=1e-7)
        # trunk: height and orientation as sampled, COG_approx horizontally fixed
        base = robot.frame_pose(q, robot.base_link)
        assert base.translation[2] == pytest.approx(z[k], abs=1e-12)
        np.testing.assert_allclose(base.rotation, rpy_matrix(rpy[k]), atol=1e-12)
        # fixed joints at the reference
        for name in ("CHEST_JOINT0", "CHEST_JOINT1", "HEAD_JOINT0", "RARM_JOINT6", "LARM_JOINT6"):
            i = 7 + robot.joint_index[name]
            assert q[i] == projector.q_ref[i]
    np.testing.assert_allclose(projector.cog_approx(res.q[ok])[:, :2], np.tile(projector.cog_approx_xy, (len(ok), 1)),
                               atol=1e-12)


def test_failure_counts_follow_algorithm_1(projected):
    reg, p, R, z, rpy, res = projected
    f = res.failures
    n = len(res.ok)
    # right arm tried on all, left on the right failures, legs on the arm successes
    assert f["right_arm"] <= n and f["left_arm"] <= f["right_arm"]
    arm_ok = n - f["left_arm"]
    assert res.ok.sum() == arm_ok - f["right_leg"] - f["left_leg"]


def test_forced_arm(projector, projected):
    reg, p, R, z, rpy, res = projected
    left = projector.project_config(p, R, z, rpy, arm="left")
    assert set(np.unique(left.arm[left.ok])) <= {LEFT}
    assert left.failures["right_arm"] == 0
    with pytest.raises(ValueError):
        projector.project_config(p, R, z, rpy, arm="both")


def test_plan_config_round_trip(robot, projector, projected):
    reg, p, R, z, rpy, res = projected
    k = np.flatnonzero(res.ok & (res.arm == RIGHT))[:20]
    q_plan = projector.plan_config_of(res.q[k], "right")
    back = projector.project_plan_config(q_plan, "right")
    assert back.ok.all()
    np.testing.assert_allclose(back.q, res.q[k], atol=1e-9)
    # out-of-limit arm joints are rejected
    bad = q_plan.copy()
    bad[0, 0] = 10.0
    out = projector.project_plan_config(bad, "right")
    assert not out.ok[0] and out.failures["arm_limits"] == 1


@pytest.mark.parametrize("arm", ["right", "left"])
def test_compiled_plan_projection_matches_numpy_reference(robot, projector, arm):
    """project_plan_config's fused numba kernel == the numpy path (LimbIKSet(compiled=False)):
    same ok rows and failure counts, configurations within 1e-12 (1e-9 near a stretched
    knee, see test_limb_ik), trunk poses within 1e-12; also for NaN rows, arm joints
    outside their limits and trunk heights the legs cannot reach."""
    from humanoid_reach_ros.kinematics.registry import LimbIKSet

    ref = Projector(robot, ik=LimbIKSet(robot, compiled=False))
    assert projector.compiled and not ref.compiled
    ji = list(robot.limbs[f"{arm}_arm"].joint_index)
    lo = np.concatenate([robot.lower[ji] - 0.1, [0.45, -0.2, -0.2, -0.5]])
    hi = np.concatenate([robot.upper[ji] + 0.1, [0.85, 0.2, 0.7, 0.5]])
    rng = np.random.default_rng(21)
    X = lo + rng.random((4000, 10)) * (hi - lo)
    X[3, 7] = np.nan
    X[4, 0] = np.inf
    X[5, 6] = 2.0          # trunk far above the feet: legs unreachable
    for rows in (X, X[:1], X[10:13]):
        a = projector.project_plan_config(rows, arm)
        b = ref.project_plan_config(rows, arm)
        assert np.array_equal(a.ok, b.ok) and np.array_equal(a.arm, b.arm)
        assert a.failures == b.failures
        fin = np.isfinite(rows).all(axis=1)
        np.testing.assert_allclose(a.trunk_p[fin], b.trunk_p[fin], rtol=0, atol=1e-12)
        np.testing.assert_allclose(a.trunk_R[fin], b.trunk_R[fin], rtol=0, atol=1e-12)
        if a.ok.any():
            diff = np.abs(a.q[a.ok] - b.q[a.ok]).max(axis=1)
            assert diff.max() <= 1e-9
            assert np.mean(diff <= 1e-12) >= (0.999 if len(diff) >= 1000 else 1.0)
    full = projector.project_plan_config(X, arm)
    f = full.failures
    assert full.ok.mean() > 0.2 and f["arm_limits"] > 100 and f["right_leg"] + f["left_leg"] > 0


@pytest.mark.parametrize("arm", ["auto", "right", "left"])
def test_project_config_matches_unfiltered_per_arm_solves(robot, projector, projected, arm):
    """project_config skips the arm IK on rows maybe_reachable rejects: the result must be
    the one of Algorithm 1 solving every row (arms tried in order, then both legs)."""
    reg, p, R, z, rpy, _ = projected
    n = 1500
    p, R, z, rpy = p[:n], R[:n], z[:n], rpy[:n]
    res = projector.project_config(p, R, z, rpy, arm=arm)
    p_t, R_t = projector.trunk_pose(z, rpy)
    c_p, c_R = projector.chest_pose(p_t, R_t)
    order = {"auto": ("right_arm", "left_arm"), "right": ("right_arm",), "left": ("left_arm",)}[arm]
    todo = np.arange(n)
    q_arm = np.full((n, 6), np.nan)
    used = np.full(n, NONE)
    fails = {"right_arm": 0, "left_arm": 0}
    for name in order:
        r = projector.ik.solve(name, c_p[todo], c_R[todo], p[todo], R[todo])
        fails[name] = int(np.count_nonzero(~r.ok))
        q_arm[todo[r.ok]] = r.q[r.ok]
        used[todo[r.ok]] = RIGHT if name == "right_arm" else LEFT
        todo = todo[~r.ok]
    for name in ("right_arm", "left_arm"):
        assert res.failures[name] == fails[name]
    arm_ok = used != NONE
    assert np.all(res.ok <= arm_ok)
    for code, name in ((RIGHT, "right_arm"), (LEFT, "left_arm")):
        k = np.flatnonzero(res.ok & (used == code))
        assert np.all(res.arm[k] == code)
        np.testing.assert_array_equal(res.q[k][:, projector.cols[name]], q_arm[k])
    assert res.failures["right_leg"] + res.failures["left_leg"] == np.count_nonzero(arm_ok) - res.ok.sum()
