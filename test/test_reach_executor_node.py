"""Node-level tests of reach_executor: real joint_driver + reach_executor processes in an
isolated graph, probed over ROS (the /execute_reach action, /reach_trajectory,
/joint_command, /executor/metrics, /diagnostics, logs), and the input validation of
``io/exec_msgs.py`` in process.

The trajectories are real plans: ``ReachPlanner`` on the plant scene, valve WGR (eq. 3),
computed in this process as in test_reach.py. Nothing here asserts speed: command
intervals are checked loosely (the machine is shared), step times come from bench/.
"""
from __future__ import annotations

import math
import time

import numpy as np
import pytest
import yaml
from action_msgs.msg import GoalStatus
from diagnostic_msgs.msg import DiagnosticArray
from humanoid_reach_interfaces.action import ExecuteReach
from humanoid_reach_interfaces.msg import ExecutorMetrics
from rclpy.action import ActionClient
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState, PointCloud2
from trajectory_msgs.msg import JointTrajectory

from humanoid_reach_ros.codes import ErrorCode
from humanoid_reach_ros.io import exec_msgs, msgs
from humanoid_reach_ros.io.exec_msgs import ExecInputError
from humanoid_reach_ros.nodes import reach_executor
from humanoid_reach_ros.execution import config as reach_executor_params
from humanoid_reach_ros.planning.reach import PlannerParams, PlanRequest, ReachPlanner
from humanoid_reach_ros.planning.wgr import valve_region
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.sim.scene import load_scene
from nodetools import REPO_ROOT

R = ErrorCode   # one numbering for every interface (msg/ErrorCode)
G = ExecuteReach.Goal
PARAMS_FILE = "config/reach_executor.yaml"
DRIVER_PARAMS = "config/joint_driver.yaml"
READY = r"reach executor ready"
DEEP = QoSProfile(depth=2000, reliability=ReliabilityPolicy.RELIABLE)  # every /joint_command, none dropped
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
FAST_DIAG = {"diagnostics_period_s": 0.2}
JUMP_PERIODS = 4.0   # consecutive commands may differ by at most velocity limit * this many periods


# ---------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def model() -> RobotModel:
    return RobotModel()


@pytest.fixture(scope="module")
def valve_plan():
    """A right-arm reach to the valve planned on the plant scene (in process)."""
    scene = load_scene("scenes/plant.yaml")
    planner = ReachPlanner(params=PlannerParams(time_budget_s=10.0))
    planner.set_map(scene.voxelize(0.02, exclude_groups=("valve",)))
    out = planner.plan(planner.robot.half_sitting_joints, PlanRequest(valve_region(scene.target.pose), arm="right",
                                                                      seed=3))
    assert out.success, out.message
    return out


def trajectory(plan, reverse: bool = False) -> JointTrajectory:
    t, pos = np.asarray(plan.times), np.asarray(plan.positions)
    if reverse:
        t, pos = t[-1] - t[::-1], pos[::-1]
    return msgs.joint_trajectory(plan.joint_names, t, pos, frame_id="world")


def goal(traj: JointTrajectory, arm: int = exec_msgs.ARM_RIGHT, **kw) -> ExecuteReach.Goal:
    return ExecuteReach.Goal(mode=G.MODE_TRAJECTORY, trajectory=traj, arm=arm, **kw)


# ---------------------------------------------------------------- in process: configuration and validation
def test_config_matches_declared_defaults() -> None:
    """config/reach_executor.yaml lists every parameter with the node's default."""
    doc = yaml.safe_load((REPO_ROOT / PARAMS_FILE).read_text())["/**"]["ros__parameters"]
    assert doc == {k: spec.default for k, spec in reach_executor_params.PARAMETERS.items()}
    fields = set(reach_executor_params.ExecutorParams.__dataclass_fields__)
    assert set(reach_executor_params.EXECUTOR_PARAMETERS) <= fields
    assert reach_executor_params.executor_params(doc) == reach_executor_params.ExecutorParams(
        **{k: doc[k] for k in reach_executor_params.EXECUTOR_PARAMETERS})


def bad_trajectories(plan, model: RobotModel) -> dict[str, tuple[JointTrajectory, str]]:
    """Each defect of a trajectory and a word its rejection message must contain."""
    good = trajectory(plan)
    out = {}

    def copy() -> JointTrajectory:
        return msgs.joint_trajectory(plan.joint_names, plan.times, plan.positions, frame_id="world")

    empty = JointTrajectory(joint_names=list(plan.joint_names))
    out["empty"] = (empty, "empty")
    t = copy()
    t.joint_names[3] = "NO_SUCH_JOINT"
    out["unknown joint"] = (t, "NO_SUCH_JOINT")
    keep = [i for i in range(len(plan.joint_names)) if i != 5]
    out["missing joint"] = (msgs.joint_trajectory([plan.joint_names[i] for i in keep], plan.times,
                                                  np.asarray(plan.positions)[:, keep], frame_id="world"),
                            plan.joint_names[5])
    t = copy()
    t.points[4].time_from_start, t.points[5].time_from_start = t.points[5].time_from_start, t.points[4].time_from_start
    out["non-increasing times"] = (t, "strictly increasing")
    t = copy()
    pos = np.array(t.points[7].positions)
    pos[2] = math.nan
    t.points[7].positions = pos.tolist()
    out["NaN"] = (t, "NaN")
    t = copy()
    pos = np.array(t.points[3].positions)
    pos[0] = model.upper[0] + 0.5
    t.points[3].positions = pos.tolist()
    out["outside limits"] = (t, "limits")
    t = copy()
    t.points = t.points[:1]
    out["single point"] = (t, "single point")
    t = copy()
    t.points[2].positions = list(t.points[2].positions)[:-1]
    out["short point"] = (t, "sizes")
    assert len(good.points) > 8
    return out


def test_look_requests_in_process(model) -> None:
    """/look goals: the scan pattern when empty, refusals naming the pose and the limit, and a
    motion whose reference moves only the head joints to the pose."""
    from humanoid_reach_ros.codes import RequestError
    from humanoid_reach_ros.execution.requests import ExecutionRequests

    p = {k: spec.default for k, spec in reach_executor_params.PARAMETERS.items()}
    p["scene_file"] = ""
    req = ExecutionRequests(model, p)
    scan = req.head_poses([], [])
    np.testing.assert_allclose(np.degrees(scan).ravel(), p["scan_poses_deg"])
    for yaw, pitch, words in (([0.1, 0.2], [0.3], "one pitch per yaw"), ([math.nan], [0.0], "NaN"),
                              ([0.0], [math.radians(200)], "HEAD_JOINT1's limits"),
                              ([math.radians(-170)], [0.0], "pose 0 of the goal: yaw -170.0")):
        with pytest.raises(RequestError, match=words):
            req.head_poses(yaw, pitch)
    # the scan pattern (a parameter for any robot) is clamped into this robot's head limits; the same
    # pose asked for in a goal is refused
    idx = [model.joint_index[n] for n in model.spec.head_joints]
    hi_deg = np.degrees(model.upper[idx])
    req.config = req.config.changed({"scan_poses_deg": [0.0, 10.0, 0.0, float(hi_deg[1]) + 20.0]})   # at run time
    np.testing.assert_allclose(np.degrees(req.head_poses([], []))[1], [0.0, hi_deg[1]])
    with pytest.raises(RequestError, match="limits"):
        req.head_poses([0.0], [math.radians(hi_deg[1] + 20.0)])
    req.config = req.config.changed({"scan_poses_deg": [0.0, 10.0, 5.0]})
    with pytest.raises(RequestError, match="yaw, pitch pairs"):
        req.head_poses([], [])
    joints = model.half_sitting_joints
    with pytest.raises(RequestError) as exc:
        req.look(1, "look", (0.2, 0.4), None, "no /joint_states received")
    assert exc.value.code == reach_executor.C.NO_JOINT_STATES
    motion = req.look(1, "look", (0.2, 0.4), joints, "")
    head = [model.joint_index[n] for n in ("HEAD_JOINT0", "HEAD_JOINT1")]
    end = motion.spline.position(motion.spline.duration)
    np.testing.assert_allclose(end[head], [0.2, 0.4])
    others = np.ones(model.n_joints, bool)
    others[head] = False
    np.testing.assert_array_equal(end[others], joints[others])
    assert motion.params.collision_avoidance and motion.params.com_compensation
    assert np.max(motion.spline.max_velocity[head]) <= p["head_speed_rad_s"] + 1e-9


def test_reference_validation_in_process(valve_plan, model) -> None:
    ref = exec_msgs.reference_from_trajectory(trajectory(valve_plan), model)
    assert ref.times[0] == 0.0 and ref.positions.shape == (len(valve_plan.times), 30)
    np.testing.assert_allclose(ref.spline.position(ref.times), ref.positions, atol=1e-9)
    # times shifted to start at 0; joint order taken from the names
    shifted = msgs.joint_trajectory(valve_plan.joint_names[::-1], np.asarray(valve_plan.times) + 1.5,
                                    np.asarray(valve_plan.positions)[:, ::-1], frame_id="world")
    ref2 = exec_msgs.reference_from_trajectory(shifted, model)
    np.testing.assert_allclose(ref2.positions, ref.positions)
    assert ref2.time_offset_s == pytest.approx(1.5) and ref2.times[0] == 0.0
    for name, (traj, word) in bad_trajectories(valve_plan, model).items():
        with pytest.raises(ExecInputError, match=word) as info:
            exec_msgs.reference_from_trajectory(traj, model)
        assert info.value.code == R.INVALID_REQUEST, name
    travel = exec_msgs.arm_motion(model, ref.positions)
    assert travel["right"].joint_travel_rad > 1.0 and travel["left"].joint_travel_rad == 0.0
    assert travel["right"].hand_travel_m > travel["left"].hand_travel_m > 0.0  # the trunk moves the left hand too
    assert exec_msgs.resolve_arm(0, travel) == "right" and exec_msgs.resolve_arm(1, travel) == "right"
    with pytest.raises(ExecInputError, match="wrong arm"):
        exec_msgs.resolve_arm(2, travel)
    with pytest.raises(ExecInputError, match="arm 7 is unknown"):
        exec_msgs.resolve_arm(7, travel)


# ---------------------------------------------------------------- node helpers
class Run:
    """One goal sent to /execute_reach: its handle, feedback and result."""

    def __init__(self, probe, client: ActionClient, g: ExecuteReach.Goal) -> None:
        self.probe, self.feedback = probe, []
        self.sent = client.send_goal_async(g, feedback_callback=lambda m: self.feedback.append(m.feedback))
        self.handle = None
        self.result_future = None

    def accepted(self, timeout: float = 20.0):
        self.handle = self.probe.spin_until(lambda: self.sent.done() and self.sent.result(), timeout, "goal response")
        assert self.handle.accepted
        self.result_future = self.handle.get_result_async()
        return self.handle

    def result(self, timeout: float = 40.0):
        if self.result_future is None:
            self.accepted()
        self.probe.spin_until(self.result_future.done, timeout, "action result")
        res = self.result_future.result()
        return res.status, res.result

    def progress(self) -> float:
        return self.feedback[-1].progress if self.feedback else 0.0


def wait_log(probe, proc, pattern: str, timeout: float = 20.0) -> str:
    """First log line of ``proc`` matching ``pattern``, spinning the probe meanwhile."""
    return probe.spin_until(lambda: (lines := proc.log_lines(pattern)) and lines[0], timeout,
                            f"{proc.name} to log {pattern!r}", on_timeout=proc.log_tail)


def status(diags, suffix: str):
    for arr in reversed(diags.messages):
        for st in arr.status:
            if st.name.endswith(suffix):
                return st
    return None


def command_array(commands, model: RobotModel, since: int = 0) -> tuple[np.ndarray, np.ndarray]:
    msgs_ = commands.messages[since:]
    for m in msgs_:
        assert tuple(m.name) == model.joint_names
    J = np.array([m.position for m in msgs_])
    stamps = np.array([msgs.seconds_from_time(m.header.stamp) for m in msgs_])
    return J, stamps


def max_jump_ratio(J: np.ndarray, model: RobotModel, period: float, stamps: np.ndarray | None = None) -> float:
    """Largest |q_{k+1} - q_k| / (v_max * period) over consecutive commands and joints.

    With ``stamps`` (the commands' header stamps), a pair further apart than a period is
    divided by its own interval: /joint_command keeps 10 messages for a reader (a driver
    wants the latest), so a probe stalled on a loaded machine loses some (CI, stamps 60 ms
    apart: 12.7 periods of motion between two received commands, none of them a jump)."""
    if len(J) < 2:
        return 0.0
    periods = np.ones(len(J) - 1)
    if stamps is not None:
        periods = np.maximum(np.diff(stamps) / period, 1.0)
    return float(np.max(np.abs(np.diff(J, axis=0)) / (model.velocity_limit * period) / periods[:, None]))


def left_sole_offset(model: RobotModel, joints: np.ndarray) -> float:
    """Distance [m] of the left sole from its stance pose with the right sole at its own
    (how far the feet moved relative to each other; both fixed -> 0)."""
    q = model.config(joints, model.base_on_feet(joints))
    left = model.frame_pose(q, "l_sole")
    ref = model.stance_soles[1]
    return float(np.linalg.norm(left.translation - ref.translation)
                 + np.linalg.norm(left.rotation - ref.rotation))


def hand_distance(model: RobotModel, joints: np.ndarray, ref_joints: np.ndarray, limb: str = "right_arm") -> float:
    """Distance [m] between the hand of ``joints`` and of ``ref_joints``, both standing on the feet."""
    tip = model.limbs[limb].tip
    a, b = (model.frame_pose(model.config(j, model.base_on_feet(j)), tip).translation for j in (joints, ref_joints))
    return float(np.linalg.norm(a - b))


# ---------------------------------------------------------------- node test
@pytest.mark.node
def test_execute_preempt_cancel_topic_and_bad_inputs(start_node, ros_probe, model, valve_plan) -> None:
    period = 0.005
    diags = ros_probe.collect(DiagnosticArray, "/diagnostics")
    commands = ros_probe.collect(JointState, "/joint_command", DEEP)
    metrics = ros_probe.collect(ExecutorMetrics, "/executor/metrics", DEEP)
    # the hold republishes for 30 s rather than 1 s: the checks of held commands below must not race
    # the hold's end on a loaded machine (the hold timeout itself: test_supervisor.py)
    ex = start_node("reach_executor", params_file=PARAMS_FILE, params={**FAST_DIAG, "hold_timeout_s": 30.0},
                    ready_log=READY, timeout=60.0)
    assert ex.log_lines(r"map source: scene file .*plant\.yaml \(\d+ voxels")
    client = ActionClient(ros_probe.node, ExecuteReach, "/execute_reach")
    ros_probe.spin_until(client.server_is_ready, 20.0, "/execute_reach server", on_timeout=ex.log_tail)
    forward, backward = trajectory(valve_plan), trajectory(valve_plan, reverse=True)

    # no joint driver yet: NO_JOINT_STATES; a dual-arm goal without targets (empty frame_id): INVALID_REQUEST
    # (targets are checked before the joint states; dual-arm mode itself: test_dual_arm_node.py)
    st, res = Run(ros_probe, client, goal(forward)).result()
    assert res.error_code.val == R.NO_JOINT_STATES and "no /joint_states" in res.message, res.message
    assert st == GoalStatus.STATUS_ABORTED and not res.success
    st, res = Run(ros_probe, client, ExecuteReach.Goal(mode=G.MODE_DUAL_ARM)).result()
    assert res.error_code.val == R.INVALID_REQUEST and "DUAL_ARM" in res.message, res.message
    assert len(commands) == 0  # nothing commanded yet

    driver = start_node("joint_driver", params_file=DRIVER_PARAMS, ready_log=r"simulated hrp2")
    ros_probe.spin_until(lambda: (s := status(diags, ": inputs")) is not None and "current" in s.message
                         and msgs.diagnostic_level(s) == msgs.LEVEL_OK, 20.0, "executor to see /joint_states",
                         on_timeout=ex.log_tail)

    # every bad goal: INVALID_REQUEST with a message naming the defect; nothing is commanded
    bad = {name: goal(t) for name, (t, _) in bad_trajectories(valve_plan, model).items()}
    bad["arm 7"] = goal(forward, arm=7)
    bad["wrong arm"] = goal(forward, arm=exec_msgs.ARM_LEFT)
    bad["mode 9"] = ExecuteReach.Goal(mode=9, trajectory=forward)
    bad["frame map"] = goal(trajectory(valve_plan))
    bad["frame map"].trajectory.header.frame_id = "map"
    words = {name: w for name, (_, w) in bad_trajectories(valve_plan, model).items()}
    words.update({"arm 7": "arm 7", "wrong arm": "wrong arm", "mode 9": "mode 9", "frame map": "frame_id"})
    names = list(bad)
    for i in range(0, len(names), 5):  # in bursts of 5 (a client's request queue holds 10)
        runs = {name: Run(ros_probe, client, bad[name]) for name in names[i:i + 5]}
        for name, run in runs.items():
            st, res = run.result()
            assert res.error_code.val == R.INVALID_REQUEST and st == GoalStatus.STATUS_ABORTED, (name, res.message)
            assert words[name] in res.message, (name, res.message)
            print(f"{name}: {res.message}")
    assert ex.alive() and len(commands) == 0

    # bad /reach_trajectory messages: throttled warning + diagnostic counter, nothing commanded
    traj_pub = ros_probe.node.create_publisher(JointTrajectory, "/reach_trajectory",
                                               QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE))
    ros_probe.spin_until(lambda: traj_pub.get_subscription_count() > 0, 10.0, "/reach_trajectory subscription")
    topic_bad = [bad_trajectories(valve_plan, model)[k][0] for k in ("unknown joint", "NaN", "non-increasing times")]
    for i, t in enumerate(topic_bad):  # one at a time: the subscription keeps only the latest (depth 1)
        traj_pub.publish(t)
        ros_probe.spin_until(lambda i=i: (s := status(diags, ": execution")) is not None
                             and int(msgs.diagnostic_values(s)["trajectories_rejected"]) == i + 1, 20.0,
                             f"rejection {i + 1} in /diagnostics", on_timeout=ex.log_tail)
    wait_log(ros_probe, ex, r"rejected /reach_trajectory #1 \(INVALID_REQUEST\): .*NO_SUCH_JOINT")
    values = msgs.diagnostic_values(status(diags, ": execution"))
    assert int(values["goals_rejected"]) == 2 + len(bad) and "/reach_trajectory #3" in values["last_rejection"]
    assert len(commands) == 0

    # /voxel_map: a malformed cloud is rejected (the scene-file map stays), a good one replaces the map
    map_pub = ros_probe.node.create_publisher(PointCloud2, "/voxel_map", LATCHED)
    broken = msgs.cloud_from_points(np.ones((10, 3)), "world")
    broken.fields = broken.fields[:2]
    map_pub.publish(broken)
    wait_log(ros_probe, ex, r"rejected /voxel_map \(1 so far\): .*no z field.*keeping the previous map \(scene file")
    voxels = load_scene("scenes/plant.yaml").voxelize(0.02, exclude_groups=("valve",))
    map_pub.publish(msgs.cloud_from_points(voxels, "world"))
    wait_log(ros_probe, ex, rf"map source: /voxel_map \({len(voxels)} voxels, sphere tree built in .* "
                            r"replaces scene file")
    ros_probe.spin_until(lambda: (s := status(diags, ": inputs")) is not None
                         and msgs.diagnostic_values(s)["map_source"] == "/voxel_map", 20.0, "map source diagnostic")
    assert int(msgs.diagnostic_values(status(diags, ": inputs"))["maps_rejected"]) == 1
    # /voxel_map/unobserved (the frontier a gaze may keep out of): taken, and a malformed one refused
    frontier_pub = ros_probe.node.create_publisher(PointCloud2, "/voxel_map/unobserved", LATCHED)
    frontier_pub.publish(broken)
    wait_log(ros_probe, ex, r"rejected /voxel_map/unobserved \(2 maps rejected so far\): .*no z field.*keeping the "
                            r"previous frontier")
    frontier_pub.publish(msgs.cloud_from_points(np.array([[-1.0, 0.0, 1.0], [-1.02, 0.0, 1.0]]), "world"))
    wait_log(ros_probe, ex, r"unobserved frontier: /voxel_map/unobserved \(2 voxels\)")

    # G1 to the valve, preempted at a quarter by G2 (same trajectory: its start differs from where G1 is)
    g1 = Run(ros_probe, client, goal(forward))
    g1.accepted()
    ros_probe.spin_until(lambda: g1.progress() >= 0.25, 30.0, "G1 progress", on_timeout=ex.log_tail)
    g2 = Run(ros_probe, client, goal(forward, arm=exec_msgs.ARM_AUTO))
    st1, r1 = g1.result()
    assert r1.error_code.val == R.PREEMPTED and st1 == GoalStatus.STATUS_ABORTED and "preempted by goal" in r1.message
    assert r1.steps > 0 and 0.25 <= g1.progress() < 1.0
    st2, r2 = g2.result(60.0)
    assert r2.success and r2.error_code.val == R.SUCCESS and st2 == GoalStatus.STATUS_SUCCEEDED, r2.message
    print(f"\nG2: {r2.message}: {r2.steps} steps, {r2.overruns} overruns, {r2.duration_s:.2f} s, min distance "
          f"{r2.min_distance_m:.4f} m, max COG error {r2.max_com_error_m * 1e3:.3f} mm, final hand error "
          f"{r2.final_hand_error_m * 1e3:.3f} mm")
    assert r2.min_distance_m >= 0.0 and math.isfinite(r2.min_distance_m)
    assert r2.final_hand_error_m < 0.005 and r2.max_com_error_m < 0.005
    # the whole reference, played against the clock: one step per period, a late step (an overrun)
    # advancing it by up to max_catch_up_periods (4) at once; never cut short. A deadline the tick
    # thread itself missed (woken more than a period late: skipped, not an overrun) sends no step:
    # a few allowed (fresh clone, three xdist workers: 1,382 steps of 1,383, 0 overruns)
    assert r2.steps + 3 * r2.overruns >= math.floor(valve_plan.times[-1] / period) - 3, (r2.steps, r2.overruns)
    assert r2.duration_s >= valve_plan.times[-1] - period, r2.duration_s
    assert g2.feedback and 0.0 <= g2.feedback[0].progress <= g2.feedback[-1].progress <= 1.0
    assert all(f.min_distance_m >= 0.0 for f in g2.feedback)
    assert wait_log(ros_probe, ex, r"goal #\d+: SUCCESS at progress 1\.00: .*min distance")
    # the result can be taken before the last motion commands queued at the probe (a loaded machine):
    # wait for a command sent after the result (the hold republishes), so J ends where the motion did
    t_result = time.time()
    ros_probe.spin_until(lambda: len(commands) and msgs.seconds_from_time(commands.messages[-1].header.stamp)
                         >= t_result, 20.0, "a command after the result")

    J, stamps = command_array(commands, model)
    assert np.median(np.diff(stamps)) < 0.02           # loosely the 5 ms period
    jump = max_jump_ratio(J, model, period, stamps)
    print(f"commands: {len(J)}, median interval {np.median(np.diff(stamps)) * 1e3:.2f} ms, max jump "
          f"{jump:.2f} x v_max * period")
    assert jump <= JUMP_PERIODS
    assert all(model.in_limits(j, 1e-9) for j in J)
    assert max(left_sole_offset(model, j) for j in J[::10]) < 1e-3   # the feet do not move
    assert hand_distance(model, J[-1], valve_plan.positions[-1]) < 0.005   # at the valve
    assert len(metrics) > 100
    m = metrics.last
    assert m.header.frame_id == "world" and 0.0 <= m.progress <= 1.0 and m.step_time_s > 0.0
    assert m.step_time_s >= m.ik_time_s and m.min_distance_m >= 0.0 and 1 in bytes(m.active_levels)

    # holding after the motion: commands keep coming, all equal
    n_done = len(commands)
    ros_probe.spin_until(lambda: len(commands) > n_done + 80, 20.0, "held commands")
    Jh, _ = command_array(commands, model, n_done)
    assert np.max(np.abs(Jh[-40:] - Jh[-1])) < 1e-12 and np.max(np.abs(Jh[-1] - J[-1])) < 1e-12

    # G3 back to half-sitting with smooth reshaping, canceled at a quarter: the robot stops smoothly
    # and holds
    n0 = len(commands)
    g3 = Run(ros_probe, client, goal(backward, smooth_reshaping=True))
    handle = g3.accepted()
    ros_probe.spin_until(lambda: g3.progress() >= 0.25, 60.0, "G3 progress", on_timeout=ex.log_tail)
    assert wait_log(ros_probe, ex, r"goal #\d+: smooth reshaping: \d+ portion\(s\) reshaped in")
    assert wait_log(ros_probe, ex, r"goal #\d+: accepted: .*COM compensation on; smooth reshaping")
    cancel = handle.cancel_goal_async()
    ros_probe.spin_until(cancel.done, 20.0, "cancel response")
    st3, r3 = g3.result()
    assert st3 == GoalStatus.STATUS_CANCELED and r3.error_code.val == R.CANCELED, r3.message
    assert 0 < r3.steps and r3.min_distance_m >= 0.0
    assert wait_log(ros_probe, ex, r"goal #\d+: CANCELED at progress")

    def holding():
        Jc, _ = command_array(commands, model, n0)
        return len(Jc) > 60 and np.max(np.abs(Jc[-40:] - Jc[-1])) < 1e-9

    ros_probe.spin_until(holding, 20.0, "the robot to hold after the cancel", on_timeout=ex.log_tail)
    Jc, sc = command_array(commands, model, n0 - 1)    # from the last held command (== J[-1], checked above)
    assert max_jump_ratio(Jc, model, period, sc) <= JUMP_PERIODS
    assert max(left_sole_offset(model, j) for j in Jc[::10]) < 1e-3
    start, mid = valve_plan.positions[-1], Jc[-1]
    assert np.max(np.abs(mid - start)) > 0.01 and np.max(np.abs(mid - valve_plan.positions[0])) > 0.01  # mid-way

    # a good /reach_trajectory after it all (the backward reach from the held posture): executed to the end
    n1 = len(commands)
    traj_pub.publish(backward)
    line = wait_log(ros_probe, ex, r"/reach_trajectory #4: SUCCESS at progress 1\.00", 60.0)
    print(line)

    def held_after_motion():   # the probe's queue may still hold motion commands when the log line arrives
        Jm, _ = command_array(commands, model, n1)
        # ... or not have them yet: the hold before the motion is 40 equal commands too (ci41: the hand
        # 0.58 m from the end, the probe behind the log line); the motion must be in before its hold
        return (len(Jm) > 60 and np.max(np.abs(Jm[-40:] - Jm[-1])) < 1e-9
                and float(np.max(np.abs(Jm - Jm[0]))) > 0.01)

    ros_probe.spin_until(held_after_motion, 30.0, "the robot to hold at the end of /reach_trajectory #4",
                         on_timeout=ex.log_tail)
    Jt, st = command_array(commands, model, n1 - 1)
    assert max_jump_ratio(Jt, model, period, st) <= JUMP_PERIODS
    assert hand_distance(model, Jt[-1], valve_plan.positions[0]) < 0.005   # the hand task (level 3) is met
    np.testing.assert_allclose(Jt[-1], valve_plan.positions[0], atol=0.05)  # the posture (level 4) nearly
    assert max(left_sole_offset(model, j) for j in Jt[::10]) < 1e-3
    slip = ros_probe.spin_until(lambda: status(diags, "joint_driver: odometry"), 10.0, "driver odometry")
    assert float(msgs.diagnostic_values(slip)["left_foot_slip_m"]) < 2e-3
    loop = msgs.diagnostic_values(status(diags, "reach_executor: loop"))
    assert int(loop["published_total"]) >= len(commands) * 0.9

    # a slow reach (times x 3, both constraints off: Figs. 7-8 "without") whose joint driver stops on
    # the way: ABORTED once /joint_states are older than joint_states_abort_s, the last command
    # held; then a start is refused as stale
    slow = msgs.joint_trajectory(valve_plan.joint_names, 3.0 * np.asarray(valve_plan.times), valve_plan.positions,
                                 frame_id="world")
    g4 = Run(ros_probe, client, goal(slow, disable_collision_avoidance=True, disable_com_compensation=True))
    g4.accepted()
    wait_log(ros_probe, ex, r"goal #\d+: accepted: .*collision avoidance OFF, COM compensation OFF")
    ros_probe.spin_until(lambda: g4.progress() >= 0.05, 30.0, "G4 progress", on_timeout=ex.log_tail)
    driver.stop()
    st4, r4 = g4.result()
    assert st4 == GoalStatus.STATUS_ABORTED and r4.error_code.val == R.ABORTED and "stale" in r4.message, r4.message
    assert g4.progress() < 0.9
    # the commands sent after the result (not those of the motion still queued at the probe): held
    t_abort = time.time()

    def held_since_abort():
        return [m for m in commands.messages if msgs.seconds_from_time(m.header.stamp) >= t_abort]

    ros_probe.spin_until(lambda: len(held_since_abort()) > 20, 20.0, "held commands without the driver")
    Js = np.array([m.position for m in held_since_abort()])
    assert np.max(np.abs(Js[-10:] - Js[-1])) < 1e-6   # holding still
    st, res = Run(ros_probe, client, goal(forward)).result()
    assert res.error_code.val == R.NO_JOINT_STATES and "stale" in res.message, res.message
    assert ex.alive()


def test_dual_arm_requests_need_a_torso_model(model, tmp_path) -> None:
    """A robot whose description names no torso regression model: dual-arm goals and the
    sequential service are refused with INVALID_REQUEST naming what to do (the node starts its
    loop without a dual-arm engine)."""
    import yaml

    from humanoid_reach_ros.codes import ExecuteCode, RequestError
    from humanoid_reach_ros.execution.requests import ExecutionRequests
    from humanoid_reach_ros.robot.spec import robot_config_path

    src = robot_config_path("hrp2").parent
    doc = yaml.safe_load((src / "robot.yaml").read_text())
    doc.pop("torso_regression")
    for f in ("hrp2.urdf", "collision.yaml", "dual_arm_workspace.yaml"):
        (tmp_path / f).write_text((src / f).read_text())
    (tmp_path / "robot.yaml").write_text(yaml.safe_dump(doc))
    p = {k: spec.default for k, spec in reach_executor_params.PARAMETERS.items()}
    p["scene_file"] = ""
    req = ExecutionRequests(RobotModel(tmp_path / "robot.yaml"), p)
    assert req.dual_arm_model() is None
    for call in (lambda: req.dual(1, "goal", None, model.half_sitting_joints, ""),
                 lambda: req.sequential(2, "seq", 3, 0, model.half_sitting_joints, "")):
        with pytest.raises(RequestError, match="no dual-arm torso regression model") as e:
            call()
        assert e.value.code == ExecuteCode.INVALID_REQUEST
    assert ExecutionRequests(model, p).dual_arm_model() == model.spec.torso_regression


def test_dual_arm_workspace_is_the_robots_unless_given(model) -> None:
    """The dual-arm mode reads the workspace file its robot's model was trained on (robot.yaml
    dual_arm_workspace) unless the dual_arm_workspace parameter names another (no node)."""
    from humanoid_reach_ros.execution.requests import ExecutionRequests

    p = {k: spec.default for k, spec in reach_executor_params.PARAMETERS.items()}
    assert p["dual_arm_workspace"] == ""
    assert ExecutionRequests(model, p).dual_arm_workspace() == model.spec.dual_arm_workspace
    talos = RobotModel("talos")
    assert (ExecutionRequests(talos, p).dual_arm_workspace() == talos.spec.dual_arm_workspace
            != model.spec.dual_arm_workspace)
    p["dual_arm_workspace"] = "elsewhere/ws.yaml"
    assert ExecutionRequests(talos, p).dual_arm_workspace() == "elsewhere/ws.yaml"
