"""The session bench's operator sequences on the PHYSICS plant (issue 32): does the robot stay standing?

Per robot (``--robots``, default HRP-2, Talos and the G1) ``--sessions`` sessions (default 3) of
bench/session.py's operator sequence on its scene (``run_session`` with ``plant="mujoco"``: the
six nodes as processes, ``joint_driver`` on the MuJoCo plant standing in the scene the sensors
render; the steps: an automatic look, the scan, the marker, a touch, a plain target, home), then
one **stress session** (HRP-2): the same sequence with the planner timing every trajectory at the
executor's velocity limits (``reach_planner`` ``joint_velocity_rad_s`` far above them, so its
``velocity_scale * URDF limit`` bound rules every joint: the fastest the executor ever moves).

Each session's plant figures come from ``/physics/metrics`` (msg/PlantMetrics; the plant's own
worst-since-start fields, so nothing between messages is missed; sim/physics/summary.py). The
session bench's own figures (steps, retreats, waits, overruns) are bench/session.py's.

Measured, over every session (stress included):

* ``physics_steps``, ``physics_steps_succeeded_rate``: the session bench's steps and how many
  succeeded (target 1.0);
* ``falls`` (target 0): sessions whose plant fell (base below where its joints hold it on its feet
  by ``fall.base_drop_m``, tilt beyond ``fall.tilt_deg``, or the capture point 5 cm outside the
  support polygon; physics.yaml);
* ``foot_slip_mm_max`` (<= 1.0), ``cop_margin_mm_min`` (>= 20), ``base_tilt_deg_max`` (report),
  ``joint_tracking_error_rad_p99`` (report: the largest over sessions of each session's p99 of the
  per-message maximum over joints);
* ``hand_contact_force_n_max``: the largest hand-environment contact force (target: at most the
  touch bound, :func:`touch_force_bound_n` of the robot with the smallest bound);
* ``real_time_factor_min`` (>= 1.0: over 1 s windows, the first left out; reported to 2 decimals,
  as the plant paces itself by the wall clock), ``plant_cpu_pct`` (report: the largest);
* ``executor_overruns`` (0): every motion's, from the executor's log (bench/session.py);
* ``operator_wait_ms_p50`` / ``_p95`` (300 / 1,000): as bench/session.py measures them.

A figure a session did not measure (no /physics/metrics, a session that broke) is ``null`` and
a missed target, never "n/a".

Last line: one JSON object with those keys, ``machine``, ``targets`` (each judged), per-robot
figures and the sessions under ``details``.

Usage: ``python bench/physics.py [--robots hrp2 talos g1] [--sessions 3] [--no-stress]
[--out out/bench_physics]``.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
for _p in (REPO, REPO / "bench"):
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))

import session as session_bench  # noqa: E402  (bench/session.py)

ROBOTS = ("hrp2", "talos", "g1")
STRESS_ROBOT = "hrp2"
#: the stress session's planner: durations at this speed [rad/s] (the top of the parameter's range), above
#: every joint's executor bound (velocity_scale 0.5 x URDF limits: HRP-2's 3-4 rad/s give 1.5-2), so the
#: bound rules every joint of every segment
STRESS_PLANNER = {"reach_planner": {"joint_velocity_rad_s": 10.0}}
TARGETS = {   # key: (comparison, bound); hand_contact_force_n_max's bound is the touch bound, set in main
    "physics_steps_succeeded_rate": ("==", 1.0), "falls": ("==", 0), "foot_slip_mm_max": ("<=", 1.0),
    "cop_margin_mm_min": (">=", 20.0), "real_time_factor_min": (">=", 1.0), "executor_overruns": ("==", 0),
    "operator_wait_ms_p50": ("<=", 300.0), "operator_wait_ms_p95": ("<=", 1000.0),
}
KEYS = ("physics_steps", "physics_steps_succeeded_rate", "falls", "foot_slip_mm_max", "cop_margin_mm_min",
        "base_tilt_deg_max", "joint_tracking_error_rad_p99", "hand_contact_force_n_max", "real_time_factor_min",
        "executor_overruns", "plant_cpu_pct", "operator_wait_ms_p50", "operator_wait_ms_p95")


def touch_force_bound_n(robot_name: str) -> dict[str, Any]:
    """The robot's touch bound (sim/physics/touch.py: half the force its weakest wrist joint resists
    at the hand), as a dict."""
    from dataclasses import asdict

    from humanoid_reach_ros.robot.model import RobotModel
    from humanoid_reach_ros.sim.physics.touch import touch_force_bound

    return asdict(touch_force_bound(RobotModel(robot_name)))


def robot_steps(robot_name: str) -> tuple[str, dict[str, Any]]:
    """The session bench's plant sequence for ``robot_name``'s own scene (robot.yaml ``demo_scene``):
    (scene name, SCENES-style entry). The plant itself where that is the robot's scene; else the
    plant's steps carried into its scene: the per-axis map ``x' = a x + b`` (x, y, z) fitted over the
    centres of the primitives both scenes name (tools/scale_scene.py moves objects, keeps their
    sizes), each target mapped, then moved along the surface normal so that its clearance to the
    nearest object is what it was in the plant (a touching target only: 1 cm above a pipe stays 1 cm
    above it)."""
    import copy

    import numpy as np

    from humanoid_reach_ros.paths import config_path
    from humanoid_reach_ros.robot.spec import load_robot_spec
    from humanoid_reach_ros.sim.scene import load_scene

    base = session_bench.SCENES[session_bench.QUICK_SCENE]
    plant_path = config_path(base["scene"])
    own = Path(load_robot_spec(robot_name)[0].demo_scene)
    if own.resolve() == plant_path.resolve():
        return session_bench.QUICK_SCENE, base
    src, dst = load_scene(plant_path), load_scene(own)
    names = [p.name for p in src.primitives if not getattr(p, "floor", False)
             and p.name in {q.name for q in dst.primitives}]
    if len(names) < 2:
        raise ValueError(f"{own}: fewer than two primitives named as in {plant_path}: cannot carry the steps over")
    c0 = np.array([np.mean(src.primitive(n).bounds(), axis=0) for n in names])
    c1 = np.array([np.mean(dst.primitive(n).bounds(), axis=0) for n in names])
    # the target's group (the valve) moves as one piece about its centre: its parts leave the fit, the
    # worst first, until the rest fit within 2 mm (at least four primitives, half of them)
    keep = np.ones(len(names), bool)
    while True:
        coef = [np.polyfit(c0[keep, k], c1[keep, k], 1) for k in range(3)]
        resid = np.max([np.abs(np.polyval(coef[k], c0[:, k]) - c1[:, k]) for k in range(3)], axis=0)
        worst = int(np.argmax(np.where(keep, resid, -1.0)))
        if resid[worst] <= 0.002:
            break
        keep[worst] = False
        if keep.sum() < max(4, len(names) // 2):
            raise ValueError(f"{own}: not a per-axis scaling of {plant_path}: cannot carry the steps over")
    entry = copy.deepcopy(base)
    entry["scene"] = str(own)
    for t in entry["targets"]:
        if "target" not in t:
            continue
        p0 = np.asarray(t["target"], float)
        d0 = float(src.sdf(p0[None])[0])
        n = src.normals(p0[None])[0]
        p1 = np.array([np.polyval(coef[k], p0[k]) for k in range(3)])
        if t["kind"] == "touch":      # along the plant's normal until the clearance is the plant's
            for _ in range(3):
                p1 = p1 + n * (d0 - float(dst.sdf(p1[None])[0]))
        t["target"] = [round(float(v), 4) for v in p1]
        t["why"] = f"{t['why']} (carried from the plant: {np.round(p0, 3).tolist()} -> {t['target']})"
    entry["scaled_from"] = {"scene": str(plant_path), "x": coef[0].round(4).tolist(), "y": coef[1].round(4).tolist(),
                            "z": coef[2].round(4).tolist()}
    return f"{session_bench.QUICK_SCENE}@{robot_name}", entry


def session_physics_ok(s: dict[str, Any]) -> bool:
    return bool(s.get("physics")) and s["physics"].get("plant_messages", 0) > 0


def summarize(sessions: list[dict[str, Any]], bound_n: float) -> dict[str, Any]:
    """The issue's keys over ``sessions`` (module doc); a figure a session lacks is None."""
    base = session_bench.summarize(sessions) if sessions else {}
    ph = [s.get("physics") or {} for s in sessions]
    complete = bool(sessions) and all(session_physics_ok(s) for s in sessions)

    def worst(key: str, fn) -> Any:
        vals = [p.get(key) for p in ph]
        return fn(vals) if complete and vals and None not in vals else None
    return {
        "physics_steps": base.get("session_steps", 0),
        "physics_steps_succeeded_rate": base.get("session_steps_succeeded_rate"),
        "falls": sum(p["falls"] for p in ph) if complete else None,
        "foot_slip_mm_max": worst("foot_slip_mm_max", max),
        "cop_margin_mm_min": worst("cop_margin_mm_min", min),
        "base_tilt_deg_max": worst("base_tilt_deg_max", max),
        "joint_tracking_error_rad_p99": worst("joint_tracking_error_rad_p99", max),
        "hand_contact_force_n_max": worst("hand_contact_force_n_max", max),
        "real_time_factor_min": worst("real_time_factor_min", min),
        "executor_overruns": base.get("session_overruns"),
        "plant_cpu_pct": worst("plant_cpu_pct", max),
        "operator_wait_ms_p50": base.get("operator_wait_ms_p50"),
        "operator_wait_ms_p95": base.get("operator_wait_ms_p95"),
        "touch_bound_n": bound_n,
        "base_vs_feet_odometry_mm_max": worst("base_vs_feet_odometry_mm_max", max),
        "base_vs_feet_odometry_deg_max": worst("base_vs_feet_odometry_deg_max", max),
        "fall_reasons": [p.get("fall_reason") for p in ph if p.get("falls")],
        "failed_steps": base.get("failed_steps", []),
    }


def judge(figures: dict[str, Any], targets: dict[str, tuple[str, float]]) -> dict[str, dict[str, Any]]:
    import graph as bench_graph
    return bench_graph.judge(figures, targets)


def main(argv: list[str] | None = None) -> int:
    from humanoid_reach_ros.testing.machine import describe as machine

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robots", nargs="+", choices=ROBOTS, default=list(ROBOTS))
    ap.add_argument("--sessions", type=int, default=3, help="sessions per robot (default 3)")
    ap.add_argument("--no-stress", action="store_true", help="leave out the stress session")
    ap.add_argument("--seed-base", type=int, default=1)
    ap.add_argument("--out", default="out/bench_physics")
    args = ap.parse_args(argv)
    if args.sessions < 0:
        ap.error("--sessions must be >= 0")
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)

    def log(text: str) -> None:
        print(f"[bench/physics] {text}", flush=True)

    session_bench.stop_on_signals()
    bounds = {r: touch_force_bound_n(r) for r in set(args.robots) | ({STRESS_ROBOT} if not args.no_stress else set())}
    for r, b in sorted(bounds.items()):
        log(f"{r}: touch bound {b['bound_n']} N (half of {b['effort_nm']} N m over {b['lever_m']} m: "
            f"{b['arm']} {b['joint']})")
    t0 = time.monotonic()
    runs: list[tuple[str, str, dict[str, Any]]] = []     # (robot, kind, session)
    plan = [(r, "session", args.seed_base + k) for r in args.robots for k in range(args.sessions)]
    if not args.no_stress:
        plan.append((STRESS_ROBOT, "stress", args.seed_base + 100))
    steps = {r: robot_steps(r) for r in {r for r, _, _ in plan}}
    for r, (_scene, entry) in sorted(steps.items()):
        log(f"{r}: scene {entry['scene']}, targets " + ", ".join(f"{t['name']} {t.get('target', '')}"
                                                                  for t in entry["targets"]))
    for robot, kind, seed in plan:
        scene, entry = steps[robot]
        log(f"{robot} {kind} (seed {seed}, scene {scene}): graph up ...")
        try:
            s = session_bench.run_session(out / f"{robot}_{kind}_s{seed}", scene, seed, robot, log, plant="mujoco",
                                          scene_steps=entry, node_params=STRESS_PLANNER if kind == "stress" else None)
        except (RuntimeError, AssertionError, TimeoutError) as exc:
            log(f"  session failed: {exc}")
            s = {"scene": scene, "seed": seed, "steps": [session_bench.failed_step("graph", str(exc))],
                 "error": str(exc)[-3000:]}
        s["robot"], s["kind"] = robot, kind
        runs.append((robot, kind, s))
        p = s.get("physics") or {}
        log(f"  {robot} {kind}: falls {p.get('falls')}, CoP margin min {p.get('cop_margin_mm_min')} mm, slip "
            f"{p.get('foot_slip_mm_max')} mm, tilt {p.get('base_tilt_deg_max')} deg, hand force "
            f"{p.get('hand_contact_force_n_max')} N, RTF min {p.get('real_time_factor_min')}, plant CPU "
            f"{p.get('plant_cpu_pct')} %, {s.get('wall_s')} s")
    sessions = [s for _, _, s in runs]
    bound = min(b["bound_n"] for b in bounds.values())
    figures = summarize(sessions, bound)
    targets = {**TARGETS, "hand_contact_force_n_max": ("<=", bound)}
    required = {k: figures[k] for k in KEYS}
    judged = judge(required, targets)
    per_robot = {r: {k: v for k, v in summarize([s for rr, kind, s in runs if rr == r and kind == "session"],
                                                bounds[r]["bound_n"]).items() if k in KEYS or k == "touch_bound_n"}
                 for r in args.robots}
    result = {**required, "machine": machine(), "details": {
        "targets": judged, "targets_met": all(t["met"] for t in judged.values()),
        "touch_bounds": bounds, "per_robot": per_robot,
        "stress": None if args.no_stress else summarize([s for _, kind, s in runs if kind == "stress"],
                                                        bounds[STRESS_ROBOT]["bound_n"]),
        "extra": {k: v for k, v in figures.items() if k not in KEYS},
        "sessions": sessions, "sessions_per_robot": args.sessions, "bench": "physics",
        "wall_s": round(time.monotonic() - t0, 1)}}
    (out / "physics.json").write_text(json.dumps(result, indent=2, default=str))
    for key, t in judged.items():
        log(f"{'ok  ' if t['met'] else 'MISS'} {key}: {t['value']} (target {t['target']})"
            + (" (not measured)" if t.get("missing") else ""))
    print(json.dumps({k: v for k, v in result.items() if k != "details"}
                     | {"details": {k: v for k, v in result["details"].items() if k != "sessions"}}, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
