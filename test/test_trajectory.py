"""Path -> monotone cubic (PCHIP, zero end slopes) trajectory (Kanehiro Sec. IV; the paper's clamped
cubic spline overshot the joint limits between waypoints: test/test_trajectory_limits.py)."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from hypothesis.extra.numpy import arrays

from humanoid_reach_ros.geometry.trajectory import (
    SplineTrajectory, TrajectoryOptions, path_to_trajectory, segment_durations,
)

WAYPOINTS = np.array([[0.0, 0.0, 0.0], [0.5, -0.2, 0.1], [0.6, 0.4, 0.1], [0.2, 0.4, -0.3]])


def test_durations_rule():
    v = np.array([0.5, 1.0, 0.25])
    T = segment_durations(WAYPOINTS, v, 0.01)
    expected = [max(0.5 / 0.5, 0.2 / 1.0, 0.1 / 0.25), max(0.1 / 0.5, 0.6 / 1.0, 0.0), max(0.4 / 0.5, 0.0, 0.4 / 0.25)]
    np.testing.assert_allclose(T, expected)
    # repeated waypoint -> minimum duration
    np.testing.assert_allclose(segment_durations(np.zeros((2, 3)), 1.0, 0.05), [0.05])
    with pytest.raises(ValueError):
        segment_durations(WAYPOINTS, 0.0, 0.01)


def test_passes_through_waypoints_at_times_and_rests_at_ends():
    traj = path_to_trajectory(WAYPOINTS, TrajectoryOptions(joint_velocity=(0.5, 1.0, 0.25)))
    np.testing.assert_allclose(traj.times,
                               np.concatenate([[0], np.cumsum(segment_durations(WAYPOINTS, [0.5, 1.0, 0.25], 0.01))]))
    np.testing.assert_allclose(traj.position(traj.times), WAYPOINTS, atol=1e-12)
    np.testing.assert_allclose(traj.velocity(traj.times[0]), 0.0, atol=1e-12)
    np.testing.assert_allclose(traj.velocity(traj.times[-1]), 0.0, atol=1e-12)
    q, qd, qdd = traj.evaluate(0.3)
    assert q.shape == qd.shape == qdd.shape == (3,)
    # clamped outside the time range: at rest at the end points
    np.testing.assert_allclose(traj.position(traj.duration + 1.0), WAYPOINTS[-1])


def test_velocity_continuous_at_knots_acceleration_may_jump():
    # PCHIP is C1: the clamped spline's continuous acceleration was the price of its overshoot
    # (its C2 condition is what pushes a joint past the waypoints); velocity stays continuous
    traj = path_to_trajectory(WAYPOINTS, TrajectoryOptions(joint_velocity=0.5))
    eps = 1e-7
    jumps = []
    for t in traj.times[1:-1]:
        np.testing.assert_allclose(traj.velocity(t - eps), traj.velocity(t + eps), atol=1e-5)
        jumps.append(np.abs(traj.acceleration(t - eps) - traj.acceleration(t + eps)).max())
    assert max(jumps) > 0.1      # measured 2.3 rad/s^2 on this path: the knots really are only C1


def test_single_segment_peak_is_one_and_a_half_v_and_rescaling_restores_the_bound():
    wp = np.array([[0.0, 0.0], [1.0, 0.5]])
    traj = path_to_trajectory(wp, TrajectoryOptions(joint_velocity=0.5))
    assert traj.duration == pytest.approx(2.0)
    np.testing.assert_allclose(traj.max_velocity, [0.75, 0.375])
    scaled = path_to_trajectory(wp, TrajectoryOptions(joint_velocity=0.5, respect_velocity_limit=True))
    assert scaled.duration == pytest.approx(3.0)
    assert np.all(scaled.max_velocity <= 0.5 + 1e-12)


def test_max_velocity_matches_dense_sampling():
    traj = path_to_trajectory(WAYPOINTS, TrajectoryOptions(joint_velocity=0.4))
    dense = np.abs(traj.velocity(np.linspace(0, traj.duration, 20001))).max(axis=0)
    assert np.all(traj.max_velocity >= dense - 1e-12)
    np.testing.assert_allclose(traj.max_velocity, dense, rtol=1e-4)


def test_resampling_period_and_points():
    traj = path_to_trajectory(WAYPOINTS, TrajectoryOptions(joint_velocity=0.5))
    for period in (0.005, 0.1, 0.37):
        pts = traj.to_points(period)
        assert pts.times[0] == 0.0 and pts.times[-1] == pytest.approx(traj.duration)
        steps = np.diff(pts.times)
        np.testing.assert_allclose(steps[:-1], period, atol=1e-12)
        assert 0 < steps[-1] <= period + 1e-12
        assert pts.positions.shape == pts.velocities.shape == pts.accelerations.shape == (len(pts.times), 3)
        np.testing.assert_allclose(pts.positions[-1], WAYPOINTS[-1], atol=1e-12)
        np.testing.assert_allclose(pts.velocities[[0, -1]], 0.0, atol=1e-12)


def test_single_waypoint_is_at_rest():
    traj = path_to_trajectory(WAYPOINTS[:1])
    assert traj.duration == 0.0
    pts = traj.to_points(0.005)
    assert len(pts.times) == 1
    np.testing.assert_allclose(pts.positions[0], WAYPOINTS[0])
    np.testing.assert_allclose(traj.max_velocity, 0.0)


@settings(max_examples=40, deadline=None)
@given(arrays(float, st.tuples(st.integers(2, 6), st.integers(1, 4)),
              elements=st.floats(-2.0, 2.0, allow_nan=False)),
       st.floats(0.1, 2.0))
def test_property_waypoints_rest_and_durations(wp, v):
    traj = path_to_trajectory(wp, TrajectoryOptions(joint_velocity=v, min_segment_duration_s=0.01))
    np.testing.assert_allclose(traj.position(traj.times), wp, atol=1e-9)
    np.testing.assert_allclose(traj.velocity(traj.times[[0, -1]]), 0.0, atol=1e-9)
    T = np.diff(traj.times)
    assert np.all(T >= 0.01 - 1e-12)
    assert np.all(np.abs(np.diff(wp, axis=0)).max(axis=1) / v <= T + 1e-9)


def test_explicit_times_constructor_validates():
    with pytest.raises(ValueError):
        SplineTrajectory(WAYPOINTS, [0.0, 1.0, 1.0, 2.0])
    with pytest.raises(ValueError):
        SplineTrajectory(WAYPOINTS, [0.0, 1.0])
