"""Node-level tests of reach_planner: real joint_driver + reach_planner processes in an
isolated graph, probed over ROS (service calls, topics, logs, diagnostics)."""
from __future__ import annotations

import contextlib
import math
import re
import time

import numpy as np
import pinocchio as pin
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from humanoid_reach_interfaces.srv import PlanReach
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2
from trajectory_msgs.msg import JointTrajectory
from visualization_msgs.msg import Marker, MarkerArray

from humanoid_reach_ros.geometry.voxels import without_target
from humanoid_reach_ros.codes import ErrorCode, code_name
from humanoid_reach_ros.io import msgs
from humanoid_reach_ros.nodes import reach_planner
from humanoid_reach_ros.planning.wgr import valve_region
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.sim.scene import load_scene
from nodetools import REPO_ROOT

E = ErrorCode
PARAMS_FILE = "config/reach_planner.yaml"
DRIVER_PARAMS = "config/joint_driver.yaml"
READY = r"reach planner ready"
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
# joint_states_timeout_s: a loaded 2-core CI machine can starve a subscriber for over a second;
# these tests are about results, and staleness itself is tested in process below.
FAST_DIAG = {"diagnostics_period_s": 0.2, "joint_states_timeout_s": 5.0}
# Generous: these tests assert correctness, not speed (bench/planning.py measures that). Inside the
# node, requests after the first run several times slower than in-process (open in issue #3), and a
# loaded 2-core CI machine must not turn a reachable valve into NO_GOAL_FOUND or NO_PATH.
SUCCESS_BUDGET_S = 20.0


@pytest.fixture(scope="module")
def model() -> RobotModel:
    return RobotModel()


def test_config_matches_declared_defaults() -> None:
    """config/reach_planner.yaml lists every parameter with the node's default."""
    doc = yaml.safe_load((REPO_ROOT / PARAMS_FILE).read_text())["/**"]["ros__parameters"]
    defaults = {k: spec.default for k, spec in reach_planner.PARAMETERS.items()}
    assert doc == defaults
    assert set(reach_planner.PLANNER_PARAMETERS) <= {f for f in reach_planner.PlannerParams.__dataclass_fields__}


# ---------------------------------------------------------------- helpers
class Planner:
    """Client side of one reach_planner process."""

    def __init__(self, probe, proc) -> None:
        self.probe, self.proc = probe, proc
        self.client = probe.node.create_client(PlanReach, "/plan_reach")
        probe.spin_until(self.client.service_is_ready, 15.0, "/plan_reach", on_timeout=proc.log_tail)

    def call_async(self, req: PlanReach.Request):
        return self.client.call_async(req)

    def wait(self, future, timeout: float = 30.0) -> PlanReach.Response:
        self.probe.spin_until(future.done, timeout, "a /plan_reach response", on_timeout=self.proc.log_tail)
        return future.result()

    def call(self, req: PlanReach.Request, timeout: float = 30.0) -> PlanReach.Response:
        """One request; asked again (at most twice) when no response comes within a third of
        ``timeout``: a fresh client's first response can be lost on a loaded machine (the server
        logs "failed to send response (timeout)": it had not matched the client's response reader
        yet; ci2, fresh clone: the planner answered SUCCESS in 44 ms, the probe never saw it)."""
        for attempt in range(3):
            future = self.call_async(req)
            try:
                return self.wait(future, timeout / 3 if attempt < 2 else timeout)
            except AssertionError:
                if attempt == 2:
                    raise
                self.client.remove_pending_request(future)
        raise AssertionError("unreachable")

    def wait_log_count(self, pattern: str, count: int, timeout: float = 20.0) -> list[str]:
        return self.probe.spin_until(
            lambda: (lines := self.proc.log_lines(pattern)) and len(lines) >= count and lines,
            timeout, f"{count} log line(s) {pattern!r}", on_timeout=self.proc.log_tail)


def valve_request(**kw) -> PlanReach.Request:
    return msgs.plan_reach_request(valve_region(), "world", **kw)


def status(diags, suffix: str):
    for arr in reversed(diags.messages):
        for st in arr.status:
            if st.name.endswith(suffix):
                return st
    return None


def start_driver(start_node, probe):
    driver = start_node("joint_driver", params_file=DRIVER_PARAMS, ready_log=r"simulated hrp2")
    return driver


def wait_inputs_ok(probe, diags, proc) -> None:
    """Until the planner's inputs diagnostic says the joint states are current."""
    probe.spin_until(lambda: (st := status(diags, ": inputs")) is not None
                     and msgs.diagnostic_level(st) == msgs.LEVEL_OK,
                     20.0, "reach_planner to receive /joint_states", on_timeout=proc.log_tail)


def check_trajectory(resp: PlanReach.Response, model: RobotModel, start: np.ndarray) -> msgs.TrajectoryArrays:
    traj = msgs.parse_joint_trajectory(resp.trajectory)
    assert resp.trajectory.header.frame_id == "world"
    assert traj.names == model.joint_names and traj.positions.shape[1] == 30
    assert len(traj.times) >= 2 and traj.times[0] == 0.0 and np.all(np.diff(traj.times) > 0)
    assert traj.velocities.shape == traj.accelerations.shape == traj.positions.shape
    np.testing.assert_allclose(traj.positions[0], start, atol=1e-6)
    assert np.all(traj.positions >= model.lower - 1e-6) and np.all(traj.positions <= model.upper + 1e-6)
    return traj


# ---------------------------------------------------------------- tests
@pytest.mark.node
def test_valve_plan_execute_markers_and_bad_requests(start_node, ros_probe, model) -> None:
    start_driver(start_node, ros_probe)
    diags = ros_probe.collect(DiagnosticArray, "/diagnostics")
    proc = start_node("reach_planner", params_file=PARAMS_FILE, params=FAST_DIAG, ready_log=READY)
    assert re.search(r"map source: scene file .*plant\.yaml \((\d+) voxels", proc.log())
    planner = Planner(ros_probe, proc)
    trajectories = ros_probe.collect(JointTrajectory, "/reach_trajectory",
                                     QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE))
    markers = ros_probe.collect(MarkerArray, "/planning/markers", LATCHED)
    wait_inputs_ok(ros_probe, diags, proc)

    # the valve WGR of eq. 3
    resp = planner.call(valve_request(time_budget_s=SUCCESS_BUDGET_S))
    assert resp.success and resp.error_code.val == E.SUCCESS, (resp.error_code.val, resp.message)
    traj = check_trajectory(resp, model, model.half_sitting_joints)
    assert resp.arm in (PlanReach.Request.ARM_RIGHT, PlanReach.Request.ARM_LEFT) and resp.message
    s = resp.statistics
    assert s.goals_found >= 1 and s.path_waypoints >= 2 and s.map_voxels > 10_000 and s.collision_checks > 0
    assert s.total_time_s >= s.path_planning_time_s > 0.0
    assert resp.waist_start.header.frame_id == "world"
    assert msgs.se3_from_pose(resp.waist_start).isApprox(model.base_on_feet(model.half_sitting_joints), 1e-6)
    print(f"\nvalve plan: {resp.message} ({len(traj.times)} points, {traj.times[-1]:.2f} s, "
          f"total {s.total_time_s * 1e3:.0f} ms)")
    assert len(trajectories) == 0  # not executed
    assert proc.wait_for_log(r"plan_reach #1: SUCCESS \(0\) in \d+ ms")

    # markers: region, goal hand poses, hand path ending in the region
    def plan_markers():
        m = markers.last
        return m if m is not None and any(x.ns == "hand_path" for x in m.markers) else None

    arr = ros_probe.spin_until(plan_markers, 10.0, "/planning/markers with a hand path")
    by_ns = {}
    for m in arr.markers[1:]:
        by_ns.setdefault(m.ns, []).append(m)
    assert arr.markers[0].action == Marker.DELETEALL
    assert len(by_ns["goal_hand_poses"]) == s.goals_found and by_ns["target_region"][0].type == Marker.CUBE
    end = by_ns["hand_path"][0].points[-1]
    assert math.dist((end.x, end.y, end.z), (0.71, 0.03, 0.90)) < 0.01

    # execute -> /reach_trajectory
    ros_probe.spin_until(lambda: ros_probe.node.count_publishers("/reach_trajectory") > 0, 10.0,
                         "reach_trajectory publisher")
    resp = planner.call(valve_request(execute=True, seed=3, arm=PlanReach.Request.ARM_RIGHT,
                                      time_budget_s=SUCCESS_BUDGET_S))
    assert resp.success, resp.message
    assert resp.arm == PlanReach.Request.ARM_RIGHT
    ros_probe.spin_until(lambda: len(trajectories) > 0, 10.0, "/reach_trajectory")
    published = msgs.parse_joint_trajectory(trajectories.last)
    np.testing.assert_allclose(published.positions, msgs.parse_joint_trajectory(resp.trajectory).positions)

    # bad requests: each its own code, the node keeps serving
    def nan_target(r):
        r.region.target.pose.position.x = math.nan

    def lower_gt_upper(r):
        r.region.lower = [0.1, 0.0, 0.0, -1.0, -1.0, -1.0]

    def map_frame(r):
        r.region.target.header.frame_id = "map"

    def arm7(r):
        r.arm = 7

    def planner_foo(r):
        r.planner = "foo"

    def marker_target(r):
        r.use_marker_target = True

    for mutate, code in [(nan_target, E.INVALID_REQUEST), (lower_gt_upper, E.INVALID_BOUNDS),
                         (map_frame, E.UNKNOWN_FRAME), (arm7, E.INVALID_REQUEST), (planner_foo, E.INVALID_REQUEST),
                         (marker_target, E.NO_TARGET)]:
        req = valve_request()
        mutate(req)
        resp = planner.call(req)
        assert not resp.success and resp.error_code.val == code, (mutate.__name__, resp.error_code.val, resp.message)
        assert resp.message and len(resp.trajectory.points) == 0
        print(f"{mutate.__name__}: {code_name(resp.error_code.val)}: {resp.message}")

    # use_marker_target with a current /target_pose: the marker pose replaces region.target
    target_pub = ros_probe.node.create_publisher(PoseStamped, "/target_pose", 10)
    ros_probe.spin_until(lambda: target_pub.get_subscription_count() > 0, 10.0, "/target_pose subscription")
    valve_pose = msgs.pose_stamped(pin.SE3(np.eye(3), np.array([0.71, 0.03, 0.90])), "world")
    req = valve_request(use_marker_target=True, time_budget_s=SUCCESS_BUDGET_S)
    req.region.target.header.frame_id = "camera"  # ignored with use_marker_target
    req.region.target.pose.position.x = 5.0

    def marker_plan():
        target_pub.publish(valve_pose)
        resp = planner.call(req)
        return None if resp.error_code.val == E.NO_TARGET else resp

    resp = ros_probe.spin_until(marker_plan, 20.0, "a plan to the /target_pose")
    assert resp.success, resp.message

    # a base_link target: the valve expressed in the waist frame gives the same region
    waist = model.base_on_feet(model.half_sitting_joints)
    region_b = valve_region(waist.inverse() * pin.SE3(np.eye(3), np.array([0.71, 0.03, 0.90])))
    resp = planner.call(msgs.plan_reach_request(region_b, "base_link", seed=1, time_budget_s=SUCCESS_BUDGET_S))
    assert resp.success, resp.message
    assert proc.alive()

    def planning_after_last_request():
        # the diagnostic is periodic: the latest one may predate the last request's response
        st = status(diags, ": planning")
        return st if st is not None and int(msgs.diagnostic_values(st)["successes"]) >= 4 else None

    planning = ros_probe.spin_until(planning_after_last_request, 10.0, "planning diagnostic counting 4 successes")
    values = msgs.diagnostic_values(planning)
    assert int(values["successes"]) == 4 and int(values["requests"]) >= 10
    assert values["last_result"] == "SUCCESS"
    assert "scene file" in msgs.diagnostic_values(status(diags, ": map"))["source"]


def box_voxels(lo, hi, h: float = 0.02) -> np.ndarray:
    axes = [np.arange(a + h / 2, b, h) for a, b in zip(lo, hi)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


@pytest.mark.node
def test_voxel_map_switch_collision_busy_and_malformed(start_node, ros_probe, model) -> None:
    diags = ros_probe.collect(DiagnosticArray, "/diagnostics")
    proc = start_node("reach_planner", params_file=PARAMS_FILE, params={**FAST_DIAG, "scene_file": ""},
                      ready_log=READY)
    assert proc.log_lines("map source: none yet")
    planner = Planner(ros_probe, proc)

    # no joint_driver yet
    resp = planner.call(valve_request())
    assert resp.error_code.val == E.NO_JOINT_STATES, resp.message
    st = ros_probe.spin_until(lambda: status(diags, ": map"), 5.0, "map diagnostic")
    assert msgs.diagnostic_level(st) == msgs.LEVEL_WARN and "no map" in st.message

    start_driver(start_node, ros_probe)
    wait_inputs_ok(ros_probe, diags, proc)
    resp = planner.call(valve_request())
    assert resp.error_code.val == E.NO_MAP, resp.message

    map_pub = ros_probe.node.create_publisher(PointCloud2, "/voxel_map", LATCHED)

    # voxels around the waist -> the start posture collides
    inside = box_voxels((-0.1, -0.1, 0.7), (0.06, 0.1, 0.8))
    map_pub.publish(msgs.cloud_from_points(inside, "world"))
    line = planner.wait_log_count(r"map source: /voxel_map", 1)[-1]
    assert f"({len(inside)} voxels" in line
    # unobserved space (unobserved_space: occupied, the default): a /voxel_map without the mapper's
    # unobserved layers cannot tell observed from unobserved space; a target inside an unobserved block
    resp = planner.call(valve_request())
    assert resp.error_code.val == E.UNOBSERVED_SPACE and "no /voxel_map/unobserved" in resp.message, resp.message
    frontier_pub = ros_probe.node.create_publisher(PointCloud2, "/voxel_map/unobserved", LATCHED)
    blocks_pub = ros_probe.node.create_publisher(PointCloud2, "/voxel_map/unobserved_blocks", LATCHED)
    target = valve_region().target_p
    frontier_pub.publish(msgs.cloud_from_points(np.empty((0, 3)), "world"))
    blocks_pub.publish(msgs.cloud_from_points(np.array([target + 0.03, [5.0, 5.0, 5.0]]), "world"))
    resp = ros_probe.spin_until(lambda: (r := planner.call(valve_request())).error_code.val == E.UNOBSERVED_SPACE
                                and "lies in space the head has not observed" in r.message and r, 20.0,
                                "the unobserved target refused", on_timeout=proc.log_tail)
    assert "scan (--scan)" in resp.message and "0.1 m block around" in resp.message, resp.message
    assert len(resp.unobserved_points) == 1, resp.unobserved_points   # where to look
    blocks_pub.publish(msgs.cloud_from_points(np.array([[5.0, 5.0, 5.0]]), "world"))   # the target is observed
    resp = ros_probe.spin_until(lambda: (r := planner.call(valve_request())).error_code.val != E.UNOBSERVED_SPACE
                                and r, 20.0, "the target observed", on_timeout=proc.log_tail)
    assert resp.error_code.val == E.START_IN_COLLISION, resp.message
    assert resp.statistics.map_voxels == len(inside)
    broken = msgs.cloud_from_points(np.ones((4, 3)), "map")                          # wrong frame: kept the old one
    blocks_pub.publish(broken)
    planner.wait_log_count(r"rejected /voxel_map/unobserved_blocks: frame_id 'map'", 1)
    assert planner.call(valve_request()).error_code.val == E.START_IN_COLLISION
    st = ros_probe.spin_until(lambda: (s := status(diags, ": map")) and "/voxel_map" in s.message and s,
                              5.0, "map diagnostic from /voxel_map")
    assert int(msgs.diagnostic_values(st)["voxels"]) == len(inside)

    # malformed: no z field -> warning, old map kept
    bad = msgs.cloud_from_points(np.ones((10, 3)), "world")
    bad.fields = bad.fields[:2]
    map_pub.publish(bad)
    planner.wait_log_count(r"rejected /voxel_map .*no z field.*keeping the previous map", 1)
    assert proc.alive()
    resp = planner.call(valve_request())
    assert resp.error_code.val == E.START_IN_COLLISION and resp.statistics.map_voxels == len(inside)

    # the plant scene with a wall between the robot and the valve -> no reach; a second
    # request during that plan gets BUSY
    scene = load_scene(REPO_ROOT / "config/scenes/plant.yaml").voxelize(0.02, exclude_groups=("valve",))
    wall = box_voxels((0.45, -1.0, 0.0), (0.47, 1.0, 2.0))
    walled = np.concatenate([scene, wall])
    map_pub.publish(msgs.cloud_from_points(walled, "world"))
    # a second /voxel_map is a repetition (logged at DEBUG): its arrival shows in the diagnostics
    ros_probe.spin_until(lambda: (s := status(diags, ": map")) and "/voxel_map" in s.message
                         and int(msgs.diagnostic_values(s)["voxels"]) == len(walled), 20.0,
                         "map diagnostic of the walled scene", on_timeout=proc.log_tail)
    assert len(proc.log_lines(r"map source: /voxel_map")) == 1      # state changes at INFO only
    first = planner.call_async(valve_request(time_budget_s=1.5))
    second = planner.call_async(valve_request())
    r1, r2 = planner.wait(first), planner.wait(second)
    codes = sorted([r1.error_code.val, r2.error_code.val])
    print(f"\nwall: {r1.error_code.val} {r1.message!r}; concurrent: {r2.error_code.val} {r2.message!r}")
    assert E.BUSY in codes, codes
    blocked = r1 if r2.error_code.val == E.BUSY else r2
    assert blocked.error_code.val in (E.NO_GOAL_FOUND, E.NO_PATH), blocked.message
    # the voxels around the valve target are left out (target_exclusion_radius_m)
    kept = without_target(walled, valve_region().target_p, 0.15)
    assert len(kept) < len(walled) and blocked.statistics.map_voxels == len(kept)
    assert proc.alive()


@contextlib.contextmanager
def planner_in_process(ros_env, standing: bool = True):
    """A ``ReachPlannerNode`` in this process, on its own context in the test's domain; ``standing``:
    its start posture is half-sitting (no /joint_states needed)."""
    import rclpy

    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=int(ros_env["ROS_DOMAIN_ID"]))
    try:
        node = reach_planner.ReachPlannerNode(context=ctx)
        if standing:
            node.current_joints = lambda: (node.model.half_sitting_joints.copy(), "")
        yield node
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


def test_exception_in_planning_is_internal_error(ros_env) -> None:
    """In process: a planner that raises -> INTERNAL_ERROR with the message; the next request is served."""
    with planner_in_process(ros_env) as node:
        node.planner.set_map(np.empty((0, 3)))
        calls = []

        def broken(joints, request):
            calls.append(request)
            raise RuntimeError("boom")

        real_plan, node.planner.plan = node.planner.plan, broken
        resp = node._on_plan_reach(valve_request(), PlanReach.Response())
        assert resp.error_code.val == E.INTERNAL_ERROR and not resp.success and "boom" in resp.message
        assert calls and calls[0].arm == "auto" and calls[0].seed is None
        node.planner.plan = real_plan
        resp = node._on_plan_reach(valve_request(goal_count=3), PlanReach.Response())
        assert resp.success and resp.statistics.goals_requested == 3, resp.message
        statuses = {st.name.split(": ")[1]: st for st in node.diagnostic_statuses()}
        assert msgs.diagnostic_values(statuses["planning"])["last_result"] == "SUCCESS"


def test_a_refused_retreat_logs_every_retreat_tried(ros_env) -> None:
    """In process: START_IN_COLLISION with more retreats tried than the answer keeps -> one more
    INFO line holding all of them, numbered (the answer is unchanged)."""
    from humanoid_reach_ros.codes import PlanError
    from humanoid_reach_ros.planning.reach import PlanOutcome

    with planner_in_process(ros_env) as node:
        node.planner.set_map(np.empty((0, 3)))
        tried = tuple(f"direction {k}: the arm cannot follow the line beyond {k} mm (IK, limits)" for k in range(9))
        message = "the right hand touches the map and no retreat frees it: " + "; ".join(tried[:6]) + "; ... 3 more"
        node.planner.plan = lambda joints, request: PlanOutcome(
            False, PlanError.START_IN_COLLISION, message, None, node.model.joint_names, retreats_tried=tried)
        lines = []

        class Recorder:
            def __getattr__(self, level):
                return lambda text, **_: lines.append((level, text))
        node.get_logger = lambda: Recorder()
        resp = node._on_plan_reach(valve_request(), PlanReach.Response())
        assert resp.error_code.val == E.START_IN_COLLISION and resp.message == message
        every = [text for level, text in lines if "retreats tried" in text]
        assert len(every) == 1 and "the 9 retreats tried: 1) direction 0" in every[0], lines
        assert all(f"{k + 1}) {why}" in every[0] for k, why in enumerate(tried))
        lines.clear()
        node.planner.plan = lambda joints, request: PlanOutcome(
            False, PlanError.NO_PATH, "no path", None, node.model.joint_names)
        node._on_plan_reach(valve_request(), PlanReach.Response())
        assert not [t for _, t in lines if "retreats tried" in t]


def test_stale_inputs_in_order(ros_env) -> None:
    """In process: a stale /joint_states is NO_JOINT_STATES; a missing marker target is reported first."""
    with planner_in_process(ros_env, standing=False) as node:
        model = node.model
        node.joint_states.put(msgs.joint_state(model.joint_names, model.half_sitting_joints),
                              time.monotonic() - 2.0 * node._p["joint_states_timeout_s"])
        resp = node._on_plan_reach(valve_request(), PlanReach.Response())
        assert resp.error_code.val == E.NO_JOINT_STATES and "stale" in resp.message, resp.message
        resp = node._on_plan_reach(valve_request(use_marker_target=True), PlanReach.Response())
        assert resp.error_code.val == E.NO_TARGET and "/target_pose" in resp.message, resp.message
        node.joint_states.put(msgs.joint_state(model.joint_names, model.half_sitting_joints))
        joints, reason = node.current_joints()
        assert reason == "" and np.allclose(joints, model.half_sitting_joints)


def test_measured_map_leaves_the_target_object_out(ros_env) -> None:
    """In process: voxels of a /voxel_map around the request's target (the valve, in a measured map)
    are left out of the planner's map (target_exclusion_radius_m), per target; 0 keeps them all."""
    from rclpy.parameter import Parameter

    with planner_in_process(ros_env) as node:
        # a scene's voxels as /voxel_map: no unobserved layers, so the permissive policy (set at run time)
        bad = node.set_parameters([Parameter("unobserved_space", value="maybe")])[0]
        assert not bad.successful and "unobserved_space must be one of" in bad.reason
        assert node.set_parameters([Parameter("unobserved_space", value="free")])[0].successful
        full = load_scene(REPO_ROOT / "config/scenes/plant.yaml").voxelize(0.02)  # valve included
        node._on_map(msgs.cloud_from_points(full, "world"))
        target = valve_region().target_p
        resp = node._on_plan_reach(valve_request(time_budget_s=SUCCESS_BUDGET_S), PlanReach.Response())
        assert resp.success, (resp.error_code.val, resp.message)
        kept = without_target(full, target, 0.15)
        # (+-few: voxels exactly at the radius, and the target's float round trip through the message)
        assert len(full) - len(kept) > 100 and abs(resp.statistics.map_voxels - len(kept)) <= 4
        assert np.all(np.linalg.norm(kept - target, axis=1) > 0.15)
        node.set_parameters([Parameter("target_exclusion_radius_m", value=0.0)])
        resp = node._on_plan_reach(valve_request(goal_count=1, time_budget_s=SUCCESS_BUDGET_S), PlanReach.Response())
        assert resp.statistics.map_voxels == len(full), resp.message
