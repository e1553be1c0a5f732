"""Node-level tests of reach_executor's dual-arm mode (dissertation Sec. 4.5, 5.3): real
joint_driver + reach_executor processes in an isolated graph, probed over ROS
(/execute_reach MODE_DUAL_ARM goals, /dual_arm/targets with the run-time parameter
``dual_arm_follow``, /joint_command, /joint_states, /executor/metrics, /diagnostics), and
the target validation of ``io/exec_msgs.py`` in process.

Reachable pairs are the fixed pairs of test_dual_arm_controller.py (orientations by the
workspace rule); hand errors are measured by FK of /joint_states standing on the right
sole (``RobotModel.base_on_feet``). Nothing here asserts speed.
"""
from __future__ import annotations

import math
import re
import time

import numpy as np
import pinocchio as pin
import pytest
from action_msgs.msg import GoalStatus
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Pose, PoseArray
from humanoid_reach_interfaces.action import ExecuteReach
from humanoid_reach_interfaces.msg import ExecutorMetrics
from rclpy.action import ActionClient
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

from humanoid_reach_ros.codes import ErrorCode
from humanoid_reach_ros.io import exec_msgs, msgs
from humanoid_reach_ros.io.exec_msgs import ExecInputError
from humanoid_reach_ros.dual_arm.controller import ControllerConfig, DualArmReachController
from humanoid_reach_ros.dual_arm.torso_regression import ReachWorkspace
from humanoid_reach_ros.robot.model import RobotModel

from test_reach_executor_node import (DEEP, DRIVER_PARAMS, JUMP_PERIODS, PARAMS_FILE, READY, Run, command_array,
                                      left_sole_offset, max_jump_ratio, status, wait_log)

R = ErrorCode   # one numbering for every interface (msg/ErrorCode)
G = ExecuteReach.Goal
#: (right, left) hand positions [m], reachable from half-sitting and from each other (test_dual_arm_controller)
PAIRS = [
    ((0.428, -0.174, 0.984), (0.401, 0.237, 0.960)),
    ((0.546, -0.099, 0.908), (0.515, 0.170, 0.692)),
    ((0.510, -0.171, 1.177), (0.200, 0.290, 0.686)),
]
UNREACHABLE = ((1.4, -0.2, 1.0), (0.35, 0.25, 1.6))
HAND_TOL_M = 1e-3


@pytest.fixture(scope="module")
def model() -> RobotModel:
    return RobotModel()


@pytest.fixture(scope="module")
def ws() -> ReachWorkspace:
    return ReachWorkspace.load()


def poses(ws: ReachWorkspace, pair) -> tuple[pin.SE3, pin.SE3]:
    t = ws.targets(np.array(pair[0]), np.array(pair[1]))
    return pin.SE3(t.R_right, t.p_right), pin.SE3(t.R_left, t.p_left)


def dual_goal(right: pin.SE3, left: pin.SE3, frame: str = "world") -> ExecuteReach.Goal:
    return ExecuteReach.Goal(mode=G.MODE_DUAL_ARM, right_hand_target=msgs.pose_stamped(right, frame),
                             left_hand_target=msgs.pose_stamped(left, frame))


def pose_array(right: pin.SE3, left: pin.SE3, frame: str = "world") -> PoseArray:
    return PoseArray(header=msgs.header(frame), poses=[msgs.pose_from_se3(right), msgs.pose_from_se3(left)])


def hand_errors(model: RobotModel, joints: np.ndarray, right: pin.SE3, left: pin.SE3) -> tuple[float, float]:
    """Position errors [m] of both hands (FK standing on the right sole) to the targets."""
    q = model.config(joints, model.base_on_feet(joints))
    return (float(np.linalg.norm(model.frame_pose(q, "r_hand_ee").translation - right.translation)),
            float(np.linalg.norm(model.frame_pose(q, "l_hand_ee").translation - left.translation)))


def bad_pose(kind: str) -> Pose:
    p = msgs.pose_from_se3(pin.SE3(np.eye(3), np.array([0.4, -0.2, 1.0])))
    if kind == "nan":
        p.position.y = math.nan
    elif kind == "quaternion":
        p.orientation.w = 2.0
    return p


# ---------------------------------------------------------------- in process
def test_target_validation_in_process(ws) -> None:
    right, left = poses(ws, PAIRS[0])
    good = exec_msgs.array_hand_targets(pose_array(right, left))
    assert [t.frame for t in good] == ["world", "world"]
    w_r, w_l = exec_msgs.targets_in_world(good, None)
    np.testing.assert_allclose(w_r.homogeneous, right.homogeneous, atol=1e-9)
    waist = pin.SE3(np.eye(3), np.array([0.0, 0.0, 0.7]))
    bl = exec_msgs.goal_hand_targets(msgs.pose_stamped(right, "base_link"), msgs.pose_stamped(left, "world"))
    assert [t.frame for t in bl] == ["base_link", "world"] and exec_msgs.needs_waist(bl)
    np.testing.assert_allclose(exec_msgs.targets_in_world(bl, waist)[0].translation,
                               right.translation + [0.0, 0.0, 0.7], atol=1e-12)
    with pytest.raises(ExecInputError, match="recent /joint_states") as info:
        exec_msgs.targets_in_world(bl, None)
    assert info.value.code == R.NO_JOINT_STATES
    cases = {
        "count": (PoseArray(header=msgs.header("world"), poses=[bad_pose("")]), "exactly 2"),
        "count 3": (PoseArray(header=msgs.header("world"), poses=[bad_pose("")] * 3), "exactly 2"),
        "nan": (PoseArray(header=msgs.header("world"), poses=[bad_pose(""), bad_pose("nan")]), "NaN"),
        "quaternion": (PoseArray(header=msgs.header("world"), poses=[bad_pose("quaternion"), bad_pose("")]),
                       "unit length"),
        "frame": (PoseArray(header=msgs.header("map"), poses=[bad_pose(""), bad_pose("")]), "'map' is unknown"),
        "no frame": (PoseArray(poses=[bad_pose(""), bad_pose("")]), "'' is unknown"),
    }
    for name, (msg, word) in cases.items():
        with pytest.raises(ExecInputError, match=word) as info:
            exec_msgs.array_hand_targets(msg)
        assert info.value.code == R.INVALID_REQUEST, name


def test_controller_starts_from_any_posture_and_brakes(model, ws) -> None:
    """The node's use of the controller: start from half-sitting (not the controller's lowered
    initial posture), brake half-way (smooth stop short of the target), restore a snapshot."""
    ctl = DualArmReachController(model, config=ControllerConfig(period_s=0.005, max_speed_mps=0.38))
    ctl.reset(model.half_sitting())
    right, left = poses(ws, PAIRS[0])
    plan = ctl.set_targets(right.translation, right.rotation, left.translation, left.rotation)
    assert plan.feasible, plan.reason
    saved = ctl.save_state()
    steps = ctl.run()
    assert max(hand_errors(model, steps[-1].joints, right, left)) < 1e-6
    ctl.restore_state(saved)
    first = [ctl.step() for _ in range(plan.n_steps // 2)]
    left_steps = ctl.brake(0.2)
    assert left_steps == 40
    rest = ctl.run()
    assert len(rest) == 40 and rest[-1].done and all(s.ok for s in rest)
    s = np.array([st.s for st in first + rest])
    ds = np.diff(s)
    assert np.all(ds >= -1e-12) and s[-1] < 1.0 and ds[-1] < 0.1 * ds[len(first) - 1]   # slowed to a stop
    J = np.array([st.joints for st in first + rest])
    assert max_jump_ratio(J, model, 0.005) < 1.0
    assert min(hand_errors(model, J[-1], right, left)) > 0.01     # stopped short of the targets


# ---------------------------------------------------------------- node test
@pytest.mark.node
def test_dual_arm_goals_follow_and_bad_inputs(start_node, ros_probe, model, ws) -> None:
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient

    period = 0.005
    diags = ros_probe.collect(DiagnosticArray, "/diagnostics")
    commands = ros_probe.collect(JointState, "/joint_command", DEEP)
    states = ros_probe.collect(JointState, "/joint_states")
    metrics = ros_probe.collect(ExecutorMetrics, "/executor/metrics", DEEP)
    ex = start_node("reach_executor", params_file=PARAMS_FILE,
                    params={"diagnostics_period_s": 0.2, "scene_file": "",
                            # generous: a loaded machine may delay /joint_states (staleness: test_reach_executor_node)
                            "joint_states_timeout_s": 5.0, "joint_states_abort_s": 10.0,
                            "hold_timeout_s": 0.0},    # the held command is republished (counted below)
                    ready_log=READY, timeout=60.0)
    start_node("joint_driver", params_file=DRIVER_PARAMS, params={"command_timeout_s": 60.0},
               ready_log=r"simulated hrp2")
    client = ActionClient(ros_probe.node, ExecuteReach, "/execute_reach")
    ros_probe.spin_until(client.server_is_ready, 20.0, "/execute_reach server", on_timeout=ex.log_tail)
    ros_probe.spin_until(lambda: (s := status(diags, ": inputs")) is not None and "current" in s.message, 20.0,
                         "executor to see /joint_states", on_timeout=ex.log_tail)

    def measured() -> np.ndarray:
        return model.joints_from_dict(dict(zip(states.last.name, states.last.position)))

    def settled_joints() -> np.ndarray:
        """/joint_states once the driver has caught up with the last command."""
        # the latest command each time (the probe may still be working through a backlog)
        # (the probe's own /joint_states subscription may not have delivered yet on a loaded machine: ci7)
        ros_probe.spin_until(lambda: states.last is not None and commands.last is not None
                             and np.max(np.abs(measured() - np.array(commands.last.position))) < 1e-6, 30.0,
                             "driver to settle on the held command")
        return measured()

    def execution() -> dict[str, str]:
        return msgs.diagnostic_values(status(diags, ": execution"))

    # bad goals and an unreachable pair: INVALID_REQUEST with the reason, nothing commanded
    right, left = poses(ws, PAIRS[0])
    bad = {"frame": (dual_goal(right, left, frame="map"), "'map' is unknown"),
           "nan": (dual_goal(right, left), "NaN"), "quaternion": (dual_goal(right, left), "unit length"),
           "unreachable": (dual_goal(*(pin.SE3(np.eye(3), np.array(p)) for p in UNREACHABLE)), "unreachable")}
    bad["nan"][0].left_hand_target.pose.position.z = math.nan
    o = bad["quaternion"][0].right_hand_target.pose.orientation
    o.x, o.y, o.z, o.w = 1.5 * o.x, 1.5 * o.y, 1.5 * o.z, 1.5 * o.w
    for name, (g, word) in bad.items():
        st, res = Run(ros_probe, client, g).result()
        assert st == GoalStatus.STATUS_ABORTED and res.error_code.val == R.INVALID_REQUEST, (name, res.message)
        assert word in res.message, (name, res.message)
        assert name == "unreachable" or "MODE_DUAL_ARM goal" in res.message, (name, res.message)
        print(f"{name}: {res.message}")
    assert len(commands) == 0 and ex.alive()     # the robot did not move

    # a reachable pair (world): SUCCESS, both hands within 1 mm by FK of /joint_states
    g = Run(ros_probe, client, dual_goal(right, left))
    st, res = g.result(60.0)
    assert st == GoalStatus.STATUS_SUCCEEDED and res.success, res.message
    print(f"dual-arm goal: {res.message}: {res.steps} steps, {res.overruns} overruns, final hand error "
          f"{res.final_hand_error_m * 1e3:.4f} mm, max CoM error {res.max_com_error_m * 1e3:.3f} mm")
    assert res.final_hand_error_m < HAND_TOL_M and res.max_com_error_m < 2e-3 and res.steps > 100
    assert g.feedback and 0.0 <= g.feedback[0].progress <= g.feedback[-1].progress <= 1.0
    J, stamps = command_array(commands, model)
    assert np.all(np.isfinite(J)) and all(model.in_limits(j, 1e-9) for j in J)
    assert max_jump_ratio(J, model, period, stamps) <= JUMP_PERIODS
    assert max(left_sole_offset(model, j) for j in J[::10]) < 1e-3      # the feet do not move
    assert max(hand_errors(model, settled_joints(), right, left)) < HAND_TOL_M
    m = metrics.last
    assert m.hand_error_m < HAND_TOL_M and m.com_error_m < 2e-3 and m.progress == pytest.approx(1.0)

    # the next pair in base_link (waist of the measured posture): SUCCESS
    right2, left2 = poses(ws, PAIRS[1])
    waist = model.base_on_feet(measured())
    st, res = Run(ros_probe, client, dual_goal(waist.inverse() * right2, waist.inverse() * left2,
                                               "base_link")).result(60.0)
    assert st == GoalStatus.STATUS_SUCCEEDED, res.message
    assert max(hand_errors(model, settled_joints(), right2, left2)) < HAND_TOL_M

    # a goal canceled on the way: CANCELED, the motion brakes on its path and holds short of the targets
    c_r, c_l = poses(ws, PAIRS[2])
    n_c = len(commands)
    g = Run(ros_probe, client, dual_goal(c_r, c_l))
    handle = g.accepted()
    ros_probe.spin_until(lambda: g.progress() >= 0.2, 30.0, "canceled goal progress", on_timeout=ex.log_tail)
    cancel = handle.cancel_goal_async()
    ros_probe.spin_until(cancel.done, 20.0, "cancel response")
    st, res = g.result()
    assert st == GoalStatus.STATUS_CANCELED and res.error_code.val == R.CANCELED, res.message
    held = settled_joints()
    Jc, sc = command_array(commands, model, n_c - 1)
    assert max_jump_ratio(Jc, model, period, sc) <= JUMP_PERIODS and np.all(np.isfinite(Jc))
    assert max(left_sole_offset(model, j) for j in Jc[::10]) < 1e-3
    assert min(hand_errors(model, held, c_r, c_l)) > 0.01            # stopped short of the targets

    # follow mode: messages are ignored until dual_arm_follow is set at run time
    pub = ros_probe.node.create_publisher(PoseArray, "/dual_arm/targets",
                                          QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE))
    ros_probe.spin_until(lambda: pub.get_subscription_count() > 0, 10.0, "/dual_arm/targets subscription")
    a_r, a_l = poses(ws, PAIRS[2])
    # the subscriber may match the new publisher after the publisher has matched it (a loaded
    # machine): the first message can be lost, so it is re-sent every 0.5 s until one is counted
    last = [-1.0]

    def publish_until_ignored() -> int:
        if time.monotonic() - last[0] > 0.5:
            last[0] = time.monotonic()
            pub.publish(pose_array(a_r, a_l))
        return int(execution()["target_messages_ignored"])

    ros_probe.spin_until(publish_until_ignored, 20.0, "ignored target message", on_timeout=ex.log_tail)
    ros_probe.spin_for(0.3)
    ignored = int(execution()["target_messages_ignored"])
    params = AsyncParameterClient(ros_probe.node, "reach_executor")
    ros_probe.spin_until(params.services_are_ready, 10.0, "parameter services")
    future = params.set_parameters([Parameter("dual_arm_follow", value=True)])
    ros_probe.spin_until(future.done, 10.0, "set dual_arm_follow")
    assert future.result().results[0].successful

    # two successive pairs: the hands converge to the second
    n0, m0 = len(commands), len(metrics)
    pub.publish(pose_array(a_r, a_l))
    ros_probe.spin_until(lambda: len(metrics) > m0 + 60, 20.0, "motion to the first followed pair",
                         on_timeout=ex.log_tail)
    pub.publish(pose_array(right, left))                          # retarget half-way
    first, second = ignored + 1, ignored + 2       # follow labels number every message received
    ros_probe.spin_until(lambda: int(execution()["target_messages"]) >= second
                         and execution()["last_result"] == f"/dual_arm/targets #{second}: SUCCESS", 30.0,
                         "followed pair reached",
                         on_timeout=ex.log_tail)
    assert wait_log(ros_probe, ex, rf"/dual_arm/targets #{first}: PREEMPTED .*preempted by /dual_arm/targets #{second}")
    assert max(hand_errors(model, settled_joints(), right, left)) < HAND_TOL_M
    Jf, sf = command_array(commands, model, n0 - 1)     # from the command before the first followed pair
    assert max_jump_ratio(Jf, model, period, sf) <= JUMP_PERIODS
    assert max(left_sole_offset(model, j) for j in Jf[::10]) < 1e-3
    # the same targets again (within the threshold): ignored, no restart
    pub.publish(pose_array(right, left))
    ros_probe.spin_until(lambda: int(execution()["target_messages_unchanged"]) == 1, 20.0, "unchanged targets")

    # bad messages: rejected (diagnostic counter), the node keeps serving; an unreachable pair: held
    bad_msgs = [PoseArray(header=msgs.header("world"), poses=[bad_pose("")]),
                PoseArray(header=msgs.header("world"), poses=[bad_pose(""), bad_pose("nan")]),
                PoseArray(header=msgs.header("map"), poses=[bad_pose(""), bad_pose("")]),
                PoseArray(header=msgs.header("world"), poses=[bad_pose("quaternion"), bad_pose("")])]
    for i, msg in enumerate(bad_msgs):   # one at a time: the subscription keeps the latest only
        pub.publish(msg)
        ros_probe.spin_until(lambda i=i: int(execution()["target_messages_rejected"]) == i + 1, 20.0,
                             f"rejection {i + 1}", on_timeout=ex.log_tail)
    assert wait_log(ros_probe, ex, r"rejected /dual_arm/targets #\d+ \(INVALID_REQUEST\): PoseArray has 1 poses")
    n_hold = len(commands)
    pub.publish(pose_array(*(pin.SE3(np.eye(3), np.array(p)) for p in UNREACHABLE)))
    ros_probe.spin_until(lambda: int(execution()["dual_arm_infeasible"]) == 2, 20.0, "infeasible follow pair",
                         on_timeout=ex.log_tail)
    assert "unreachable" in execution()["last_infeasible"]
    ros_probe.spin_until(lambda: len(commands) > n_hold + 40, 20.0, "held commands")
    Jh, _ = command_array(commands, model, n_hold - 1)
    # holding where it was when the pair arrived (not Jf[-1]: that command may still be of the
    # hold_settle_s after the followed pair's SUCCESS, micro-radians from the settled one)
    assert np.max(np.abs(Jh[1:] - Jh[0])) < 1e-12
    assert ex.alive()

    # a trajectory goal (MODE_TRAJECTORY) after the dual-arm motions: from the held posture back
    # to half-sitting
    future = params.set_parameters([Parameter("dual_arm_follow", value=False)])
    ros_probe.spin_until(future.done, 10.0, "clear dual_arm_follow")
    hs = model.half_sitting_joints
    traj = msgs.joint_trajectory(model.joint_names, [0.0, 3.0], np.vstack([Jh[-1], hs]), frame_id="world")
    n1 = len(commands)
    st, res = Run(ros_probe, client, ExecuteReach.Goal(mode=G.MODE_TRAJECTORY, trajectory=traj,
                                                        arm=exec_msgs.ARM_AUTO)).result(60.0)
    assert st == GoalStatus.STATUS_SUCCEEDED and res.success, res.message
    Jt, s_t = command_array(commands, model, n1 - 1)    # from the last held command (== Jh[-1])
    assert max_jump_ratio(Jt, model, period, s_t) <= JUMP_PERIODS
    assert max(left_sole_offset(model, j) for j in Jt[::10]) < 1e-3
    np.testing.assert_allclose(Jt[-1], hs, atol=0.05)     # back near half-sitting (hand task + posture)
    # and a dual-arm goal after the trajectory goal starts from its last command
    st, res = Run(ros_probe, client, dual_goal(right, left)).result(60.0)
    assert st == GoalStatus.STATUS_SUCCEEDED, res.message
    assert max(hand_errors(model, settled_joints(), right, left)) < HAND_TOL_M

    # sequential random targets (Sec. 5.4) by ~/dual_arm_sequential: 2 pairs, then SUCCESS with the counts
    # (each hand's target is reached from the initial posture; chained from the previous target a pair can
    # still be refused, which is counted as infeasible)
    from std_srvs.srv import Trigger

    for name, value in (("dual_arm_sequential_count", 2), ("dual_arm_sequential_seed", 6)):
        future = params.set_parameters([Parameter(name, value=value)])
        ros_probe.spin_until(future.done, 10.0, f"set {name}")
    trigger = ros_probe.node.create_client(Trigger, "/reach_executor/dual_arm_sequential")
    ros_probe.spin_until(trigger.service_is_ready, 10.0, "~/dual_arm_sequential")
    n2 = len(commands)
    call = trigger.call_async(Trigger.Request())
    ros_probe.spin_until(call.done, 20.0, "~/dual_arm_sequential response")
    assert call.result().success, call.result().message
    line = wait_log(ros_probe, ex, r"sequential #1: SUCCESS at progress .*: 2 random target pairs: \d reached, "
                                   r"\d infeasible", 60.0)
    reached, skipped = (int(v) for v in re.search(r"(\d) reached, (\d) infeasible", line).groups())
    assert reached + skipped == 2 and reached >= 1, line
    Js, ss = command_array(commands, model, n2 - 1)
    assert np.all(np.isfinite(Js)) and max_jump_ratio(Js, model, period, ss) <= JUMP_PERIODS
    assert max(left_sole_offset(model, j) for j in Js[::10]) < 1e-3
    future = params.set_parameters([Parameter("dual_arm_sequential_count", value=0)])
    ros_probe.spin_until(future.done, 10.0, "set a bad count")
    call = trigger.call_async(Trigger.Request())
    ros_probe.spin_until(call.done, 20.0, "~/dual_arm_sequential response")
    assert not call.result().success and "1..1000," in call.result().message

    values = execution()
    assert int(values["dual_arm_goals"]) == 5 and int(values["target_messages_rejected"]) == 4
    assert ex.alive()
