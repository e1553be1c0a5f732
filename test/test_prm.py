"""PRM and modified PRM (max_neighbors) on toy spaces."""
from __future__ import annotations

import numpy as np
import pytest

from humanoid_reach_ros.planning.path import PlanStatus, ShortcutOptions, plan
from humanoid_reach_ros.planning.prm import PRMOptions, build_roadmap, default_radius, plan_prm, query_roadmap
from test_rrt_connect import (  # toy worlds shared with the RRT-connect tests
    GOALS_2D, GOALS_6D, START_2D, START_6D, assert_valid_path, closed_wall, unit_space, wall_with_gap,
)

VARIANTS = [("prm", False), ("prm", True), ("modified_prm", False), ("modified_prm", True)]


@pytest.mark.parametrize("variant,lazy", VARIANTS)
def test_prm_finds_valid_path_2d(variant, lazy):
    is_valid, space = wall_with_gap(0.04), unit_space(2, 0.01)
    opts = PRMOptions(variant=variant, lazy=lazy, num_samples=600, max_time_s=10.0)
    res = plan_prm(START_2D, GOALS_2D, is_valid, space, np.random.default_rng(0), opts)
    assert_valid_path(res, START_2D, GOALS_2D, is_valid, space)
    assert res.stats.nodes == 600 + 2 and res.stats.check_calls > 0


@pytest.mark.parametrize("variant", ["prm", "modified_prm"])
def test_prm_finds_valid_path_6d(variant):
    is_valid, space = wall_with_gap(0.15), unit_space(6, 0.02)
    opts = PRMOptions(variant=variant, lazy=True, num_samples=1500, max_neighbors=20,
                      connection_radius=0.6, max_time_s=20.0)
    res = plan_prm(START_6D, GOALS_6D, is_valid, space, np.random.default_rng(0), opts)
    assert_valid_path(res, START_6D, GOALS_6D, is_valid, space)


def test_prm_start_and_goals_invalid():
    space, is_valid = unit_space(2), wall_with_gap()
    rng = np.random.default_rng(0)
    assert plan_prm([0.5, 0.9], GOALS_2D, is_valid, space, rng).status is PlanStatus.START_INVALID
    res = plan_prm(START_2D, [[0.5, 0.9], [-0.1, 0.5]], is_valid, space, rng)
    assert res.status is PlanStatus.GOALS_INVALID and res.path is None


@pytest.mark.parametrize("lazy", [False, True])
def test_prm_no_path(lazy):
    res = plan_prm(START_2D, GOALS_2D, closed_wall, unit_space(2), np.random.default_rng(0),
                   PRMOptions(num_samples=300, lazy=lazy, max_time_s=10.0))
    assert res.status is PlanStatus.NO_PATH and res.path is None and not res.success


def test_prm_time_budget():
    res = plan_prm(START_2D, GOALS_2D, closed_wall, unit_space(2), np.random.default_rng(0),
                   PRMOptions(num_samples=10**5, sample_batch=1000, max_sample_batches=200, max_time_s=0.05))
    assert res.status is PlanStatus.TIMED_OUT and res.path is None


@pytest.mark.parametrize("variant,lazy", VARIANTS)
def test_prm_deterministic_with_seed(variant, lazy):
    is_valid, space = wall_with_gap(0.04), unit_space(2)
    opts = PRMOptions(variant=variant, lazy=lazy, num_samples=400, max_time_s=10.0)
    a = plan_prm(START_2D, GOALS_2D, is_valid, space, np.random.default_rng(5), opts)
    b = plan_prm(START_2D, GOALS_2D, is_valid, space, np.random.default_rng(5), opts)
    assert a.status == b.status
    np.testing.assert_array_equal(a.path, b.path)
    assert a.stats.checked_configs == b.stats.checked_configs


@pytest.mark.parametrize("variant", ["prm", "modified_prm"])
def test_prm_chooses_reachable_goal(variant):
    goals = np.array([[0.5, 0.5], [0.9, 0.9], [0.2, 0.9]])
    space = unit_space(2)
    res = plan(variant, START_2D, goals, closed_wall, space, np.random.default_rng(1),
               PRMOptions(num_samples=300, max_time_s=10.0, shortcut=ShortcutOptions(30)))
    assert res.goal_index == 2
    assert_valid_path(res, START_2D, goals, closed_wall, space)


def test_modified_prm_limits_neighbours():
    space, is_valid = unit_space(2), wall_with_gap()
    k, n = 5, 400
    rm_mod = build_roadmap(is_valid, space, np.random.default_rng(0),
                           PRMOptions("modified_prm", num_samples=n, max_neighbors=k, connection_radius=0.3))
    rm_prm = build_roadmap(is_valid, space, np.random.default_rng(0),
                           PRMOptions("prm", num_samples=n, connection_radius=0.3))
    np.testing.assert_array_equal(rm_mod.nodes, rm_prm.nodes)
    assert len(rm_mod.edges) <= n * k < len(rm_prm.edges)
    lengths = space.distance(rm_prm.nodes[rm_prm.edges[:, 0]], rm_prm.nodes[rm_prm.edges[:, 1]])
    assert np.all(lengths <= 0.3 + 1e-12)
    # a roadmap can be queried several times
    for goal in ([[0.9, 0.9]], [[0.9, 0.1]]):
        status, path, gi = query_roadmap(rm_mod, START_2D, goal, is_valid, space,
                                         PRMOptions("modified_prm", max_neighbors=k))
        assert status is PlanStatus.SUCCESS and gi == 0


def test_default_radius_shrinks_with_n():
    space = unit_space(6)
    assert default_radius(space, 1000) < default_radius(space, 100)
    with pytest.raises(ValueError):
        PRMOptions(variant="rrt")
