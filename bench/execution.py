"""Benchmark: whole-body execution of planned reaches on the plant scene (Kanehiro et al., Sec. V, Figs. 7-10).

* Map: the plant scene voxelized at 2 cm without the valve group, one sphere per voxel
  (``SphereTree.from_voxels``); the right-arm and left-arm reaches to the valve WGR
  (eq. 3) from the real :class:`ReachPlanner` (seeded).
* Each reach is executed by :class:`WholeBodyExecutor` in 5 ms steps (as fast as
  possible, every step timed): with everything on, without the exact-COG task (Fig. 7)
  and without the velocity dampers (Fig. 8). The timed runs (everything on) continue by
  holding the goal until ``--steps`` steps are reached in total (half per arm).
* Fig. 7 exact COG (horizontal) with / without compensation; Fig. 8 minimum
  robot-environment distance with / without the collision constraints; Fig. 9 number of
  environment spheres within the distance bound; Fig. 10 per-step time split into the
  distance query and the prioritized IK (and the whole step).
* Smooth reshaping (Yoshida et al.): the reference is reshaped
  (:class:`SmoothReshaper`, clearance = the damper's security distance) and executed
  without dampers; its minimum distance and joint smoothness (max |q''|, RMS jerk from
  the executed 5 ms joint samples) are compared with the velocity-damper execution.
* Before/after: a short run of the same step with the OSQP lexicographic cascade
  (``solver="osqp"``) against the closed-form saturated null-space solver.

Per-step wall time is the contract's figure; the CPU time of the thread is reported
next to it (on a shared machine the difference is time spent preempted). The last
stdout line is one JSON object.

    python bench/execution.py [--out doc/] [--no-plots] [--steps 2000] [--seed 3]
"""
from __future__ import annotations

import argparse
import gc
import json
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pinocchio as pin

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from humanoid_reach_ros.testing.machine import describe as describe_machine  # noqa: E402
from humanoid_reach_ros.control.executor import ExecutorParams, WholeBodyExecutor  # noqa: E402
from humanoid_reach_ros.control.limits import warm_up as limits_warm_up  # noqa: E402
from humanoid_reach_ros.geometry.sphere_tree import SphereTree  # noqa: E402
from humanoid_reach_ros.planning.reach import PlannerParams, PlanRequest, ReachPlanner  # noqa: E402
from humanoid_reach_ros.planning.reshape import ReshapeParams, SmoothReshaper  # noqa: E402
from humanoid_reach_ros.planning.wgr import valve_region  # noqa: E402
from humanoid_reach_ros.robot.model import RobotModel  # noqa: E402
from humanoid_reach_ros.robot.shapes import load_collision_model  # noqa: E402
from humanoid_reach_ros.robot.spec import DEFAULT_ROBOT, robots  # noqa: E402
from humanoid_reach_ros.sim.scene import load_scene  # noqa: E402

OVERRUN_S = 0.005
ARMS = ("right", "left")


def plan_reaches(seed: int, resolution_m: float = 0.02, robot: str = DEFAULT_ROBOT):
    """(planner, voxels, tree, {arm: SplineTrajectory}) on the plant scene."""
    scene = load_scene("scenes/plant.yaml")
    voxels = scene.voxelize(resolution_m, exclude_groups=("valve",))
    planner = ReachPlanner(RobotModel(robot), params=PlannerParams(time_budget_s=5.0))
    planner.set_map(voxels)
    region = valve_region(scene.target.pose)
    refs = {}
    for arm in ARMS:
        out = planner.plan(planner.robot.half_sitting_joints, PlanRequest(region, arm=arm, seed=seed))
        if not out.success:
            raise RuntimeError(f"{arm}-arm plan failed: {out.message}")
        refs[arm] = out.trajectory
    return planner, voxels, SphereTree.from_voxels(voxels, resolution_m), refs


def execute(ex: WholeBodyExecutor, q0: np.ndarray, ref, arm: str, params: ExecutorParams,
            min_steps: int = 0, max_settle_steps: int = 400) -> dict:
    """Run one reference to the end (and on, holding the goal, up to ``min_steps``)."""
    ex.start(q0, ref, arm, params)
    rows, Q = [], []
    n_ref = int(np.ceil(ref.duration / params.period_s))
    k = 0
    while True:
        c0 = time.thread_time()
        res = ex.step()
        cpu = time.thread_time() - c0
        m = res.metrics
        rows.append((m.t, m.solve_time_s, m.distance_time_s, m.ik_time_s, m.spheres_in_bound, m.min_distance_m,
                     m.com_error_m, m.hand_error_m, m.hand_error_rad, m.active_constraints, m.damper_rows,
                     float(m.fallback), cpu, m.self_distance_m))
        Q.append(res.q)
        k += 1
        if k >= max(min_steps, n_ref) and (res.done or k >= n_ref + max_settle_steps):
            break
    a = np.array(rows)
    names = ("t", "step", "distance", "ik", "spheres", "dmin", "com_err", "hand_err", "hand_err_rad", "active",
             "damper_rows", "fallback", "cpu", "self_dmin")
    out = {n: a[:, i] for i, n in enumerate(names)}
    out["q"] = np.array(Q)
    out["n_ref"] = n_ref
    return out


def com_xy(robot, Q: np.ndarray) -> np.ndarray:
    data = robot.model.createData()
    return np.array([pin.centerOfMass(robot.model, data, q, False)[:2] for q in Q])


def smoothness(joints: np.ndarray, dt: float) -> dict:
    """max |q'|, max |q''| and RMS jerk of 5 ms joint samples (finite differences)."""
    qd = np.diff(joints, axis=0) / dt
    qdd = np.diff(qd, axis=0) / dt
    jerk = np.diff(qdd, axis=0) / dt
    return {"max_joint_velocity_radps": float(np.abs(qd).max()),
            "max_joint_acceleration_radps2": float(np.abs(qdd).max()),
            "rms_joint_jerk_radps3": float(np.sqrt(np.mean(jerk ** 2)))}


def pct(x: np.ndarray) -> dict:
    return {"p50": 1e3 * float(np.percentile(x, 50)), "p99": 1e3 * float(np.percentile(x, 99)),
            "max": 1e3 * float(np.max(x))}


def plots(out_dir: Path, runs: dict, robot, dt: float, d_s: float, d_i: float) -> list[str]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    # Fig. 7: exact COG
    fig, axes = plt.subplots(2, 2, figsize=(10, 6), sharex="col")
    for col, arm in enumerate(ARMS):
        for key, label, style in (("with", "with COG compensation", "-"), ("no_com", "without", "--")):
            r = runs[arm][key]
            n = r["n_ref"] + 100
            c = com_xy(robot, r["q"][:n])
            c0 = runs[arm]["com0"]
            for row, _axis in enumerate("xy"):
                axes[row, col].plot(r["t"][:n], 1e3 * (c[:, row] - c0[row]), style, label=label)
        axes[0, col].set_title(f"{arm} arm: exact COG (horizontal) vs start")
        axes[1, col].set_xlabel("time [s]")
        axes[0, col].set_ylabel("COG x [mm]")
        axes[1, col].set_ylabel("COG y [mm]")
        axes[0, col].legend()
    fig.tight_layout()
    p = out_dir / "fig7_cog.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    written.append(str(p))
    # Fig. 8: minimum distance
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for col, arm in enumerate(ARMS):
        ax = axes[col]
        for key, label in (("with", "with collision constraints"), ("no_col", "without (initial trajectory)")):
            r = runs[arm][key]
            n = r["n_ref"] + 100
            ax.plot(r["t"][:n], 1e3 * r["dmin"][:n], label=label)
        rs = runs[arm].get("reshaped")
        if rs is not None:
            n = rs["n_ref"] + 100
            ax.plot(rs["t"][:n], 1e3 * rs["dmin"][:n], ":", label="smooth reshaping, no dampers")
        ax.axhline(1e3 * d_s, color="gray", lw=0.8, ls="--", label="security distance d_s")
        ax.axhline(0.0, color="k", lw=0.8)
        ax.set_ylim(-5, 60)
        ax.set_title(f"{arm} arm: min robot-environment distance")
        ax.set_xlabel("time [s]")
        ax.set_ylabel("distance [mm]")
        ax.legend(fontsize=8)
    fig.tight_layout()
    p = out_dir / "fig8_min_distance.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    written.append(str(p))
    # Fig. 9: spheres in the distance bound
    fig, ax = plt.subplots(figsize=(7, 3.5))
    for arm in ARMS:
        r = runs[arm]["with"]
        n = r["n_ref"] + 100
        ax.plot(r["t"][:n], r["spheres"][:n], label=f"{arm} arm")
    ax.set_title(f"environment spheres within the distance bound d_i = {d_i:.2f} m")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("spheres")
    ax.legend()
    fig.tight_layout()
    p = out_dir / "fig9_spheres_in_bound.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    written.append(str(p))
    # Fig. 10: time split
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for col, arm in enumerate(ARMS):
        ax = axes[col]
        r = runs[arm]["with"]
        n = r["n_ref"] + 100
        ax.plot(r["t"][:n], 1e3 * r["distance"][:n], label="distance query (spheres in bound)")
        ax.plot(r["t"][:n], 1e3 * r["ik"][:n], label="prioritized IK")
        ax.plot(r["t"][:n], 1e3 * r["step"][:n], label="whole step", alpha=0.7)
        ax.axhline(1e3 * dt, color="r", lw=0.8, ls="--", label="control period")
        ax.set_title(f"{arm} arm: processing time per step")
        ax.set_xlabel("time [s]")
        ax.set_ylabel("time [ms]")
        ax.set_yscale("log")
        ax.legend(fontsize=8)
    fig.tight_layout()
    p = out_dir / "fig10_step_time.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    written.append(str(p))
    return written


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="doc/", help="directory of the PNG figures (default doc/)")
    ap.add_argument("--no-plots", action="store_true", help="skip the figures")
    ap.add_argument("--steps", type=int, default=2000, help="timed steps in total, both arms (>= 2000 for the target)")
    ap.add_argument("--seed", type=int, default=3, help="planner seed")
    ap.add_argument("--osqp-steps", type=int, default=300, help="steps of the OSQP-cascade comparison run")
    ap.add_argument("--robot", default=DEFAULT_ROBOT, choices=robots(),
                    help=f"robot of config/robots (default {DEFAULT_ROBOT})")
    args = ap.parse_args(argv)
    if args.steps < 1 or args.osqp_steps < 0:
        ap.error("--steps must be >= 1 and --osqp-steps >= 0")

    planner, voxels, tree, refs = plan_reaches(args.seed, robot=args.robot)
    robot = planner.robot
    cm = load_collision_model(None, robot)
    params = ExecutorParams()
    limits_warm_up()
    ex = WholeBodyExecutor(robot, cm, params)
    ex.set_environment(tree)
    q_start = {arm: robot.config(refs[arm].position(0.0), robot.base_on_feet(refs[arm].position(0.0))) for arm in ARMS}
    # warm-up (numba kernels, BLAS, OSQP setups)
    execute(ex, q_start["right"], refs["right"], "right", params, min_steps=0, max_settle_steps=0)

    runs: dict = {arm: {} for arm in ARMS}
    gc.collect()
    gc.freeze()
    per_arm = (args.steps + 1) // 2
    for arm in ARMS:
        runs[arm]["com0"] = robot.com(q_start[arm])[:2]
        runs[arm]["with"] = execute(ex, q_start[arm], refs[arm], arm, params, min_steps=per_arm)
    for arm in ARMS:
        runs[arm]["no_com"] = execute(ex, q_start[arm], refs[arm], arm, replace(params, com_compensation=False))
        runs[arm]["no_col"] = execute(ex, q_start[arm], refs[arm], arm, replace(params, collision_avoidance=False))

    # smooth reshaping vs velocity dampers
    reshaper = SmoothReshaper(robot, cm, ReshapeParams(period_s=params.period_s,
                                                       clearance_m=params.security_distance_m))
    reshaping = {}
    for arm in ARMS:
        rs = reshaper.reshape(refs[arm], tree, arm)
        run = execute(ex, q_start[arm], rs.trajectory, arm, replace(params, collision_avoidance=False))
        runs[arm]["reshaped"] = run
        damp = runs[arm]["with"]
        n_d = damp["n_ref"] + 1
        reshaping[arm] = {
            "portions": len(rs.portions), "reshape_time_s": rs.time_s, "success": rs.success,
            "reference_min_distance_m": float(rs.distance_before.min()),
            "reshaped_reference_min_distance_m": float(rs.distance_after.min()),
            "reshaped_exec_min_distance_m": float(run["dmin"].min()),
            "damper_exec_min_distance_m": float(damp["dmin"][:n_d].min()),
            "reshaped_exec": smoothness(run["q"][:, 7:], params.period_s),
            "damper_exec": smoothness(damp["q"][:n_d, 7:], params.period_s),
            "initial_exec": smoothness(runs[arm]["no_col"]["q"][:, 7:], params.period_s),
        }

    # before/after: the OSQP lexicographic cascade on the same step
    osqp = {}
    if args.osqp_steps:
        po = replace(params, solver="osqp")
        ex_o = WholeBodyExecutor(robot, cm, po)
        ex_o.set_environment(tree)
        r = execute(ex_o, q_start["right"], refs["right"], "right", po, min_steps=0, max_settle_steps=0)
        r = r if len(r["step"]) <= args.osqp_steps else {k: v[: args.osqp_steps] for k, v in r.items()
                                                         if isinstance(v, np.ndarray)}
        osqp = {"steps": int(len(r["step"])), "step_ms": pct(r["step"]), "ik_ms": pct(r["ik"])}
    gc.unfreeze()

    timed = {k: np.concatenate([runs[a]["with"][k] for a in ARMS]) for k in ("step", "distance", "ik", "cpu",
                                                                             "fallback", "active", "damper_rows")}
    with_all = {a: runs[a]["with"] for a in ARMS}
    result = {
        "bench": "execution", "machine": describe_machine(), "load_avg_1min": os.getloadavg()[0],
        "voxels": int(len(voxels)), "params": {"period_s": params.period_s, "distance_bound_m": params.distance_bound_m,
                                               "security_distance_m": params.security_distance_m,
                                               "damper_xi": params.damper_xi, "solver": params.solver},
        "reference_duration_s": {a: refs[a].duration for a in ARMS},
        "steps": int(len(timed["step"])),
        "step_ms": pct(timed["step"]),
        "step_cpu_ms": pct(timed["cpu"]),
        "distance_ms": pct(timed["distance"]),
        "ik_ms": pct(timed["ik"]),
        "overruns": int(np.count_nonzero(timed["step"] > OVERRUN_S)),
        "osqp_fallbacks": int(timed["fallback"].sum()),
        "damper_rows_max": int(timed["damper_rows"].max()),
        "spheres_in_bound_max": {a: int(with_all[a]["spheres"].max()) for a in ARMS},
        "cog_drift_max_m": {a: float(with_all[a]["com_err"].max()) for a in ARMS},
        "cog_drift_max_m_without_compensation": {a: float(runs[a]["no_com"]["com_err"].max()) for a in ARMS},
        "min_distance_m": {a: float(with_all[a]["dmin"].min()) for a in ARMS},
        "min_distance_m_without_dampers": {a: float(runs[a]["no_col"]["dmin"].min()) for a in ARMS},
        "self_min_distance_m": {a: float(with_all[a]["self_dmin"].min()) for a in ARMS},
        "final_hand_error_m": {a: float(with_all[a]["hand_err"][-1]) for a in ARMS},
        "final_hand_error_rad": {a: float(with_all[a]["hand_err_rad"][-1]) for a in ARMS},
        "max_hand_error_m": {a: float(with_all[a]["hand_err"].max()) for a in ARMS},
        "reshaping": reshaping,
        "osqp_cascade": osqp,
    }
    result["targets"] = {"step_p99_ms<=2.5": result["step_ms"]["p99"] <= 2.5, "overruns==0": result["overruns"] == 0,
                         "steps>=2000": result["steps"] >= 2000,
                         "min_distance>=0": min(result["min_distance_m"].values()) >= 0.0}
    if not args.no_plots:
        result["figures"] = plots(Path(args.out), runs, robot, params.period_s, params.security_distance_m,
                                  params.distance_bound_m)
    print(json.dumps(result), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
