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


def _joint_state(names, positions):
    from sensor_msgs.msg import JointState
    return JointState(name=list(names), position=[float(v) for v in positions])


def test_model_joints_ignores_unknown_names_and_requires_every_model_joint() -> None:
    """The one /joint_states policy: other devices' joints are ignored, every model joint is required."""
    from humanoid_reach_ros.robot.model import RobotModel

    model = RobotModel()
    names, hs = list(model.joint_names), model.half_sitting_joints
    order = np.random.default_rng(1).permutation(len(names))       # any order
    q, why = msgs.model_joints(_joint_state([names[i] for i in order], hs[order]), model)
    assert why == "" and q.shape == (model.n_joints,)
    np.testing.assert_array_equal(q, hs)
    # extra joints of other devices (e.g. a gripper's, a pan-tilt unit's): ignored
    q, why = msgs.model_joints(_joint_state(["gripper_finger", *names, "ptu_pan"], [0.5, *hs, math.nan]), model)
    assert why == ""
    np.testing.assert_array_equal(q, hs)
    # a missing model joint: refused, naming it
    q, why = msgs.model_joints(_joint_state(names[:-2] + ["gripper_finger"], [*hs[:-2], 0.0]), model)
    assert q is None and why == (f"joint state is missing 2 of the {model.n_joints} model joints: "
                                 f"{names[-2]}, {names[-1]}")
    q, why = msgs.model_joints(_joint_state([], []), model)
    assert q is None and why.startswith(f"joint state is missing {model.n_joints} of the") and why.endswith("(24 more)")
    bad = hs.copy()
    bad[3] = math.inf
    q, why = msgs.model_joints(_joint_state(names, bad), model)
    assert q is None and why == f"joint state has NaN/inf for {names[3]}"
    # malformed messages
    assert msgs.model_joints(_joint_state(names, hs[:-1]), model) == (None, "joint state has 30 names but 29 positions")
    assert msgs.model_joints(_joint_state(names + names[:1], [*hs, 0.0]), model) == (
        None, f"joint state has duplicate joint names: {names[0]}")


def test_gray_from_image_encodings_and_bad_sizes() -> None:
    from sensor_msgs.msg import Image

    rgb = np.random.default_rng(0).integers(0, 255, (6, 5, 3), dtype=np.uint8)
    gray = msgs.gray_from_image(msgs.image_msg(rgb, "rgb8", "c", None))
    assert gray.shape == (6, 5) and gray.dtype == np.uint8
    expected = np.rint(rgb.astype(float) @ [0.299, 0.587, 0.114])           # ITU-R BT.601 luma
    assert np.max(np.abs(gray - expected)) <= 1.0
    np.testing.assert_array_equal(msgs.gray_from_image(msgs.image_msg(rgb[:, :, ::-1], "bgr8", "c", None)), gray)
    rgba = np.concatenate([rgb, np.full((6, 5, 1), 7, np.uint8)], axis=2)
    np.testing.assert_array_equal(msgs.gray_from_image(msgs.image_msg(rgba, "rgba8", "c", None)), gray)
    bgra = np.concatenate([rgb[:, :, ::-1], np.full((6, 5, 1), 7, np.uint8)], axis=2)
    np.testing.assert_array_equal(msgs.gray_from_image(msgs.image_msg(bgra, "bgra8", "c", None)), gray)
    for enc in ("mono8", "8UC1"):
        np.testing.assert_array_equal(msgs.gray_from_image(msgs.image_msg(gray, enc, "c", None)), gray)
    padded = Image(height=6, width=5, encoding="mono8", step=8,
                   data=np.pad(gray, ((0, 0), (0, 3))).tobytes())           # row padding
    np.testing.assert_array_equal(msgs.gray_from_image(padded), gray)
    bad = {
        "unsupported image encoding '16UC1'": Image(height=6, width=5, encoding="16UC1", step=10, data=bytes(60)),
        "data has 29 bytes": Image(height=6, width=5, encoding="mono8", step=5, data=bytes(29)),
        "step 4 < width 5": Image(height=6, width=5, encoding="mono8", step=4, data=bytes(24)),
        "step 14 < width 5 \\* 3": Image(height=6, width=5, encoding="rgb8", step=14, data=bytes(84)),
        "empty image": Image(height=0, width=5, encoding="mono8", step=5, data=b""),
    }
    for text, m in bad.items():
        with pytest.raises(ValueError, match=text):
            msgs.gray_from_image(m)


def test_image_msg_layout() -> None:
    img = np.arange(4 * 3 * 3, dtype=np.uint8).reshape(4, 3, 3)
    m = msgs.image_msg(img, "rgb8", "cam", msgs.time_from_seconds(2.0))
    assert (m.height, m.width, m.step, m.encoding, m.is_bigendian, m.header.frame_id) == (4, 3, 9, "rgb8", 0, "cam")
    assert bytes(m.data) == img.tobytes() and msgs.seconds_from_time(m.header.stamp) == 2.0


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
