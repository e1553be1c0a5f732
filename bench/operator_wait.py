"""Benchmark: operator wait at the service, ``/plan_reach`` request -> trajectory (Kanehiro et al., Sec. V).

Starts ``joint_driver`` (the simulated robot, 200 Hz ``/joint_states``) and
``reach_planner`` (plant scene map, ``config/reach_planner.yaml``) as real processes in
an isolated ROS domain (``humanoid_reach_ros.graph``), waits until the planner answers,
sends one untimed warm-up request, then ``--requests`` requests with the valve WGR of
eq. (3) (seeds ``--seed-base + k``, node defaults otherwise: 10 goals, RRT-connect, 2 s
budget), one at a time, and measures the client-side wall time from ``call_async`` to the
response (the operator's wait: request -> trajectory) with a single-threaded client
executor. Figures: p50 / p95 / max of that wait, the node-side ``total_time_s`` and
its goal-sampling / path shares (from the response statistics), and the same requests
planned in this process by ``ReachPlanner`` (same parameters and seeds, no ROS), each
right before its service request, so that both see the same machine load: the
per-request ratio node / in-process is the figure that survives a shared machine.

``--joint-source probe --probe-rate-hz R`` replaces the joint driver by a
``/joint_states`` publisher in this process at R Hz (half-sitting), to see whether the
subscription rate matters; ``--planner-ros-arg name:=value`` overrides a planner
parameter.

Last stdout line: one JSON object.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from humanoid_reach_ros.testing.machine import describe as describe_machine  # noqa: E402
from humanoid_reach_ros.codes import ErrorCode  # noqa: E402
from humanoid_reach_ros.graph import NodeProcess, allocate_domain, graph_env, wait_for  # noqa: E402

PLANNER_PARAMS = REPO / "config" / "reach_planner.yaml"
DRIVER_PARAMS = REPO / "config" / "joint_driver.yaml"


def dist_ms(values_s: list[float]) -> dict:
    a = 1e3 * np.asarray(values_s, dtype=float)
    if not len(a):
        return {}
    return {"p50": float(np.median(a)), "p95": float(np.percentile(a, 95)), "max": float(a.max()),
            "mean": float(a.mean()), "min": float(a.min())}


class Client:
    """This process' rclpy context: a /plan_reach client (and optionally a /joint_states publisher)."""

    def __init__(self, domain_id: int, joint_rate_hz: float | None) -> None:
        import rclpy
        from humanoid_reach_interfaces.srv import PlanReach
        from rclpy.executors import SingleThreadedExecutor

        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node(f"operator_wait_bench_{os.getpid()}", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.client = self.node.create_client(PlanReach, "/plan_reach")
        if joint_rate_hz:
            from rclpy.qos import qos_profile_sensor_data
            from sensor_msgs.msg import JointState

            from humanoid_reach_ros.robot.model import RobotModel

            robot = RobotModel()
            pub = self.node.create_publisher(JointState, "/joint_states", qos_profile_sensor_data)
            names, pos = list(robot.joint_names), [float(x) for x in robot.half_sitting_joints]

            def publish() -> None:
                pub.publish(JointState(name=names, position=pos, velocity=[0.0] * len(names),
                                       header=_header(self.node)))

            self.node.create_timer(1.0 / joint_rate_hz, publish)

    def spin_until(self, cond, timeout: float, what: str, on_timeout=None):
        return wait_for(cond, timeout, what, on_timeout, step=lambda: self.executor.spin_once(timeout_sec=0.002))

    def call(self, req, timeout: float, on_timeout=None):
        """(response, client wall time [s])."""
        t0 = time.perf_counter()
        fut = self.client.call_async(req)
        self.spin_until(fut.done, timeout, "a /plan_reach response", on_timeout)
        return fut.result(), time.perf_counter() - t0

    def close(self) -> None:
        import rclpy

        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def _header(node):
    from std_msgs.msg import Header

    return Header(stamp=node.get_clock().now().to_msg(), frame_id="")


def in_process_planner():
    """A ``ReachPlanner`` in this process with the node's parameters (config YAML) and map."""
    import yaml

    from humanoid_reach_ros.planning.reach import PlannerParams, ReachPlanner

    with open(PLANNER_PARAMS) as f:
        ros_p = yaml.safe_load(f)["/**"]["ros__parameters"]
    fields = {k: ros_p[k] for k in PlannerParams.__dataclass_fields__ if k in ros_p}
    rp = ReachPlanner(params=PlannerParams(**fields))
    from humanoid_reach_ros.nodes.common import scene_file_voxels
    from humanoid_reach_ros.paths import config_path
    rp.set_map(scene_file_voxels(config_path("scenes/plant.yaml"), rp.params.resolution_m,
                                 tuple(ros_p.get("scene_exclude_groups", ["valve"]))))
    rp.warm_up()
    return rp


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--requests", type=int, default=20, help="timed /plan_reach requests (default 20)")
    ap.add_argument("--seed-base", type=int, default=1000, help="request k uses seed seed_base + k")
    ap.add_argument("--timeout-s", type=float, default=60.0, help="wait at most this long for one response [s]")
    ap.add_argument("--joint-source", choices=("driver", "probe"), default="driver",
                    help="/joint_states from the joint_driver process (default) or from this process")
    ap.add_argument("--probe-rate-hz", type=float, default=200.0, help="rate of the probe's /joint_states [Hz]")
    ap.add_argument("--no-in-process", action="store_true", help="skip the in-process comparison")
    ap.add_argument("--planner-ros-arg", action="append", default=[],
                    help="extra '-p name:=value' for reach_planner (repeatable), e.g. goal_count:=10")
    ap.add_argument("--planner-switch-interval-s", type=float, default=None,
                    help="diagnosis: sys.setswitchinterval() in the reach_planner process (via a "
                         "sitecustomize.py on its PYTHONPATH); default: Python's 0.005 s")
    ap.add_argument("--log-dir", default=None, help="node logs here (default: a temporary directory)")
    args = ap.parse_args()
    if args.requests < 1 or args.timeout_s <= 0 or args.probe_rate_hz <= 0:
        ap.error("--requests must be >= 1, --timeout-s and --probe-rate-hz > 0")
    if args.planner_switch_interval_s is not None and not args.planner_switch_interval_s > 0:
        ap.error("--planner-switch-interval-s must be > 0")

    from humanoid_reach_ros.io import msgs
    from humanoid_reach_ros.planning.wgr import valve_region

    region = valve_region()
    log_dir = Path(args.log_dir or tempfile.mkdtemp(prefix="operator_wait_"))
    log_dir.mkdir(parents=True, exist_ok=True)
    lease = allocate_domain()
    env = graph_env(lease.domain_id)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = env["ROS_AUTOMATIC_DISCOVERY_RANGE"]
    procs: list[NodeProcess] = []
    client = None
    seeds = [args.seed_base + k for k in range(args.requests)]
    out: dict = {"bench": "operator_wait", "machine": describe_machine(), "requests": args.requests,
                 "joint_source": args.joint_source if args.joint_source == "driver"
                 else f"probe {args.probe_rate_hz:g} Hz", "log_dir": str(log_dir)}
    try:
        extra = [a for kv in args.planner_ros_arg for a in ("-p", kv)]
        if args.joint_source == "driver":
            procs.append(NodeProcess.start("joint_driver", log_dir, env, DRIVER_PARAMS))
            procs[-1].wait_for_log(r"simulated hrp2", 60.0)
        planner_env = dict(env)
        if args.planner_switch_interval_s is not None:
            site = log_dir / "site"
            site.mkdir(exist_ok=True)
            (site / "sitecustomize.py").write_text(
                f"import sys\nsys.setswitchinterval({args.planner_switch_interval_s!r})\n")
            planner_env["PYTHONPATH"] = os.pathsep.join([str(site), env.get("PYTHONPATH", "")])
            out["planner_switch_interval_s"] = args.planner_switch_interval_s
        t0 = time.perf_counter()
        planner = NodeProcess.start("reach_planner", log_dir, planner_env, PLANNER_PARAMS, extra_ros_args=extra)
        procs.append(planner)
        planner.wait_for_log(r"reach planner ready", 120.0)
        out["planner_start_s"] = time.perf_counter() - t0
        client = Client(lease.domain_id, args.probe_rate_hz if args.joint_source == "probe" else None)
        client.spin_until(client.client.service_is_ready, 60.0, "/plan_reach", planner.log_tail)
        # warm-up (not timed): also waits until the planner has current /joint_states
        deadline = time.monotonic() + 60.0
        while True:
            resp, _ = client.call(msgs.plan_reach_request(region, seed=seeds[0] - 1), args.timeout_s, planner.log_tail)
            if resp.error_code.val != ErrorCode.NO_JOINT_STATES or time.monotonic() > deadline:
                break
            time.sleep(0.2)
        out["warmup_error_code"] = int(resp.error_code.val)
        rp = None
        if not args.no_in_process:
            from humanoid_reach_ros.planning.reach import PlanRequest

            rp = in_process_planner()
            hs = rp.robot.half_sitting_joints
            rp.plan(hs, PlanRequest(region, seed=seeds[0] - 1))
        wall, node_total, goal, path, codes = [], [], [], [], []
        ip_t, ip_goal, ip_path, ip_ok, ratio = [], [], [], 0, []
        for s in seeds:
            if rp is not None:   # the same request in this process, interleaved: same machine load
                t0 = time.perf_counter()
                o = rp.plan(hs, PlanRequest(region, seed=s))
                ip_t.append(time.perf_counter() - t0)
                ip_goal.append(o.stats["goal_sampling_time_s"])
                ip_path.append(o.stats["path_planning_time_s"])
                ip_ok += int(o.success)
            resp, dt = client.call(msgs.plan_reach_request(region, seed=s), args.timeout_s, planner.log_tail)
            if rp is not None:
                ratio.append(resp.statistics.total_time_s / ip_t[-1])
            wall.append(dt)
            st = resp.statistics
            node_total.append(st.total_time_s)
            goal.append(st.goal_sampling_time_s)
            path.append(st.path_planning_time_s)
            codes.append(int(resp.error_code.val))
            print(f"seed {s}: {'SUCCESS' if resp.success else resp.error_code.val} client {1e3 * dt:.0f} ms, node "
                  f"{1e3 * st.total_time_s:.0f} ms (goals {1e3 * st.goal_sampling_time_s:.0f}, path "
                  f"{1e3 * st.path_planning_time_s:.0f})", flush=True)
        ok = sum(c == 0 for c in codes)
        out["service"] = {"success_rate": ok / len(codes), "error_codes": sorted(set(codes)),
                          "wait_ms": dist_ms(wall), "node_total_ms": dist_ms(node_total),
                          "goal_sampling_ms": dist_ms(goal), "path_ms": dist_ms(path),
                          "transport_ms_mean": 1e3 * float(np.mean(np.array(wall) - np.array(node_total)))}
        if rp is not None:
            out["in_process"] = {"what": "same seeds planned by ReachPlanner in this process, each right before "
                                         "its service request", "success_rate": ip_ok / len(seeds),
                                 "wait_ms": dist_ms(ip_t), "goal_sampling_ms": dist_ms(ip_goal),
                                 "path_ms": dist_ms(ip_path)}
            out["node_over_in_process"] = {"per_request_median": float(np.median(ratio)),
                                           "per_request_max": float(np.max(ratio)),
                                           "sum_ratio": float(np.sum(node_total) / np.sum(ip_t))}
        for p in procs:
            if not p.alive():
                raise RuntimeError(f"{p.name} died during the bench\n{p.log_tail()}")
    finally:
        if client is not None:
            client.close()
        for p in reversed(procs):
            p.stop()
        lease.release()
    w = out["service"]["wait_ms"]
    out["targets"] = {"wait_p95_ms<=1000": w["p95"] <= 1000, "wait_p50_ms<=300": w["p50"] <= 300}
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
