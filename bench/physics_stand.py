#!/usr/bin/env python3
"""Benchmark: each robot stands in the MuJoCo physics plant (humanoid_reach_ros.sim.physics).

For every robot (default: all of config/robots), at half-sitting in its demo scene:

* an unpaced stand of ``--seconds`` simulated seconds (as fast as the machine steps): the
  worst contact figures over every 10 ms (CoP margin to the support polygon's edge, sole slip,
  base tilt, joint tracking error), whether it fell, the step cost [us] and the capacity
  (simulated over stepping time: how many times faster than real time it could run);
* a paced stand of ``--paced-seconds`` (the wall clock paces simulated time, as in the joint
  driver): the achieved real-time factor and the plant's own CPU share.

The last stdout line is one JSON object: per robot, and the worst over robots.
Usage: python bench/physics_stand.py [--robot hrp2 ...] [--seconds 10] [--paced-seconds 3]
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import mujoco  # noqa: E402

from humanoid_reach_ros.robot.model import RobotModel  # noqa: E402
from humanoid_reach_ros.robot.spec import robots  # noqa: E402
from humanoid_reach_ros.sim.physics.model_builder import build_for_robot  # noqa: E402
from humanoid_reach_ros.sim.physics.stepper import PhysicsPlant  # noqa: E402

SAMPLE_S = 0.01


def stand(robot: str, seconds: float, paced_seconds: float) -> dict:
    model = RobotModel(robot)
    pm = build_for_robot(model)
    plant = PhysicsPlant(pm)
    margin, slip, tilt, track = math.inf, 0.0, 0.0, 0.0
    fall = ""
    while plant.sim_time_s < seconds - 1e-9:
        plant.advance(SAMPLE_S)
        m = plant.metrics()
        margin = min(margin, m.cop_margin_m)
        slip = max(slip, *m.sole_slip_m)
        tilt = max(tilt, m.base_tilt_deg)
        track = max(track, float(np.abs(plant.targets - plant.joints).max()))
        if m.fallen and not fall:
            fall = f"{m.fall_reason} at {plant.sim_time_s:.2f} s"
    t = plant.timing()
    paced = PhysicsPlant(pm)
    paced.run(paced_seconds, pace=True)
    tp = paced.timing()
    return {"fell": bool(fall), "fall_reason": fall, "sim_s": round(plant.sim_time_s, 3),
            "cop_margin_mm_min": round(1e3 * margin, 2), "foot_slip_mm_max": round(1e3 * slip, 4),
            "base_tilt_deg_max": round(tilt, 3), "joint_tracking_error_rad_max": round(track, 4),
            "step_cost_us": round(t.step_cost_us, 1), "capacity_x_real_time": round(t.capacity, 1),
            "paced_real_time_factor": round(tp.real_time_factor, 3), "paced_plant_cpu_pct": round(tp.cpu_pct, 1),
            "timestep_s": pm.timestep_s, "bodies": pm.model.nbody, "geoms": pm.model.ngeom,
            "actuators": pm.model.nu}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", action="append", help="robot (repeatable); default: every robot")
    ap.add_argument("--seconds", type=float, default=10.0, help="simulated seconds of the unpaced stand")
    ap.add_argument("--paced-seconds", type=float, default=3.0, help="seconds of the paced stand")
    args = ap.parse_args()
    names = args.robot or robots()
    per = {}
    for r in names:
        per[r] = stand(r, args.seconds, args.paced_seconds)
        print(f"{r}: {per[r]}", flush=True)
    out = {
        "robots": per,
        "falls": sum(v["fell"] for v in per.values()),
        "cop_margin_mm_min": min(v["cop_margin_mm_min"] for v in per.values()),
        "foot_slip_mm_max": max(v["foot_slip_mm_max"] for v in per.values()),
        "base_tilt_deg_max": max(v["base_tilt_deg_max"] for v in per.values()),
        "step_cost_us_max": max(v["step_cost_us"] for v in per.values()),
        "real_time_factor_min": min(v["paced_real_time_factor"] for v in per.values()),
        "plant_cpu_pct_max": max(v["paced_plant_cpu_pct"] for v in per.values()),
        "machine": {"processor": platform.processor(), "cpu_count": os.cpu_count(),
                    "python": platform.python_version(), "mujoco": mujoco.__version__},
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
