"""Node-level test of the perception graph with real processes: joint_driver -> scene_sim ->
voxel_mapper (issue 5, items 2 and 6).

The test commands a head scan on ``/joint_command`` (HEAD_JOINT0 yaw / HEAD_JOINT1 pitch only,
the poses of ``SCAN_DEG``), waits at every pose until the mapper has integrated
several depth maps, and compares ``/voxel_map`` with the scene (``config/scenes/plant.yaml``
voxelized at the map's resolution by ``Scene.voxelize``):

* *no false occupancy*: every occupied voxel lies within one voxel (26-neighbourhood) of a
  ground-truth voxel (floor surface voxels included: a noisy floor point just above the
  mapper's ``floor_z_m`` band is a measurement of the floor);
* *completeness where the sensor looked*: the *visible* ground-truth voxels are those within
  one voxel of a point that scene_sim's depth sensor measured at a scan pose (the clouds the
  test itself received while the head held still, placed in the world by forward kinematics
  of the ``/joint_states`` message whose stamp they carry, floor band excluded); at least 95 %
  of them have an occupied voxel within one voxel;
* removing ``passage_pipe`` at run time (scene_sim's ``disabled_primitives`` via
  set_parameters) and rescanning clears its voxels from the map.

A second test runs scene_sim's stereo pair into a voxel_mapper with ``use_stereo`` (no depth
sensor) and compares the stereo map with the scene and with a depth-sensor map of the same
scan poses. Nothing here asserts on timing.
"""
from __future__ import annotations

import time
from typing import Any

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import JointState, PointCloud2

from humanoid_reach_ros.io import msgs
from humanoid_reach_ros.perception.markers import camera_pose
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.sim.camera import without_primitives
from humanoid_reach_ros.sim.scene import load_scene

# the head scan this test is calibrated with (the six yaw/pitch poses [deg] of the demo's first scan;
# the executor's scan_poses_deg has four more since: after that scan a single rescan left 3 of a removed
# pipe's ~400 voxels at its ends, see the issue notes)
SCAN_DEG = ((0.0, 35.0), (-30.0, 30.0), (30.0, 30.0), (-25.0, 5.0), (25.0, 5.0), (0.0, 10.0))

H = 0.02                                    # voxel_mapper's default resolution_m
GT_EXTENT = ((-0.5, -1.0, 0.0), (1.5, 1.0, 2.0))
FLOOR_BAND_M = 0.04                         # measured points below this height are floor (not mapped)
CAMERA_FRAME = "head_camera_optical_frame"
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
SIM = {"width": 320, "height": 240, "joint_states_timeout_s": 3600.0, "diagnostics_period_s": 0.5}
MAPPER = {"publish_period_s": 0.2, "diagnostics_period_s": 0.2, "warn_throttle_s": 0.0,
          "still_integration_period_s": 0.0}   # every depth map of a held pose integrated (not one a second)
CLOUDS_PER_POSE = 3                         # depth maps integrated at every scan pose
CLEAR_CLOUDS_PER_POSE = 8                   # ... when rescanning to clear (the free-space update is gentler)


@pytest.fixture(scope="module")
def model() -> RobotModel:
    return RobotModel()


@pytest.fixture(scope="module")
def scene():
    return load_scene("scenes/plant.yaml")


# ---------------------------------------------------------------- helpers
def keys(points: np.ndarray) -> np.ndarray:
    return np.floor(np.asarray(points, dtype=float).reshape(-1, 3) / H + 1e-9).astype(np.int64)


def near(a: np.ndarray, b: np.ndarray, tol: int = 1) -> np.ndarray:
    """For each point of ``a``: is a voxel of ``b`` within ``tol`` voxels (Chebyshev)?"""
    bs = set(map(tuple, keys(b)))
    r = range(-tol, tol + 1)
    offsets = [(i, j, k) for i in r for j in r for k in r]
    return np.array([any((x + i, y + j, z + k) in bs for i, j, k in offsets) for x, y, z in keys(a)], bool)


class Graph:
    """The test's side of joint_driver + scene_sim + voxel_mapper: head commands, the clouds
    scene_sim published (with the joint states of their stamps) and the mapper's outputs."""

    def __init__(self, probe, model: RobotModel, mapper, sim) -> None:
        self.probe, self.model, self.mapper, self.sim = probe, model, mapper, sim
        self.command_pub = probe.node.create_publisher(JointState, "/joint_command", 10)
        self.joints = probe.collect(JointState, "/joint_states", qos_profile_sensor_data)
        self.clouds = probe.collect(PointCloud2, "/head_camera/points", qos_profile_sensor_data)
        self.maps = probe.collect(PointCloud2, "/voxel_map", LATCHED)
        self.diags = probe.collect(DiagnosticArray, "/diagnostics")
        self.head_joints = list(model.spec.head_joints)
        self.head = [model.joint_index[n] for n in self.head_joints]

    def logs(self) -> str:
        return "\n".join(p.log_tail() for p in (self.sim, self.mapper) if p is not None)

    def mapper_status(self, section: str) -> dict[str, str] | None:
        for arr in reversed(self.diags.messages):
            for st in arr.status:
                if st.name == f"voxel_mapper: {section}":
                    return msgs.diagnostic_values(st)
        return None

    def counter(self, key: str) -> int:
        st = self.mapper_status("inputs")
        return int(st.get(key, 0)) if st is not None else 0

    def look(self, yaw_deg: float, pitch_deg: float) -> None:
        """Command the head (the two head joints only) until the driver reports it there."""
        goal = np.radians([yaw_deg, pitch_deg])
        cmd = msgs.joint_state(self.head_joints, goal)

        def there() -> bool:
            self.command_pub.publish(cmd)
            js = self.joints.last
            if js is None:
                return False
            pos = dict(zip(js.name, js.position))
            return bool(np.all(np.abs(np.array([pos[n] for n in self.head_joints]) - goal) < 0.005))

        self.probe.spin_until(there, 30.0, f"the head at yaw {yaw_deg:g}, pitch {pitch_deg:g} deg",
                              on_timeout=self.logs)

    def hold(self, yaw_deg: float, pitch_deg: float, clouds: int = CLOUDS_PER_POSE) -> list[PointCloud2]:
        """Look, then wait until the test received ``clouds`` depth maps stamped after the head
        arrived and the mapper integrated ``clouds`` more depth maps, the newest of them at least
        as new as those (its ``last_integrated_stamp_s``): a loaded mapper that is still working
        through maps taken while the head moved has not seen this pose yet. Returns the clouds."""
        self.look(yaw_deg, pitch_deg)
        arrived_ns = msgs.nanoseconds_from_time(self.joints.last.header.stamp)
        n0 = self.counter("clouds_integrated")
        k0 = len(self.clouds)

        def settled() -> list[PointCloud2] | None:
            held = [c for c in self.clouds.messages[k0:] if msgs.nanoseconds_from_time(c.header.stamp) >= arrived_ns]
            m = self.mapper_status("map")
            if len(held) < clouds or m is None or self.counter("clouds_integrated") < n0 + clouds:
                return None
            newest_ns = round(float(m.get("last_integrated_stamp_s", 0.0)) * 1e9)
            return held if newest_ns >= msgs.nanoseconds_from_time(held[clouds - 1].header.stamp) - 1000 else None

        return self.probe.spin_until(settled, 60.0, f"{clouds} depth maps integrated at yaw {yaw_deg:g}, "
                                     f"pitch {pitch_deg:g} deg", on_timeout=self.logs)

    def scan(self, clouds: int = CLOUDS_PER_POSE) -> list[PointCloud2]:
        held: list[PointCloud2] = []
        for yaw, pitch in SCAN_DEG:
            held += self.hold(yaw, pitch, clouds)
        return held

    def world_points(self, clouds: list[PointCloud2]) -> np.ndarray:
        """Points of the clouds in the world, R_T_C by FK of the joint state with their stamp."""
        by_stamp = {msgs.nanoseconds_from_time(m.header.stamp): m for m in self.joints.messages}
        out = []
        for c in clouds:
            js = by_stamp.get(msgs.nanoseconds_from_time(c.header.stamp))
            if js is None:
                continue
            T = camera_pose(self.model, self.model.joints_from_dict(dict(zip(js.name, js.position))), CAMERA_FRAME)
            out.append(msgs.points_from_cloud(c).points @ T[:3, :3].T + T[:3, 3])
        assert out, "no cloud with the joint state of its stamp"
        return np.concatenate(out)

    def settled_map(self) -> np.ndarray:
        """The map once /voxel_map shows every depth map integrated so far (map version
        published, same voxel count as the diagnostics)."""
        integrated = self.counter("clouds_integrated")

        def settled() -> PointCloud2 | None:
            m, i, cloud = self.mapper_status("map"), self.mapper_status("inputs"), self.maps.last
            if m is None or i is None or cloud is None:
                return None
            if int(i["clouds_integrated"]) < integrated or m["map_version"] != m["published_version"] \
                    or int(m["occupied_voxels"]) != cloud.width:
                return None
            return cloud

        cloud = self.probe.spin_until(settled, 30.0, "/voxel_map with every integrated depth map",
                                      on_timeout=self.logs)
        assert cloud.header.frame_id == "world"
        return msgs.points_from_cloud(cloud).points

    def disable(self, names: list[str]) -> Any:
        client = self.probe.node.create_client(SetParameters, "/scene_sim/set_parameters")
        self.probe.spin_until(client.service_is_ready, 20.0, "/scene_sim/set_parameters")
        req = SetParameters.Request(parameters=[ParameterMsg(
            name="disabled_primitives",
            value=ParameterValue(type=ParameterType.PARAMETER_STRING_ARRAY, string_array_value=names))])
        fut = client.call_async(req)
        self.probe.spin_until(fut.done, 20.0, "set_parameters response")
        return fut.result().results[0]


def visible_ground_truth(gt: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """Ground-truth voxels within one voxel of a measured point above the floor band."""
    return gt[near(gt, measured[measured[:, 2] > FLOOR_BAND_M])]


def no_pose_warnings(proc) -> list[str]:
    return proc.log_lines(r"no camera pose at its stamp")


# ---------------------------------------------------------------- tests
@pytest.mark.node
def test_head_scan_maps_the_scene_and_a_removed_pipe_clears(start_node, ros_probe, model, scene) -> None:
    start_node("joint_driver", params_file="config/joint_driver.yaml", params={"command_timeout_s": 3600.0},
               ready_log=r"simulated")
    sim = start_node("scene_sim", params_file="config/scene_sim.yaml", params=SIM, ready_log=r"scene sensors ready")
    mapper = start_node("voxel_mapper", params_file="config/voxel_mapper.yaml", params=MAPPER,
                        ready_log=r"voxel mapper ready")
    g = Graph(ros_probe, model, mapper, sim)

    held = g.scan()
    occ = g.settled_map()
    gt = scene.voxelize(H, extent=GT_EXTENT)
    gt_floor = scene.voxelize(H, extent=GT_EXTENT, include_floor=True)
    measured = g.world_points(held)
    visible = visible_ground_truth(gt, measured)
    false = ~near(occ, gt_floor)
    complete = near(visible, occ).mean()
    print(f"\nscan: {len(occ)} occupied voxels, {len(visible)} visible ground-truth voxels, completeness within "
          f"one voxel {complete:.4f}, false occupancy beyond one voxel {int(false.sum())}; no-pose warnings: "
          f"{len(no_pose_warnings(mapper))}")
    assert len(visible) > 1000 and len(occ) > 1000
    assert not false.any(), occ[false][:10]                   # no false occupancy beyond one voxel
    assert complete >= 0.95, complete                         # complete where the sensor looked
    np.testing.assert_allclose(occ, (keys(occ) + 0.5) * H, atol=1e-5)   # voxel centres

    # passage_pipe removed at run time: a rescan clears it
    without = without_primitives(scene, ["passage_pipe"])
    pipe = scene.primitive("passage_pipe")
    pipe_only = occ[np.abs(without.sdf(occ, include_floor=True)) > 1.5 * H]    # not near anything else (floor included)
    # enough of the pipe seen to test its clearing (53-58 voxels in quiet runs; 49 once under load:
    # the map's completeness is asserted above, this only needs a real observation of the pipe)
    assert len(pipe_only) > 30 and np.all(np.abs(pipe.sdf(pipe_only)) < 2 * H)
    res = g.disable(["passage_pipe"])
    assert res.successful, res.reason
    sim.wait_for_log(r"disabled primitives: \[.passage_pipe.\]")
    g.scan(CLEAR_CLOUDS_PER_POSE)
    occ2 = g.settled_map()
    left = near(pipe_only, occ2, 0).mean()
    false2 = ~near(occ2, without.voxelize(H, extent=GT_EXTENT, include_floor=True))
    print(f"pipe removed: {left:.3f} of its {len(pipe_only)} voxels left, {int(false2.sum())} voxels beyond one "
          f"voxel of the scene without it; no-pose warnings: {len(no_pose_warnings(mapper))}")
    assert left < 0.05, left
    assert not false2.any(), occ2[false2][:10]
    assert int(g.counter("clouds_rejected")) == 0


@pytest.mark.node
def test_stereo_map_agrees_with_the_scene_and_the_depth_map(start_node, ros_probe, model, scene) -> None:
    """scene_sim's stereo pair -> voxel_mapper (use_stereo, its depth-cloud input remapped
    away) and a second voxel_mapper on the depth sensor of the same frames. The head is
    brought to the first scan pose before the mappers start, so both maps come from the same
    view. Within one voxel: >= 90 % of the stereo map's voxels lie on the scene and >= 90 %
    on the depth map, and >= 70 % of the depth map's voxels have a stereo voxel (stereo has
    no depth where the left-right check fails: occlusion borders, weak texture; measured at
    320 x 240 on the loaded machine: 0.99, 0.95, 0.80; bench/voxel_map.py compares the two
    offline at 640 x 480 over six poses: 0.93 on the scene, 0.92 on the depth map, 0.92
    covered)."""
    start_node("joint_driver", params_file="config/joint_driver.yaml", params={"command_timeout_s": 3600.0},
               ready_log=r"simulated")
    # 5 Hz: three ray casts per frame; a lighter scene_sim also exits promptly on SIGINT under load
    sim = start_node("scene_sim", params_file="config/scene_sim.yaml",
                     params={**SIM, "stereo_enabled": True, "period_s": 0.2}, ready_log=r"scene sensors ready")
    g = Graph(ros_probe, model, None, sim)
    g.look(*SCAN_DEG[0])
    stereo_mapper = start_node("voxel_mapper", params_file="config/voxel_mapper.yaml",
                               params={**MAPPER, "use_stereo": True}, ready_log=r"voxel mapper ready",
                               extra_ros_args=["-r", "head_camera/points:=unused_points",
                                               "-r", "voxel_map:=stereo_map",
                                               "-r", "voxel_map/markers:=stereo_map/markers",
                                               "-r", "__node:=stereo_mapper"])
    g.mapper = start_node("voxel_mapper", params_file="config/voxel_mapper.yaml", params=MAPPER,
                          ready_log=r"voxel mapper ready")
    stereo_maps = ros_probe.collect(PointCloud2, "/stereo_map", LATCHED)

    def stereo_pairs() -> int:
        for arr in reversed(g.diags.messages):
            for st in arr.status:
                if st.name == "stereo_mapper: inputs":
                    return int(msgs.diagnostic_values(st).get("clouds_integrated", 0))
        return 0

    ros_probe.spin_until(lambda: stereo_pairs() >= 3 and g.counter("clouds_integrated") >= 3, 60.0,
                         "3 stereo pairs and 3 depth maps integrated",
                         on_timeout=lambda: stereo_mapper.log_tail() + g.logs())
    depth_occ = g.settled_map()
    # the mapper publishes only when a voxel changed: the map has settled when none came for a while
    last_change = [len(stereo_maps), time.monotonic()]

    def stereo_settled() -> bool:
        if len(stereo_maps) != last_change[0]:
            last_change[:] = [len(stereo_maps), time.monotonic()]
        return len(stereo_maps) > 0 and time.monotonic() - last_change[1] > 1.5

    ros_probe.spin_until(stereo_settled, 60.0, "a settled /stereo_map", on_timeout=stereo_mapper.log_tail)
    stereo_occ = msgs.points_from_cloud(stereo_maps.last).points
    gt = scene.voxelize(H, extent=GT_EXTENT, include_floor=True)
    on_gt, on_depth = near(stereo_occ, gt).mean(), near(stereo_occ, depth_occ).mean()
    covered = near(depth_occ, stereo_occ).mean()
    print(f"\nstereo: {len(stereo_occ)} voxels (depth map {len(depth_occ)}); stereo within one voxel of the scene "
          f"{on_gt:.3f}, of the depth map {on_depth:.3f}; depth map covered by stereo {covered:.3f}")
    assert len(stereo_occ) > 300 and len(depth_occ) > 300
    assert on_gt >= 0.90, on_gt            # the stereo map lies on the scene ...
    assert on_depth >= 0.90, on_depth      # ... and on the depth sensor's map
    assert covered >= 0.70, covered        # and has most of what the depth sensor mapped
