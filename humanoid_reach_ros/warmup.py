"""Compile every numba kernel of the package into its on-disk cache.

``tools/setup.sh`` runs this once after a build (``python -m humanoid_reach_ros.warmup``),
so that nodes, tests and benchmarks start with compiled kernels instead of paying a few
seconds of JIT compilation inside their first request. Nodes still warm up at start-up
(cheap once the cache is filled), so a cold cache never lands inside a request.
"""
from __future__ import annotations

import time

import numpy as np


def warm_up_all() -> dict[str, float]:
    """Compile (or load) all kernels; returns seconds per part."""
    from humanoid_reach_ros.geometry import sphere_tree
    from humanoid_reach_ros.planning.service import PlanningService, PlanningServiceConfig
    from humanoid_reach_ros.sim.scene import load_scene

    times = {}
    t = time.perf_counter()
    sphere_tree.warm_up()
    times["sphere_tree"] = time.perf_counter() - t
    t = time.perf_counter()
    scene = load_scene("scenes/plant.yaml")
    scene.raycast(np.zeros((4, 3)) + [0.0, 0.0, 1.4], np.tile([1.0, 0.0, -0.3], (4, 1)), max_range=5.0)
    times["scene_raycast"] = time.perf_counter() - t
    t = time.perf_counter()
    # the planner node's own warm-up: a free-space plan, then one on a measured map with unobserved
    # layers (PlanningService.warm_up_measured: a fresh clone's first plan compiled those kernels)
    if not PlanningService(PlanningServiceConfig()).warm_up():
        raise RuntimeError("the planner's warm-up plans did not succeed")
    times["planner_and_collision"] = time.perf_counter() - t
    t = time.perf_counter()
    from humanoid_reach_ros.geometry.batch_collision import LANES, BatchCollision
    from humanoid_reach_ros.geometry.distance import RobotCollision
    from humanoid_reach_ros.geometry.sphere_tree import SphereTree
    from humanoid_reach_ros.robot.model import RobotModel
    from humanoid_reach_ros.robot.shapes import load_collision_model

    robot = RobotModel()
    batch = BatchCollision(RobotCollision(robot, load_collision_model(None, robot),
                                          SphereTree.build(np.array([[5.0, 5.0, 5.0]]), 0.01)))
    batch.first_collision(np.tile(robot.half_sitting(), (LANES + 1, 1)))   # check_batch's kernel too
    times["batch_collision"] = time.perf_counter() - t
    t = time.perf_counter()
    from humanoid_reach_ros.control.executor import ExecutorParams, WholeBodyExecutor
    from humanoid_reach_ros.robot.model import RobotModel
    from humanoid_reach_ros.robot.shapes import load_collision_model

    robot = RobotModel()
    WholeBodyExecutor(robot, load_collision_model(None, robot), ExecutorParams()).warm_up()
    times["executor"] = time.perf_counter() - t
    t = time.perf_counter()
    from humanoid_reach_ros.dual_arm.controller import ControllerConfig, DualArmReachController
    from humanoid_reach_ros.dual_arm.torso_regression import ReachWorkspace, TorsoRegression
    from humanoid_reach_ros.execution.process import warm_up_dual

    robot = RobotModel()
    ctl = DualArmReachController(robot, TorsoRegression.load(robot.spec.torso_regression),
                                 ReachWorkspace.for_robot(robot),
                                 ControllerConfig())
    warm_up_dual(ctl, robot)
    from humanoid_reach_ros import kinematics
    kinematics.warm_up()   # every limb solver's kernels and a 7-joint arm's control step (Talos's)
    times["dual_arm"] = time.perf_counter() - t
    t = time.perf_counter()
    from humanoid_reach_ros.sim import camera

    cam = camera.PinholeCamera.from_fov(16, 12, 1.0)
    T = camera.look_at(np.array([0.0, 0.0, 1.4]), np.array([0.71, 0.03, 0.9]))
    hits = camera.cast(scene, cam, T, max_range_m=5.0)
    camera.render_image(scene, hits, camera.marker_print_from_scene(scene))
    camera.depth_points(hits, camera.DepthNoise(stride=1), np.random.default_rng(0))
    times["camera"] = time.perf_counter() - t
    t = time.perf_counter()
    from humanoid_reach_ros.perception.voxel_map import VoxelMap

    vm = VoxelMap()
    vm.integrate(np.array([[0.0, 0.0, 1.0]]), np.eye(4))
    vm.occupied_centers()
    times["voxel_map"] = time.perf_counter() - t
    return times


def main() -> int:
    t0 = time.perf_counter()
    times = warm_up_all()
    parts = ", ".join(f"{k} {v:.1f} s" for k, v in times.items())
    print(f"numba kernels ready in {time.perf_counter() - t0:.1f} s ({parts})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
