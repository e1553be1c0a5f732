"""DualArmReachController (dissertation Sec. 4.5, 5.2-5.4) and the balance checks."""
from __future__ import annotations

import numpy as np
import pytest

from humanoid_reach_ros.dual_arm.balance import (
    com_projection, polygon_margin, support_polygon, zmp_trajectory,
)
from humanoid_reach_ros.dual_arm.controller import ControllerConfig, DualArmReachController

MARGIN_M = 0.02
#: fixed target pairs (right, left) [m] in the workspace: mid, low (squat), asymmetric
PAIRS = [
    ((0.428, -0.174, 0.984), (0.401, 0.237, 0.960)),
    ((0.546, -0.099, 0.908), (0.515, 0.170, 0.692)),
    ((0.510, -0.171, 1.177), (0.200, 0.290, 0.686)),
]


@pytest.fixture(scope="module")
def ctl():
    return DualArmReachController()


def _run(ctl, pr, pl):
    ctl.reset()
    t = ctl.ws.targets(np.array(pr), np.array(pl))
    plan = ctl.set_targets(t.p_right, t.R_right, t.p_left, t.R_left)
    steps = ctl.run()
    return t, plan, steps


def test_static_zmp_is_com_projection(ctl):
    q = ctl.q_init
    zmp = zmp_trajectory(ctl.robot, np.array([q, q, q]), 0.005)
    np.testing.assert_allclose(zmp, np.repeat(com_projection(ctl.robot, [q]), 3, 0), atol=1e-9)


def test_support_polygon(ctl):
    poly = support_polygon(ctl.robot)
    assert polygon_margin(poly, [0.0, 0.0])[0] > 0.1
    assert polygon_margin(poly, [0.3, 0.0])[0] < 0


@pytest.mark.parametrize("pair", PAIRS)
def test_fixed_targets_error_and_balance(ctl, pair):
    t, plan, steps = _run(ctl, *pair)
    assert plan.feasible, plan.reason
    assert len(steps) == plan.n_steps
    assert all(s.ok for s in steps), [s.reason for s in steps if not s.ok][:3]
    qs = np.array([s.q for s in steps])
    assert np.all(np.isfinite(qs))
    d = ctl.robot
    er = np.linalg.norm(d.frame_pose(qs[-1], "r_hand_ee").translation - t.p_right)
    el = np.linalg.norm(d.frame_pose(qs[-1], "l_hand_ee").translation - t.p_left)
    assert max(er, el) <= 1e-3
    assert max(s.com_error for s in steps) < 2e-3
    # speed limit 0.38 m/s at 5 ms on the hand references
    refs = np.array([s.hands.p_right for s in steps] + [s.hands.p_left for s in steps]).reshape(2, -1, 3)
    step_len = np.linalg.norm(np.diff(refs, axis=1), axis=2)
    assert step_len.max() <= 0.38 * 0.005 + 1e-12
    # balance at every step: CoM projection and RNEA ZMP inside the support polygon
    traj = np.vstack([ctl.q_init[None], qs, qs[-1:]])
    poly = support_polygon(d)
    assert polygon_margin(poly, com_projection(d, traj)).min() >= MARGIN_M
    assert polygon_margin(poly, zmp_trajectory(d, traj, ctl.config.period_s)).min() >= MARGIN_M


def test_low_targets_squat(ctl):
    _, plan, steps = _run(ctl, *PAIRS[1])
    assert plan.com.label == "down"
    assert steps[-1].q[2] < ctl.q_init[2] - 0.05


def test_unreachable_targets_fail_clearly_never_nan(ctl):
    ctl.reset()
    R = np.eye(3)
    plan = ctl.set_targets([1.4, -0.2, 1.0], R, [0.35, 0.25, 1.6], R)
    assert plan.com.label in ("init", "up", "down")
    assert not plan.feasible and "unreachable" in plan.reason
    steps = ctl.run()
    assert all(np.all(np.isfinite(s.joints)) for s in steps)
    assert not steps[-1].ok and "arm" in steps[-1].reason
    np.testing.assert_array_equal(steps[-1].q, ctl.q_init)     # refused before moving


@pytest.mark.parametrize("args,msg", [
    (([np.nan, 0, 1], np.eye(3), [0.3, 0.2, 1.0], np.eye(3)), "finite"),
    (([0.3, 0.2], np.eye(3), [0.3, 0.2, 1.0], np.eye(3)), "shape"),
    (([0.3, -0.2, 1.0], np.zeros((3, 3)), [0.3, 0.2, 1.0], np.eye(3)), "rotation"),
])
def test_bad_targets_raise_and_keep_state(ctl, args, msg):
    ctl.reset()
    q = ctl.q.copy()
    with pytest.raises(ValueError, match=msg):
        ctl.set_targets(*args)
    assert ctl.plan is None
    np.testing.assert_array_equal(ctl.step().q, q)      # no target: posture held


def test_sequential_random_targets(ctl):
    ctl.reset()
    ctl.start_sequential(2, seed=3)
    steps = ctl.run(max_steps=5000)
    assert 0 < len(steps) < 5000
    assert sum(s.done for s in steps) == 2
    assert all(np.all(np.isfinite(s.joints)) and s.joints.shape == (30,) for s in steps)
    # the targets were drawn among those the method reaches: both pairs were executed
    assert all(s.ok for s in steps), [s.reason for s in steps if not s.ok][:1]
    # the same pairs given explicitly (e.g. drawn by another thread) give the same motion
    PR, PL = ctl.sample_reachable(np.random.default_rng(3), 2)
    ctl.reset()
    ctl.start_sequential(2, pairs=(PR, PL))
    again = ctl.run(max_steps=5000)
    np.testing.assert_array_equal(again[-1].q, steps[-1].q)
    for bad in ((PR[:1], PL), (PR, PL * np.nan), (PR.ravel(), PL)):
        with pytest.raises(ValueError, match="pairs must be two finite"):
            ctl.start_sequential(2, pairs=bad)
    ctl.reset()


def test_bad_config(ctl):
    with pytest.raises(ValueError, match="period_s"):
        ControllerConfig(period_s=0.0)
    with pytest.raises(ValueError, match="max_speed_mps"):
        ControllerConfig(max_speed_mps=float("nan"))
    with pytest.raises(ValueError, match="count"):
        ctl.start_sequential(0)


def test_sample_reachable_targets_are_reached_and_state_kept(ctl):
    ctl.reset()
    t = ctl.ws.targets(np.array(PAIRS[0][0]), np.array(PAIRS[0][1]))
    ctl.set_targets(t.p_right, t.R_right, t.p_left, t.R_left)
    for _ in range(5):
        ctl.step()
    q, k, plan = ctl.q.copy(), ctl._k, ctl.plan
    PR, PL = ctl.sample_reachable(np.random.default_rng(11), 3)
    # the running motion is untouched
    np.testing.assert_array_equal(ctl.q, q)
    assert ctl._k == k and ctl.plan is plan
    ws = ctl.ws
    assert PR.shape == PL.shape == (3, 3)
    assert np.all((PR >= ws.right_lower) & (PR <= ws.right_upper))
    assert np.all((PL >= ws.left_lower) & (PL <= ws.left_upper))
    mirror = np.array([1.0, -1.0, 1.0])
    for pr, pl in zip(PR, PL):      # each hand's symmetric pair is reached from the initial posture
        for a, b in ((pr, pr * mirror), (pl * mirror, pl)):
            _, p, steps = _run(ctl, a, b)
            assert p.feasible and steps and all(s.ok for s in steps)
    with pytest.raises(ValueError, match="n must be"):
        ctl.sample_reachable(np.random.default_rng(0), -1)
    # the whole box is not reachable: a tiny draw budget gives up clearly
    with pytest.raises(ValueError, match="reachable right hand targets in 1 draws"):
        ctl.sample_reachable(np.random.default_rng(0), 5, max_draws=1)
    ctl.reset()


def test_step_failing_between_checks_holds_and_stops(ctl):
    """A pair whose end is reachable but whose path is not: with a single check point the
    plan is accepted, the motion fails mid-way, and then the whole configuration is held
    (no later jump), the motion ends and no NaN comes out."""
    coarse = DualArmReachController(robot=ctl.robot, regression=ctl.regression, workspace=ctl.ws,
                                    config=ControllerConfig(path_checks=1))
    rng = np.random.default_rng(5)
    for _ in range(400):
        pr, pl = ctl.ws.sample(rng, 1)
        t = ctl.ws.targets(pr[0], pl[0])
        ctl.reset()
        if ctl.final_configuration(t).ok and not ctl.set_targets(t.p_right, t.R_right, t.p_left, t.R_left).feasible:
            break
    else:
        pytest.fail("no pair with a reachable end and an unreachable path in 400 draws")
    ctl.reset()
    coarse.reset()
    assert coarse.set_targets(t.p_right, t.R_right, t.p_left, t.R_left).feasible
    steps = coarse.run()
    bad = [i for i, s in enumerate(steps) if not s.ok]
    assert bad == [len(steps) - 1], "the first failed step ends the motion"
    failed = steps[-1]
    assert failed.done and "stopped at" in failed.reason and "posture held" in failed.reason
    prev_q = steps[-2].q if len(steps) > 1 else coarse.q_init
    np.testing.assert_array_equal(failed.q, prev_q)
    assert np.all(np.isfinite(failed.q))
    assert not coarse.busy
    for _ in range(3):              # then the posture is held
        np.testing.assert_array_equal(coarse.step().q, prev_q)
    # a new target starts from what is held: its first step moves the hands only a little
    pr, pl = PAIRS[0]
    t2 = ctl.ws.targets(np.array(pr), np.array(pl))
    assert coarse.set_targets(t2.p_right, t2.R_right, t2.p_left, t2.R_left).feasible
    first = coarse.step()
    assert first.ok
    assert np.max(np.abs(first.q[7:] - prev_q[7:])) < 0.05
