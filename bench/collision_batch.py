#!/usr/bin/env python3
"""Collision checks in SIMD lanes (geometry/batch_collision.py) against today's checker (issue 35, item 4).

Per robot (hrp2, talos, g1), on the plant scene voxelised at 2 cm without the valve (the
path planner's map of bench/peers), the same configurations through both checkers:

* **edges' samples**: ``--configs`` configurations (default 100,000) made of straight edges
  ``a -> b`` cut every ``--step-rad`` (0.05 rad) in the joints, edge after edge; ``a`` is
  half the time uniform in the joint limits (mostly colliding), half near the half-sitting
  posture (mostly free); ``b = a`` + N(0, 0.3 rad) within the limits;
* ``collision_us_per_config_batched``: :meth:`BatchCollision.check_batch` over all of
  them in one call, per configuration, forward kinematics included; ``..._today``:
  :meth:`RobotCollision.check_batch`, the same; ``ratio``: today / batched;
* ``..._per_edge_call``: one ``check_batch`` call per edge (what a Python caller pays);
* ``mismatches``: configurations whose verdicts differ (must be 0), over two passes: without
  the distance field (the first call on a map, lazy) and with it; ``undecided``: lanes redone by
  the scalar kernels (first pass), ``free_fraction``;
* HRP-2 only (its planner): ``PlanChecker.first_invalid_edge`` on random planning-space
  edges, lanes vs the scalar fused kernel (projection and leg IK included), per point.

Timings: best of ``--repeat`` runs, wall clock (``perf_counter``) and CPU time of this
process (``process_time``, what a loaded machine's waits do not inflate); the load
average before and after. Prints a summary and, as the last line, one JSON object.
Run: ``python bench/collision_batch.py`` (from the repository root).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from humanoid_reach_ros.geometry.batch_collision import BatchCollision  # noqa: E402
from humanoid_reach_ros.geometry.distance import RobotCollision  # noqa: E402
from humanoid_reach_ros.geometry.sphere_tree import SphereTree  # noqa: E402
from humanoid_reach_ros.robot.model import N_BASE_Q, RobotModel  # noqa: E402
from humanoid_reach_ros.robot.shapes import load_collision_model  # noqa: E402
from humanoid_reach_ros.sim.scene import load_scene  # noqa: E402

RESOLUTION_M = 0.02


def edge_samples(robot: RobotModel, n: int, step: float, rng: np.random.Generator) -> tuple[np.ndarray, list]:
    """(n, nq) configurations along edges, and the slices of the edges."""
    lo, hi = robot.lower, robot.upper
    q0 = robot.half_sitting()
    rows, edges, total = [], [], 0
    while total < n:
        a = lo + rng.random(robot.n_joints) * (hi - lo) if rng.random() < 0.5 else \
            np.clip(q0[N_BASE_Q:] + rng.normal(scale=0.4, size=robot.n_joints), lo, hi)
        b = np.clip(a + rng.normal(scale=0.3, size=robot.n_joints), lo, hi)
        m = max(1, int(math.ceil(np.max(np.abs(b - a)) / step)))
        s = np.arange(m + 1)[:, None] / m
        Q = np.tile(q0, (m + 1, 1))
        Q[:, N_BASE_Q:] = a + s * (b - a)
        rows.append(Q)
        edges.append(slice(total, total + m + 1))
        total += m + 1
    Q = np.vstack(rows)[:n]
    edges = [e for e in edges if e.stop <= n]
    return Q, edges


def best_of(fn, repeat: int) -> tuple[float, float]:
    """(best wall s, best CPU s) of ``repeat`` calls."""
    wall, cpu = math.inf, math.inf
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall = min(wall, time.perf_counter() - t0)
        cpu = min(cpu, time.process_time() - c0)
    return wall, cpu


def bench_robot(name: str, voxels: np.ndarray, n: int, step: float, repeat: int) -> dict:
    robot = RobotModel(name)
    col = RobotCollision(robot, load_collision_model(None, robot), SphereTree.from_voxels(voxels, RESOLUTION_M))
    bc = BatchCollision(col)
    rng = np.random.default_rng(20261129)
    Q, edges = edge_samples(robot, n, step, rng)
    bc.check_batch(Q[:64])                       # compile / load the cache, build the field
    col.check_batch(Q[:64])
    ref = col.check_batch(Q)
    u0 = bc.undecided
    got = bc.check_batch(Q)
    undecided = bc.undecided - u0
    bc.field_args()                              # the first call ran without it (lazy); the timed ones use it
    mismatches = int(np.count_nonzero(ref != got)) + int(np.count_nonzero(ref != bc.check_batch(Q)))
    w_b, c_b = best_of(lambda: bc.check_batch(Q), repeat)
    w_t, c_t = best_of(lambda: col.check_batch(Q), repeat)
    sub = edges[:2000]
    n_sub = sum(e.stop - e.start for e in sub)
    w_e, c_e = best_of(lambda: [bc.check_batch(Q[e]) for e in sub], repeat)
    w_et, c_et = best_of(lambda: [col.check_batch(Q[e]) for e in sub], repeat)
    us = 1e6 / len(Q)
    out = {"configs": len(Q), "edges": len(edges), "samples_per_edge": len(Q) / max(len(edges), 1),
           "mismatches": mismatches, "undecided": int(undecided),
           "free_fraction": float(ref.mean()), "shapes": int(col.cm.n_shapes), "self_pairs": int(len(col._pi)),
           "collision_us_per_config_batched": w_b * us, "collision_us_per_config_today": w_t * us,
           "ratio": w_t / w_b,
           "cpu_us_per_config_batched": c_b * us, "cpu_us_per_config_today": c_t * us, "cpu_ratio": c_t / c_b,
           "per_edge_call_us_per_config_batched": 1e6 * w_e / n_sub,
           "per_edge_call_us_per_config_today": 1e6 * w_et / n_sub,
           "field_build_ms": 1e3 * bc.field_build_s, "field_cells": int(bc.field_args()[0].size)}
    print(f"{name:6s} {len(Q)} configs ({out['samples_per_edge']:.1f} per edge, {100 * out['free_fraction']:.0f} % "
          f"free): batched {out['collision_us_per_config_batched']:.2f} us, today "
          f"{out['collision_us_per_config_today']:.2f} us (x{out['ratio']:.1f}); CPU "
          f"{out['cpu_us_per_config_batched']:.2f} vs {out['cpu_us_per_config_today']:.2f} us "
          f"(x{out['cpu_ratio']:.1f}); per edge call "
          f"{out['per_edge_call_us_per_config_batched']:.2f} vs {out['per_edge_call_us_per_config_today']:.2f} us; "
          f"mismatches {out['mismatches']}, undecided {out['undecided']}", flush=True)
    return out


def bench_planner_edges(voxels: np.ndarray, repeat: int) -> dict:
    """PlanChecker.first_invalid_edge, lanes vs scalar, on HRP-2's planner (same answers)."""
    from humanoid_reach_ros.planning.plan_check import PlanChecker
    from humanoid_reach_ros.planning.reach import PlannerParams, ReachPlanner
    from humanoid_reach_ros.planning.space import edge_steps

    rp = ReachPlanner(RobotModel("hrp2"), params=PlannerParams())
    rp.set_map(voxels)
    arm = "right"
    space = rp.planning_space(arm)
    lanes = PlanChecker(rp.projector, rp.collision, arm, lanes=True)
    scalar = PlanChecker(rp.projector, rp.collision, arm, lanes=False)
    rng = np.random.default_rng(3)
    start = rp.projector.plan_config_of(rp.start_config(rp.robot.half_sitting_joints), arm)[0]
    A = start + rng.normal(scale=0.1, size=(2000, len(start)))
    B = A + rng.normal(scale=0.15, size=A.shape)
    m = np.atleast_1d(edge_steps(A, B, space))
    answers = [(lanes.first_invalid_edge(A[i:i + 1], B[i:i + 1], m[i:i + 1], True),
                scalar.first_invalid_edge(A[i:i + 1], B[i:i + 1], m[i:i + 1], True)) for i in range(len(A))]
    same = sum(a == b for a, b in answers)
    points = {}
    for key, pc in (("lanes", lanes), ("scalar", scalar)):
        examined = []

        def run(pc=pc, examined=examined):
            examined.clear()
            for i in range(len(A)):
                pc.first_invalid_edge(A[i:i + 1], B[i:i + 1], m[i:i + 1], True)
                examined.append(pc.last_examined)
        w, c = best_of(run, repeat)
        points[key] = (w, c, sum(examined))
    out = {"edges": len(A), "valid_fraction": float(np.mean([a == 1 for a, _ in answers])),
           "same_answers": same, "points_per_edge": float(np.mean(m + 1)),
           "edge_us_lanes": 1e6 * points["lanes"][0] / len(A), "edge_us_scalar": 1e6 * points["scalar"][0] / len(A),
           "edge_ratio": points["scalar"][0] / points["lanes"][0],
           "edge_cpu_ratio": points["scalar"][1] / points["lanes"][1],
           "points_examined_lanes": points["lanes"][2], "points_examined_scalar": points["scalar"][2]}
    print(f"planner edges (hrp2, right arm, {len(A)} edges, {out['points_per_edge']:.1f} points each, "
          f"{100 * out['valid_fraction']:.0f} % valid): lanes {out['edge_us_lanes']:.1f} us, scalar "
          f"{out['edge_us_scalar']:.1f} us per edge (x{out['edge_ratio']:.2f}), same answers {same}/{len(A)}",
          flush=True)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--robots", nargs="+", default=["hrp2", "talos", "g1"])
    ap.add_argument("--configs", type=int, default=100_000)
    ap.add_argument("--step-rad", type=float, default=0.05)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--no-planner", action="store_true", help="skip the PlanChecker edge comparison")
    args = ap.parse_args()
    load0 = os.getloadavg()
    voxels = load_scene("scenes/plant.yaml").voxelize(RESOLUTION_M, exclude_groups=("valve",))
    result: dict = {"robots": {}}
    for name in args.robots:
        result["robots"][name] = bench_robot(name, voxels, args.configs, args.step_rad, args.repeat)
    if not args.no_planner:
        try:
            result["planner_edges_hrp2"] = bench_planner_edges(voxels, args.repeat)
        except Exception as e:     # the planner of another work in progress: say so, keep the figures above
            result["planner_edges_hrp2"] = {"error": f"{type(e).__name__}: {e}"}
    r = result["robots"]
    result["collision_us_per_config_batched"] = {k: v["collision_us_per_config_batched"] for k, v in r.items()}
    result["collision_us_per_config_today"] = {k: v["collision_us_per_config_today"] for k, v in r.items()}
    result["ratio"] = {k: v["ratio"] for k, v in r.items()}
    result["mismatches"] = sum(v["mismatches"] for v in r.values())
    result["load_avg_before"] = [round(x, 2) for x in load0]
    result["load_avg_after"] = [round(x, 2) for x in os.getloadavg()]
    result["cpus"] = os.cpu_count()
    print(json.dumps(result))
    return 1 if result["mismatches"] else 0


if __name__ == "__main__":
    sys.exit(main())
