"""``reach_operator``, the operator's CLI: its rclpy side. :class:`Operator` is the ``operator.session``
flow's client: ``/plan_reach``, ``/execute_reach`` and ``/look``, waits that honour Ctrl-C, goal statuses
standing in for lost responses, the marker's topics, the executor's parameters, message conversions.
Arguments: ``operator.cli``; texts and exit codes: ``operator.report``; docs/operator.md has every flag.
"""
from __future__ import annotations

import argparse
import signal
import sys
import time
from contextlib import contextmanager
from typing import Any, Callable, Iterator, TextIO

import numpy as np

from humanoid_reach_ros.codes import ExecuteCode
from humanoid_reach_ros.operator.cli import parse_args, plan_inputs
from humanoid_reach_ros.operator.goal_status import GOAL_DONE, GOAL_KNOWN, GoalStatuses
from humanoid_reach_ros.operator.marker import MarkerSightings
from humanoid_reach_ros.operator.report import (
    EXIT, Progress, ProgressPrinter, code_text, execution_report, execution_summary,
    exit_class, progress_bar, trajectory_duration)
from humanoid_reach_ros.operator.session import Canceled, Countdown, OperatorSession

__all__ = ["EXIT", "Operator", "OperatorSession", "Progress", "ProgressPrinter",
           "code_text", "execution_report", "execution_summary", "exit_class", "main", "parse_args", "plan_request",
           "progress_bar"]   # the names tests and benches use

SCAN_POSES_ASSUMED = 20   # for the result deadline of a scan: poses of the executor's scan_poses_deg at most
LOOK_START_GRACE_S = 5.0        # /look answered NO_JOINT_STATES: asked again for this long (a graph just up)
EXECUTOR_NODE = "/reach_executor"       # the executor node the CLI talks to (its parameters)


def plan_request(args: argparse.Namespace) -> Any:
    """The ``PlanReach`` request of the command line (``cli.plan_inputs``)."""
    import pinocchio as pin
    from humanoid_reach_interfaces.srv import PlanReach
    from humanoid_reach_ros.io import msgs

    p = plan_inputs(args)
    req = PlanReach.Request(arm=p.arm, goal_count=p.goal_count, planner=p.planner, time_budget_s=p.time_budget_s,
                            use_marker_target=p.use_marker_target, execute=False, seed=p.seed, home=p.home)
    if p.target is not None:
        req.region.target = msgs.pose_stamped(pin.SE3(p.target[1], p.target[0]), p.frame)
    req.region.lower, req.region.upper = p.lower, p.upper
    return req


class Operator:
    """The rclpy side: one node, service + action clients, waits that honour Ctrl-C."""

    def __init__(self, timeout_s: float, err: TextIO, init: bool = True) -> None:
        """``init``: initialise rclpy here (the CLI); False: a process that did (the console node)."""
        import rclpy
        from action_msgs.msg import GoalStatusArray
        from rclpy.action import ActionClient
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import qos_profile_action_status_default
        from rclpy.signals import SignalHandlerOptions

        from humanoid_reach_interfaces.action import ExecuteReach, Look
        from humanoid_reach_interfaces.srv import PlanReach

        self.rclpy, self.timeout_s, self.err, self.interrupted, self.owns_rclpy = rclpy, timeout_s, err, False, init
        if init:
            rclpy.init(args=sys.argv, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(f"reach_operator_{int(time.time() * 1e3) % 10**9}")
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self.plan_client = self.node.create_client(PlanReach, "/plan_reach")
        self.exec_client = ActionClient(self.node, ExecuteReach, "/execute_reach")
        self.look_client = ActionClient(self.node, Look, "/look")
        self.ExecuteReach, self.Look = ExecuteReach, Look
        self.goal_status = GoalStatuses()   # as the servers publish it: for lost responses (:meth:`_await`)
        for name in ("/execute_reach", "/look"):
            self.node.create_subscription(GoalStatusArray, f"{name}/_action/status", self._on_status,
                                          qos_profile_action_status_default)

    def _on_status(self, msg: Any) -> None:
        for st in msg.status_list:
            self.goal_status.update(bytes(st.goal_info.goal_id.uuid), int(st.status))

    def close(self) -> None:
        self.look_client.destroy()
        self.exec_client.destroy()
        self.node.destroy_node()
        if self.owns_rclpy:
            self.rclpy.try_shutdown()

    def spin_until(self, done: Callable[[], bool], timeout_s: float | None, cancelable: bool = True) -> bool:
        """Spin until ``done()``; False on timeout; ``Canceled`` on Ctrl-C when ``cancelable``."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while not done():
            if cancelable and self.interrupted:
                raise Canceled()
            if deadline is not None and time.monotonic() > deadline:
                return False
            self.executor.spin_once(timeout_sec=0.02)
        return True

    def wait_for_server(self, ready: Callable[[], bool], name: str, owner: str) -> bool:
        """Spin until ``ready()`` (a server is up), at most ``timeout_s``, with ``session.Countdown``'s lines
        on stderr (``waiting for /look (reach_executor) ... 55 s left``); False on timeout; Canceled on Ctrl-C."""
        notes = Countdown(self.err, f"{name} ({owner})", self.timeout_s)
        return self.spin_until(lambda: ready() or notes.tick(), self.timeout_s)

    def wait_for_look(self, owner: str) -> bool:
        return self.wait_for_server(self.look_client.server_is_ready, "/look", owner)

    def _executor_up(self, client: Any, name: str) -> str | None:
        """None when the executor's action ``name`` is there, else the outcome: canceled, unavailable."""
        try:
            if self.wait_for_server(client.server_is_ready, name, "reach_executor"):
                return None
        except Canceled:
            return "canceled"
        self.err.write(f"reach_operator: {name} not available after {self.timeout_s:g} s: is reach_executor running?\n")
        return "unavailable"

    @contextmanager
    def watch_marker(self) -> Iterator[MarkerSightings]:
        """``/target_pose``, ``/diagnostics`` and ``/joint_states`` for a ``with`` block."""
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseStamped
        from rclpy.qos import qos_profile_sensor_data as sensor
        from sensor_msgs.msg import JointState

        w = MarkerSightings(lambda: self.node.count_publishers("/target_pose"))
        subs = [self.node.create_subscription(PoseStamped, "/target_pose", w.on_pose, sensor),
                self.node.create_subscription(DiagnosticArray, "/diagnostics", w.on_diagnostics, 20),
                self.node.create_subscription(JointState, "/joint_states", w.on_joint_state, sensor)]
        try:
            yield w
        finally:
            for sub in subs:
                self.node.destroy_subscription(sub)

    @contextmanager
    def watch_map(self) -> Iterator[MarkerSightings]:
        """``/diagnostics`` only (the voxel mapper's map size) for a ``with`` block."""
        from diagnostic_msgs.msg import DiagnosticArray

        w = MarkerSightings(lambda: 0)
        sub = self.node.create_subscription(DiagnosticArray, "/diagnostics", w.on_diagnostics, 20)
        try:
            yield w
        finally:
            self.node.destroy_subscription(sub)

    def executor_parameters(self, names: list[str], timeout_s: float = 2.0) -> dict[str, Any]:
        """The executor's parameters ``names``; the declared defaults for those it does not answer in time."""
        from rcl_interfaces.srv import GetParameters
        from rclpy.parameter import parameter_value_to_python

        from humanoid_reach_ros.execution.config import PARAMETERS

        values = {n: PARAMETERS[n].default for n in names}
        client = self.node.create_client(GetParameters, f"{EXECUTOR_NODE}/get_parameters")
        try:
            if self.spin_until(client.service_is_ready, timeout_s):
                future = client.call_async(GetParameters.Request(names=names))
                if self.spin_until(future.done, timeout_s) and future.result() is not None:
                    for n, v in zip(names, future.result().values):
                        if v.type != 0:   # PARAMETER_NOT_SET
                            values[n] = parameter_value_to_python(v)
        finally:
            self.node.destroy_client(client)
        return values

    def plan(self, req: Any) -> Any | None:
        """The response, or None if the service is missing / does not answer."""
        if not self.wait_for_server(self.plan_client.service_is_ready, "/plan_reach", "reach_planner"):
            self.err.write(f"reach_operator: /plan_reach not available after {self.timeout_s:g} s: is reach_planner "
                           "running (same ROS_DOMAIN_ID)?\n")
            return None
        future = self.plan_client.call_async(req)
        budget = float(req.time_budget_s)
        if not self.spin_until(future.done, self.timeout_s + budget):
            self.err.write(f"reach_operator: no /plan_reach response within {self.timeout_s + budget:g} s\n")
            return None
        return future.result()

    def execute(self, trajectory: Any, arm: int, args: argparse.Namespace,
                on_feedback: Callable[[Progress], None]) -> tuple[str, Any]:
        """("done", result) | ("unavailable" | "rejected" | "timeout", None) | ("canceled", result or None)."""
        if (down := self._executor_up(self.exec_client, "/execute_reach")) is not None:
            return down, None
        goal = self.ExecuteReach.Goal(mode=self.ExecuteReach.Goal.MODE_TRAJECTORY, trajectory=trajectory, arm=arm,
                                      disable_collision_avoidance=args.no_collision_avoidance,
                                      disable_com_compensation=args.no_com_compensation,
                                      smooth_reshaping=args.smooth_reshaping)
        return self._await(self.exec_client, goal, lambda m: on_feedback(Progress.from_feedback(m.feedback)),
                           trajectory_duration(trajectory) + self.timeout_s)

    def look(self, yaw_rad: list[float], pitch_rad: list[float], dwell_s: float,
             on_feedback: Callable[[Any], None], gaze_points: np.ndarray | None = None,
             come_back: bool = False) -> tuple[str, Any]:
        """/look: head angles, or a whole-body gaze at each of ``gaze_points`` (K, 3) [m, world];
        ``come_back``: then back to the posture the look began in (the automatic looks)."""
        if (down := self._executor_up(self.look_client, "/look")) is not None:
            return down, None
        goal = self.Look.Goal(yaw_rad=list(yaw_rad), pitch_rad=list(pitch_rad), dwell_s=float(dwell_s),
                              come_back=bool(come_back))
        if gaze_points is not None:
            from humanoid_reach_ros.io.msgs import points_list
            goal.gaze_points = points_list(gaze_points)
        poses = len(yaw_rad) or (len(gaze_points) if gaze_points is not None else SCAN_POSES_ASSUMED)
        deadline = time.monotonic() + LOOK_START_GRACE_S
        while True:
            outcome, result = self._await(self.look_client, goal, lambda m: on_feedback(m.feedback),
                                          self.timeout_s + poses * ((dwell_s or 1.0) + 5.0))
            # right after the graph came up the executor may not have taken a /joint_states yet (bench/session,
            # a --scan at once after start-up: NO_JOINT_STATES): ask again, for a few seconds only
            if result is None or result.error_code.val != ExecuteCode.NO_JOINT_STATES or time.monotonic() > deadline:
                return outcome, result
            self.spin_until(lambda: False, 0.5)   # a pause that Ctrl-C ends (Canceled)

    def _await(self, client: Any, goal: Any, feedback: Callable[[Any], None],
               result_timeout_s: float) -> tuple[str, Any]:
        """Send the goal, await its response and result; its status (by our goal id) stands in for a lost one."""
        import uuid
        from unique_identifier_msgs.msg import UUID
        goal_id = UUID(uuid=list(uuid.uuid4().bytes))
        send, key = client.send_goal_async(goal, feedback_callback=feedback, goal_uuid=goal_id), bytes(goal_id.uuid)
        handle = None
        try:
            if not self.spin_until(lambda: send.done() or self.goal_status.says(key, GOAL_KNOWN), self.timeout_s):
                return "timeout", None
            if send.done():
                handle = send.result()
                if not handle.accepted:
                    return "rejected", None
            else:
                from rclpy.action.client import ClientGoalHandle
                self.err.write("reach_operator: the goal's acceptance never arrived (a response lost while the "
                               "server discovered this client); its status says accepted: waiting for its result\n")
                handle = ClientGoalHandle(client, goal_id, client._action_type.Impl.SendGoalService.Response(
                    accepted=True))
            result_future = handle.get_result_async()
            deadline = time.monotonic() + result_timeout_s
            if not self.spin_until(lambda: result_future.done() or self.goal_status.says(key, GOAL_DONE),
                                   deadline - time.monotonic()):
                return "timeout", None
            while not result_future.done():   # finished, and no result for LOST_RESPONSE_GRACE_S: ask again
                self.err.write("reach_operator: the goal finished but its result did not arrive: asking again\n")
                result_future = handle.get_result_async()
                if not self.spin_until(result_future.done,
                                       min(self.timeout_s, max(0.0, deadline - time.monotonic()))):
                    return "timeout", None
            return "done", result_future.result().result
        except Canceled:
            if handle is None and send.done() and send.result().accepted:
                handle = send.result()
            if handle is None:
                return "canceled", None
            self.err.write("\nreach_operator: Ctrl-C: canceling the goal ...\n")
            cancel = handle.cancel_goal_async()
            self.spin_until(cancel.done, self.timeout_s, cancelable=False)
            result_future = handle.get_result_async()
            self.spin_until(result_future.done, self.timeout_s, cancelable=False)
            return "canceled", result_future.result().result if result_future.done() else None


def run(args: argparse.Namespace, out: TextIO = sys.stdout, err: TextIO = sys.stderr) -> int:
    req = plan_request(args) if args.plan else None
    op = Operator(args.timeout, err)
    old = {s: signal.signal(s, lambda *_: setattr(op, "interrupted", True)) for s in (signal.SIGINT, signal.SIGTERM)}
    try:   # with --json, stdout holds only the JSON line
        return OperatorSession(op, args, err if args.json else out, err).run(req, out)
    finally:
        op.close()
        for s, h in old.items():
            signal.signal(s, h)


def main(argv: list[str] | None = None) -> int:
    from rclpy.utilities import remove_ros_args
    args = parse_args(remove_ros_args(sys.argv if argv is None else argv)[1:])
    try:
        return run(args)
    except (KeyboardInterrupt, Canceled):   # Ctrl-C before run() took the signal over, or between its steps
        sys.stderr.write("\nreach_operator: canceled (Ctrl-C)\n")
        return EXIT["canceled"]


if __name__ == "__main__":
    sys.exit(main())
