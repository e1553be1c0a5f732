"""Trunk ranges from the robot and the target (planning/trunk_region.py): the leg grid,
the target band, the conditioned draw and the out-of-reach proof."""
from __future__ import annotations

import re

import numpy as np
import pytest

from humanoid_reach_ros.planning.projector import Projector
from humanoid_reach_ros.planning.trunk_region import TrunkRegion
from humanoid_reach_ros.planning.wgr import valve_region
from humanoid_reach_ros.robot.model import RobotModel


@pytest.fixture(scope="module")
def region_and_projector():
    projector = Projector(RobotModel())
    return TrunkRegion(projector), projector


def _leg_ok(projector, z, pitch, roll=0.0, yaw=0.0):
    q = np.zeros((len(z), 10))
    q[:, :6] = projector.q_ref[projector.cols["right_arm"]]
    q[:, 6], q[:, 7], q[:, 8], q[:, 9] = z, roll, pitch, yaw
    return projector.project_plan_config(q, "right").ok


def test_leg_grid_is_what_the_leg_ik_allows(region_and_projector):
    tr, projector = region_and_projector
    np.testing.assert_array_equal(_leg_ok(projector, tr.z_grid, tr.pitch_grid), tr.feasible)
    assert 0 < tr.feasible.sum() < len(tr.feasible)
    # the half-sitting trunk (0.74 m, upright) is inside, a stretched 0.83 m one is not
    s = tr.all_cells()
    assert s.z_range[0] < 0.5 and 0.74 < s.z_range[1] <= tr.trunk_z_max
    assert not _leg_ok(projector, np.array([tr.trunk_z_max + 0.01]), np.array([0.0]))[0]


def test_target_band_moves_the_trunk_toward_the_target(region_and_projector):
    tr, _ = region_and_projector
    low = tr.for_target(valve_region((0.45, -0.15, 0.20)))
    mid = tr.for_target(valve_region((0.71, 0.03, 0.90)))
    high = tr.for_target(valve_region((0.30, 0.0, 1.65)))
    assert low.narrowed and mid.narrowed and high.narrowed
    assert low.z_range[1] < mid.z_range[1] - 0.1          # a low target gets a low trunk
    assert high.z_range[0] > mid.z_range[0] + 0.05        # a high one a high trunk
    assert low.pitch_range[0] > 0.0                        # and a low one a forward lean
    for s in (low, mid, high):                            # only leg-feasible cells
        assert set(zip(s.z_cells, s.pitch_cells)) <= set(zip(tr.z_grid[tr.feasible], tr.pitch_grid[tr.feasible]))


def test_draws_stay_in_their_cells_and_start_near_the_start(region_and_projector):
    tr, _ = region_and_projector
    s = tr.for_target(valve_region((0.71, 0.03, 0.90))).near(0.74, 0.0)
    rng = np.random.default_rng(0)
    z, rpy = s.sample(rng, 4000, batch=0)
    first = s.order[:int(np.ceil(0.25 * len(s.order)))]
    cell = np.argmin(np.abs(z[:, None] - s.z_cells[None]) / s.dz + np.abs(rpy[:, 1:2] - s.pitch_cells[None]) / s.dpitch
                     + 1e9 * ~np.isin(np.arange(len(s.z_cells)), first)[None], axis=1)
    assert np.all(np.abs(z - s.z_cells[cell]) <= s.dz / 2 + 1e-12)
    assert np.all(np.abs(rpy[:, 1] - s.pitch_cells[cell]) <= s.dpitch / 2 + 1e-12)
    assert np.all((rpy[:, 0] >= s.roll[0]) & (rpy[:, 0] <= s.roll[1]))
    assert np.all((rpy[:, 2] >= s.yaw[0]) & (rpy[:, 2] <= s.yaw[1]))
    # the first batch is drawn near the half-sitting trunk, the third from every cell
    assert np.max(np.abs(z - 0.74)) < np.ptp(s.z_cells)
    z2, _ = s.sample(rng, 4000, batch=2)
    assert z2.min() < z.min() - 0.05


def test_conditioned_draw_never_drops_a_solvable_trunk(region_and_projector):
    """The reach test of sample_for is the closed form's own: any (hand, trunk) pair the
    arm IK solves passes it, and the conditioned draw makes solvable trunks far more likely."""
    tr, projector = region_and_projector
    region = valve_region((0.45, -0.15, 0.30))
    rng = np.random.default_rng(3)
    plain = tr.for_target(region)
    p_e, R_e = region.sample(rng, 3000)
    z, rpy = plain.sample(rng, 3000)
    p_t, R_t = projector.trunk_pose(z, rpy)
    c_p, c_R = projector.chest_pose(p_t, R_t)
    solved = projector.ik.solve("right_arm", c_p, c_R, p_e, R_e).ok
    g = tr.arms["right"]
    w = p_e - np.einsum("nij,j->ni", R_e @ g.Re.T, g.te)
    s = p_t + R_t @ g.shoulder
    passes = np.linalg.norm(s - w, axis=1) <= g.wrist_reach
    assert solved.any() and not np.any(solved & ~passes)
    z_c, rpy_c = plain.sample_for(np.random.default_rng(4), p_e, R_e, "right")
    p_t, R_t = projector.trunk_pose(z_c, rpy_c)
    c_p, c_R = projector.chest_pose(p_t, R_t)
    solved_c = projector.ik.solve("right_arm", c_p, c_R, p_e, R_e).ok
    assert solved_c.sum() > 2 * solved.sum()


@pytest.mark.parametrize("target, arm", [((1.5, 0.0, 1.0), "auto"), ((0.30, 0.0, 2.25), "auto"),
                                         ((0.2, 0.9, 0.9), "right")])
def test_out_of_reach_is_a_proof(region_and_projector, target, arm):
    """Where the bound says out of reach, no trunk pose of the searched ranges (any height
    from the floor up) lets the arm's IK reach any hand pose of the region."""
    tr, projector = region_and_projector
    region = valve_region(target)
    msg = tr.out_of_reach(region, arm)
    assert msg and "short" in msg
    rng = np.random.default_rng(5)
    n = 20000
    z = rng.uniform(0.0, tr.trunk_z_max, n)
    rpy = np.stack([rng.uniform(*tr.roll, n), rng.uniform(*tr.pitch_span, n), rng.uniform(*tr.yaw, n)], axis=1)
    p_t, R_t = projector.trunk_pose(z, rpy)
    c_p, c_R = projector.chest_pose(p_t, R_t)
    # the hand pose nearest the shoulders, any orientation: position-only reach test
    p_e, R_e = region.sample(rng, n)
    for a in (("right", "left") if arm == "auto" else (arm,)):
        assert not projector.ik[f"{a}_arm"].maybe_reachable(c_p, c_R, p_e, R_e).any()


def test_a_far_target_is_told_in_short_numbers(region_and_projector):
    """``--target 1e308 0 1``: the proof's lengths in 3 significant digits, not 300-digit numbers."""
    tr, _ = region_and_projector
    msg = tr.out_of_reach(valve_region((1e308, 0.0, 1.0)))
    assert "1e+308 m short" in msg and len(msg) < 300 and not re.search(r"\d{8}", msg), msg


def test_reachable_targets_are_never_ruled_out(region_and_projector):
    tr, _ = region_and_projector
    for target in [(0.71, 0.03, 0.90), (0.55, 0.0, 0.45), (0.45, -0.05, 1.50), (0.45, 0.5, 0.95), (0.3, -0.53, 1.05)]:
        assert tr.out_of_reach(valve_region(target)) is None, target


def test_a_seven_joint_arm_is_bounded_by_its_centre_circle():
    """Talos (7-DOF arms: the joint-2 centre on a circle about joint 1): the hands of random
    postures -- trunk up to the legs' chain length at any searched orientation, arm joints
    anywhere within their limits -- are never ruled out, the highest, lowest and farthest of
    them included; and the valve 2.25 m up (suite case high_valve) is ruled out, which the
    bound through joint 1's origin widened by the circle's radius could not do."""
    projector = Projector(RobotModel("talos"))
    tr = TrunkRegion(projector)
    rng = np.random.default_rng(9)
    for arm in ("right", "left"):
        lk = projector.ik[f"{arm}_arm"]
        n = 100_000
        q = rng.uniform(lk.lower, lk.upper, (n, 7))
        q[n // 2:, 3] = rng.uniform(lk.upper[3] - 0.05, lk.upper[3], n - n // 2)   # elbow nearly straight
        z = np.where(np.arange(n) % 2 == 0, rng.uniform(tr.trunk_z_max - 0.05, tr.trunk_z_max, n),
                     rng.uniform(tr.z_span[0], tr.trunk_z_max, n))
        rpy = np.stack([rng.uniform(*tr.roll, n), rng.uniform(*tr.pitch_span, n), rng.uniform(*tr.yaw, n)], axis=1)
        c_p, c_R = projector.chest_pose(*projector.trunk_pose(z, rpy))
        p, _ = lk.fk(c_p, c_R, q)
        far = np.hypot(p[:, 0] - tr.cog_xy[0], p[:, 1] - tr.cog_xy[1])
        pick = np.concatenate([np.argsort(p[:, 2])[-60:], np.argsort(p[:, 2])[:20], np.argsort(far)[-60:],
                               rng.integers(0, n, 40)])
        ruled_out = [tuple(np.round(p[k], 3)) for k in pick if tr.out_of_reach(valve_region(p[k]), arm)]
        assert not ruled_out, ruled_out
        assert p[:, 2].max() > 2.15                                 # the bound is close above the highest
        assert tr.out_of_reach(valve_region((0.30, 0.0, 2.25), np.eye(3)), arm)


def test_bad_spans_are_refused(region_and_projector):
    _, projector = region_and_projector
    with pytest.raises(ValueError, match="pitch_span"):
        TrunkRegion(projector, pitch_span=(0.5, -0.5))
    with pytest.raises(ValueError, match="z_span"):
        TrunkRegion(projector, z_span=(float("nan"), 1.0))
    with pytest.raises(ValueError, match="admits no trunk height"):
        TrunkRegion(projector, z_span=(1.5, 1.6))
    with pytest.raises(ValueError, match="cell sizes"):
        TrunkRegion(projector, dz=0.0)


def test_compiled_pick_equals_a_numpy_reference(region_and_projector):
    """sample_for keeps, per hand pose, the first of its candidates whose shoulder reaches
    the wrist centre (computed here with the projector's own trunk and chest poses)."""
    tr, projector = region_and_projector
    region = valve_region((0.5, -0.1, 0.5))
    s = tr.for_target(region)
    rng = np.random.default_rng(11)
    p_e, R_e = region.sample(rng, 300)
    state = rng.bit_generator.state
    z_c, rpy_c = s.sample_for(rng, p_e, R_e, "auto")
    rng.bit_generator.state = state
    n, k = len(p_e), s.candidates
    z, rpy = s.sample(rng, n * k)
    p_t, R_t = projector.trunk_pose(z, rpy)
    ok = np.zeros((k, n), bool)
    for arm in ("right", "left"):
        g = tr.arms[arm]
        c = (p_t + R_t @ g.shoulder).reshape(k, n, 3)
        w = p_e - np.einsum("nij,j->ni", R_e @ g.Re.T, g.te)
        ok |= np.linalg.norm(c - w[None], axis=2) <= g.wrist_reach
    pick = np.where(ok.any(axis=0), np.argmax(ok, axis=0), 0) * n + np.arange(n)
    np.testing.assert_array_equal(z_c, z[pick])
    np.testing.assert_array_equal(rpy_c, rpy[pick])
    assert 0 < ok.any(axis=0).sum() < n
