"""humanoid_reach_interfaces: import from Python and round-trip one of each through rclpy."""
from __future__ import annotations

import math

import numpy as np
import pytest

from humanoid_reach_interfaces.action import ExecuteReach
from humanoid_reach_interfaces.msg import ExecutorMetrics, PlanningStatistics, WorkspaceGoalRegion
from humanoid_reach_interfaces.srv import PlanReach

from humanoid_reach_ros.codes import ErrorCode

pytestmark = pytest.mark.node

# The valve region of Kanehiro et al. eq. (3), as offsets around the valve centre.
VALVE_LOWER = [0.0, 0.0, 0.0, -math.pi / 2, -math.pi / 2, -math.pi]
VALVE_UPPER = [0.0, 0.0, 0.0, math.pi / 2, math.pi / 2, math.pi]


def valve_region() -> WorkspaceGoalRegion:
    r = WorkspaceGoalRegion()
    r.target.header.frame_id = "world"
    r.target.pose.position.x, r.target.pose.position.y, r.target.pose.position.z = 0.71, 0.03, 0.90
    r.lower = VALVE_LOWER
    r.upper = VALVE_UPPER
    return r


def test_messages_round_trip(ros_probe):
    from rclpy.qos import QoSProfile

    metrics = ExecutorMetrics()
    metrics.header.frame_id = "world"
    metrics.step_time_s, metrics.spheres_in_bound, metrics.active_levels = 0.0011, 42, [1, 2, 3]
    metrics.min_distance_m, metrics.com_error_m = -0.002, 4e-4
    stats = PlanningStatistics(samples=1308226, goals_found=100, collision_time_s=0.25)
    node = ros_probe.node
    sent = {"/wgr": valve_region(), "/metrics": metrics, "/stats": stats}
    got = {}
    pubs = []
    for topic, msg in sent.items():
        node.create_subscription(type(msg), topic, lambda m, t=topic: got.setdefault(t, m), QoSProfile(depth=5))
        pubs.append((node.create_publisher(type(msg), topic, QoSProfile(depth=5)), msg))

    def publish_and_check():
        for pub, msg in pubs:
            pub.publish(msg)
        return len(got) == len(sent)

    ros_probe.spin_until(publish_and_check, timeout=10, what="all three messages back")
    for topic, msg in sent.items():
        assert got[topic] == msg, topic
    assert list(got["/metrics"].active_levels) == [1, 2, 3]
    assert np.allclose(got["/wgr"].upper, VALVE_UPPER)


def test_service_round_trip(ros_probe):
    node = ros_probe.node
    seen = []

    def handle(req: PlanReach.Request, resp: PlanReach.Response) -> PlanReach.Response:
        seen.append(req)
        resp.success = False
        resp.error_code.val = ErrorCode.NO_MAP
        resp.message = f"no map (arm {req.arm}, planner {req.planner})"
        resp.arm = req.arm
        resp.statistics.samples = 7
        return resp

    node.create_service(PlanReach, "/plan_reach_test", handle)
    client = node.create_client(PlanReach, "/plan_reach_test")
    ros_probe.spin_until(lambda: client.service_is_ready(), timeout=10, what="service")
    req = PlanReach.Request(region=valve_region(), arm=PlanReach.Request.ARM_LEFT, goal_count=100,
                            planner="rrt_connect", time_budget_s=1.0, execute=True, seed=3)
    future = client.call_async(req)
    ros_probe.spin_until(future.done, timeout=10, what="service response")
    resp = future.result()
    assert seen and seen[0] == req
    assert (resp.success, resp.error_code.val, resp.arm, resp.statistics.samples) == (False, 6, 2, 7)
    assert resp.message == "no map (arm 2, planner rrt_connect)"


def test_action_round_trip(ros_probe):
    from rclpy.action import ActionClient, ActionServer

    node = ros_probe.node

    def execute(goal_handle):
        n = len(goal_handle.request.trajectory.points)
        for i in range(n):
            fb = ExecuteReach.Feedback(progress=(i + 1) / n, min_distance_m=0.05)
            goal_handle.publish_feedback(fb)
        goal_handle.succeed()
        return ExecuteReach.Result(success=True, steps=n, final_hand_error_m=1e-4)

    server = ActionServer(node, ExecuteReach, "/execute_reach_test", execute)
    client = ActionClient(node, ExecuteReach, "/execute_reach_test")
    ros_probe.spin_until(lambda: client.server_is_ready(), timeout=10, what="action server")
    goal = ExecuteReach.Goal(mode=ExecuteReach.Goal.MODE_TRAJECTORY, arm=1)
    goal.trajectory.joint_names = ["RARM_JOINT0"]
    from trajectory_msgs.msg import JointTrajectoryPoint

    goal.trajectory.points = [JointTrajectoryPoint(positions=[0.1 * k]) for k in range(3)]
    feedback = []
    send = client.send_goal_async(goal, feedback_callback=lambda f: feedback.append(f.feedback.progress))
    ros_probe.spin_until(send.done, timeout=10, what="goal accepted")
    handle = send.result()
    assert handle.accepted
    res = handle.get_result_async()
    ros_probe.spin_until(res.done, timeout=10, what="action result")
    result = res.result().result
    assert result.success and result.steps == 3 and result.final_hand_error_m == pytest.approx(1e-4)
    ros_probe.spin_until(lambda: len(feedback) == 3, timeout=5, what="feedback")
    assert feedback[-1] == pytest.approx(1.0)
    server.destroy()
    client.destroy()
