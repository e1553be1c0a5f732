"""``hr_graph`` (``make up``): start the whole reaching graph and keep it running until Ctrl-C.

What ``ros2 launch humanoid_reach_ros reach.launch.py`` does on a ROS 2 install, for an
environment without ``launch`` (a pip-installed Jazzy, this repository's ``.venv``): the six
nodes, each a process with its ``config/<name>.yaml`` (``graph.Graph``, the demo's and the
tests' orchestration), and the launch file's arguments: ``--scene FILE`` (its ``scene:=``, to
``scene_sim``, ``reach_planner`` and ``reach_executor``) and ``--no-sim-sensors`` (its
``use_sim_sensors:=false``: no ``joint_driver`` and ``scene_sim``, the real robot's drivers
stand in); ``--robot NAME`` sets every node's ``robot_config``; ``--plant mujoco`` puts the
simulated robot on the MuJoCo physics plant (its ``plant:=``; docs/physics.md); ``--host robot|compute``
starts one host's share (its ``host:=``, ``graph.HOST_NODES``; docs/deployment.md).

A node is *up* when its main interface is visible in the ROS graph, as another shell sees it
(``UP_WHEN``: ``/plan_reach`` of the planner, the ``/look`` and ``/execute_reach`` actions of the
executor, the topic a sensor node publishes). One line per node as it comes up, then ``ready``;
``hr_graph`` then stays until Ctrl-C (or SIGTERM), stops every node in reverse order (SIGINT,
each within ``graph.STOP_DEADLINE_S``) and exits 0. A node that exits by itself is named with
the last lines of its log (stdout and stderr); the others keep running, and the exit code is
then 1. The graph lives in the shell's ``ROS_DOMAIN_ID`` (``. tools/env.sh`` keeps discovery on
localhost), so ``reach_operator`` in another shell reaches it. Node logs: ``--log-dir``
(default ``out/graph``).

Exit codes: 0 stopped by Ctrl-C with every node exiting cleanly; 1 a node exited by itself or
did not stop cleanly; 2 bad arguments.
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import time
from pathlib import Path
from typing import Mapping, TextIO

from humanoid_reach_ros.graph import (ENCLAVE_ENV, HOST_NODES, STOP_DEADLINE_S, Graph, NodeProcess, graph_env,
                                      host_nodes, launch_params, nodes_text)
from humanoid_reach_ros.paths import config_path
from humanoid_reach_ros.robot.spec import robots
from humanoid_reach_ros.sim.physics import PLANTS

# node -> (what shows it is up, names): "pub" topics it publishes, "srv" services it serves
UP_WHEN: dict[str, tuple[str, tuple[str, ...]]] = {
    "joint_driver": ("pub", ("/joint_states",)),
    "scene_sim": ("pub", ("/head_camera/points",)),
    "voxel_mapper": ("pub", ("/voxel_map",)),
    "marker_localizer": ("pub", ("/target_pose",)),
    "reach_planner": ("srv", ("/plan_reach",)),
    "reach_executor": ("srv", ("/execute_reach/_action/send_goal", "/look/_action/send_goal")),
    "operator_console": ("srv", ("/operator_console/get_parameters",)),   # --console (its page: the URL line)
}
WAITING_EVERY_S = 15.0   # while starting: a line naming the nodes not up yet this often
TAIL_LINES = 15          # log lines shown of a node that exited


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="hr_graph", allow_abbrev=False,
                                description="Start the six nodes of the reaching graph (what reach.launch.py "
                                            "starts), each with its config/<name>.yaml, and keep them running "
                                            "until Ctrl-C.")
    p.add_argument("--robot", choices=robots(), help="robot_config of every node (default: the YAML files')")
    p.add_argument("--scene", help="scene file of scene_sim, reach_planner and reach_executor (reach.launch.py's "
                   "scene:=; default: the YAML files', config/scenes/plant.yaml, or the robot's demo_scene)")
    p.add_argument("--plant", choices=PLANTS, default=None,
                   help="what joint_driver simulates (reach.launch.py's plant:=): kinematic (joints where commanded, "
                        "the waist on the feet) or mujoco (a physics plant: servos, contacts, a measured base; "
                        "docs/physics.md); default: config/joint_driver.yaml's (kinematic)")
    p.add_argument("--no-sim-sensors", action="store_true", help="leave out joint_driver and scene_sim "
                   "(reach.launch.py's use_sim_sensors:=false: the real robot's drivers publish)")
    p.add_argument("--host", choices=sorted(HOST_NODES), default="all",
                   help="start only this host's nodes (reach.launch.py's host:=): robot (sensors, driver, mapper, "
                        "localizer, executor), compute (the planner) or all (default); across hosts set "
                        "ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET or ROS_STATIC_PEERS (docs/deployment.md)")
    p.add_argument("--enclave", default="", help="SROS2 enclave of every node (reach.launch.py's enclave:=; "
                   "ROS_SECURITY_ENCLAVE_OVERRIDE), e.g. /humanoid/robot; the shell's ROS_SECURITY_* variables pass "
                   "through untouched (docs/deployment.md)")
    p.add_argument("--console", action="store_true", help="also start operator_console, the operator's console in "
                   "a browser (reach.launch.py's console:=true; docs/operator.md)")
    p.add_argument("--console-port", type=int, default=None, metavar="PORT",
                   help="its port (reach.launch.py's console_port:=; default config/operator_console.yaml's, 8765)")
    p.add_argument("--log-dir", default="out/graph", help="directory of the node logs (default out/graph)")
    a = p.parse_args(argv)
    if a.console_port is not None and not (a.console and 1 <= a.console_port <= 65535):
        p.error(f"--console-port {a.console_port}: needs --console and a port in 1..65535")
    if a.enclave and not a.enclave.startswith("/"):
        p.error(f"--enclave {a.enclave}: an enclave is an absolute name, e.g. /humanoid/robot")
    if a.scene is not None:
        path = config_path(a.scene) if not Path(a.scene).is_file() else Path(a.scene).resolve()
        if not path.is_file():
            p.error(f"--scene {a.scene}: no such file")
        a.scene = str(path)
    elif a.robot is not None:   # a robot too small for the plant names the scene made for its size (demo_scene)
        from humanoid_reach_ros.robot.spec import DEFAULT_DEMO_SCENE, load_robot_spec
        try:
            scene = load_robot_spec(a.robot)[0].demo_scene
        except ValueError as exc:
            p.error(f"--robot {a.robot}: {exc}")
        if Path(scene) != config_path(DEFAULT_DEMO_SCENE):
            a.scene = scene
    return a


class GraphWatch:
    """An rclpy node of this process that looks at the graph (never subscribes)."""

    def __init__(self) -> None:
        import rclpy
        from rclpy.signals import SignalHandlerOptions

        self.rclpy = rclpy
        rclpy.init(args=[], signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node("hr_graph", start_parameter_services=False)

    def up(self, name: str) -> bool:
        kind, names = UP_WHEN[name]
        try:
            if kind == "pub":
                have = {t for t, _ in self.node.get_publisher_names_and_types_by_node(name, "/")}
            else:
                have = {s for s, _ in self.node.get_service_names_and_types_by_node(name, "/")}
        except Exception:  # noqa: BLE001 -- NodeNameNonExistentError: not in the graph yet
            return False
        return all(n in have for n in names)

    def close(self) -> None:
        self.node.destroy_node()
        self.rclpy.try_shutdown()


def report_dead(p: NodeProcess, out: TextIO) -> None:
    tail = p.log().splitlines()[-TAIL_LINES:]
    out.write(f"[hr_graph] {p.name} exited with code {p.proc.returncode}; the last lines of its log "
              f"({p.log_path}):\n" + "".join(f"  | {line}\n" for line in tail))
    out.flush()


def console_port(args: argparse.Namespace) -> int:
    """``--console-port``, else config/operator_console.yaml's port."""
    if args.console_port is not None:
        return int(args.console_port)
    import yaml
    return int(yaml.safe_load(config_path("operator_console.yaml").read_text())["/**"]["ros__parameters"]["port"])


def nodes_env(args: argparse.Namespace, shell: Mapping[str, str]) -> dict[str, str]:
    """The nodes' environment: the shell's (its ``ROS_SECURITY_*`` untouched), its domain, its
    discovery settings where it has them (else localhost), ``--enclave`` as rcl's
    ``ROS_SECURITY_ENCLAVE_OVERRIDE``."""
    env = graph_env(int(shell.get("ROS_DOMAIN_ID") or 0), base=shell)
    for key in ("ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_STATIC_PEERS"):   # the shell's own discovery settings win
        if shell.get(key):
            env[key] = shell[key]
    if args.enclave:
        env[ENCLAVE_ENV] = args.enclave
    return env


def run(args: argparse.Namespace, out: TextIO = sys.stdout) -> int:
    stop: list[int] = []
    old = {s: signal.signal(s, lambda signum, _f: stop.append(signum)) for s in (signal.SIGINT, signal.SIGTERM)}
    log_dir = Path(args.log_dir).resolve()
    log_dir.mkdir(parents=True, exist_ok=True)
    env = nodes_env(args, os.environ)
    domain = env["ROS_DOMAIN_ID"]
    names = list(host_nodes(args.host, sim_sensors=not args.no_sim_sensors))
    console = {"port": args.console_port} if args.console_port is not None else {}
    if args.console:
        names.append("operator_console")
    graph = Graph(log_dir, env, new_session=True)   # Ctrl-C reaches hr_graph, which stops the nodes in order
    watch = None
    dead: set[str] = set()
    t0 = time.monotonic()
    try:
        out.write(f"[hr_graph] starting {nodes_text(len(names))}"
                  + (f" of host {args.host}" if args.host != "all" else "") + f" (ROS_DOMAIN_ID={domain}, discovery "
                  f"{env.get('ROS_AUTOMATIC_DISCOVERY_RANGE', '-')}); logs in {log_dir}/\n")
        out.flush()
        for name in names:
            graph.start(name, {**launch_params(name, args.scene, args.robot, args.plant),
                               **(console if name == "operator_console" else {})})
        watch = GraphWatch()
        pending = list(names)
        ready = False
        next_note = t0 + WAITING_EVERY_S
        while not stop:
            for p in graph.dead():
                if p.name not in dead:
                    dead.add(p.name)
                    report_dead(p, out)
            pending = [n for n in pending if n not in dead]
            for name in [n for n in pending if watch.up(n)]:
                pending.remove(name)
                kind, what = UP_WHEN[name]
                what = ", ".join(x.replace("/_action/send_goal", " (action)") for x in what)
                out.write(f"[hr_graph] {name} up ({time.monotonic() - t0:.1f} s): "
                          f"{'serves' if kind == 'srv' else 'publishes'} {what}\n")
                if name == "operator_console":
                    out.write(f"[hr_graph] the console: open http://127.0.0.1:{console_port(args)}/ "
                              f"(its log: {log_dir}/operator_console.*.log)\n")
                out.flush()
            if not pending and not ready:
                ready = True
                out.write(f"[hr_graph] ready: {nodes_text(len(names) - len(dead))} up in {time.monotonic() - t0:.1f} s"
                          + (f" ({', '.join(sorted(dead))} exited)" if dead else "") + "; Ctrl-C stops them\n")
                out.flush()
            if pending and time.monotonic() > next_note:
                next_note += WAITING_EVERY_S
                out.write(f"[hr_graph] waiting for {', '.join(pending)} ({time.monotonic() - t0:.0f} s)\n")
                out.flush()
            time.sleep(0.1)
        out.write(f"[hr_graph] {signal.Signals(stop[0]).name}: stopping {nodes_text(len(graph.procs))}\n")
        out.flush()
    finally:
        if watch is not None:
            watch.close()
        codes = graph.stop()
        for s, h in old.items():
            signal.signal(s, h)
    for p in graph.procs:
        if p.name not in dead and not p.alive() and p.proc.returncode != 0:
            report_dead(p, out)
    bad = {n: c for n, c in codes.items() if c != 0 or n in dead}
    slow = {p.name: round(p.stop_s, 2) for p in graph.procs if (p.stop_s or 0.0) > STOP_DEADLINE_S}
    out.write(f"[hr_graph] stopped {nodes_text(len(codes))}" + (f"; exit codes {bad}" if bad else " cleanly")
              + (f"; slower than {STOP_DEADLINE_S:g} s to stop: {slow}" if slow else "") + "\n")
    out.flush()
    return 1 if bad else 0


def main(argv: list[str] | None = None) -> int:
    from rclpy.utilities import remove_ros_args

    argv = sys.argv if argv is None else argv
    return run(parse_args(remove_ros_args(argv)[1:]))


if __name__ == "__main__":
    sys.exit(main())

