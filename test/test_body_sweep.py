"""The robot's own volume (geometry/body_sweep.py, issue 31): the self-filter margin's
derivation, the space swept between reported postures (and only that), the voxel mapper's
self filter, and a hand beside the unobserved frontier that is not in contact with it."""
from __future__ import annotations

import numpy as np
import pytest

from humanoid_reach_ros.geometry.body_sweep import DEFAULT_SELF_FILTER_MARGIN_M, BodySweep, self_filter_margin_m
from humanoid_reach_ros.geometry.voxels import points_within_capsules
from humanoid_reach_ros.perception.mapping import MappingConfig, MappingPipeline
from humanoid_reach_ros.perception.voxel_map import VoxelMap
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.shapes import load_collision_model


@pytest.fixture(scope="module")
def robot() -> RobotModel:
    return RobotModel()


@pytest.fixture(scope="module")
def cm(robot):
    return load_collision_model(None, robot)


def test_the_margin_is_derived_not_chosen() -> None:
    # 3 sigma of the range noise at 1.5 m + 2 mrad over 1.5 m + half a 2 cm voxel
    assert self_filter_margin_m() == pytest.approx(3 * 0.0025 * 1.5 ** 2 + 2e-3 * 1.5 + 0.01)
    assert DEFAULT_SELF_FILTER_MARGIN_M == pytest.approx(0.030)
    assert self_filter_margin_m(resolution_m=0.05) > self_filter_margin_m()   # coarser map, wider shell
    with pytest.raises(ValueError, match="range_noise_per_m"):
        self_filter_margin_m(range_noise_per_m=float("nan"))


def _arm_moved(robot: RobotModel, radians: float) -> np.ndarray:
    j = robot.half_sitting_joints.copy()
    j[robot.limbs["right_arm"].joint_index[0]] -= radians      # shoulder pitch: the arm swings forward
    return j


def _hand(robot: RobotModel, joints: np.ndarray) -> np.ndarray:
    q = robot.config(joints, robot.base_on_feet(joints))
    return robot.frame_pose(q, robot.limbs["right_arm"].tip).translation.copy()


def test_the_swept_volume_of_a_reported_motion_is_marked_and_10_cm_beside_it_is_not(robot, cm) -> None:
    """Two states 50 ms apart, the arm swung 1.2 rad between them: the postures between are
    marked (the hand's path at mid-swing), the space 10 cm beside the shapes is not."""
    sweep = BodySweep(robot, cm, margin_m=DEFAULT_SELF_FILTER_MARGIN_M, step_m=0.01, max_gap_s=0.1)
    j0, j1 = robot.half_sitting_joints.copy(), _arm_moved(robot, 1.2)
    postures = sweep.postures([(10.0, j0), (10.05, j1)])
    assert len(postures) > 10 and sweep.interpolated == len(postures) - 2
    m = VoxelMap()
    m.mark_swept(*sweep.capsules_of(postures))
    mid = _hand(robot, 0.5 * (j0 + j1))                       # never reported: swept on the way
    assert m.swept[tuple(np.floor(mid / 0.02).astype(int) - m.index_lo)]
    # 10 cm beside the shapes, all along the swing: not marked (the 25 cm shell would be)
    P0, P1, R = cm.world_shapes(robot.config(j0, robot.base_on_feet(j0)))
    hand = cm.index("r_hand")
    for j in (j0, 0.5 * (j0 + j1), j1):
        P0, P1, R = cm.world_shapes(robot.config(j, robot.base_on_feet(j)))
        outward = np.array([0.0, -1.0, 0.0])                 # to the robot's right, away from the body
        p = 0.5 * (P0[hand] + P1[hand]) + outward * (R[hand] + 0.10)
        assert not points_within_capsules(p[None], *sweep.capsules_of(postures))[0]
        idx = np.floor(p / 0.02).astype(int) - m.index_lo
        assert not m.swept[tuple(idx)], p
    # and the shell grown by the margin only: a voxel inside the hand shape is marked
    assert m.swept[tuple(np.floor(0.5 * (P0[hand] + P1[hand]) / 0.02).astype(int) - m.index_lo)]


def test_states_too_far_apart_are_marked_but_not_joined(robot, cm) -> None:
    sweep = BodySweep(robot, cm, margin_m=0.03, step_m=0.01, max_gap_s=0.1)
    j0, j1 = robot.half_sitting_joints.copy(), _arm_moved(robot, 1.2)
    postures = sweep.postures([(0.0, j0), (0.5, j1)])        # messages lost: nobody knows the path
    assert len(postures) == 2 and sweep.gaps == 1 and sweep.interpolated == 0
    assert sweep.postures([(0.6, j1)]) == []                  # still: nothing new
    assert len(sweep.postures([(0.3, j0)])) == 1              # time jumped back: a fresh sweep


def test_the_mappers_self_filter_drops_the_robots_own_points(robot, cm) -> None:
    states = [(1.0, robot.half_sitting_joints.copy())]
    pipe = MappingPipeline(MappingConfig(), robot, cm, joint_states=lambda: states[:])
    j = robot.half_sitting_joints
    q = robot.config(j, robot.base_on_feet(j))
    P0, P1, R = cm.world_shapes(q)
    hand = cm.index("r_hand")
    on_hand = 0.5 * (P0[hand] + P1[hand])
    beside = on_hand + np.array([0.0, -1.0, 0.0]) * (R[hand] + 0.10)
    keep = pipe.self_filter(np.array([on_hand, beside]), j)
    assert keep.tolist() == [False, True]
    assert pipe.self_filter(np.array([on_hand]), None).tolist() == [True]    # no joints: nothing filtered
    from humanoid_reach_ros.perception.mapping import DepthJob
    T = np.eye(4)
    T[:3, 3] = q[:3] + np.array([1.0, 0.0, 0.5])             # a world-frame cloud, origin in front
    assert pipe.integrate(DepthJob(np.array([on_hand, beside]), "world", 1.0, "test")) in ("integrated", "marked")
    assert pipe.counters.points_self == 1


def test_a_hand_beside_the_frontier_is_not_in_contact(robot) -> None:
    """A hand touches what was measured, never the unobserved frontier: with the body's own
    volume as the only swept space (the 3 cm shell), the frontier lies 2 cm from the hanging
    hand, and the start is neither a contact to retreat from nor a collision."""
    from humanoid_reach_ros.planning.reach import PlanError, PlannerParams, PlanRequest, ReachPlanner
    from humanoid_reach_ros.planning.wgr import valve_region
    from humanoid_reach_ros.scene.planning_scene import PlanningScene, SceneParams

    pl = ReachPlanner(robot, PlannerParams(time_budget_s=1.0))
    pl.scene = PlanningScene(robot, SceneParams(body_clearance_m=DEFAULT_SELF_FILTER_MARGIN_M), pl.collision_model)
    j = robot.half_sitting_joints
    P0, P1, R = pl.collision_model.world_shapes(pl.start_config(j))
    hand = pl.collision_model.index("r_hand")
    c = 0.5 * (P0[hand] + P1[hand])
    near = c + np.array([0.0, -1.0, 0.0]) * (R[hand] + DEFAULT_SELF_FILTER_MARGIN_M + 0.012)
    frontier = near + 0.02 * np.array([[0, 0, k] for k in range(-3, 4)], float)
    pl.scene.set_occupied(np.array([[3.0, 0.0, 1.0]]), "/voxel_map")     # a wall far away
    pl.scene.set_unobserved(frontier, np.zeros((0, 3)))
    out = pl.plan(j, PlanRequest(valve_region(), seed=0))
    assert out.error != PlanError.START_IN_COLLISION, out.message
    assert not out.retreat, out.message


def test_the_stance_zone_is_where_the_robot_stands_not_where_it_reached(robot, cm) -> None:
    """The mapper counts the shapes at the reference posture grown by stance_clearance_m as
    observed (the operator keeps that clear) from the first joint state on, and after a clear; a
    later posture counts only its own volume grown by the self-filter margin: 8 cm beside the
    hanging hand is observed, 8 cm beside the same hand stretched forward is not."""
    j0 = robot.half_sitting_joints.copy()
    j1 = _arm_moved(robot, 1.4)
    side = np.array([0.0, -1.0, 0.0])
    hand = cm.index("r_hand")

    def beside(j: np.ndarray) -> np.ndarray:
        P0, P1, R = cm.world_shapes(robot.config(j, robot.base_on_feet(j)))
        return 0.5 * (P0[hand] + P1[hand]) + side * (R[hand] + 0.08)

    def swept(pipe, p) -> bool:
        return bool(pipe.map.swept[tuple(np.floor(p / 0.02).astype(int) - pipe.map.index_lo)])

    states = [(1.0, j0), (1.05, j1)]
    pipe = MappingPipeline(MappingConfig(), robot, cm, joint_states=lambda: states[:])
    assert MappingConfig().stance_clearance_m == pytest.approx(0.12)
    pipe.sweep_robot()
    assert swept(pipe, beside(j0)) and not swept(pipe, beside(j1))
    pipe.clear()
    states[:] = [(2.0, j1)]
    pipe.sweep_robot()
    assert swept(pipe, beside(j0))                      # the zone again after a clear
    none = MappingPipeline(MappingConfig(stance_clearance_m=0.0), robot, cm, joint_states=lambda: [(1.0, j1)])
    none.sweep_robot()
    assert not swept(none, beside(j0)) and not swept(none, beside(j1))
