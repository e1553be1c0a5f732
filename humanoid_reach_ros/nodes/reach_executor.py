"""``reach_executor``: the 5 ms whole-body execution loop of Kanehiro et al. (Sec. IV-V).

An adapter between ROS and the execution manager (``execution/manager.py``; the layers in
docs/architecture.md). The control loop runs in a process of its own (``execution/process.py``,
its publishing ``nodes/reach_executor_loop.py``) that publishes ``/joint_command`` every
``period_s`` while a motion runs and while holding after one, and ``/executor/metrics``: this
node's callbacks never share an interpreter lock with the 5 ms deadlines. This node converts:

* the ``/execute_reach`` action (``MODE_TRAJECTORY``: ``goal.trajectory`` with the hand of
  ``goal.arm``, flags ``disable_collision_avoidance``, ``disable_com_compensation``,
  ``smooth_reshaping``; ``MODE_DUAL_ARM``: the dissertation's dual-arm controller to
  ``right_hand_target`` / ``left_hand_target``) and the ``/look`` action (head poses, the scan
  pattern, or gaze points);
* ``/reach_trajectory`` (executed like a goal with ``arm = 0``), ``/dual_arm/targets``
  (PoseArray right, left; followed while ``dual_arm_follow``), ``~/dual_arm_sequential``,
  ``/voxel_map`` (the collision map), ``/voxel_map/unobserved`` (the frontier a gaze keeps the
  body out of) and ``/joint_states`` (the start posture; stale after
  ``joint_states_timeout_s``: NO_JOINT_STATES; after ``joint_states_abort_s`` a running motion
  is ABORTED and the last command held);
* the results, feedback and ``/diagnostics``.

Bad inputs never stop the node: an invalid goal gets ``INVALID_REQUEST`` (or ``NO_JOINT_STATES``)
with a message and does not disturb the running motion; an invalid topic message gets a
throttled warning and a diagnostic.

Run: ``ros2 run humanoid_reach_ros reach_executor --ros-args --params-file
config/reach_executor.yaml`` (here: ``python -m humanoid_reach_ros.nodes.reach_executor ...``).
"""
from __future__ import annotations

import sys
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray
from humanoid_reach_interfaces.action import ExecuteReach, Look
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import JointState, PointCloud2
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory

from humanoid_reach_ros.codes import ExecuteCode as C, RequestError
from humanoid_reach_ros.execution.config import PARAMETERS, SOLVERS, ExecutionConfig, supervisor_config
from humanoid_reach_ros.execution.manager import DualArmGoal, ExecutionManager, LookGoal, LookProgress, \
    TrajectoryGoal
from humanoid_reach_ros.execution.process import LoopConfig, LoopProcess
from humanoid_reach_ros.io import exec_msgs, msgs
from humanoid_reach_ros.io.endpoints import LATCHED, RELIABLE_LATEST, LatestOnDemand, current_joints
from humanoid_reach_ros.nodes.common import declare_parameters, run_node, scene_file_voxels
from humanoid_reach_ros.paths import config_path
from humanoid_reach_ros.robot.model import RobotModel

NODE_NAME = "reach_executor"
LOOP_ENTRY = "humanoid_reach_ros.nodes.reach_executor_loop"


class GoalHandlePort:
    """An rclpy goal handle as the manager's ``GoalPort``; ``feedback`` converts what it gets."""

    def __init__(self, handle, feedback) -> None:
        self.handle, self._feedback = handle, feedback

    def cancel_requested(self) -> bool:
        return self.handle.is_cancel_requested

    def active(self) -> bool:
        return self.handle.is_active

    def feedback(self, value) -> None:
        self.handle.publish_feedback(self._feedback(value))

    def close(self, code: int) -> None:
        if code == C.SUCCESS:
            self.handle.succeed()
        elif code == C.CANCELED and self.handle.is_cancel_requested:
            self.handle.canceled()
        else:
            self.handle.abort()


def _execute_goal(req: ExecuteReach.Goal, robot) -> TrajectoryGoal | DualArmGoal:
    if req.mode == ExecuteReach.Goal.MODE_DUAL_ARM:
        try:
            return DualArmGoal(exec_msgs.goal_hand_targets(req.right_hand_target, req.left_hand_target))
        except RequestError as exc:
            raise RequestError(exc.code, f"MODE_DUAL_ARM goal: {exc}") from None
    if req.mode != ExecuteReach.Goal.MODE_TRAJECTORY:
        raise RequestError(C.INVALID_REQUEST, f"mode {req.mode} is unknown; use 0 (TRAJECTORY) or 1 (DUAL_ARM)")
    return TrajectoryGoal(exec_msgs.reference_from_trajectory(req.trajectory, robot), req.trajectory.header.frame_id,
                          req.arm, req.disable_collision_avoidance, req.disable_com_compensation, req.smooth_reshaping)


def _look_feedback(p: LookProgress) -> Look.Feedback:
    return Look.Feedback(pose_index=p.pose_index, pose_count=p.pose_count, yaw_rad=p.yaw_rad, pitch_rad=p.pitch_rad,
                         holding=p.holding)


class ReachExecutorNode(Node):
    """ROS adapter of the execution manager (see the module docstring)."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = declare_parameters(self, PARAMETERS)
        if p["solver"] not in SOLVERS:
            raise ValueError(f"solver must be one of {SOLVERS}, got {p['solver']!r}")
        if p["metrics_decimation"] < 1:
            raise ValueError(f"metrics_decimation must be >= 1, got {p['metrics_decimation']}")
        config = ExecutionConfig.from_values(p)
        self.params = config.executor
        self.period_s = self.params.period_s
        self.robot = RobotModel(p["robot_config"])
        # the start posture and a staleness check only: taken when needed, no 200 Hz callbacks
        self.joint_states = LatestOnDemand(self, JointState, "joint_states", qos_profile_sensor_data)
        self.manager = m = ExecutionManager(
            self.robot, config,
            lambda: current_joints(self.joint_states, m.config.joint_states_timeout_s, self.robot),
            self.joint_states.age_s, self.get_logger(), lambda: self.context.ok())
        t0 = time.perf_counter()
        dual = m.requests.dual_arm_model()
        self.loop = LoopProcess(LoopConfig(
            robot_config=p["robot_config"], executor_params=self.params, supervisor=supervisor_config(p),
            dual_arm={"regression": dual, "workspace": m.requests.dual_arm_workspace(),
                      "max_speed_mps": p["dual_arm_max_speed_mps"]} if dual else None,
            node_name=f"{self.get_name()}_loop", namespace=self.get_namespace(),
            command_topic=self.resolve_topic_name("joint_command"),
            metrics_topic=self.resolve_topic_name("executor/metrics"), map_frame=p["map_frame"],
            metrics_decimation=p["metrics_decimation"], rt_priority=p["rt_priority"],
            lock_memory=p["lock_memory"], status_period_s=min(p["feedback_period_s"], 0.1),
            domain_id=self.context.get_domain_id()), m.on_event, LOOP_ENTRY)
        m.attach(self.loop)
        m.requests.warm_surroundings()   # the scan's gazes around the body, while the loop process starts
        info = self.loop.wait_ready(p["loop_start_timeout_s"])
        rt = "; ".join(f"{k}: {v}" for k, v in info.realtime())
        self.get_logger().info(f"control loop process ready in {time.perf_counter() - t0:.1f} s (kernels warmed "
                               f"up in {info.warm_up_s:.1f} s); {rt}")
        if p["rt_priority"] > 0 and not all(v.startswith("SCHED_FIFO") for v in (info.tick, info.solver)):
            self.get_logger().warning(f"the control loop runs WITHOUT real-time priority: {info.tick}")
        scene = str(config_path(p["scene_file"])) if p["scene_file"] else ""
        m.scene_map(scene_file_voxels(scene, p["resolution_m"], tuple(p["scene_exclude_groups"])) if scene else None,
                    scene)

        state, inputs, actions = (MutuallyExclusiveCallbackGroup(), MutuallyExclusiveCallbackGroup(),
                                  ReentrantCallbackGroup())
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_subscription(PointCloud2, "voxel_map", lambda msg: m.map_message(
            lambda: msgs.points_from_cloud(msg)), LATCHED, callback_group=inputs)
        self.create_subscription(PointCloud2, "voxel_map/unobserved", lambda msg: m.unobserved_message(
            lambda: msgs.points_from_cloud(msg)), LATCHED, callback_group=inputs)
        self.create_subscription(JointTrajectory, "reach_trajectory", lambda msg: m.trajectory_topic(
            lambda: TrajectoryGoal(exec_msgs.reference_from_trajectory(msg, self.robot), msg.header.frame_id)),
            RELIABLE_LATEST, callback_group=inputs)
        self.create_subscription(PoseArray, "dual_arm/targets", lambda msg: m.targets_topic(
            lambda: exec_msgs.array_hand_targets(msg)), QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT),
            callback_group=inputs)
        self.create_service(Trigger, "~/dual_arm_sequential", self._on_sequential, callback_group=inputs)
        requests = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        servers = dict(goal_callback=lambda _goal: GoalResponse.ACCEPT,
                       cancel_callback=lambda _goal: CancelResponse.ACCEPT, callback_group=actions,
                       goal_service_qos_profile=requests, result_service_qos_profile=requests,
                       cancel_service_qos_profile=requests)
        self.action_server = ActionServer(self, ExecuteReach, "execute_reach", execute_callback=self._on_execute,
                                          **servers)
        self.look_server = ActionServer(self, Look, "look", execute_callback=self._on_look, **servers)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(p["diagnostics_period_s"], self._publish_diagnostics, clock=steady, callback_group=state)
        self.create_timer(0.1, m.watch_joint_states, clock=steady, callback_group=state)
        self.add_post_set_parameters_callback(self._on_parameters)
        self.get_logger().info(
            f"reach executor ready: actions execute_reach (trajectory, dual arm) and look (head poses, scan), "
            f"topics reach_trajectory, dual_arm/targets (follow {'on' if p['dual_arm_follow'] else 'off'}); "
            f"/joint_command every {self.period_s * 1e3:g} ms while executing or holding; solver "
            f"{self.params.solver}, distance bound {self.params.distance_bound_m:g} m; joint_states stale after "
            f"{p['joint_states_timeout_s']:g} s")

    def _on_parameters(self, params) -> None:
        self.manager.reconfigure({x.name: x.value for x in params})

    def _on_execute(self, goal_handle) -> ExecuteReach.Result:
        port = GoalHandlePort(goal_handle, lambda st: exec_msgs.execute_feedback(st.last))
        out = self.manager.execute(lambda: _execute_goal(goal_handle.request, self.robot), port)
        port.close(out.code)
        return exec_msgs.result_message(out.code, out.message, out.summary)

    def _on_look(self, goal_handle) -> Look.Result:
        req = goal_handle.request
        port = GoalHandlePort(goal_handle, _look_feedback)
        out = self.manager.look(lambda: LookGoal(tuple(req.yaw_rad), tuple(req.pitch_rad),
                                                 exec_msgs.gaze_points(req), float(req.dwell_s),
                                                 bool(req.come_back)), port)
        port.close(out.code)
        return Look.Result(success=out.success, error_code=msgs.error_code(out.code), message=out.message,
                           poses_done=out.poses_done, duration_s=out.duration_s, max_com_error_m=out.max_com_error_m)

    def _on_sequential(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        response.success, response.message = self.manager.sequential()
        return response

    def diagnostic_statuses(self) -> list:
        return [msgs.diagnostic_status(f"{self.get_name()}: {name}", level, message, values, self.robot.name)
                for name, level, message, values in self.manager.diagnostics(self.period_s)]

    def _publish_diagnostics(self) -> None:
        self.diagnostics_pub.publish(msgs.diagnostic_array(self.diagnostic_statuses(),
                                                           self.get_clock().now().to_msg()))

    def destroy_node(self) -> None:
        # the child tears its node down while this process tears down its own (two DDS
        # participants' teardown overlap: Ctrl-C ends the node within STOP_DEADLINE_S on a busy machine)
        self.loop.request_close()
        self.joint_states.destroy()
        for server in (self.action_server, self.look_server):
            try:
                server.destroy()
            except Exception:
                pass
        self.loop.close()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """Run the node until Ctrl-C / SIGTERM (exit 0); a configuration error exits 2."""
    return run_node(ReachExecutorNode, NODE_NAME, args, executor=lambda: MultiThreadedExecutor(num_threads=4))


if __name__ == "__main__":
    sys.exit(main())
