"""``reach_executor``: the 5 ms whole-body execution loop of Kanehiro et al. (Sec. IV-V).

An adapter between ROS and ``humanoid_reach_ros.execution`` (docs/architecture.md):

* the control loop (supervisor, whole-body executor, dual-arm controller, tick and solver
  threads at real-time priority where allowed) runs in a process of its own
  (``nodes/reach_executor_loop.py``) that publishes ``/joint_command`` every ``period_s`` while
  a motion runs and while holding after one, and ``/executor/metrics``; this node's
  callbacks never share an interpreter lock with the 5 ms deadlines;
* this node validates inputs and forwards them: the ``/execute_reach`` action
  (``MODE_TRAJECTORY``: ``goal.trajectory`` with the hand of ``goal.arm``, flags
  ``disable_collision_avoidance``, ``disable_com_compensation``, ``smooth_reshaping`` --
  reshaped here, seconds, while the loop holds; ``MODE_DUAL_ARM``: the dissertation's
  dual-arm controller to ``right_hand_target`` / ``left_hand_target`` in ``world`` or
  ``base_link``), ``/reach_trajectory`` (executed like a goal with ``arm = 0``),
  ``/dual_arm/targets`` (PoseArray right, left; followed while ``dual_arm_follow``),
  ``~/dual_arm_sequential`` (Sec. 5.4 sequential random targets), ``/voxel_map`` (the
  collision map: sphere tree built here, the object at the motion's target left out),
  ``/joint_states`` (the start posture when nothing was commanded; stale after
  ``joint_states_timeout_s``: NO_JOINT_STATES; after ``joint_states_abort_s`` a running
  motion is ABORTED and the last command held);
* it publishes the action feedback, the results and ``/diagnostics``.

Continuity, preemption, holding and the clock-following reference are the supervisor's
(``execution/supervisor.py``). Bad inputs never stop the node: an invalid goal gets
``INVALID_GOAL`` (or ``NO_JOINT_STATES``) with a message and does not disturb the running
motion; an invalid ``/reach_trajectory`` gets a throttled warning and a diagnostic.

Run: ``ros2 run humanoid_reach_ros reach_executor --ros-args --params-file
config/reach_executor.yaml`` (here: ``python -m humanoid_reach_ros.nodes.reach_executor ...``).
"""
from __future__ import annotations

import itertools
import sys
import time

import numpy as np
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

from humanoid_reach_ros.codes import ARM_AUTO, ExecuteCode as C, RequestError
from humanoid_reach_ros.execution.messages import SetMap, StopMotion
from humanoid_reach_ros.execution.requests import ExecutionRequests
from humanoid_reach_ros.io import exec_msgs, msgs
from humanoid_reach_ros.nodes.common import (LATCHED, RELIABLE_LATEST, LatestOnDemand, current_joints,
                                             declare_parameters, run_node, scene_file_voxels)
from humanoid_reach_ros.nodes.reach_executor_diagnostics import LoopWindow, executor_statuses
from humanoid_reach_ros.nodes.reach_executor_goals import MotionTracker, execute_goal, look_goal, reject
from humanoid_reach_ros.nodes.reach_executor_loop import LoopConfig, LoopProcess
from humanoid_reach_ros.nodes.reach_executor_params import (MAX_SEQUENTIAL, PARAMETERS, SOLVERS, executor_params,
                                                            supervisor_config)
from humanoid_reach_ros.paths import config_path
from humanoid_reach_ros.robot.model import RobotModel

NODE_NAME = "reach_executor"


class ReachExecutorNode(Node):
    """ROS adapter of the execution loop process (see the module docstring)."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = self.p = declare_parameters(self, PARAMETERS)
        if p["solver"] not in SOLVERS:
            raise ValueError(f"solver must be one of {SOLVERS}, got {p['solver']!r}")
        if p["metrics_decimation"] < 1:
            raise ValueError(f"metrics_decimation must be >= 1, got {p['metrics_decimation']}")
        self.params = executor_params(p)
        self.period_s = self.params.period_s
        self.robot = RobotModel(p["robot_config"])
        self.hardware_id = self.robot.name
        self.requests = ExecutionRequests(self.robot, p)
        self.counters = self.requests.counters
        self.motion_ids = itertools.count(1)
        self.goal_ids, self._trajectory_ids = itertools.count(1), itertools.count(1)
        self._follow_ids, self._sequential_ids = itertools.count(1), itertools.count(1)
        self._aborted_id = None
        self._window = LoopWindow()
        self.tracker = MotionTracker(lambda command: self.loop.send(command), self.get_logger(), self.counters, p,
                                     lambda: self.context.ok())

        t0 = time.perf_counter()
        self.loop = LoopProcess(LoopConfig(
            robot_config=p["robot_config"], executor_params=self.params, supervisor=supervisor_config(p),
            dual_arm={"regression": self.requests.dual_arm_model(), "workspace": self.requests.dual_arm_workspace(),
                      "max_speed_mps": p["dual_arm_max_speed_mps"]} if self.requests.dual_arm_model() else None,
            node_name=f"{self.get_name()}_loop", namespace=self.get_namespace(),
            command_topic=self.resolve_topic_name("joint_command"),
            metrics_topic=self.resolve_topic_name("executor/metrics"), map_frame=p["map_frame"],
            metrics_decimation=p["metrics_decimation"], rt_priority=p["rt_priority"],
            lock_memory=p["lock_memory"], status_period_s=min(p["feedback_period_s"], 0.1),
            domain_id=self.context.get_domain_id()), self.tracker.on_event)
        info = self.loop.wait_ready(p["loop_start_timeout_s"])
        rt = "; ".join(f"{k}: {v}" for k, v in info.realtime())
        self.get_logger().info(f"control loop process ready in {time.perf_counter() - t0:.1f} s (kernels warmed "
                               f"up in {info.warm_up_s:.1f} s); {rt}")
        if p["rt_priority"] > 0 and not all(v.startswith("SCHED_FIFO") for v in (info.tick, info.solver)):
            self.get_logger().warning(f"the control loop runs WITHOUT real-time priority: {info.tick}")
        self.requests.send_map = lambda tree: self.loop.send(SetMap(tree))
        scene_voxels = None
        if p["scene_file"]:
            scene_path = config_path(p["scene_file"])
            scene_voxels = scene_file_voxels(str(scene_path), p["resolution_m"], tuple(p["scene_exclude_groups"]))
        tree, note = self.requests.scene_map(scene_voxels, str(scene_path) if scene_voxels is not None else "")
        if tree is not None:
            self.loop.send(SetMap(tree))
        self.get_logger().info(note)

        state, inputs, actions = (MutuallyExclusiveCallbackGroup(), MutuallyExclusiveCallbackGroup(),
                                  ReentrantCallbackGroup())
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        # the start posture and a staleness check only: taken when needed, no 200 Hz callbacks
        self.joint_states = LatestOnDemand(self, JointState, "joint_states", qos_profile_sensor_data)
        self.create_subscription(PointCloud2, "voxel_map", self._on_map, LATCHED, callback_group=inputs)
        self.create_subscription(JointTrajectory, "reach_trajectory", self._on_trajectory, RELIABLE_LATEST,
                                 callback_group=inputs)
        self.create_subscription(PoseArray, "dual_arm/targets", self._on_targets,
                                 QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT), callback_group=inputs)
        self.create_service(Trigger, "~/dual_arm_sequential", self._on_sequential, callback_group=inputs)
        requests = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.action_server = ActionServer(self, ExecuteReach, "execute_reach",
                                          execute_callback=lambda goal: execute_goal(self, goal),
                                          goal_callback=lambda _goal: GoalResponse.ACCEPT,
                                          cancel_callback=lambda _goal: CancelResponse.ACCEPT,
                                          callback_group=actions, goal_service_qos_profile=requests,
                                          result_service_qos_profile=requests, cancel_service_qos_profile=requests)
        self.look_server = ActionServer(self, Look, "look", execute_callback=lambda goal: look_goal(self, goal),
                                        goal_callback=lambda _goal: GoalResponse.ACCEPT,
                                        cancel_callback=lambda _goal: CancelResponse.ACCEPT, callback_group=actions,
                                        goal_service_qos_profile=requests, result_service_qos_profile=requests,
                                        cancel_service_qos_profile=requests)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(p["diagnostics_period_s"], self._publish_diagnostics, clock=steady, callback_group=state)
        self.create_timer(0.1, self._watch_joint_states, clock=steady, callback_group=state)
        self.add_post_set_parameters_callback(lambda params: [self.p.__setitem__(x.name, x.value) for x in params])
        self.get_logger().info(
            f"reach executor ready: actions execute_reach (trajectory, dual arm) and look (head poses, scan), "
            f"topics reach_trajectory, dual_arm/targets (follow {'on' if p['dual_arm_follow'] else 'off'}); "
            f"/joint_command every "
            f"{self.period_s * 1e3:g} ms while executing or holding; solver {self.params.solver}, distance bound "
            f"{self.params.distance_bound_m:g} m; joint_states stale after {p['joint_states_timeout_s']:g} s")

    # ------------------------------------------------------------ inputs
    def current_joints(self) -> tuple[np.ndarray | None, str]:
        """The latest valid joint angles, or None and the reason."""
        return current_joints(self.joint_states, self.p["joint_states_timeout_s"], self.robot)

    def _watch_joint_states(self) -> None:
        """A running motion whose /joint_states went stale is aborted (the loop holds)."""
        mid = self.tracker.status.motion_id
        age = self.joint_states.age_s()
        if mid is not None and mid != self._aborted_id and age > self.p["joint_states_abort_s"]:
            self._aborted_id = mid
            self.loop.send(StopMotion(mid, int(C.ABORTED), f"stopped: /joint_states stale ({age:.2f} s > "
                                                          f"{self.p['joint_states_abort_s']:g} s)"))

    def _on_map(self, msg: PointCloud2) -> None:
        try:
            tree, line, changed = self.requests.measured_map(msgs.points_from_cloud(msg))
        except Exception as exc:  # malformed cloud: keep the previous map
            self.requests.reject_map(exc)
            self.get_logger().warning(f"rejected /voxel_map ({self.counters.maps_rejected} so far): {exc}; keeping "
                                      f"the previous map ({self.counters.map_source})",
                                      throttle_duration_sec=self.p["warn_throttle_s"])
            return
        self.loop.send(SetMap(tree))
        if changed:   # state changes at INFO, repetition at DEBUG
            self.get_logger().info(line)
        else:
            self.get_logger().debug(line)

    def _on_trajectory(self, msg: JointTrajectory) -> None:
        self.counters.trajectories = n = next(self._trajectory_ids)
        label = f"/reach_trajectory #{n}"
        try:
            ref = exec_msgs.reference_from_trajectory(msg, self.robot)
            motion = self.requests.trajectory(next(self.motion_ids), label, ref, msg.header.frame_id, ARM_AUTO, False,
                                              False, False, *self.current_joints(), log=self.get_logger().info)
        except Exception as exc:  # never die on an input
            reject(self, "trajectories_rejected", label, exc)
            return
        self.get_logger().info(f"{label}: accepted: {self.requests.describe(motion)}")
        self.tracker.submit(motion)

    def _on_targets(self, msg: PoseArray) -> None:
        c = self.counters
        c.target_messages = n = next(self._follow_ids)
        label = f"/dual_arm/targets #{n}"
        try:
            targets = exec_msgs.array_hand_targets(msg)
            if not self.p["dual_arm_follow"]:
                c.target_messages_ignored += 1
                self.get_logger().info(f"{label} ignored: dual_arm_follow is false (set it true to follow the "
                                       "targets)", throttle_duration_sec=self.p["warn_throttle_s"])
                return
            motion = self.requests.dual(next(self.motion_ids), label, targets, *self.current_joints(), follow=True)
        except Exception as exc:
            reject(self, "target_messages_rejected", label, exc)
            return
        if self.requests.unchanged(motion.targets, self.tracker.status.dual_targets):
            c.target_messages_unchanged += 1
            return
        self.get_logger().info(f"{label}: accepted: {self.requests.describe(motion)}",
                               throttle_duration_sec=self.p["warn_throttle_s"])
        self.tracker.submit(motion)

    def _on_sequential(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        count, seed = int(self.p["dual_arm_sequential_count"]), int(self.p["dual_arm_sequential_seed"])
        label = f"sequential #{next(self._sequential_ids)}"
        t0 = time.perf_counter()
        try:
            if not 1 <= count <= MAX_SEQUENTIAL:
                raise RequestError(C.INVALID_GOAL, f"dual_arm_sequential_count must be in 1..{MAX_SEQUENTIAL}, "
                                                   f"got {count}")
            if seed < 0:
                raise RequestError(C.INVALID_GOAL, f"dual_arm_sequential_seed must be >= 0, got {seed}")
            motion = self.requests.sequential(next(self.motion_ids), label, count, seed, *self.current_joints())
        except Exception as exc:
            reject(self, "goals_rejected", "~/dual_arm_sequential", exc)
            response.success, response.message = False, str(exc)
            return response
        self.get_logger().info(f"{label}: accepted: {self.requests.describe(motion)}")
        self.tracker.submit(motion)
        response.success, response.message = True, (f"{label}: {count} random target pairs (seed {seed}, drawn in "
                                                     f"{time.perf_counter() - t0:.2f} s)")
        return response

    # ------------------------------------------------------------ diagnostics
    def diagnostic_statuses(self) -> list:
        return executor_statuses(self, self._window)

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
