"""Trajectories never leave the joint limits (issue 21 part 5).

A planned reach was refused by the executor: ``trajectory leaves the joint limits: RARM_JOINT2
= 1.6181 rad at point 99 (limits [-1.6057, 1.6057])`` -- the paper's clamped cubic spline
overshot between waypoints the planner had checked. ``SplineTrajectory`` is now a monotone
cubic (PCHIP, zero end slopes); these tests check on 10,000 random paths, exactly (roots of each
segment's derivative) and by dense sampling, that it stays within the limits wherever its
waypoints are, that the old clamped spline does not (so the test can fail), that
``max_velocity`` is exact, that ``respect_velocity_limit`` bounds the peak, and that the
planner's and the executor's checks agree.

Measured (these paths): the clamped spline leaves the limits on 9,001 of the 10,000 paths on
random time grids (up to 175 rad where neighbouring durations differ 200:1) and on 898 of 1,000
paths timed by the planner's rule (up to 1.2 rad); PCHIP on none, not by a single ulp at the
exact extrema, at most ``ROUND`` in the samples.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import CubicSpline, PchipInterpolator

from humanoid_reach_ros.geometry.trajectory import (
    SplineTrajectory, TrajectoryOptions, path_to_trajectory, pchip_slopes,
)
from humanoid_reach_ros.robot.model import N_BASE_Q, RobotModel

N_PATHS = 10_000
ROUND = 1e-12       # rounding of a cubic's evaluation (measured <= 2.3e-16 rad past a waypoint)


@pytest.fixture(scope="module")
def robot() -> RobotModel:
    return RobotModel()


class ClampedSpline(SplineTrajectory):
    """The interpolant this replaced (scipy CubicSpline, bc_type="clamped"), with the same exact
    extrema / limit check (they read only the PPoly coefficients)."""

    def __init__(self, waypoints: np.ndarray, times: np.ndarray) -> None:
        super().__init__(waypoints, times)
        if self._spline is not None:
            self._spline = CubicSpline(self.times, self.waypoints, axis=0, bc_type="clamped")


def random_paths(lower: np.ndarray, upper: np.ndarray, n_paths: int, seed: int = 0) -> list[np.ndarray]:
    """``n_paths`` waypoint arrays (2-12, n) within ``[lower, upper]``, drawn per joint and path
    from: at a limit, within 1e-3 of one, uniform inside, alternating between near-lower and
    near-upper (sign flips of a symmetric joint), a plateau at a limit with steps off it (what
    made the clamped spline overshoot); then ~20 % of the waypoints repeat the previous one."""
    rng = np.random.default_rng(seed)
    n = len(lower)
    k_all = rng.integers(2, 13, n_paths)
    K = int(k_all.max())
    span = upper - lower
    shape = (n_paths, K, n)
    u = rng.random(shape)
    near = rng.random(shape) * 1e-3
    side = rng.random(shape) < 0.5
    at = np.where(side, lower, upper)
    near_v = np.where(side, lower + near, upper - near)
    inside = lower + u * span
    flip = np.where(np.arange(K)[None, :, None] % 2 == 0, upper - near, lower + near)
    plateau = np.where(rng.random(shape) < 0.6, upper - near * (rng.random(shape) < 0.3), inside)
    mixed = np.where(rng.random(shape) < 0.5, at, inside)
    mode = rng.integers(0, 6, (n_paths, 1, n))
    Q = np.choose(mode, [at, near_v, inside, flip, plateau, mixed])
    rep = rng.random((n_paths, K)) < 0.2
    rep[:, 0] = False
    for i in range(1, K):   # repeated waypoints (whole rows): zero secants, zero slopes
        Q[rep[:, i], i] = Q[rep[:, i], i - 1]
    Q = np.clip(Q, lower, upper)
    return [Q[p, :k] for p, k in enumerate(k_all)]


def batches(paths: list[np.ndarray], rng: np.random.Generator, size: int = 100):
    """The paths side by side: for each length ``k``, chunks of ``size`` paths as one
    ``(k, size * n)`` waypoint array on one random time grid. Every joint's interpolant depends
    only on its own column and the times, so this is ``size`` trajectories at once; the
    segment durations are log-uniform in [0.01, 2] s (the durations rule's ``T_min`` up to a
    long reach), i.e. neighbour ratios up to 200, where the PCHIP slope bound 3 d is nearly met."""
    by_k: dict[int, list[np.ndarray]] = {}
    for Q in paths:
        by_k.setdefault(len(Q), []).append(Q)
    for k, group in sorted(by_k.items()):
        for c in range(0, len(group), size):
            chunk = group[c:c + size]
            times = np.concatenate([[0.0], np.cumsum(np.exp(rng.uniform(np.log(0.01), np.log(2.0), k - 1)))])
            yield np.concatenate(chunk, axis=1), times, len(chunk)


def dense_extremes(traj: SplineTrajectory, per_segment: int = 33) -> tuple[np.ndarray, np.ndarray]:
    """Min / max per joint over ``per_segment`` samples of every segment (knots included)."""
    t = traj.times
    grid = (t[:-1, None] + np.diff(t)[:, None] * np.linspace(0.0, 1.0, per_segment)[None]).ravel()
    q = traj.position(grid)
    return q.min(axis=0), q.max(axis=0)


def test_pchip_slopes_are_scipys_inside_and_zero_at_the_ends():
    rng = np.random.default_rng(1)
    t = np.cumsum(rng.uniform(0.01, 2.0, 9))
    Q = rng.normal(size=(9, 6))
    Q[4] = Q[3]                                   # a repeated waypoint
    m = pchip_slopes(t, Q)
    ref = PchipInterpolator(t, Q, axis=0).derivative()(t)
    np.testing.assert_allclose(m[1:-1], ref[1:-1], rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(m[[0, -1]], 0.0)
    np.testing.assert_array_equal(m[[3, 4]], 0.0)  # either side of a flat secant


def test_ten_thousand_random_paths_stay_within_the_limits(robot):
    """10,000 paths over HRP-2's 30 joints (300,000 joint curves), 100 at a time: exactly
    (segment extrema) and by dense sampling (33 samples a segment) no joint leaves
    [lower, upper], nor the range of its own waypoints (the monotonicity the limits follow from)."""
    lo, hi = robot.lower, robot.upper
    rng = np.random.default_rng(10)
    curves = 0
    for W, times, b in batches(random_paths(lo, hi, N_PATHS), rng):
        lower, upper = np.tile(lo, b), np.tile(hi, b)
        traj = SplineTrajectory(W, times)
        assert traj.check_limits(lower, upper, tol=0.0) is None
        qmin, qmax = traj.position_range()
        assert np.all(qmin >= W.min(axis=0)) and np.all(qmax <= W.max(axis=0))   # exact: no rounding flagged
        dmin, dmax = dense_extremes(traj)
        assert np.all(dmin >= lower - ROUND) and np.all(dmax <= upper + ROUND)
        assert np.all(dmin >= qmin - ROUND) and np.all(dmax <= qmax + ROUND)   # the exact range bounds the samples
        curves += W.shape[1]
    assert curves == N_PATHS * robot.n_joints


def test_planner_timed_paths_stay_within_the_limits(robot):
    """1,000 of the paths one by one, timed as the planner times them (durations rule at
    ``min(0.5, 0.5 x URDF)`` per joint, stretched to the peak bound): the exact check and the
    samples of the JointTrajectory (50 ms) agree that nothing leaves the limits."""
    lo, hi = robot.lower, robot.upper
    v = 0.5 * robot.velocity_limit
    opts = TrajectoryOptions(joint_velocity=tuple(np.minimum(0.5, v)), respect_velocity_limit=True,
                             velocity_limit=tuple(v))
    for Q in random_paths(lo, hi, 1000, seed=11):
        traj = SplineTrajectory.from_path(Q, opts)
        assert traj.check_limits(lo, hi, tol=0.0) is None
        assert np.all(traj.max_position_excursion() == 0.0)
        q = traj.to_points(0.05).positions
        assert np.all(q >= lo - ROUND) and np.all(q <= hi + ROUND)


def test_the_clamped_spline_overshoots_on_the_same_paths(robot):
    """The old interpolant on the same paths and times: it does leave the limits (the exact
    check and the samples agree), so the tests above can fail."""
    lo, hi = robot.lower, robot.upper
    rng = np.random.default_rng(10)
    flagged = paths = 0
    worst = 0.0
    for W, times, b in batches(random_paths(lo, hi, N_PATHS), rng):
        lower, upper = np.tile(lo, b), np.tile(hi, b)
        old = ClampedSpline(W, times)
        qmin, qmax = old.position_range()
        excess = np.maximum(lower - qmin, qmax - upper).reshape(b, -1)      # (paths, joints)
        flagged += int(np.sum(np.any(excess > 1e-9, axis=1)))
        paths += b
        worst = max(worst, float(excess.max()))
        dmin, dmax = dense_extremes(old)
        if excess.max() > 1e-2:                                               # the samples see it too
            assert float(np.max(np.maximum(lower - dmin, dmax - upper))) > 0.0
        assert np.all(dmin >= qmin - ROUND) and np.all(dmax <= qmax + ROUND)   # no sample beyond the exact extremes ...
        hit = old.check_limits(lower, upper)
        if hit is not None:                                   # ... and the first violation is on the curve
            q = old.position(hit.time)[hit.joint]
            assert q == pytest.approx(hit.value, abs=1e-9) and not lower[hit.joint] <= q <= upper[hit.joint]
    assert paths == N_PATHS
    assert flagged > N_PATHS // 2        # measured: 9,001 of 10,000 paths, up to 175 rad past a limit
    assert worst > 0.1                   # (200:1 neighbour durations; planner-timed: 898 of 1,000, 1.2 rad)


def test_the_reported_case_rarm_joint2_at_its_upper_limit(robot):
    """RARM_JOINT2 climbing to its upper limit and staying there a little while the trunk moves,
    then leaving: the clamped spline passes 1.6057 (as in the issue), PCHIP does not."""
    j = robot.joint_index["RARM_JOINT2"]
    up = robot.upper[j]
    W = np.tile(robot.half_sitting_joints, (5, 1))
    W[:, j] = [0.2, up - 0.05, up, up, 0.9]
    W[:, robot.joint_index["CHEST_JOINT1"]] = [0.3, 0.4, 0.5, 0.9, 0.6]   # the long segment at the plateau
    opts = TrajectoryOptions(joint_velocity=0.5)
    new = path_to_trajectory(W, opts)
    old = ClampedSpline(W, new.times)
    hit = old.check_limits(robot.lower, robot.upper)
    assert hit is not None and hit.joint == j and hit.value > up + 1e-3
    assert new.check_limits(robot.lower, robot.upper, tol=0.0) is None
    assert new.position_range()[1][j] == up
    # what the executor saw: the JointTrajectory samples (50 ms) of the old spline were outside
    assert old.to_points(0.05).positions[:, j].max() > up + 1e-3
    assert new.to_points(0.05).positions[:, j].max() <= up + ROUND


def test_max_velocity_is_exact(robot):
    """``max_velocity`` (vertex of each segment's q') against 2,001 samples a segment, 500 paths:
    never below the samples, and equal to them within the grid's resolution."""
    lo, hi = robot.lower, robot.upper
    for Q in random_paths(lo, hi, 500, seed=2):
        traj = SplineTrajectory.from_path(Q, TrajectoryOptions(joint_velocity=0.5))
        t = traj.times
        grid = (t[:-1, None] + np.diff(t)[:, None] * np.linspace(0.0, 1.0, 2001)[None]).ravel()
        dense = np.abs(traj.velocity(grid)).max(axis=0)
        assert np.all(traj.max_velocity >= dense - 1e-12)
        np.testing.assert_allclose(traj.max_velocity, dense, rtol=1e-5, atol=1e-12)


def test_respect_velocity_limit_bounds_the_peak(robot):
    """The time stretch ``kappa = max_j peak_j / v_j`` makes the peak <= v exactly (PCHIP is
    time-scale equivariant: the stretched curve is ``q(t / kappa)``), with the bound given
    apart from the durations' velocity too, as the planner does."""
    lo, hi = robot.lower, robot.upper
    bound = 0.2 * robot.velocity_limit         # 0.4-0.8 rad/s: the cubic's peak (up to 0.75) passes it
    stretched = 0
    for Q in random_paths(lo, hi, 1000, seed=3):
        free = SplineTrajectory.from_path(Q, TrajectoryOptions(joint_velocity=0.5))
        traj = SplineTrajectory.from_path(Q, TrajectoryOptions(joint_velocity=0.5, respect_velocity_limit=True,
                                                               velocity_limit=tuple(bound)))
        assert np.all(traj.max_velocity <= bound * (1 + 1e-12))
        kappa = max(1.0, float(np.max(free.max_velocity / bound)))
        np.testing.assert_allclose(traj.times, free.times * kappa, rtol=1e-12)
        s = np.linspace(0.0, free.duration, 97)
        np.testing.assert_allclose(traj.position(s * kappa), free.position(s), atol=1e-12)
        stretched += kappa > 1.0
        same_v = SplineTrajectory.from_path(Q, TrajectoryOptions(joint_velocity=0.5, respect_velocity_limit=True))
        assert np.all(same_v.max_velocity <= 0.5 * (1 + 1e-12))
    assert stretched > 500        # measured: 945 of 1,000 paths need it


def test_the_planners_trajectory_keeps_the_executors_velocity_bound(robot):
    """``ReachPlanner._trajectory`` on waypoints at the limits: within them, exactly, and its
    peak within ``velocity_scale`` x the URDF limits (0.2: 0.4 rad/s at the wrists, below the
    0.5 rad/s durations rule, so both the per-joint durations and the stretch act)."""
    from humanoid_reach_ros.planning.reach import PlannerParams, ReachPlanner

    rp = ReachPlanner(robot, PlannerParams(velocity_scale=0.2))
    lo, hi = robot.lower, robot.upper
    for Wj in random_paths(lo, hi, 20, seed=4):
        if len(Wj) < 3:
            continue
        Q = np.zeros((len(Wj), N_BASE_Q + robot.n_joints))
        Q[:, 6] = 1.0                       # identity base quaternion
        Q[:, N_BASE_Q:] = Wj
        out = rp._trajectory(Q)
        assert np.all(out.spline.max_velocity <= 0.2 * robot.velocity_limit * (1 + 1e-12))
        assert out.spline.check_limits(lo, hi, tol=0.0) is None
        assert np.all(out.positions >= lo - ROUND) and np.all(out.positions <= hi + ROUND)


def test_the_executor_checks_the_curve_between_points(robot, monkeypatch):
    """``reference_from_trajectory`` accepts the samples of a PCHIP trajectory at its limits,
    and refuses, naming the joint, time and points, an interpolant that leaves the limits
    between points that are within them (here the old clamped spline, swapped in)."""
    from humanoid_reach_ros.io import exec_msgs, msgs
    from humanoid_reach_ros.codes import RequestError

    j = robot.joint_index["RARM_JOINT2"]
    up = robot.upper[j]
    W = np.tile(robot.half_sitting_joints, (5, 1))
    W[:, j] = [0.2, up - 0.05, up, up, 0.9]
    W[:, robot.joint_index["CHEST_JOINT1"]] = [0.3, 0.4, 0.5, 0.9, 0.6]
    traj = path_to_trajectory(W, TrajectoryOptions(joint_velocity=0.5))
    msg = msgs.joint_trajectory(robot.joint_names, traj.times, W, frame_id="world")
    ref = exec_msgs.reference_from_trajectory(msg, robot)
    assert ref.spline.check_limits(robot.lower, robot.upper, tol=0.0) is None
    monkeypatch.setattr(exec_msgs, "SplineTrajectory", ClampedSpline)
    with pytest.raises(RequestError, match=r"leaves the joint limits between points 2 and 3: RARM_JOINT2 "
                                           r"reaches 1\.6\d+ rad at t = "):
        exec_msgs.reference_from_trajectory(msg, robot)
