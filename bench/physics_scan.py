#!/usr/bin/env python3
"""Why does a robot lose balance on the physics plant? The scan's gazes around the body, in-process.

For each robot (``--robot``, default HRP-2, Talos and the G1): the executor's 5 ms IK loop
(``control/executor.py``, the reach executor's parameters) runs the scan's whole-body gazes around
the body (``ExecutionRequests.surroundings_points``, each the balanced gaze of ``control/gaze.py``
from the last command, timed by the look's spline, then ``--dwell-s`` held), and every command is one
tick of the joint driver (its kinematic simulator's rate limit and first-order tracking, time constant
``--tracking-tau-s``, config/joint_driver.yaml's 0.01 s, whose joints are the servos' targets; then
``PhysicsDriver.step``: MuJoCo, the force guard; the stabilizer with ``--stabilizer``), as
``joint_driver`` with ``plant: mujoco`` does. No ROS, no graph: a few simulated seconds per gaze.

* ``--scene demo`` (default): the robot stands in its demo scene; ``--scene floor``: a bare floor.
* ``--map``: the executor knows the scene's voxels (0.02 m; its dampers keep its shapes off them):
  what a finished scan would have; without it the executor knows no obstacle, as at a scan's first
  gazes, before the head has seen around the body.

Per gaze: the smallest CoP margin and foot normal force, slip, tilt, the largest commanded joint
acceleration (between 5 ms commands) and which joint, and every contact of the robot with the world
other than the soles on the floor (largest normal force per pair of shapes). The last line is JSON.

Usage: python bench/physics_scan.py [--robot hrp2 ...] [--scene demo|floor] [--map] [--stabilizer]
[--no-guard] [--tracking-tau-s 0.01] [--gazes N] [--dwell-s 1.0]
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import mujoco  # noqa: E402

from humanoid_reach_ros.control.executor import WholeBodyExecutor  # noqa: E402
from humanoid_reach_ros.execution.config import ExecutionConfig  # noqa: E402
from humanoid_reach_ros.execution.requests import ExecutionRequests  # noqa: E402
from humanoid_reach_ros.robot.model import RobotModel  # noqa: E402
from humanoid_reach_ros.robot.shapes import load_collision_model  # noqa: E402
from humanoid_reach_ros.sim.physics.driver import PhysicsDriver  # noqa: E402
from humanoid_reach_ros.sim.joint_sim import JointSimulator  # noqa: E402
from humanoid_reach_ros.sim.physics.stabilizer import FootStabilizer  # noqa: E402

TICK_S = 0.005
FLOOR = "name: bare_floor\nframe_id: world\nprimitives:\n" \
        "  - {name: floor, type: plane, normal: [0.0, 0.0, 1.0], offset: 0.0, floor: true}\n"


def world_contacts(driver: PhysicsDriver, seen: dict) -> None:
    """The largest normal force of each (robot shape, world shape) pair in contact now, the soles on the
    floor left out, into ``seen``."""
    pm, data = driver.plant.pm, driver.plant.data
    f6 = np.zeros(6)
    for i in range(data.ncon):
        c = data.contact[i]
        ga, gb = int(c.geom1), int(c.geom2)
        if (ga in pm.world_geoms) == (gb in pm.world_geoms):
            continue
        robot_g, world_g = (gb, ga) if ga in pm.world_geoms else (ga, gb)
        if world_g in pm.floor_geoms and robot_g in pm.sole_geoms:
            continue
        mujoco.mj_contactForce(pm.model, data, i, f6)
        key = (mujoco.mj_id2name(pm.model, mujoco.mjtObj.mjOBJ_GEOM, robot_g),
               mujoco.mj_id2name(pm.model, mujoco.mjtObj.mjOBJ_GEOM, world_g))
        seen[key] = max(seen.get(key, 0.0), float(f6[0]))


def run(name: str, scene: str, with_map: bool, stabilizer: bool, gazes: int, dwell_s: float, log,
        guard: bool = True, tau_s: float = 0.01) -> dict:
    robot = RobotModel(name)
    cfg = ExecutionConfig.from_values({})
    req = ExecutionRequests(robot, cfg)
    points = req.surroundings_points()[:gazes]
    params = cfg.executor
    ex = WholeBodyExecutor(robot, load_collision_model(None, robot), params)
    scene_file = scene if scene != "demo" else None
    driver = PhysicsDriver(robot, robot.half_sitting_joints, scene_file)
    if with_map:
        from humanoid_reach_ros.nodes.common import scene_file_voxels
        from humanoid_reach_ros.paths import config_path
        req.scene_map(scene_file_voxels(config_path(scene_file or robot.spec.demo_scene), 0.02, ()))
        ex.set_environment(req._tree(None))
    else:
        params = dataclasses.replace(params, collision_avoidance=False)
    if not guard:
        driver.guard = None
    if stabilizer:
        pm = driver.plant.pm
        driver.stabilizer = FootStabilizer(pm)
        driver.stabilizer.cfg = dataclasses.replace(pm.config.stabilizer, enabled=True)
    hs = robot.half_sitting_joints
    sim = JointSimulator(robot, hs, velocity_scale=1.0, time_constant_s=tau_s)   # joint_driver's defaults
    for _ in range(100):                       # 0.5 s: settle on the floor
        driver.step(hs, TICK_S)
    cmd = hs.copy()
    out = []
    for k, p in enumerate(points):
        g = req.gaze_solver().balanced(cmd, p)
        spline = req._look_spline(cmd, g.joints)
        ex.start(robot.config(cmd, robot.base_on_feet(cmd)), spline, "right", params)
        worst = {"margin_mm": math.inf, "foot_force_n_min": math.inf, "slip_mm": 0.0, "tilt_deg": 0.0,
                 "accel_rad_s2": 0.0, "accel_joint": "", "fall": ""}
        contacts: dict = {}
        v_prev = np.zeros(len(cmd))
        done, ticks, dwell = False, 0, 0
        limit = round((spline.duration + params.settle_timeout_s + 1.0) / TICK_S)
        while dwell < round(dwell_s / TICK_S) and ticks < limit + round(dwell_s / TICK_S):
            if not done:
                r = ex.step()
                done, new = r.done, r.joints
            else:
                new, dwell = cmd, dwell + 1
            v = (new - cmd) / TICK_S
            a = np.abs(v - v_prev) / TICK_S
            if a.max() > worst["accel_rad_s2"]:
                worst["accel_rad_s2"], worst["accel_joint"] = float(a.max()), robot.joint_names[int(a.argmax())]
            v_prev, cmd = v, new
            sim.set_command(robot.joint_names, cmd)
            driver.step(sim.step(TICK_S).copy(), TICK_S)
            ticks += 1
            m = driver.metrics
            worst["margin_mm"] = min(worst["margin_mm"], 1e3 * m.cop_margin_m)
            worst["foot_force_n_min"] = min(worst["foot_force_n_min"], min(m.foot_force_n))
            worst["slip_mm"] = max(worst["slip_mm"], 1e3 * max(m.sole_slip_m))
            worst["tilt_deg"] = max(worst["tilt_deg"], m.base_tilt_deg)
            worst["fall"] = worst["fall"] or m.fall_reason
            world_contacts(driver, contacts)
        row = {"gaze": k, "point": np.round(p, 3).tolist(),
               "chest_moved_deg": round(math.degrees(g.chest_moved_rad), 1),
               **{key: (round(val, 2) if isinstance(val, float) and math.isfinite(val) else
                        (None if isinstance(val, float) else val)) for key, val in worst.items()},
               "contacts_n": {f"{a}/{b}": round(f, 1) for (a, b), f in sorted(contacts.items(), key=lambda x: -x[1])}}
        log(f"{name} gaze {k} {row['point']} (chest {row['chest_moved_deg']} deg): CoP margin min "
            f"{row['margin_mm']} mm, foot force min {row['foot_force_n_min']} N, slip {row['slip_mm']} mm, "
            f"tilt {row['tilt_deg']} deg, "
            f"command accel max {row['accel_rad_s2']} rad/s^2 ({row['accel_joint']}), contacts {row['contacts_n']}"
            + (f", FALL: {row['fall']}" if row["fall"] else ""))
        out.append(row)
    margins = [r["margin_mm"] for r in out]
    return {"gazes": out,
            "cop_margin_mm_min": min((m if m is not None else -math.inf) for m in margins) if out else None,
            "foot_slip_mm_max": max(r["slip_mm"] for r in out) if out else None,
            "falls": sum(bool(r["fall"]) for r in out),
            "world_contact_n_max": max([max(r["contacts_n"].values(), default=0.0) for r in out], default=0.0)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", action="append", choices=("hrp2", "talos", "g1"))
    ap.add_argument("--scene", default="demo", choices=("demo", "floor"))
    ap.add_argument("--map", action="store_true", help="the executor knows the scene's voxels")
    ap.add_argument("--stabilizer", action="store_true",
                    help="the foot force stabilizer on (physics.yaml's settings)")
    ap.add_argument("--no-guard", action="store_true", help="the force guard off")
    ap.add_argument("--tracking-tau-s", type=float, default=0.01,
                    help="the joint driver's tracking time constant (config/joint_driver.yaml: 0.01 s)")
    ap.add_argument("--gazes", type=int, default=8, help="at most this many gazes (default 8)")
    ap.add_argument("--dwell-s", type=float, default=1.0)
    args = ap.parse_args()
    if args.gazes < 1 or not args.dwell_s >= 0.0 or not args.tracking_tau_s >= 0.0:
        ap.error("--gazes must be >= 1, --dwell-s and --tracking-tau-s >= 0")
    with tempfile.TemporaryDirectory() as tmp:
        scene = "demo"
        if args.scene == "floor":
            scene = str(Path(tmp) / "bare_floor.yaml")
            Path(scene).write_text(FLOOR)
        per = {r: run(r, scene, args.map, args.stabilizer, args.gazes, args.dwell_s, lambda s: print(s, flush=True),
                      guard=not args.no_guard, tau_s=args.tracking_tau_s)
               for r in (args.robot or ["hrp2", "talos", "g1"])}
    summary = {r: {k: v for k, v in d.items() if k != "gazes"} for r, d in per.items()}
    print(json.dumps({"scene": args.scene, "map": args.map, "stabilizer": args.stabilizer, "guard": not args.no_guard,
                      "tracking_tau_s": args.tracking_tau_s,
                      "robots": summary,
                      "details": per}))


if __name__ == "__main__":
    main()
