"""``perception/localizing.py`` without ROS: skip order and bookkeeping, stamp matching against
the joint-state buffer, the still-camera skip, the pose chain R_T_C C_T_M M_T_O, hand pairs and
the diagnostics. A scripted detector stands in for ArUco (test_markers.py tests detection on
rendered images); the robot model and forward kinematics are the real ones."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from humanoid_reach_ros.geometry.camera import CameraCalibration
from humanoid_reach_ros.perception import markers as M
from humanoid_reach_ros.perception.localizing import OK, WARN, MarkerLocalizing, hand_target_poses
from humanoid_reach_ros.robot.model import RobotModel

TABLE = M.marker_table("DICT_4X4_50", [7, 3, 5], [0.1, 0.05, 0.05],
                       [0.0, 0.0, 0.04, -0.5, 0.5, 0.5, 0.5] + [0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0] * 2)
W, H = 64, 48
CAL = CameraCalibration(W, H, [[50, 0, 32], [0, 50, 24], [0, 0, 1]], np.zeros(5), np.eye(3),
                        [[50, 0, 32, 0], [0, 50, 24, 0], [0, 0, 1, 0]])


def C_T_M(z: float = 0.6) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[2, 3] = z
    return T


class ScriptedDetector:
    """Returns the next scripted result: ``([(id, C_T_M), ...], [(id, reason), ...])``."""

    def __init__(self) -> None:
        self.script: list = []
        self.calls = 0

    def detect(self, gray, K, dist=None) -> M.DetectionResult:
        self.calls += 1
        accepted, rejected = self.script.pop(0) if self.script else ([], [])
        return M.DetectionResult(tuple(M.MarkerDetection(i, T, 0.25, np.zeros((4, 2))) for i, T in accepted),
                                 tuple(rejected))


class Clock:
    def __init__(self) -> None:
        self.now = 50.0

    def __call__(self) -> float:
        return self.now


class Workspace:
    """The hand orientation rule's interface (dual_arm.ReachWorkspace.hand_rotation)."""

    def __init__(self, fail: bool = False) -> None:
        self.fail = fail

    def hand_rotation(self, side: str, p: np.ndarray) -> np.ndarray:
        if self.fail:
            raise ValueError("target at the shoulder")
        return np.eye(3) if side == "right" else pin.utils.rpyToMatrix(0.0, 0.0, 0.5)


@pytest.fixture(scope="module")
def model() -> RobotModel:
    return RobotModel()


def make(model: RobotModel, **kw):
    det, clock, log = ScriptedDetector(), Clock(), []
    loc = MarkerLocalizing(model, TABLE, det, camera_frame_id=model.camera_frame, target_marker_id=7,
                           on_skip=lambda what, n, reason: log.append(("skip", what, n, reason)),
                           on_rejection=lambda text: log.append(("rejected", text)), clock=clock, **kw)
    return loc, det, clock, log


def joints_at(model: RobotModel, stamps, offset: float = 0.0) -> list:
    q = np.asarray(model.half_sitting_joints, float) + offset
    return [(s, q.copy(), "") for s in stamps]


def image(loc: MarkerLocalizing, stamp: float, size=(H, W), joint_states=(), gray_calls=None):
    def gray():
        if gray_calls is not None:
            gray_calls.append(stamp)
        return np.zeros((H, W), np.uint8)

    def shape():
        if isinstance(size, Exception):
            raise size
        return size

    return loc.localize(stamp, shape, gray, lambda: list(joint_states))


def test_skips_in_order_with_their_reasons(model: RobotModel) -> None:
    loc, det, clock, log = make(model)
    grays: list = []
    assert image(loc, 10.0, gray_calls=grays) is None
    assert log[-1] == ("skip", "image", 1, "no valid camera_info received yet")
    loc.set_intrinsics(CAL, 5.0)
    assert image(loc, 10.0, gray_calls=grays) is None
    assert "camera_info is 5.0 s away from the image stamp (> 2 s)" in log[-1][3]
    loc.set_intrinsics(CAL, 10.0)
    assert image(loc, 10.0, size=ValueError("data is 3 bytes, expected 3072"), gray_calls=grays) is None
    assert log[-1][3] == "data is 3 bytes, expected 3072"
    assert image(loc, 10.0, size=(H, W + 1), gray_calls=grays) is None
    assert log[-1][3] == f"image is {W + 1} x {H} but camera_info says {W} x {H}"
    assert image(loc, 10.0, gray_calls=grays) is None
    assert log[-1][3].startswith("no camera pose at the image stamp: no /joint_states received yet")
    assert grays == [] and det.calls == 0                 # never converted nor detected
    assert loc.counters.images == 5 and loc.counters.skipped_image == 5
    assert loc.last_skip_reason.startswith("image: no camera pose")
    level, message, values = loc.diagnostics()
    assert level == WARN and message.startswith("skipping input: image: no camera pose")
    assert values["skipped_images_total"] == 5 and values["images_total"] == 5


def test_bad_joint_states_are_skipped_and_gaps_tracked(model: RobotModel) -> None:
    loc, _, _, log = make(model)
    loc.add_joint_states(joints_at(model, [1.0, 1.005]) + [(0.0, None, "7 joint names, 30 expected")]
                         + joints_at(model, [1.030]))
    assert log == [("skip", "joint_states", 1, "7 joint names, 30 expected")]
    _, _, values = loc.diagnostics()
    assert values["joint_states_buffered"] == 3 and values["bad_joint_states_total"] == 1
    assert values["joint_states_max_gap_ms"] == pytest.approx(25.0)
    _, _, values = loc.diagnostics()
    assert values["joint_states_max_gap_ms"] == 0.0 and values["joint_states_max_gap_ms_since_start"] == \
        pytest.approx(25.0)


def test_the_pose_chain_at_the_image_stamp(model: RobotModel) -> None:
    loc, det, clock, log = make(model)
    loc.set_intrinsics(CAL, 10.0)
    js = joints_at(model, [9.9, 10.1])
    det.script.append(([(7, C_T_M()), (3, C_T_M(0.8))], [(9, "unknown id")]))
    out = image(loc, 10.0, joint_states=js)
    R_T_C = M.camera_pose(model, js[0][1], model.camera_frame)
    assert out is not None and len(out.markers) == 2 and len(out.targets) == 1 and out.hands is None
    np.testing.assert_allclose(out.markers[0], R_T_C @ C_T_M(), atol=1e-12)
    np.testing.assert_allclose(out.targets[0], R_T_C @ C_T_M() @ TABLE.markers[7].M_T_O, atol=1e-12)
    np.testing.assert_allclose(loc.last_target, out.targets[0][:3, 3])
    assert log == [("rejected", "id 9: unknown id")] and loc.counters.rejected == 1
    assert loc.counters.localized == 1 and loc.last_error_px == 0.25
    loc.processed(0.012)
    level, message, values = loc.diagnostics()
    assert level == OK and message.startswith("localizing at")
    assert values["max_process_ms"] == pytest.approx(12.0) and values["target_x_m"] == out.targets[0][0, 3]
    # an image beyond the buffered states by more than max_stamp_gap_s: no camera pose
    assert image(loc, 10.5) is None and "no camera pose at the image stamp" in loc.last_skip_reason


def test_still_camera_skips_detection_until_the_period_passes(model: RobotModel) -> None:
    loc, det, clock, _ = make(model, still_period_s=0.5)
    loc.set_intrinsics(CAL, 10.0)
    loc.add_joint_states(joints_at(model, np.arange(9.0, 11.0, 0.01)))
    det.script = [([(7, C_T_M())], [])] * 3
    grays: list = []
    assert image(loc, 10.0, gray_calls=grays) is not None
    clock.now += 0.2
    assert image(loc, 10.1, gray_calls=grays) is None           # same head pose, 0.2 s later
    assert loc.counters.skipped_still == 1 and grays == [10.0]
    clock.now += 0.4
    assert image(loc, 10.2, gray_calls=grays) is not None       # 0.6 s since the last detection
    # the head moved: detect at once
    loc.add_joint_states(joints_at(model, np.arange(11.0, 12.0, 0.01), offset=0.05))
    clock.now += 0.1
    assert image(loc, 11.5, gray_calls=grays) is not None
    assert grays == [10.0, 10.2, 11.5] and loc.counters.skipped_still == 1


def test_still_skip_off_with_period_zero_and_with_hand_markers(model: RobotModel) -> None:
    for kw in ({"still_period_s": 0.0}, {"hand_ids": (3, 5)}):
        loc, det, clock, _ = make(model, **kw)
        loc.set_intrinsics(CAL, 10.0)
        loc.add_joint_states(joints_at(model, np.arange(9.0, 11.0, 0.01)))
        for s in (10.0, 10.01, 10.02):
            image(loc, s)
        assert det.calls == 3 and loc.counters.skipped_still == 0


def test_hand_pairs(model: RobotModel) -> None:
    loc, det, clock, log = make(model, hand_ids=(3, 5), workspace=Workspace(), still_period_s=0.0)
    loc.set_intrinsics(CAL, 10.0)
    js = joints_at(model, np.arange(9.0, 11.0, 0.01))
    loc.add_joint_states(js)
    det.script = [([(3, C_T_M(0.5)), (5, C_T_M(0.7)), (7, C_T_M())], []), ([(3, C_T_M(0.5))], [])]
    out = image(loc, 10.0)
    R_T_C = M.camera_pose(model, js[100][1], model.camera_frame)
    right = R_T_C @ C_T_M(0.5) @ TABLE.markers[3].M_T_O
    assert out.hands is not None and len(out.hands) == 2
    np.testing.assert_allclose(out.hands[0].translation, right[:3, 3], atol=1e-9)
    np.testing.assert_allclose(out.hands[0].rotation, np.eye(3))      # the workspace rule's orientation
    np.testing.assert_allclose(loc.last_hands[0], right[:3, 3], atol=1e-9)
    out = image(loc, 10.01)
    assert out.hands is None and loc.counters.hand_pair_incomplete == 1 and loc.counters.hand_pairs == 1
    _, _, values = loc.diagnostics()
    assert values["hand_pairs_total"] == 1 and values["hand_pair_incomplete_total"] == 1

    loc.workspace = Workspace(fail=True)
    det.script = [([(3, C_T_M(0.5)), (5, C_T_M(0.7))], [])]
    assert image(loc, 10.02).hands is None
    assert log[-1] == ("skip", "hand targets", 1, "target at the shoulder")


def test_hand_target_poses_marker_orientation() -> None:
    a, b = np.eye(4), np.eye(4)
    b[:3, :3] = pin.utils.rpyToMatrix(0.1, 0.2, 0.3)
    b[:3, 3] = [1.0, 2.0, 3.0]
    out = hand_target_poses([a, b], None)
    np.testing.assert_allclose(out[1].homogeneous, b)


def test_diagnostics_messages_without_skips(model: RobotModel) -> None:
    loc, det, clock, _ = make(model)
    clock.now += 1.0
    assert loc.diagnostics()[:2] == (WARN, "no images received")
    loc.set_intrinsics(CAL, 10.0)
    loc.add_joint_states(joints_at(model, [9.9, 10.1]))
    det.script = [([], [(7, "reprojection error 3.1 px > 1 px")])]
    assert image(loc, 10.0) is None and loc.counters.no_marker == 1
    clock.now += 1.0
    level, message, values = loc.diagnostics()
    assert level == WARN
    assert message == "target marker 7 not seen (last rejection: id 7: reprojection error 3.1 px > 1 px)"
    assert values["image_rate_hz"] == pytest.approx(1.0) and values["localization_rate_hz"] == 0.0
    assert "hand_pairs_total" not in values and "target_x_m" not in values
