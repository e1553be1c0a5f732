"""RRT-connect and the shared path tools (edges, shortcutting) on toy spaces."""
from __future__ import annotations

import numpy as np
import pytest

from humanoid_reach_ros.planning.path import (
    CountingChecker, PlanningSpace, PlanStatus, ShortcutOptions, check_edge, check_edges, check_path,
    first_invalid, interpolate_edge, interpolate_path, plan, remove_redundant_waypoints, shortcut_path,
)
from humanoid_reach_ros.planning.rrt_connect import RRTConnectOptions, plan_rrt_connect


# ------------------------------------------------------------------ toy worlds (also used by test_prm)
def wall_with_gap(gap: float = 0.04, thickness: float = 0.05):
    """Unit square, wall ``|x0 - 0.5| < thickness`` open only for ``|x1 - 0.5| < gap``."""
    def is_valid(Q: np.ndarray) -> np.ndarray:
        Q = np.atleast_2d(Q)
        in_wall = np.abs(Q[:, 0] - 0.5) < thickness
        in_gap = np.all(np.abs(Q[:, 1:3] - 0.5) < gap, axis=1)
        return ~(in_wall & ~in_gap)
    return is_valid


def closed_wall(Q: np.ndarray) -> np.ndarray:
    return ~(np.abs(np.atleast_2d(Q)[:, 0] - 0.5) < 0.05)


def unit_space(d: int, resolution: float = 0.01) -> PlanningSpace:
    return PlanningSpace(np.zeros(d), np.ones(d), resolution=resolution)


def assert_valid_path(result, start, goals, is_valid, space):
    assert result.success, result.status
    path = result.path
    assert path.ndim == 2 and path.shape[1] == space.dim
    np.testing.assert_allclose(path[0], start)
    np.testing.assert_allclose(path[-1], np.atleast_2d(goals)[result.goal_index])
    dense = interpolate_path(path, space)
    assert np.all(is_valid(dense)), "a waypoint or an interpolated configuration is invalid"
    assert np.all(space.in_bounds(dense))


START_2D, GOALS_2D = np.array([0.1, 0.1]), np.array([[0.9, 0.9]])
START_6D = np.full(6, 0.15)
GOALS_6D = np.full((1, 6), 0.85)


# ------------------------------------------------------------------ RRT-connect
@pytest.mark.parametrize("d,start,goals,gap", [(2, START_2D, GOALS_2D, 0.03), (6, START_6D, GOALS_6D, 0.12)])
def test_rrt_connect_finds_valid_path_through_narrow_gap(d, start, goals, gap):
    is_valid, space = wall_with_gap(gap), unit_space(d, 0.01)
    res = plan_rrt_connect(start, goals, is_valid, space, np.random.default_rng(1),
                           RRTConnectOptions(step=0.1, max_time_s=10.0, max_iterations=20000))
    assert_valid_path(res, start, goals, is_valid, space)
    s = res.stats
    assert s.iterations > 0 and s.nodes >= 2 and s.check_calls > 0 and s.checked_configs > s.check_calls


def test_rrt_connect_straight_line_when_free():
    space = unit_space(3)
    res = plan_rrt_connect(np.full(3, 0.1), np.full((1, 3), 0.9), lambda Q: np.ones(len(Q), bool), space,
                           np.random.default_rng(0), RRTConnectOptions(step=0.2))
    assert res.success and res.stats.iterations == 1
    np.testing.assert_allclose(space.path_length(res.path), space.distance(np.full(3, 0.1), np.full(3, 0.9)))


def test_rrt_connect_start_invalid():
    res = plan_rrt_connect([0.5, 0.9], GOALS_2D, wall_with_gap(), unit_space(2), np.random.default_rng(0))
    assert res.status is PlanStatus.START_INVALID and not res.success and res.path is None


def test_rrt_connect_goals_invalid_or_out_of_bounds():
    res = plan_rrt_connect(START_2D, [[0.5, 0.9], [1.5, 0.5]], wall_with_gap(), unit_space(2),
                           np.random.default_rng(0))
    assert res.status is PlanStatus.GOALS_INVALID and res.path is None and res.goal_index is None


def test_rrt_connect_no_path_times_out():
    res = plan_rrt_connect(START_2D, GOALS_2D, closed_wall, unit_space(2), np.random.default_rng(0),
                           RRTConnectOptions(step=0.1, max_time_s=0.3, max_iterations=300))
    assert res.status is PlanStatus.TIMED_OUT and res.path is None
    assert res.stats.iterations <= 300


def test_rrt_connect_deterministic_with_seed():
    is_valid, space = wall_with_gap(0.03), unit_space(2)
    opts = RRTConnectOptions(step=0.1, max_time_s=10.0, max_iterations=20000)
    a = plan_rrt_connect(START_2D, GOALS_2D, is_valid, space, np.random.default_rng(7), opts)
    b = plan_rrt_connect(START_2D, GOALS_2D, is_valid, space, np.random.default_rng(7), opts)
    assert a.success and b.success
    np.testing.assert_array_equal(a.path, b.path)
    assert (a.stats.iterations, a.stats.nodes, a.stats.checked_configs) == \
        (b.stats.iterations, b.stats.nodes, b.stats.checked_configs)


def test_rrt_connect_chooses_a_reachable_goal_among_several():
    # goal 0 invalid (in the wall), goal 1 behind the closed wall, goal 2 reachable
    goals = np.array([[0.5, 0.5], [0.9, 0.9], [0.2, 0.9]])
    space = unit_space(2)
    for seed in range(3):
        res = plan_rrt_connect(START_2D, goals, closed_wall, space, np.random.default_rng(seed),
                               RRTConnectOptions(step=0.1, max_time_s=5.0))
        assert res.goal_index == 2
        assert_valid_path(res, START_2D, goals, closed_wall, space)


def test_rrt_connect_with_shortcut_and_dispatch_by_name():
    is_valid, space = wall_with_gap(0.03), unit_space(2)
    opts = RRTConnectOptions(step=0.1, max_time_s=10.0, max_iterations=20000, shortcut=ShortcutOptions(50))
    raw = plan("rrt_connect", START_2D, GOALS_2D, is_valid, space, np.random.default_rng(3),
               RRTConnectOptions(step=0.1, max_time_s=10.0, max_iterations=20000))
    short = plan("rrt_connect", START_2D, GOALS_2D, is_valid, space, np.random.default_rng(3), opts)
    assert_valid_path(short, START_2D, GOALS_2D, is_valid, space)
    assert space.path_length(short.path) <= space.path_length(raw.path) + 1e-9
    with pytest.raises(ValueError):
        plan("rrt", START_2D, GOALS_2D, is_valid, space, np.random.default_rng(3))


# ------------------------------------------------------------------ edges
def test_interpolate_edge_spacing_and_endpoints():
    space = PlanningSpace(np.zeros(3), np.ones(3), weights=[1.0, 2.0, 0.5], resolution=0.05)
    a, b = np.array([0.1, 0.2, 0.3]), np.array([0.8, 0.6, 0.1])
    pts = interpolate_edge(a, b, space)
    np.testing.assert_allclose(pts[0], a)
    np.testing.assert_allclose(pts[-1], b)
    assert np.all(space.distance(pts[1:], pts[:-1]) <= space.resolution + 1e-12)
    assert len(interpolate_edge(a, a, space)) == 2


def test_check_edges_one_call_and_detects_thin_wall():
    space = unit_space(2, 0.01)
    checker = CountingChecker(wall_with_gap(0.03, thickness=0.006))
    A = np.array([[0.1, 0.1], [0.1, 0.5], [0.1, 0.1]])
    B = np.array([[0.9, 0.1], [0.9, 0.5], [0.3, 0.9]])
    ok = check_edges(A, B, checker, space)
    np.testing.assert_array_equal(ok, [False, True, True])
    assert checker.calls == 1
    assert check_edge(A[1], B[1], checker, space) and checker.calls == 2
    # chunking keeps the answer
    np.testing.assert_array_equal(check_edges(A, B, checker, space, max_configs_per_call=50), ok)


# ------------------------------------------------------------------ shortcutting
@pytest.mark.parametrize("seed", range(6))
def test_shortcut_never_invalidates_or_lengthens(seed):
    is_valid, space = wall_with_gap(0.03), unit_space(2, 0.01)
    res = plan_rrt_connect(START_2D, GOALS_2D, is_valid, space, np.random.default_rng(seed),
                           RRTConnectOptions(step=0.05, max_time_s=10.0, max_iterations=20000))
    assert res.success
    short = shortcut_path(res.path, is_valid, space, np.random.default_rng(100 + seed), ShortcutOptions(200, 2.0))
    assert check_path(short, is_valid, space)
    np.testing.assert_allclose(short[0], res.path[0])
    np.testing.assert_allclose(short[-1], res.path[-1])
    assert space.path_length(short) <= space.path_length(res.path) + 1e-9


def test_remove_redundant_waypoints():
    space = unit_space(2)
    free = lambda Q: np.ones(len(Q), bool)  # noqa: E731
    line = np.linspace([0.1, 0.1], [0.9, 0.9], 9)
    line = np.vstack([line[:3], line[2:]])  # with a duplicate
    out = remove_redundant_waypoints(line, free, space)
    np.testing.assert_allclose(out, [[0.1, 0.1], [0.9, 0.9]])
    # around the wall the corner waypoints must stay
    detour = np.array([[0.1, 0.1], [0.1, 0.5], [0.9, 0.5], [0.9, 0.9]])
    out = remove_redundant_waypoints(detour, wall_with_gap(0.03), space)
    assert check_path(out, wall_with_gap(0.03), space)
    assert space.path_length(out) <= space.path_length(detour) + 1e-12


def test_rrt_connect_start_equal_to_goal():
    space = unit_space(2)
    res = plan_rrt_connect(START_2D, [START_2D], closed_wall, space, np.random.default_rng(0))
    assert res.success and res.goal_index == 0
    assert len(res.path) >= 1
    np.testing.assert_allclose(res.path[0], START_2D)
    np.testing.assert_allclose(res.path[-1], START_2D)


def with_first_invalid(is_valid, examined: list):
    """``is_valid`` plus a ``first_invalid`` that checks point by point and stops at the
    first invalid one; ``examined`` collects how many points it looked at."""
    def fn(Q):
        return is_valid(Q)

    def first(Q):
        for k, q in enumerate(np.atleast_2d(Q)):
            if not is_valid(q[None])[0]:
                examined.append(k + 1)
                return k
        examined.append(len(Q))
        return len(Q)

    fn.first_invalid = first
    return fn


@pytest.mark.parametrize("seed", range(5))
def test_prefix_edge_checks_agree_with_full_checks(seed):
    """check_edges(prefix=True) == the full check up to and including the first invalid
    edge, False after it; a checker's first_invalid is used and may stop early."""
    rng = np.random.default_rng(seed)
    space = unit_space(3, 0.02)
    base = wall_with_gap(0.08)
    examined: list[int] = []
    fast = with_first_invalid(base, examined)
    A, B = rng.random((12, 3)), rng.random((12, 3))
    for include in (False, True):
        full = check_edges(A, B, base, space, include_endpoints=include)
        pre = check_edges(A, B, fast, space, include_endpoints=include, prefix=True)
        k = len(full) if full.all() else int(np.argmin(full))
        assert np.array_equal(pre[:k], full[:k]) and not pre[k:].any()
        # a plain checker (no first_invalid) in prefix mode: same answer
        assert np.array_equal(check_edges(A, B, base, space, include_endpoints=include, prefix=True), pre)
    assert examined and all(n > 0 for n in examined)
    Q = rng.random((50, 3))
    ok = base(Q)
    expect = len(Q) if ok.all() else int(np.argmin(ok))
    assert first_invalid(base, Q) == expect == first_invalid(fast, Q)
    counting = CountingChecker(fast)
    assert counting.first_invalid(Q) == expect
    assert counting.calls == 1 and counting.configs == min(expect + 1, len(Q))


def test_rrt_connect_same_plan_with_early_exit_checker():
    """RRT-connect grows the same tree whether or not the checker stops at the first
    invalid point (early exit only skips work)."""
    space = unit_space(3, 0.01)
    base = wall_with_gap(0.06)
    start, goals = np.array([0.1, 0.5, 0.5]), np.array([[0.9, 0.5, 0.5]])
    opts = RRTConnectOptions(step=0.2, max_time_s=20.0)
    a = plan_rrt_connect(start, goals, base, space, np.random.default_rng(4), opts)
    examined: list[int] = []
    b = plan_rrt_connect(start, goals, with_first_invalid(base, examined), space, np.random.default_rng(4), opts)
    assert a.success and b.success and np.array_equal(a.path, b.path)
    assert b.stats.checked_configs <= a.stats.checked_configs


def test_bisect_order_is_a_coarse_to_fine_permutation():
    from humanoid_reach_ros.planning.space import bisect_order

    for n in range(0, 80):
        o = bisect_order(n)
        assert sorted(o.tolist()) == list(range(n))
    assert bisect_order(9).tolist()[:3] == [4, 2, 6]


def test_prefix_edge_checks_in_bisect_order_match_in_order_checks():
    """check_edges(prefix=True) visits each edge's points coarse to fine: the first invalid
    edge reported must be the one an in-order scan finds (random edges, random blobs)."""
    from humanoid_reach_ros.planning.space import PlanningSpace, check_edges

    rng = np.random.default_rng(5)
    space = PlanningSpace(np.zeros(3), np.ones(3), resolution=0.01)
    for trial in range(200):
        centres = rng.random((3, 3))
        radius = rng.uniform(0.05, 0.2)

        def valid(Q, centres=centres, radius=radius):
            return np.all(np.linalg.norm(Q[:, None] - centres[None], axis=-1) > radius, axis=1)

        calls = []

        def in_order(Q, calls=calls):
            calls.append(len(Q))
            return valid(Q)

        A = rng.random((rng.integers(1, 6), 3))
        B = rng.random(A.shape)
        inc = bool(trial % 2)
        got = check_edges(A, B, valid_with_first(valid), space, include_endpoints=inc, prefix=True)
        ref = check_edges(A, B, in_order, space, include_endpoints=inc, prefix=False)
        first_bad = int(np.argmin(ref)) if not ref.all() else len(ref)
        assert got[:first_bad].all()
        assert not got[first_bad:].any()


def valid_with_first(valid):
    def fn(Q):
        return valid(Q)

    def first(Q):
        ok = valid(Q)
        return len(ok) if ok.all() else int(np.argmin(ok))

    fn.first_invalid = first
    return fn
