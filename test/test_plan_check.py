"""PlanChecker (fused, manifold-specialised validity of q_plan rows) == the unfused path."""
from __future__ import annotations

import numpy as np
import pytest

from humanoid_reach_ros.geometry.distance import RobotCollision
from humanoid_reach_ros.planning.plan_check import PlanChecker
from humanoid_reach_ros.planning.reach import PlannerParams, ReachPlanner


@pytest.fixture(scope="module")
def planner():
    from humanoid_reach_ros.sim.scene import load_scene

    params = PlannerParams()
    rp = ReachPlanner(params=params)
    scene = load_scene("scenes/plant.yaml")
    rp.set_map(scene.voxelize(params.resolution_m, exclude_groups=("valve",)))
    return rp


def _reference(rp: ReachPlanner, arm: str, collision: RobotCollision):
    """The unfused checker: project_plan_config, then RobotCollision.check_batch."""
    def fn(Q):
        res = rp.projector.project_plan_config(Q, arm)
        ok = res.ok.copy()
        idx = np.flatnonzero(ok)
        if idx.size:
            ok[idx] = collision.check_batch(res.q[idx])
        return ok
    return fn


@pytest.mark.parametrize("arm", ["right", "left"])
def test_batch_and_first_invalid_match_unfused(planner, arm):
    rng = np.random.default_rng(3 if arm == "right" else 4)
    space = planner.planning_space(arm)
    # box samples (limits, leg IK failures, collisions) and samples near the start
    Q = np.vstack([space.sample(rng, 4000),
                   planner.projector.plan_config_of(planner.start_config(planner.robot.half_sitting_joints), arm)
                   + rng.normal(scale=0.3, size=(2000, 10))])
    pc = PlanChecker(planner.projector, planner.collision, arm)
    ref = _reference(planner, arm, planner.collision)(Q)
    got = pc(Q)
    assert 0.1 < ref.mean() < 0.95
    np.testing.assert_array_equal(got, ref)
    for _ in range(300):
        i = int(rng.integers(0, len(Q)))
        j = int(rng.integers(i, min(len(Q), i + 60) + 1))
        r = ref[i:j]
        expect = len(r) if r.all() else int(np.argmin(r))
        assert pc.first_invalid(Q[i:j]) == expect


def test_rigid_pairs_dropped_and_all_hit(planner):
    pc = PlanChecker(planner.projector, planner.collision, "right")
    assert pc.n_pairs_dropped > 0 and not pc.all_hit
    # a self margin that the rigid pairs (other arm vs chest...) violate: every row collides
    tight = RobotCollision(planner.robot, planner.collision_model, planner.collision.tree, self_margin_m=0.5)
    pc2 = PlanChecker(planner.projector, tight, "right")
    assert pc2.all_hit
    rng = np.random.default_rng(1)
    Q = planner.planning_space("right").sample(rng, 300)
    np.testing.assert_array_equal(pc2(Q), _reference(planner, "right", tight)(Q))
    assert not pc2(Q).any()


def test_counters_and_validity_fn(planner):
    fn = planner.validity_fn("right", planner.collision)
    assert isinstance(fn, PlanChecker) and fn is planner.validity_fn("right", planner.collision)
    c0 = planner.collision.counters.checks
    fn(planner.planning_space("right").sample(np.random.default_rng(2), 50))
    assert planner.collision.counters.checks > c0
    base = ReachPlanner(planner.robot, planner.params, early_exit_checks=False)
    assert not isinstance(base.validity_fn("right", planner.collision), PlanChecker)


@pytest.mark.parametrize("arm", ["right", "left"])
def test_first_invalid_edge_matches_check_edges_on_unfused_points(planner, arm):
    from humanoid_reach_ros.planning.space import CountingChecker, check_edges

    rng = np.random.default_rng(7)
    space = planner.planning_space(arm)
    pc = PlanChecker(planner.projector, planner.collision, arm)
    assert pc.lanes       # the SIMD-lane edge kernel (geometry/batch_collision.py) is the default
    scalar = PlanChecker(planner.projector, planner.collision, arm, lanes=False)
    ref_fn = _reference(planner, arm, planner.collision)
    start = planner.projector.plan_config_of(planner.start_config(planner.robot.half_sitting_joints), arm)[0]
    for trial in range(60):
        E = int(rng.integers(1, 5))
        A = start + rng.normal(scale=0.4, size=(E, 10))
        B = A + rng.normal(scale=0.4, size=(E, 10))
        inc = bool(trial % 2)
        ref = check_edges(A, B, ref_fn, space, include_endpoints=inc)            # every point, in order
        want = len(ref) if ref.all() else int(np.argmin(ref))
        for checker in (pc, CountingChecker(pc), scalar):
            got = check_edges(A, B, checker, space, include_endpoints=inc, prefix=True)
            assert got[:want].all() and not got[want:].any()
