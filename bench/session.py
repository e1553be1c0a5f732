"""A session of reaches in the RUNNING graph (issue 21), as an operator types it.

Per session a fresh graph (bench/graph.py's ``Bench``: the six nodes as separate processes in
an isolated ROS domain, the measured ``/voxel_map`` as the map, nothing from the scene file),
then one operator's sequence, each step a ``reach_operator --json`` process (the CLI as a user
runs it):

1. ``--scan``;
2. the scene's steps (``SCENES``: each given target with why it is there), ``--target X Y Z
   --execute``: one that needs an automatic look (reachable, but in space nobody has seen:
   the operator looks there through ``/look`` ``gaze_points`` and plans again; checked with
   the JSON's ``auto_looks``) -- before the scan (issue 31: the scan sees everything in reach
   that a gaze can), so this one is step 1 and the scan step 2; ``--marker --execute`` where the head can see a marker
   (plant; dense_pipes' marker is hidden behind its upper pipe, two_valves and wide_pipes have
   none: skipped, and said why under ``scenes``); one target touching a surface (on or 1-2 cm
   in front of a pipe or a panel), so that the NEXT step starts with the hand in contact and
   must retreat first (as after the marker's or a valve's reach: the hand ends on the rim);
   plain ones;
3. ``--home --execute``: back to half-sitting (a retreat first when the hand rests on something).

Every plan gets ``--seed`` (session and step) and ``--budget 10`` (a cap: a plan ends when it
is found, so a loaded machine fails no feasible step for time), node defaults otherwise.

The operator process is the real CLI (``reach_operator.main``) started as ``python
bench/session.py --operator-child EVENTS -- <reach_operator args>``: the only addition is a
recorder around its ROS calls that writes, stamped (``time.monotonic()`` and ``time.time()``),
every /plan_reach request and response (the trajectory's samples, ``retreat``, ``unobserved_points``), every
/look (automatic ones included), every wait for a server and the /execute_reach goal to EVENTS
(JSON lines). Its stdout
(the ``--json`` summary), stderr and exit code are the user's.

Measured:

* **success** per step: exit code 0 and, with ``--execute``, the execution's success; the
  automatic-look step also needs ``auto_looks`` non-empty, each look successful; ``--home``
  also needs the robot at half-sitting afterwards (``HOME_TOL_RAD``, measured /joint_states).
* **retreats**: the step after a touching target, the marker's reach or a valve's must report a
  retreat (``PlanReach.retreat`` non-empty, the planner's "first a retreat" message);
  ``retreat_success_rate`` is over the steps where a retreat was expected or planned (a step
  may start in contact unplanned: a gaze that leaned the chest): succeeded with a retreat.
* **operator wait** (per reaching step: marker, targets, home), from the command's request
  reaching the graph to the motion's start, the motions themselves (the automatic looks)
  excluded: the sum of the step's /plan_reach calls (client side, request sent to response
  received: every call, the one that answered UNOBSERVED_SPACE before an automatic look
  included) + from the last response to the motion's start: the stamp of the motion's first
  executor step (its first ``/executor/metrics`` message, ``time_from_start_s < 0.2``, the
  first after the goal was sent; the stamp, not the receipt, as this bench's probe lags under
  load), against the child's system clock at the response. Where no such stamp is found the goal's
  sending time stands in (it shortens the wait): counted, ``motion_start_fallbacks``. A step that
  started no motion (its plan refused, no answer) waits its time to failure, first request to the
  CLI's end (``operator_waits_to_failure``): every reaching step is in the percentiles' denominator.
  Reported apart, not in the wait (they are the CLI process's, not the graph's): its start-up to
  the first request (Python, rclpy, discovery of /plan_reach: ``cli_startup_ms_p50``), its wait for the /execute_reach
  action server to be discovered after the plan (``execute_server_wait_ms_max``: a fresh
  process may not have discovered it yet when a plan comes back fast) and, for ``--marker``,
  its wait for a fresh ``/target_pose`` on the subscription it has just created
  (``marker_wait_ms_max``; a head turn toward the marker excluded).
* **trajectories outside the joint limits**: every trajectory /plan_reach returned, rebuilt
  as the executor rebuilds it (``SplineTrajectory(samples, times)`` in model joint order) and
  checked exactly (``check_limits(lower, upper)``: extrema of each cubic segment, tol 1e-12)
  against the URDF limits of the robot model.
* **executor refusals**: every INVALID_REQUEST result (executions, scans, looks, automatic looks)
  and every rejected goal.
* **overruns**: of every motion the executor ran (reaches, retreats, home, the scan's and the
  automatic looks' head poses), from the outcome line it logs for each, summed
  (``reach_overruns``: those of the reaching steps' execution results alone).
* **feet drift**: from every /joint_states of the session (scan to the end of home, joints
  settled), as bench/graph.py measures it (``graph_metrics.measured_balance``: the left sole
  in the right sole's frame, from the model's forward kinematics of the measured joints),
  max over the session against its first sample.

A missing figure (no step of its kind, a session without its joint states, fewer executor motions
logged than goals that ran, a step that never ran) is ``null`` and a missed target.

Last line: one JSON object: ``session_steps`` and the keys of ``TARGETS``, ``machine``,
``scenes`` (per scene: the marker step or why it was skipped, the targets with why, each
session's steps) and ``details`` (the targets judged, failed steps, the CLI's own waits).

Usage: ``python bench/session.py [--scenes plant dense_pipes ...] [--sessions 3] [--robot hrp2]
[--quick] [--out out/bench_session]``; ``--quick``: the plant, one session (the test suite's).
"""
from __future__ import annotations

import argparse
import contextlib
import json
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
for _p in (REPO, REPO / "bench"):
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))

BUDGET_S = 10.0             # --budget of every plan: a cap (a plan ends when found), so a loaded machine fails no step
STEP_TIMEOUT_S = 300.0       # one reach_operator process at most
HOME_TOL_RAD = 0.01          # after --home: every joint within this of half-sitting (measured, settled; the
                             # executor holds the exact COG of the motion's start, so the legs end up to 7 mrad off)
PLANT_HOME_TOL_RAD = 0.02   # the same on the physics plant: its servos hold joints up to 0.010 rad off their targets
                             # under gravity standing (docs/physics.md), so measured joints end that much further off
MOTION_START_TFS_S = 0.2     # the first /executor/metrics of a motion: time_from_start_s below this
READY_LOGS = {               # a node's log line once it serves (test_session's)
    "joint_driver": r"simulated \w+", "scene_sim": r"scene sensors ready", "voxel_mapper": r"voxel mapper ready",
    "marker_localizer": r"marker localizer ready", "reach_planner": r"reach planner ready",
    "reach_executor": r"reach executor ready"}
TARGETS = {   # key: (comparison, bound)
    "session_steps_succeeded_rate": ("==", 1.0), "retreat_success_rate": ("==", 1.0),
    "home_success_rate": ("==", 1.0), "auto_look_success_rate": (">=", 0.9),
    "trajectories_outside_limits": ("==", 0), "executor_refusals": ("==", 0),
    "session_feet_drift_measured_mm_max": ("<=", 0.1), "session_overruns": ("==", 0),
    "operator_wait_ms_p50": ("<=", 300.0), "operator_wait_ms_p95": ("<=", 1000.0),
}

MARKER = {"name": "marker", "kind": "marker", "why": "the valve's AR marker (--marker --execute): the hand ends on "
          "the valve's rim, the next step retreats first"}
# Per scene: the scene file, whether it has the valve's marker, and the steps between the scan
# and --home in the order of the session (MARKER: the marker's reach there), the given targets
# ([x, y, z] world, the valve WGR of eq. 3 around it: position fixed, roll/pitch within +-90 deg,
# yaw free). kind: "touch" (the next step starts in contact), "look" (needs an automatic look),
# "plain" ("contact": it ends on something too, a valve's rim). World frame: origin between the
# soles, x forward, y left; HRP-2 in half-sitting: shoulders (0.03, +-0.25, 1.27), hands hanging
# at (0.08, +-0.36, 0.63), head camera (0.11, 0, 1.45).
SCENES: dict[str, dict[str, Any]] = {
    "plant": {
        "scene": "scenes/plant.yaml", "marker": True,
        "targets": [
            {"name": "right_side", "kind": "look", "target": [0.20, -0.60, 1.00],
             "why": "beside the right shoulder, 81 deg right of the head, within the right arm's reach: the "
                    "first step, before the scan (the operator reaches at once; the plan names what it must see, "
                    "the operator looks there). Issue 31: after the scan nothing in reach that a gaze can see is "
                    "left unobserved (its gazes around the body see this target too; above the shoulders, where "
                    "no ray returns, nothing is ever observed), so the look step comes first"},
            MARKER,
            {"name": "passage_pipe_top", "kind": "touch", "target": [0.35, -0.15, 0.78],
             "why": "1 cm above the top of the passage pipe (axis x 0.35, z 0.72, radius 0.05), right of the "
                    "centre: the hand rests on the pipe; starts at the valve (the marker's reach): a retreat first"},
            {"name": "under_shoulder_pipe", "kind": "plain", "target": [0.50, 0.20, 1.08],
             "why": "under the left shoulder pipe (bench/graph.py's target); starts on the passage pipe: a "
                    "retreat first"},
        ]},
    "dense_pipes": {
        "scene": "scenes/dense_pipes.yaml", "marker": False,
        "marker_skipped": "the scene has a marker, but the head camera (1.45 m up, 0.64 m behind it) cannot see "
                          "it whole: the upper dense pipe (z 0.98-1.04 at x 0.60) hides all but its top 2 cm from "
                          "any head pose (the marker localizer never saw it in the scan; reach_operator --marker, "
                          "which turns the head only, waits 15 s and ends NO_INPUT (6))",
        "targets": [
            {"name": "right_side", "kind": "look", "target": [0.20, -0.60, 1.00],
             "why": "beside the right shoulder: not seen by the scan, within the right arm's reach (first: see "
                    "plant)"},
            {"name": "valve", "kind": "plain", "contact": True, "target": [0.71, 0.03, 0.90],
             "why": "the valve's centre between the dense pipes, given (bench/graph.py's dense target: the marker "
                    "is hidden); ends with the hand on the rim: a retreat first next"},
            {"name": "dense_lower_pipe_top", "kind": "touch", "target": [0.60, -0.20, 0.83],
             "why": "1 cm above the top of the dense lower pipe (axis x 0.60, z 0.79, radius 0.03), right of the "
                    "valve: the hand rests on it"},
            {"name": "over_passage_pipe", "kind": "plain", "target": [0.45, -0.22, 0.86],
             "why": "above the passage pipe, in front of the dense pipes (bench/graph.py's target); starts on "
                    "the lower pipe: a retreat first"},
        ]},
    "two_valves": {
        "scene": "scenes/two_valves.yaml", "marker": False,
        "targets": [
            {"name": "left_side", "kind": "look", "target": [0.20, 0.60, 1.00],
             "why": "beside the left shoulder: not seen by the scan, within the left arm's reach (first: see "
                    "plant)"},
            {"name": "panel_face", "kind": "touch", "target": [0.645, -0.20, 1.10],
             "why": "1.5 cm in front of the panel's face (x 0.66), between the valves above the pipe: the hand "
                    "rests against the panel"},
            {"name": "right_valve", "kind": "plain", "contact": True, "target": [0.45, -0.50, 0.95],
             "why": "the right valve's centre (suite case two_valves_right); starts at the panel: a retreat first; "
                    "ends with the hand on the rim"},
            {"name": "left_valve", "kind": "plain", "contact": True, "target": [0.45, 0.50, 0.95],
             "why": "the left valve's centre (suite case two_valves_left: the left arm); starts on the right "
                    "valve: a retreat first"},
        ]},
    "wide_pipes": {
        "scene": "scenes/wide_pipes.yaml", "marker": False,
        "targets": [
            {"name": "right_side", "kind": "look", "target": [0.20, -0.60, 1.00],
             "why": "beside the right shoulder: not seen by the scan, within the right arm's reach (first: see "
                    "plant)"},
            {"name": "lower_pipe_top", "kind": "touch", "target": [0.55, 0.05, 0.89],
             "why": "1 cm above the top of the lower pipe (axis x 0.55, z 0.85, radius 0.03), left of the "
                    "valve: the hand rests on it"},
            {"name": "below_the_pipes", "kind": "plain", "target": [0.40, -0.10, 0.75],
             "why": "in front of and below the lower pipe; starts on the pipe: a retreat first"},
            {"name": "valve", "kind": "plain", "contact": True, "target": [0.63, -0.05, 1.00],
             "why": "the valve's centre between the pipes (24 cm gap; suite case wide_pipes); ends with the hand "
                    "on the rim: home retreats first"},
        ]},
}
QUICK_SCENE = "plant"
REQUIRED_KEYS = ("session_steps", "session_steps_succeeded_rate", "retreat_success_rate", "home_success_rate",
                 "auto_look_success_rate", "trajectories_outside_limits", "executor_refusals",
                 "session_feet_drift_measured_mm_max", "session_overruns", "operator_wait_ms_p50",
                 "operator_wait_ms_p95")


# ---------------------------------------------------------------- the operator process (child)
def operator_child(events_path: str, argv: list[str]) -> int:
    """``reach_operator.main(argv)`` with a recorder around its ROS calls (module doc)."""
    from humanoid_reach_ros.nodes import reach_operator as ro

    out = open(events_path, "a", encoding="utf-8")

    def emit(event: str, **kw: Any) -> None:
        out.write(json.dumps({"event": event, "t": time.monotonic(), "wall": time.time(), **kw}) + "\n")
        out.flush()

    def response(resp: Any) -> dict[str, Any]:
        tr = resp.trajectory
        return {"error_code": int(resp.error_code.val), "success": bool(resp.success), "message": resp.message,
                "retreat": resp.retreat, "arm": int(resp.arm),
                "unobserved_points": [[p.x, p.y, p.z] for p in resp.unobserved_points],
                "total_time_s": float(resp.statistics.total_time_s),
                "joint_names": list(tr.joint_names),
                "times": [p.time_from_start.sec + p.time_from_start.nanosec * 1e-9 for p in tr.points],
                "positions": [list(p.positions) for p in tr.points]}

    init, plan = ro.Operator.__init__, ro.Operator.plan

    def recording_init(self: Any, *a: Any, **k: Any) -> None:
        init(self, *a, **k)
        call, send = self.plan_client.call_async, self.exec_client.send_goal_async

        def call_async(req: Any) -> Any:
            emit("plan_sent", home=bool(req.home), marker=bool(req.use_marker_target))
            return call(req)

        def send_goal_async(goal: Any, **kw: Any) -> Any:
            emit("execute_sent")
            return send(goal, **kw)
        self.plan_client.call_async = call_async
        self.exec_client.send_goal_async = send_goal_async
    ro.Operator.__init__ = recording_init

    def recording_plan(self: Any, req: Any) -> Any:
        resp = plan(self, req)    # returns as soon as the response is in (spin_until(future.done))
        if resp is not None:
            emit("plan_response", **response(resp))
        return resp
    ro.Operator.plan = recording_plan

    wait_for_server = ro.Operator.wait_for_server

    def recording_wait_for_server(self: Any, ready: Any, name: str, owner: str) -> bool:
        emit("server_wait_start", name=name)
        up = wait_for_server(self, ready, name, owner)
        emit("server_wait_end", name=name, up=bool(up))
        return up
    ro.Operator.wait_for_server = recording_wait_for_server

    look = ro.Operator.look

    def recording_look(self: Any, *a: Any, **k: Any) -> Any:
        emit("look_start", gaze=(k.get("gaze_points") if "gaze_points" in k else (a[4] if len(a) > 4 else None))
             is not None)
        outcome, result = look(self, *a, **k)
        emit("look_end", outcome=outcome, error_code=None if result is None else int(result.error_code.val))
        return outcome, result
    ro.Operator.look = recording_look

    marker = ro.OperatorSession.ensure_marker_target

    def recording_marker(*a: Any, **k: Any) -> int:
        emit("marker_start")
        code = marker(*a, **k)
        emit("marker_end", code=int(code))
        return code
    ro.OperatorSession.ensure_marker_target = recording_marker
    try:
        return ro.main(["reach_operator", *argv])
    finally:
        out.close()


# ---------------------------------------------------------------- the graph and the probe (parent)
def stop_on_signals() -> None:
    """SIGINT and SIGTERM raise KeyboardInterrupt, so that a session's ``finally`` stops its graph."""
    def interrupt(*_: Any) -> None:
        raise KeyboardInterrupt
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, interrupt)


@contextlib.contextmanager
def _graph_for_robot(robot: str | None, plant: str | None = None, scene: Path | None = None,
                     node_params: dict[str, dict[str, Any]] | None = None):
    """bench/graph.py's ``Bench`` starts each node with its YAML file and a few parameters, with
    no robot or plant option: while it starts, its ``Graph`` adds ``launch_params(name, robot=...,
    plant=...)`` (the physics plant standing in the session's scene) and ``node_params[name]``."""
    import graph as bench_graph
    from humanoid_reach_ros.graph import Graph, launch_params

    if robot is None and plant is None and not node_params:
        yield
        return

    class RobotGraph(Graph):
        def start(self, module: str, params: dict[str, Any] | None = None):
            extra = launch_params(module, None, robot, plant)
            if "physics_scene" not in extra and plant is not None and module == "joint_driver":
                extra["physics_scene"] = str(scene)
            return super().start(module, {**(params or {}), **extra, **(node_params or {}).get(module, {})})
    saved = bench_graph.Graph
    bench_graph.Graph = RobotGraph
    try:
        yield
    finally:
        bench_graph.Graph = saved


class Session:
    """One graph (bench/graph.py's ``Bench``) and this bench's probe: /joint_states over the
    whole session, /executor/metrics receipt times."""

    def __init__(self, out: Path, scene: Path, robot: str | None, log, plant: str | None = None,
                 node_params: dict[str, dict[str, Any]] | None = None) -> None:
        from graph import Bench

        self.out, self.log = out, log
        self.plant = plant
        self.plant_metrics: list[Any] = []    # /physics/metrics (plant mujoco), every message
        self.bench = Bench.__new__(Bench)
        try:
            with _graph_for_robot(robot, plant, scene, node_params):
                self.bench.__init__(out, scene)
        except BaseException:    # the nodes did not come up: stop those that did
            for name in ("op", "graph", "lease"):
                part = getattr(self.bench, name, None)
                if part is not None:
                    with contextlib.suppress(Exception):
                        (part.stop if name == "graph" else part.close if name == "op" else part.release)()
            raise
        self.op = self.bench.op
        stop_on_signals()    # rclpy.init (the probe's) took SIGINT over: the graph must be stopped on Ctrl-C
        try:
            self._ready(robot)
        except BaseException:
            self.close()
            raise

    def _ready(self, robot: str | None) -> None:
        from humanoid_reach_interfaces.msg import ExecutorMetrics
        from humanoid_reach_ros.robot.model import RobotModel

        self.robot = RobotModel(robot) if robot else RobotModel()
        self.bench.robot = self.robot
        for p in self.bench.graph.procs:
            p.wait_for_log(READY_LOGS[p.name], 180.0)
        self.metric_starts: list[float] = []     # stamps [s, system clock] of the steps that start a motion
        self._last_tfs = float("inf")

        def on_metrics(m: ExecutorMetrics) -> None:
            if m.time_from_start_s < MOTION_START_TFS_S and not self._last_tfs < MOTION_START_TFS_S:
                self.metric_starts.append(m.header.stamp.sec + m.header.stamp.nanosec * 1e-9)
            self._last_tfs = m.time_from_start_s
        self.op.node.create_subscription(ExecutorMetrics, "/executor/metrics", on_metrics, 400)
        if self.plant == "mujoco":
            from humanoid_reach_interfaces.msg import PlantMetrics
            self.op.node.create_subscription(PlantMetrics, "/physics/metrics", self.plant_metrics.append, 200)
        self.op.spin_until(lambda: self.op.joint_states is not None, 30.0, "/joint_states")
        self.op.samples.clear()
        self.op.recording = True                 # every /joint_states from here on

    def close(self) -> dict[str, int]:
        return self.bench.close()

    def run_operator(self, args: list[str], tag: str) -> dict[str, Any]:
        """One ``reach_operator --json`` process (module doc), the probe spinning meanwhile."""
        events = self.out / f"{tag}.events.jsonl"
        stdout, stderr = self.out / f"{tag}.stdout", self.out / f"{tag}.stderr"
        cmd = [sys.executable, str(Path(__file__).resolve()), "--operator-child", str(events), "--", *args, "--json"]
        t0 = time.monotonic()
        with open(stdout, "wb") as so, open(stderr, "wb") as se:
            proc = subprocess.Popen(cmd, stdout=so, stderr=se, stdin=subprocess.DEVNULL, env=self.bench.graph.env,
                                    cwd=REPO)
            try:
                while proc.poll() is None:
                    self.op.executor.spin_once(timeout_sec=0.005)
                    if time.monotonic() - t0 > STEP_TIMEOUT_S:
                        proc.kill()
                        proc.wait(10.0)
                        break
                    self.bench.graph.check_alive()
            finally:
                if proc.poll() is None:
                    proc.kill()
                    proc.wait(10.0)
        t1 = time.monotonic()
        self.op.spin_for(0.05)
        self.op.metrics.clear()                  # demo.Operator keeps every /executor/metrics: not needed here
        lines = stdout.read_text().strip().splitlines()
        try:
            summary = json.loads(lines[-1]) if lines else {}
        except json.JSONDecodeError:
            summary = {}
        evs = [json.loads(line) for line in events.read_text().splitlines()] if events.exists() else []
        return {"args": args, "exit_code": proc.returncode, "summary": summary, "events": evs, "t_start": t0,
                "t_end": t1, "stderr": stderr.read_text(errors="replace")}

    def settle(self, timeout: float = 20.0) -> None:
        """Until the measured joints stop moving (20 samples within 1e-5 rad)."""
        def settled() -> bool:
            s = self.op.samples
            if len(s) < 20:
                return False
            a, b = np.array(s[-20].position), np.array(s[-1].position)
            return a.shape == b.shape and float(np.max(np.abs(a - b))) < 1e-5
        self.op.spin_until(settled, timeout, "the measured joints to settle")

    def joints_now(self) -> np.ndarray:
        from humanoid_reach_ros.io import msgs
        j, why = msgs.model_joints(self.op.joint_states, self.robot)
        if j is None:
            raise RuntimeError(f"a joint state is unusable: {why}")
        return j

    def joint_series(self) -> tuple[np.ndarray, list[int]]:
        """The session's measured joints (model order, usable messages only) and, per recorded
        message, its index in that series (for the steps' boundaries)."""
        from humanoid_reach_ros.io import msgs
        series, index = [], []
        for m in self.op.samples:
            index.append(len(series))
            j, _ = msgs.model_joints(m, self.robot)
            if j is not None:
                series.append(j)
        return np.array(series).reshape(-1, self.robot.n_joints), index


def session_drift(robot, series: np.ndarray, spans: list[tuple[int, int]]) -> dict[str, Any]:
    """bench/graph.py's measure (``graph_metrics.measured_balance``) over the whole session and,
    per step, over its samples, both against the session's first sample."""
    from humanoid_reach_ros.testing.graph_metrics import measured_balance
    if not len(series):
        return {"feet_drift_mm": None, "com_drift_mm": None, "per_step_feet_drift_mm": []}
    whole = measured_balance(robot, series)
    steps = [measured_balance(robot, np.vstack([series[:1], series[a:b]]))["feet_drift_mm"] if b > a else 0.0
             for a, b in spans]
    return {"feet_drift_mm": whole["feet_drift_mm"], "com_drift_mm": whole["com_drift_mm"],
            "per_step_feet_drift_mm": steps}


# ---------------------------------------------------------------- one step's figures
def limits_check(robot, resp: dict[str, Any]) -> dict[str, Any] | None:
    """The executor's rebuild of a returned trajectory, checked exactly against the URDF limits;
    None when the response carried no trajectory."""
    from humanoid_reach_ros.geometry.trajectory import SplineTrajectory
    if not resp["times"]:
        return None
    names = resp["joint_names"]
    pos = np.asarray(resp["positions"], float)[:, [names.index(n) for n in robot.joint_names]]
    t = np.asarray(resp["times"], float)
    v = SplineTrajectory(pos, t - t[0]).check_limits(robot.lower, robot.upper)
    out = {"points": len(t), "outside": v is not None}
    if v is not None:
        out["violation"] = {"joint": robot.joint_names[v.joint], "time_s": v.time, "value": v.value,
                            "limits": [float(robot.lower[v.joint]), float(robot.upper[v.joint])]}
    return out


def step_figures(sess: Session, kind: str, run: dict[str, Any]) -> dict[str, Any]:
    s, evs = run["summary"], run["events"]
    plans = [e for e in evs if e["event"] in ("plan_sent", "plan_response")]
    sent = [e["t"] for e in plans if e["event"] == "plan_sent"]
    responses = [e for e in plans if e["event"] == "plan_response"]
    plan_s = sum(r["t"] - t for t, r in zip(sent, responses))
    ex = s.get("execution") or {}
    looks_all = [x for x in [s.get("look")] + list(s.get("auto_looks") or []) if x]
    fig: dict[str, Any] = {
        "kind": kind, "args": run["args"], "exit_code": run["exit_code"],
        "plan_calls": len(responses),
        "plan_codes": [r["error_code"] for r in responses],
        "plan_message": (s.get("plan") or {}).get("message"),
        "retreat": next((r["retreat"] for r in reversed(responses) if r["success"]), "") if responses else "",
        "auto_looks": len(s.get("auto_looks") or []),
        "auto_looks_ok": all(x.get("success") for x in (s.get("auto_looks") or [])),
        "looks_ok": sum(1 for x in looks_all if x.get("success")),   # looks that ran (session_motions)
        "execution": {k: ex.get(k) for k in ("outcome", "success", "error_name", "message", "duration_s", "steps",
                                             "overruns", "final_hand_error_m", "min_distance_m")} if ex else None,
        "overruns": int(ex.get("overruns") or 0),
        "refusals": sum(1 for x in [ex] + looks_all if x.get("error_name") == "INVALID_REQUEST")
        + sum(1 for x in [ex] + looks_all if x.get("outcome") == "rejected"),
        "limits": [c for c in (limits_check(sess.robot, r) for r in responses) if c is not None],
    }
    first = min([e["t"] for e in evs if e["event"] in ("plan_sent", "marker_start")], default=None)
    fig["cli_startup_ms"] = None if first is None else (first - run["t_start"]) * 1e3
    success = run["exit_code"] == 0 and bool(s)
    if kind != "scan":
        success = success and bool(ex.get("success"))
        # operator wait: the plan calls + from the last response to the motion's start (module doc)
        wait = plan_s
        ms = [e["t"] for e in evs if e["event"] == "marker_start"]
        me = [e["t"] for e in evs if e["event"] == "marker_end"]
        if ms and me:   # --marker: the wait for a fresh /target_pose, its head turn excluded (apart)
            turns = [(a["t"], b["t"]) for a, b in zip([e for e in evs if e["event"] == "look_start"],
                                                       [e for e in evs if e["event"] == "look_end"])
                     if ms[0] <= a["t"] <= me[0]]
            fig["marker_wait_ms"] = ((me[0] - ms[0]) - sum(b - a for a, b in turns)) * 1e3
            fig["marker_head_turn"] = bool(turns)
        sent_exec = next((e["wall"] for e in evs if e["event"] == "execute_sent"), None)
        if sent_exec is not None and responses:
            # the motion's first executor step, by its own stamp (the system clock, as the child's "wall")
            start = next((t for t in sess.metric_starts if t >= sent_exec - 0.002), None)
            # a fallback (no executor step stamp: the goal's sending time, which shortens the wait) is counted
            fig["motion_start_from"] = "executor_metrics_stamp" if start is not None else "goal_sent"
            if start is None:
                start = sent_exec
            # the CLI's discovery of /execute_reach in that window (a fresh process's, apart)
            ws = [e for e in evs if e["event"] == "server_wait_start" and e["name"] == "/execute_reach"]
            we = [e for e in evs if e["event"] == "server_wait_end" and e["name"] == "/execute_reach"]
            discovery = sum(b["t"] - a["t"] for a, b in zip(ws, we) if a["t"] >= responses[-1]["t"])
            fig["execute_server_wait_ms"] = discovery * 1e3
            fig["response_to_motion_ms"] = (start - responses[-1]["wall"]) * 1e3
            wait += start - responses[-1]["wall"] - discovery
            fig["operator_wait_ms"] = wait * 1e3
            fig["plan_ms"] = plan_s * 1e3
        else:
            # no motion started (a refused plan, no answer, a rejected goal): the step's wait is its time to
            # failure, from its first request (or the CLI's start, when none was sent) to the CLI's end
            fig["operator_wait_ms"] = (run["t_end"] - (sent[0] if sent else run["t_start"])) * 1e3
            fig["wait_to_failure"] = True
    if kind == "look":
        success = success and fig["auto_looks"] > 0 and fig["auto_looks_ok"]
    fig["success"] = bool(success)
    if not success or run["exit_code"] != 0:
        fig["stderr_tail"] = run["stderr"].strip().splitlines()[-12:]
    return fig


def failed_step(name: str, why: str) -> dict[str, Any]:
    """A step that could not run (the graph did not come up, a wait timed out): counted failed."""
    return {"name": name, "kind": name, "args": [], "exit_code": None, "success": False, "plan_calls": 0,
            "plan_codes": [], "retreat": "", "retreat_expected": False, "auto_looks": 0, "auto_looks_ok": True,
            "execution": None, "overruns": 0, "refusals": 0, "limits": [], "stderr_tail": why.splitlines()[-12:]}


# ---------------------------------------------------------------- a session
def run_session(out: Path, scene_name: str, seed: int, robot: str | None, log, plant: str | None = None,
                scene_steps: dict[str, Any] | None = None,
                node_params: dict[str, dict[str, Any]] | None = None) -> dict[str, Any]:
    """One session (module doc) on ``plant`` (None: joint_driver's YAML, kinematic); with
    ``mujoco`` the result's ``physics`` holds the plant's figures (sim/physics/summary.py).
    ``scene_steps``: the scene's entry of SCENES to use instead; ``node_params``: parameters per node on
    top of their YAML files (bench/physics.py's stress session)."""
    from humanoid_reach_ros.paths import config_path

    spec = scene_steps or SCENES[scene_name]
    shutil.rmtree(out, ignore_errors=True)    # this session's logs and events only
    out.mkdir(parents=True, exist_ok=True)
    res: dict[str, Any] = {"scene": scene_name, "seed": seed, "steps": []}
    t0 = time.monotonic()
    sess = Session(out, config_path(spec["scene"]), robot, log, plant, node_params)
    res["graph_up_s"] = round(time.monotonic() - t0, 1)
    spans: list[tuple[int, int]] = []     # each step's /joint_states (recorded messages)
    try:   # the graph is stopped whatever happens, Ctrl-C (KeyboardInterrupt) included
        try:
            # (name, kind, args, whether the hand ends on something: the next step must retreat first)
            # the step that needs an automatic look comes before the scan (issue 31: the scan now sees
            # everything in reach that a gaze can, 6-12 cm around the body included)
            plan_steps: list[tuple[str, str, list[str], bool]] = []
            looks = [t for t in spec["targets"] if t["kind"] == "look"]
            for tgt in looks + [{"kind": "scan"}] + [t for t in spec["targets"] if t["kind"] != "look"]:
                if tgt["kind"] == "scan":
                    plan_steps.append(("scan", "scan", ["--scan"], False))
                    continue
                if tgt["kind"] == "marker":
                    args = ["--marker", "--execute"]
                else:
                    args = ["--target", *(f"{v:g}" for v in tgt["target"]), "--execute"] + list(tgt.get("args", []))
                plan_steps.append((tgt["name"], tgt["kind"], args, tgt["kind"] in ("touch", "marker")
                                   or bool(tgt.get("contact"))))
            plan_steps.append(("home", "home", ["--home", "--execute"], False))
            in_contact = False       # the last step that moved the robot ended with the hand on something
            for k, (name, kind, args, contact_after) in enumerate(plan_steps):
                if kind != "scan":
                    args = [*args, "--seed", str(seed * 100 + k), "--budget", f"{BUDGET_S:g}"]
                i0 = len(sess.op.samples)
                run = sess.run_operator(args, f"{k:02d}_{name}")
                fig = step_figures(sess, kind, run)
                fig["name"] = name
                fig["retreat_expected"] = retreat_expected = in_contact
                if fig["success"]:
                    in_contact = contact_after
                if kind == "home":
                    sess.settle()
                    err = np.abs(sess.joints_now() - sess.robot.half_sitting_joints)
                    fig["home_joint_error_mrad"] = float(err.max() * 1e3)
                    fig["home_joint_error_worst"] = sess.robot.joint_names[int(np.argmax(err))]
                    fig["success"] = fig["success"] and float(err.max()) <= (
                        PLANT_HOME_TOL_RAD if plant == "mujoco" else HOME_TOL_RAD)
                spans.append((i0, len(sess.op.samples)))
                res["steps"].append(fig)
                wait = fig.get("operator_wait_ms")
                log(f"  {name:24s} {'ok  ' if fig['success'] else 'FAIL'} exit {fig['exit_code']} plans "
                    f"{fig['plan_codes']} looks {fig['auto_looks']} retreat {'yes' if fig['retreat'] else 'no'}"
                    f"{' (expected)' if retreat_expected else ''} wait "
                    f"{'-' if wait is None else f'{wait:.0f} ms'}"
                    + (f" home error {fig['home_joint_error_mrad']:.2f} mrad" if kind == "home" else ""))
                if not fig["success"]:
                    for line in fig.get("stderr_tail", []):
                        log(f"      | {line}")
            sess.settle()
        except (RuntimeError, AssertionError, TimeoutError, subprocess.SubprocessError) as exc:
            log(f"  session failed: {exc}")
            res["error"] = str(exc)[-3000:]
            res["steps"].append(failed_step("session", str(exc)))
        series, index = sess.joint_series()
        idx = index + [len(series)]
        drift = session_drift(sess.robot, series, [(idx[a], idx[b]) for a, b in spans])
        for st, d in zip(res["steps"], drift.pop("per_step_feet_drift_mm")):
            st["feet_drift_mm_max"] = d
        res.update(drift, joint_state_samples=len(series))
        if plant == "mujoco":
            from humanoid_reach_ros.sim.physics.summary import plant_figures
            sess.op.spin_for(0.1)
            res["physics"] = plant_figures(sess.plant_metrics)
        np.savez_compressed(out / "joint_states.npz", joints=series, step_spans=np.array(
            [(idx[a], idx[b]) for a, b in spans]).reshape(-1, 2))
    finally:
        res["exit_codes"] = sess.close()
    res.update(executor_motion_overruns(out))
    res["wall_s"] = round(time.monotonic() - t0, 1)
    return res


def session_motions(sessions: list[dict[str, Any]]) -> dict[str, Any]:
    """The goals that ran per session (executions, the scan or look, automatic looks, each successful)
    against the motions the executor logged (``executor_motion_overruns``): ``complete`` when every
    session logged at least as many (a session without its log, or with fewer lines, is not)."""
    expected, complete = 0, True
    for s in sessions:
        ran = sum(bool((st.get("execution") or {}).get("success")) for st in s["steps"]) + sum(
            st.get("looks_ok", 0) for st in s["steps"])
        expected += ran
        complete = complete and "executor_motions" in s and s["executor_motions"] >= ran
    return {"expected": expected, "complete": complete}


MOTION_LINE = re.compile(r"\[[\d.]+ s, (\d+) steps, (\d+) overruns")


def executor_motion_overruns(out: Path) -> dict[str, int]:
    """Every motion the executor ran in the session (goals, scans, looks, automatic looks), from
    the outcome line it logs for each (``[2.99 s, 593 steps, 0 overruns, ...]``)."""
    steps = overruns = motions = 0
    for log in out.glob("reach_executor.*.log"):
        for m in MOTION_LINE.finditer(log.read_text(errors="replace")):
            motions += 1
            steps += int(m.group(1))
            overruns += int(m.group(2))
    return {"executor_motions": motions, "executor_steps": steps, "executor_overruns": overruns}


# ---------------------------------------------------------------- the figures
def judge(figures: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """This bench's ``TARGETS``, judged as bench/graph.py judges its own."""
    import graph as bench_graph
    return bench_graph.judge(figures, TARGETS)


def summarize(sessions: list[dict[str, Any]]) -> dict[str, Any]:
    from humanoid_reach_ros.testing.graph_metrics import percentile

    steps = [st for s in sessions for st in s["steps"]]
    retreat_steps = [st for st in steps if st["retreat_expected"] or st["retreat"]]
    homes = [st for st in steps if st["kind"] == "home"]
    looks = [st for st in steps if st["kind"] == "look" or st["auto_looks"]]
    # every step but the scan waits for a motion (a failed one: its time to failure, step_figures); a step
    # that never ran (failed_step: the graph or the session broke) has no wait: the figure is missing
    reaching = [st for st in steps if st["kind"] != "scan"]
    waits = [st["operator_wait_ms"] for st in reaching if st.get("operator_wait_ms") is not None]
    waits_ok = bool(reaching) and len(waits) == len(reaching)
    cli = [st["cli_startup_ms"] for st in steps if st.get("cli_startup_ms") is not None]
    marker = [st["marker_wait_ms"] for st in steps if st.get("marker_wait_ms") is not None]
    disc = [st["execute_server_wait_ms"] for st in steps if st.get("execute_server_wait_ms") is not None]
    checks = [c for st in steps for c in st["limits"]]
    drifts = [s.get("feet_drift_mm") for s in sessions]
    motions = session_motions(sessions)

    def rate(sel: list[dict[str, Any]], ok) -> float | None:
        return round(sum(1 for x in sel if ok(x)) / len(sel), 4) if sel else None
    return {
        "session_steps": len(steps),
        "session_steps_succeeded_rate": rate(steps, lambda x: x["success"]),
        "retreat_success_rate": rate(retreat_steps, lambda x: x["success"] and bool(x["retreat"])),
        "home_success_rate": rate(homes, lambda x: x["success"]),
        "auto_look_success_rate": rate(looks, lambda x: x["success"] and x["auto_looks"] > 0 and x["auto_looks_ok"]),
        # none checked (no plan came back) or no step ran: not measured
        "trajectories_outside_limits": sum(1 for c in checks if c["outside"]) if checks else None,
        "executor_refusals": (sum(st["refusals"] for st in steps)
                              if any(st["exit_code"] is not None for st in steps) else None),
        # every session's (one without its measured joints: missing)
        "session_feet_drift_measured_mm_max": (round(max(drifts), 5) if drifts and None not in drifts else None),
        # every motion's, looks and scans included (the executor's log), not only the reaches'; missing when
        # the log shows fewer motions than the goals that ran (session_motions)
        "session_overruns": (sum(s["executor_overruns"] for s in sessions) if sessions and motions["complete"]
                             else None),
        "operator_wait_ms_p50": round(percentile(waits, 50), 1) if waits_ok else None,
        "operator_wait_ms_p95": round(percentile(waits, 95), 1) if waits_ok else None,
        # context
        "operator_wait_ms_max": round(max(waits), 1) if waits else None,
        "operator_waits": len(waits), "operator_wait_steps": len(reaching),
        "operator_waits_to_failure": sum(1 for st in reaching if st.get("wait_to_failure")),
        "motion_start_fallbacks": sum(1 for st in steps if st.get("motion_start_from") == "goal_sent"),
        "executor_motions_expected": motions["expected"],
        "trajectories_checked": len(checks),
        "retreat_steps": len(retreat_steps), "home_steps": len(homes), "auto_look_steps": len(looks),
        "reach_overruns": sum(st["overruns"] for st in steps),
        "executor_motions": sum(s.get("executor_motions", 0) for s in sessions),
        "executor_steps": sum(s.get("executor_steps", 0) for s in sessions),
        "cli_startup_ms_p50": round(percentile(cli, 50), 1) if cli else None,
        "cli_startup_ms_max": round(max(cli), 1) if cli else None,
        "marker_wait_ms_max": round(max(marker), 1) if marker else None,
        "execute_server_wait_ms_max": round(max(disc), 1) if disc else None,
        "failed_steps": [{"scene": s["scene"], "seed": s["seed"], "step": st["name"], "exit_code": st["exit_code"],
                          "plan_codes": st["plan_codes"], "auto_looks": st["auto_looks"],
                          "retreat": bool(st["retreat"]),
                          "execution": (st.get("execution") or {}).get("error_name"),
                          "home_joint_error_mrad": st.get("home_joint_error_mrad"),
                          "stderr_tail": st.get("stderr_tail", [])[-4:]}
                         for s in sessions for st in s["steps"] if not st["success"]],
    }


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--operator-child"]:
        rest = argv[2:]
        return operator_child(argv[1], rest[1:] if rest[:1] == ["--"] else rest)
    from humanoid_reach_ros.testing.machine import describe as machine
    from humanoid_reach_ros.robot.spec import robots

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", nargs="+", choices=tuple(SCENES), default=list(SCENES), help="scenes to run")
    ap.add_argument("--sessions", type=int, default=3, help="sessions per scene (fresh graph, own seed) (default 3)")
    ap.add_argument("--robot", choices=robots(), default=None, help="robot_config of every node (default the YAML "
                    "files')")
    ap.add_argument("--plant", choices=("kinematic", "mujoco"), default=None, help="joint_driver's plant (default "
                    "its YAML's, kinematic); mujoco: the physics plant in the session's scene (bench/physics.py "
                    "judges its figures)")
    ap.add_argument("--seed-base", type=int, default=1, help="session k of a scene uses seed base + k")
    ap.add_argument("--quick", action="store_true", help=f"one scene ({QUICK_SCENE}), one session")
    ap.add_argument("--out", default="out/bench_session", help="logs, events and a copy of the JSON")
    args = ap.parse_args(argv)
    if args.sessions < 1:
        ap.error("--sessions must be >= 1")
    scenes, n = (([QUICK_SCENE], 1) if args.quick else (args.scenes, args.sessions))
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)

    def log(text: str) -> None:
        print(f"[bench/session] {text}", flush=True)

    t0 = time.monotonic()
    sessions = []
    stop_on_signals()
    for scene in scenes:
        for k in range(n):
            seed = args.seed_base + k
            log(f"{scene}, session {k + 1}/{n} (seed {seed}): graph up ...")
            try:
                s = run_session(out / f"{scene}_s{seed}", scene, seed, args.robot, log, args.plant)
            except (RuntimeError, AssertionError, TimeoutError) as exc:   # the graph did not come up
                log(f"  session failed: {exc}")
                s = {"scene": scene, "seed": seed, "steps": [failed_step("graph", str(exc))],
                     "error": str(exc)[-3000:]}
            sessions.append(s)
            log(f"  feet drift {s.get('feet_drift_mm', float('nan')):.5f} mm over {s.get('joint_state_samples')} "
                f"joint states; {s.get('wall_s')} s")
    figures = summarize(sessions)
    required = {k: figures.pop(k) for k in REQUIRED_KEYS}
    for s in sessions:   # per step: the trajectories' checks as counts (and any violation)
        for st in s["steps"]:
            st["limits"] = {"trajectories": len(st["limits"]),
                            "violations": [c["violation"] for c in st["limits"] if c["outside"]]}
    per_scene = {sc: {"marker": "reached (--marker --execute)" if SCENES[sc]["marker"] else
                      "skipped: " + SCENES[sc].get("marker_skipped", "the scene has no marker"),
                      "targets": [t for t in SCENES[sc]["targets"] if t["kind"] != "marker"],
                      "sessions": [s for s in sessions if s["scene"] == sc]} for sc in scenes}
    judged = judge(required)
    result = {**required, "machine": machine(), "scenes": per_scene, "details": {
        **figures, "targets": judged,
        "targets_met": all(t["met"] for t in judged.values()),
        "session_errors": [{"scene": s["scene"], "seed": s["seed"], "error": s["error"]}
                           for s in sessions if "error" in s],
        "robot": args.robot or "the config YAML files' (hrp2)", "sessions_per_scene": n,
        "bench": "session", "wall_s": round(time.monotonic() - t0, 1)}}
    (out / "session.json").write_text(json.dumps(result, indent=2))
    for key, t in judged.items():
        log(f"{'ok  ' if t['met'] else 'MISS'} {key}: {t['value']} (target {t['target']})"
            + (" (not measured)" if t.get("missing") else ""))
    log(f"waits: {figures['operator_waits_to_failure']} of {figures['operator_wait_steps']} to a failure, "
        f"{figures['motion_start_fallbacks']} motion start(s) from the goal's sending (no executor step stamp)")
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
