"""Tests of humanoid_reach_ros.planning.reshape (smooth reshaping, Yoshida et al. Sec. IV)."""
from __future__ import annotations

import numpy as np
import pytest

from humanoid_reach_ros.geometry.sphere_tree import SphereTree
from humanoid_reach_ros.planning.reshape import ReshapeParams, SmoothReshaper, _bump, _pinned_ends, _runs
from humanoid_reach_ros.geometry.trajectory import SplineTrajectory

DT = 0.005


def test_runs_and_pinned_ends():
    m = np.array([1, 1, 0, 0, 1, 1, 1, 0, 1], bool)
    assert _runs(m) == [(0, 1), (4, 6), (8, 8)]
    assert _runs(np.zeros(4, bool)) == []
    p = _pinned_ends(m)
    assert list(np.flatnonzero(p)) == [0, 1, 8]


def test_bump_is_a_smooth_plateau():
    t = np.arange(0, 201) * DT
    w = _bump(t, 20, 80, 120, 180)
    assert np.all(w[:20] == 0) and np.all(w[181:] == 0)
    assert w[80] == pytest.approx(1.0) and w[120] == pytest.approx(1.0)
    assert w[20] == pytest.approx(0.0, abs=1e-12) and w[180] == pytest.approx(0.0, abs=1e-12)
    # C1 at the junctions: the slope is ~0 at both ends of the window
    assert abs(w[21] - w[20]) < 1e-3 and abs(w[180] - w[179]) < 1e-3


@pytest.fixture(scope="module")
def colliding_case(robot):
    """Right arm swings forward through a small obstacle placed on the hand's path."""
    hs = robot.half_sitting_joints
    j1 = hs.copy()
    j1[robot.joint_index["RARM_JOINT0"]] -= 1.2
    ref = SplineTrajectory(np.vstack([hs, j1]), np.array([0.0, 2.0]))
    q_mid = robot.config(ref.position(1.0), robot.base_on_feet(ref.position(1.0)))
    hand = robot.frame_pose(q_mid, "r_hand_ee").translation
    ball = hand + np.array([0.0, 0.0, -0.01])
    return ref, SphereTree.build(ball[None], 0.045)


def test_reshape_removes_the_collision_smoothly(robot, cm, colliding_case):
    ref, tree = colliding_case
    rs = SmoothReshaper(robot, cm, ReshapeParams(samples=120))
    res = rs.reshape(ref, tree, "right")
    assert res.distance_reference.min() < 0.0         # the planner samples collide
    assert res.distance_before.min() < rs.params.clearance_m   # and so does the balanced motion
    assert res.reshaped and res.success
    assert res.distance_after.min() >= rs.params.clearance_m - 1e-9
    p = res.portions[0]
    assert p.a < p.u1 <= p.u2 < p.b
    # windows from v_ref: the displacement is spread over enough samples
    assert (p.u1 - p.a) * DT >= 1.5 * p.offset_m / rs.params.v_ref_mps - DT
    # smooth: joint velocities stay moderate, no jumps
    qd = np.diff(res.joints, axis=0) / DT
    assert np.abs(qd).max() < 3.0
    # start and goal are kept
    assert np.allclose(res.joints[0], ref.position(0.0), atol=1e-3)
    goal_hand = robot.frame_pose(robot.config(ref.position(ref.duration), robot.base_on_feet(ref.position(
        ref.duration))), "r_hand_ee")
    end = res.joints[-1]
    got = robot.frame_pose(robot.config(end, robot.base_on_feet(end)), "r_hand_ee")
    assert np.linalg.norm(got.translation - goal_hand.translation) < 2e-3
    # the result is a trajectory the executor can take
    assert res.trajectory.n_joints == robot.n_joints and res.trajectory.times[0] == 0.0


def test_nothing_to_reshape_far_from_obstacles(robot, cm, colliding_case):
    ref, _ = colliding_case
    far = SphereTree.build(np.array([[3.0, 3.0, 3.0]]), 0.05)
    res = SmoothReshaper(robot, cm).reshape(ref, far, "right")
    assert not res.reshaped and res.success
    assert res.distance_after.min() > 1.0


def test_bad_inputs(robot, cm, colliding_case):
    ref, tree = colliding_case
    rs = SmoothReshaper(robot, cm)
    with pytest.raises(ValueError, match="unknown arm"):
        rs.reshape(ref, tree, "both")
    with pytest.raises(ValueError, match="SphereTree"):
        rs.reshape(ref, None, "right")
    with pytest.raises(ValueError, match="joints"):
        rs.reshape(SplineTrajectory(np.zeros((2, 4)), np.array([0.0, 1.0])), tree, "right")
    with pytest.raises(ValueError, match="v_ref_mps"):
        ReshapeParams(v_ref_mps=0.0)
