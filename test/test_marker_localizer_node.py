"""marker_localizer: message parsers, and node-level tests with real processes --
joint_driver + scene_sim + marker_localizer puts the valve centre within 1 cm of the scene
file's valve pose; bad images / camera_info from the test get warnings and the node keeps working."""
from __future__ import annotations

import math

import numpy as np
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray, PoseStamped
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image, JointState

from humanoid_reach_ros.io import msgs
from humanoid_reach_ros.nodes import marker_localizer as ML
from humanoid_reach_ros.nodes.scene_sim import camera_info_msg
from humanoid_reach_ros.perception.markers import camera_pose
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.sim import camera as C
from humanoid_reach_ros.sim.scene import load_scene
from nodetools import REPO_ROOT

PARAMS_FILE = "config/marker_localizer.yaml"
READY = r"marker localizer ready"
HEAD_PITCH_RAD = 0.6   # half-sitting with this head pitch sees the valve marker (0 does not)


def test_config_matches_declared_defaults() -> None:
    doc = yaml.safe_load((REPO_ROOT / PARAMS_FILE).read_text())["/**"]["ros__parameters"]
    assert doc == {k: spec.default for k, spec in ML.PARAMETERS.items()}


# ---------------------------------------------------------------- parsers
def test_camera_info_is_converted_once_and_checked() -> None:
    """One CameraInfo conversion for every node (io/msgs.py: camera_calibration, camera_info):
    a round trip keeps K, D, R, P and the size; unusable ones are refused with the reason."""
    cam = C.PinholeCamera.from_fov(64, 48, 1.0)
    good = camera_info_msg(cam, "c", None)
    cal = msgs.camera_calibration(good)
    np.testing.assert_allclose(cal.K, cam.K)
    assert cal.size == (64, 48) and cal.D.shape == (5,) and good.distortion_model == "plumb_bob"
    assert msgs.camera_calibration(msgs.camera_info(cal, "c")) == cal
    right = msgs.camera_calibration(camera_info_msg(cam, "c", None, tx_m=0.1))
    assert right.P[0, 3] == pytest.approx(-cam.fx * 0.1) and right != cal
    zero = camera_info_msg(cam, "c", None)
    zero.k[0] = 0.0
    with pytest.raises(ValueError, match="focal lengths must be > 0"):
        msgs.camera_calibration(zero)
    nan = camera_info_msg(cam, "c", None)
    nan.k[4] = math.nan
    with pytest.raises(ValueError, match="non-finite"):
        msgs.camera_calibration(nan)
    with pytest.raises(ValueError, match="empty"):
        msgs.camera_calibration(CameraInfo(k=list(cam.K.ravel())))
    odd = camera_info_msg(cam, "c", None)
    odd.d = [0.0] * 3
    with pytest.raises(ValueError, match="3 distortion coefficients"):
        msgs.camera_calibration(odd)


# ---------------------------------------------------------------- node tests
def status(diags, suffix: str, level: int | None = None, text: str = ""):
    for arr in reversed(diags.messages):
        for st in arr.status:
            if st.name.endswith(suffix) and (level is None or msgs.diagnostic_level(st) == level) \
                    and text in st.message:
                return st
    return None


@pytest.mark.node
def test_valve_centre_within_1cm_with_joint_driver_and_scene_sim(start_node, ros_probe) -> None:
    scene = load_scene("scenes/plant.yaml")
    valve = scene.target.pose
    start_node("joint_driver", params_file="config/joint_driver.yaml", params={"command_timeout_s": 600.0},
               ready_log=r"simulated hrp2")
    command = ros_probe.node.create_publisher(JointState, "/joint_command", 10)
    targets = ros_probe.collect(PoseStamped, "/target_pose", qos_profile_sensor_data)
    marker_arrays = ros_probe.collect(PoseArray, "/markers", qos_profile_sensor_data)
    diags = ros_probe.collect(DiagnosticArray, "/diagnostics")
    sim = start_node("scene_sim", params_file="config/scene_sim.yaml",
                     params={"publish_points": False, "joint_states_timeout_s": 5.0}, ready_log=r"scene sensors ready")
    loc = start_node("marker_localizer", params_file=PARAMS_FILE, params={"diagnostics_period_s": 0.3},
                     ready_log=READY)
    head = msgs.joint_state(["HEAD_JOINT1"], [HEAD_PITCH_RAD])

    def settled_target():
        command.publish(head)   # the driver holds it; resent until the head has arrived
        # only poses from images taken once the head has stopped (two equal consecutive poses)
        if len(targets) < 3:
            return None
        a, b = (msgs.se3_from_pose(m) for m in targets.messages[-2:])
        return b if np.linalg.norm(a.translation - b.translation) < 1e-4 else None

    pose = ros_probe.spin_until(settled_target, 60.0, "a settled /target_pose",
                                on_timeout=lambda: sim.log_tail() + loc.log_tail())
    assert targets.last.header.frame_id == "world"
    err = np.linalg.norm(pose.translation - valve[:3, 3])
    assert err < 0.01, f"valve centre off by {err * 1e3:.1f} mm"
    angle = np.linalg.norm(np.asarray(pose.rotation.T @ valve[:3, :3]) - np.eye(3))
    assert angle < 0.05
    # /markers holds the marker's own pose (4 cm behind the valve centre, on the hub plate)
    ros_probe.spin_until(lambda: len(marker_arrays) > 0, 20.0, "/markers")
    arr = marker_arrays.last
    assert arr.header.frame_id == "world" and len(arr.poses) == 1
    m = msgs.se3_from_pose(arr.poses[0])
    assert np.linalg.norm(m.translation - scene.target.marker_pose[:3, 3]) < 0.01
    ros_probe.spin_until(lambda: status(diags, ": localization", msgs.LEVEL_OK), 20.0, "OK diagnostics",
                         on_timeout=loc.log_tail)


@pytest.mark.node
def test_bad_images_and_camera_info_get_warnings_and_the_node_keeps_working(start_node, ros_probe) -> None:
    """The test plays camera and joint driver: bad inputs first, then one good frame."""
    model, scene = RobotModel(), load_scene("scenes/plant.yaml")
    cam = C.PinholeCamera.from_fov(640, 480, math.radians(60.0))
    joints = model.half_sitting_joints.copy()
    joints[model.joint_index["HEAD_JOINT1"]] = HEAD_PITCH_RAD
    T_wc = camera_pose(model, joints, "head_camera_optical_frame")
    frame = C.render_image(scene, C.cast(scene, cam, T_wc), C.marker_print_from_scene(scene))

    pubs = {
        "js": ros_probe.node.create_publisher(JointState, "/joint_states", qos_profile_sensor_data),
        "img": ros_probe.node.create_publisher(Image, "/head_camera/image_raw", qos_profile_sensor_data),
        "info": ros_probe.node.create_publisher(CameraInfo, "/head_camera/camera_info", qos_profile_sensor_data),
    }
    targets = ros_probe.collect(PoseStamped, "/target_pose", qos_profile_sensor_data)
    diags = ros_probe.collect(DiagnosticArray, "/diagnostics")
    loc = start_node("marker_localizer", params_file=PARAMS_FILE, params={"diagnostics_period_s": 0.3},
                     ready_log=READY)
    t = [100.0]

    def stamp():
        t[0] += 0.01
        return msgs.time_from_seconds(t[0])

    def send(img_msg=None, info_msg=None) -> None:
        s = stamp()
        pubs["js"].publish(msgs.joint_state(model.joint_names, joints, stamp=s))
        if info_msg is not None:
            info_msg.header.stamp = s
            pubs["info"].publish(info_msg)
        if img_msg is not None:
            img_msg.header.stamp = s
            pubs["img"].publish(img_msg)

    def expect_warning(pattern: str, make) -> None:
        n = len(loc.log_lines(pattern))
        ros_probe.spin_until(lambda: send(*make()) or len(loc.log_lines(pattern)) > n, 20.0,
                             f"warning {pattern!r}", on_timeout=loc.log_tail)

    good_img = lambda: msgs.image_msg(frame, "rgb8", "head_camera_optical_frame", None)  # noqa: E731
    good_info = lambda: camera_info_msg(cam, "head_camera_optical_frame", None)     # noqa: E731

    def zero_focal():
        info = good_info()
        info.k[0] = 0.0
        return info

    def short_data():
        m = good_img()
        m.data = bytes(m.data)[:-7]
        return m

    def bad_encoding():
        m = good_img()
        m.encoding = "32FC1"
        return m

    # a frame without the marker: the images of this step that are still queued when a valid
    # camera_info arrives (step 3) must not give a target
    blank_img = lambda: msgs.image_msg(np.zeros_like(frame), "rgb8", "head_camera_optical_frame", None)  # noqa: E731
    expect_warning(r"no valid camera_info received yet", lambda: (blank_img(), None))
    expect_warning(r"skipping camera_info .*focal lengths must be > 0", lambda: (blank_img(), zero_focal()))
    expect_warning(r"unsupported image encoding '32FC1'", lambda: (bad_encoding(), good_info()))
    expect_warning(r"image data has \d+ bytes", lambda: (short_data(), good_info()))
    ros_probe.spin_until(lambda: status(diags, ": localization", msgs.LEVEL_WARN, "skipping input"), 20.0,
                         "WARN diagnostics for skipped input", on_timeout=loc.log_tail)
    assert len(targets) == 0 and loc.alive()
    # still working: a good frame gives the valve centre
    ros_probe.spin_until(lambda: send(good_img(), good_info()) or len(targets) > 0, 30.0, "a /target_pose",
                         on_timeout=loc.log_tail)
    pose = msgs.se3_from_pose(targets.last)
    assert np.linalg.norm(pose.translation - scene.target.pose[:3, 3]) < 0.01
    assert loc.alive()


@pytest.mark.node
def test_a_still_camera_detects_once_per_still_period_a_moving_one_every_image(start_node, ros_probe) -> None:
    """The robot standing: the same view is detected in one image per still_period_s (the rest
    counted as still_skipped); a moving head has every image detected."""
    model, scene = RobotModel(), load_scene("scenes/plant.yaml")
    cam = C.PinholeCamera.from_fov(640, 480, math.radians(60.0))
    pubs = {
        "js": ros_probe.node.create_publisher(JointState, "/joint_states", qos_profile_sensor_data),
        "img": ros_probe.node.create_publisher(Image, "/head_camera/image_raw", qos_profile_sensor_data),
        "info": ros_probe.node.create_publisher(CameraInfo, "/head_camera/camera_info", qos_profile_sensor_data),
    }
    diags = ros_probe.collect(DiagnosticArray, "/diagnostics")
    loc = start_node("marker_localizer", params_file=PARAMS_FILE,
                     params={"diagnostics_period_s": 0.2, "still_period_s": 1.0}, ready_log=READY)
    frames = {}
    for pitch in (HEAD_PITCH_RAD, HEAD_PITCH_RAD + 0.01):
        joints = model.half_sitting_joints.copy()
        joints[model.joint_index["HEAD_JOINT1"]] = pitch
        T_wc = camera_pose(model, joints, "head_camera_optical_frame")
        frames[pitch] = (joints, C.render_image(scene, C.cast(scene, cam, T_wc), C.marker_print_from_scene(scene)))
    t = [100.0]

    def send(pitch: float) -> None:
        t[0] += 0.05
        s = msgs.time_from_seconds(t[0])
        joints, frame = frames[pitch]
        pubs["js"].publish(msgs.joint_state(model.joint_names, joints, stamp=s))
        pubs["info"].publish(camera_info_msg(cam, "head_camera_optical_frame", s))
        pubs["img"].publish(msgs.image_msg(frame, "rgb8", "head_camera_optical_frame", s))
        ros_probe.spin_for(0.05)

    def counts() -> dict:
        st = status(diags, ": localization")
        return {} if st is None else {k: int(v) for k, v in msgs.diagnostic_values(st).items() if k.endswith("_total")}

    ros_probe.spin_until(lambda: send(HEAD_PITCH_RAD) or counts().get("still_skipped_images_total", 0) >= 10, 60.0,
                         "ten images of a still camera skipped", on_timeout=loc.log_tail)
    c = counts()
    assert c["localized_total"] >= 1 and c["localized_total"] < c["images_total"] / 2, c
    k = [0]

    def moving() -> bool:
        k[0] += 1
        send(HEAD_PITCH_RAD + 0.01 * (k[0] % 2))              # the head nods between two poses
        return counts().get("localized_total", 0) >= c["localized_total"] + 10
    ros_probe.spin_until(moving, 60.0, "ten localizations of a moving camera", on_timeout=loc.log_tail)
    c2 = counts()
    # every image of the moving head detected (the still ones skipped before it, and at most one after)
    assert c2["still_skipped_images_total"] <= c["still_skipped_images_total"] + 1, (c, c2)
    assert loc.alive()


@pytest.mark.node
def test_bad_marker_table_stops_with_a_clear_error(start_node) -> None:
    proc = start_node("marker_localizer", params_file=PARAMS_FILE, params={"marker_sizes_m": [0.1, 0.2]})
    proc.ok_exit_codes = (2,)
    line = proc.wait_for_log(r"cannot start", 30.0)
    assert "1 marker_ids need 1 marker_sizes_m (got 2)" in line
    assert proc.proc.wait(30.0) == 2


# ---------------------------------------------------------------- dual-arm hand markers
HAND_IDS = (3, 5)                       # right, left
BOARD_X = 0.89                          # front face of the board the two markers are printed on
R_WM = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])   # z out of the face (-x), y up


def _two_marker_frame(model, joints, cam):
    """A board facing the robot with markers 3 (right, y = -0.15) and 5 (left, y = +0.15)
    at z = 1.05; rendered once per marker and merged (the renderer prints one marker)."""
    scene, hits = _board_only(model, joints, cam)
    plain = C.render_image(scene, hits)
    out, centres = plain.copy(), {}
    for mid, y in zip(HAND_IDS, (-0.15, 0.15)):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R_WM, (BOARD_X, y, 1.05)
        img = C.render_image(scene, hits, C.MarkerPrint(T, 0.1, C.aruco_cells("DICT_4X4_50", mid)))
        changed = np.any(img != plain, axis=2)
        out[changed] = img[changed]
        centres[mid] = T[:3, 3]
    return out, centres


def test_hand_marker_parameters_are_checked() -> None:
    known = {7: None, 3: None, 5: None}
    assert ML.hand_marker_setup([-1, -1], "workspace", "robots/hrp2/dual_arm_workspace.yaml", known) == (None, None)
    ids, ws = ML.hand_marker_setup([3, 5], "workspace", "robots/hrp2/dual_arm_workspace.yaml", known)
    assert ids == (3, 5) and ws is not None
    assert ML.hand_marker_setup([5, 3], "marker", "unused.yaml", known) == ((5, 3), None)
    for args, msg in ((([3], "workspace"), "needs 2 ids"), (([3, 3], "workspace"), "two different markers"),
                      (([3, 9], "workspace"), r"\[9\] are not among marker_ids"),
                      (([3, 5], "gripper"), "must be 'workspace' or 'marker'")):
        with pytest.raises(ValueError, match=msg):
            ML.hand_marker_setup(*args, "robots/hrp2/dual_arm_workspace.yaml", known)


@pytest.mark.node
def test_two_hand_markers_give_dual_arm_targets(start_node, ros_probe) -> None:
    """Markers 3 and 5 in one image -> /dual_arm/targets [right, left] at the markers'
    object positions (M_T_O: 2 cm in front of each face) with the workspace rule's
    orientations; an image with one of them only publishes nothing."""
    from humanoid_reach_ros.dual_arm.torso_regression import ReachWorkspace

    model = RobotModel()
    cam = C.PinholeCamera.from_fov(640, 480, math.radians(60.0))
    joints = model.half_sitting_joints.copy()
    joints[model.joint_index["HEAD_JOINT1"]] = 0.45
    frame, centres = _two_marker_frame(model, joints, cam)
    one_marker = frame.copy()
    one_marker[:, 320:] = C.render_image(*_board_only(model, joints, cam))[:, 320:]   # left marker gone
    pubs = {
        "js": ros_probe.node.create_publisher(JointState, "/joint_states", qos_profile_sensor_data),
        "img": ros_probe.node.create_publisher(Image, "/head_camera/image_raw", qos_profile_sensor_data),
        "info": ros_probe.node.create_publisher(CameraInfo, "/head_camera/camera_info", qos_profile_sensor_data),
    }
    hands = ros_probe.collect(PoseArray, "/dual_arm/targets", qos_profile_sensor_data)
    markers = ros_probe.collect(PoseArray, "/markers", qos_profile_sensor_data)
    M_T_O = [0.0, 0.0, 0.02, 0.0, 0.0, 0.0, 1.0]
    loc = start_node("marker_localizer", params_file=PARAMS_FILE,
                     params={"marker_ids": [7, 3, 5], "marker_sizes_m": [0.1, 0.1, 0.1],
                             "marker_object_poses": [0.0, 0.0, 0.04, -0.5, 0.5, 0.5, 0.5] + M_T_O + M_T_O,
                             "hand_marker_ids": list(HAND_IDS)},
                     ready_log=r"dual_arm/targets from ids \[3, 5\]")
    t = [200.0]

    def send(img) -> None:
        t[0] += 0.01
        s = msgs.time_from_seconds(t[0])
        pubs["js"].publish(msgs.joint_state(model.joint_names, joints, stamp=s))
        pubs["info"].publish(camera_info_msg(cam, "head_camera_optical_frame", s))
        pubs["img"].publish(msgs.image_msg(img, "rgb8", "head_camera_optical_frame", s))

    # one hand marker only: /markers, but no hand targets
    ros_probe.spin_until(lambda: send(one_marker) or len(markers) > 0, 30.0, "a /markers message",
                         on_timeout=loc.log_tail)
    ros_probe.spin_for(0.5)
    assert len(hands) == 0
    ros_probe.spin_until(lambda: send(frame) or len(hands) > 0, 30.0, "a /dual_arm/targets message",
                         on_timeout=loc.log_tail)
    msg = hands.last
    assert msg.header.frame_id == "world" and len(msg.poses) == 2
    ws = ReachWorkspace.load()
    for side, mid, pose in zip(("right", "left"), HAND_IDS, msg.poses):
        M = msgs.se3_from_pose(pose)
        expected = centres[mid] + R_WM @ np.array(M_T_O[:3])
        assert np.linalg.norm(M.translation - expected) < 0.01, (side, M.translation, expected)
        np.testing.assert_allclose(M.rotation, ws.hand_rotation(side, M.translation), atol=1e-6)
    assert loc.alive()


def _board_only(model, joints, cam):
    """The board scene (no marker) and its ray cast from the head camera."""
    from humanoid_reach_ros.sim.scene import scene_from_dict

    scene = scene_from_dict({"name": "board", "frame_id": "world", "primitives": [
        {"name": "board", "type": "box", "center": [BOARD_X + 0.01, 0.0, 1.1], "size": [0.02, 1.0, 0.8]}]})
    return scene, C.cast(scene, cam, camera_pose(model, joints, "head_camera_optical_frame"))
