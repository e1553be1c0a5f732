"""Simulated head sensors (humanoid_reach_ros.sim.camera): pinhole model, tiled ray cast,
rendering of the plant scene with the ArUco marker, depth cloud noise and dropouts, stereo."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.sim import camera as C
from humanoid_reach_ros.sim.scene import load_scene, scene_from_dict

HEAD_PITCH_RAD = 0.6  # the head pitch at which the half-sitting robot sees the valve marker


@pytest.fixture(scope="module")
def scene():
    return load_scene("scenes/plant.yaml")


@pytest.fixture(scope="module")
def cam() -> C.PinholeCamera:
    return C.PinholeCamera.from_fov(640, 480, math.radians(60.0))


@pytest.fixture(scope="module")
def head_pose() -> np.ndarray:
    """World pose of head_camera_optical_frame, half-sitting with the head pitched down."""
    model = RobotModel()
    j = model.half_sitting_joints.copy()
    j[model.joint_index["HEAD_JOINT1"]] = HEAD_PITCH_RAD
    return np.asarray(model.frame_pose(model.config(j, model.base_on_feet(j)), "head_camera_optical_frame").homogeneous)


# ---------------------------------------------------------------- camera model
def test_intrinsics_and_projection_of_known_points(cam) -> None:
    f = 320.0 / math.tan(math.radians(30.0))
    assert cam.fx == pytest.approx(f) and cam.fy == pytest.approx(f)
    assert (cam.cx, cam.cy) == (319.5, 239.5)
    np.testing.assert_allclose(cam.K, [[f, 0, 319.5], [0, f, 239.5], [0, 0, 1]])
    pts = np.array([[0.0, 0.0, 2.0],                 # on the axis -> principal point
                    [math.tan(math.radians(30.0)), 0.0, 1.0],  # edge of the horizontal fov
                    [0.1, -0.2, 0.5],
                    [0.0, 0.0, -1.0]])               # behind the camera
    uv, z = cam.project(pts)
    np.testing.assert_allclose(uv[0], [319.5, 239.5])
    np.testing.assert_allclose(uv[1], [319.5 + 320.0, 239.5])
    np.testing.assert_allclose(uv[2], [319.5 + f * 0.2, 239.5 - f * 0.4])
    assert np.all(np.isnan(uv[3])) and z[3] == -1.0


def test_ray_directions_reproject_to_their_pixels(cam) -> None:
    rays = cam.rays()
    assert rays.shape == (640 * 480, 3)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0)
    for u, v in [(0, 0), (639, 479), (320, 17), (5, 400)]:
        uv, _ = cam.project(rays[v * 640 + u][None] * 3.7)
        np.testing.assert_allclose(uv[0], [u, v], atol=1e-9)
    assert np.all(rays[:, 2] > 0)                      # all in front
    assert rays[0, 0] < 0 and rays[0, 1] < 0            # top-left pixel: x left (<0), y up (<0)


def test_bad_camera_parameters_are_refused() -> None:
    with pytest.raises(ValueError, match="focal"):
        C.PinholeCamera(640, 480, 0.0, 500.0, 320.0, 240.0)
    with pytest.raises(ValueError, match="field of view"):
        C.PinholeCamera.from_fov(640, 480, 3.5)
    with pytest.raises(ValueError, match="size"):
        C.PinholeCamera(0, 480, 500.0, 500.0, 320.0, 240.0)


def test_look_at_points_the_optical_axis() -> None:
    T = C.look_at([0.0, 0.0, 1.0], [1.0, 0.0, 1.0])
    np.testing.assert_allclose(T[:3, 2], [1, 0, 0], atol=1e-12)    # z forward
    np.testing.assert_allclose(T[:3, 1], [0, 0, -1], atol=1e-12)   # y down
    np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)
    with pytest.raises(ValueError):
        C.look_at([0, 0, 1], [0, 0, 2])


# ---------------------------------------------------------------- ray casting
def test_tiled_cast_equals_full_cast(scene, cam, head_pose) -> None:
    for T in (head_pose, C.look_at([0.2, 0.3, 1.2], [0.9, -0.2, 0.5]), C.look_at([0.0, 0.0, 0.5], [1.0, 0.0, 0.5])):
        hits = C.cast(scene, cam, T)
        r, k = scene.raycast(T[:3, 3], cam.rays() @ T[:3, :3].T, return_index=True)
        np.testing.assert_array_equal(hits.primitive, k)
        np.testing.assert_allclose(hits.range_m[k >= 0], r[k >= 0])
        threaded = C.cast(scene, cam, T, threads=2)
        np.testing.assert_array_equal(threaded.primitive, hits.primitive)
        np.testing.assert_array_equal(threaded.range_m, hits.range_m)


def test_cast_range_to_the_floor() -> None:
    floor = scene_from_dict({"primitives": [{"name": "floor", "type": "plane", "normal": [0, 0, 1]}]})
    small = C.PinholeCamera.from_fov(41, 31, 1.0)
    T = C.look_at([0.0, 0.0, 1.5], [0.0, 0.0, 0.0], up=[1.0, 0.0, 0.0])  # looking straight down
    hits = C.cast(floor, small, T)
    centre = 15 * 41 + 20
    assert hits.range_m[centre] == pytest.approx(1.5)
    pts = hits.points_world()
    np.testing.assert_allclose(pts[:, 2], 0.0, atol=1e-12)
    np.testing.assert_allclose(hits.range_m * small.rays()[:, 2], 1.5)   # depth z is constant


def test_surface_normals_match_sdf_gradients(scene, cam, head_pose) -> None:
    hits = C.cast(scene, cam, head_pose)
    pts = hits.points_world()
    rng = np.random.default_rng(1)
    for k in np.unique(hits.primitive[hits.hit]):
        prim = scene.primitives[k]
        idx = np.flatnonzero(hits.primitive == k)
        idx = rng.choice(idx, min(50, len(idx)), replace=False)
        p = pts[idx]
        n = C.surface_normals(prim, p)
        g = np.stack([prim.sdf(p + e) - prim.sdf(p - e) for e in 1e-6 * np.eye(3)], axis=1)
        g /= np.linalg.norm(g, axis=1, keepdims=True)
        # a box edge / cylinder rim has two valid normals; all but a few must agree
        agree = np.einsum("ij,ij->i", n, g) > 0.999
        assert agree.mean() > 0.9, prim.name


# ---------------------------------------------------------------- rendering
def test_valve_region_and_marker_decode(scene, cam, head_pose) -> None:
    hits = C.cast(scene, cam, head_pose)
    img = C.render_image(scene, hits, C.marker_print_from_scene(scene))
    assert img.shape == (480, 640, 3) and img.dtype == np.uint8
    T_cw = np.linalg.inv(head_pose)
    # the valve rim's top point is in view and rendered red
    rim = scene.primitive("valve_rim")
    top = np.asarray(rim.center) + [0.0, 0.0, rim.major_radius]
    uv, _ = cam.project((T_cw[:3, :3] @ top + T_cw[:3, 3])[None])
    u, v = np.round(uv[0]).astype(int)
    assert scene.primitives[hits.primitive[v * 640 + u]].group == "valve"
    r, g, b = img[v, u].astype(int)
    assert r > 2 * g and r > 2 * b
    # the marker decodes with OpenCV at the projected corners of the scene's marker pose
    T_wm = scene.target.marker_pose
    s = scene.target.aruco.size_m
    corners_m = np.array([[-s / 2, s / 2, 0], [s / 2, s / 2, 0], [s / 2, -s / 2, 0], [-s / 2, -s / 2, 0]])
    corners_w = corners_m @ T_wm[:3, :3].T + T_wm[:3, 3]
    expect, _ = cam.project(corners_w @ T_cw[:3, :3].T + T_cw[:3, 3])
    det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50))
    corners, ids, _ = det.detectMarkers(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY))
    assert ids is not None and ids.ravel().tolist() == [7]
    np.testing.assert_allclose(corners[0].reshape(4, 2), expect, atol=1.5)
    # rays that miss everything get the background colour; mono8 is one channel
    mono = C.render_image(scene, hits, None, encoding="mono8")
    assert mono.shape == (480, 640) and mono.dtype == np.uint8
    with pytest.raises(ValueError, match="unsupported encoding"):
        C.render_image(scene, hits, None, encoding="bgr16")


def test_marker_cells_and_albedo() -> None:
    cells = C.aruco_cells("DICT_4X4_50", 7)
    assert cells.shape == (6, 6)
    assert not cells[0].any() and not cells[-1].any() and not cells[:, 0].any() and not cells[:, -1].any()
    mp = C.MarkerPrint(np.eye(4), 0.06, cells)
    a = mp.albedo(np.array([[-0.029, 0.029], [0.0, 0.0], [0.034, 0.0], [0.05, 0.0]]))
    assert a[0] == pytest.approx(0.05)      # black border cell
    assert a[2] == pytest.approx(0.92)      # white label margin
    assert math.isnan(a[3])                 # off the label
    with pytest.raises(ValueError, match="not in DICT_4X4_50"):
        C.aruco_cells("DICT_4X4_50", 50)
    with pytest.raises(ValueError, match="unknown ArUco dictionary"):
        C.aruco_cells("DICT_NOPE", 1)


def test_texture_adds_contrast_everywhere_but_the_marker(scene, cam, head_pose) -> None:
    hits = C.cast(scene, cam, head_pose)
    marker = C.marker_print_from_scene(scene)
    plain = C.render_image(scene, hits, marker, C.RenderStyle(), "mono8").astype(float)
    tex = C.render_image(scene, hits, marker, C.RenderStyle(texture_amplitude=0.3), "mono8").astype(float)
    floor = hits.primitive.reshape(480, 640) == 0
    lap = lambda im: np.abs(cv2.Laplacian(im, cv2.CV_64F))[floor].mean()  # noqa: E731
    assert lap(tex) > 3.0 * lap(plain)
    ids = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)).detectMarkers(
        tex.astype(np.uint8))[1]
    assert ids is not None and 7 in ids.ravel()


def test_without_primitives(scene, cam, head_pose) -> None:
    reduced = C.without_primitives(scene, ["valve_supply_pipe"])
    assert len(reduced.primitives) == len(scene.primitives) - 1
    a, b = C.cast(scene, cam, head_pose), C.cast(reduced, cam, head_pose)
    pipe = scene._index["valve_supply_pipe"]
    seen = a.primitive == pipe
    assert seen.sum() > 1000
    assert np.all(b.range_m[seen] > a.range_m[seen])   # what was behind the pipe is further away
    with pytest.raises(KeyError, match="no primitive"):
        C.without_primitives(scene, ["no_such_pipe"])


# ---------------------------------------------------------------- depth sensor
def test_depth_points_exact_without_noise(scene, cam, head_pose) -> None:
    hits = C.cast(scene, cam, head_pose)
    pts = C.depth_points(hits, C.DepthNoise(0.0, 0.0, 0.1, 5.0, 1), np.random.default_rng(0))
    assert len(pts) == int((np.isfinite(hits.range_m) & (hits.range_m <= 5.0)).sum())
    world = pts @ head_pose[:3, :3].T + head_pose[:3, 3]
    assert np.abs(scene.sdf(world)).max() < 1e-6
    r = np.linalg.norm(pts, axis=1)
    assert r.min() >= 0.1 and r.max() <= 5.0


def test_depth_noise_grows_with_range_squared_and_dropouts(scene, cam, head_pose) -> None:
    hits = C.cast(scene, cam, head_pose)
    k, p = 0.01, 0.2
    clean = C.depth_points(hits, C.DepthNoise(0.0, 0.0, 0.1, 5.0, 2), np.random.default_rng(0))
    noisy = C.depth_points(hits, C.DepthNoise(k, 0.0, 0.1, 5.0, 2), np.random.default_rng(0))
    assert noisy.shape == clean.shape
    r = np.linalg.norm(clean, axis=1)
    err = np.linalg.norm(noisy, axis=1) - r
    # along the ray only: same directions
    np.testing.assert_allclose(noisy / np.linalg.norm(noisy, axis=1, keepdims=True), clean / r[:, None], atol=1e-9)
    z = err / (k * r * r)
    assert abs(z.mean()) < 0.05 and abs(z.std() - 1.0) < 0.05
    dropped = C.depth_points(hits, C.DepthNoise(0.0, p, 0.1, 5.0, 2), np.random.default_rng(0))
    assert abs(1.0 - len(dropped) / len(clean) - p) < 0.02
    with pytest.raises(ValueError):
        C.DepthNoise(dropout_probability=1.5)
    with pytest.raises(ValueError):
        C.DepthNoise(min_range_m=2.0, max_range_m=1.0)


# ---------------------------------------------------------------- stereo pair
def test_stereo_pair_geometry_and_disparity(scene, cam, head_pose) -> None:
    left, right = C.stereo_poses(head_pose, 0.07)
    np.testing.assert_allclose(left, head_pose)
    np.testing.assert_allclose(right[:3, 3] - left[:3, 3], 0.07 * head_pose[:3, 0])
    np.testing.assert_allclose(right[:3, :3], left[:3, :3])
    # a point at depth z shows a disparity fx B / z between the two images
    p_w = scene.target.marker_pose[:3, 3]
    uvs = []
    for T in (left, right):
        T_cw = np.linalg.inv(T)
        uv, z = cam.project((T_cw[:3, :3] @ p_w + T_cw[:3, 3])[None])
        uvs.append(uv[0])
    assert uvs[0][0] - uvs[1][0] == pytest.approx(cam.fx * 0.07 / z[0])
    assert uvs[0][1] == pytest.approx(uvs[1][1])
    with pytest.raises(ValueError, match="baseline"):
        C.stereo_poses(head_pose, 0.0)


def test_shading_kernel_texture_matches_the_reference() -> None:
    """ambient 1: a pixel is colour x texture factor, the factor of RenderStyle.texture."""
    floor = scene_from_dict({"primitives": [{"name": "floor", "type": "plane", "normal": [0, 0, 1],
                                             "color": [0.5, 0.5, 0.5]}]})
    small = C.PinholeCamera.from_fov(64, 48, 1.0)
    hits = C.cast(floor, small, C.look_at([0.0, 0.0, 1.0], [0.3, 0.1, 0.0]))
    style = C.RenderStyle(ambient=1.0, texture_amplitude=0.5)
    img = C.render_image(floor, hits, None, style).astype(float)[..., 0].ravel()
    expect = np.clip(0.5 * style.texture(hits.points_world()) * 255.0 + 0.5, 0, 255).astype(int)
    assert np.abs(img - expect).max() <= 1
    assert img.std() > 10.0
