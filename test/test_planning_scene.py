"""The planning scene (scene/planning_scene.py): layers, versions, snapshots, caches, body-swept space."""
from __future__ import annotations

import numpy as np
import pytest

from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.scene.planning_scene import BodySweptSpace, PlanningScene, SceneParams


@pytest.fixture(scope="module")
def robot() -> RobotModel:
    return RobotModel()


def test_versions_snapshots_and_tree_cache(robot) -> None:
    scene = PlanningScene(robot, SceneParams(target_exclusion_radius_m=0.15))
    assert not scene.has_map and not scene.snapshot().has_map
    v1 = scene.set_occupied(np.array([[0.7, 0.0, 0.9], [0.71, 0.03, 0.9], [0.3, 0.5, 1.0]]))
    snap = scene.snapshot()
    assert snap.version == v1 and snap is scene.snapshot()      # cached until a change
    tree, dt = snap.tree(np.array([0.7, 0.0, 0.9]))
    assert tree.n_spheres == 1 and dt > 0                      # the target's object left out
    again, dt2 = snap.tree(np.array([0.7, 0.0, 0.9]))
    assert again is tree and dt2 == 0.0                         # cached per version and exclusion
    assert snap.tree()[0].n_spheres == 3
    scene.set_occupied(np.zeros((0, 3)))
    assert scene.version > v1 and len(snap.occupied) == 3       # an old snapshot does not change
    with pytest.raises(ValueError):
        snap.occupied[0, 0] = 1.0


def test_bad_layers_are_refused_and_keep_the_scene(robot) -> None:
    scene = PlanningScene(robot)
    scene.set_occupied(np.ones((2, 3)))
    v = scene.version
    for bad in (np.array([[np.nan, 0, 0]]), np.zeros((3, 2)), "text"):
        with pytest.raises(ValueError):
            scene.set_occupied(bad)
        with pytest.raises(ValueError):
            scene.set_unobserved(frontier=bad)
    assert scene.version == v and len(scene.snapshot().occupied) == 2
    with pytest.raises(ValueError, match="unobserved_space"):
        SceneParams(unobserved_space="maybe")
    with pytest.raises(ValueError, match="finite"):
        scene.mark_body(np.full(robot.n_joints, np.nan))


def test_body_swept_space_is_observed(robot) -> None:
    """Frontier voxels and unobserved blocks where the body has been are not unobserved; the
    rest stays, behind the robot as well as in front."""
    scene = PlanningScene(robot, SceneParams(body_clearance_m=0.1))
    scene.set_occupied(np.zeros((0, 3)), "set_map")
    near_hand = robot.frame_pose(robot.half_sitting(), robot.hand_frames["right"]).translation + [0.0, 0.0, 0.02]
    far = np.array([-0.6, 0.0, 0.9])
    scene.set_unobserved(np.array([near_hand, far]), np.array([near_hand, far]))
    before = scene.snapshot()
    assert len(before.frontier) == 2 and len(before.blocks) == 2
    assert scene.mark_body(robot.half_sitting_joints) > 1000
    assert scene.mark_body(robot.half_sitting_joints) == 0          # the same posture again: nothing new
    after = scene.snapshot()
    np.testing.assert_allclose(after.frontier, far[None])
    np.testing.assert_allclose(after.blocks, far[None])
    assert "not observed" in after.unobserved_target(far)
    assert after.unobserved_target(near_hand) == ""


def test_body_grid_marks_capsules_exactly() -> None:
    grid = BodySweptSpace(0.02, (-0.5, -0.5, -0.5), (0.5, 0.5, 0.5))
    n = grid.mark(np.array([[0.0, 0.0, 0.0]]), np.array([[0.2, 0.0, 0.0]]), np.array([0.05]))
    c = (np.argwhere(grid.grid) + grid.lo + 0.5) * 0.02
    t = np.clip(c[:, 0] / 0.2, 0, 1)
    d = np.linalg.norm(c - np.stack([0.2 * t, 0 * t, 0 * t], axis=1), axis=1)
    assert n == len(c) > 0 and np.all(d <= 0.05 + 1e-12)
    assert grid.contains(np.array([[0.1, 0.0, 0.0], [0.1, 0.2, 0.0]])).tolist() == [True, False]
    assert grid.touches_boxes(np.array([[0.1, 0.0, 0.0], [0.0, 0.3, 0.0]]), 0.1).tolist() == [True, False]


def test_policies_follow_parameters(robot) -> None:
    scene = PlanningScene(robot, SceneParams(unobserved_space="occupied"))
    scene.set_occupied(np.zeros((0, 3)), "/voxel_map")
    assert "no /voxel_map/unobserved" in scene.snapshot().unobserved_target(np.array([0.7, 0.0, 0.9]))
    scene.set_params(SceneParams(unobserved_space="free"))
    assert scene.snapshot().unobserved_target(np.array([0.7, 0.0, 0.9])) == ""
    with pytest.raises(ValueError, match="resolution"):
        scene.set_params(SceneParams(resolution_m=0.05))
    scene.set_occupied(np.ones((4, 3)), "scene file plant.yaml")
    snap = scene.snapshot()
    assert not snap.measured and not snap.avoids_unobserved
