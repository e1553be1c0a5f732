#!/usr/bin/env python3
"""Train a robot's reachability map (planning/reach_map.py: the outer bound that proves
TARGET_OUT_OF_REACH, and the capability map the goal sampler draws trunk postures from)
into the file its robot.yaml names (``reach_map``, beside robot.yaml). Usage:

    python tools/train_reach_map.py [--robot NAME] [--seed S] [--grid-points N] [--samples N] [--per-voxel K]
                                    [--out PATH]

Deterministic for a seed. HRP-2: 9 min at load 20-30 on this machine (docs/benchmarks.md).
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace

import numpy as np

from humanoid_reach_ros.codes import ARMS
from humanoid_reach_ros.kinematics import Chain6
from humanoid_reach_ros.planning.reach_map import ReachMap, capability_poses, train_arm_map
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.spec import DEFAULT_ROBOT


def train(robot: RobotModel, seed: int, grid_points: float, samples: int, per_voxel: int = 24,
          log=print) -> ReachMap:
    """Both arms' maps; the capability grids share one box (the union of the arms' outer boxes)."""
    chains = {arm: Chain6.from_model(robot, robot.limbs[f"{arm}_arm"].root, robot.limbs[f"{arm}_arm"].joints,
                                     robot.limbs[f"{arm}_arm"].tip) for arm in ARMS}
    rng = np.random.default_rng(seed)
    first = {}
    for arm in ARMS:   # the outer bounds first: their boxes give the shared capability box
        log(f"{arm} arm ({robot.name})")
        first[arm] = train_arm_map(chains[arm], robot.limbs[f"{arm}_arm"].joints, rng, max_points=grid_points,
                                   cap_samples=0, log=log)
    box = (np.min([m.box_lo for m in first.values()], axis=0), np.max([m.box_hi for m in first.values()], axis=0))
    arms = {}
    for arm in ARMS:
        m = first[arm]
        shape, start, rpy = capability_poses(chains[arm], rng, box, m.cap_voxel_m, samples, per_voxel)
        log(f"{arm} arm capability: {samples:,} samples, {int(np.count_nonzero(np.diff(start))):,} voxels "
            f"reached, {len(rpy):,} orientations kept")
        arms[arm] = replace(m, cap_origin=np.asarray(box[0], float), cap_shape=shape, pose_start=start, pose_rpy=rpy,
                            meta={**m.meta, "cap_samples": int(samples), "per_voxel": int(per_voxel)})
    return ReachMap(robot.name, arms, {"seed": seed, "grid_points": grid_points, "samples": samples,
                                       "per_voxel": per_voxel})


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default=DEFAULT_ROBOT, help=f"robot (config/robots/<name>; default {DEFAULT_ROBOT})")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--grid-points", type=float, default=2e7,
                    help="joint-grid points of the outer bound per arm (more: a tighter bound; default 2e7)")
    ap.add_argument("--samples", type=int, default=4_000_000,
                    help="random joint vectors of the capability map per arm (default 4e6)")
    ap.add_argument("--per-voxel", type=int, default=24, help="orientations kept per capability voxel (default 24)")
    ap.add_argument("--out", default=None, help="output .npz (default: the robot description's reach_map)")
    a = ap.parse_args(argv)
    try:
        robot = RobotModel(a.robot)
    except ValueError as e:
        ap.error(str(e))
    out = a.out or robot.spec.reach_map
    if not out:
        ap.error(f"robot {a.robot!r} names no reach_map in its description: give --out")
    if a.grid_points < 1000 or a.samples < 1000:
        ap.error("--grid-points and --samples must be >= 1000")
    t = time.perf_counter()
    rmap = train(robot, a.seed, a.grid_points, a.samples, a.per_voxel)
    rmap.meta["train_seconds"] = round(time.perf_counter() - t, 1)
    path = rmap.save(out)
    print(f"wrote {path} in {rmap.meta['train_seconds']} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
