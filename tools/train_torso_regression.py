#!/usr/bin/env python3
"""Regenerate a robot's dual-arm torso regression model (dissertation Sec. 4.1).

Algorithm 2 dataset over the robot's workspace file (robot.yaml dual_arm_workspace; HRP-2:
config/robots/hrp2/dual_arm_workspace.yaml) from the initial posture (half-sitting with its
initial_joints_deg, lowered by its initial_com_drop_m), then one RBF SVR per chest angle with the Table 1 parameters,
written to the robot's torso_regression stem (.npz + .yaml, beside its robot.yaml). Usage:

    python tools/train_torso_regression.py [--robot NAME] [--samples N] [--seed S] [--out STEM]
"""
from __future__ import annotations

import argparse
import os
import sys
import time

from humanoid_reach_ros.paths import config_path
from humanoid_reach_ros.dual_arm.torso_regression import ReachWorkspace, TorsoRegression, generate_dataset
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.spec import DEFAULT_ROBOT


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=None,
                    help="target pairs tried (default: the workspace file's dataset.n_samples)")
    ap.add_argument("--seed", type=int, default=None)
    ap.add_argument("--robot", default=DEFAULT_ROBOT, help=f"robot (config/robots/<name>; default {DEFAULT_ROBOT})")
    ap.add_argument("--out", default=None, help="output stem under config/ (default: the robot description's "
                                                "torso_regression)")
    a = ap.parse_args(argv)
    try:
        robot = RobotModel(a.robot)
    except ValueError as e:
        ap.error(str(e))
    out = a.out or robot.spec.torso_regression
    if not out:
        ap.error(f"robot {a.robot!r} names no torso_regression in its description: give --out")
    ws = ReachWorkspace.for_robot(robot)
    n = int(ws.dataset["n_samples"]) if a.samples is None else a.samples
    seed = int(ws.dataset["seed"]) if a.seed is None else a.seed
    if n < 10:
        ap.error("--samples must be >= 10")
    q0 = ws.initial_posture(robot)
    t = time.perf_counter()
    X, Y, tried = generate_dataset(robot, ws, q0, n, seed)
    t_data = time.perf_counter() - t
    if len(X) < 10:
        print(f"only {len(X)} of {tried} pairs solvable: check the workspace", file=sys.stderr)
        return 1
    reg = TorsoRegression.fit(X, Y, **{k: float(ws.svr[k]) for k in ("kernel_width_m", "C", "epsilon")})
    reg.meta.update({"n_tried": tried, "seed": seed, "dataset_seconds": round(t_data, 1),
                     # the workspace file, relative to the model's directory (the robot's)
                     "workspace": os.path.relpath(robot.spec.dual_arm_workspace, config_path(str(out)).parent)})
    npz, yml = reg.save(out)
    print(f"{len(X)}/{tried} pairs solvable ({t_data:.1f} s); wrote {npz} and {yml}; "
          f"train RMSE {reg.meta['train_rmse_rad']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
