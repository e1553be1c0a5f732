"""The executor's joint acceleration bound (``max_joint_acceleration_rad_s2``): every command a
real robot's servos can follow, with the exact COG, the feet and the dampers kept.

Each scenario is also run without the bound (0.0) and must exceed it there: the test would fail
without the bound. No timing assertions."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from humanoid_reach_ros.control.executor import ExecutorParams, WholeBodyExecutor
from humanoid_reach_ros.control.limits import braking_speed, damper_braking_bound, damper_bound, joint_step_box
from humanoid_reach_ros.geometry.sphere_tree import SphereTree
from humanoid_reach_ros.geometry.trajectory import SplineTrajectory

DT = 0.005
A = 10.0
TOL = 1e-3          # rad/s^2: the solvers hold a row to ~1e-9 rad a step, 4e-5 rad/s^2 over 5 ms


def _accelerations(q0_joints, results) -> np.ndarray:
    J = np.vstack([q0_joints] + [r.joints for r in results])
    return np.abs(np.diff(J, n=2, axis=0)) / DT ** 2


def _soles(robot, q):
    return [robot.frame_pose(q, f) for f in robot.sole_frames]


def _run(ex, n):
    return [ex.step() for _ in range(n)]


def test_a_fast_reference_and_its_hold_stay_within_the_bound(robot, cm):
    """A 0.3 s reference of 0.8 rad on three arm joints (about 50 rad/s^2 in the reference) and a
    hold mid-motion: every command's acceleration within the bound, COG and feet exact."""
    hs = robot.half_sitting_joints
    j1 = hs.copy()
    for n, d in (("RARM_JOINT0", -0.8), ("RARM_JOINT3", -0.8), ("CHEST_JOINT0", 0.4)):
        j1[robot.joint_index[n]] += d
    ref = SplineTrajectory(np.vstack([hs, j1]), np.array([0.0, 0.3]))
    out = {}
    for a in (A, 0.0):
        ex = WholeBodyExecutor(robot, cm, ExecutorParams(velocity_scale=0.5, max_joint_acceleration_rad_s2=a))
        q0 = robot.half_sitting()
        ex.start(q0, ref, "right")
        res = _run(ex, 40)
        ex.hold()                                   # a stop while the arm moves fast
        res += _run(ex, 400)
        out[a] = _accelerations(hs, res).max()
        if a > 0:
            assert out[a] <= a + TOL, out[a]
            assert all(r.metrics.accel_relaxed == 0 for r in res)
            assert max(r.metrics.com_error_m for r in res) < 2e-5     # the COG held (linearisation error)
            for s0, s1 in zip(_soles(robot, q0), _soles(robot, res[-1].q)):
                assert np.linalg.norm(s1.translation - s0.translation) < 1e-6
            # the hold brought it to rest (no swing back through the hold point)
            assert np.max(np.abs(res[-1].joints - res[-2].joints)) < 1e-9
    assert out[0.0] > 5 * A          # without the bound the same commands jump


def test_a_start_from_a_moving_command_keeps_its_velocity(robot, cm):
    """A motion preempted mid-way by another from its last sent command: the new motion starts
    at the command's velocity (no stop in one step)."""
    hs = robot.half_sitting_joints
    j1 = hs.copy()
    j1[robot.joint_index["RARM_JOINT0"]] -= 0.8
    ref = SplineTrajectory(np.vstack([hs, j1]), np.array([0.0, 1.0]))
    ex = WholeBodyExecutor(robot, cm, ExecutorParams(velocity_scale=0.5, max_joint_acceleration_rad_s2=A))
    ex.start(robot.half_sitting(), ref, "right")
    res = _run(ex, 100)                              # mid-motion, about 1.2 rad/s
    sent = res[-3]                                   # the supervisor restarts from the last *sent* command
    back = SplineTrajectory(np.vstack([sent.joints, hs]), np.array([0.0, 1.0]))
    ex.start(sent.q, back, "right")
    res2 = _run(ex, 300)
    acc = _accelerations(res[-4].joints, [res[-3]] + res2)
    assert acc.max() <= A + TOL, acc.max()


def test_the_damper_brakes_the_hand_before_a_wall_within_the_bound(robot, cm):
    """The hand driven at a wall of spheres 15 cm ahead: the dampers' braking curve stops it
    outside d_s with every joint acceleration within the bound (no step needed more), while the
    plain per-step damper (no bound) brakes it late and hard."""
    q0 = robot.half_sitting()
    hand0 = robot.frame_pose(q0, "r_hand_ee")
    yz = np.mgrid[-0.25:0.25:0.03, -0.25:0.25:0.03].reshape(2, -1).T
    wall = np.column_stack([np.full(len(yz), 0.15), yz]) + hand0.translation
    hs = robot.half_sitting_joints
    out = {}
    for a in (A, 0.0):
        ex = WholeBodyExecutor(robot, cm, ExecutorParams(security_distance_m=0.01, velocity_scale=0.5,
                                                         max_joint_acceleration_rad_s2=a))
        ex.set_environment(SphereTree.build(wall, 0.02))
        ex.start(q0, SplineTrajectory(hs[None], np.zeros(1)), "right")
        target = [pin.SE3(hand0.rotation, hand0.translation)]
        ex.reference_hand = lambda joints, target=target: target[0]
        res = []
        for k in range(300):                         # the target moves through the wall at 0.6 m/s
            target[0] = pin.SE3(hand0.rotation, hand0.translation + np.array([min(0.003 * k, 0.3), 0.0, 0.0]))
            res.append(ex.step())
        out[a] = _accelerations(hs, res).max()
        dmin = min(r.metrics.min_distance_m for r in res)
        assert dmin >= 0.007, (a, dmin)               # held at d_s (first-order dampers: mm of linearisation)
        assert res[-1].metrics.hand_error_m > 0.05    # the hand did not get through
        if a > 0:
            assert out[a] <= a + TOL, out[a]
            assert all(r.metrics.accel_relaxed >= 0 for r in res)
            assert max(r.metrics.com_error_m for r in res) < 2e-5
    assert out[0.0] > 5 * A


def test_joints_brake_before_their_limits(robot, cm):
    """A reference far beyond three joints' limits: each joint arrives at its limit on the braking
    curve, never outside the range, every acceleration within the bound but in the rare steps
    the executor flags (-1000: a self-collision pair that the free arm, swung by the COG task
    against the limits, brought into the influence distance faster than its braking curve)."""
    names = ("RARM_JOINT0", "RARM_JOINT3", "LARM_JOINT1")
    hs = robot.half_sitting_joints
    j1 = hs.copy()
    for n in names:
        i = robot.joint_index[n]
        j1[i] = robot.upper[i] + 0.5 if n != "RARM_JOINT3" else robot.lower[i] - 0.5
    ref = SplineTrajectory(np.vstack([hs, j1]), np.array([0.0, 1.0]))
    ex = WholeBodyExecutor(robot, cm, ExecutorParams(velocity_scale=0.5, max_joint_acceleration_rad_s2=A))
    ex.start(robot.half_sitting(), ref, "right")
    res = _run(ex, 400)
    for r in res:
        assert np.all(r.joints >= robot.lower) and np.all(r.joints <= robot.upper)
    acc = _accelerations(hs, res).max(axis=1)       # acc[i]: the change step i + 1 made
    flag = np.array([r.metrics.accel_relaxed for r in res])
    assert acc[flag[1:] == 0].max() <= A + TOL
    assert np.count_nonzero(flag) <= 0.1 * len(res), flag[flag != 0]   # 32 of 400 here (-40, -1000)
    idx = [robot.joint_index[n] for n in names]
    gap = min(min(r.joints[i] - robot.lower[i], robot.upper[i] - r.joints[i]) for r in res for i in idx)
    assert gap < 1e-3                              # the run really brought a joint to its limit


# ---------------------------------------------------------------- the rows
def test_braking_speed_is_recursively_feasible():
    rng = np.random.default_rng(0)
    for _ in range(200):
        a, dt, s = rng.uniform(0.5, 20.0), rng.choice([0.005, 0.01, 0.02]), rng.uniform(0.0, 0.5)
        v = float(braking_speed(s, a, dt))
        assert v * dt + v * v / (2 * a) <= s + 1e-12
        v_next = max(v - a * dt, 0.0)
        assert v_next <= float(braking_speed(s - v * dt, a, dt)) + 1e-9


def test_joint_step_box_holds_the_acceleration_and_gives_way_to_the_limits():
    lower, upper, vmax = np.array([-1.0, -1.0]), np.array([1.0, 1.0]), np.array([2.0, 2.0])
    # free joints: the box is v_prev +- a dt
    up, lo, relaxed = joint_step_box(np.zeros(2), lower, upper, vmax, np.array([0.5, -0.5]), A, DT)
    np.testing.assert_allclose(up / DT, [0.5 + A * DT, -0.5 + A * DT])
    np.testing.assert_allclose(-lo / DT, [0.5 - A * DT, -0.5 - A * DT])
    assert not relaxed.any()
    # a joint faster than its limit allows right at its upper limit: the limit wins (relaxed)
    up, lo, relaxed = joint_step_box(np.array([1.0, 0.0]), lower, upper, vmax, np.array([1.5, 0.0]), A, DT)
    assert relaxed[0] and not relaxed[1] and up[0] <= 1e-15


def test_damper_braking_bound_is_within_the_plain_damper_and_never_negative():
    d = np.linspace(-0.01, 0.12, 50)
    for v in (0.0, 0.3, 3.0):
        h = damper_braking_bound(d, 0.01, 0.5, np.full(len(d), v), 1.5, DT)
        assert np.all(h >= 0.0) and np.all(h <= damper_bound(d, 0.01, 0.5) + 1e-15)
    # far from d_s a pair approaching faster than the curve keeps braking at the deceleration
    h = damper_braking_bound(np.array([0.05]), 0.01, 0.5, np.array([3.0]), 1.5, DT)
    assert h[0] == pytest.approx((3.0 - 1.5 * DT) * DT)
