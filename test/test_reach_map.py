"""The reach map (planning/reach_map.py): never a false "no" -- the map's inverse keeps the trunk
cell of every feasible goal, over the map's own training distribution and over random balanced
goals through the robot's own forward kinematics --, a bad map file answered clearly, and a
proof the sphere bound cannot make."""
from __future__ import annotations

import math

import numpy as np
import pytest

from humanoid_reach_ros.codes import ARMS
from humanoid_reach_ros.kinematics import Chain6, LimbIKSet
from humanoid_reach_ros.planning.projector import Projector
from humanoid_reach_ros.planning.reach_map import (
    ORIENTATION_BINS, InverseReach, ReachMap, orientation_bins,
)
from humanoid_reach_ros.planning.trunk_region import TrunkRegion
from humanoid_reach_ros.planning.wgr import WorkspaceGoalRegion, rpy_matrix
from humanoid_reach_ros.robot.model import RobotModel

ROBOTS = ("hrp2", "g1", "talos")


@pytest.fixture(scope="module", params=ROBOTS)
def setup(request):
    robot = RobotModel(request.param)
    projector = Projector(robot, LimbIKSet(robot))
    region = TrunkRegion(projector)
    inv = InverseReach(ReachMap.load(robot.spec.reach_map, robot), region)
    return robot, projector, region, inv


def _point_region(p: np.ndarray) -> WorkspaceGoalRegion:
    lo = np.array([0.0, 0.0, 0.0, -math.pi / 2, -math.pi / 2, -math.pi])
    return WorkspaceGoalRegion(np.asarray(p, float), np.eye(3), lo, -lo)


def _random_trunk(inv: InverseReach, rng, n: int, edge: bool) -> np.ndarray:
    """(n, 4) trunk poses (z, roll, pitch, yaw) in random cells of the searched manifold;
    ``edge``: at a random corner of the cell (where the bound's slack is spent)."""
    k = rng.integers(0, len(inv.cells), n)
    u = rng.choice([-1.0, 1.0], size=(n, 4)) if edge else rng.uniform(-1, 1, size=(n, 4))
    return inv.cells[k] + u * inv.half


def _kept(inv: InverseReach, cells: np.ndarray, trunk: np.ndarray) -> bool:
    return bool(np.any(np.all(np.abs(cells - trunk) <= inv.half + 1e-9, axis=1)))


def _check(inv: InverseReach, arm: str, trunk: np.ndarray, hand_p: np.ndarray) -> None:
    msg, cells, _ = inv.for_target(_point_region(hand_p), (arm,))
    assert msg is None, f"false 'no' for the {arm} hand at {hand_p} from trunk {trunk}: {msg}"
    assert _kept(inv, cells, trunk), f"the inverse dropped the cell of trunk {trunk} ({arm} hand at {hand_p})"


def test_never_a_false_no_over_the_training_distribution(setup):
    """Joint vectors drawn as the map's training draws them (uniform within the limits), and
    the limits' corners, from trunk poses at the corners of random cells."""
    robot, projector, _, inv = setup
    rng = np.random.default_rng(7)
    for arm in ARMS:
        spec = robot.limbs[f"{arm}_arm"]
        chain = Chain6.from_model(robot, spec.root, spec.joints, spec.tip)
        n = 40
        q = rng.uniform(chain.lower, chain.upper, size=(n, len(chain.axes)))
        q[:10] = np.where(rng.random((10, len(chain.axes))) < 0.5, chain.lower, chain.upper)
        tip, _ = chain.fk(q)
        trunk = _random_trunk(inv, rng, n, edge=True)
        p_t, R_t = projector.trunk_pose(trunk[:, 0], trunk[:, 1:])
        c_p, c_R = projector.chest_pose(p_t, R_t)
        hand = c_p + np.einsum("nij,nj->ni", c_R, tip)
        for i in range(n):
            _check(inv, arm, trunk[i], hand[i])


def test_never_a_false_no_for_random_balanced_goals(setup):
    """Random arm joints and trunk poses through Algorithm 1's planning-space projection (legs
    solved: a balanced posture), the hand placed by the robot model's own forward kinematics."""
    robot, projector, _, inv = setup
    rng = np.random.default_rng(11)
    for arm in ARMS:
        ji = np.array(robot.limbs[f"{arm}_arm"].joint_index)
        n = 60
        trunk = _random_trunk(inv, rng, n, edge=False)
        q_plan = np.concatenate([rng.uniform(robot.lower[ji], robot.upper[ji], size=(n, len(ji))),
                                 trunk[:, :1], trunk[:, 1:]], axis=1)
        res = projector.project_plan_config(q_plan, arm)
        assert res.ok.sum() >= 10, "too few balanced postures to test"
        tip = robot.limbs[f"{arm}_arm"].tip
        for i in np.flatnonzero(res.ok)[:25]:
            _check(inv, arm, trunk[i], robot.frame_pose(res.q[i], tip).translation)


def test_the_capability_filter_prefers_draws_the_map_holds(setup):
    """``CapabilityFilter.pick`` takes, per hand pose, the first candidate whose hand pose the
    map holds (the numpy ``ArmMap.capable`` of the same pose), else the pose's first draw."""
    _, projector, _, inv = setup
    rng = np.random.default_rng(3)
    n, k = 50, 4
    trunk = _random_trunk(inv, rng, n * k, edge=False)
    p_e = rng.uniform([0.1, -0.6, 0.5], [0.7, 0.6, 1.3], size=(n, 3))
    R_e = rpy_matrix(rng.uniform(-math.pi, math.pi, size=(n, 3)))
    pick = inv.capability.pick(trunk[:, 0].copy(), np.ascontiguousarray(trunk[:, 1:]), p_e, R_e, ARMS, k)
    p_t, R_t = projector.trunk_pose(trunk[:, 0], trunk[:, 1:])
    c_p, c_R = projector.chest_pose(p_t, R_t)
    idx = np.arange(n * k) % n
    x = np.einsum("nji,nj->ni", c_R, p_e[idx] - c_p)
    Rl = np.einsum("nji,njk->nik", c_R, R_e[idx])
    cap = np.zeros(n * k, bool)
    for arm in ARMS:
        cap |= inv.map.arms[arm].capable(x, Rl)
    for i in range(n):
        cands = [j * n + i for j in range(k)]
        held = [c for c in cands if cap[c]]
        assert pick[i] == (held[0] if held else i)
    assert 0 < cap.sum() < n * k


def test_orientation_bins_cover_and_separate():
    rng = np.random.default_rng(0)
    R = rpy_matrix(rng.uniform(-math.pi, math.pi, size=(20000, 3)))
    b = orientation_bins(R)
    assert b.min() >= 0 and b.max() < ORIENTATION_BINS and len(np.unique(b)) == ORIENTATION_BINS
    # a half turn about the hand's own z axis changes the bin, the z cell stays
    flip = R @ np.diag([-1.0, -1.0, 1.0])
    b2 = orientation_bins(flip)
    assert np.all(b // 4 == b2 // 4) and np.all(b != b2)


def test_a_bad_map_file_is_a_clear_error(tmp_path):
    robot = RobotModel("hrp2")
    with pytest.raises(ValueError, match="does not exist.*train_reach_map.py --robot hrp2"):
        ReachMap.load(tmp_path / "missing.npz", robot)
    bad = tmp_path / "corrupt.npz"
    bad.write_bytes(b"not a zip file at all")
    with pytest.raises(ValueError, match="not a readable map.*train_reach_map.py"):
        ReachMap.load(bad, robot)
    other = RobotModel("g1")
    with pytest.raises(ValueError, match="trained for right arm joints"):
        ReachMap.load(other.spec.reach_map, robot)
