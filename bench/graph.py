"""The headline figures in the RUNNING graph (issue #12), as a user of `make demo` feels them.

Starts the whole graph as separate processes the way the demo does (isolated ROS domain,
localhost discovery: joint_driver, scene_sim, voxel_mapper, marker_localizer, reach_planner,
reach_executor), scans the plant with the head, then measures from outside the nodes:

1. **idle** (robot standing still after the scan, ``--idle-s`` >= 20 s): CPU per node from
   /proc (utime + stime of the node's process tree: reach_executor's control loop is a child
   process), INFO-or-louder log lines per node per minute, the largest gap between joint
   states each node reports in /diagnostics (``joint_states_max_gap_ms``) and the bench's own
   probe subscriber;
2. **operator wait**: ``--plan-calls`` /plan_reach calls (the valve WGR at a given target, plan only)
   from this process, the rest of the graph running;
3. **executions** through /plan_reach + /execute_reach: both arms, the marker target and given
   targets, one passing close to a pipe; then a second session on
   ``config/scenes/dense_pipes.yaml`` (two pipes 16 cm apart in front of the valve). For each:
   the executor's own step times (/executor/metrics) and overruns (action result), wall time
   from acceptance to result over the trajectory's duration, and from the measured
   /joint_states (what the robot did): feet drift (left sole in the right sole's frame), exact
   COG drift (right sole's frame, from the execution's start) and the final hand error after
   the joints settle; steps after the reference's end (settling, holding) separately.

Last line: one JSON object (``targets`` lists each target of the issue with pass/fail).
Usage: ``python bench/graph.py [--idle-s 20] [--plan-calls 30] [--out out/bench_graph] [--quick]``
(``make bench`` runs it).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from humanoid_reach_ros.codes import ARM_NAMES, ErrorCode
from humanoid_reach_ros.demo import GRAPH_NODES, SIM_JOINT_STATES_ABORT_S, SIM_JOINT_STATES_TIMEOUT_S, Graph, \
    DemoClient, scan_plant, wait_marker
from humanoid_reach_ros.graph import allocate_domain, graph_env
from humanoid_reach_ros.testing.graph_metrics import CpuSampler, log_lines_at_or_above, max_gap_ms, measured_balance, \
    percentile
from humanoid_reach_ros.testing.machine import describe as machine
from humanoid_reach_ros.paths import config_path

PRODUCT = tuple(n for n in GRAPH_NODES if n != "scene_sim")
TARGETS = {   # key: (comparison, bound)
    "idle_cpu_pct_product": ("<=", 40.0), "idle_cpu_pct_scene_sim": ("<=", 25.0),
    "executor_overruns": ("==", 0), "executor_steps": (">=", 3000), "executor_step_ms_p99": ("<=", 2.5),
    "exec_wall_over_duration_max": ("<=", 1.05), "feet_drift_measured_mm_max": ("<=", 0.1),
    "com_drift_measured_mm_max": ("<=", 1.0), "hand_error_final_mm_max": ("<=", 1.0),
    "hold_step_ms_p99": ("<=", 2.5), "plan_wait_ms_p50": ("<=", 100.0), "plan_wait_ms_p95": ("<=", 200.0),
    "joint_states_max_gap_ms": ("<=", 20.0), "idle_info_lines_per_min": ("<=", 1.0),
    "executions_failed_count": ("==", 0),
}
# (name, arm, target or None for the marker, scene)
PLANT_EXECUTIONS = [
    ("valve_marker_right", "right", None),
    ("over_passage_pipe_right", "right", (0.45, -0.22, 0.86)),     # hand just above the passage pipe
    ("valve_left", "left", (0.71, 0.03, 0.90)),
    ("under_shoulder_pipe_left", "left", (0.50, 0.20, 1.08)),      # under the left shoulder pipe
    ("valve_marker_right_again", "right", None),
]
DENSE_EXECUTIONS = [("dense_valve_right", "right", (0.71, 0.03, 0.90)),
                    ("dense_valve_left", "left", (0.71, 0.03, 0.90))]


class Bench:
    """One graph session and the operator side in this process."""

    def __init__(self, out: Path, scene: Path) -> None:
        self.out = out
        out.mkdir(parents=True, exist_ok=True)
        self.lease = allocate_domain()
        self.graph = Graph(out, graph_env(self.lease.domain_id))
        for name in GRAPH_NODES:
            params: dict[str, Any] = {}
            if name == "scene_sim":
                params["scene_file"] = str(scene)
            elif name in ("reach_planner", "reach_executor"):
                params["scene_file"] = ""
                params["joint_states_timeout_s"] = SIM_JOINT_STATES_TIMEOUT_S
                if name == "reach_executor":
                    params["joint_states_abort_s"] = SIM_JOINT_STATES_ABORT_S
            self.graph.start(name, params)
        self.op = DemoClient(self.lease.domain_id, self.graph)
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.qos import qos_profile_sensor_data
        from sensor_msgs.msg import JointState
        self.js_times: list[float] = []
        self.js_record = False
        self.gaps: dict[str, float] = {}
        self.op.node.create_subscription(JointState, "/joint_states", self._on_js, qos_profile_sensor_data)
        self.commands: list = []          # /joint_command while recording (what the executor sent)
        self.op.node.create_subscription(JointState, "/joint_command",
                                         lambda m: self.commands.append(m) if self.js_record else None, 400)
        self.op.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 50)
        names = set(GRAPH_NODES)
        self.op.spin_until(lambda: names <= set(self.op.node.get_node_names()) and self.op.joint_states is not None,
                           120.0, f"the nodes {sorted(names)} in the graph")
        from humanoid_reach_ros.robot.model import RobotModel
        self.robot = RobotModel()

    def _on_js(self, _msg) -> None:
        if self.js_record:
            self.js_times.append(time.monotonic())

    def _on_diag(self, msg) -> None:
        for st in msg.status:
            for kv in st.values:
                if kv.key == "joint_states_max_gap_ms":
                    try:
                        v = float(kv.value)
                    except ValueError:
                        continue
                    node = st.name.split(":")[0]
                    self.gaps[node] = max(self.gaps.get(node, 0.0), v)

    def procs(self) -> dict[str, Any]:
        return {p.name: p for p in self.graph.procs}

    def close(self) -> dict[str, int]:
        try:
            self.op.close()
        finally:
            codes = self.graph.stop()
            self.lease.release()
        return codes

    # ------------------------------------------------------------ measurements
    def idle(self, seconds: float) -> dict[str, Any]:
        procs = self.procs()
        self.js_times.clear()
        self.op.spin_for(1.5)       # what the last head command started (the driver going idle, the nodes'
        self.gaps.clear()           # diagnostics windows of the scan) is not part of the idle figures
        sizes = {n: len(p.log()) for n, p in procs.items()}
        sampler = CpuSampler({n: p.pid for n, p in procs.items()})
        self.js_record = True
        sampler.start()
        t0 = time.monotonic()
        self.op.spin_for(seconds)
        cpu = sampler.stop()
        dt = time.monotonic() - t0
        self.js_record = False
        lines = {n: log_lines_at_or_above(p.log()[sizes[n]:]) * 60.0 / dt for n, p in procs.items()}
        return {"gaps": dict(self.gaps), "cpu": cpu, "info_lines_per_min": lines,
                "probe_gap_ms": max_gap_ms(self.js_times), "window_s": dt}

    def plan_request(self, arm: str, target: tuple[float, float, float] | None, budget: float = 5.0):
        from humanoid_reach_ros.demo import arm_code
        from humanoid_reach_ros.io import msgs
        from humanoid_reach_ros.planning.wgr import valve_region
        region = valve_region()
        if target is not None:
            region = type(region)(np.asarray(target, float), region.target_R, region.lower, region.upper)
        return msgs.plan_reach_request(region, "world", arm=arm_code(arm), use_marker_target=target is None,
                                       time_budget_s=budget)

    def call_plan(self, req, timeout: float = 40.0):
        self.op.spin_until(lambda: self.op.plan_client.service_is_ready(), 30.0, "/plan_reach")
        t0 = time.monotonic()
        fut = self.op.plan_client.call_async(req)
        self.op.spin_until(fut.done, timeout, "the /plan_reach response")
        return fut.result(), time.monotonic() - t0

    def plan_waits(self, n: int) -> list[float]:
        req = self.plan_request("right", (0.71, 0.03, 0.90))   # the valve, given (the marker path: executions)
        waits = []
        for _ in range(n):
            resp, wait = self.call_plan(req)
            if not resp.success:
                raise RuntimeError(f"/plan_reach failed during the wait measurement: {resp.message}")
            waits.append(wait * 1e3)
        return waits

    def reach_and_return(self, name: str, arm: str, target) -> list[dict[str, Any]]:
        """A planned reach, then back along the same path (the planner plans from half-sitting-like
        postures; the way back is the trajectory reversed, executed like any other)."""
        resp, plan_s = self.call_plan(self.plan_request(arm, target))
        if not resp.success:
            return [{"name": name, "arm": arm, "success": False, "error_code": -int(resp.error_code.val),
                     "message": f"/plan_reach failed: {resp.message}"}]
        there = self.execute(name, resp.trajectory, resp.arm)
        there["plan_ms"] = plan_s * 1e3
        return [there, self.execute(f"{name}_return", reversed_trajectory(resp.trajectory), resp.arm)]

    def execute(self, name: str, traj, arm_code: int, hold_s: float = 2.0) -> dict[str, Any]:
        from humanoid_reach_ros.io import msgs
        arm = ARM_NAMES[arm_code]
        t_end = traj.points[-1].time_from_start
        duration = t_end.sec + t_end.nanosec * 1e-9
        ex = self.op.ExecuteReach
        goal = ex.Goal(mode=ex.Goal.MODE_TRAJECTORY, trajectory=traj, arm=arm_code)
        self.op.spin_until(lambda: self.op.action_client.server_is_ready(), 30.0, "/execute_reach")
        self.op.metrics.clear()
        self.op.samples.clear()
        self.commands.clear()
        self.js_times.clear()
        self.op.recording = self.js_record = True
        send = self.op.action_client.send_goal_async(goal)
        self.op.spin_until(send.done, 30.0, "/execute_reach to accept the goal")
        t_accept = time.monotonic()
        handle = send.result()
        if not handle.accepted:
            raise RuntimeError(f"{name}: /execute_reach rejected the goal")
        fut = handle.get_result_async()
        self.op.spin_until(fut.done, duration * 5 + 60.0, "the /execute_reach result")
        wall = time.monotonic() - t_accept
        result = fut.result().result
        if not result.success and result.error_code.val != ErrorCode.TARGET_NOT_REACHED:
            raise RuntimeError(f"{name}: /execute_reach failed ({result.error_code.val}): {result.message}")
        # hold: settle of the measured joints (the driver's tracking lag), then hold_s more
        t_hold = time.monotonic()

        def settled() -> bool:
            s = self.op.samples
            if len(s) < 20:
                return False
            a, b = np.array(s[-20].position), np.array(s[-1].position)
            return a.shape == b.shape and float(np.max(np.abs(a - b))) < 1e-5
        self.op.spin_until(settled, 20.0, f"{name}: the measured joints to settle")
        self.op.spin_for(max(0.0, hold_s - (time.monotonic() - t_hold)))
        self.op.recording = self.js_record = False
        def joints(messages) -> list:
            out = []
            for m in messages:
                j, why = msgs.model_joints(m, self.robot)
                if j is None:
                    raise RuntimeError(f"{name}: a recorded joint state is unusable: {why}")
                out.append(j)
            return out
        series = joints(self.op.samples)
        final_ref = self.robot.joints_from_dict(dict(zip(traj.joint_names, traj.points[-1].positions)))
        bal = measured_balance(self.robot, series, arm=arm, final_reference=final_ref)
        commanded = joints(self.commands)
        if commanded:   # the same drifts of what the executor commanded: the loop's part vs the tracking's
            cb = measured_balance(self.robot, commanded)
            bal["feet_drift_commanded_mm"], bal["com_drift_commanded_mm"] = cb["feet_drift_mm"], cb["com_drift_mm"]
        np.savez_compressed(self.out / f"{name}_joints.npz", measured=np.array(series), commanded=np.array(commanded))
        metrics = list(self.op.metrics)
        run = [m.step_time_s * 1e3 for m in metrics if m.time_from_start_s <= duration + 1e-9]
        after = [m.step_time_s * 1e3 for m in metrics if m.time_from_start_s > duration + 1e-9]
        return {"name": name, "arm": arm, "success": bool(result.success), "error_code": int(result.error_code.val),
                "message": result.message,
                "duration_s": duration, "wall_s": wall, "wall_over_duration": wall / duration,
                "steps": int(result.steps), "overruns": int(result.overruns), "metrics_messages": len(metrics),
                "step_ms_p50": percentile(run, 50), "step_ms_p99": percentile(run, 99),
                "step_ms_max": max(run) if run else None, "steps_over_5ms": int(sum(t > 5.0 for t in run)),
                "after_end_steps": len(after), "after_end_step_ms": after, "run_step_ms": run,
                "min_distance_m": float(result.min_distance_m), "probe_gap_ms": max_gap_ms(self.js_times), **bal}


def reversed_trajectory(traj):
    """The same JointTrajectory run backwards (times mirrored)."""
    from humanoid_reach_ros.io import msgs
    t = np.array([p.time_from_start.sec + p.time_from_start.nanosec * 1e-9 for p in traj.points])
    pos = np.array([p.positions for p in traj.points])
    return msgs.joint_trajectory(list(traj.joint_names), t[-1] - t[::-1], pos[::-1], frame_id=traj.header.frame_id)


def judge(figures: dict[str, Any], targets: dict[str, tuple[str, float]] = TARGETS,
          not_run: dict[str, str] | None = None) -> dict[str, dict[str, Any]]:
    """Each figure of ``targets`` (key: (comparison, bound)) against its bound (bench/session.py and
    bench/hosts.py too). A missing measurement (None) is a missed target (``"missing": True``), never
    skipped; only a part of the bench its options left out (``not_run``: key -> why) is not judged."""
    out = {}
    for key, (op, bound) in targets.items():
        if key in (not_run or {}):
            continue
        v = figures.get(key)
        ok = v is not None and {"<=": v <= bound, ">=": v >= bound, "==": v == bound}[op]
        out[key] = {"value": v, "target": f"{op} {bound}", "met": bool(ok), **({"missing": True} if v is None else {})}
    return out


def session(out: Path, scene: Path, executions, idle_s: float, plan_calls: int, log) -> dict[str, Any]:
    b = Bench(out, scene)
    res: dict[str, Any] = {"scene": scene.name}
    try:
        log(f"graph up ({scene.name}); scanning")
        res["map_voxels"] = scan_plant(b.op, 0.6)
        if any(target is None for _, _, target in executions) or plan_calls > 0:
            wait_marker(b.op, (0.0, 25.0))      # the marker target is used
        if idle_s > 0:
            log(f"idle for {idle_s:g} s")
            res["idle"] = b.idle(idle_s)
        if plan_calls > 0:
            log(f"{plan_calls} /plan_reach calls")
            res["plan_wait_ms"] = b.plan_waits(plan_calls)
        res["executions"] = []
        b.op.spin_for(1.5)
        b.gaps.clear()              # joint-state gaps while executing (start-up and scan excluded)
        for name, arm, target in executions:
            log(f"execution {name} (and back)")
            for r in b.reach_and_return(name, arm, target):
                if "steps" not in r:
                    log(f"  {r['name']}: FAILED: {r['message']}")
                    res.setdefault("failed", []).append(r)
                    continue
                log(f"  {r['name']}: {r['steps']} steps, {r['overruns']} overruns, wall/duration "
                    f"{r['wall_over_duration']:.3f}, p99 {r['step_ms_p99']:.2f} ms, feet {r['feet_drift_mm']:.4f} mm, "
                    f"COG {r['com_drift_mm']:.3f} mm, "
                    f"hand {r.get('hand_error_final_mm', float('nan')):.3f} mm")
                res["executions"].append(r)
        res["joint_states_gap_ms_by_node"] = {**res.get("idle", {}).get("gaps", {}), **dict(b.gaps)}
    finally:
        res["exit_codes"] = b.close()
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--idle-s", type=float, default=20.0, help="idle measurement window [s] (>= 20 for the figure)")
    ap.add_argument("--plan-calls", type=int, default=30, help="/plan_reach calls for the operator wait (>= 30)")
    ap.add_argument("--out", default="out/bench_graph", help="logs and a copy of the JSON")
    ap.add_argument("--quick", action="store_true", help="smoke run: 5 s idle, 5 calls, 2 executions, no dense scene")
    ap.add_argument("--dense-only", action="store_true", help="only the dense scene's executions (diagnosis; no "
                    "idle, wait or plant figures)")
    args = ap.parse_args(argv)
    if args.idle_s < 0 or args.plan_calls < 0:
        ap.error("--idle-s and --plan-calls must be >= 0")
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)

    def log(text: str) -> None:
        print(f"[bench/graph] {text}", flush=True)

    plant_exec, dense_exec = PLANT_EXECUTIONS, DENSE_EXECUTIONS
    idle_s, calls = args.idle_s, args.plan_calls
    if args.quick:
        plant_exec, dense_exec, idle_s, calls = PLANT_EXECUTIONS[:2], [], min(idle_s, 5.0), min(calls, 5)
    t0 = time.monotonic()
    plant = session(out / "plant", config_path("scenes/plant.yaml"), plant_exec, idle_s, calls, log) \
        if not args.dense_only else {"executions": [], "joint_states_gap_ms_by_node": {}}
    dense = session(out / "dense", config_path("scenes/dense_pipes.yaml"), dense_exec, 0.0, 0, log) \
        if dense_exec else {"executions": [], "joint_states_gap_ms_by_node": {}}
    execs = plant["executions"] + dense["executions"]
    failed = plant.get("failed", []) + dense.get("failed", []) + [e for e in execs if not e["success"]]
    idle = plant.get("idle", {})
    cpu = idle.get("cpu", {})
    after = [t for e in execs for t in e["after_end_step_ms"]]
    waits = plant.get("plan_wait_ms", [])
    node_gaps = {**{k: v for k, v in dense["joint_states_gap_ms_by_node"].items()},
                 **{k: max(v, dense["joint_states_gap_ms_by_node"].get(k, 0.0))
                    for k, v in plant["joint_states_gap_ms_by_node"].items()}}
    product_gaps = {k: v for k, v in node_gaps.items() if k in PRODUCT}
    figures: dict[str, Any] = {
        "idle_cpu_pct": {k: round(v, 1) for k, v in cpu.items()},
        "idle_cpu_pct_product": round(sum(v for k, v in cpu.items() if k != "scene_sim"), 1) if cpu else None,
        "idle_cpu_pct_scene_sim": round(cpu["scene_sim"], 1) if "scene_sim" in cpu else None,
        "executions_failed_count": len(failed),
        "executions_failed": [{k: e[k] for k in ("name", "error_code", "message")} for e in failed],
        "executor_steps": sum(e["steps"] for e in execs),
        "executor_overruns": sum(e["overruns"] for e in execs),
        "executor_step_ms_p99": percentile([t for e in execs for t in e["run_step_ms"]], 99),
        "exec_wall_over_duration_max": max((e["wall_over_duration"] for e in execs), default=None),
        "feet_drift_measured_mm_max": max((e["feet_drift_mm"] for e in execs), default=None),
        "com_drift_measured_mm_max": max((e["com_drift_mm"] for e in execs), default=None),
        "hand_error_final_mm_max": max((e.get("hand_error_final_mm", 0.0) for e in execs), default=None),
        "hold_step_ms_p99": percentile(after, 99) if after else 0.0,
        "hold_steps": len(after),
        "plan_wait_ms_p50": percentile(waits, 50), "plan_wait_ms_p95": percentile(waits, 95),
        "plan_wait_ms_max": max(waits) if waits else None, "plan_calls": len(waits),
        "joint_states_max_gap_ms": max(product_gaps.values()) if product_gaps else None,
        "joint_states_gap_ms_by_node": {k: round(v, 1) for k, v in node_gaps.items()},
        "joint_states_max_gap_ms_probe": max([g for g in [idle.get("probe_gap_ms")]
                                              + [e["probe_gap_ms"] for e in execs] if g is not None], default=None),
        "idle_info_lines_per_min": max(idle.get("info_lines_per_min", {}).values(), default=None),
        "idle_info_lines_per_min_by_node": {k: round(v, 2) for k, v in idle.get("info_lines_per_min", {}).items()},
    }
    figures["executions"] = [{k: (round(v, 4) if isinstance(v, float) else v) for k, v in e.items()
                              if k not in ("after_end_step_ms", "run_step_ms")} for e in execs]
    figures["exit_codes"] = {"plant": plant.get("exit_codes", {}), "dense": dense.get("exit_codes", {})}
    figures["targets"] = judge(figures)
    figures["targets_met"] = all(t["met"] for t in figures["targets"].values())
    figures["bench"] = "graph"
    figures["machine"] = machine()
    figures["wall_s"] = round(time.monotonic() - t0, 1)
    text = json.dumps(figures)
    (out / "graph.json").write_text(json.dumps(figures, indent=2))
    for key, t in figures["targets"].items():
        log(f"{'ok  ' if t['met'] else 'MISS'} {key}: {t['value']} (target {t['target']})"
            + (" (not measured)" if t.get("missing") else ""))
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
