"""Unit tests of humanoid_reach_ros.io.msgs (conversions only, no ROS graph)."""
from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest
from geometry_msgs.msg import Pose

from humanoid_reach_ros.io import msgs


@pytest.mark.parametrize("t", [0.0, 1.5, 1795338388.953156495, 12.000000001])
def test_time_round_trip(t: float) -> None:
    stamp = msgs.time_from_seconds(t)
    assert 0 <= stamp.nanosec < 1_000_000_000
    assert msgs.seconds_from_time(stamp) == pytest.approx(t, abs=1e-6)  # float64 resolution at epoch times
    ns = msgs.nanoseconds_from_time(stamp)
    assert msgs.time_from_nanoseconds(ns) == stamp


def test_time_rejects_negative_and_non_finite() -> None:
    with pytest.raises(ValueError):
        msgs.time_from_seconds(-1.0)
    with pytest.raises(ValueError):
        msgs.time_from_seconds(math.nan)


def test_joint_state_build_parse_and_fill() -> None:
    msg = msgs.joint_state(["a", "b"], np.array([0.1, 0.2]), [1.0, 2.0], stamp=msgs.time_from_seconds(3.5),
                           frame_id="f")
    arrays = msgs.parse_joint_state(msg)
    assert arrays.names == ("a", "b") and arrays.stamp_s == 3.5 and msg.header.frame_id == "f"
    np.testing.assert_array_equal(arrays.positions, [0.1, 0.2])
    np.testing.assert_array_equal(arrays.velocities, [1.0, 2.0])
    assert arrays.efforts is None
    msgs.fill_joint_state(msg, np.array([0.3, 0.4]), np.array([0.0, -1.0]), msgs.time_from_seconds(4.0))
    np.testing.assert_array_equal(msg.position, [0.3, 0.4])
    np.testing.assert_array_equal(msg.velocity, [0.0, -1.0])
    assert msgs.seconds_from_time(msg.header.stamp) == 4.0


def test_joint_state_build_rejects_what_a_consumer_would_reject() -> None:
    with pytest.raises(ValueError, match="2 entries for 1 names"):
        msgs.joint_state(["a"], [0.1, 0.2])
    with pytest.raises(ValueError, match="non-finite"):
        msgs.joint_state(["a"], [math.nan])


def test_pose_round_trip() -> None:
    pose = pin.SE3(pin.rpy.rpyToMatrix(0.1, -0.2, 0.3), np.array([1.0, -2.0, 0.5]))
    msg = msgs.pose_stamped(pose, "world", msgs.time_from_seconds(1.0))
    assert msg.header.frame_id == "world"
    assert msgs.se3_from_pose(msg).isApprox(pose, 1e-12)
    assert msgs.se3_from_pose(msg.pose).isApprox(pose, 1e-12)


def test_se3_from_pose_rejects_bad_quaternions() -> None:
    bad = Pose()
    bad.orientation.w = 0.0  # all-zero quaternion
    with pytest.raises(ValueError, match="not unit length"):
        msgs.se3_from_pose(bad)
    bad.orientation.w = math.nan
    with pytest.raises(ValueError, match="non-finite"):
        msgs.se3_from_pose(bad)


def test_diagnostic_status() -> None:
    st = msgs.diagnostic_status("n: x", msgs.LEVEL_WARN, "msg", {"a": 1, "b": 0.5, "c": True, "d": "s"}, "hw")
    assert msgs.diagnostic_level(st) == msgs.LEVEL_WARN and st.hardware_id == "hw"
    assert msgs.diagnostic_values(st) == {"a": "1", "b": "0.5", "c": "true", "d": "s"}
    arr = msgs.diagnostic_array([st], msgs.time_from_seconds(2.0))
    assert arr.status[0].name == "n: x"
    with pytest.raises(ValueError):
        msgs.diagnostic_status("n", 7, "")
