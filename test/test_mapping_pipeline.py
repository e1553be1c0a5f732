"""Tests of perception/mapping.py without ROS: the voxel mapper's frame routing, still-camera
skip, publish policy, robot sweep, mailbox and worker, problems and diagnostics values."""
from __future__ import annotations

import dataclasses
import threading
import time

import numpy as np
import pytest
import yaml

from humanoid_reach_ros.perception.mapping import DepthJob, MapLayers, MappingConfig, MappingPipeline
from humanoid_reach_ros.geometry.camera import CameraCalibration
from humanoid_reach_ros.perception.markers import camera_pose
from humanoid_reach_ros.perception.stereo import render_textured_pair
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.shapes import load_collision_model
from nodetools import REPO_ROOT

CAMERA_FRAME = "head_camera_optical_frame"
T0 = 1000.0
GX, GY = np.meshgrid(np.linspace(-0.3, 0.3, 25), np.linspace(-0.3, 0.3, 25))
WALL = np.stack([GX.ravel(), GY.ravel(), np.full(GX.size, 1.0)], axis=1)   # camera frame, 1 m ahead


@pytest.fixture(scope="module")
def model() -> RobotModel:
    return RobotModel()


@pytest.fixture(scope="module")
def collision(model):
    return load_collision_model(None, model)


class Clock:
    """A monotonic clock the test moves."""

    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


class Rig:
    """A pipeline with a test clock, joint states the test feeds and the warnings it logged."""

    def __init__(self, model, collision, **config) -> None:
        self.model, self.clock, self.warnings = model, Clock(), []
        self.pending: list[tuple[float, np.ndarray]] = []
        self.pipeline = MappingPipeline(MappingConfig(**config), model, collision, joint_states=self._take,
                                        warn=self.warnings.append, clock=self.clock)

    def _take(self):
        out, self.pending = self.pending, []
        return out

    def joints(self, yaw: float = 0.0, pitch: float = 0.5) -> np.ndarray:
        j = self.model.half_sitting_joints.copy()
        j[self.model.joint_index["HEAD_JOINT0"]] = yaw
        j[self.model.joint_index["HEAD_JOINT1"]] = pitch
        return j

    def hold(self, joints: np.ndarray, t: float) -> None:
        """Joint states bracketing stamp ``t``."""
        self.pending += [(t - 0.02, joints), (t + 0.02, joints)]

    def counter(self, name: str) -> int:
        return getattr(self.pipeline.counters, name)


@pytest.fixture
def rig(model, collision) -> Rig:
    return Rig(model, collision)


# ---------------------------------------------------------------- config
def test_config_from_the_node_parameters_file_is_the_default() -> None:
    p = yaml.safe_load((REPO_ROOT / "config/voxel_mapper.yaml").read_text())["/**"]["ros__parameters"]
    assert MappingConfig.from_parameters(p) == MappingConfig()
    bad = {**p, "unobserved_region_min_m": [0.0, 0.0]}
    with pytest.raises(ValueError, match=r"unobserved_region_min_m must have 3 finite entries"):
        MappingConfig.from_parameters(bad)
    with pytest.raises(ValueError, match=r"extent_max_m must have 3 finite entries"):
        MappingConfig.from_parameters({**p, "extent_max_m": [1.0, float("nan"), 1.0]})
    c = MappingConfig.from_parameters({**p, "stereo_block_size": 9, "resolution_m": 0.05})
    assert c.stereo.block_size == 9 and c.fusion.resolution_m == 0.05


def test_bad_settings_fail_at_construction(model, collision) -> None:
    with pytest.raises(KeyError, match="no_such_frame"):
        MappingPipeline(MappingConfig(sensor_frame="no_such_frame"), model, collision)
    with pytest.raises(ValueError, match="num_disparities"):
        MappingPipeline(MappingConfig(stereo=dataclasses.replace(MappingConfig().stereo, num_disparities=30)),
                        model, collision)
    p = MappingPipeline(MappingConfig(), model, collision)
    assert p.config.sensor_frame == model.camera_frame   # empty: the head camera


# ---------------------------------------------------------------- frame routing
def test_urdf_frame_cloud_is_placed_by_the_joint_states_at_its_stamp(rig) -> None:
    p = rig.pipeline
    joints = rig.joints(0.2, 0.5)
    rig.hold(joints, T0)
    assert p.integrate(DepthJob(WALL, CAMERA_FRAME, T0, "test")) == "integrated"
    T = camera_pose(rig.model, joints, CAMERA_FRAME)
    world = WALL @ T[:3, :3].T + T[:3, 3]
    occupied = p.map.occupied_centers()
    assert len(occupied) > 100
    inside = np.all((world > np.array(p.config.fusion.extent_min_m)) & (world < np.array(p.config.fusion.extent_max_m)),
                    axis=1)
    d = np.min(np.linalg.norm(occupied[:, None, :] - world[None, inside], axis=2), axis=1)
    assert d.max() < 0.02 * 1.8
    assert rig.counter("clouds_integrated") == 1 and rig.counter("points_integrated") > 0
    assert p.counters.last_integrated_stamp_s == T0


def test_unknown_frame_and_missing_pose_leave_the_map_alone(rig) -> None:
    p = rig.pipeline
    assert p.integrate(DepthJob(WALL, "camera_link_typo", T0, "/head_camera/points")) == "unknown_frame"
    assert p.integrate(DepthJob(WALL, CAMERA_FRAME, T0, "/head_camera/points")) == "no_pose"   # no joint states
    rig.hold(rig.joints(), T0)
    assert p.integrate(DepthJob(WALL, CAMERA_FRAME, T0 + 100.0, "/head_camera/points")) == "no_pose"   # far stamp
    assert p.map.version == 0 and p.map.depth_maps == 0
    c = p.counters
    assert (c.unknown_frame, c.no_pose, c.clouds_integrated) == (1, 2, 0)
    assert c.problems == {"unknown_frame": 1, "no_pose": 2}
    assert any("unknown frame 'camera_link_typo'" in w for w in rig.warnings)
    assert any("no camera pose at its stamp" in w for w in rig.warnings)


def test_world_frame_cloud_clears_from_the_sensor_origin_or_is_only_marked(rig) -> None:
    p = rig.pipeline
    joints = rig.joints(0.0, 0.5)
    T = camera_pose(rig.model, joints, CAMERA_FRAME)
    world = WALL @ T[:3, :3].T + T[:3, 3]
    # no joint states: marked, nothing cleared, counted as a problem but not as a rejected cloud
    assert p.integrate(DepthJob(world, "world", T0, "test")) == "marked"
    assert p.counters.no_pose == 0 and p.counters.problems["no_pose"] == 1
    observed_marked = p.map.observed_count
    p.clear()
    rig.hold(joints, T0)
    assert p.integrate(DepthJob(world, "world", T0, "test")) == "integrated"
    assert p.map.observed_count > 3 * observed_marked     # the rays from the head camera cleared space
    assert p.map.occupied_count() > 100


def test_unstamped_cloud_takes_the_newest_joint_state(rig) -> None:
    p = rig.pipeline
    rig.pending += [(T0, rig.joints(-0.3, 0.5)), (T0 + 5.0, rig.joints(0.3, 0.5))]
    assert p.integrate(DepthJob(WALL, CAMERA_FRAME, 0.0, "test")) == "integrated"
    T = camera_pose(rig.model, rig.joints(0.3, 0.5), CAMERA_FRAME)
    centre = T[:3, :3] @ np.array([0.0, 0.0, 1.0]) + T[:3, 3]
    assert np.min(np.linalg.norm(p.map.occupied_centers() - centre, axis=1)) < 0.03


def test_still_camera_integrates_once_per_period(rig) -> None:
    p = rig.pipeline   # still_integration_period_s = 1.0
    still = rig.joints()
    for k in range(4):
        rig.hold(still, T0 + k)
        outcome = p.integrate(DepthJob(WALL, CAMERA_FRAME, T0 + k, "test"))
        assert outcome == ("integrated" if k == 0 else "still")
        rig.clock.t += 0.2
    rig.clock.t += 1.0                                     # the period passed: once more
    rig.hold(still, T0 + 10)
    assert p.integrate(DepthJob(WALL, CAMERA_FRAME, T0 + 10, "test")) == "integrated"
    rig.hold(rig.joints(0.3), T0 + 11)                     # a moved head: at once
    assert p.integrate(DepthJob(WALL, CAMERA_FRAME, T0 + 11, "test")) == "integrated"
    assert (rig.counter("clouds_integrated"), rig.counter("clouds_skipped_still")) == (3, 3)


# ---------------------------------------------------------------- publish policy and sweep
def test_publish_policy_minor_changes_of_a_still_view_wait(model, collision) -> None:
    rig = Rig(model, collision, still_integration_period_s=0.0, minor_change_period_s=60.0)
    p = rig.pipeline
    first = p.layers_to_publish()                          # the empty map, once
    assert first is not None and len(first.occupied) == 0 and len(first.blocks) > 0
    assert p.layers_to_publish() is None                   # nothing changed
    still = rig.joints()
    rig.hold(still, T0)
    p.integrate(DepthJob(WALL, CAMERA_FRAME, T0, "test"))  # the first view: published at once
    layers = p.layers_to_publish()
    assert layers is not None and len(layers.occupied) > 100 and layers.frontier is not None
    assert p.published_version == p.map.version
    rig.hold(still, T0 + 1)                                # the same pose, one voxel more: minor, deferred
    p.integrate(DepthJob(np.vstack([WALL, [[0.0, 0.0, 0.7]]]), CAMERA_FRAME, T0 + 1, "test"))
    assert p.layers_to_publish() is None and p.layers_to_publish() is None
    assert rig.counter("minor_changes_deferred") == 2
    rig.clock.t += 61.0                                    # ... until minor_change_period_s passed
    layers = p.layers_to_publish()
    assert layers is not None and len(layers.occupied) == len(p.map.occupied_centers())
    rig.hold(still, T0 + 2)
    p.integrate(DepthJob(np.vstack([WALL, [[0.05, 0.0, 0.7]]]), CAMERA_FRAME, T0 + 2, "test"))
    assert p.layers_to_publish(force=True) is not None    # forced (a clear)
    rig.hold(rig.joints(0.05), T0 + 3)                    # a new camera pose: at once
    p.integrate(DepthJob(WALL, CAMERA_FRAME, T0 + 3, "test"))
    assert p.layers_to_publish() is not None


def test_unchanged_layers_are_not_repeated_and_forced_publication_sends_none(rig) -> None:
    p = rig.pipeline
    p.layers_to_publish()
    assert p.layers_to_publish(force=True) == MapLayers(None, None, None)


def test_robot_body_is_swept_into_observed_free_space(rig) -> None:
    p = rig.pipeline
    before = p.layers_to_publish()
    assert p.map.swept_count == 0                          # no joint states: nothing swept
    rig.pending.append((T0, rig.joints()))
    after = p.layers_to_publish()                          # the sweep is a change: published
    swept = p.map.swept_count
    assert swept > 1000 and after is not None and len(after.blocks) < len(before.blocks)
    rig.pending.append((T0 + 1, rig.joints() + 1e-4))      # the same posture: no new mark
    assert p.layers_to_publish() is None and p.map.swept_count == swept
    assert p.clear() == 0 and p.counters.clears == 1 and p.map.swept_count == 0
    rig.pending.append((T0 + 2, rig.joints()))            # still: the body is swept again after a clear
    p.layers_to_publish()
    assert p.map.swept_count == swept


def test_stereo_pair_becomes_points_in_the_left_optical_frame(rig) -> None:
    pair = render_textured_pair(320, 240, focal_px=277.0, baseline_m=0.07, plane_depth_m=1.0)
    c = pair.calibration
    left = CameraCalibration(c.size[0], c.size[1], c.K1, np.zeros(5), np.eye(3), c.P1)
    right = CameraCalibration(c.size[0], c.size[1], c.K2, np.zeros(5), np.eye(3), c.P2)
    points = rig.pipeline.stereo_points(left, right, pair.left, pair.right)
    assert len(points) > 1000 and np.median(np.abs(points[:, 2] - 1.0)) < 0.01
    assert rig.counter("stereo_pairs") == 1
    small = CameraCalibration(160, 120, c.K2, np.zeros(5), np.eye(3), c.P2)
    with pytest.raises(ValueError):
        rig.pipeline.stereo_points(left, small, pair.left, pair.right)
    assert rig.counter("stereo_pairs") == 1


# ---------------------------------------------------------------- mailbox and worker
def test_full_mailbox_drops_the_oldest(model, collision) -> None:
    rig = Rig(model, collision, input_queue_depth=2)
    p = rig.pipeline
    for k in range(5):
        p.post(k, "clouds_received")
    assert rig.counter("clouds_received") == 5 and rig.counter("clouds_dropped_busy") == 3
    seen, done = [], threading.Event()
    rig.hold(rig.joints(), T0)

    def convert(item):
        seen.append(item)
        if item == 3:
            raise RuntimeError("boom")                    # the worker survives an input's error
        done.set()
        return DepthJob(WALL, CAMERA_FRAME, T0, "test")

    p.start(convert)
    try:
        assert done.wait(20.0)
        deadline = time.monotonic() + 20.0
        while rig.counter("clouds_integrated") < 1 and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        p.stop()
    assert seen == [3, 4] and rig.counter("clouds_integrated") == 1
    assert p.counters.problems["internal_error"] == 1 and "RuntimeError: boom" in p.counters.last_problem


# ---------------------------------------------------------------- problems and diagnostics
def test_problems_are_counted_always_and_warned_once_per_throttle(model, collision) -> None:
    rig = Rig(model, collision, warn_throttle_s=2.0, problem_hold_s=5.0)
    p = rig.pipeline
    status = p.status()
    assert not status.inputs_ok and status.inputs_message == "no depth input yet"
    for _ in range(3):
        p.problem("malformed_cloud", "bad cloud", "clouds_rejected")
    assert rig.warnings == ["bad cloud (malformed_cloud, 1 so far)"]
    rig.clock.t += 2.5
    p.problem("malformed_cloud", "bad cloud", "clouds_rejected")
    assert rig.warnings[-1] == "bad cloud (malformed_cloud, 4 so far)"
    p.problem("nonfinite_points", "NaN", "points_nonfinite", 20)
    status = p.status()
    assert not status.inputs_ok and status.inputs_message.startswith("rejected input: nonfinite_points: NaN")
    v = status.inputs_values
    assert v["clouds_rejected"] == 4 and v["points_nonfinite"] == 20
    assert v["problem_malformed_cloud"] == 4 and v["problem_nonfinite_points"] == 1
    rig.clock.t += 6.0                                    # problem_hold_s passed; an input arrived
    p.post(object(), "clouds_received")
    status = p.status()
    assert status.inputs_ok and status.inputs_message == "0 depth maps integrated, 0 dropped while busy"


def test_status_values(rig) -> None:
    p = rig.pipeline
    rig.pending += [(T0, rig.joints()), (T0 + 0.05, rig.joints()), (T0 + 0.06, rig.joints())]
    rig.hold(rig.joints(), T0 + 0.1)
    p.integrate(DepthJob(WALL, CAMERA_FRAME, T0 + 0.1, "test"))
    p.layers_to_publish()
    s = p.status()
    m = s.map_values
    assert {"occupied_voxels", "capacity_voxels", "memory_bytes", "resolution_m", "depth_maps", "frame_id",
            "last_integration_ms", "mean_integration_ms", "last_integrated_stamp_s", "points_per_s", "clears",
            "map_version", "published_version", "unobserved_frontier_voxels", "unobserved_blocks"} <= set(m)
    assert m["occupied_voxels"] > 100 and m["depth_maps"] == 1 and m["frame_id"] == "world"
    assert m["map_version"] == m["published_version"] and m["last_integrated_stamp_s"] == f"{T0 + 0.1:.6f}"
    assert s.map_message == f"{m['occupied_voxels']} occupied voxels from 1 depth maps"
    v = s.inputs_values
    assert v["joint_states_buffered"] == 5 and v["clouds_integrated"] == 1
    assert v["joint_states_max_gap_ms"] == pytest.approx(50.0, abs=1e-6)
    assert p.status().inputs_values["joint_states_max_gap_ms"] == 0.0    # per diagnostics window
    assert v["joint_states_max_gap_ms_since_start"] == pytest.approx(50.0, abs=1e-6)
