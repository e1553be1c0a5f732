"""``reach_planner``: the planning service of Kanehiro et al. (goal sampling + RRT-connect/PRM).

A thin node around ``humanoid_reach_ros.planning.service.PlanningService`` (which holds
``planning.reach.ReachPlanner``, the planning scene, the request logic, the log lines, the
diagnostics' content and the counters): it declares the parameters, converts the messages
(``io/msgs.py``), runs the timers and publishes:

* subscribes ``/voxel_map`` (sensor_msgs/PointCloud2 of occupied voxel centres in
  ``map_frame``; transient local, reliable, depth 1): each new map rebuilds the planner's
  environment model. Until one arrives the map comes from the ``scene_file`` parameter
  (empty = no map until ``/voxel_map``). A malformed cloud is rejected with a warning and
  the previous map stays;
* subscribes ``/joint_states`` (the start posture; stale after ``joint_states_timeout_s``)
  and ``/target_pose`` (geometry_msgs/PoseStamped of the AR marker, used by requests with
  ``use_marker_target``; stale after ``target_timeout_s``);
* serves ``/plan_reach`` (humanoid_reach_interfaces/srv/PlanReach): validates and converts
  the request (``io.msgs.reach_request``), calls ``ReachPlanner.plan`` and fills the
  response (30-joint trajectory in ``map_frame``, waist_start, arm, statistics, message);
* publishes ``/reach_trajectory`` (trajectory_msgs/JointTrajectory, reliable, depth 1) when
  a request has ``execute`` and planning succeeded, ``/planning/markers``
  (visualization_msgs/MarkerArray: target region, goal hand poses, hand path) after each
  plan, and ``/diagnostics`` (map source and size, last plan result, planning times).

Concurrency policy (MultiThreadedExecutor):

* the service runs in a reentrant callback group so that a second request arriving while
  one is planning is answered at once with ``BUSY`` (a non-blocking ``plan lock``) instead
  of queueing behind it;
* ``/joint_states`` and ``/target_pose`` run in their own mutually exclusive group and
  keep updating while a plan runs;
* ``/voxel_map`` has its own group; a new map is built beside a running plan and replaces
  the planner's map atomically when built (``ReachPlanner.set_map``): the running plan
  finishes on the map it started with, the next request uses the new one.

Every failure is a response with its error code and a message; an exception inside
planning becomes ``INTERNAL_ERROR`` and the node keeps serving.

Run: ``python -m humanoid_reach_ros.nodes.reach_planner --ros-args --params-file
config/reach_planner.yaml`` (``ros2 run humanoid_reach_ros reach_planner`` on an install).
"""
from __future__ import annotations

import sys
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from humanoid_reach_interfaces.srv import PlanReach
from rcl_interfaces.msg import SetParametersResult
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState, PointCloud2
from trajectory_msgs.msg import JointTrajectory
from visualization_msgs.msg import MarkerArray

from humanoid_reach_ros.geometry.body_sweep import DEFAULT_SELF_FILTER_MARGIN_M
from humanoid_reach_ros.io import msgs
from humanoid_reach_ros.io.endpoints import LATCHED, RELIABLE_LATEST, LatestOnDemand
from humanoid_reach_ros.nodes.common import declare_parameters, run_node
from humanoid_reach_ros.params import ParamSpec
from humanoid_reach_ros.planning.reach import PlannerParams
from humanoid_reach_ros.planning.space import PLANNER_NAMES
from humanoid_reach_ros.planning.service import PlanningService, PlanningServiceConfig, PlanReply
from humanoid_reach_ros.robot.spec import DEFAULT_ROBOT

NODE_NAME = "reach_planner"
#: a request within this long [s] of the first /voxel_map waits (up to the end of it) for the
#: map's unobserved layers, queued behind the map in its callback group (_wait_for_unobserved_layers)
UNOBSERVED_LAYERS_WAIT_S = 3.0
#: a request within this long [s] of the node's start waits until then: its subscriptions are new
#: and a client that waited for the service (the demo) asked before they matched the latched map and
#: the 10 Hz target (make demo ROBOT=talos: NO_TARGET "no /target_pose received" 14 ms after ready)
START_SETTLE_S = 1.5
__all__ = ["NODE_PARAMETERS", "PARAMETERS", "PLANNER_PARAMETERS", "PlannerParams", "ReachPlannerNode",
           "main"]

# Defaults match config/reach_planner.yaml (checked by test_reach_planner_node).
# These map one to one onto ``PlannerParams`` fields and take their defaults from it.
_D = PlannerParams()
PLANNER_PARAMETERS: dict[str, ParamSpec] = {
    "resolution_m": ParamSpec(_D.resolution_m,
                              "voxel size of the environment map [m] (scene-file maps are voxelised at it)",
                              (0.001, 1.0)),
    # the executor's velocity dampers keep d_s = 0.01 m (reach_executor security_distance_m): a plan closer
    # than that ends with the hand held off its goal (TARGET_NOT_REACHED), so plans keep it too
    "safety_margin_m": ParamSpec(0.01, "extra clearance added to the robot's collision shapes [m]; at least the "
                                 "executor's security_distance_m", (0.0, 0.5)),
    "goal_count": ParamSpec(_D.goal_count, "goal postures sampled per request (a request's goal_count > 0 overrides)"),
    "planner": ParamSpec(_D.planner, "default path planner (a request's non-empty planner overrides)",
                         constraints=f"one of {', '.join(PLANNER_NAMES)}"),
    "time_budget_s": ParamSpec(_D.time_budget_s, "default wall-time budget of one request [s]", (0.01, 600.0)),
    "joint_velocity_rad_s": ParamSpec(_D.joint_velocity_rad_s, "joint speed used to time the trajectory [rad/s]",
                                      (0.01, 10.0)),
    "output_period_s": ParamSpec(_D.output_period_s, "sample period of the output trajectory [s]", (0.001, 1.0)),
    "edge_resolution": ParamSpec(_D.edge_resolution, "collision-check step along path edges [rad, planning space]",
                                 (1e-4, 1.0)),
    "rrt_step": ParamSpec(_D.rrt_step, "RRT-connect extension step [rad, planning space]", (1e-3, 10.0)),
    "seed": ParamSpec(_D.seed, "random seed used when a request's seed is negative"),
    # off in the node (the library's PlannerParams has it on, bench/generality.py measures with it): in the
    # graph, a plan before the scan wanted space behind the robot with it (config/reach_planner.yaml)
    "use_reach_map": ParamSpec(False, "use the robot's reach map (robot.yaml reach_map): the proof of "
                               "TARGET_OUT_OF_REACH and the goal sampler's trunk cells; a map named but missing or "
                               "unreadable is a configuration error (exit 2)"),
    "reach_map_step_rad": ParamSpec(_D.reach_map_step_rad, "roll and yaw cell size of the reach map's trunk cells "
                                    "[rad]", (0.005, 1.0)),
    "reach_map_candidates": ParamSpec(_D.reach_map_candidates, "proposals of the reach map's capability map "
                                      "(a trunk draw and a stored hand orientation) tried per goal sample", (1, 256)),
    "reach_map_min_orientations": ParamSpec(_D.reach_map_min_orientations, "trunk cells from which the reach "
                                            "map holds fewer hand orientations at the target (its border) are "
                                            "sampled last", (1, 256)),
}

NODE_PARAMETERS: dict[str, ParamSpec] = {
    "robot_config": ParamSpec(DEFAULT_ROBOT, "robot: a name (config/robots/<name>/robot.yaml) or the path of "
                                          "a robot description (relative to config/, or absolute)"),
    "scene_file": ParamSpec("scenes/plant.yaml", "scene whose voxels are the map until /voxel_map arrives, "
                            "relative to config/ or absolute; empty = wait for /voxel_map"),
    "scene_exclude_groups": ParamSpec(["valve"], "scene primitive groups left out of the scene-file map "
                                      "(the object to be grasped)"),
    "map_frame": ParamSpec("world", "frame of /voxel_map, the trajectory and markers (the stance frame)"),
    "target_exclusion_radius_m": ParamSpec(0.15, "voxels of a /voxel_map within this distance of the request's "
                                           "target are the object to be reached and left out of the collision "
                                           "map [m]; 0 = keep all", (0.0, 1.0), read_only=False),
    "unobserved_space": ParamSpec("occupied", "space the head has not observed (from voxel_mapper's "
                                  "/voxel_map/unobserved and /voxel_map/unobserved_blocks): 'occupied' = never "
                                  "planned through (UNOBSERVED_SPACE: scan first), 'free' = planned through",
                                  constraints="one of: occupied, free", read_only=False),
    "unobserved_block_m": ParamSpec(0.1, "edge of the blocks of /voxel_map/unobserved_blocks [m] (voxel_mapper's "
                                    "unobserved_block_voxels * resolution_m)", (0.001, 10.0)),
    "body_clearance_m": ParamSpec(DEFAULT_SELF_FILTER_MARGIN_M, "the robot-volume policy: the robot's shapes "
                                  "grown by this (the depth sensor's self-filter margin), at the start of every "
                                  "request, count as observed free space in the planning scene; more counts space "
                                  "no sensor saw as seen [m]", (0.0, 0.1)),
    "joint_states_timeout_s": ParamSpec(0.5, "/joint_states older than this [s] -> NO_JOINT_STATES",
                                        (0.001, 3600.0), read_only=False),
    "target_timeout_s": ParamSpec(1.0, "/target_pose older than this [s] -> NO_TARGET for use_marker_target",
                                  (0.001, 3600.0), read_only=False),
    "diagnostics_period_s": ParamSpec(1.0, "period of /diagnostics [s]", (0.05, 60.0)),
    "marker_path_points": ParamSpec(100, "at most this many hand positions in the hand-path marker"),
    "warn_throttle_s": ParamSpec(1.0, "minimum interval between repeated warnings [s]", (0.0, 3600.0)),
}

PARAMETERS: dict[str, ParamSpec] = {**PLANNER_PARAMETERS, **NODE_PARAMETERS}


class ReachPlannerNode(Node):
    """Thin node around ``PlanningService``: parameters, topics, the service, conversions and timers."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self._p = declare_parameters(self, PARAMETERS)
        self.service = PlanningService(PlanningServiceConfig.from_parameters(self._p), log=self._log)
        self._map_since: float | None = None     # when the first /voxel_map arrived (monotonic)
        self.model, self.planner = self.service.model, self.service.planner
        self.map_frame, self.hardware_id = self.service.config.map_frame, self.model.name
        self.service.warm_up()
        self.service.load_scene_file()

        self._state_group = MutuallyExclusiveCallbackGroup()
        self._map_group = MutuallyExclusiveCallbackGroup()
        self._service_group = ReentrantCallbackGroup()
        self.trajectory_pub = self.create_publisher(JointTrajectory, "reach_trajectory", RELIABLE_LATEST)
        self.markers_pub = self.create_publisher(MarkerArray, "planning/markers", LATCHED)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_subscription(PointCloud2, "voxel_map", self._on_map, LATCHED, callback_group=self._map_group)
        for topic, layer in (("voxel_map/unobserved", "frontier"), ("voxel_map/unobserved_blocks", "blocks")):
            self.create_subscription(PointCloud2, topic, lambda m, t=topic, a=layer: self._on_unobserved(t, a, m),
                                     LATCHED, callback_group=self._map_group)
        # the start posture and the marker target: the latest messages, taken when a request needs them
        # (no callback per 200 Hz joint state or 10 Hz target; their ages come from the reception times)
        self.joint_states = LatestOnDemand(self, JointState, "joint_states", qos_profile_sensor_data)
        self.target_pose = LatestOnDemand(self, PoseStamped, "target_pose")
        self.create_service(PlanReach, "plan_reach", self._on_plan_reach, callback_group=self._service_group)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(self._p["diagnostics_period_s"], self._publish_diagnostics, clock=steady,
                          callback_group=self._state_group)
        self.add_on_set_parameters_callback(self._check_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.get_logger().info(self.service.ready_line())
        self._ready_at = time.monotonic()

    def _log(self, level: str, text: str, throttled: bool = False) -> None:
        """The service's log lines, through this node's logger (looked up per line); rclpy keys a line's
        severity and throttle by its call site, so each has its own (``throttled``: a warning)."""
        log = self.get_logger()
        if throttled:
            log.warning(text, throttle_duration_sec=self._p["warn_throttle_s"])
        elif level == "debug":
            log.debug(text)
        elif level == "info":
            log.info(text)
        elif level == "warning":
            log.warning(text)
        else:
            log.error(text)

    # ------------------------------------------------------------ subscriptions
    def _on_map(self, msg: PointCloud2) -> None:
        if self._map_since is None:
            self._map_since = time.monotonic()
        try:
            self.service.set_map(msgs.points_from_cloud(msg))
        except Exception as exc:  # malformed cloud or a map the planner refuses: keep the old one
            self.service.map_rejected(exc)
        self._publish_diagnostics()

    def _on_unobserved(self, topic: str, layer: str, msg: PointCloud2) -> None:
        """/voxel_map/unobserved (the frontier) or /voxel_map/unobserved_blocks into the planning
        scene, for the next request."""
        self.service.set_unobserved(self.resolve_topic_name(topic), layer, lambda: msgs.points_from_cloud(msg))

    def _wait_for_unobserved_layers(self, n: int) -> None:
        """A /voxel_map that arrived just before request ``n`` has its unobserved layers queued
        behind it (one callback group; the service runs beside it): wait for them up to
        ``UNOBSERVED_LAYERS_WAIT_S`` rather than answer UNOBSERVED_SPACE ("no
        /voxel_map/unobserved received"), as a planner whose warm-up ended as the map came did."""
        if self._map_since is None:
            return
        deadline = self._map_since + UNOBSERVED_LAYERS_WAIT_S
        scene = self.service.scene
        snap = scene.snapshot()
        if (snap.params.unobserved_space != "occupied" or snap.source != "/voxel_map" or snap.knows_unobserved
                or time.monotonic() >= deadline):
            return
        while time.monotonic() < deadline and not scene.snapshot().knows_unobserved:
            time.sleep(0.02)
        self.get_logger().info(f"plan_reach #{n}: waited for the unobserved layers of the map that just arrived: "
                               + ("received" if scene.snapshot().knows_unobserved else "none came"))

    # ------------------------------------------------------------ inputs
    def current_joints(self):
        """The latest valid joint angles, or None and the reason."""
        msg = self.joint_states.latest()
        return self.service.fresh_joints(None if msg is None else msgs.model_joints(msg, self.model),
                                         self.joint_states.age_s())

    def _marker_target(self):
        """``(to_world, age_s)`` of the newest /target_pose (``to_world(waist)``: its world pose), None if none."""
        msg = self.target_pose.latest()
        return (None if msg is None else lambda waist: msgs.target_in_world(msg, waist, "/target_pose"),
                self.target_pose.age_s())

    # ------------------------------------------------------------ service
    def _on_plan_reach(self, req: PlanReach.Request, resp: PlanReach.Response) -> PlanReach.Response:
        t0 = time.monotonic()
        if t0 - self._ready_at < START_SETTLE_S:     # the subscriptions are new: let them match first
            time.sleep(self._ready_at + START_SETTLE_S - t0)
        n, busy = self.service.begin()
        if busy is not None:
            self._fill_response(resp, busy, time.monotonic() - t0)
            return resp
        try:
            self._wait_for_unobserved_layers(n)
            reply = self.service.plan(n, lambda waist: msgs.reach_request(req, waist), self.current_joints,
                                      self._marker_target)
            total = time.monotonic() - t0
            try:
                self._fill_response(resp, reply, total)
            except Exception as exc:  # e.g. an outcome that does not convert
                reply = self.service.internal_error(n, "building the response", exc, region=reply.region)
                resp = PlanReach.Response()
                self._fill_response(resp, reply, total)
            published = bool(resp.success and reply.execute)
            if published:
                if self.trajectory_pub.get_subscription_count() == 0:
                    self.get_logger().warning(f"plan_reach #{n}: nobody subscribes to /reach_trajectory yet (is "
                                              "reach_executor running?); the trajectory is published anyway")
                self.trajectory_pub.publish(resp.trajectory)
            self.service.finish(n, reply, total, published)
            try:
                self._publish_markers(reply)
            except Exception as exc:  # visualisation must not fail a request
                self.get_logger().warning(f"plan_reach #{n}: planning markers not published: {exc}")
        finally:
            self.service.end()
        self._publish_diagnostics()
        return resp

    def _fill_response(self, resp: PlanReach.Response, reply: PlanReply, total_s: float) -> None:
        out, stamp = reply.outcome, self.get_clock().now().to_msg()
        resp.error_code = msgs.error_code(reply.code)
        resp.success = reply.success
        resp.message = reply.response_message
        resp.statistics = msgs.planning_statistics(self.service.statistics(reply, total_s))
        resp.arm = reply.arm_code
        if reply.waist_start is not None:
            resp.waist_start = msgs.pose_stamped(reply.waist_start, self.map_frame, stamp)
        if resp.success:
            resp.trajectory = msgs.joint_trajectory(out.joint_names, out.times, out.positions, out.velocities,
                                                    out.accelerations, self.map_frame, stamp)
        resp.retreat = reply.retreat
        pts = reply.unobserved_points
        resp.unobserved_points = msgs.points_list(pts) if pts is not None else []

    def _publish_markers(self, reply: PlanReply) -> None:
        """Target region, goal hand poses and the hand path of a reply on /planning/markers."""
        stamp, frame = self.get_clock().now().to_msg(), self.map_frame
        markers = msgs.region_markers(reply.region, "target_region", frame, stamp) if reply.region is not None else []
        markers += msgs.pose_arrow_markers(self.service.goal_hand_poses(reply), "goal_hand_poses", frame, stamp)
        path = self.service.hand_path(reply)
        if path is not None:
            markers.append(msgs.line_strip_marker(path, "hand_path", frame, stamp))
        self.markers_pub.publish(msgs.marker_array(markers, True, frame, stamp))

    # ------------------------------------------------------------ diagnostics
    def diagnostic_statuses(self) -> list:
        joints, reason = self.current_joints()
        return [msgs.diagnostic_status(f"{self.get_name()}: {suffix}", level, message, values, self.hardware_id)
                for suffix, level, message, values in self.service.diagnostics(
                    None if joints is not None else reason, self.joint_states.age_s(), self.target_pose.age_s())]

    def _publish_diagnostics(self) -> None:
        self.diagnostics_pub.publish(msgs.diagnostic_array(self.diagnostic_statuses(),
                                                           self.get_clock().now().to_msg()))

    # ------------------------------------------------------------ parameters
    @staticmethod
    def _check_parameters(params) -> SetParametersResult:
        reason = next((r for prm in params if (r := PlanningServiceConfig.refusal(prm.name, prm.value))), "")
        return SetParametersResult(successful=not reason, reason=reason)

    def _apply_parameters(self, params) -> None:
        for prm in params:
            self._p[prm.name] = prm.value
        self.service.reconfigure(PlanningServiceConfig.from_parameters(self._p))


def main(args: list[str] | None = None) -> int:
    """Run the node until Ctrl-C / SIGTERM (exit 0); a configuration error exits 2."""
    return run_node(ReachPlannerNode, NODE_NAME, args, executor=lambda: MultiThreadedExecutor(num_threads=4))


if __name__ == "__main__":
    sys.exit(main())
