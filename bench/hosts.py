"""The operator's flow across three hosts, and link faults (issue 24; docs/deployment.md).

``tools/hosts.sh up`` (three network namespaces on a bridge: <P>_robot 10.231.0.1, <P>_compute .2,
<P>_operator .3, <P> the prefix ``tools/hosts.sh names`` prints, below hr_<host>; links 1 Gbit/s,
the operator's 20 Mbit/s) and, per placement of the planner:

* ``compute``: ``hr_graph --host robot`` in hr_robot, ``hr_graph --host compute`` in hr_compute;
* ``robot``: both in hr_robot (the planner beside the robot's nodes, on the same "host").

Every process runs through ``tools/hosts.sh exec HOST`` (discovery across the LAN, one
``ROS_DOMAIN_ID`` locked for this run). A probe in hr_robot (the robot's own host: nothing it
receives crosses a link) records ``/joint_states``, ``/executor/metrics`` and ``/diagnostics``.
A thread samples the bridge ends of the three veth pairs (``/sys/class/net/<port>/
statistics/{rx,tx}_bytes``) at 10 Hz.

Per placement: the graph idle (``IDLE_S``), then the operator's flow from hr_operator, each step
a ``reach_operator --json`` process (bench/session.py's ``--operator-child``: the real CLI with a
recorder of its /plan_reach calls): ``--scan``, ``--marker --execute`` (the plant's valve),
``--target 0.50 0.20 1.08 --execute`` (under the left shoulder pipe, a retreat from the valve
first), ``--home --execute``; then ``--plans`` plan-only requests (the valve and the second
target in turn: more samples of the operator's wait for a plan, each /plan_reach call from
request sent to response received in the CLI); then idle again. The planner's map after the
scan: the voxels of its /diagnostics 'map' status over the robot-side mapper's occupied voxels
(both reported at least 2 s after the scan ended).

Then, with the planner on compute (same graph), three link faults, each a 5 s cut
(``tools/hosts.sh link HOST down``, then ``up``): (a) ``reach``: the operator's link during a
reach's execution (0.3 s after the goal was sent); (b) ``scan``: the operator's link during a
scan (2 s after the /look goal); (c) ``plan``: the compute link while a plan is computed (0.1 s
after the request left the CLI; the plan asks for 300 goal postures so that it takes a while);
(d) ``start``: the operator's link down as the CLI starts (a plan to the valve; its DDS
participant is made while the link has no carrier).
For each: the executor's overruns in the cut (its ``overruns_total`` in ``/diagnostics``, the
last report before the cut against the first one a second after it), the feet drift measured
from ``/joint_states`` in the cut (``graph_metrics.measured_balance``, as bench/session.py
measures it, against the sample at the cut), the CLI's fate (ran through the cut, exited with
a clear error, or *hung*: still running 10 s after its ``--timeout`` past both the link's
return and the step's own duration in the flow: killed and counted) and the recovery time:
a client in hr_operator that discovered ``/plan_reach`` before the cuts asks it every 0.5 s
from the moment the link is back (a cheap request: a target 3 m away, answered
``TARGET_OUT_OF_REACH`` without sampling); the recovery is from the link's return to the first
response.

Last line: one JSON object, ``REQUIRED_KEYS`` first, then ``targets`` (judged: a missing figure,
e.g. a cut whose trigger never came or without the executor's diagnostics, is a miss),
``targets_not_run`` (what ``--no-flow``, ``--no-cuts`` or ``--placements`` left out, not judged),
``placements``, ``cuts``, ``machine`` and ``load_average``. Exit codes: 0 the run finished (targets judged in
the JSON), 1 it could not run (the namespaces are in use, the graph did not come up), 2 not
root / bad arguments. Ctrl-C, SIGTERM or an exception: every process started is stopped and
``tools/hosts.sh down`` runs.

Usage (as root): ``python bench/hosts.py [--out out/bench_hosts] [--placements compute robot]
[--no-cuts] [--cuts reach scan plan start] [--no-flow] [--plans 6] [--timeout 30] [--idle 10]``; a
reduced run: ``--placements compute --no-flow --cuts scan --idle 3`` (~60 s; the suite's short version of
the cuts is test/test_hosts.py).
"""
from __future__ import annotations

import argparse
import functools
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable

REPO = Path(__file__).resolve().parents[1]
for _p in (REPO, REPO / "bench"):
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))

HOSTS_SH = REPO / "tools" / "hosts.sh"
BIN = REPO / "install" / "humanoid_reach_ros" / "lib" / "humanoid_reach_ros"
SESSION_PY = REPO / "bench" / "session.py"
HOSTS = ("robot", "compute", "operator")
READY_DEADLINE_S = 300.0     # hr_graph's "ready" (a loaded machine: planner and executor warm up)
PROBE_DEADLINE_S = 120.0
IDLE_S = 10.0                # each idle window
SAMPLE_HZ = 10.0             # the link counters
PEAK_WINDOW_S = 1.0          # peak rate: the largest mean over this long
CUT_S = 5.0
HANG_GRACE_S = 10.0          # a CLI still running this long after its --timeout (past the cut and its step) hung
RECOVERY_DEADLINE_S = 60.0
STEP_CAP_S = 300.0           # any reach_operator process at most (bench/session.py's): killed, counted hung
PING_PERIOD_S = 0.5
PING_TARGET = ("3.0", "0.0", "1.0")    # out of reach: answered at once, no sampling (a cheap request)
BUDGET_S = 10.0
SECOND_TARGET = ("0.50", "0.20", "1.08")   # bench/session.py's plant "under_shoulder_pipe"
VALVE = ("0.71", "0.03", "0.90")           # the plant's valve, given (test_hosts.py's)
FLOW = (("scan", ["--scan"]), ("marker", ["--marker", "--execute"]),
        ("target", ["--target", *SECOND_TARGET, "--execute"]), ("home", ["--home", "--execute"]))
CUTS = {   # name: (host cut, the CLI's arguments, the event after which to cut, delay after it [s])
    "reach": ("operator", ["--target", *SECOND_TARGET, "--execute"], "execute_sent", 0.3),
    "scan": ("operator", ["--scan"], "look_start", 2.0),
    "plan": ("compute", ["--target", *VALVE, "--goals", "300"], "plan_sent", 0.1),
    # the operator's link down when the CLI starts (its DDS participant is created on a link without carrier)
    "start": ("operator", ["--target", *VALVE], "spawned", 0.0),
}
TARGETS = {
    "hosts_flow_success_rate": ("==", 1.0), "plan_wait_ms_p95_remote_planner": ("<=", 300.0),
    "map_voxels_remote_over_local": (">=", 0.99), "operator_link_idle_kbit_s": ("<=", 200.0),
    "link_cut_executor_overruns": ("==", 0), "link_cut_feet_drift_measured_mm_max": ("<=", 0.1),
    "link_cut_recovery_s": ("<=", 5.0), "link_cut_operator_hangs": ("==", 0),
}
REQUIRED_KEYS = ("hosts_flow_success_rate", "plan_wait_ms_p95_remote_planner", "map_voxels_remote_over_local",
                 "operator_link_idle_kbit_s", "operator_link_peak_mbit_s", "robot_compute_link_mbit_s_during_scan",
                 "link_cut_executor_overruns", "link_cut_feet_drift_measured_mm_max", "link_cut_recovery_s",
                 "link_cut_operator_hangs")


# ---------------------------------------------------------------- children (inside a namespace)
def _child_node(name: str):
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    stop: list[int] = []
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, lambda signum, _f: stop.append(signum))
    rclpy.init(args=[], signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node(name, start_parameter_services=False)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    return rclpy, node, ex, stop


def probe_child(out: Path) -> int:
    """In hr_robot: every /joint_states (receipt time, positions), /executor/metrics (receipt time,
    the goal's overruns) and the map and loop statuses of /diagnostics, until SIGINT."""
    import numpy as np
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState

    from humanoid_reach_interfaces.msg import ExecutorMetrics

    rclpy, node, ex, stop = _child_node("hosts_bench_probe")
    out.mkdir(parents=True, exist_ok=True)
    times, positions, names = [], [], []
    metrics: list[tuple[float, int, float]] = []
    diag = open(out / "diagnostics.jsonl", "a", encoding="utf-8")

    def on_joints(m: JointState) -> None:
        if not names:
            names.extend(m.name)
        if list(m.name) == names:
            times.append(time.monotonic())
            positions.append(np.asarray(m.position, float))

    def on_metrics(m: ExecutorMetrics) -> None:
        metrics.append((time.monotonic(), int(m.overruns), float(m.time_from_start_s)))

    def on_diag(m: DiagnosticArray) -> None:
        t = time.monotonic()
        for st in m.status:
            if st.name.endswith((": map", ": loop")):
                diag.write(json.dumps({"t": t, "name": st.name, "message": st.message,
                                       "values": {kv.key: kv.value for kv in st.values}}) + "\n")
        diag.flush()
    node.create_subscription(JointState, "/joint_states", on_joints, 100)
    node.create_subscription(ExecutorMetrics, "/executor/metrics", on_metrics, 400)
    node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 50)
    ready = False
    while not stop:
        ex.spin_once(timeout_sec=0.05)
        if not ready and times:
            (out / "probe.ready").write_text(f"{time.monotonic()}\n")
            ready = True
    diag.close()
    np.savez(out / "probe.npz", times=np.asarray(times), positions=np.asarray(positions).reshape(len(times), -1),
             names=np.asarray(names), metrics=np.asarray(metrics, float).reshape(-1, 3))
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def pinger_child(out: Path) -> int:
    """In hr_operator: a /plan_reach client that, while ``out/ping.on`` exists, asks every
    ``PING_PERIOD_S`` (a target out of reach); each response a JSON line in ``out/ping.jsonl``."""
    from humanoid_reach_interfaces.srv import PlanReach
    from humanoid_reach_ros.nodes import reach_operator as ro

    rclpy, node, ex, stop = _child_node("hosts_bench_pinger")
    client = node.create_client(PlanReach, "/plan_reach")
    req = ro.plan_request(ro.parse_args(["--target", *PING_TARGET]))
    log = open(out / "ping.jsonl", "a", encoding="utf-8")
    flag = out / "ping.on"
    pending: list[tuple[float, Any]] = []
    last = 0.0
    ready = False
    while not stop:
        ex.spin_once(timeout_sec=0.02)
        if not ready and client.service_is_ready():
            (out / "pinger.ready").write_text(f"{time.monotonic()}\n")
            ready = True
        now = time.monotonic()
        if flag.exists() and now - last >= PING_PERIOD_S:
            pending.append((now, client.call_async(req)))
            last = now
        for sent, fut in [p for p in pending if p[1].done()]:
            pending.remove((sent, fut))
            r = fut.result()
            log.write(json.dumps({"sent": sent, "recv": time.monotonic(),
                                  "code": None if r is None else int(r.error_code.val)}) + "\n")
            log.flush()
        if len(pending) > 200:     # a long cut: forget the oldest
            pending = pending[-100:]
    log.close()
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


# ---------------------------------------------------------------- the links
@functools.cache
def host_names() -> dict[str, list[str]]:
    """``tools/hosts.sh names``: {"bridge": [BR], HOST: [NETNS, PORT, ADDRESS]} (the prefix: HR_HOSTS_PREFIX)."""
    r = subprocess.run(["bash", str(HOSTS_SH), "names"], capture_output=True, text=True, timeout=30, check=True)
    return {f[0]: f[1:] for f in (line.split() for line in r.stdout.splitlines()) if f}


def link_counters(host: str) -> tuple[int, int]:
    """(rx, tx) bytes of the bridge's end of the host's veth pair: rx from the host, tx towards it."""
    stats = Path(f"/sys/class/net/{host_names()[host][1]}/statistics")
    try:
        return int((stats / "rx_bytes").read_text()), int((stats / "tx_bytes").read_text())
    except (OSError, ValueError):
        return -1, -1


class LinkSampler(threading.Thread):
    """The three links' byte counters at ``SAMPLE_HZ``, and the load average."""

    def __init__(self) -> None:
        super().__init__(daemon=True, name="link-sampler")
        self.samples: list[tuple[float, dict[str, tuple[int, int]]]] = []
        self.load_max = 0.0
        self._stop = threading.Event()

    def run(self) -> None:
        period = 1.0 / SAMPLE_HZ
        nxt = time.monotonic()
        while not self._stop.is_set():
            self.samples.append((time.monotonic(), {h: link_counters(h) for h in HOSTS}))
            self.load_max = max(self.load_max, os.getloadavg()[0])
            nxt += period
            self._stop.wait(max(0.0, nxt - time.monotonic()))

    def stop(self) -> None:
        self._stop.set()

    def _series(self, host: str, t0: float, t1: float) -> list[tuple[float, int, int]]:
        return [(t, c[host][0], c[host][1]) for t, c in list(self.samples) if t0 <= t <= t1 and c[host][0] >= 0]

    def rate(self, host: str, t0: float, t1: float) -> dict[str, float] | None:
        """Mean bit/s over [t0, t1]: both directions summed, and each."""
        s = self._series(host, t0, t1)
        if len(s) < 2 or s[-1][0] - s[0][0] <= 0:
            return None
        dt = s[-1][0] - s[0][0]
        rx, tx = (s[-1][1] - s[0][1]) * 8 / dt, (s[-1][2] - s[0][2]) * 8 / dt
        return {"both": rx + tx, "from_host": rx, "to_host": tx}

    def peak(self, host: str, t0: float, t1: float, window: float = PEAK_WINDOW_S) -> dict[str, float] | None:
        """The largest mean bit/s over ``window`` within [t0, t1]."""
        s = self._series(host, t0, t1)
        best = None
        j = 0
        for i in range(len(s)):
            while s[i][0] - s[j][0] > window:
                j += 1
            if s[i][0] - s[j][0] >= window * 0.95:
                dt = s[i][0] - s[j][0]
                rx, tx = (s[i][1] - s[j][1]) * 8 / dt, (s[i][2] - s[j][2]) * 8 / dt
                if best is None or rx + tx > best["both"]:
                    best = {"both": rx + tx, "from_host": rx, "to_host": tx, "at_s": s[i][0] - t0}
        return best


# ---------------------------------------------------------------- the bench (root's namespace)
def hosts_sh(*args: str, check: bool = True, timeout: float = 60.0) -> subprocess.CompletedProcess:
    r = subprocess.run(["bash", str(HOSTS_SH), *args], capture_output=True, text=True, timeout=timeout)
    if check and r.returncode != 0:
        raise RuntimeError(f"tools/hosts.sh {' '.join(args)} failed ({r.returncode}): {r.stderr.strip()}")
    return r


def hosts_up() -> bool:
    return subprocess.run(["ip", "link", "show", host_names()["bridge"][0]], capture_output=True).returncode == 0


class HostsBench:
    def __init__(self, out: Path, timeout: float, log: Callable[[str], None]) -> None:
        from humanoid_reach_ros.graph import allocate_domain, graph_env

        self.out, self.timeout, self.log = out, timeout, log
        self.lease = allocate_domain()
        self.env = graph_env(self.lease.domain_id)
        self.procs: list[subprocess.Popen] = []
        self.sampler = LinkSampler()
        self.t0 = time.monotonic()
        self.links_down: set[str] = set()

    # ---- processes
    def spawn(self, host: str, argv: list[str], log_path: Path, stderr_path: Path | None = None) -> subprocess.Popen:
        log_path.parent.mkdir(parents=True, exist_ok=True)
        with open(log_path, "wb") as so, open(stderr_path or log_path, "ab") as se:
            p = subprocess.Popen(["bash", str(HOSTS_SH), "exec", host, *argv], env=dict(self.env), cwd=REPO,
                                 stdout=so, stderr=se if stderr_path else subprocess.STDOUT,
                                 stdin=subprocess.DEVNULL, start_new_session=True)
        self.procs.append(p)
        return p

    def stop(self, p: subprocess.Popen, timeout: float = 60.0) -> int | None:
        if p.poll() is None:
            try:
                os.killpg(p.pid, signal.SIGINT)
            except ProcessLookupError:
                pass
            try:
                p.wait(timeout)
            except subprocess.TimeoutExpired:
                self.kill(p)
        return p.returncode

    @staticmethod
    def kill(p: subprocess.Popen) -> None:
        try:
            os.killpg(p.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        try:
            p.wait(10.0)
        except subprocess.TimeoutExpired:
            pass

    def link(self, host: str, state: str) -> float:
        hosts_sh("link", host, state)
        (self.links_down.add if state == "down" else self.links_down.discard)(host)
        return time.monotonic()

    def close(self) -> None:
        """Every process this bench started (their groups; then whatever still runs inside the
        namespaces: only this bench's), then the namespaces."""
        for host in list(self.links_down):
            hosts_sh("link", host, "up", check=False)
        for p in self.procs:
            if p.poll() is None:
                try:
                    os.killpg(p.pid, signal.SIGINT)
                except ProcessLookupError:
                    pass
        deadline = time.monotonic() + 30.0
        for p in self.procs:
            try:
                p.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                self.kill(p)
        for host in HOSTS:     # orphans (a node whose hr_graph was killed): by pid, inside our namespaces only
            r = subprocess.run(["ip", "netns", "pids", host_names()[host][0]], capture_output=True, text=True)
            for pid in r.stdout.split():
                try:
                    os.kill(int(pid), signal.SIGKILL)
                except (ProcessLookupError, ValueError):
                    pass
        self.sampler.stop()
        hosts_sh("down", check=False)
        self.lease.release()

    # ---- the graph
    def graph_up(self, placement: str, out: Path) -> dict[str, Any]:
        t0 = time.monotonic()
        self.graphs: dict[str, tuple[subprocess.Popen, Path]] = {}
        for share, host in (("robot", "robot"), ("compute", placement)):
            log = out / f"hr_graph_{share}.out"
            self.graphs[share] = (self.spawn(host, [str(BIN / "hr_graph"), "--host", share, "--log-dir",
                                                    str(out / f"nodes_{share}")], log), log)
        for share, (p, log) in self.graphs.items():
            deadline = time.monotonic() + READY_DEADLINE_S
            while "[hr_graph] ready" not in log.read_text(errors="replace"):
                if p.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"hr_graph --host {share} did not come up "
                                       f"({'exited ' + str(p.returncode) if p.poll() is not None else 'timed out'}):"
                                       f"\n{log.read_text(errors='replace')[-3000:]}")
                time.sleep(0.2)
        self.probe_dir = out / "probe"
        self.probe_dir.mkdir(parents=True, exist_ok=True)
        self.probe = self.spawn("robot", [sys.executable, str(Path(__file__).resolve()), "--probe-child",
                                          str(self.probe_dir)], out / "probe.out")
        self._wait_file(self.probe_dir / "probe.ready", self.probe, "the probe's first /joint_states")
        return {"graph_up_s": round(time.monotonic() - t0, 1)}

    def _wait_file(self, path: Path, p: subprocess.Popen, what: str, deadline_s: float = PROBE_DEADLINE_S) -> None:
        deadline = time.monotonic() + deadline_s
        while not path.exists():
            if p.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"timed out waiting for {what}")
            time.sleep(0.1)

    def graph_down(self) -> dict[str, Any]:
        codes = {}
        if getattr(self, "probe", None) is not None:
            codes["probe"] = self.stop(self.probe)
        for share, (p, _) in reversed(list(self.graphs.items())):
            codes[f"hr_graph_{share}"] = self.stop(p)
        return codes

    def diagnostics(self) -> list[dict[str, Any]]:
        path = self.probe_dir / "diagnostics.jsonl"
        rows = []
        for line in path.read_text(errors="replace").splitlines() if path.exists() else []:
            try:
                rows.append(json.loads(line))
            except json.JSONDecodeError:
                pass
        return rows

    def latest_diag(self, suffix: str, key: str, after: float = 0.0) -> tuple[float, float] | None:
        rows = [r for r in self.diagnostics() if r["name"].endswith(suffix) and key in r["values"] and r["t"] >= after]
        if not rows:
            return None
        try:
            return rows[-1]["t"], float(rows[-1]["values"][key])
        except ValueError:
            return None

    # ---- the operator
    def operator(self, args: list[str], tag: str, out: Path, hook: Callable[[list[dict], float], None] | None = None,
                 hang_after: Callable[[], float | None] | None = None) -> dict[str, Any]:
        """One ``reach_operator --json`` in hr_operator (bench/session.py's recorder around it).
        ``hook(events, t_start)`` is called while it runs; ``hang_after()`` the time after which it
        counts as hung (killed)."""
        events = out / f"{tag}.events.jsonl"
        stdout, stderr = out / f"{tag}.stdout", out / f"{tag}.stderr"
        argv = [sys.executable, str(SESSION_PY), "--operator-child", str(events), "--", *args,
                "--timeout", f"{self.timeout:g}", "--json"]
        t0 = time.monotonic()
        p = self.spawn("operator", argv, stdout, stderr)
        hung = False
        evs: list[dict] = []
        while p.poll() is None:
            evs = read_events(events)
            if hook is not None:
                hook(evs, t0)
            limit = hang_after() if hang_after is not None else None
            if time.monotonic() - t0 > STEP_CAP_S or (limit is not None and time.monotonic() > limit):
                hung = True
                self.kill(p)
                break
            time.sleep(0.05)
        t1 = time.monotonic()
        evs = read_events(events)
        if hook is not None:
            hook(evs, t0)
        lines = stdout.read_text(errors="replace").strip().splitlines()
        try:
            summary = json.loads(lines[-1]) if lines else {}
        except json.JSONDecodeError:
            summary = {}
        err = stderr.read_text(errors="replace")
        return {"args": args, "exit_code": p.returncode, "hung": hung, "t_start": t0, "t_end": t1,
                "duration_s": round(t1 - t0, 2), "summary": summary, "events": evs,
                "stderr_last": next((ln for ln in reversed(err.strip().splitlines()) if ln.strip()), "")}


def read_events(path: Path) -> list[dict]:
    out = []
    try:
        text = path.read_text(errors="replace")
    except FileNotFoundError:
        return out
    for line in text.splitlines():
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:
            pass     # a line being written
    return out


def plan_waits_ms(evs: list[dict]) -> list[float]:
    """Each /plan_reach call of the CLI: request sent to response received (client side)."""
    sent = [e["t"] for e in evs if e["event"] == "plan_sent"]
    resp = [e["t"] for e in evs if e["event"] == "plan_response"]
    return [(b - a) * 1e3 for a, b in zip(sent, resp)]


def step_plan_waits_ms(run: dict[str, Any]) -> tuple[list[float], int]:
    """Every wait for a plan of a step, and how many of them ended in a failure: each answered call
    (``plan_waits_ms``); a call never answered, until the CLI ended; a step that plans (all but
    ``--scan``) yet sent no call (``/plan_reach`` never found), its whole run. So a failed step stays
    in the percentiles' denominator, at its time to failure."""
    evs = run["events"]
    sent = [e["t"] for e in evs if e["event"] == "plan_sent"]
    answered = plan_waits_ms(evs)
    lost = [(run["t_end"] - t) * 1e3 for t in sent[len(answered):]]
    if not sent and "--scan" not in run["args"]:
        lost = [(run["t_end"] - run["t_start"]) * 1e3]
    return answered + lost, len(lost)


def step_success(run: dict[str, Any]) -> bool:
    s = run["summary"]
    ok = run["exit_code"] == 0 and bool(s) and not run["hung"]
    if "--execute" in run["args"]:
        ok = ok and bool((s.get("execution") or {}).get("success"))
    return ok


def step_record(run: dict[str, Any], t_ref: float) -> dict[str, Any]:
    s = run["summary"]
    plan = s.get("plan") or {}
    ex = s.get("execution") or {}
    waits, to_failure = step_plan_waits_ms(run)
    return {"args": run["args"], "exit_code": run["exit_code"], "hung": run["hung"], "success": step_success(run),
            "start_s": round(run["t_start"] - t_ref, 2), "duration_s": run["duration_s"],
            "plan_waits_ms": [round(w, 1) for w in waits], "plan_waits_to_failure": to_failure,
            "plan": {k: plan.get(k) for k in ("error_name", "message")} if plan else None,
            "planner_total_ms": round(float((plan.get("statistics") or {}).get("total_time_s", 0.0)) * 1e3, 1)
            if plan else None,
            "map_voxels_in_plan": (plan.get("statistics") or {}).get("map_voxels") if plan else None,
            # the last call's wait less the planner's own time: the transport (and the planner's queue)
            "plan_overhead_ms": round(plan_waits_ms(run["events"])[-1] - float((plan.get("statistics") or {}).get(
                "total_time_s", 0.0)) * 1e3, 1) if plan and plan_waits_ms(run["events"]) else None,
            "auto_looks": len(s.get("auto_looks") or []),
            "execution": {k: ex.get(k) for k in ("outcome", "success", "error_name", "duration_s", "overruns")}
            if ex else None,
            "stderr_last": run["stderr_last"][-300:]}


# ---------------------------------------------------------------- measures from the probe
class ProbeData:
    def __init__(self, path: Path) -> None:
        import numpy as np

        from humanoid_reach_ros.robot.model import RobotModel
        d = np.load(path)
        self.times, names = d["times"], [str(n) for n in d["names"]]
        self.robot = RobotModel()
        order = [names.index(n) for n in self.robot.joint_names]
        self.joints = d["positions"][:, order] if len(self.times) else np.zeros((0, self.robot.n_joints))
        self.metrics = d["metrics"]

    def feet_drift_mm(self, t0: float, t1: float) -> float | None:
        """graph_metrics.measured_balance over the joint states received in [t0, t1], against the
        first of them (bench/session.py's measure over a window)."""
        from humanoid_reach_ros.testing.graph_metrics import measured_balance
        sel = self.joints[(self.times >= t0) & (self.times <= t1)]
        if not len(sel):
            return None
        return float(measured_balance(self.robot, sel[::2] if len(sel) > 4000 else sel)["feet_drift_mm"])

    def samples(self, t0: float, t1: float) -> int:
        return int(((self.times >= t0) & (self.times <= t1)).sum())

    def max_gap_ms(self, t0: float, t1: float) -> float | None:
        from humanoid_reach_ros.testing.graph_metrics import max_gap_ms
        return max_gap_ms(self.times[(self.times >= t0) & (self.times <= t1)])


# ---------------------------------------------------------------- a placement
def run_placement(b: HostsBench, placement: str, args: argparse.Namespace, out: Path) -> dict[str, Any]:
    res: dict[str, Any] = {"placement": placement, "planner_on": host_names()[placement][0], "steps": [], "cuts": []}
    shutil.rmtree(out, ignore_errors=True)     # this run's logs, events and probe files only (they are appended to)
    out.mkdir(parents=True, exist_ok=True)
    b.log(f"placement {placement}: the planner in {host_names()[placement][0]}; graph up ...")
    try:
        res.update(b.graph_up(placement, out))
        b.log(f"  graph up in {res['graph_up_s']} s; idle {args.idle:g} s")
        time.sleep(3.0)     # the start-up's discovery settles
        res["idle"] = idle_window(b, args.idle)
        durations: dict[str, float] = {}
        if not args.no_flow:
            for k, (name, step_args) in enumerate(FLOW):
                extra = [] if name == "scan" else ["--seed", str(100 + k), "--budget", f"{BUDGET_S:g}"]
                run = b.operator([*step_args, *extra], f"{k:02d}_{name}", out)
                rec = step_record(run, b.t0)
                rec["name"] = name
                rec["t"] = (run["t_start"], run["t_end"])
                durations[name] = run["duration_s"]
                res["steps"].append(rec)
                b.log(f"  {name:7s} {'ok  ' if rec['success'] else 'FAIL'} exit {run['exit_code']} "
                      f"{run['duration_s']:.1f} s plan waits {rec['plan_waits_ms']} ms"
                      + ("" if rec["success"] else f" | {rec['stderr_last']}"))
                if name == "scan":
                    res["map"] = map_ratio(b, run["t_end"])
                    b.log(f"  map after the scan: {res['map']}")
            for k in range(args.plans):     # plan only: more samples of the operator's wait for a plan
                target = VALVE if k % 2 == 0 else SECOND_TARGET
                run = b.operator(["--target", *target, "--seed", str(200 + k), "--budget", f"{BUDGET_S:g}"],
                                 f"plan_{k:02d}", out)
                rec = step_record(run, b.t0)
                rec["name"] = f"plan_{k}"
                rec["t"] = (run["t_start"], run["t_end"])
                res["steps"].append(rec)
                b.log(f"  plan {k}  {'ok  ' if rec['success'] else 'FAIL'} exit {run['exit_code']} "
                      f"{run['duration_s']:.1f} s plan waits {rec['plan_waits_ms']} ms (planner "
                      f"{rec['planner_total_ms']} ms)" + ("" if rec["success"] else f" | {rec['stderr_last']}"))
            time.sleep(2.0)     # the executor's hold ends
            res["idle_after"] = idle_window(b, args.idle)
            flow = [s for s in res["steps"]]
            for st in flow:
                st["operator_link_mb"] = link_mb(b.sampler, "operator", *st["t"])
                st["operator_link_peak_mbit_s"] = round((b.sampler.peak("operator", *st["t"]) or {}).get(
                    "both", 0.0) / 1e6, 2)
            if flow:
                t_a, t_b = flow[0]["t"][0], flow[-1]["t"][1]
                res["operator_link_peak"] = b.sampler.peak("operator", t_a, t_b)
                res["compute_link_peak"] = b.sampler.peak("compute", t_a, t_b)
                scan = flow[0]["t"]
                res["compute_link_during_scan"] = b.sampler.rate("compute", *scan)
                res["compute_link_peak_during_scan"] = b.sampler.peak("compute", *scan)
                res["operator_link_during_flow"] = b.sampler.rate("operator", t_a, t_b)
        if not args.no_cuts and placement == "compute":
            res["cuts"] = run_cuts(b, args, out, durations)
    finally:
        res["exit_codes"] = b.graph_down()
    res["executor_log"] = executor_overruns(out)
    probe_file = b.probe_dir / "probe.npz" if getattr(b, "probe_dir", None) else None
    if probe_file is not None and probe_file.exists():
        data = ProbeData(probe_file)
        res["joint_state_samples"] = int(len(data.times))
        for st in res["steps"]:
            st["feet_drift_mm"] = data.feet_drift_mm(*st["t"])
        if res["steps"]:
            res["flow_feet_drift_mm"] = data.feet_drift_mm(res["steps"][0]["t"][0], res["steps"][-1]["t"][1])
        for c in [c for c in res["cuts"] if "t_down" in c]:     # a cut that never came has no window
            c["feet_drift_mm"] = data.feet_drift_mm(c["t_down"], c["t_up"])
            c["joint_state_samples_in_cut"] = data.samples(c["t_down"], c["t_up"])
            c["joint_state_max_gap_ms_in_cut"] = data.max_gap_ms(c["t_down"], c["t_up"])
    for st in res["steps"]:
        st["t"] = [round(x - b.t0, 2) for x in st["t"]]
    for c in [c for c in res["cuts"] if "t_down" in c]:
        for k in ("t_down", "t_up"):
            c[k] = round(c[k] - b.t0, 2)
    return res


def link_mb(sampler: LinkSampler, host: str, t0: float, t1: float) -> float | None:
    s = sampler._series(host, t0, t1)
    return round((s[-1][1] + s[-1][2] - s[0][1] - s[0][2]) / 1e6, 3) if len(s) >= 2 else None


def idle_window(b: HostsBench, seconds: float) -> dict[str, Any]:
    t0 = time.monotonic()
    time.sleep(seconds)
    t1 = time.monotonic()
    return {h: b.sampler.rate(h, t0, t1) for h in HOSTS}


def map_ratio(b: HostsBench, t_scan_end: float) -> dict[str, Any]:
    """The planner's map (its /diagnostics 'map' voxels) against the robot-side mapper's occupied
    voxels, both reported after the scan: until both have reported twice since it ended and the
    planner's count matches the mapper's published version (at most 15 s)."""
    deadline = t_scan_end + 15.0
    remote = local = None
    while time.monotonic() < deadline:
        remote = b.latest_diag("reach_planner: map", "voxels", t_scan_end + 2.0)
        local = b.latest_diag("voxel_mapper: map", "occupied_voxels", t_scan_end + 2.0)
        if remote and local and remote[1] >= local[1] * 0.99:
            break
        time.sleep(0.5)
    out: dict[str, Any] = {"planner_voxels": None if remote is None else int(remote[1]),
                           "mapper_occupied_voxels": None if local is None else int(local[1])}
    if remote and local and local[1] > 0:
        out["ratio"] = round(remote[1] / local[1], 4)
        out["waited_s"] = round(max(remote[0], local[0]) - t_scan_end, 1)
    return out


def executor_overruns(out: Path) -> dict[str, int]:
    import session
    totals = {"executor_motions": 0, "executor_steps": 0, "executor_overruns": 0}
    for d in out.glob("nodes_*"):
        for k, v in session.executor_motion_overruns(d).items():
            totals[k] += v
    return totals


def run_cuts(b: HostsBench, args: argparse.Namespace, out: Path, durations: dict[str, float]) -> list[dict[str, Any]]:
    pdir = out / "pinger"
    pdir.mkdir(parents=True, exist_ok=True)
    pinger = b.spawn("operator", [sys.executable, str(Path(__file__).resolve()), "--pinger-child", str(pdir)],
                     out / "pinger.out")
    b._wait_file(pdir / "pinger.ready", pinger, "the pinger's /plan_reach")
    results = []
    expected = {"reach": durations.get("target", 60.0), "scan": durations.get("scan", 60.0),
                "plan": BUDGET_S, "start": BUDGET_S}
    for name in args.cuts:
        host, cli, event, delay = CUTS[name]
        b.log(f"  cut {name}: the {host} link down {CUT_S:g} s {delay:g} s after '{event}'")
        state: dict[str, Any] = {}

        def hook(evs: list[dict], t_start: float, host=host, event=event, delay=delay, state=state) -> None:
            if "t_down" not in state:
                ev = ({"t": t_start} if event == "spawned" else
                      next((e for e in evs if e["event"] == event and e["t"] >= t_start), None))
                if ev is not None and time.monotonic() >= ev["t"] + delay:
                    state["event_t"] = ev["t"]
                    state["t_down"] = b.link(host, "down")
            elif "t_up" not in state and time.monotonic() >= state["t_down"] + CUT_S:
                state["t_up"] = b.link(host, "up")
                (pdir / "ping.on").write_text("")

        t_start = time.monotonic()

        def hang_after(state=state, name=name, t_start=t_start) -> float | None:
            if "t_up" not in state:
                return None
            return max(state["t_up"], t_start + expected[name]) + b.timeout + HANG_GRACE_S
        extra = ["--seed", "7", "--budget", f"{BUDGET_S:g}"] if name != "scan" else []
        run = b.operator([*cli, *extra], f"cut_{name}", out, hook=hook, hang_after=hang_after)
        if "t_down" in state and "t_up" not in state:       # the CLI ended within the cut
            while time.monotonic() < state["t_down"] + CUT_S:
                time.sleep(0.05)
            hook([], 0.0)
        rec: dict[str, Any] = {"name": name, "link": host, "args": run["args"], "exit_code": run["exit_code"],
                               "hung": run["hung"], "duration_s": run["duration_s"],
                               "stderr_last": run["stderr_last"][-300:], "success": step_success(run)}
        if "t_down" not in state:
            rec["error"] = f"'{event}' never came: no cut"
            b.log(f"    {rec['error']} (exit {run['exit_code']}: {run['stderr_last']})")
            results.append(rec)
            continue
        rec.update(t_down=state["t_down"], t_up=state["t_up"],
                   cut_from_start_s=round(state["t_down"] - run["t_start"], 2))
        if run["hung"]:
            outcome = "hung (killed)"
        elif rec["success"]:
            outcome = "rode out the cut"
        elif "reach_operator:" in run["stderr_last"] or run["exit_code"] in (3, 4, 5, 6, 7):
            outcome = "clear error"
        else:
            outcome = "unclear failure"
        rec["outcome"] = outcome
        rec["cli_end_after_up_s"] = round(run["t_end"] - state["t_up"], 2)
        if name == "plan":
            plan = (run["summary"].get("plan") or {})
            total = float((plan.get("statistics") or {}).get("total_time_s", 0.0) or 0.0)
            sent = next((e["t"] for e in run["events"] if e["event"] == "plan_sent"), None)
            rec["planner_total_ms"] = round(total * 1e3, 1)
            rec["planning_during_cut"] = bool(sent is not None and sent + total > state["t_down"])
        # recovery: the pinger's first response after the link came back
        rec["recovery_s"] = recovery(pdir / "ping.jsonl", state["t_up"])
        (pdir / "ping.on").unlink(missing_ok=True)
        # the executor's overruns in the cut: its loop report before the cut against the first a second after it
        before = [r for r in b.diagnostics()
                  if r["name"].endswith("reach_executor: loop") and r["t"] <= state["t_down"]]
        deadline = time.monotonic() + 10.0
        after = []
        while time.monotonic() < deadline and not after:
            after = [r for r in b.diagnostics() if r["name"].endswith("reach_executor: loop")
                     and r["t"] >= state["t_up"] + 1.0]
            time.sleep(0.2)
        if before and after:
            rec["executor_overruns"] = int(after[0]["values"]["overruns_total"]) - int(
                before[-1]["values"]["overruns_total"])
        else:
            rec["executor_overruns"] = None
        b.log(f"    {outcome}: exit {run['exit_code']} after {run['duration_s']:.1f} s "
              f"({rec['cli_end_after_up_s']:+.1f} s from the link's return); recovery "
              f"{rec['recovery_s']} s; overruns {rec['executor_overruns']}"
              + (f"; planning during the cut: {rec.get('planning_during_cut')}" if name == "plan" else "")
              + (f" | {run['stderr_last']}" if not rec["success"] else ""))
        results.append(rec)
        if name == "reach":     # back to half-sitting for the next one
            home = b.operator(["--home", "--execute", "--budget", f"{BUDGET_S:g}"], f"cut_{name}_home", out)
            rec["home_after"] = step_success(home)
    b.stop(pinger)
    return results


def save_links(sampler: LinkSampler, t_ref: float, path: Path) -> None:
    """The counters as sampled: t [s from the bench's start], then per host rx, tx bytes."""
    rows = [[round(t - t_ref, 3), *[v for h in HOSTS for v in c[h]]] for t, c in list(sampler.samples)]
    path.write_text(json.dumps({"columns": ["t_s", *[f"{h}_{d}" for h in HOSTS for d in ("rx", "tx")]],
                                "rows": rows}))


def recovery(path: Path, t_up: float) -> float | None:
    deadline = time.monotonic() + RECOVERY_DEADLINE_S
    while time.monotonic() < deadline:
        for e in read_events(path):
            if e["recv"] >= t_up and e["code"] is not None:
                return round(e["recv"] - t_up, 2)
        time.sleep(0.1)
    return None


# ---------------------------------------------------------------- the figures
def summarize(placements: list[dict[str, Any]], cuts_expected: int | None = None) -> dict[str, Any]:
    """The figures of a run. Missing is ``None`` (a missed target, bench/graph.py's ``judge``): a cut
    whose trigger never came, or fewer cuts than ``cuts_expected`` (default: those recorded), leaves
    every ``link_cut_*`` figure missing; so does a cut without the executor's loop diagnostics
    (overruns) or its measured joints (feet drift). Each step's plan waits include those that ended
    in a failure (``step_plan_waits_ms``), counted in ``plan_waits_to_failure``."""
    from humanoid_reach_ros.testing.graph_metrics import percentile

    steps = [s for p in placements for s in p["steps"]]
    remote = [w for p in placements if p["placement"] == "compute" for s in p["steps"] for w in s["plan_waits_ms"]]
    local = [w for p in placements if p["placement"] == "robot" for s in p["steps"] for w in s["plan_waits_ms"]]
    recorded = [c for p in placements for c in p["cuts"]]
    cuts = [c for c in recorded if "t_down" in c]
    n_cuts = len(recorded) if cuts_expected is None else cuts_expected
    cuts_ok = n_cuts > 0 and len(cuts) == n_cuts
    ratio = next((p["map"].get("ratio") for p in placements if p["placement"] == "compute" and p.get("map")), None)
    idle = [w["operator"]["both"] for p in placements for k in ("idle", "idle_after")
            if (w := p.get(k)) and w.get("operator")]
    peaks = [p["operator_link_peak"]["both"] for p in placements if p.get("operator_link_peak")]
    scan = next((p["compute_link_during_scan"]["both"] for p in placements
                 if p["placement"] == "compute" and p.get("compute_link_during_scan")), None)

    over = {pl: [s["plan_overhead_ms"] for p in placements if p["placement"] == pl for s in p["steps"]
                 if s.get("plan_overhead_ms") is not None] for pl in ("compute", "robot")}
    own = {pl: [s["planner_total_ms"] for p in placements if p["placement"] == pl for s in p["steps"]
                if s.get("planner_total_ms")] for pl in ("compute", "robot")}

    def r(v, nd=3):
        return None if v is None else round(v, nd)
    drifts = [c.get("feet_drift_mm") for c in cuts]
    overruns = [c.get("executor_overruns") for c in cuts]
    recov = [c.get("recovery_s") for c in cuts]
    return {
        "hosts_flow_success_rate": r(sum(s["success"] for s in steps) / len(steps), 4) if steps else None,
        "plan_wait_ms_p95_remote_planner": r(percentile(remote, 95), 1) if remote else None,
        "map_voxels_remote_over_local": ratio,
        "operator_link_idle_kbit_s": r(max(idle) / 1e3, 1) if idle else None,
        "operator_link_peak_mbit_s": r(max(peaks) / 1e6, 2) if peaks else None,
        "robot_compute_link_mbit_s_during_scan": r(scan / 1e6, 2) if scan is not None else None,
        "link_cut_executor_overruns": (sum(overruns) if cuts_ok and None not in overruns else None),
        "link_cut_feet_drift_measured_mm_max": r(max(drifts), 5) if cuts_ok and None not in drifts else None,
        # a cut with no recovery within RECOVERY_DEADLINE_S counts as that long (a measured miss)
        "link_cut_recovery_s": (r(max(RECOVERY_DEADLINE_S if x is None else x for x in recov), 2)
                                if cuts_ok else None),
        "link_cut_operator_hangs": sum(1 for c in cuts if c.get("hung")) if cuts_ok else None,
        "cuts_expected": n_cuts, "cuts_not_done": n_cuts - len(cuts),
        "plan_waits_to_failure": sum(s.get("plan_waits_to_failure", 0) for s in steps),
        # detail
        "plan_wait_ms_p50_remote_planner": r(percentile(remote, 50), 1) if remote else None,
        "plan_wait_ms_p95_local_planner": r(percentile(local, 95), 1) if local else None,
        "plan_wait_ms_p50_local_planner": r(percentile(local, 50), 1) if local else None,
        "plan_calls": {"remote": len(remote), "local": len(local)},
        "plan_overhead_ms_p95_remote_planner": r(percentile(over["compute"], 95), 1) if over["compute"] else None,
        "plan_overhead_ms_p95_local_planner": r(percentile(over["robot"], 95), 1) if over["robot"] else None,
        "planner_own_ms_p95_remote_planner": r(percentile(own["compute"], 95), 1) if own["compute"] else None,
        "flow_steps": len(steps), "cuts_done": len(cuts),
    }


FLOW_KEYS = ("hosts_flow_success_rate", "plan_wait_ms_p95_remote_planner", "map_voxels_remote_over_local",
             "operator_link_peak_mbit_s", "robot_compute_link_mbit_s_during_scan")
CUT_KEYS = ("link_cut_executor_overruns", "link_cut_feet_drift_measured_mm_max", "link_cut_recovery_s",
            "link_cut_operator_hangs")


def not_run_targets(args: argparse.Namespace) -> dict[str, str]:
    """The figures this run's options leave out (not judged, said why); every other missing figure
    is a missed target."""
    out = {k: "--no-flow" for k in FLOW_KEYS if args.no_flow}
    if "compute" not in args.placements:
        out.update({k: "no placement on compute" for k in ("plan_wait_ms_p95_remote_planner",
                                                           "map_voxels_remote_over_local",
                                                           "robot_compute_link_mbit_s_during_scan", *CUT_KEYS)})
    if not args.cuts:
        out.update({k: "--no-cuts" for k in CUT_KEYS})
    return out


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--probe-child"]:
        return probe_child(Path(argv[1]))
    if argv[:1] == ["--pinger-child"]:
        return pinger_child(Path(argv[1]))
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    ap.add_argument("--out", default="out/bench_hosts", help="logs and hosts.json (default out/bench_hosts)")
    ap.add_argument("--placements", nargs="+", choices=("compute", "robot"), default=["compute", "robot"],
                    help="where the planner runs, one graph each (default: compute robot)")
    ap.add_argument("--no-cuts", action="store_true", help="no link faults")
    ap.add_argument("--cuts", nargs="+", choices=tuple(CUTS), default=list(CUTS),
                    help="which faults (with the planner on compute; default all: reach scan plan start)")
    ap.add_argument("--no-flow", action="store_true", help="skip the operator's flow (the cuts only)")
    ap.add_argument("--timeout", type=float, default=30.0, help="reach_operator --timeout of every step (default 30)")
    ap.add_argument("--plans", type=int, default=6, help="plan-only requests after the flow, per placement (more "
                    "samples of the wait for a plan; default 6)")
    ap.add_argument("--idle", type=float, default=IDLE_S, help=f"each idle window [s] (default {IDLE_S:g})")
    ap.add_argument("--wait-hosts", type=float, default=0.0, help="when the namespaces are up (another run), wait "
                    "this long for them to go (default 0: exit 1 at once)")
    args = ap.parse_args(argv)
    if os.geteuid() != 0:
        print("bench/hosts.py: needs root (network namespaces, veth, tc: tools/hosts.sh): run it as root or with "
              "sudo", file=sys.stderr)
        return 2
    if args.no_cuts:
        args.cuts = []
    if args.no_cuts and args.no_flow:
        ap.error("--no-cuts with --no-flow leaves nothing to run")
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)

    def log(text: str) -> None:
        print(f"[bench/hosts] {text}", flush=True)

    deadline = time.monotonic() + args.wait_hosts
    while hosts_up():
        if time.monotonic() > deadline:
            print(f"bench/hosts.py: the namespaces are up ({host_names()['bridge'][0]} exists): another run is "
                  "using them, or one was "
                  "killed -- 'tools/hosts.sh down' once nobody runs", file=sys.stderr)
            return 1
        time.sleep(2.0)
    from humanoid_reach_ros.testing.machine import describe

    import graph as bench_graph
    import session

    session.stop_on_signals()      # SIGINT / SIGTERM: KeyboardInterrupt, the finally below cleans up
    load_start = os.getloadavg()
    b = HostsBench(out, args.timeout, log)
    placements: list[dict[str, Any]] = []
    errors: list[str] = []
    interrupted = False
    try:
        hosts_sh("up")
        b.sampler.start()
        log(f"hosts up (ROS_DOMAIN_ID {b.lease.domain_id}); load average {load_start[0]:.2f}")
        order = sorted(args.placements, key=lambda p: p != "compute")
        for placement in order:
            try:
                placements.append(run_placement(b, placement, args, out / placement))
            except (RuntimeError, OSError, subprocess.SubprocessError) as exc:
                log(f"placement {placement} failed: {exc}")
                errors.append(f"{placement}: {str(exc)[-2000:]}")
                placements.append({"placement": placement, "error": str(exc)[-2000:], "steps": [], "cuts": [],
                                   "graph_up_failed": True})
    except KeyboardInterrupt:
        interrupted = True
        log("interrupted: stopping every process and taking the namespaces down")
    finally:
        b.close()
        save_links(b.sampler, b.t0, out / "links.json")
    if interrupted:
        return 130
    figures = summarize(placements, cuts_expected=len(args.cuts) if "compute" in args.placements else 0)
    not_run = not_run_targets(args)
    for k in not_run:
        figures[k] = None
    if any(p.get("graph_up_failed") for p in placements) and "hosts_flow_success_rate" not in not_run:
        figures["hosts_flow_success_rate"] = 0.0
    required = {k: figures.pop(k) for k in REQUIRED_KEYS}
    judged = bench_graph.judge(required, TARGETS, not_run)
    load_end = os.getloadavg()
    result = {**required, "targets": judged, "targets_not_run": not_run,
              "targets_met": all(t["met"] for t in judged.values()),
              "load_average": {"start_1min": round(load_start[0], 2), "end_1min": round(load_end[0], 2),
                               "max_1min": round(b.sampler.load_max, 2), "start": [round(x, 2) for x in load_start],
                               "end": [round(x, 2) for x in load_end]},
              "machine": describe(), "details": figures, "placements": placements, "errors": errors,
              "cut_s": CUT_S, "operator_timeout_s": args.timeout,
              "links": "tools/hosts.sh up defaults: 1gbit, operator 20mbit (tbf, both directions)",
              "command": "python bench/hosts.py " + " ".join(argv), "wall_s": round(time.monotonic() - b.t0, 1)}
    (out / "hosts.json").write_text(json.dumps(result, indent=2))
    for key, t in judged.items():
        log(f"{'ok  ' if t['met'] else 'MISS'} {key}: {t['value']} (target {t['target']})"
            + (" (not measured)" if t.get("missing") else ""))
    for key, why in not_run.items():
        log(f"not run {key}: {why}")
    print(json.dumps(result), flush=True)
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
