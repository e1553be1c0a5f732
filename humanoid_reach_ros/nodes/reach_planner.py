"""``reach_planner``: the planning service of Kanehiro et al. (goal sampling + RRT-connect/PRM).

A thin node around ``humanoid_reach_ros.planning.reach.ReachPlanner``:

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

import dataclasses
import math
import sys
import threading
import time
import traceback
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin
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

from humanoid_reach_ros.codes import ARM_CODES, ARM_NAMES, ARM_NONE, ARMS
from humanoid_reach_ros.io import msgs
from humanoid_reach_ros.nodes.common import (LATCHED, RELIABLE_LATEST, LatestOnDemand, ParamSpec, current_joints,
                                             declare_parameters, run_node, scene_file_voxels)
from humanoid_reach_ros.paths import config_path
from humanoid_reach_ros.planning.reach import PlannerParams, PlanRequest, ReachPlanner
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.spec import DEFAULT_ROBOT
from humanoid_reach_ros.scene.planning_scene import UNOBSERVED_POLICIES, PlanningScene, SceneParams

NODE_NAME = "reach_planner"
E = PlanReach.Response
ERROR_NAMES: dict[int, str] = {getattr(E, n): n for n in dir(E)
                               if n.isupper() and not n.startswith("_") and isinstance(getattr(E, n), int)}

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
                         constraints=f"one of {', '.join(msgs.PLANNERS)}"),
    "time_budget_s": ParamSpec(_D.time_budget_s, "default wall-time budget of one request [s]", (0.01, 600.0)),
    "joint_velocity_rad_s": ParamSpec(_D.joint_velocity_rad_s, "joint speed used to time the trajectory [rad/s]",
                                      (0.01, 10.0)),
    "output_period_s": ParamSpec(_D.output_period_s, "sample period of the output trajectory [s]", (0.001, 1.0)),
    "edge_resolution": ParamSpec(_D.edge_resolution, "collision-check step along path edges [rad, planning space]",
                                 (1e-4, 1.0)),
    "rrt_step": ParamSpec(_D.rrt_step, "RRT-connect extension step [rad, planning space]", (1e-3, 10.0)),
    "seed": ParamSpec(_D.seed, "random seed used when a request's seed is negative"),
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
    "body_clearance_m": ParamSpec(0.25, "the robot's shapes grown by this, at the start of every request, count as "
                                  "observed free space in the planning scene [m]", (0.0, 1.0)),
    "joint_states_timeout_s": ParamSpec(0.5, "/joint_states older than this [s] -> NO_JOINT_STATES",
                                        (0.001, 3600.0), read_only=False),
    "target_timeout_s": ParamSpec(1.0, "/target_pose older than this [s] -> NO_TARGET for use_marker_target",
                                  (0.001, 3600.0), read_only=False),
    "diagnostics_period_s": ParamSpec(1.0, "period of /diagnostics [s]", (0.05, 60.0)),
    "marker_path_points": ParamSpec(100, "at most this many hand positions in the hand-path marker"),
    "warn_throttle_s": ParamSpec(1.0, "minimum interval between repeated warnings [s]", (0.0, 3600.0)),
}

PARAMETERS: dict[str, ParamSpec] = {**PLANNER_PARAMETERS, **NODE_PARAMETERS}
HAND_LIMBS = {"right": "right_arm", "left": "left_arm"}


def planner_params(values: dict[str, Any]) -> PlannerParams:
    """``PlannerParams`` from the declared parameters (fields ``PlannerParams`` lacks are left out)."""
    known = {f.name for f in dataclasses.fields(PlannerParams)}
    return PlannerParams(**{k: values[k] for k in PLANNER_PARAMETERS if k in known})


def scene_params(values: dict[str, Any]) -> SceneParams:
    """The planning scene's policies from the declared parameters."""
    return SceneParams(resolution_m=values["resolution_m"], safety_margin_m=values["safety_margin_m"],
                       target_exclusion_radius_m=values["target_exclusion_radius_m"],
                       unobserved_space=values["unobserved_space"], unobserved_block_m=values["unobserved_block_m"],
                       body_clearance_m=values["body_clearance_m"])


@dataclass
class MapInfo:
    source: str = "none"          # "scene file <path>" | "/voxel_map" | "none"
    voxels: int = 0
    build_time_s: float = 0.0
    received: int = 0             # /voxel_map messages accepted
    rejected: int = 0             # /voxel_map messages rejected (malformed)
    dropped_nonfinite: int = 0    # NaN points dropped from the last accepted map
    last_rejection: str = ""


@dataclass
class PlanReply:
    """What one request produced, for the response, the log line, markers and diagnostics."""

    code: int = E.INTERNAL_ERROR
    message: str = ""
    outcome: Any = None                       # PlanOutcome when the planner ran
    region: Any = None                        # WorkspaceGoalRegion (world) when valid
    joints: np.ndarray | None = None          # start posture
    waist: pin.SE3 | None = None
    execute: bool = False
    stats: dict[str, Any] = field(default_factory=dict)


class ReachPlannerNode(Node):
    """Thin node around ``ReachPlanner``: conversions, locking, logging and diagnostics only."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = declare_parameters(self, PARAMETERS)
        self._p = p
        if p["planner"] not in msgs.PLANNERS:
            raise ValueError(f"planner must be one of {msgs.PLANNERS}, got {p['planner']!r}")
        if p["unobserved_space"] not in UNOBSERVED_POLICIES:
            raise ValueError(f"unobserved_space must be one of {UNOBSERVED_POLICIES}, got {p['unobserved_space']!r}")
        if p["goal_count"] < 1 or p["marker_path_points"] < 2:
            raise ValueError("goal_count must be >= 1 and marker_path_points >= 2")
        self.map_frame: str = p["map_frame"]
        self.model = RobotModel(p["robot_config"])            # node-side FK (waist, markers)
        robot = RobotModel(p["robot_config"])
        self.scene = PlanningScene(robot, scene_params(p))      # the world model, fed by the subscriptions
        from humanoid_reach_ros.control.gaze import GazeSolver   # UNOBSERVABLE_SPACE: no reachable gaze sees it
        gaze = GazeSolver(RobotModel(p["robot_config"]))
        self.planner = ReachPlanner(robot, planner_params(p), scene=self.scene,
                                    observable=lambda joints, points: gaze.observable(joints, points))
        t0 = time.perf_counter()
        warm = self.planner.warm_up()  # compiled kernels before the first request (cache: tools/setup.sh)
        self.get_logger().info(f"planning kernels warmed up in {1e3 * (time.perf_counter() - t0):.0f} ms; goal "
                               f"search: {self.planner.trunk_region.describe()}")
        if not warm:
            self.get_logger().warn("the warm-up plan (free space) did not succeed: the first request may pay "
                                   "for compiling the path checker")
        self.hardware_id = self.model.name

        self._plan_lock = threading.Lock()   # one request at a time; a second one gets BUSY
        self.map_info = MapInfo()
        self.requests = self.successes = self.busy_rejections = 0
        self.last: PlanReply | None = None
        self.last_total_s = 0.0

        if p["scene_file"]:
            path = config_path(p["scene_file"])
            voxels = scene_file_voxels(str(path), p["resolution_m"], tuple(p["scene_exclude_groups"]))
            self.scene.set_occupied(voxels, source=f"scene file {path}")
            build_s = self.scene.snapshot().tree()[1]
            self.map_info = MapInfo(f"scene file {path}", int(len(voxels)), float(build_s))
            self.get_logger().info(
                f"map source: scene file {path} ({self.map_info.voxels} voxels without groups "
                f"{list(p['scene_exclude_groups'])}, built in {build_s * 1e3:.1f} ms); a /voxel_map replaces it")
        else:
            self.get_logger().info("map source: none yet (scene_file is empty): waiting for /voxel_map; "
                                   "requests get NO_MAP until it arrives")

        self._state_group = MutuallyExclusiveCallbackGroup()
        self._map_group = MutuallyExclusiveCallbackGroup()
        self._service_group = ReentrantCallbackGroup()
        self.trajectory_pub = self.create_publisher(JointTrajectory, "reach_trajectory", RELIABLE_LATEST)
        self.markers_pub = self.create_publisher(MarkerArray, "planning/markers", LATCHED)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_subscription(PointCloud2, "voxel_map", self._on_map, LATCHED, callback_group=self._map_group)
        for topic, attr in (("voxel_map/unobserved", "_frontier"), ("voxel_map/unobserved_blocks", "_blocks")):
            self.create_subscription(PointCloud2, topic, lambda m, t=topic, a=attr: self._on_unobserved(t, a, m),
                                     LATCHED, callback_group=self._map_group)
        # the start posture and the marker target: the latest messages, taken when a request needs them
        # (no callback per 200 Hz joint state or 10 Hz target; their ages come from the reception times)
        self.joint_states = LatestOnDemand(self, JointState, "joint_states", qos_profile_sensor_data)
        self.target_pose = LatestOnDemand(self, PoseStamped, "target_pose")
        self.create_service(PlanReach, "plan_reach", self._on_plan_reach, callback_group=self._service_group)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(p["diagnostics_period_s"], self._publish_diagnostics, clock=steady,
                          callback_group=self._state_group)
        self.add_on_set_parameters_callback(self._check_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        pp = self.planner_defaults_text()
        self.get_logger().info(
            f"reach planner ready: service plan_reach ({pp}); start posture from joint_states "
            f"(stale after {p['joint_states_timeout_s']:g} s), marker target from target_pose "
            f"(stale after {p['target_timeout_s']:g} s), map frame {self.map_frame!r}")

    def planner_defaults_text(self) -> str:
        p = self._p
        return (f"defaults: {p['planner']}, {p['goal_count']} goals, budget {p['time_budget_s']:g} s, "
                f"seed {p['seed']}")

    # ------------------------------------------------------------ subscriptions
    def _on_map(self, msg: PointCloud2) -> None:
        log = self.get_logger()
        try:
            cloud = msgs.points_from_cloud(msg)
            if cloud.frame_id not in ("", self.map_frame):
                raise ValueError(f"frame_id {cloud.frame_id!r} is not the map frame {self.map_frame!r}")
            self.scene.set_occupied(cloud.points, source="/voxel_map")
            build_s = 0.0   # the sphere trees are built per request (the target's object left out), then cached
        except Exception as exc:  # malformed cloud or a map the planner refuses: keep the old one
            self.map_info.rejected += 1
            self.map_info.last_rejection = f"{type(exc).__name__}: {exc}"
            log.warning(f"rejected /voxel_map ({self.map_info.rejected} so far): {self.map_info.last_rejection}; "
                        f"keeping the previous map ({self.map_info.source}, {self.map_info.voxels} voxels)")
            self._publish_diagnostics()
            return
        info = self.map_info
        self.map_info = MapInfo("/voxel_map", int(len(cloud.points)), build_s, info.received + 1, info.rejected,
                                cloud.dropped_nonfinite, info.last_rejection)
        dropped = f", {cloud.dropped_nonfinite} NaN/inf points dropped" if cloud.dropped_nonfinite else ""
        line = (f"map source: /voxel_map ({self.map_info.voxels} voxels{dropped}, planning scene version "
                f"{self.scene.version}; replaces {info.source})")
        if info.source != "/voxel_map":   # state changes at INFO, repetition at DEBUG
            log.info(line)
        else:
            log.debug(line)
        if cloud.dropped_nonfinite:
            log.warning(f"/voxel_map had {cloud.dropped_nonfinite} points with NaN/inf coordinates (dropped)")
        self._publish_diagnostics()

    def _on_unobserved(self, topic: str, attr: str, msg: PointCloud2) -> None:
        """/voxel_map/unobserved (the frontier) or /voxel_map/unobserved_blocks into the planning
        scene, for the next request."""
        topic = self.resolve_topic_name(topic)
        try:
            cloud = msgs.points_from_cloud(msg)
            if cloud.frame_id not in ("", self.map_frame):
                raise ValueError(f"frame_id {cloud.frame_id!r} is not the map frame {self.map_frame!r}")
        except ValueError as exc:
            self.map_info.rejected += 1
            self.map_info.last_rejection = f"{topic}: {exc}"
            self.get_logger().warning(f"rejected {topic}: {exc}; keeping the previous one",
                                      throttle_duration_sec=self._p["warn_throttle_s"])
            return
        if attr == "_frontier":
            self.scene.set_unobserved(frontier=cloud.points)
        else:
            self.scene.set_unobserved(blocks=cloud.points)

    # ------------------------------------------------------------ inputs
    def current_joints(self) -> tuple[np.ndarray | None, str]:
        """The latest valid joint angles, or None and the reason."""
        return current_joints(self.joint_states, self._p["joint_states_timeout_s"], self.model)

    def current_target(self) -> tuple[PoseStamped | None, str]:
        msg, age = self.target_pose.latest(), self.target_pose.age_s()
        if msg is None:
            return None, "use_marker_target but no /target_pose received"
        if age > self._p["target_timeout_s"]:
            return None, (f"use_marker_target but /target_pose is stale "
                          f"({age:.2f} s > {self._p['target_timeout_s']:g} s)")
        return msg, ""

    # ------------------------------------------------------------ service
    def _on_plan_reach(self, req: PlanReach.Request, resp: PlanReach.Response) -> PlanReach.Response:
        t0 = time.monotonic()
        self.requests += 1
        n = self.requests
        if not self._plan_lock.acquire(blocking=False):
            self.busy_rejections += 1
            result = PlanReply(E.BUSY, "another /plan_reach request is being planned; try again when it is done")
            self._fill_response(resp, result, time.monotonic() - t0)
            self.get_logger().warning(f"plan_reach #{n}: BUSY ({result.message})")
            return resp
        try:
            try:
                result = self._plan(req)
            except Exception as exc:  # the node never dies on a request
                result = PlanReply(E.INTERNAL_ERROR, f"internal error while planning: {type(exc).__name__}: {exc}")
                self.get_logger().error(f"plan_reach #{n}: {result.message}\n{traceback.format_exc()}")
            total = time.monotonic() - t0
            try:
                self._fill_response(resp, result, total)
            except Exception as exc:  # e.g. an outcome that does not convert
                result = PlanReply(E.INTERNAL_ERROR, f"internal error building the response: "
                                                     f"{type(exc).__name__}: {exc}", region=result.region)
                self.get_logger().error(f"plan_reach #{n}: {result.message}\n{traceback.format_exc()}")
                resp = PlanReach.Response()
                self._fill_response(resp, result, total)
            published = False
            if resp.success and result.execute:
                if self.trajectory_pub.get_subscription_count() == 0:
                    self.get_logger().warning(f"plan_reach #{n}: nobody subscribes to /reach_trajectory yet (is "
                                              "reach_executor running?); the trajectory is published anyway")
                self.trajectory_pub.publish(resp.trajectory)
                published = True
            self.successes += int(resp.success)
            self.last, self.last_total_s = result, total
            self._log_request(n, resp, total, published, ran=result.outcome is not None)
            tried = getattr(result.outcome, "retreats_tried", ()) if not resp.success else ()
            if tried:   # the response keeps six; the log has them all (a refused retreat is found from here)
                self.get_logger().info(f"plan_reach #{n}: the {len(tried)} retreats tried: "
                                       + "; ".join(f"{k + 1}) {why}" for k, why in enumerate(tried)))
            try:
                self._publish_markers(result)
            except Exception as exc:  # visualisation must not fail a request
                self.get_logger().warning(f"plan_reach #{n}: planning markers not published: {exc}")
        finally:
            self._plan_lock.release()
        self._publish_diagnostics()
        return resp

    def _plan(self, req: PlanReach.Request) -> PlanReply:
        """Validate, convert, plan. Errors of the request are results, not exceptions."""
        joints, joints_reason = self.current_joints()
        waist = self.model.base_on_feet(joints) if joints is not None else None
        try:
            rr = msgs.reach_request(req, waist)
        except msgs.RequestError as exc:
            return PlanReply(exc.code, str(exc), joints=joints, waist=waist)
        result = PlanReply(region=rr.region, joints=joints, waist=waist, execute=rr.execute)
        # Inputs in the order an operator fixes them: the target they asked for, then the robot state.
        target = None
        if rr.use_marker_target and not rr.home:
            target, reason = self.current_target()
            if target is None:
                result.code, result.message = E.NO_TARGET, reason
                return result
        if joints is None:
            result.code, result.message = E.NO_JOINT_STATES, joints_reason
            return result
        if target is not None:
            try:
                result.region = msgs.region_with_target(rr.region, msgs.target_in_world(target, waist, "/target_pose"))
            except msgs.RequestError as exc:
                result.code, result.message = exc.code, str(exc)
                return result
        if not self.planner.has_map:
            result.code = E.NO_MAP
            result.message = "no environment map: no /voxel_map received and no scene_file"
            return result
        plan_request = PlanRequest(region=result.region, arm=rr.arm, goal_count=rr.goal_count, planner=rr.planner,
                                   time_budget_s=rr.time_budget_s, seed=rr.seed, home=rr.home)
        outcome = self.planner.plan(joints, plan_request)
        result.outcome = outcome
        result.code, result.message = int(outcome.error), str(outcome.message)
        result.stats = dict(outcome.stats or {})
        return result

    def _fill_response(self, resp: PlanReach.Response, result: PlanReply, total_s: float) -> None:
        out = result.outcome
        resp.error_code = int(result.code)
        resp.success = resp.error_code == E.SUCCESS
        resp.message = result.message or ERROR_NAMES.get(resp.error_code, "unknown error")
        stamp = self.get_clock().now().to_msg()
        stats = dict(result.stats)
        stats.setdefault("map_voxels", self.map_info.voxels)
        stats.setdefault("sphere_tree_build_time_s", self.map_info.build_time_s)
        stats["total_time_s"] = total_s
        resp.statistics = msgs.planning_statistics(stats)
        resp.arm = ARM_CODES.get(getattr(out, "arm", None) or "", ARM_NONE)
        waist = getattr(out, "waist_start", None) or result.waist
        if waist is not None:
            resp.waist_start = msgs.pose_stamped(waist, self.map_frame, stamp)
        if resp.success:
            resp.trajectory = msgs.joint_trajectory(out.joint_names, out.times, out.positions, out.velocities,
                                                    out.accelerations, self.map_frame, stamp)
        resp.retreat = str(getattr(out, "retreat", "") or "")
        pts = getattr(out, "unobserved_points", None)
        resp.unobserved_points = msgs.points_list(pts) if pts is not None else []

    def _log_request(self, n: int, resp: PlanReach.Response, total_s: float, published: bool, ran: bool) -> None:
        """One INFO line per request (ERROR for INTERNAL_ERROR): outcome, times, sizes, message."""
        s = resp.statistics
        name = ERROR_NAMES.get(resp.error_code, str(resp.error_code))
        head = f"plan_reach #{n}: {name} ({resp.error_code}) in {total_s * 1e3:.0f} ms"
        if ran:
            head += (f" [goal sampling {s.goal_sampling_time_s * 1e3:.0f} ms, {s.goals_found}/{s.goals_requested} "
                     f"goals; path {s.path_planning_time_s * 1e3:.0f} ms, {s.path_waypoints} waypoints; "
                     f"{s.collision_checks} collision checks]")
        if resp.success:
            pts = resp.trajectory.points
            dur = msgs.seconds_from_duration(pts[-1].time_from_start) if pts else 0.0
            arm = ARM_NAMES.get(resp.arm, "?")
            tail = (f"; {arm} arm, {len(pts)} points over {dur:.2f} s"
                    f"{', published on reach_trajectory' if published else ''}")
            self.get_logger().info(head + tail + f": {resp.message}")
        elif resp.error_code == E.INTERNAL_ERROR:
            self.get_logger().error(head + f": {resp.message}")
        else:
            self.get_logger().info(head + f": {resp.message}")

    # ------------------------------------------------------------ markers
    def hand_positions(self, joints: np.ndarray, limb: str) -> np.ndarray:
        """World positions (K, 3) of a hand for joint vectors (K, 30) standing on the feet."""
        tip = self.model.limbs[limb].tip
        out = np.empty((len(joints), 3))
        for i, j in enumerate(joints):
            q = self.model.config(j, self.model.base_on_feet(j))
            out[i] = self.model.frame_pose(q, tip).translation
        return out

    def _full_configs(self, rows: np.ndarray | None) -> np.ndarray | None:
        """Full configurations (K, nq) of rows given as (K, nq) q or (K, 30) joints standing on
        the feet; None for anything else."""
        if rows is None:
            return None
        a = np.asarray(rows, dtype=float)
        if a.ndim != 2:
            return None
        if a.shape[1] == self.model.model.nq:
            return a
        if a.shape[1] == self.model.n_joints:
            return np.array([self.model.config(j, self.model.base_on_feet(j)) for j in a])
        return None

    def _publish_markers(self, result: PlanReply) -> None:
        stamp = self.get_clock().now().to_msg()
        frame = self.map_frame
        markers = []
        if result.region is not None:
            markers += msgs.region_markers(result.region, "target_region", frame, stamp)
        out = result.outcome
        if out is not None:
            goals = self._full_configs(getattr(out, "goals", None))
            arms = getattr(out, "goal_arms", None)
            if goals is not None and len(goals):
                tips = [self.model.limbs[limb].tip for limb in HAND_LIMBS.values()]  # right, left
                poses = []
                for i, q in enumerate(goals):
                    if arms is not None and len(arms) == len(goals) and int(arms[i]) in ARM_NAMES:
                        poses.append(self.model.frame_pose(q, tips[ARMS.index(ARM_NAMES[int(arms[i])])]))
                    elif result.region is not None:  # the hand that reaches: the one nearest the target
                        hands = [self.model.frame_pose(q, tip) for tip in tips]
                        target = np.asarray(result.region.target_p)
                        poses.append(min(hands, key=lambda h: np.linalg.norm(h.translation - target)))
                markers += msgs.pose_arrow_markers(poses, "goal_hand_poses", frame, stamp)
            if out.success and out.positions is not None and out.arm in HAND_LIMBS:
                k = len(out.positions)
                idx = np.unique(np.linspace(0, k - 1, min(k, self._p["marker_path_points"])).round().astype(int))
                path = self.hand_positions(np.asarray(out.positions)[idx], HAND_LIMBS[out.arm])
                markers.append(msgs.line_strip_marker(path, "hand_path", frame, stamp))
        self.markers_pub.publish(msgs.marker_array(markers, True, frame, stamp))

    # ------------------------------------------------------------ diagnostics
    def diagnostic_statuses(self) -> list:
        name, m = self.get_name(), self.map_info
        statuses = []
        values = {"source": m.source, "voxels": m.voxels, "build_time_ms": m.build_time_s * 1e3,
                  "maps_received": m.received, "maps_rejected": m.rejected,
                  "dropped_nonfinite_points": m.dropped_nonfinite, "last_rejection": m.last_rejection,
                  "frame_id": self.map_frame,
                  **{f"scene_{k}": v for k, v in self.scene.describe().items()}}   # the planning scene's layers
        if self.planner.has_map:
            level, message = msgs.LEVEL_OK, f"{m.voxels} voxels from {m.source}"
        else:
            level, message = msgs.LEVEL_WARN, "no map yet: waiting for /voxel_map"
        if m.last_rejection and m.rejected:
            message += f"; {m.rejected} /voxel_map rejected, last: {m.last_rejection}"
        statuses.append(msgs.diagnostic_status(f"{name}: map", level, message, values, self.hardware_id))

        last = self.last
        values = {"requests": self.requests, "successes": self.successes, "busy_rejections": self.busy_rejections,
                  "planning": self._plan_lock.locked()}
        if last is None:
            level, message = msgs.LEVEL_OK, "no request yet"
        else:
            code_name = ERROR_NAMES.get(last.code, str(last.code))
            st = last.stats
            values.update({"last_result": code_name, "last_error_code": last.code, "last_message": last.message,
                           "last_total_time_s": self.last_total_s,
                           "last_goal_sampling_time_s": float(st.get("goal_sampling_time_s", 0.0) or 0.0),
                           "last_path_planning_time_s": float(st.get("path_planning_time_s", 0.0) or 0.0)})
            level = msgs.LEVEL_ERROR if last.code == E.INTERNAL_ERROR else msgs.LEVEL_OK
            message = f"last request: {code_name} in {self.last_total_s * 1e3:.0f} ms"
        statuses.append(msgs.diagnostic_status(f"{name}: planning", level, message, values, self.hardware_id))

        joints, reason = self.current_joints()
        js_age, target_age = self.joint_states.age_s(), self.target_pose.age_s()
        values = {"joint_states_age_s": js_age if math.isfinite(js_age) else "never",
                  "target_pose_age_s": target_age if math.isfinite(target_age) else "never"}
        level, message = (msgs.LEVEL_OK, "joint_states current") if joints is not None else (msgs.LEVEL_WARN, reason)
        statuses.append(msgs.diagnostic_status(f"{name}: inputs", level, message, values, self.hardware_id))
        return statuses

    def _publish_diagnostics(self) -> None:
        self.diagnostics_pub.publish(msgs.diagnostic_array(self.diagnostic_statuses(),
                                                           self.get_clock().now().to_msg()))

    # ------------------------------------------------------------ parameters
    @staticmethod
    def _check_parameters(params) -> SetParametersResult:
        for prm in params:
            if prm.name == "unobserved_space" and prm.value not in UNOBSERVED_POLICIES:
                return SetParametersResult(successful=False, reason=f"unobserved_space must be one of "
                                                                    f"{UNOBSERVED_POLICIES}, got {prm.value!r}")
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params) -> None:
        for prm in params:
            self._p[prm.name] = prm.value
        self.scene.set_params(scene_params(self._p))   # the scene's policies follow (a new version)


def main(args: list[str] | None = None) -> int:
    """Run the node until Ctrl-C / SIGTERM (exit 0); a configuration error exits 2."""
    return run_node(ReachPlannerNode, NODE_NAME, args, executor=lambda: MultiThreadedExecutor(num_threads=4))


if __name__ == "__main__":
    sys.exit(main())
