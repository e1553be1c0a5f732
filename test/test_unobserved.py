"""Unobserved space (issue: the operator's flow, part 2): the planner never plans through
space the head has not observed unless told to, and says so.

On the plant, from depth scans of the head camera at the robot's own head poses (forward
kinematics of half-sitting with the head turned): after the executor's whole scan pattern
the valve is planned with the frontier of unobserved space as an obstacle; after a single
level look (the head as the launch leaves it) the same request is ``UNOBSERVED_SPACE``,
naming where the permissive plan would enter unobserved space; the occupied voxels alone
(``unobserved_space: free``) still plan it. The node side (the target-block check, the
topics) runs in test_session.
"""
from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
import pytest

from humanoid_reach_ros.geometry.camera import PinholeCamera
from humanoid_reach_ros.geometry.voxels import without_target
from humanoid_reach_ros.execution.config import PARAMETERS as EXECUTOR_PARAMETERS
from humanoid_reach_ros.nodes.reach_planner import PARAMETERS as PLANNER_PARAMETERS
from humanoid_reach_ros.nodes.voxel_mapper import PARAMETERS as MAPPER_PARAMETERS
from humanoid_reach_ros.perception.markers import camera_pose
from humanoid_reach_ros.perception.voxel_map import FusionParams, VoxelMap, depth_scan
from humanoid_reach_ros.planning.reach import PlanError, PlannerParams, PlanRequest, ReachPlanner
from humanoid_reach_ros.planning.wgr import valve_region
from humanoid_reach_ros.sim.scene import load_scene

CAM = PinholeCamera.from_fov(320, 240, math.radians(60.0))   # scene_sim's depth grid
REGION = (MAPPER_PARAMETERS["unobserved_region_min_m"].default, MAPPER_PARAMETERS["unobserved_region_max_m"].default)
CLEARANCE = MAPPER_PARAMETERS["unobserved_robot_clearance_m"].default
STANCE = MAPPER_PARAMETERS["stance_clearance_m"].default
EXCLUSION = PLANNER_PARAMETERS["target_exclusion_radius_m"].default


@pytest.fixture(scope="module")
def planner() -> ReachPlanner:
    return ReachPlanner(params=PlannerParams(time_budget_s=3.0))


@pytest.fixture(scope="module")
def scene():
    return load_scene("scenes/plant.yaml")


@functools.lru_cache(maxsize=None)
def surroundings() -> np.ndarray:
    """The scan's gazes around the body (reach_executor's, cached per robot)."""
    from humanoid_reach_ros.execution.config import ExecutionConfig
    from humanoid_reach_ros.execution.requests import ExecutionRequests
    from humanoid_reach_ros.robot.model import RobotModel
    return ExecutionRequests(RobotModel(), ExecutionConfig()).surroundings_points()


def scanned(planner: ReachPlanner, scene, poses_deg, around: bool = True) -> VoxelMap:
    """The map after the head poses and, with ``around``, the scan's gazes around the body
    (as reach_executor's scan), the body's volume marked at every posture (as voxel_mapper)."""
    m = VoxelMap(FusionParams(resolution_m=0.02))
    robot = planner.robot
    j0 = robot.half_sitting_joints.copy()
    head = [robot.joint_index[n] for n in robot.spec.head_joints]
    postures = []
    for yaw, pitch in poses_deg:
        j = j0.copy()
        j[head] = np.radians([yaw, pitch])
        postures.append(j)
    if around:
        from humanoid_reach_ros.control.gaze import GazeSolver
        gaze = GazeSolver(robot)
        postures += [gaze.solve(j0, p).joints for p in surroundings()]
    p0, p1, radii = planner.collision_model.world_shapes(planner.start_config(j0))
    m.mark_swept(p0, p1, radii + STANCE)                 # the stance zone, as voxel_mapper does
    for j in postures + [j0]:
        T = camera_pose(robot, j, robot.camera_frame)
        m.integrate(depth_scan(scene, CAM, T), T)
        p0, p1, radii = planner.collision_model.world_shapes(planner.start_config(j))   # as voxel_mapper does
        m.mark_swept(p0, p1, radii + CLEARANCE)
    return m


def plan_on(planner: ReachPlanner, scene, m: VoxelMap, with_unobserved: bool):
    target = scene.target.pose[:3, 3]
    j0 = planner.robot.half_sitting_joints
    unobserved = without_target(m.frontier_centers(*REGION), target, EXCLUSION) if with_unobserved else None
    planner.set_map(without_target(m.occupied_centers(), target, EXCLUSION), unobserved)
    return planner.plan(j0, PlanRequest(valve_region(scene.target.pose), arm="auto", seed=0))


def test_after_the_scan_the_valve_is_planned_around_unobserved_space(planner, scene) -> None:
    flat = EXECUTOR_PARAMETERS["scan_poses_deg"].default
    m = scanned(planner, scene, list(zip(flat[::2], flat[1::2])))
    out = plan_on(planner, scene, m, with_unobserved=True)
    assert out.success, out.message
    assert planner.unobserved_voxels > 1000
    full = planner.collision
    margin = planner.scene.params.safety_margin_m
    cm = planner.collision_model
    for j in out.positions:   # the trajectory stays out of the frontier too (sampled at its output period):
        # the spline between the checked waypoints may come up to 2 mm closer than they (measured after
        # issue 31, the frontier 3 cm from the arm: 0.3 mm into a voxel's inscribed sphere at margin 0,
        # 1.8 mm into the 10 mm margin of the node's default)
        P0, P1, R = cm.world_shapes(planner.start_config(j))
        d, _ = full.tree.nearest_batch(P0, P1, R)
        assert float(d.min()) + margin > -0.002, float(d.min())


def test_a_look_away_is_not_enough(planner, scene) -> None:
    m = scanned(planner, scene, [(40.0, 0.0)], around=False)     # level, to the left: not the valve's side
    out = plan_on(planner, scene, m, with_unobserved=True)
    assert not out.success and out.error == PlanError.UNOBSERVED_SPACE, out.message
    assert "look there" in out.message and "would enter it around [" in out.message, out.message
    assert out.unobserved_points is not None and len(out.unobserved_points) >= 1   # where to look
    free = plan_on(planner, scene, m, with_unobserved=False)   # unobserved_space: free
    assert free.success, free.message


def test_bad_unobserved_input(planner) -> None:
    with pytest.raises(ValueError, match="unobserved voxels contain NaN"):
        planner.set_map(np.empty((0, 3)), np.array([[np.nan, 0.0, 0.0]]))
    with pytest.raises(ValueError, match="unobserved voxels must be an"):
        planner.set_map(np.empty((0, 3)), np.zeros((3, 2)))


def test_behind_the_robot_is_unobserved_and_no_gaze_sees_it(scene) -> None:
    """The unobserved region reaches behind the robot (voxel_mapper's unobserved_region_min_m):
    after the whole scan a target behind the back is not planned as if free; since no gaze of
    the head and chest reaches there, the answer is UNOBSERVABLE_SPACE; a low target beside
    the hip, in the body's own swept space, is planned."""
    from humanoid_reach_ros.control.gaze import GazeSolver
    from humanoid_reach_ros.robot.model import RobotModel
    from humanoid_reach_ros.scene.planning_scene import PlanningScene, SceneParams

    robot = RobotModel()
    gaze = GazeSolver(RobotModel())
    pl = ReachPlanner(robot, PlannerParams(time_budget_s=2.0), observable=gaze.observable)
    pl.scene = PlanningScene(robot, SceneParams(body_clearance_m=CLEARANCE), pl.collision_model)
    assert REGION[0][0] <= -0.5, REGION   # behind the robot too
    flat = EXECUTOR_PARAMETERS["scan_poses_deg"].default
    m = scanned(pl, scene, list(zip(flat[::2], flat[1::2])))
    pl.scene.set_occupied(m.occupied_centers(), "/voxel_map")
    pl.scene.set_unobserved(m.frontier_centers(*REGION), m.unobserved_blocks(*REGION, 5))
    j0 = robot.half_sitting_joints
    behind = dataclasses.replace(valve_region(), target_p=np.array([-0.4, 0.0, 0.9]))
    out = pl.plan(j0, PlanRequest(behind, seed=0))
    assert out.error == PlanError.UNOBSERVABLE_SPACE, out.message
    assert "no reachable gaze" in out.message and len(out.unobserved_points) >= 1
    # beside the hip, where the body has been (body-swept space counts as observed): planned
    hip = dataclasses.replace(valve_region(), target_p=np.array([0.25, -0.29, 0.66]))
    assert pl.plan(j0, PlanRequest(hip, seed=0)).success


def test_a_crossing_between_samples_still_names_a_point_to_look_at() -> None:
    """CI once answered UNOBSERVED_SPACE with no point (the permissive plan crossed a thin frontier
    between its trajectory samples), and the operator could not look. Samples that never touch the
    frontier still name the frontier voxel nearest the swept shapes."""
    planner = ReachPlanner()                   # no body-swept space from earlier plans
    j0 = planner.robot.half_sitting_joints
    P0, P1 = planner.collision_model.world_shapes(planner.start_config(j0))[:2]
    front = np.vstack([P0, P1])
    beside = np.array([front[:, 0].max() + 0.2, 0.0, 0.9])               # 20 cm in front of the robot
    far = beside + np.array([3.0, 0.0, 0.0])
    planner.set_map(np.empty((0, 3)), np.array([beside, far]))
    snap = planner.scene.snapshot()
    full, known, _ = planner._scene_collision(snap, None)
    assert full.check(planner.start_config(j0))                           # no sample meets it
    points, where = planner._unobserved_entries(np.array([j0, j0]), full, known, snap.frontier)
    assert points.shape == (1, 3) and np.allclose(points[0], beside, atol=0.03), (points, where)
    assert "passes" in where and "mm from it around" in where, where


def test_a_hidden_pipe_behind_the_robot_is_never_planned_through(scene) -> None:
    """Issue 31: a vertical pipe 18 cm behind the robot's back and a rail at chest height behind
    it, which no scan sees (they are not in what the head camera renders); targets behind the
    robot are answered without a plan through them (before: SUCCESS, the forearm 7 cm inside
    the pipe, the hand 1.5 cm inside the rail)."""
    from humanoid_reach_ros.control.gaze import GazeSolver
    from humanoid_reach_ros.robot.model import RobotModel
    from humanoid_reach_ros.robot.shapes import segment_segment_distance
    from humanoid_reach_ros.scene.planning_scene import PlanningScene, SceneParams

    robot = RobotModel()
    pl = ReachPlanner(robot, PlannerParams(time_budget_s=2.0), observable=GazeSolver(RobotModel()).observable)
    pl.scene = PlanningScene(robot, SceneParams(body_clearance_m=CLEARANCE), pl.collision_model)
    flat = EXECUTOR_PARAMETERS["scan_poses_deg"].default
    m = scanned(pl, scene, list(zip(flat[::2], flat[1::2])))
    pl.scene.set_occupied(m.occupied_centers(), "/voxel_map")
    pl.scene.set_unobserved(m.frontier_centers(*REGION), m.unobserved_blocks(*REGION, 5))
    j0 = robot.half_sitting_joints
    P0, P1, _ = pl.collision_model.world_shapes(pl.start_config(j0))
    back = float(np.min(np.vstack([P0, P1])[:, 0]))
    # (a, b, radius): the pipe 18 cm behind the back, the rail 10 cm behind it at chest height
    hidden = [(np.array([back - 0.18, 0.0, 0.0]), np.array([back - 0.18, 0.0, 2.0]), 0.04),
              (np.array([back - 0.12, -0.6, 1.05]), np.array([back - 0.12, 0.6, 1.05]), 0.03)]
    cm = pl.collision_model
    for target in ([-0.4, 0.0, 0.9], [-0.35, 0.3, 1.0], [-0.3, -0.3, 0.8]):
        out = pl.plan(j0, PlanRequest(dataclasses.replace(valve_region(), target_p=np.array(target)), seed=0))
        if not out.success:
            assert out.error in (PlanError.UNOBSERVABLE_SPACE, PlanError.UNOBSERVED_SPACE), out.message
            continue
        for j in out.positions:       # a plan: clear of the hidden pipes at every sample
            A, B, R = cm.world_shapes(pl.start_config(j))
            for a, b, r in hidden:
                d = segment_segment_distance(A, B, np.broadcast_to(a, A.shape), np.broadcast_to(b, B.shape))[0] - R - r
                assert float(np.min(d)) > 0.0, (target, float(np.min(d)))
