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
    ORIENTATION_BINS, InverseReach, ReachMap, decode_rpy, encode_rpy, orientation_bins,
)
from humanoid_reach_ros.planning.trunk_region import TrunkRegion
from humanoid_reach_ros.planning.wgr import WorkspaceGoalRegion, rpy_matrix, valve_region
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


def test_the_map_proposes_goal_samples_in_the_region_that_the_ik_solves_more_often(setup):
    """``TrunkSampler.sample_poses`` (the capability map's proposals): every sample lies in the
    region and in a trunk cell of the inverse, and Algorithm 1 solves far more of them than
    of the plain draw (a hand pose from the region, a trunk from the same cells)."""
    robot, projector, region, inv = setup
    rng = np.random.default_rng(5)
    target = valve_region((0.45, -0.25, 0.75))
    msg, cells, _ = inv.for_target(target, ("right",))
    assert msg is None and len(cells)
    trunk = region.from_cells(cells, inv.droll, inv.dyaw, inv.proposals, 16)
    n = 600
    p_e, R_e, z, rpy = trunk.sample_poses(rng, target, n, "right")
    assert np.all(target.contains(p_e, R_e, tol=1e-6))
    assert np.all(np.any(np.all(np.abs(cells[None, :, :] - np.column_stack([z, rpy])[:, None, :])
                                <= inv.half + 1e-9, axis=2), axis=1))
    proposed = projector.project_config(p_e, R_e, z, rpy, arm="right").ok.mean()
    p0, R0 = target.sample(rng, n)
    z0, rpy0 = trunk.sample(rng, n)
    plain = projector.project_config(p0, R0, z0, rpy0, arm="right").ok.mean()
    assert proposed >= 0.15 and proposed >= 3 * plain, (proposed, plain)


def test_orientation_bins_cover_and_separate():
    rng = np.random.default_rng(0)
    R = rpy_matrix(rng.uniform(-math.pi, math.pi, size=(20000, 3)))
    b = orientation_bins(R)
    assert b.min() >= 0 and b.max() < ORIENTATION_BINS and len(np.unique(b)) == ORIENTATION_BINS
    # a half turn about the hand's own z axis changes the bin, the z cell stays
    flip = R @ np.diag([-1.0, -1.0, 1.0])
    b2 = orientation_bins(flip)
    assert np.all(b // 4 == b2 // 4) and np.all(b != b2)
    # the stored orientations: within half a step of 2 pi / 256
    rpy = rng.uniform(-math.pi, math.pi, size=(1000, 3))
    d = np.angle(np.exp(1j * (decode_rpy(encode_rpy(rpy)) - rpy)))
    assert np.abs(d).max() <= math.pi / 256 + 1e-12


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
