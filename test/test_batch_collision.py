"""BatchCollision (SIMD lanes) == RobotCollision, configuration for configuration."""
from __future__ import annotations

import math

import numpy as np
import pytest

from humanoid_reach_ros.geometry.batch_collision import LANES, BatchCollision, _field_lb, _sincos_lanes, batch_checker
from humanoid_reach_ros.geometry.distance import RobotCollision
from humanoid_reach_ros.geometry.sphere_tree import SphereTree
from humanoid_reach_ros.robot.model import N_BASE_Q, RobotModel
from humanoid_reach_ros.robot.shapes import load_collision_model


@pytest.fixture(scope="module")
def voxels():
    from humanoid_reach_ros.sim.scene import load_scene

    return load_scene("scenes/plant.yaml").voxelize(0.02, exclude_groups=("valve",))


def _checker(name: str, voxels: np.ndarray, **kw) -> RobotCollision:
    robot = RobotModel(name)
    return RobotCollision(robot, load_collision_model(None, robot), SphereTree.from_voxels(voxels, 0.02), **kw)


def _configs(robot: RobotModel, n: int, seed: int) -> np.ndarray:
    """Half uniform in the joint limits (mostly colliding), half near the half-sitting
    posture (mostly free); the base is turned and moved a little."""
    rng = np.random.default_rng(seed)
    Q = np.tile(robot.half_sitting(), (n, 1))
    lo, hi = robot.lower, robot.upper
    k = n // 2
    Q[:k, N_BASE_Q:] = lo + rng.random((k, robot.n_joints)) * (hi - lo)
    Q[k:, N_BASE_Q:] = np.clip(Q[k:, N_BASE_Q:] + rng.normal(scale=0.4, size=(n - k, robot.n_joints)), lo, hi)
    Q[:, :2] += rng.normal(scale=0.05, size=(n, 2))
    yaw = rng.normal(scale=0.3, size=n)
    Q[:, 3:7] = np.column_stack([np.zeros(n), np.zeros(n), np.sin(yaw / 2), np.cos(yaw / 2)])
    return Q


@pytest.mark.parametrize("name,n", [("hrp2", 20000), ("talos", 4000), ("g1", 4000)])
def test_verdicts_identical(voxels, name, n):
    col = _checker(name, voxels)
    bc = BatchCollision(col)
    Q = _configs(col.robot, n, seed=len(name))
    ref = col.check_batch(Q)
    got = bc.check_batch(Q)                  # one call: the lazy field is not built yet (tree only)
    assert bc._field is None
    assert 0.05 < ref.mean() < 0.95          # both answers well represented
    np.testing.assert_array_equal(got, ref)
    bc.field_args()                          # now with the distance field's broad phase
    np.testing.assert_array_equal(bc.check_batch(Q), ref)
    # first_collision on slices that start and end inside blocks
    rng = np.random.default_rng(1)
    for _ in range(200):
        i = int(rng.integers(0, n))
        j = int(rng.integers(i, min(n, i + 40) + 1))
        assert bc.first_collision(Q[i:j]) == col.first_collision(Q[i:j])


def test_self_margin_empty_tree_and_large_angles(voxels):
    col = _checker("hrp2", voxels, self_margin_m=0.02)
    Q = _configs(col.robot, 2000, seed=5)
    np.testing.assert_array_equal(BatchCollision(col).check_batch(Q), col.check_batch(Q))
    empty = RobotCollision(col.robot, col.cm, SphereTree.build(np.zeros((0, 3)), 0.0))
    np.testing.assert_array_equal(BatchCollision(empty).check_batch(Q), empty.check_batch(Q))
    Q[3, N_BASE_Q] += 2e3 * math.pi      # same posture, outside the lanes' trigonometry range
    np.testing.assert_array_equal(BatchCollision(col).check_batch(Q), col.check_batch(Q))
    assert batch_checker(col) is batch_checker(col)


def test_lane_trigonometry_and_field_bound(voxels):
    x = np.concatenate([np.linspace(-40.0, 40.0, 8 * 997), [0.0, math.pi / 4, -math.pi / 2, math.pi, 7.0, -3.0,
                                                            1e-300, 999.0]])
    QT = np.ascontiguousarray(x.reshape(-1, LANES))
    SN = np.empty_like(QT)
    CS = np.empty_like(QT)
    _sincos_lanes(QT, np.arange(len(QT)), SN, CS)
    assert np.max(np.abs(SN - np.sin(QT))) < 1e-13 and np.max(np.abs(CS - np.cos(QT))) < 1e-13
    # the field never exceeds the true distance to the spheres' surface, in and outside its grid
    col = _checker("hrp2", voxels)
    field = BatchCollision(col).field_args()
    rng = np.random.default_rng(2)
    lo, hi = voxels.min(0) - 1.0, voxels.max(0) + 1.0
    P = lo + rng.random((3000, 3)) * (hi - lo)
    f, origin, cell, box_lo, box_hi, r_max = field
    lb = np.array([_field_lb(f, origin, 1.0 / cell, box_lo, box_hi, r_max, *p) for p in P])
    true = np.array([col.tree.min_distance(p, p, 0.0) for p in P])
    assert np.all(lb <= true) and np.mean(true - lb < 0.15) > 0.5


def test_bad_input(voxels):
    bc = BatchCollision(_checker("hrp2", voxels))
    q = bc.collision.robot.half_sitting()
    with pytest.raises(ValueError, match="shape"):
        bc.check_batch(np.zeros((3, 5)))
    Q = np.tile(q, (3, 1))
    Q[1, 10] = np.nan
    with pytest.raises(ValueError, match="finite"):
        bc.check_batch(Q)
    with pytest.raises(ValueError, match="field_cell_m"):
        BatchCollision(bc.collision, field_cell_m=0.0)
    assert bc.check_batch(q).shape == (1,) and bc.first_collision(np.zeros((0, len(q)))) == 0
