"""RobotCollision: numba FK vs pinocchio, environment checks vs brute force, self-collision."""
from __future__ import annotations

import math

import numpy as np
import pytest

from humanoid_reach_ros.geometry.distance import RobotCollision
from humanoid_reach_ros.geometry.sphere_tree import SphereTree
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.shapes import load_collision_model, point_segment_distance
from humanoid_reach_ros.sim.scene import load_scene


@pytest.fixture(scope="module")
def setup():
    robot = RobotModel()
    cm = load_collision_model(None, robot)
    voxels = load_scene("scenes/plant.yaml").voxelize(0.02, exclude_groups=("valve",))
    tree = SphereTree.from_voxels(voxels, 0.02)
    return robot, cm, tree, RobotCollision(robot, cm, tree)


def random_configs(robot: RobotModel, rng: np.random.Generator, n: int) -> np.ndarray:
    """Joints uniform in limits, base near half-sitting (small tilt, shifted towards the plant)."""
    q0 = robot.half_sitting()
    Q = np.repeat(q0[None], n, axis=0)
    Q[:, 7:] = rng.uniform(robot.lower, robot.upper, (n, robot.n_joints))
    Q[:, :3] += rng.uniform([-0.1, -0.2, -0.2], [0.25, 0.2, 0.05], (n, 3))
    quat = np.c_[rng.normal(0, 0.15, (n, 3)), np.ones(n)]
    Q[:, 3:7] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    return Q


def brute_env(cm, tree, P0, P1) -> tuple[bool, float]:
    """Min signed distance of the shapes to all environment spheres, in plain numpy."""
    best = math.inf
    for s in range(len(P0)):
        d, _ = point_segment_distance(tree.centers, P0[s], P1[s])
        best = min(best, float(np.min(d - tree.radii - cm.radii[s])))
    return best < 0.0, best


def test_fk_matches_pinocchio(setup):
    robot, cm, tree, rc = setup
    for q in random_configs(robot, np.random.default_rng(0), 20):
        P0, P1 = rc.world_shapes(q)
        A0, A1 = rc.world_shapes_pin(q)
        np.testing.assert_allclose(P0, A0, atol=1e-12)
        np.testing.assert_allclose(P1, A1, atol=1e-12)


def test_env_check_matches_brute_force(setup):
    robot, cm, tree, rc = setup
    Q = random_configs(robot, np.random.default_rng(1), 40)
    env = rc.in_collision_env(Q)
    n_hit = 0
    for q, hit in zip(Q, env):
        P0, P1 = rc.world_shapes(q)
        want, dmin = brute_env(cm, tree, P0, P1)
        assert hit == want
        assert rc.in_collision_env(q) == want
        assert rc.min_distance(q) == pytest.approx(dmin, abs=1e-12)
        n_hit += want
    assert 0 < n_hit < len(Q)   # both outcomes exercised


def test_self_check_matches_numpy_model(setup):
    robot, cm, tree, rc = setup
    Q = random_configs(robot, np.random.default_rng(2), 300)
    got = rc.in_self_collision(Q)
    want = np.array([cm.in_self_collision_at(q) for q in Q])
    np.testing.assert_array_equal(got, want)
    assert 0 < want.sum() < len(Q)
    q = Q[0]
    assert rc.self_min_distance(q) == pytest.approx(float(cm.self_distances_at(q).min()), abs=1e-12)


def test_crafted_self_collision_and_half_sitting(setup):
    robot, cm, tree, rc = setup
    q0 = robot.half_sitting()
    assert not rc.in_self_collision(q0)
    assert not rc.in_collision_env(q0)
    assert rc.check(q0)
    j = robot.half_sitting_joints.copy()
    for name, deg in (("RARM_JOINT0", -90), ("RARM_JOINT1", 60), ("RARM_JOINT3", -100)):  # arm across the chest
        j[robot.joint_index[name]] = np.radians(deg)
    q = robot.config(j, robot.base_on_feet(j))
    assert rc.in_self_collision(q)
    assert not rc.check(q)
    assert rc.self_min_distance(q) < 0.0


def test_check_batch_and_counters(setup):
    robot, cm, tree, rc = setup
    Q = random_configs(robot, np.random.default_rng(3), 100)
    rc.reset_counters()
    valid = rc.check_batch(Q)
    assert rc.counters.checks == 100 and rc.counters.calls == 1
    assert rc.counters.check_time_s > 0.0 and rc.counters.fk_time_s > 0.0
    env = rc.in_collision_env(Q)
    slf = rc.in_self_collision(Q)
    np.testing.assert_array_equal(valid, ~(env | slf))
    assert [rc.check(q) for q in Q[:10]] == valid[:10].tolist()


def test_empty_tree_and_bad_shape(setup):
    robot, cm, tree, rc = setup
    empty = RobotCollision(robot, cm, SphereTree.build(np.empty((0, 3)), 0.01))
    q0 = robot.half_sitting()
    assert empty.check(q0) and empty.min_distance(q0) == math.inf
    with pytest.raises(ValueError):
        rc.check_batch(np.zeros((3, 5)))


def test_first_collision_is_the_first_invalid_of_check_batch(setup):
    """first_collision (FK + tests config by config, stopping at the first hit) agrees
    with check_batch on every prefix; counters count the configurations examined."""
    robot, cm, tree, col = setup
    rng = np.random.default_rng(17)
    Q = random_configs(robot, rng, 400)
    ok = col.check_batch(Q)
    assert 0 < ok.sum() < len(ok)
    free = Q[ok]
    for start in range(0, 400, 7):
        rows = Q[start:start + 25]
        expect = len(rows) if col.check_batch(rows).all() else int(np.argmin(col.check_batch(rows)))
        before = col.counters.checks
        assert col.first_collision(rows) == expect
        assert col.counters.checks - before == min(expect + 1, len(rows))
    assert col.first_collision(free[:30]) == 30
    assert col.first_collision(np.vstack([free[:5], Q[~ok][:1], free[5:9]])) == 5
    assert col.first_collision(Q[:0]) == 0
    with pytest.raises(ValueError):
        col.first_collision(np.zeros((3, 5)))
