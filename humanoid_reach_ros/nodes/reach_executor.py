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

import dataclasses
import itertools
import math
import sys
import threading
import time
import traceback

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
from humanoid_reach_ros.execution.requests import ExecutionRequests
from humanoid_reach_ros.execution.supervisor import IDLE, Motion
from humanoid_reach_ros.io import exec_msgs, msgs
from humanoid_reach_ros.nodes.common import (LATCHED, RELIABLE_LATEST, LatestOnDemand, current_joints,
                                             declare_parameters, run_node)
from humanoid_reach_ros.nodes.reach_executor_loop import LoopConfig, LoopProcess
from humanoid_reach_ros.nodes.reach_executor_params import (MAX_SEQUENTIAL, PARAMETERS, SOLVERS, executor_params,
                                                            supervisor_config)
from humanoid_reach_ros.robot.model import RobotModel

NODE_NAME = "reach_executor"
R = ExecuteReach.Result
RESULT_NAMES = {int(c): c.name for c in C}


@dataclasses.dataclass(eq=False)
class Pending:
    """A motion handed to the loop, as this node follows it."""

    label: str
    finished: threading.Event = dataclasses.field(default_factory=threading.Event)
    code: int | None = None
    message: str = ""
    summary: dict = dataclasses.field(default_factory=dict)


class ReachExecutorNode(Node):
    """ROS adapter of the execution loop process (see the module docstring)."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = self._p = declare_parameters(self, PARAMETERS)
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
        self._ids = itertools.count(1)
        self._goal_ids, self._trajectory_ids = itertools.count(1), itertools.count(1)
        self._follow_ids, self._sequential_ids = itertools.count(1), itertools.count(1)
        self._pending: dict[int, Pending] = {}
        self._lock = threading.Lock()
        self.status: dict = {"mode": IDLE}
        self.last_result: Pending | None = None
        self._aborted_id = None

        t0 = time.perf_counter()
        self.loop = LoopProcess(LoopConfig(
            robot_config=p["robot_config"], executor_params=self.params, supervisor=supervisor_config(p),
            dual_arm={"regression": p["dual_arm_regression"] or self.robot.spec.torso_regression,
                      "workspace": p["dual_arm_workspace"],
                      "max_speed_mps": p["dual_arm_max_speed_mps"]},
            node_name=f"{self.get_name()}_loop", namespace=self.get_namespace(),
            command_topic=self.resolve_topic_name("joint_command"),
            metrics_topic=self.resolve_topic_name("executor/metrics"), map_frame=p["map_frame"],
            metrics_decimation=p["metrics_decimation"], rt_priority=p["rt_priority"],
            lock_memory=p["lock_memory"], status_period_s=min(p["feedback_period_s"], 0.1),
            domain_id=self.context.get_domain_id()), self._on_event)
        info = self.loop.wait_ready(p["loop_start_timeout_s"])
        rt = "; ".join(f"{k}: {v}" for k, v in info.items() if k != "warm_up_s")
        self.get_logger().info(f"control loop process ready in {time.perf_counter() - t0:.1f} s (kernels warmed "
                               f"up in {info.get('warm_up_s', 0.0):.1f} s); {rt}")
        if p["rt_priority"] > 0 and not all(str(v).startswith("SCHED_FIFO") for k, v in info.items()
                                            if k in ("tick", "solver")):
            self.get_logger().warning(f"the control loop runs WITHOUT real-time priority: {info.get('tick')}")
        self.requests.send_map = lambda tree: self.loop.send(("map", tree))
        tree, note = self.requests.scene_map()
        if tree is not None:
            self.loop.send(("map", tree))
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
        self.action_server = ActionServer(self, ExecuteReach, "execute_reach", execute_callback=self._execute,
                                          goal_callback=lambda _goal: GoalResponse.ACCEPT,
                                          cancel_callback=lambda _goal: CancelResponse.ACCEPT,
                                          callback_group=actions, goal_service_qos_profile=requests,
                                          result_service_qos_profile=requests, cancel_service_qos_profile=requests)
        self.look_server = ActionServer(self, Look, "look", execute_callback=self._look,
                                        goal_callback=lambda _goal: GoalResponse.ACCEPT,
                                        cancel_callback=lambda _goal: CancelResponse.ACCEPT, callback_group=actions,
                                        goal_service_qos_profile=requests, result_service_qos_profile=requests,
                                        cancel_service_qos_profile=requests)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(p["diagnostics_period_s"], self._publish_diagnostics, clock=steady, callback_group=state)
        self.create_timer(0.1, self._watch_joint_states, clock=steady, callback_group=state)
        self.add_post_set_parameters_callback(lambda params: [self._p.__setitem__(x.name, x.value) for x in params])
        self.get_logger().info(
            f"reach executor ready: actions execute_reach (trajectory, dual arm) and look (head poses, scan), "
            f"topics reach_trajectory, dual_arm/targets (follow {'on' if p['dual_arm_follow'] else 'off'}); /joint_command every "
            f"{self.period_s * 1e3:g} ms while executing or holding; solver {self.params.solver}, distance bound "
            f"{self.params.distance_bound_m:g} m; joint_states stale after {p['joint_states_timeout_s']:g} s")

    # ------------------------------------------------------------ events of the loop process
    def _on_event(self, event: tuple) -> None:
        kind, log = event[0], self.get_logger()
        if kind == "status":
            self.status = event[1]
        elif kind == "started":
            _, mid, note, source = event
            with self._lock:
                pend = self._pending.get(mid)
            line = f"{pend.label}: started from {source}" + (f": {note}" if note else "") if pend else ""
            if pend is not None and pend.label.startswith("/dual_arm"):   # followed targets: throttled
                log.info(line, throttle_duration_sec=self._p["warn_throttle_s"])
            elif pend is not None:
                log.info(line)
        elif kind == "finished":
            _, mid, code, message, summary, _note = event
            with self._lock:
                pend = self._pending.pop(mid, None)
            if pend is None:
                return
            pend.code, pend.message, pend.summary = code, message, summary
            self.last_result = pend
            self.counters.last_result = f"{pend.label}: {RESULT_NAMES.get(code, code)}"
            self.counters.successes += int(code == C.SUCCESS)
            if code == C.INVALID_GOAL and message.startswith("infeasible"):
                self.counters.dual_arm_infeasible += 1
                self.counters.last_infeasible = f"{pend.label}: {message}"
            line = (f"{pend.label}: {RESULT_NAMES.get(code, code)} at progress {summary.pop('progress', 0.0):.2f}: "
                    f"{message} [{summary['duration_s']:.2f} s, "
                    f"{summary['steps']} steps, {summary['overruns']} overruns, max COG error "
                    f"{summary['max_com_error_m'] * 1e3:.2f} mm, min distance {summary['min_distance_m']:.4f} m, "
                    f"final hand error {summary['final_hand_error_m'] * 1e3:.2f} mm]")
            if code in (C.SUCCESS, C.PREEMPTED, C.CANCELED):
                log.info(line)
            else:
                log.warning(line)
            pend.finished.set()
        elif kind == "log" and event[1] == "error":
            log.error(event[2])
        elif kind == "log" and event[1] == "warning":
            log.warning(event[2])
        elif kind == "log":
            log.info(event[2])
        elif kind == "exited":
            if self.context.ok():
                log.error(f"the control loop process exited ({event[1]}): no more commands")
            with self._lock:
                pending, self._pending = list(self._pending.values()), {}
            for pend in pending:
                pend.code, pend.message = C.ABORTED, "the control loop process exited"
                pend.finished.set()

    def _submit(self, motion: Motion) -> Pending:
        pend = Pending(motion.label)
        with self._lock:
            self._pending[motion.id] = pend
        self.loop.send(("start", motion))
        return pend

    # ------------------------------------------------------------ inputs
    def current_joints(self) -> tuple[np.ndarray | None, str]:
        """The latest valid joint angles, or None and the reason."""
        return current_joints(self.joint_states, self._p["joint_states_timeout_s"], self.robot)

    def _watch_joint_states(self) -> None:
        """A running motion whose /joint_states went stale is aborted (the loop holds)."""
        st = self.status
        mid = st.get("motion_id")
        age = self.joint_states.age_s()
        if mid is not None and mid != self._aborted_id and age > self._p["joint_states_abort_s"]:
            self._aborted_id = mid
            self.loop.send(("stop", mid, int(C.ABORTED), f"stopped: /joint_states stale ({age:.2f} s > "
                                                           f"{self._p['joint_states_abort_s']:g} s)"))

    def _on_map(self, msg: PointCloud2) -> None:
        try:
            tree, line, changed = self.requests.measured_map(msgs.points_from_cloud(msg))
        except Exception as exc:  # malformed cloud: keep the previous map
            self.requests.reject_map(exc)
            self.get_logger().warning(f"rejected /voxel_map ({self.counters.maps_rejected} so far): {exc}; keeping "
                                      f"the previous map ({self.counters.map_source})",
                                      throttle_duration_sec=self._p["warn_throttle_s"])
            return
        self.loop.send(("map", tree))
        if changed:   # state changes at INFO, repetition at DEBUG
            self.get_logger().info(line)
        else:
            self.get_logger().debug(line)

    def _reject(self, counter: str, label: str, exc: Exception) -> None:
        code = exc.code if isinstance(exc, RequestError) else C.ABORTED
        what = RESULT_NAMES.get(code, code) if isinstance(exc, RequestError) else "internal error"
        setattr(self.counters, counter, getattr(self.counters, counter) + 1)
        self.counters.last_rejection = f"{label}: {what}: {exc}"
        if isinstance(exc, RequestError) and counter == "goals_rejected":
            self.get_logger().warning(f"{label} rejected ({what}): {exc}")
        elif isinstance(exc, RequestError):   # topics: throttled (a flood must not flood the log)
            self.get_logger().warning(f"rejected {label} ({what}): {exc}", throttle_duration_sec=self._p["warn_throttle_s"])
        else:
            self.get_logger().error(f"{label}: internal error: {exc}\n{traceback.format_exc()}")

    def _on_trajectory(self, msg: JointTrajectory) -> None:
        self.counters.trajectories = n = next(self._trajectory_ids)
        label = f"/reach_trajectory #{n}"
        try:
            ref = exec_msgs.reference_from_trajectory(msg, self.robot)
            motion = self.requests.trajectory(next(self._ids), label, ref, msg.header.frame_id, ARM_AUTO, False,
                                              False, False, *self.current_joints(), log=self.get_logger().info)
        except Exception as exc:  # never die on an input
            self._reject("trajectories_rejected", label, exc)
            return
        self.get_logger().info(f"{label}: accepted: {self.requests.describe(motion)}")
        self._submit(motion)

    def _on_targets(self, msg: PoseArray) -> None:
        c = self.counters
        c.target_messages = n = next(self._follow_ids)
        label = f"/dual_arm/targets #{n}"
        try:
            targets = exec_msgs.array_hand_targets(msg)
            if not self._p["dual_arm_follow"]:
                c.target_messages_ignored += 1
                self.get_logger().info(f"{label} ignored: dual_arm_follow is false (set it true to follow the "
                                       "targets)", throttle_duration_sec=self._p["warn_throttle_s"])
                return
            motion = self.requests.dual(next(self._ids), label, targets, *self.current_joints(), follow=True)
        except Exception as exc:
            self._reject("target_messages_rejected", label, exc)
            return
        if self.requests.unchanged(motion.targets, self.status.get("dual_targets")):
            c.target_messages_unchanged += 1
            return
        self.get_logger().info(f"{label}: accepted: {self.requests.describe(motion)}",
                               throttle_duration_sec=self._p["warn_throttle_s"])
        self._submit(motion)

    def _on_sequential(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        count, seed = int(self._p["dual_arm_sequential_count"]), int(self._p["dual_arm_sequential_seed"])
        label = f"sequential #{next(self._sequential_ids)}"
        t0 = time.perf_counter()
        try:
            if not 1 <= count <= MAX_SEQUENTIAL:
                raise RequestError(C.INVALID_GOAL, f"dual_arm_sequential_count must be in 1..{MAX_SEQUENTIAL}, "
                                                   f"got {count}")
            if seed < 0:
                raise RequestError(C.INVALID_GOAL, f"dual_arm_sequential_seed must be >= 0, got {seed}")
            motion = self.requests.sequential(next(self._ids), label, count, seed, *self.current_joints())
        except Exception as exc:
            self._reject("goals_rejected", "~/dual_arm_sequential", exc)
            response.success, response.message = False, str(exc)
            return response
        self.get_logger().info(f"{label}: accepted: {self.requests.describe(motion)}")
        self._submit(motion)
        response.success, response.message = True, (f"{label}: {count} random target pairs (seed {seed}, drawn in "
                                                     f"{time.perf_counter() - t0:.2f} s)")
        return response

    # ------------------------------------------------------------ action
    def _execute(self, goal_handle) -> ExecuteReach.Result:
        self.counters.goals = max(self.counters.goals, n := next(self._goal_ids))
        label, req = f"goal #{n}", goal_handle.request
        try:
            joints = self.current_joints()
            if req.mode == ExecuteReach.Goal.MODE_DUAL_ARM:
                try:
                    targets = exec_msgs.goal_hand_targets(req.right_hand_target, req.left_hand_target)
                    motion = self.requests.dual(next(self._ids), label, targets, *joints)
                except RequestError as exc:
                    raise RequestError(exc.code, f"MODE_DUAL_ARM goal: {exc}") from None
                self.counters.dual_arm_goals += 1
            elif req.mode != ExecuteReach.Goal.MODE_TRAJECTORY:
                raise RequestError(C.INVALID_GOAL, f"mode {req.mode} is unknown; use 0 (TRAJECTORY) or 1 (DUAL_ARM)")
            else:
                ref = exec_msgs.reference_from_trajectory(req.trajectory, self.robot)
                motion = self.requests.trajectory(next(self._ids), label, ref, req.trajectory.header.frame_id, req.arm,
                                                  req.disable_collision_avoidance, req.disable_com_compensation,
                                                  req.smooth_reshaping, *joints, log=self.get_logger().info)
        except Exception as exc:  # never die on a goal
            self._reject("goals_rejected", label, exc)
            goal_handle.abort()
            code = exc.code if isinstance(exc, RequestError) else C.ABORTED
            return exec_msgs.result_message(code, str(exc) if isinstance(exc, RequestError)
                                            else f"internal error: {type(exc).__name__}: {exc}")
        if goal_handle.is_cancel_requested:  # while it was being validated / reshaped
            self.get_logger().info(f"{label}: CANCELED before execution started")
            goal_handle.canceled()
            return exec_msgs.result_message(C.CANCELED, "canceled before execution started")
        self.get_logger().info(f"{label}: accepted: {self.requests.describe(motion)}")
        pend = self._follow(goal_handle, motion, lambda st: goal_handle.publish_feedback(
            exec_msgs.execute_feedback(st["last"])))
        result = exec_msgs.result_message(pend.code, pend.message, pend.summary)
        self._close_goal(goal_handle, pend.code)
        return result

    def _follow(self, goal_handle, motion: Motion, feedback) -> Pending:
        """Submit ``motion`` and wait for its end, sending ``feedback(status)`` while it runs and
        the stop to the loop when the client cancels."""
        pend = self._submit(motion)
        cancel_sent = False
        while not pend.finished.wait(self._p["feedback_period_s"]):
            if not self.context.ok():
                break
            if goal_handle.is_cancel_requested and not cancel_sent:
                cancel_sent = True
                self.loop.send(("stop", motion.id, int(C.CANCELED), "canceled by the client"))
            st = self.status
            if st.get("motion_id") == motion.id and st.get("last") is not None and goal_handle.is_active:
                feedback(st)
        if pend.code is None:
            pend.code, pend.message = C.ABORTED, "the reach_executor node is shutting down"
        return pend

    @staticmethod
    def _close_goal(goal_handle, code: int) -> None:
        if code == C.SUCCESS:
            goal_handle.succeed()
        elif code == C.CANCELED and goal_handle.is_cancel_requested:
            goal_handle.canceled()
        else:
            goal_handle.abort()

    def _look(self, goal_handle) -> Look.Result:
        """The look action: one whole-body motion per head pose, each followed by ``dwell_s`` of
        holding (the loop holds after a motion); feedback names the pose."""
        self.counters.goals = max(self.counters.goals, n := next(self._goal_ids))
        label, req, t0 = f"look #{n}", goal_handle.request, time.monotonic()
        result = Look.Result(error_code=int(C.SUCCESS))
        try:
            poses = self.requests.head_poses(list(req.yaw_rad), list(req.pitch_rad))
            dwell = float(req.dwell_s) if math.isfinite(req.dwell_s) and req.dwell_s > 0 else self._p["scan_dwell_s"]
            if dwell > 60.0:
                raise RequestError(C.INVALID_GOAL, f"dwell_s {dwell:g} s is longer than 60 s")
        except RequestError as exc:
            self._reject("goals_rejected", label, exc)
            goal_handle.abort()
            return Look.Result(error_code=exc.code, message=str(exc))
        self.get_logger().info(f"{label}: accepted: {len(poses)} head poses, {dwell:g} s each")
        fb = Look.Feedback(pose_count=len(poses))
        for k, (yaw, pitch) in enumerate(poses):
            fb.pose_index, fb.yaw_rad, fb.pitch_rad, fb.holding = k, float(yaw), float(pitch), False
            goal_handle.publish_feedback(fb)
            try:
                motion = self.requests.look(next(self._ids), f"{label} pose {k}", (yaw, pitch), *self.current_joints())
            except RequestError as exc:
                result.error_code, result.message = exc.code, f"pose {k}: {exc}"
                break
            pend = self._follow(goal_handle, motion, lambda st: None)
            result.max_com_error_m = max(result.max_com_error_m, float(pend.summary.get("max_com_error_m", 0.0)))
            if pend.code != C.SUCCESS:
                result.error_code, result.message = pend.code, f"pose {k}: {pend.message}"
                break
            fb.holding = True
            goal_handle.publish_feedback(fb)
            end = time.monotonic() + dwell
            while time.monotonic() < end and not goal_handle.is_cancel_requested and self.context.ok():
                time.sleep(min(0.05, max(0.0, end - time.monotonic())))
            if goal_handle.is_cancel_requested:
                result.error_code, result.message = int(C.CANCELED), f"canceled at pose {k} (holding there)"
                break
            result.poses_done = k + 1
        result.success = result.error_code == C.SUCCESS
        result.duration_s = time.monotonic() - t0
        if result.success:
            result.message = f"{len(poses)} head poses reached and held {dwell:g} s each"
        line = (f"{label}: {RESULT_NAMES.get(result.error_code, result.error_code)}: {result.message} "
                f"[{result.duration_s:.1f} s, max COG error {result.max_com_error_m * 1e3:.2f} mm]")
        if result.error_code in (C.SUCCESS, C.CANCELED):   # one severity per call site (rclpy's rule)
            self.get_logger().info(line)
        else:
            self.get_logger().warning(line)
        self._close_goal(goal_handle, result.error_code)
        return result

    # ------------------------------------------------------------ diagnostics
    def diagnostic_statuses(self) -> list:
        st, c = dict(self.status), self.counters
        name, hw = self.get_name(), self.hardware_id
        values = {"state": st.get("mode", IDLE), "motion": st.get("motion_label", ""),
                  "progress": st.get("progress", 0.0), "engine": st.get("engine", ""),
                  "dual_arm_follow": bool(self._p["dual_arm_follow"]),
                  **{k: v for k, v in dataclasses.asdict(c).items() if not k.startswith("map")}}
        message = f"{values['state']}" + (f": {values['motion']}" if values["motion"] else "")
        if c.last_rejection:
            message += f"; last rejection: {c.last_rejection}"
        out = [msgs.diagnostic_status(f"{name}: execution", msgs.LEVEL_OK, message, values, hw)]
        w = self._window = getattr(self, "_window", {"steps": 0, "overruns": 0, "missed": 0, "ticks": 0,
                                                     "t": time.monotonic()})
        now = time.monotonic()
        steps, overruns = st.get("steps", 0) - w["steps"], st.get("overruns", 0) - w["overruns"]
        ticks, elapsed = st.get("ticks", 0) - w["ticks"], max(now - w["t"], 1e-9)
        self._window = {"steps": st.get("steps", 0), "overruns": st.get("overruns", 0), "ticks": st.get("ticks", 0),
                        "missed": st.get("missed_deadlines", 0), "t": now}
        values = {"nominal_rate_hz": 1.0 / self.period_s, "tick_rate_hz": ticks / elapsed, "steps_recent": steps,
                  "overruns_recent": overruns, "overruns_total": st.get("overruns", 0),
                  "missed_deadlines_total": st.get("missed_deadlines", 0), "published_total": st.get("published", 0),
                  "step_p50_ms": st.get("step_p50_ms", 0.0), "step_p99_ms": st.get("step_p99_ms", 0.0),
                  "max_step_ms": st.get("step_max_ms", 0.0), "hold_step_p99_ms": st.get("hold_step_p99_ms", 0.0),
                  "loop_process_alive": self.loop.alive()}
        level, message = msgs.LEVEL_OK, f"{ticks / elapsed:.0f} Hz ticks, {steps} steps, {overruns} overruns"
        if not self.loop.alive():
            level, message = msgs.LEVEL_ERROR, "the control loop process is not running"
        elif steps and overruns / max(steps + overruns, 1) > self._p["max_overrun_fraction"]:
            level, message = msgs.LEVEL_WARN, f"{overruns} of {steps + overruns} periods overran (last command held)"
        out.append(msgs.diagnostic_status(f"{name}: loop", level, message, values, hw))
        joints, reason = self.current_joints()
        last = st.get("last_joints")
        values = {"joint_states_age_s": self.joint_states.age_s() if self.joint_states.latest() is not None
                  else "never", "tracking_error_rad": float(np.max(np.abs(joints - last)))
                  if joints is not None and last is not None else 0.0,
                  **{k: v for k, v in dataclasses.asdict(c).items() if k.startswith("map")}}
        level, message = (msgs.LEVEL_OK, "joint_states current") if joints is not None else (msgs.LEVEL_WARN, reason)
        out.append(msgs.diagnostic_status(f"{name}: inputs", level, message, values, hw))
        return out

    def _publish_diagnostics(self) -> None:
        self.diagnostics_pub.publish(msgs.diagnostic_array(self.diagnostic_statuses(),
                                                           self.get_clock().now().to_msg()))

    def destroy_node(self) -> None:
        self.loop.close()
        self.joint_states.destroy()
        for server in (self.action_server, self.look_server):
            try:
                server.destroy()
            except Exception:
                pass
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """Run the node until Ctrl-C / SIGTERM (exit 0); a configuration error exits 2."""
    return run_node(ReachExecutorNode, NODE_NAME, args, executor=lambda: MultiThreadedExecutor(num_threads=4))


if __name__ == "__main__":
    sys.exit(main())
