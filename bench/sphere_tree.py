#!/usr/bin/env python3
"""Benchmark of the environment sphere tree (humanoid_reach_ros.geometry.sphere_tree).

Kanehiro et al., Sec. V: a sphere tree from 22,753 voxels is built in 20 ms (C++,
Core i7 3.2 GHz); a collision check of one configuration costs 0.016 ms (goal
sampling) to 0.032 ms (path planning). Targets (docs/benchmarks.md): build <= 20 ms, check
<= 0.016 ms per configuration.

Measured here, on the plant scene (config/scenes/plant.yaml) voxelized at its default
0.02 m (about the paper's voxel count):

* build time: median (and min) of repeated builds after compilation;
* ``any_intersection`` per configuration for the robot's collision shapes
  (config/robots/hrp2/collision.yaml) in randomly perturbed half-sitting postures
  around the pipes -- colliding and free configurations separately -- both per
  Python call (one configuration per call, what a Python planner pays) and in
  batches of configurations (one kernel call, per-configuration cost);
* per-shape nearest distance (``min_distance``) and ``spheres_within`` (0.1 m bound,
  the executor's velocity-damper query).

Prints a human-readable summary and, as the last line, one JSON object.
Run: ``python bench/sphere_tree.py`` (from the repository root).
"""
from __future__ import annotations

import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numba  # noqa: E402

from humanoid_reach_ros.geometry.sphere_tree import SphereTree, warm_up  # noqa: E402
from humanoid_reach_ros.robot.model import RobotModel  # noqa: E402
from humanoid_reach_ros.robot.shapes import load_collision_model  # noqa: E402
from humanoid_reach_ros.sim.scene import load_scene  # noqa: E402

N_BUILDS = 21
N_CONFIGS = 4000
BOUND_M = 0.1
SEED = 20240611


def median_time(fn, repeats: int) -> tuple[float, float]:
    """(median, min) wall time [s] of ``fn()`` over ``repeats`` runs."""
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts)), float(np.min(ts))


def perturbed_configs(robot: RobotModel, n: int, rng: np.random.Generator) -> np.ndarray:
    """Half-sitting with the arms swung about (N(0, 0.6) rad on every arm joint), the
    chest pitched forward up to 0.5 rad and the waist lowered up to 0.15 m: postures
    among the passage pipe, the left shoulder pipe and the valve."""
    q0 = robot.half_sitting()
    qs = np.repeat(q0[None], n, axis=0)
    arms = [i for limb in ("right_arm", "left_arm") for i in robot.limbs[limb].joint_index]
    qs[:, [7 + i for i in arms]] += rng.normal(0.0, 0.6, (n, len(arms)))
    qs[:, 7 + robot.joint_index["CHEST_JOINT1"]] = rng.uniform(0.0, 0.5, n)
    qs[:, 7 + robot.joint_index["CHEST_JOINT0"]] = rng.uniform(-0.4, 0.4, n)
    qs[:, 2] -= rng.uniform(0.0, 0.15, n)
    lo, hi = robot.model.lowerPositionLimit[7:], robot.model.upperPositionLimit[7:]
    qs[:, 7:] = np.clip(qs[:, 7:], lo, hi)
    return qs


def main() -> None:
    t0 = time.perf_counter()
    warm_up()
    compile_s = time.perf_counter() - t0

    scene = load_scene("scenes/plant.yaml")
    h = scene.resolution_m
    t0 = time.perf_counter()
    voxels = scene.voxelize(h)
    voxelize_ms = 1e3 * (time.perf_counter() - t0)
    build_med, build_min = median_time(lambda: SphereTree.from_voxels(voxels, h), N_BUILDS)
    tree = SphereTree.from_voxels(voxels, h)

    robot = RobotModel()
    shapes = load_collision_model(None, robot)
    rng = np.random.default_rng(SEED)
    qs = perturbed_configs(robot, N_CONFIGS, rng)
    P0, P1, R = shapes.world_shapes_batch(qs)
    P0, P1 = np.ascontiguousarray(P0), np.ascontiguousarray(P1)
    R = np.ascontiguousarray(R)
    hit = tree.any_intersection_configs(P0, P1, R)
    n_shapes = P0.shape[1]

    # per configuration, batched (one kernel call over all configurations of a kind)
    per_config_batch = {}
    for name, sel in (("all", np.ones(len(hit), bool)), ("free", ~hit), ("colliding", hit)):
        A, B = np.ascontiguousarray(P0[sel]), np.ascontiguousarray(P1[sel])
        med, _ = median_time(lambda A=A, B=B: tree.any_intersection_configs(A, B, R), 7)
        per_config_batch[name] = 1e6 * med / max(1, sel.sum())
    # per configuration, one Python call each (what a Python planner loop pays)
    per_config_call = {}
    for name, sel in (("all", np.ones(len(hit), bool)), ("free", ~hit), ("colliding", hit)):
        A = [P0[c] for c in np.flatnonzero(sel)]
        B = [P1[c] for c in np.flatnonzero(sel)]

        def loop(A=A, B=B):
            for a, b in zip(A, B):
                tree.any_intersection(a, b, R)

        med, _ = median_time(loop, 5)
        per_config_call[name] = 1e6 * med / max(1, len(A))

    # per shape: nearest distance and spheres within the damper bound
    S0, S1 = P0.reshape(-1, 3), P1.reshape(-1, 3)
    SR = np.ascontiguousarray(np.broadcast_to(R, P0.shape[:2]).reshape(-1))
    med, _ = median_time(lambda: tree.nearest_batch(S0, S1, SR), 5)
    nearest_batch_us = 1e6 * med / len(S0)
    k = min(5000, len(S0))

    def nearest_loop():
        for i in range(k):
            tree.min_distance(S0[i], S1[i], SR[i])

    med, _ = median_time(nearest_loop, 3)
    nearest_call_us = 1e6 * med / k
    med, _ = median_time(lambda: tree.spheres_within_batch(S0, S1, SR, BOUND_M), 5)
    within_us = 1e6 * med / len(S0)
    within_mean = len(tree.spheres_within_batch(S0, S1, SR, BOUND_M)[0]) / len(S0)
    dist = tree.min_distance_batch(S0, S1, SR)

    result = {
        "bench": "sphere_tree",
        "scene": scene.name,
        "resolution_m": h,
        "voxels": int(len(voxels)),
        "paper_voxels": 22753,
        "voxels_at_0.015m": int(len(scene.voxelize(0.015))),
        "voxelize_ms": round(voxelize_ms, 1),
        "compile_or_cache_load_s": round(compile_s, 2),
        "build_ms_median": round(1e3 * build_med, 2),
        "build_ms_min": round(1e3 * build_min, 2),
        "nodes": int(tree.n_nodes),
        "depth": int(tree.depth),
        "shapes_per_config": int(n_shapes),
        "configs": int(len(hit)),
        "colliding_fraction": round(float(hit.mean()), 3),
        "any_intersection_us_per_config_batched": {k_: round(v, 2) for k_, v in per_config_batch.items()},
        "any_intersection_us_per_config_python_call": {k_: round(v, 2) for k_, v in per_config_call.items()},
        "min_distance_us_per_shape_batched": round(nearest_batch_us, 3),
        "min_distance_us_per_shape_python_call": round(nearest_call_us, 3),
        "spheres_within_us_per_shape": round(within_us, 3),
        "spheres_within_bound_m": BOUND_M,
        "spheres_within_mean_count": round(within_mean, 2),
        "shape_distance_m_percentiles_5_50_95": [round(float(x), 3) for x in np.percentile(dist, [5, 50, 95])],
        "paper": {"build_ms": 20.0, "check_ms_per_config": [0.016, 0.032], "cpu": "Core i7 3.2 GHz, C++"},
        "targets": {
            "build_ms_le_20": bool(1e3 * build_med <= 20.0),
            "check_us_per_config_le_16_python_call": bool(per_config_call["all"] <= 16.0),
            "check_us_per_config_le_16_batched": bool(per_config_batch["all"] <= 16.0),
        },
        "machine": {
            "platform": platform.platform(),
            "processor": platform.processor() or platform.machine(),
            "cpu_count": os.cpu_count(),
            "load_avg_1min": round(os.getloadavg()[0], 2),
            "python": platform.python_version(),
            "numpy": np.__version__,
            "numba": numba.__version__,
        },
    }
    print(f"plant scene: {len(voxels)} voxels at {h} m (paper: 22,753), voxelized in {voxelize_ms:.0f} ms")
    print(f"sphere tree build: median {1e3 * build_med:.2f} ms, min {1e3 * build_min:.2f} ms "
          f"({tree.n_nodes} nodes, depth {tree.depth}); paper 20 ms")
    print(f"any_intersection, {n_shapes} capsules/config, {len(hit)} configs ({hit.mean():.0%} colliding):")
    for name in ("all", "free", "colliding"):
        print(f"  {name:9s}: {per_config_batch[name]:6.2f} us/config batched, "
              f"{per_config_call[name]:6.2f} us/config one Python call each")
    print("  paper: 16-32 us/config")
    print(f"min_distance: {nearest_batch_us:.3f} us/shape batched, {nearest_call_us:.3f} us/shape per call")
    print(f"spheres_within {BOUND_M} m: {within_us:.3f} us/shape, {within_mean:.1f} spheres/shape on average")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
