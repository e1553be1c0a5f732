"""WorkspaceGoalRegion: validation, eq. 3 sampling, membership with angle wrap-around."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from humanoid_reach_ros.planning.wgr import ANGLE_TOL, WorkspaceGoalRegion, clamp_angle_bounds, matrix_rpy, \
    rpy_matrix, valve_region

PI = math.pi


def rot(axis: str, a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
            "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def region(lo, hi, p=(0.0, 0.0, 0.0), R=None):
    return WorkspaceGoalRegion(np.array(p, float), np.eye(3) if R is None else R, np.array(lo, float),
                               np.array(hi, float))


@pytest.mark.parametrize("kwargs, text", [
    (dict(lo=[0, 0, 0, 0, 0, 0], hi=[0, 0, 0, 0, 0, np.nan]), "non-finite"),
    (dict(lo=[0, 0.1, 0, 0, 0, 0], hi=[0, 0, 0, 0, 0, 0]), "lower > upper for y"),
    (dict(lo=[0, 0, 0, -4, 0, 0], hi=[0, 0, 0, 0, 0, 0]), "within \\[-pi, pi\\]"),
    (dict(lo=[0, 0, 0, 0], hi=[0, 0, 0, 0]), "6 values"),
    (dict(lo=[0] * 6, hi=[0] * 6, R=np.diag([1.0, 1.0, -1.0])), "not a rotation"),
])
def test_validation(kwargs, text):
    with pytest.raises(ValueError, match=text):
        region(kwargs["lo"], kwargs["hi"], R=kwargs.get("R"))


@pytest.mark.parametrize("typed", [3.1416, 3.14159, 3.142, math.pi + ANGLE_TOL, math.radians(180.0)])
def test_angle_bounds_near_pi_are_clamped(typed: float) -> None:
    """A typed pi (3.1416, 180 deg) is pi: accepted and clamped, on every angle and both sides."""
    r = region([0, 0, 0, -typed, -typed, -typed], [0, 0, 0, typed, typed, typed])
    expected = min(typed, PI)  # 3.14159 lies inside and is kept as typed
    np.testing.assert_array_equal(r.lower[3:], [-expected] * 3)
    np.testing.assert_array_equal(r.upper[3:], [expected] * 3)
    assert np.all(np.abs(r.lower[3:]) <= PI) and np.all(np.abs(r.upper[3:]) <= PI)
    assert r.contains(np.zeros(3), rot("z", 3.0))
    if typed >= PI:  # the clamped yaw interval is the whole circle: every yaw is inside
        assert r.contains(np.zeros(3), rot("z", -PI)) and r.contains(np.zeros(3), rot("z", PI))
    # bounds inside [-pi, pi] are kept exactly
    r = region([0, 0, 0, -1.5708, -1.5708, -3.0], [0, 0, 0, 1.5708, 1.5708, 3.0])
    np.testing.assert_array_equal(r.lower[3:], [-1.5708, -1.5708, -3.0])


@pytest.mark.parametrize("side, index, value", [
    ("upper", 5, PI + 1.5e-3), ("lower", 3, -PI - 0.01), ("upper", 4, 4.0), ("lower", 5, -180.0),
])
def test_angle_bounds_beyond_the_tolerance_are_refused(side: str, index: int, value: float) -> None:
    lo, hi = [0.0, 0.0, 0.0, -1.0, -1.0, -1.0], [0.0, 0.0, 0.0, 1.0, 1.0, 1.0]
    (lo if side == "lower" else hi)[index] = value
    name = ("roll", "pitch", "yaw")[index - 3]
    with pytest.raises(ValueError, match=r"within \[-pi, pi\]") as exc:
        region(lo, hi)
    text = str(exc.value)
    assert f"{side} {name} {value!r}" in text and "beyond pi" in text and "clamped" in text


def test_clamp_angle_bounds_unit() -> None:
    lo, hi = clamp_angle_bounds(np.array([-3.1416, 0.0, -PI]), np.array([3.1416, 0.5, PI]))
    np.testing.assert_array_equal(lo, [-PI, 0.0, -PI])
    np.testing.assert_array_equal(hi, [PI, 0.5, PI])
    with pytest.raises(ValueError, match="upper roll 3.2"):
        clamp_angle_bounds(np.zeros(3), np.array([3.2, 0.0, 0.0]))
    # the tolerance is a parameter
    with pytest.raises(ValueError):
        clamp_angle_bounds(np.zeros(3), np.array([3.1416, 0.0, 0.0]), tol=1e-6)


def test_rpy_convention_and_inverse():
    r, p, y = 0.3, -0.4, 1.2
    np.testing.assert_allclose(rpy_matrix(np.array([r, p, y])), rot("z", y) @ rot("y", p) @ rot("x", r), atol=1e-15)
    np.testing.assert_allclose(matrix_rpy(rpy_matrix(np.array([r, p, y]))), [r, p, y], atol=1e-12)


def test_valve_region_is_eq3():
    reg = valve_region()
    np.testing.assert_allclose(reg.target_p + reg.lower[:3], [0.71, 0.03, 0.9])
    np.testing.assert_allclose(reg.target_p + reg.upper[:3], [0.71, 0.03, 0.9])
    np.testing.assert_allclose(reg.lower[3:], [-PI / 2, -PI / 2, -PI])
    np.testing.assert_allclose(reg.upper[3:], [PI / 2, PI / 2, PI])
    H = np.eye(4)
    H[:3, 3] = [0.71, 0.03, 0.9]
    np.testing.assert_allclose(valve_region(H).target_p, reg.target_p)
    p, R = reg.sample(np.random.default_rng(0), 500)
    np.testing.assert_allclose(p, np.tile([0.71, 0.03, 0.9], (500, 1)))
    assert np.all(R[:, 2, 2] >= -1e-12)   # hand z axis in the upper hemisphere
    assert reg.contains(p, R).all()


def test_sample_form_and_contains():
    R_T = rot("z", 0.7) @ rot("x", 0.2)
    reg = region([-0.1, -0.05, 0, -0.3, -0.2, 2.0], [0.1, 0.05, 0.2, 0.3, 0.4, PI], p=(1, 2, 3), R=R_T)
    rng = np.random.default_rng(1)
    off = reg.sample_offsets(rng, 200)
    p, R = reg.poses_from_offsets(off)
    np.testing.assert_allclose(p[5], [1, 2, 3] + R_T @ off[5, :3])
    np.testing.assert_allclose(R[5], R_T @ rot("z", off[5, 5]) @ rot("y", off[5, 4]) @ rot("x", off[5, 3]))
    assert reg.contains(p, R).all()
    assert reg.contains(p[0], R[0]) is True
    # outside in position, in each angle
    assert not reg.contains(p[0] + R_T @ np.array([0, 0.2, 0]), R[0])
    for k, bad in ((3, 0.5), (4, -0.5), (5, 0.0)):
        o = off[0].copy()
        o[k] = bad
        pp, RR = reg.poses_from_offsets(o[None])
        assert not reg.contains(pp[0], RR[0])


def test_contains_wraps_yaw():
    reg = region([0] * 3 + [0, 0, 3.0], [0] * 3 + [0, 0, PI])
    assert reg.contains(np.zeros(3), rot("z", -PI + 1e-13))       # -pi == pi
    assert reg.contains(np.zeros(3), rot("z", 3.1))
    assert not reg.contains(np.zeros(3), rot("z", -3.0))
    # a band across +-pi
    reg2 = region([0] * 3 + [-PI, 0, 0], [0] * 3 + [PI, 0, 0])
    assert reg2.contains(np.zeros(3), rot("x", 3.0))


def test_contains_alternative_decomposition_and_gimbal():
    # (3, 3, 3) is also (3 - pi, pi - 3, 3 - pi) = matrix_rpy's answer: the alternative form is needed
    reg = region([0] * 3 + [2.9, 0, 2.9], [0] * 3 + [PI, PI, PI])
    R = rot("z", 3.0) @ rot("y", 3.0) @ rot("x", 3.0)   # matrix_rpy gives pitch ~ 0.14: alt form needed
    assert reg.contains(np.zeros(3), R)
    # gimbal lock: at pitch = +pi/2 only roll - yaw is defined (here in [0 - 0.6, 0.2 - 0.5])
    reg3 = region([0] * 3 + [0.0, -PI / 2, 0.5], [0] * 3 + [0.2, PI / 2, 0.6])
    assert reg3.contains(np.zeros(3), rot("y", PI / 2) @ rot("x", -0.4))       # e.g. roll 0.1, yaw 0.5
    assert not reg3.contains(np.zeros(3), rot("y", PI / 2) @ rot("x", 0.15))
    assert reg3.contains(np.zeros(3), rot("z", 0.55) @ rot("y", PI / 2) @ rot("x", 0.1))


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-PI, PI), min_size=3, max_size=3), st.lists(st.floats(0, 1), min_size=6, max_size=6))
def test_contains_accepts_every_sample(center, width):
    lo = np.array([-width[0], -width[1], -width[2], *(np.array(center) - np.array(width[3:]) * PI)])
    hi = np.array([width[0], width[1], width[2], *(np.array(center) + np.array(width[3:]) * PI)])
    lo[3:] = np.clip(lo[3:], -PI, PI)
    hi[3:] = np.clip(hi[3:], -PI, PI)
    lo[3:], hi[3:] = np.minimum(lo[3:], hi[3:]), np.maximum(lo[3:], hi[3:])
    reg = region(lo, hi, p=(0.3, -0.2, 1.0), R=rot("y", 0.4))
    p, R = reg.sample(np.random.default_rng(0), 50)
    assert reg.contains(p, R, tol=1e-7).all()


def test_negative_zero_bounds_sample() -> None:
    """An upper bound of -0.0 (what `-lower` gives for lower 0.0) equals lower 0.0: the
    region samples instead of numpy's "high - low < 0" (a plan request answered
    INTERNAL_ERROR before)."""
    lo = np.array([0.0, 0.0, 0.0, -1.0, -1.0, -np.pi])
    region = WorkspaceGoalRegion(np.zeros(3), np.eye(3), lo, -lo)
    p, R = region.sample(np.random.default_rng(0), 8)
    assert np.all(p == 0.0) and R.shape == (8, 3, 3)
