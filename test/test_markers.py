"""AR-marker localization (humanoid_reach_ros.perception.markers): transform chain (eq. 1),
marker table and config file, IPPE-square PnP, detection on rendered images, joint-state buffer."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from humanoid_reach_ros.perception import markers as M
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.sim import camera as C
from humanoid_reach_ros.sim.scene import load_scene

GOOD = dict(dictionary="DICT_4X4_50", ids=[7, 3], sizes_m=[0.1, 0.05],
            object_poses=[0.0, 0.0, 0.04, -0.5, 0.5, 0.5, 0.5, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])


@pytest.fixture(scope="module")
def scene():
    return load_scene("scenes/plant.yaml")


def random_pose(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    return M.transform(rng.normal(size=3), q / np.linalg.norm(q))


# ---------------------------------------------------------------- transforms
def test_transform_matches_pinocchio_quaternion() -> None:
    rng = np.random.default_rng(0)
    for _ in range(20):
        xyz, q = rng.normal(size=3), rng.normal(size=4)
        q /= np.linalg.norm(q)
        ref = pin.XYZQUATToSE3(np.concatenate([xyz, q])).homogeneous
        np.testing.assert_allclose(M.transform(xyz, q), ref, atol=1e-12)
    with pytest.raises(ValueError, match="not unit"):
        M.transform([0, 0, 0], [0, 0, 0, 2.0])


def test_chain_round_trip_with_known_poses() -> None:
    """R_T_O = R_T_C C_T_M M_T_O recovers a known object pose from its parts, whichever way
    the known poses are split (eq. 1)."""
    rng = np.random.default_rng(1)
    for _ in range(20):
        R_T_O, R_T_C, M_T_O = (random_pose(rng) for _ in range(3))
        C_T_M = np.linalg.inv(R_T_C) @ R_T_O @ np.linalg.inv(M_T_O)
        np.testing.assert_allclose(M.object_pose(R_T_C, C_T_M, M_T_O), R_T_O, atol=1e-10)
    # hand-checked: camera 1 m above the origin looking down, marker 0.5 m ahead, object 4 cm in front of it
    R_T_C = C.look_at([0.0, 0.0, 1.0], [0.0, 0.0, 0.0], up=[1.0, 0.0, 0.0])
    C_T_M = np.eye(4)
    C_T_M[:3, :3] = np.diag([1.0, -1.0, -1.0])      # marker facing the camera
    C_T_M[2, 3] = 0.5
    M_T_O = np.eye(4)
    M_T_O[2, 3] = 0.04
    np.testing.assert_allclose(M.object_pose(R_T_C, C_T_M, M_T_O)[:3, 3], [0.0, 0.0, 0.54], atol=1e-12)


# ---------------------------------------------------------------- marker table and file
def test_marker_table_and_its_errors() -> None:
    t = M.marker_table(**GOOD)
    assert sorted(t.markers) == [3, 7] and t.markers[3].size_m == 0.05
    np.testing.assert_allclose(t.markers[3].M_T_O[:3, 3], [0.1, 0.0, 0.0])
    bad = {
        "unknown ArUco dictionary": dict(GOOD, dictionary="DICT_9X9_1"),
        "need 2 marker_sizes_m": dict(GOOD, sizes_m=[0.1]),
        "marker_object_poses numbers": dict(GOOD, object_poses=GOOD["object_poses"][:7]),
        "duplicate id 7": dict(GOOD, ids=[7, 7]),
        "integer in 0..49": dict(GOOD, ids=[7, 50]),
        "size_m: must be > 0": dict(GOOD, sizes_m=[0.1, -0.05]),
        "finite number": dict(GOOD, object_poses=[math.nan] + GOOD["object_poses"][1:]),
        "not unit length": dict(GOOD, object_poses=GOOD["object_poses"][:13] + [3.0]),
        "at least one marker": dict(GOOD, ids=[], sizes_m=[], object_poses=[]),
    }
    for text, kw in bad.items():
        with pytest.raises(ValueError, match=text):
            M.marker_table(**kw)


def test_config_file_agrees_with_the_scene(scene) -> None:
    """config/marker_localizer.yaml: M_T_O of marker 7 is the inverse of the marker's pose on
    the valve in the scene file, so R_T_O lands on the scene's valve pose."""
    table = M.load_marker_config()
    a = scene.target.aruco
    spec = table.markers[a.marker_id]
    assert table.dictionary == a.dictionary and spec.size_m == a.size_m
    O_T_M = np.linalg.inv(scene.target.pose) @ scene.target.marker_pose
    np.testing.assert_allclose(spec.M_T_O, np.linalg.inv(O_T_M), atol=1e-9)
    np.testing.assert_allclose(scene.target.marker_pose @ spec.M_T_O, scene.target.pose, atol=1e-9)


def test_bad_config_files(tmp_path: Path) -> None:
    cases = {
        "not valid YAML": "/**: {ros__parameters: [",
        "unknown top-level": "other_node:\n  ros__parameters: {}\n",
        "missing parameter": "/**:\n  ros__parameters:\n    dictionary: DICT_4X4_50\n",
        "duplicate id": ("/**:\n  ros__parameters:\n    dictionary: DICT_4X4_50\n    marker_ids: [1, 1]\n"
                         "    marker_sizes_m: [0.1, 0.1]\n    marker_object_poses: [0,0,0,0,0,0,1, 0,0,0,0,0,0,1]\n"),
    }
    for text, content in cases.items():
        f = tmp_path / "bad.yaml"
        f.write_text(content)
        with pytest.raises(ValueError, match=text) as info:
            M.load_marker_config(f)
        assert str(f) in str(info.value)


# ---------------------------------------------------------------- PnP
def test_ippe_square_recovers_a_known_pose() -> None:
    cam = C.PinholeCamera.from_fov(640, 480, math.radians(60.0))
    rng = np.random.default_rng(3)
    for _ in range(10):
        C_T_M = C.look_at(rng.uniform(-0.3, 0.3, 3) + [0.0, 0.0, -1.0], rng.uniform(-0.1, 0.1, 3))
        C_T_M = np.linalg.inv(C_T_M)  # marker pose in a camera placed in front of it
        corners = M.marker_corners(0.1) @ C_T_M[:3, :3].T + C_T_M[:3, 3]
        uv, _ = cam.project(corners)
        T, err = M.solve_marker_pose(uv, 0.1, cam.K)
        assert err < 1e-6
        np.testing.assert_allclose(T, C_T_M, atol=1e-6)


# ---------------------------------------------------------------- detection on rendered images
def render_view(scene, cam, distance_m: float, azimuth_rad: float, elevation_rad: float):
    """Mono image of the valve marker seen from ``distance_m`` at the given angles off its normal."""
    T_wm = scene.target.marker_pose
    n = T_wm[:3, 2]                                # out of the printed face, towards the robot
    up = np.array([0.0, 0.0, 1.0])
    side = np.cross(up, n)
    d = math.cos(elevation_rad) * (math.cos(azimuth_rad) * n + math.sin(azimuth_rad) * side) \
        + math.sin(elevation_rad) * up
    T_wc = C.look_at(T_wm[:3, 3] + distance_m * d, T_wm[:3, 3])
    hits = C.cast(scene, cam, T_wc)
    return C.render_image(scene, hits, C.marker_print_from_scene(scene), encoding="mono8"), T_wc


@pytest.mark.parametrize("distance_m,limit_m", [(0.5, 0.003), (1.0, 0.006), (1.5, 0.01)])
def test_localization_error_on_rendered_views(scene, distance_m: float, limit_m: float) -> None:
    cam = C.PinholeCamera.from_fov(640, 480, math.radians(60.0))
    table = M.load_marker_config()
    det = M.MarkerDetector(table, max_reprojection_error_px=1.0)
    for az, el in [(0.0, 0.0), (0.4, 0.1), (-0.3, 0.5)]:
        img, T_wc = render_view(scene, cam, distance_m, az, el)
        res = det.detect(img, cam.K)
        assert [d.marker_id for d in res.detections] == [7], res.rejected
        d = res.detections[0]
        R_T_O = M.object_pose(T_wc, d.C_T_M, table.markers[7].M_T_O)
        err = np.linalg.norm(R_T_O[:3, 3] - scene.target.pose[:3, 3])
        assert err < limit_m, (distance_m, az, el, err)
        assert d.reprojection_error_px < 1.0


def test_edge_line_corners_beat_subpixel_corners(scene) -> None:
    """The edge-line fit removes the inward bias of cornerSubPix corners on rendered views."""
    cam = C.PinholeCamera.from_fov(640, 480, math.radians(60.0))
    det = M.MarkerDetector(M.load_marker_config(), edge_refinement=False)
    T_wm = scene.target.marker_pose
    raw_err, edge_err = [], []
    for az, el in [(0.0, 0.0), (0.3, 0.2), (-0.4, 0.4)]:
        img, T_wc = render_view(scene, cam, 1.0, az, el)
        T_cw = np.linalg.inv(T_wc)
        truth, _ = cam.project((M.marker_corners(0.1) @ T_wm[:3, :3].T + T_wm[:3, 3]) @ T_cw[:3, :3].T + T_cw[:3, 3])
        raw = det.detect(img, cam.K).detections[0].corners
        edge = M.refine_corners_by_edges(img, raw, 6)
        assert edge is not None
        raw_err.append(np.abs(raw - truth).max())
        edge_err.append(np.abs(edge - truth).max())
    assert max(edge_err) < 0.12 and max(edge_err) < 0.5 * max(raw_err)
    # nothing to fit: a flat image
    assert M.refine_corners_by_edges(np.full((480, 640), 90, np.uint8), raw, 6) is None


def test_rejections_unknown_ids_and_reprojection_error(scene) -> None:
    cam = C.PinholeCamera.from_fov(640, 480, math.radians(60.0))
    img, _ = render_view(scene, cam, 1.0, 0.2, 0.1)
    other = M.marker_table("DICT_4X4_50", [3], [0.1], [0, 0, 0, 0, 0, 0, 1])
    res = M.MarkerDetector(other).detect(img, cam.K)
    assert res.detections == () and res.rejected == ((7, "id not in the marker table"),)
    strict = M.MarkerDetector(M.load_marker_config(), max_reprojection_error_px=1e-6).detect(img, cam.K)
    assert strict.detections == () and "reprojection error" in strict.rejected[0][1]
    empty = M.MarkerDetector(M.load_marker_config()).detect(np.full((480, 640), 128, np.uint8), cam.K)
    assert empty.detections == () and empty.rejected == ()
    with pytest.raises(ValueError, match="mono8"):
        M.MarkerDetector(M.load_marker_config()).detect(np.zeros((4, 4, 3), np.uint8), cam.K)
    with pytest.raises(ValueError, match="max_reprojection_error_px"):
        M.MarkerDetector(M.load_marker_config(), max_reprojection_error_px=0.0)


# ---------------------------------------------------------------- R_T_C at the image stamp
def test_joint_state_buffer_lookup() -> None:
    buf = M.JointStateBuffer(window_s=1.0)
    assert buf.at(0.0, 0.05) == (None, "no /joint_states received yet")
    for k in range(11):
        buf.push(10.0 + 0.01 * k, np.full(3, float(k)))
    np.testing.assert_allclose(buf.at(10.03, 0.05)[0], 3.0)          # exact stamp
    np.testing.assert_allclose(buf.at(10.035, 0.05)[0], 3.5)         # interpolated
    q, why = buf.at(10.14, 0.05)                                      # within the gap, but moving: stale
    assert q is None and "newer" in why and "move" in why
    plain = M.JointStateBuffer(window_s=1.0, pose_tolerance_rad=math.inf)
    for k in range(11):
        plain.push(10.0 + 0.01 * k, np.full(3, float(k)))
    np.testing.assert_allclose(plain.at(10.14, 0.05)[0], 10.0)       # nearest within the gap (time rule only)
    np.testing.assert_allclose(plain.at(9.97, 0.05)[0], 0.0)
    q, why = buf.at(10.3, 0.05)
    assert q is None and "newer" in why
    q, why = buf.at(9.0, 0.05)
    assert q is None and "older" in why
    with pytest.raises(ValueError, match="pose_tolerance_rad"):
        M.JointStateBuffer(pose_tolerance_rad=-1.0)


def test_joint_state_buffer_gaps_of_a_still_robot() -> None:
    """A loaded machine loses /joint_states: a still robot's pose survives wide gaps (the
    voxel_mapper warning 'joint states around the image stamp are 0.246 s apart'), a moving
    robot's does not."""
    buf = M.JointStateBuffer(window_s=2.0)
    still = np.array([0.1, -0.2, 0.3])
    buf.push(20.0, still)
    buf.push(20.246, still + 2e-4)                                    # 0.246 s gap, held still
    np.testing.assert_allclose(buf.at(20.1, 0.1)[0], still + 2e-4 * 0.1 / 0.246)
    np.testing.assert_allclose(buf.at(20.3, 0.1)[0], still + 2e-4)    # newer, still: the nearest
    np.testing.assert_allclose(buf.at(19.95, 0.1)[0], still)          # older, still: the nearest
    buf.push(20.6, still + 0.2)                                       # then the head turned
    q, why = buf.at(20.4, 0.1)
    assert q is None and "0.354 s apart" in why and "0.1998 rad" in why
    q, why = buf.at(20.62, 0.1)                                       # 20 ms ahead of a moving head
    assert q is None and "move" in why
    start = M.JointStateBuffer()                                      # a joint starts at 2 rad/s at t = 1 s:
    for k in range(6):                                                # states at 0.9 .. 1.0 s still, ...
        start.push(0.9 + 0.02 * k, np.zeros(1))
    for k in range(1, 6):                                             # ... then 1.06 .. 1.14 s moving
        start.push(1.04 + 0.02 * k, np.array([2.0 * (0.04 + 0.02 * k)]))
    q, why = start.at(1.03, 0.05)                                     # between 1.00 and 1.06: the chord errs
    assert q is None and "velocities change" in why
    np.testing.assert_allclose(start.at(1.09, 0.05)[0], 2.0 * 0.09)   # constant velocity: exact
    single = M.JointStateBuffer()
    single.push(5.0, still)
    np.testing.assert_allclose(single.at(5.05, 0.1)[0], still)        # one state: no evidence of motion
    wide = M.JointStateBuffer(pose_tolerance_rad=math.inf)
    wide.push(1.0, still)
    wide.push(1.5, still + 1.0)
    np.testing.assert_allclose(wide.at(1.25, 0.1)[0], still + 0.5)    # inf: any bracket is interpolated


def test_joint_state_buffer_window_and_time_jumps() -> None:
    buf = M.JointStateBuffer(window_s=1.0)
    for k in range(11):
        buf.push(10.0 + 0.01 * k, np.full(3, float(k)))
    buf.push(11.5, np.zeros(3))                                       # window: older states dropped
    assert len(buf) == 1
    buf.push(5.0, np.ones(3))                                         # time jumped back: restart
    assert len(buf) == 1 and buf.at(5.0, 0.0)[0][0] == 1.0


def test_camera_pose() -> None:
    model = RobotModel()
    q = model.half_sitting_joints
    T = M.camera_pose(model, q, "head_camera_optical_frame")
    np.testing.assert_allclose(T, model.frame_pose(model.half_sitting(), "head_camera_optical_frame").homogeneous,
                               atol=1e-12)
    assert T[2, 2] < 0.01 and T[0, 2] > 0.99   # optical axis forward (x), horizontal at pitch 0

