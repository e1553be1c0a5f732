"""Benchmark: the planner on scenes and targets it was not tuned for (config/scenes/suite.yaml).

Every case of the suite x both arms x ``--seeds`` seeds is planned through the library
API (``ReachPlanner.plan``, the node's parameters from config/reach_planner.yaml, the
half-sitting start, a ``--budget-s`` budget): a case whose expectation for the arm is
``reachable`` must succeed, ``out_of_reach`` must be answered TARGET_OUT_OF_REACH (the
geometric bound, no sampling), ``no_goal`` NO_GOAL_FOUND, and ``marginal`` (zero clearance in
the model) SUCCESS, NO_GOAL_FOUND or NO_PATH, counted apart from both (config/scenes/suite.yaml;
expectations per robot). Then one case of each class
goes through ``/plan_reach``: ``joint_driver`` and ``reach_planner`` as real processes
(isolated domain), the planner started on the case's scene (``scene_file``,
``scene_exclude_groups:=[target]``); the request is sent until the planner has joint
states, then once more, timed (the operator's wait, and the first answer's apart).

Figures (per robot): ``feasible_success_rate``, ``feasible_ms_p50`` / ``_p95`` (wall time
of the plan call, successes and failures alike), ``infeasible_correct_code_rate``,
``infeasible_ms_max`` and ``infeasible_geometric_ms_max`` (the TARGET_OUT_OF_REACH ones),
``infeasible_ms_p95`` (every infeasible case) and ``infeasible_ms_p95_bound`` (the cases a
reach bound decides: those expected TARGET_OUT_OF_REACH), ``samples_per_goal_p50`` / ``_p95``
(goal-sampling draws per goal found, over the requests that found one), per case and arm the
codes and times. Targets (issue 13): success >= 0.95, p50 <= 300 ms, correct codes on every
infeasible case, geometric ones in <= 50 ms; issue 35: samples per goal <= 20, infeasible
p95 <= 100 ms. ``--no-reach-map``: the planner without the robots' reach maps (the same run's
baseline). The last line's ``summary``: per robot the issue's figures.

Last stdout line: one JSON object.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

from humanoid_reach_ros.testing.machine import describe as describe_machine  # noqa: E402
from humanoid_reach_ros.codes import ErrorCode, code_name  # noqa: E402
from humanoid_reach_ros.robot.spec import robots  # noqa: E402

PLANNER_PARAMS = REPO / "config" / "reach_planner.yaml"
DRIVER_PARAMS = REPO / "config" / "joint_driver.yaml"
NODE_CASES = ("low_valve", "two_valves_left", "far_valve", "caged_valve")   # one per class (and a left-arm one)


def planner_params():
    import yaml

    from humanoid_reach_ros.planning.reach import PlannerParams

    with open(PLANNER_PARAMS) as f:
        ros_p = yaml.safe_load(f)["/**"]["ros__parameters"]
    return PlannerParams(**{k: ros_p[k] for k in PlannerParams.__dataclass_fields__ if k in ros_p})


def ms_stats(values_ms: list[float]) -> dict:
    a = np.asarray(values_ms, float)
    if not len(a):
        return {}
    return {"p50": float(np.median(a)), "p95": float(np.percentile(a, 95)), "max": float(a.max()),
            "mean": float(a.mean())}


def library_runs(cases, seeds: int, budget_s: float, robot: str, reach_map: bool = True) -> list[dict]:
    from dataclasses import replace

    from humanoid_reach_ros.planning.reach import PlanRequest, ReachPlanner
    from humanoid_reach_ros.robot.model import RobotModel

    rp = ReachPlanner(RobotModel(robot), params=replace(planner_params(), use_reach_map=reach_map))
    rp.warm_up()
    hs = rp.robot.half_sitting_joints
    runs = []
    for case in cases:
        rp.set_map(case.voxels(rp.params.resolution_m))
        expect = case.expect_for(robot)
        for arm in ("right", "left"):
            expected = case.expected_codes(arm, robot)
            for seed in range(seeds):
                t0 = time.perf_counter()
                o = rp.plan(hs, PlanRequest(case.region(), arm=arm, seed=seed, time_budget_s=budget_s))
                ms = 1e3 * (time.perf_counter() - t0)
                runs.append({"case": case.name, "arm": arm, "seed": seed, "expect": expect[arm],
                             "code": o.error.name, "correct": o.error.name in expected, "ms": ms,
                             "goals": int(o.stats.get("goals_found", 0)), "samples": int(o.stats.get("samples", 0)),
                             "duration_s": float(o.times[-1]) if o.success else None})
            sel = [r for r in runs if r["case"] == case.name and r["arm"] == arm]
            print(f"{case.name:18s} {arm:5s} expect {expect[arm]:12s} "
                  f"{sum(r['correct'] for r in sel)}/{len(sel)} correct, "
                  f"{dict(Counter(r['code'] for r in sel))}, ms p50 {np.median([r['ms'] for r in sel]):.0f} "
                  f"max {max(r['ms'] for r in sel):.0f}", flush=True)
    return runs


def summarize(runs: list[dict]) -> dict:
    feas = [r for r in runs if r["expect"] == "reachable"]
    infeas = [r for r in runs if r["expect"] not in ("reachable", "marginal")]
    marginal = [r for r in runs if r["expect"] == "marginal"]
    geo = [r for r in infeas if r["expect"] == "out_of_reach"]
    spg = [r["samples"] / r["goals"] for r in runs if r["goals"] > 0]
    out = {
        "feasible_runs": len(feas), "infeasible_runs": len(infeas), "marginal_runs": len(marginal),
        "marginal_correct_code_rate": sum(r["correct"] for r in marginal) / len(marginal) if marginal else None,
        "marginal_successes": sum(r["code"] == "SUCCESS" for r in marginal),
        "feasible_success_rate": sum(r["correct"] for r in feas) / len(feas) if feas else None,
        "feasible_ms_p50": float(np.median([r["ms"] for r in feas])) if feas else None,
        "feasible_ms_p95": float(np.percentile([r["ms"] for r in feas], 95)) if feas else None,
        "infeasible_correct_code_rate": sum(r["correct"] for r in infeas) / len(infeas) if infeas else None,
        "infeasible_ms_max": max(r["ms"] for r in infeas) if infeas else None,
        "infeasible_geometric_ms_max": max(r["ms"] for r in geo) if geo else None,
        "infeasible_ms_p95": float(np.percentile([r["ms"] for r in infeas], 95)) if infeas else None,
        "infeasible_ms_p95_bound": float(np.percentile([r["ms"] for r in geo], 95)) if geo else None,
        "samples_per_goal_p50": float(np.median(spg)) if spg else None,
        "samples_per_goal_p95": float(np.percentile(spg, 95)) if spg else None,
        "trajectory_s_p50": float(np.median([r["duration_s"] for r in feas if r["duration_s"] is not None]))
        if any(r["duration_s"] is not None for r in feas) else None,
    }
    per = {}
    for r in runs:
        k = f"{r['case']}/{r['arm']}"
        d = per.setdefault(k, {"expect": r["expect"], "codes": Counter(), "ms": []})
        d["codes"][r["code"]] += 1
        d["ms"].append(r["ms"])
    out["per_case"] = {k: {"expect": d["expect"], "codes": dict(d["codes"]), "ms": ms_stats(d["ms"])}
                       for k, d in per.items()}
    keys = ("case", "arm", "seed", "expect", "code", "ms")
    out["wrong"] = [{k: r[k] for k in keys} for r in runs if not r["correct"]]
    return out


def node_runs(cases, budget_s: float, timeout_s: float, robot: str) -> list[dict]:
    """One case per class through /plan_reach (the planner restarted on each scene)."""
    from operator_wait import Client

    from humanoid_reach_ros.codes import ARM_CODES
    from humanoid_reach_ros.graph import NodeProcess, allocate_domain, graph_env
    from humanoid_reach_ros.io import msgs

    log_dir = Path(tempfile.mkdtemp(prefix="generality_"))
    lease = allocate_domain()
    env = graph_env(lease.domain_id)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = env["ROS_AUTOMATIC_DISCOVERY_RANGE"]
    out, client, procs = [], None, []
    try:
        driver = NodeProcess.start("joint_driver", log_dir, env, DRIVER_PARAMS, params={"robot_config": robot})
        procs.append(driver)
        driver.wait_for_log(r"simulated ", 60.0)
        client = Client(lease.domain_id, None)
        for case in cases:
            expect = case.expect_for(robot)
            arm = next(a for a in ("right", "left") if expect[a] == case.scene_class(robot))
            planner = NodeProcess.start("reach_planner", log_dir, env, PLANNER_PARAMS,
                                        params={"scene_file": str(case.scene_path), "robot_config": robot,
                                                "scene_exclude_groups": list(case.exclude_groups)})
            procs.append(planner)
            planner.wait_for_log(r"reach planner ready", 120.0)
            client.spin_until(client.client.service_is_ready, 60.0, "/plan_reach", planner.log_tail)
            req = msgs.plan_reach_request(case.region(), "world", seed=0, time_budget_s=budget_s)
            req.arm = ARM_CODES[arm]
            deadline = time.monotonic() + 60.0
            while True:   # the first answers may be NO_JOINT_STATES until the planner has them
                first, first_s = client.call(req, timeout_s, planner.log_tail)
                if first.error_code.val != ErrorCode.NO_JOINT_STATES or time.monotonic() > deadline:
                    break
                time.sleep(0.2)
            resp, wait_s = client.call(req, timeout_s, planner.log_tail)   # the same request again, timed
            name = code_name(resp.error_code.val)
            out.append({"case": case.name, "arm": arm, "expect": expect[arm], "code": name,
                        "correct": {name, code_name(first.error_code.val)} <= set(case.expected_codes(arm, robot)),
                        "wait_ms": 1e3 * wait_s, "node_ms": 1e3 * resp.statistics.total_time_s,
                        "first_wait_ms": 1e3 * first_s, "message": resp.message[:200]})
            print(f"/plan_reach {case.name} {arm}: {name} in {1e3 * wait_s:.0f} ms ({resp.message[:120]})", flush=True)
            planner.stop()
            procs.remove(planner)
            if not planner.exited_cleanly():
                raise RuntimeError(f"reach_planner exited with {planner.proc.returncode}\n{planner.log_tail()}")
    finally:
        if client is not None:
            client.close()
        for p in reversed(procs):
            p.stop()
        lease.release()
    return out




def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5, help="seeds per case and arm (default 5)")
    ap.add_argument("--budget-s", type=float, default=2.0, help="planning budget per request [s] (default 2)")
    ap.add_argument("--cases", nargs="*", default=None, help="only these suite cases (default: all)")
    ap.add_argument("--no-node", action="store_true", help="skip the /plan_reach subset")
    ap.add_argument("--no-reach-map", action="store_true", help="plan without the robots' reach maps (baseline)")
    ap.add_argument("--robot", nargs="+", default=robots(), choices=robots(), metavar="ROBOT",
                    help=f"robots of config/robots (default: all of them, {' '.join(robots())})")
    args = ap.parse_args()
    if args.seeds < 1 or not args.budget_s > 0:
        ap.error("--seeds must be >= 1 and --budget-s > 0")

    from humanoid_reach_ros.planning.suite import load_suite

    cases = load_suite()
    if args.cases:
        unknown = set(args.cases) - {c.name for c in cases}
        if unknown:
            ap.error(f"unknown case(s) {sorted(unknown)}; the suite has {[c.name for c in cases]}")
        cases = [c for c in cases if c.name in args.cases]
    result = {"bench": "generality", "machine": describe_machine(), "seeds": args.seeds, "budget_s": args.budget_s,
              "reach_map": not args.no_reach_map, "load_before": os.getloadavg()[0],
              "cases": [c.name for c in cases], "robots": {}}
    for name in dict.fromkeys(args.robot):
        print(f"== {name}", flush=True)
        t0 = time.perf_counter()
        runs = library_runs(cases, args.seeds, args.budget_s, name, not args.no_reach_map)
        robot = summarize(runs)
        robot["library_s"] = time.perf_counter() - t0
        if not args.no_node:
            node = node_runs([c for c in cases if c.name in NODE_CASES], args.budget_s, 60.0, name)
            robot["node"] = {"runs": node,
                             "correct_rate": sum(r["correct"] for r in node) / len(node) if node else None}
        robot["targets"] = {
            "feasible_success_rate>=0.95": (robot["feasible_success_rate"] or 0) >= 0.95,
            "feasible_ms_p50<=300": (robot["feasible_ms_p50"] or 1e9) <= 300,
            "infeasible_correct_code_rate==1": robot["infeasible_correct_code_rate"] == 1.0,
            "infeasible_geometric_ms_max<=50": (robot["infeasible_geometric_ms_max"] or 0) <= 50,
            "samples_per_goal_p50<=20": (robot["samples_per_goal_p50"] or 1e9) <= 20,
            "infeasible_ms_p95<=100": (robot["infeasible_ms_p95"] or 1e9) <= 100,
        }
        result["robots"][name] = robot
    keys = ("feasible_success_rate", "feasible_ms_p50", "feasible_ms_p95", "infeasible_ms_p95",
            "infeasible_ms_p95_bound", "samples_per_goal_p50", "samples_per_goal_p95")
    result["summary"] = {n: {k: (round(r[k], 2) if isinstance(r[k], float) else r[k]) for k in keys}
                         for n, r in result["robots"].items()}
    result["load_after"] = os.getloadavg()[0]
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
