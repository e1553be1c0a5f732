"""Goal sampling: determinism, Table I statistics, goals valid."""
from __future__ import annotations

import numpy as np
import pytest

from humanoid_reach_ros.geometry.distance import RobotCollision
from humanoid_reach_ros.geometry.sphere_tree import SphereTree
from humanoid_reach_ros.planning.goal_sampler import TrunkSampling, cog_errors, sample_goals
from humanoid_reach_ros.codes import ARM_LEFT as LEFT, ARM_RIGHT as RIGHT
from humanoid_reach_ros.planning.projector import Projector
from humanoid_reach_ros.planning.wgr import valve_region
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.shapes import load_collision_model
from humanoid_reach_ros.sim.scene import load_scene


@pytest.fixture(scope="module")
def env():
    robot = RobotModel()
    cm = load_collision_model(None, robot)
    scene = load_scene("scenes/plant.yaml")
    tree = SphereTree.from_voxels(scene.voxelize(0.02, exclude_groups=("valve",)), 0.02)
    return robot, RobotCollision(robot, cm, tree), Projector(robot), valve_region(scene.target.pose)


def test_deterministic_and_valid(env):
    robot, rc, pr, reg = env
    a = sample_goals(reg, 12, robot, rc, np.random.default_rng(7), projector=pr, batch_size=256)
    b = sample_goals(reg, 12, robot, rc, np.random.default_rng(7), projector=pr, batch_size=256)
    assert len(a) == 12
    np.testing.assert_array_equal(a.q, b.q)
    np.testing.assert_array_equal(a.arm, b.arm)
    assert a.stats.n_samples == b.stats.n_samples and a.stats.ik_failures == b.stats.ik_failures
    assert rc.check_batch(a.q).all()
    for q in a.q:
        assert robot.in_limits(q[7:], tol=1e-9)
    assert reg.contains(a.p_e, a.R_e).all()
    for q, arm, p in zip(a.q, a.arm, a.p_e):
        hand = robot.frame_pose(q, "r_hand_ee" if arm == RIGHT else "l_hand_ee")
        np.testing.assert_allclose(hand.translation, p, atol=1e-9)


def test_stats_consistency(env):
    robot, rc, pr, reg = env
    g = sample_goals(reg, 15, robot, rc, np.random.default_rng(3), projector=pr, batch_size=300)
    s = g.stats
    f = s.ik_failures
    assert s.n_goals == 15 == s.arm_used["right"] + s.arm_used["left"]
    assert s.arm_used["right"] == int(np.sum(g.arm == RIGHT)) and s.arm_used["left"] == int(np.sum(g.arm == LEFT))
    ik_ok = s.n_samples - f["left_arm"] - f["right_leg"] - f["left_leg"]
    assert s.collision_checks == ik_ok
    assert s.collision_checks - s.n_in_collision == s.n_goals
    assert f["left_arm"] <= f["right_arm"] <= s.n_samples
    assert s.time_per_goal_s > 0 and 0 < s.collision_time_per_call_s < 1e-3
    d = s.as_dict()
    assert d["n_samples"] == s.n_samples and "ik_failures" in d
    # the last sample drawn is the last goal (stats stop there)
    err = cog_errors(g.q, robot, pr)
    assert err.shape == (15, 2) and np.all(np.abs(err) < 0.2)


def test_forced_arm_budget_and_trunk_ranges(env):
    robot, rc, pr, reg = env
    g = sample_goals(reg, 3, robot, rc, np.random.default_rng(1), arm="left", projector=pr)
    assert np.all(g.arm == LEFT) and g.stats.ik_failures["right_arm"] == 0
    t = sample_goals(reg, 1000, robot, rc, np.random.default_rng(1), projector=pr, time_budget_s=0.0)
    assert t.stats.timed_out and len(t) == 0
    m = sample_goals(reg, 1000, robot, rc, np.random.default_rng(1), projector=pr, max_samples=600, batch_size=300)
    assert m.stats.timed_out and m.stats.n_samples == 600
    with pytest.raises(ValueError):
        TrunkSampling(z_t=(0.8, 0.5))
    trunk = TrunkSampling(z_t=(0.65, 0.65), roll=(0, 0), pitch=(0.5, 0.5), yaw=(0, 0))
    g2 = sample_goals(reg, 2, robot, rc, np.random.default_rng(2), projector=pr, trunk=trunk, time_budget_s=20.0)
    assert len(g2) == 2
    np.testing.assert_allclose(g2.q[:, 2], 0.65)
