"""Node-level tests of scene_sim: real joint_driver + scene_sim processes (headers, sizes, clouds
on the scene's surfaces, stereo pair, disabling a primitive at run time), and scene_sim fed
by the test's own /joint_states (malformed ones are skipped with a warning)."""
from __future__ import annotations

import numpy as np
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image, JointState, PointCloud2

from humanoid_reach_ros.io import msgs
from humanoid_reach_ros.nodes import scene_sim
from humanoid_reach_ros.perception.markers import camera_pose
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.sim.camera import without_primitives
from humanoid_reach_ros.sim.scene import load_scene
from nodetools import REPO_ROOT

PARAMS_FILE = "config/scene_sim.yaml"
READY = r"scene sensors ready"
SMALL = {"width": 320, "height": 240, "diagnostics_period_s": 0.3, "joint_states_timeout_s": 5.0}


def test_config_matches_declared_defaults() -> None:
    doc = yaml.safe_load((REPO_ROOT / PARAMS_FILE).read_text())["/**"]["ros__parameters"]
    assert doc == {k: spec.default for k, spec in scene_sim.PARAMETERS.items()}


def test_message_builders() -> None:
    from humanoid_reach_ros.sim.camera import PinholeCamera

    cam = PinholeCamera.from_fov(64, 48, 1.0)
    img = np.arange(64 * 48 * 3, dtype=np.uint8).reshape(48, 64, 3)
    m = msgs.image_msg(img, "rgb8", "cam", msgs.time_from_seconds(3.5))
    assert (m.width, m.height, m.step, len(m.data), m.header.frame_id) == (64, 48, 192, 64 * 48 * 3, "cam")
    info = scene_sim.camera_info_msg(cam, "right", None, tx_m=0.1)
    assert info.p[3] == pytest.approx(-cam.fx * 0.1) and info.k[0] == pytest.approx(cam.fx)
    assert list(info.d) == [0.0] * 5 and info.distortion_model == "plumb_bob"


def set_parameters(probe, names_values, timeout=20.0):
    client = probe.node.create_client(SetParameters, "/scene_sim/set_parameters")
    probe.spin_until(client.service_is_ready, timeout, "/scene_sim/set_parameters")
    req = SetParameters.Request(parameters=[
        ParameterMsg(name=n, value=ParameterValue(type=ParameterType.PARAMETER_STRING_ARRAY, string_array_value=v))
        for n, v in names_values])
    fut = client.call_async(req)
    probe.spin_until(fut.done, timeout, "set_parameters response")
    return fut.result().results


def world_points(model, cloud: PointCloud2, joint_msgs) -> np.ndarray:
    """The cloud's points in world, with R_T_C from the joint state of the cloud's stamp."""
    stamp = msgs.nanoseconds_from_time(cloud.header.stamp)
    # the joint state of that stamp, or the nearest one the probe received (a loaded machine drops
    # some: fresh clone, three xdist workers; the robot stands still in these tests)
    js = min(joint_msgs, key=lambda m: abs(msgs.nanoseconds_from_time(m.header.stamp) - stamp))
    assert abs(msgs.nanoseconds_from_time(js.header.stamp) - stamp) < 0.5e9, "no joint state near the cloud's stamp"
    joints = model.joints_from_dict(dict(zip(js.name, js.position)))
    T = camera_pose(model, joints, "head_camera_optical_frame")
    pts = msgs.points_from_cloud(cloud).points
    return pts @ T[:3, :3].T + T[:3, 3]


@pytest.mark.node
def test_headers_sizes_clouds_stereo_and_disabled_primitives(start_node, ros_probe) -> None:
    model, scene = RobotModel(), load_scene("scenes/plant.yaml")
    start_node("joint_driver", params_file="config/joint_driver.yaml", ready_log=r"simulated hrp2")
    joints = ros_probe.collect(JointState, "/joint_states", qos_profile_sensor_data)
    images = ros_probe.collect(Image, "/head_camera/image_raw", qos_profile_sensor_data)
    infos = ros_probe.collect(CameraInfo, "/head_camera/camera_info", qos_profile_sensor_data)
    clouds = ros_probe.collect(PointCloud2, "/head_camera/points", qos_profile_sensor_data)
    stereo = {s: ros_probe.collect(Image, f"/stereo/{s}/image_raw", qos_profile_sensor_data) for s in ("left", "right")}
    stereo_info = ros_probe.collect(CameraInfo, "/stereo/right/camera_info", qos_profile_sensor_data)
    proc = start_node("scene_sim", params_file=PARAMS_FILE,
                      params={**SMALL, "stereo_enabled": True, "range_noise_per_m": 0.0}, ready_log=READY)
    ros_probe.spin_until(lambda: len(images) >= 2 and len(clouds) >= 2 and len(stereo["right"]) >= 1
                         and len(infos) >= 1 and len(stereo_info) >= 1, 30.0, "scene_sim output",
                         on_timeout=proc.log_tail)
    # stamps: those of /joint_states messages the driver published. The probe's best-effort joint-state
    # subscription may match the driver late, or lose a message on a loaded machine: take the newest
    # image and cloud whose joint state the probe has (more arrive every 0.1 s)

    def with_joint_state(collector):
        stamps = {msgs.nanoseconds_from_time(m.header.stamp) for m in joints.messages}
        return next((m for m in reversed(collector.messages) if msgs.nanoseconds_from_time(m.header.stamp) in stamps),
                    None)

    img = ros_probe.spin_until(lambda: with_joint_state(images), 30.0, "an image stamped like a received joint state",
                               on_timeout=proc.log_tail)
    cloud = ros_probe.spin_until(lambda: with_joint_state(clouds), 30.0, "a cloud stamped like a received joint state",
                                 on_timeout=proc.log_tail)
    info = infos.last
    assert (img.width, img.height, img.encoding, img.step, len(img.data)) == (320, 240, "rgb8", 960, 320 * 240 * 3)
    assert img.header.frame_id == info.header.frame_id == cloud.header.frame_id == "head_camera_optical_frame"
    assert (info.width, info.height) == (320, 240) and info.k[0] > 0 and info.k[0] == info.k[4]
    right = stereo["right"].last
    # the default: camera frame + _right
    assert right.encoding == "mono8" and right.header.frame_id == model.camera_frame + "_right"
    assert stereo_info.last.p[3] == pytest.approx(-stereo_info.last.k[0] * 0.07)
    # the cloud (no range noise, every 2nd pixel, within 5 m) lies on the scene's surfaces
    pts = world_points(model, cloud, joints.messages)
    assert 2000 < len(pts) <= 160 * 120
    assert np.abs(scene.sdf(pts)).max() < 1e-4

    # disabling: an unknown name is refused with a reason, a real one removes the pipe from the cloud
    res = set_parameters(ros_probe, [("disabled_primitives", ["no_such_pipe"])])
    assert not res[0].successful and "no_such_pipe" in res[0].reason
    pipe = scene.primitive("left_shoulder_pipe")

    others = without_primitives(scene, [pipe.name])

    def on_pipe(c: PointCloud2) -> int:
        """Points on the pipe's surface and on no other primitive's."""
        p = world_points(model, c, joints.messages)
        return int(((np.abs(pipe.sdf(p)) < 1e-4) & (np.abs(others.sdf(p)) > 1e-4)).sum())

    assert on_pipe(cloud) > 100
    res = set_parameters(ros_probe, [("disabled_primitives", ["left_shoulder_pipe"])])
    assert res[0].successful, res[0].reason
    proc.wait_for_log(r"disabled primitives: \[.left_shoulder_pipe.\]")
    n = len(clouds)
    ros_probe.spin_until(lambda: len(clouds) >= n + 2, 20.0, "clouds after disabling", on_timeout=proc.log_tail)
    assert on_pipe(clouds.last) == 0


@pytest.mark.node
def test_own_joint_states_bad_ones_are_skipped(start_node, ros_probe) -> None:
    """Without joint_driver: nothing is published until a good /joint_states arrives; malformed
    ones get a warning and a WARN diagnostic; the node keeps working; the image stamp is the
    joint state's stamp."""
    model = RobotModel()
    pub = ros_probe.node.create_publisher(JointState, "/joint_states", 10)
    images = ros_probe.collect(Image, "/head_camera/image_raw", qos_profile_sensor_data)
    diags = ros_probe.collect(DiagnosticArray, "/diagnostics")
    proc = start_node("scene_sim", params_file=PARAMS_FILE, params={**SMALL, "image_encoding": "mono8"},
                      ready_log=READY)
    names = list(model.joint_names)
    bad = msgs.joint_state(names[:-1], model.half_sitting_joints[:-1], stamp=msgs.time_from_seconds(1.0))

    def warned() -> bool:
        for arr in diags.messages:
            for st in arr.status:
                if st.name.endswith(": sensors") and msgs.diagnostic_level(st) == msgs.LEVEL_WARN \
                        and "missing" in st.message:
                    return True
        return False

    k = 0

    def send_bad() -> bool:
        nonlocal k
        k += 1
        bad.header.stamp = msgs.time_from_seconds(1.0 + 0.01 * k)
        pub.publish(bad)
        return bool(proc.log_lines("skipping /joint_states")) and warned()

    ros_probe.spin_until(send_bad, 30.0, "warning about malformed joint states", on_timeout=proc.log_tail)
    assert len(images) == 0
    good = msgs.joint_state(names, model.half_sitting_joints, stamp=msgs.time_from_seconds(123.25))
    ros_probe.spin_until(lambda: pub.publish(good) or len(images) > 0, 30.0, "an image after a good joint state",
                         on_timeout=proc.log_tail)
    assert images.last.encoding == "mono8" and images.last.step == 320
    assert msgs.seconds_from_time(images.last.header.stamp) == 123.25
    assert proc.alive()


@pytest.mark.node
def test_bad_parameters_stop_with_a_clear_error(start_node) -> None:
    proc = start_node("scene_sim", params_file=PARAMS_FILE, params={"image_encoding": "bgr16"})
    proc.ok_exit_codes = (2,)
    line = proc.wait_for_log(r"cannot start", 30.0)
    assert "image_encoding must be one of ('rgb8', 'mono8'), got 'bgr16'" in line
    assert proc.proc.wait(30.0) == 2
