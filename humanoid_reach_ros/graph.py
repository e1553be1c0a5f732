"""Process orchestration for node graphs: isolated ROS domains and node processes.

Used by the demo (``humanoid_reach_ros.demo``) and by the node-level tests.

* ``allocate_domain`` gives a ``ROS_DOMAIN_ID`` (1..101) that no other process on this
  machine holds (an exclusive lock file per id), and ``graph_env`` the environment for
  it with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` (docs/operator.md: graph isolation)
  and, unless the caller set one, the package's Fast DDS profile (``config/fastdds.xml``:
  large messages over shared memory).
* ``NodeProcess.start`` runs ``python -m humanoid_reach_ros.nodes.<name> --ros-args ...``
  as a real process with its output in a log file; ``stop`` sends SIGINT, waits, kills. A
  node ends with exit code 0 within ``STOP_DEADLINE_S`` of a SIGINT (the demo and
  test_session check it).
* ``wait_for`` polls a condition with a timeout.
* ``Graph`` is the node processes of one run (the demo, ``hr_graph``, benches, tools): each
  node with its ``config/<name>.yaml``, stopped in reverse order; ``GRAPH_NODES`` the six
  nodes of ``launch/reach.launch.py`` and ``launch_params`` the parameters that launch file
  adds to each node's YAML file.

No rclpy here: this module only starts and stops processes.
"""
from __future__ import annotations

import fcntl
import itertools
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, TypeVar

from humanoid_reach_ros.paths import config_path, unique_stamp

PACKAGE_ROOT = Path(__file__).resolve().parent.parent  # the directory holding humanoid_reach_ros/
DOMAIN_MIN, DOMAIN_MAX = 1, 101
_LOCK_DIR = Path(tempfile.gettempdir()) / "humanoid_reach_ros_domains"
_counter = itertools.count()
STOP_DEADLINE_S = 3.0   # a node exits (code 0) within this long of SIGINT
# Fast DDS profile with an 8 MB shared-memory segment: point clouds (0.3-0.84 MB) exceed the
# built-in 0.5 MB and were lost as best-effort UDP fragments (config/fastdds.xml says more)
FASTDDS_PROFILES = PACKAGE_ROOT / "config" / "fastdds.xml"
FASTDDS_PROFILES_ENV = "FASTRTPS_DEFAULT_PROFILES_FILE"
ENCLAVE_ENV = "ROS_SECURITY_ENCLAVE_OVERRIDE"   # rcl: the SROS2 enclave of every node of a process

T = TypeVar("T")


# ---------------------------------------------------------------- waiting
def wait_for(condition: Callable[[], T], timeout: float, what: str = "condition",
             on_timeout: Callable[[], str] | None = None, step: Callable[[], None] | None = None) -> T:
    """Call ``condition`` until it returns a truthy value (returned) or ``timeout`` s pass
    (``AssertionError`` naming ``what``, plus ``on_timeout()`` text, e.g. a node log).
    Between calls ``step()`` runs (default: sleep 10 ms; a probe spins its executor)."""
    deadline = time.monotonic() + timeout
    step = step or (lambda: time.sleep(0.01))
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            extra = f"\n{on_timeout()}" if on_timeout else ""
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what}{extra}")
        step()


# ---------------------------------------------------------------- graph isolation
@dataclass
class DomainLease:
    """An exclusive ``ROS_DOMAIN_ID`` for this process while held."""

    domain_id: int
    _fd: int | None = None

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing drops the flock
            self._fd = None


def allocate_domain() -> DomainLease:
    """Lock a free domain id in 1..101, starting from one derived from pid + a counter."""
    _LOCK_DIR.mkdir(parents=True, exist_ok=True)
    span = DOMAIN_MAX - DOMAIN_MIN + 1
    start = (os.getpid() * 7 + next(_counter)) % span
    for k in range(span):
        domain = DOMAIN_MIN + (start + k) % span
        fd = os.open(_LOCK_DIR / f"{domain}.lock", os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            continue
        return DomainLease(domain, fd)
    raise RuntimeError("no free ROS_DOMAIN_ID in 1..101 (all locked by other tests)")


def graph_env(domain_id: int, base: Mapping[str, str] | None = None) -> dict[str, str]:
    """Environment for processes of an isolated graph (localhost discovery, own domain); every
    other variable of ``base`` (the ``ROS_SECURITY_*`` ones included) passes through untouched."""
    env = dict(os.environ if base is None else base)
    env.update({
        "ROS_DOMAIN_ID": str(domain_id),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
        "PYTHONUNBUFFERED": "1",
        "RCUTILS_COLORIZED_OUTPUT": "0",
        "RCUTILS_LOGGING_BUFFERED_STREAM": "0",
    })
    env.pop("ROS_STATIC_PEERS", None)
    env.setdefault(FASTDDS_PROFILES_ENV, str(FASTDDS_PROFILES))
    path = env.get("PYTHONPATH", "")
    if str(PACKAGE_ROOT) not in path.split(os.pathsep):
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(PACKAGE_ROOT), path) if p)
    return env


# ---------------------------------------------------------------- node processes
def _param_text(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(_param_text(v) for v in value) + "]"
    if isinstance(value, str) and value == "":
        return "''"  # rcl refuses a bare empty value in -p name:=value
    return str(value)


def node_command(module: str, params_file: str | Path | None = None, params: Mapping[str, Any] | None = None,
                 extra_ros_args: list[str] | None = None) -> list[str]:
    """Command line for a node module (``joint_driver`` -> ``humanoid_reach_ros.nodes.joint_driver``)."""
    if "." not in module:
        module = f"humanoid_reach_ros.nodes.{module}"
    cmd = [sys.executable, "-m", module, "--ros-args"]
    if params_file is not None:
        cmd += ["--params-file", str(params_file)]
    for k, v in (params or {}).items():
        cmd += ["-p", f"{k}:={_param_text(v)}"]
    return cmd + list(extra_ros_args or [])


@dataclass
class NodeProcess:
    """A node running as a real process; stdout and stderr go to ``log_path``."""

    name: str
    proc: subprocess.Popen
    log_path: Path
    cmd: list[str] = field(default_factory=list)
    ok_exit_codes: tuple[int, ...] = (0,)  # what teardown accepts (Ctrl-C ends a node with 0); a test may expect others
    stop_s: float | None = None             # SIGINT to exit [s], by stop()

    @classmethod
    def start(cls, module: str, log_dir: Path, env: Mapping[str, str], params_file: str | Path | None = None,
              params: Mapping[str, Any] | None = None, extra_ros_args: list[str] | None = None,
              new_session: bool = False) -> "NodeProcess":
        """``new_session``: the node gets a process group of its own, so a terminal's Ctrl-C
        reaches only the process that started it, which then stops it (``hr_graph``)."""
        cmd = node_command(module, params_file, params, extra_ros_args)
        name = module.rsplit(".", 1)[-1]
        log_path = Path(log_dir) / unique_stamp(log_dir, ".log", f"{name}.")   # joint_driver.20261128-101500.log
        with open(log_path, "wb") as log:
            proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                    env=dict(env), cwd=PACKAGE_ROOT, start_new_session=new_session)
        return cls(name, proc, log_path, cmd)

    @property
    def pid(self) -> int:
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def log(self) -> str:
        try:
            return self.log_path.read_text(errors="replace")
        except FileNotFoundError:
            return ""

    def log_tail(self, lines: int = 60) -> str:
        text = self.log().splitlines()[-lines:]
        return f"--- log of {self.name} (pid {self.pid}, {self.log_path}) ---\n" + "\n".join(text)

    def log_lines(self, pattern: str) -> list[str]:
        rx = re.compile(pattern)
        return [line for line in self.log().splitlines() if rx.search(line)]

    def wait_for_log(self, pattern: str, timeout: float = 20.0) -> str:
        """First log line matching ``pattern``; fails early if the process exits."""
        def found() -> str | None:
            lines = self.log_lines(pattern)
            if lines:
                return lines[0]
            if not self.alive():
                raise AssertionError(f"{self.name} exited with {self.proc.returncode} before logging "
                                     f"{pattern!r}\n{self.log_tail()}")
            return None
        return wait_for(found, timeout, f"{self.name} to log {pattern!r}", on_timeout=self.log_tail)

    def stop(self, timeout: float = 10.0) -> int:
        """SIGINT (Ctrl-C), wait ``timeout`` s, then SIGKILL. Returns the exit code; ``stop_s``
        is how long the process took to exit after the SIGINT."""
        if self.alive():
            t0 = time.monotonic()
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5.0)
            self.stop_s = time.monotonic() - t0
        return self.proc.returncode

    def exited_cleanly(self) -> bool:
        return self.proc.returncode in self.ok_exit_codes


# ---------------------------------------------------------------- a graph of node processes
def nodes_text(n: int) -> str:
    """``1 node``, ``6 nodes``: a count of nodes in a line."""
    return f"{n} node{'' if n == 1 else 's'}"


# the six nodes of launch/reach.launch.py, in its order; the first two are the simulated robot and
# head sensors (its use_sim_sensors:=false leaves them out: the real robot's drivers stand in)
GRAPH_NODES = ("joint_driver", "scene_sim", "voxel_mapper", "marker_localizer", "reach_planner", "reach_executor")
SIM_NODES = ("joint_driver", "scene_sim")
SCENE_NODES = ("scene_sim", "reach_planner", "reach_executor")   # the launch file's scene:= goes to these
# where each node runs when the graph spans hosts (reach.launch.py host:=, hr_graph --host; docs/deployment.md):
# the robot's computers keep everything with a deadline or a sensor, the planner may run beside the operator
HOST_NODES = {
    "all": GRAPH_NODES,
    "robot": ("joint_driver", "scene_sim", "voxel_mapper", "marker_localizer", "reach_executor"),
    "compute": ("reach_planner",),
}


def host_nodes(host: str, sim_sensors: bool = True) -> tuple[str, ...]:
    """The graph's nodes on ``host`` (``HOST_NODES``), in launch order; without ``sim_sensors``
    the simulated robot and head sensors are left out (the real robot's drivers stand in)."""
    if host not in HOST_NODES:
        raise ValueError(f"host must be one of {sorted(HOST_NODES)}, got {host!r}")
    return tuple(n for n in GRAPH_NODES if n in HOST_NODES[host] and (sim_sensors or n not in SIM_NODES))


def launch_params(name: str, scene: str | Path | None = None, robot: str | None = None,
                  plant: str | None = None) -> dict[str, Any]:
    """What ``reach.launch.py`` gives node ``name`` besides its YAML file: ``scene_file`` (its
    ``scene:=``) for the nodes that read a scene; ``robot_config`` when a robot is named; the
    joint driver's ``plant`` (its ``plant:=``, kinematic or mujoco) and, with a scene, the scene
    the physics plant stands in (``physics_scene``: the one the sensors render)."""
    params: dict[str, Any] = {}
    if scene is not None and name in SCENE_NODES:
        params["scene_file"] = str(scene)
    if robot is not None:
        params["robot_config"] = robot
    if plant is not None and name == "joint_driver":
        params["plant"] = plant
        if scene is not None:
            params["physics_scene"] = str(scene)
    return params


@dataclass
class Graph:
    """The node processes of one run; ``stop()`` shuts them down in reverse order."""

    out: Path
    env: dict[str, str]
    procs: list[NodeProcess] = field(default_factory=list)
    new_session: bool = False   # each node in a process group of its own (NodeProcess.start)

    def start(self, module: str, params: dict[str, Any] | None = None) -> NodeProcess:
        """``module`` with its ``config/<name>.yaml`` (if there is one) and ``params`` on top."""
        name = module.rsplit(".", 1)[-1]
        params_file = config_path(f"{name}.yaml")
        proc = NodeProcess.start(module, self.out, self.env, params_file if params_file.is_file() else None,
                                 params, new_session=self.new_session)
        self.procs.append(proc)
        return proc

    def start_command(self, name: str, cmd: list[str]) -> NodeProcess:
        log_path = self.out / f"{name}.log"
        with open(log_path, "wb") as log:
            p = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=self.env)
        proc = NodeProcess(name, p, log_path, cmd)
        self.procs.append(proc)
        return proc

    def dead(self) -> list[NodeProcess]:
        """The processes that have exited."""
        return [p for p in self.procs if not p.alive()]

    def check_alive(self) -> None:
        for p in self.procs:
            if not p.alive():
                raise RuntimeError(f"{p.name} exited with code {p.proc.returncode}\n{p.log_tail(30)}")

    def log_tails(self) -> str:
        return "\n".join(p.log_tail(15) for p in self.procs)

    def stop(self) -> dict[str, int]:
        return {p.name: p.stop() for p in reversed(self.procs)}
