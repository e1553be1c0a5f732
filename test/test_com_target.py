"""Target CoM from the three candidates of eq. 6 (dissertation Sec. 4.2)."""
from __future__ import annotations

import numpy as np
import pytest

from humanoid_reach_ros.dual_arm.com_target import ComTargetSelector, interpolate_com
from humanoid_reach_ros.dual_arm.targets import HandTargets
from humanoid_reach_ros.dual_arm.whole_body_ik import lowered_initial_posture
from humanoid_reach_ros.robot.model import RobotModel


@pytest.fixture(scope="module")
def sel():
    robot = RobotModel()
    q0 = lowered_initial_posture(robot, 0.08)
    return ComTargetSelector(robot, q0, 0.1)


def _pair(sel, wr, wl):
    """Hand targets whose wrist centres are at wr / wl (tool axis down, R = Ry(pi))."""
    R = np.diag([-1.0, 1.0, -1.0])
    pr = np.asarray(wr) + (R @ sel.tip_offset["right"][0].T) @ sel.tip_offset["right"][1]
    pl = np.asarray(wl) + (R @ sel.tip_offset["left"][0].T) @ sel.tip_offset["left"][1]
    t = HandTargets.make(pr, R, pl, R)
    np.testing.assert_allclose(sel.wrist("right", t.p_right, t.R_right), wr, atol=1e-12)
    return t


def test_three_candidates(sel):
    sr, sl = sel.shoulder["right"], sel.shoulder["left"]
    L = sel.l_arm["right"]
    near = _pair(sel, sr + [0.2, 0, -0.2], sl + [0.2, 0, -0.2])
    c = sel.select(near)
    assert c.label == "init" and c.reachable
    np.testing.assert_allclose(c.p_com, sel.p_com_init)
    high = _pair(sel, sr + [0.05, 0, L + 0.05], sl + [0.2, 0, 0.0])
    c = sel.select(high)
    assert c.label == "up" and c.reachable
    np.testing.assert_allclose(c.p_com - sel.p_com_init, [0, 0, 0.1])
    low = _pair(sel, sr + [0.05, 0, -L - 0.05], sl + [0.05, 0, -L - 0.05])
    c = sel.select(low)
    assert c.label == "down" and c.reachable
    np.testing.assert_allclose(c.p_com - sel.p_com_init, [0, 0, -0.1])


def test_unreachable_gives_candidate_or_flag(sel):
    sr, sl = sel.shoulder["right"], sel.shoulder["left"]
    # far forward, slightly low: the literal eq. 6 keeps init; the generalisation lowers
    fwd = _pair(sel, sr + [0.5, 0, -0.05], sl + [0.3, 0, 0])
    c = sel.select(fwd)
    assert c.label in ("init", "up", "down")
    assert c.excess[c.label] == min(c.excess.values())
    # far away: no candidate satisfies eq. 5 -> flagged, still a finite CoM
    away = _pair(sel, sr + [1.5, 0, 0], sl + [1.5, 0, 0])
    c = sel.select(away)
    assert not c.reachable and np.all(np.isfinite(c.p_com))


def test_interpolation():
    a, b = np.zeros(3), np.array([0.0, 0.0, -0.1])
    np.testing.assert_allclose(interpolate_com(a, b, 0.0), a)
    np.testing.assert_allclose(interpolate_com(a, b, 1.0), b)
    np.testing.assert_allclose(interpolate_com(a, b, 0.25), [0, 0, -0.025])
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        interpolate_com(a, b, 1.5)
    with pytest.raises(ValueError, match="finite"):
        interpolate_com([np.nan, 0, 0], b, 0.5)


def test_bad_offset():
    robot = RobotModel()
    with pytest.raises(ValueError, match="offset"):
        ComTargetSelector(robot, robot.half_sitting(), -0.1)
