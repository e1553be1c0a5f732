"""Shared pytest fixtures.

Node-level tests::

    def test_x(start_node, ros_probe):
        driver = start_node("joint_driver", params_file="config/joint_driver.yaml",
                            params={"command_timeout_s": 5.0}, ready_log="simulated")
        states = ros_probe.collect(JointState, "/joint_states")
        ros_probe.spin_until(lambda: len(states) > 10, timeout=10, what="joint states")

``ros_env`` isolates the graph (own ``ROS_DOMAIN_ID``, localhost discovery) for the
test process itself and every node it starts; ``start_node`` stops the nodes at
teardown with SIGINT, checks they exited cleanly, and prints their logs when the
test failed.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping

import pytest

_TEST_DIR = Path(__file__).resolve().parent
for _p in (_TEST_DIR, _TEST_DIR.parent):  # test/nodetools and the package from the checkout
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))

from nodetools import REPO_ROOT, NodeProcess, RosProbe, allocate_domain, graph_env, wait_for  # noqa: E402


#: the test files that take longest (seconds summed over their tests, a fresh clone, 2026-11-27),
#: heaviest first: ``make test``'s pytest-xdist ``loadfile --no-loadscope-reorder`` hands files out
#: in collection order, so these go first and the short ones fill the gaps (longest processing time
#: first: the two workers end together. xdist's default order, most tests first, ran these one-test
#: graph files last, one worker idle meanwhile)
HEAVY_FIRST = ("test_session.py", "test_operator_marker.py", "test_hosts.py", "test_bag_replay.py",
               "test_fault_tolerance.py", "test_voxel_mapper_node.py", "test_reach_operator.py", "test_demo.py",
               "test_perception_graph.py", "test_operator_console.py", "test_joint_driver_node.py",
               "test_reach_executor_node.py",
               "test_marker_localizer_node.py", "test_dual_arm_node.py", "test_executor.py", "test_mcap_bag.py",
               "test_graph_up.py", "test_scene_suite.py")


def pytest_collection_modifyitems(session: pytest.Session, config: pytest.Config, items: list[pytest.Item]) -> None:
    """The heavy files first (``HEAVY_FIRST``); the rest, and the tests within a file, keep their order."""
    rank = {name: i for i, name in enumerate(HEAVY_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


@pytest.hookimpl(wrapper=True, tryfirst=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo) -> Any:
    """Keep each phase's report on the item so fixtures can tell whether the test failed."""
    rep = yield
    setattr(item, f"rep_{rep.when}", rep)
    return rep


def _test_failed(request: pytest.FixtureRequest) -> bool:
    return any(getattr(getattr(request.node, f"rep_{w}", None), "failed", False) for w in ("setup", "call"))


@pytest.fixture(scope="module")
def robot():
    """The HRP-2-class RobotModel, one per test module."""
    from humanoid_reach_ros.robot.model import RobotModel

    return RobotModel()


@pytest.fixture(scope="module")
def cm(robot):
    """The robot's default collision model, one per test module."""
    from humanoid_reach_ros.robot.shapes import load_collision_model

    return load_collision_model(None, robot)


@pytest.fixture
def ros_env(monkeypatch: pytest.MonkeyPatch) -> Iterator[dict[str, str]]:
    """Environment of an isolated ROS graph: a domain id locked for this test (1..101) and
    ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``; also applied to this process' environment
    so that the test's own rclpy context joins the same graph."""
    lease = allocate_domain()
    env = graph_env(lease.domain_id)
    for key in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE"):
        monkeypatch.setenv(key, env[key])
    monkeypatch.delenv("ROS_STATIC_PEERS", raising=False)
    try:
        yield env
    finally:
        lease.release()


@pytest.fixture
def ros_domain_id(ros_env: Mapping[str, str]) -> int:
    return int(ros_env["ROS_DOMAIN_ID"])


@pytest.fixture
def ros_probe(ros_domain_id: int) -> Iterator[RosProbe]:
    """The test's own rclpy context and node in the isolated graph."""
    probe = RosProbe(ros_domain_id, name=f"test_probe_{os.getpid()}")
    try:
        yield probe
    finally:
        probe.close()


StartNode = Callable[..., NodeProcess]


@pytest.fixture
def start_node(ros_env: Mapping[str, str], tmp_path: Path, request: pytest.FixtureRequest) -> Iterator[StartNode]:
    """Factory: ``start_node(module_or_exe, params_file=None, params=None, env=None,
    ready_log=None, ready=None, timeout=30.0)`` starts
    ``python -m humanoid_reach_ros.nodes.<name> --ros-args ...`` as a real process.

    It waits until a log line matches ``ready_log`` and/or ``ready()`` is truthy.
    At teardown every started node still running gets SIGINT (then SIGKILL after 10 s); a
    node whose exit code is not 0 fails the test (Ctrl-C ends a node with 0), and logs are printed on failure.
    """
    started: list[NodeProcess] = []

    def start(module_or_exe: str, params_file: str | Path | None = None, params: Mapping[str, Any] | None = None,
              env: Mapping[str, str] | None = None, ready_log: str | None = None,
              ready: Callable[[], Any] | None = None, timeout: float = 30.0,
              extra_ros_args: list[str] | None = None) -> NodeProcess:
        if params_file is not None and not Path(params_file).is_absolute():
            params_file = REPO_ROOT / params_file
        proc = NodeProcess.start(module_or_exe, tmp_path, env or ros_env, params_file, params, extra_ros_args)
        started.append(proc)
        if ready_log is not None:
            proc.wait_for_log(ready_log, timeout)
        if ready is not None:
            wait_for(ready, timeout, f"{proc.name} ready", on_timeout=proc.log_tail)
        return proc

    yield start

    problems = []
    for proc in reversed(started):
        was_alive = proc.alive()
        code = proc.stop()
        if not proc.exited_cleanly():
            how = "exited by itself" if not was_alive else "stopped by SIGINT"
            problems.append(f"{proc.name} (pid {proc.pid}) {how} with exit code {code}")
    if problems or _test_failed(request):
        for proc in started:
            print(proc.log_tail(200))
    assert not problems, "; ".join(problems) + "\n" + "\n".join(p.log_tail() for p in started)
