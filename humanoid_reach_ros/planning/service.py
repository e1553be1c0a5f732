"""The planning service: what ``nodes/reach_planner.py`` does, without ROS.

The node adapts messages, parameters and timers; everything it decides is here, so that it can
be tested without a ROS graph (test/test_planning_service.py):

* :class:`PlanningServiceConfig`: the node's parameters, typed and checked (a bad value is a
  ``ValueError`` with the message the node has always given);
* the world model's bookkeeping: the scene file's voxels as the map until a measured map
  arrives, each measured map and unobserved layer accepted (its frame checked) or rejected
  and counted (:class:`MapInfo`);
* one request, from validated inputs to a :class:`PlanReply`: the start joints and the marker
  target checked for freshness, in the order an operator fixes them (the target they asked for,
  then the robot state), the map, then ``ReachPlanner.plan``; an exception is
  ``INTERNAL_ERROR``, never a dead service; one request at a time (``BUSY``);
* the statistics of the answer, the log lines, the hand poses and path the markers show, the
  diagnostics' content and the counters behind them.

Messages never reach this module: the node hands in converted values and callables that
convert on demand (a request needs the current waist to place a ``base_link`` target).
Log lines go to a ``log(level, text, throttled=False)`` callable (levels of a ROS logger:
``debug``, ``info``, ``warning``, ``error``).
"""
from __future__ import annotations

import dataclasses
import math
import threading
import time
import traceback
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np
import pinocchio as pin

from humanoid_reach_ros.counters import Counters
from humanoid_reach_ros.codes import ARM_CODES, ARM_NAMES, ARM_NONE, ARMS, PlanError, RequestError, code_name
from humanoid_reach_ros.control.gaze import GazeSolver
from humanoid_reach_ros.paths import config_path
from humanoid_reach_ros.planning.reach import PlannerParams, PlanRequest, ReachPlanner
from humanoid_reach_ros.planning.space import PLANNER_NAMES
from humanoid_reach_ros.planning.wgr import WorkspaceGoalRegion
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.spec import DEFAULT_ROBOT
from humanoid_reach_ros.scene.planning_scene import UNOBSERVED_POLICIES, PlanningScene, SceneParams
from humanoid_reach_ros.sim.scene import load_scene

HAND_LIMBS = {"right": "right_arm", "left": "left_arm"}
OK, WARN, ERROR = 0, 1, 2          # diagnostic_msgs/DiagnosticStatus levels
Log = Callable[..., None]          # log(level, text, throttled=False)
#: statistics whose message fields are integers (rounded as ``io.msgs.planning_statistics`` does)
_COUNTS = ("goals_found", "goals_requested", "path_waypoints", "collision_checks")


def _no_log(level: str, text: str, throttled: bool = False) -> None:
    pass


@dataclass
class ServiceCounters(Counters):
    """The planner's requests (its ``/diagnostics``)."""

    requests: int = 0
    successes: int = 0
    busy_rejections: int = 0


@dataclass(frozen=True)
class PlanningServiceConfig:
    """The reach_planner node's parameters, typed; :meth:`from_parameters` checks them."""

    planner: PlannerParams = field(default_factory=PlannerParams)
    scene: SceneParams = field(default_factory=SceneParams)
    robot_config: str = DEFAULT_ROBOT            # a name or the path of a robot description
    scene_file: str = ""                         # "" = no map until a measured one arrives
    scene_exclude_groups: tuple[str, ...] = ()
    map_frame: str = "world"
    joint_states_timeout_s: float = 0.5
    target_timeout_s: float = 1.0
    marker_path_points: int = 100

    @classmethod
    def from_parameters(cls, values: Mapping[str, Any]) -> PlanningServiceConfig:
        """From the node's parameter values (names as declared); ValueError on a bad value."""
        if values["planner"] not in PLANNER_NAMES:
            raise ValueError(f"planner must be one of {PLANNER_NAMES}, got {values['planner']!r}")
        reason = cls.refusal("unobserved_space", values["unobserved_space"])
        if reason:
            raise ValueError(reason)
        if values["goal_count"] < 1 or values["marker_path_points"] < 2:
            raise ValueError("goal_count must be >= 1 and marker_path_points >= 2")
        known = {f.name for f in dataclasses.fields(PlannerParams)}
        scene = SceneParams(**{f.name: values[f.name] for f in dataclasses.fields(SceneParams) if f.name in values})
        return cls(PlannerParams(**{k: v for k, v in values.items() if k in known}), scene,
                   str(values["robot_config"]), str(values["scene_file"]), tuple(values["scene_exclude_groups"]),
                   str(values["map_frame"]), float(values["joint_states_timeout_s"]),
                   float(values["target_timeout_s"]), int(values["marker_path_points"]))

    @staticmethod
    def refusal(name: str, value: Any) -> str:
        """Why a parameter changed at run time cannot take ``value`` ("" = it can)."""
        if name == "unobserved_space" and value not in UNOBSERVED_POLICIES:
            return f"unobserved_space must be one of {UNOBSERVED_POLICIES}, got {value!r}"
        return ""

    def defaults_text(self) -> str:
        p = self.planner
        return f"defaults: {p.planner}, {p.goal_count} goals, budget {p.time_budget_s:g} s, seed {p.seed}"


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

    code: int = PlanError.INTERNAL_ERROR
    message: str = ""
    outcome: Any = None                       # PlanOutcome when the planner ran
    region: Any = None                        # WorkspaceGoalRegion (world) when valid
    joints: np.ndarray | None = None          # start posture
    waist: pin.SE3 | None = None
    execute: bool = False
    stats: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.code = int(self.code)

    def answer(self, code: int, message: str) -> PlanReply:
        """This reply with its code and message (the request ends here)."""
        self.code, self.message = int(code), message
        return self

    @property
    def success(self) -> bool:
        return int(self.code) == PlanError.SUCCESS

    @property
    def response_message(self) -> str:
        return self.message or code_name(self.code)

    @property
    def arm_code(self) -> int:
        return ARM_CODES.get(getattr(self.outcome, "arm", None) or "", ARM_NONE)

    @property
    def waist_start(self) -> pin.SE3 | None:
        return getattr(self.outcome, "waist_start", None) or self.waist

    @property
    def retreat(self) -> str:
        return str(getattr(self.outcome, "retreat", "") or "")

    @property
    def unobserved_points(self) -> np.ndarray | None:
        return getattr(self.outcome, "unobserved_points", None)


class PlanningService:
    """The reach planner's world model, requests, counters and diagnostics (see the module)."""

    def __init__(self, config: PlanningServiceConfig, log: Log = _no_log) -> None:
        self.config, self.log = config, log
        self.model = RobotModel(config.robot_config)           # FK of the waist and the markers
        robot = RobotModel(config.robot_config)
        self.scene = PlanningScene(robot, config.scene)        # the world model, fed by the subscriptions
        gaze = GazeSolver(RobotModel(config.robot_config))      # UNOBSERVABLE_SPACE: no reachable gaze sees it
        self.planner = ReachPlanner(robot, config.planner, scene=self.scene,
                                    observable=lambda joints, points: gaze.observable(joints, points))
        self.plan_lock = threading.Lock()   # one request at a time; a second one gets BUSY
        self.map_info = MapInfo()
        self.counters = ServiceCounters()
        self.last: PlanReply | None = None
        self.last_total_s = 0.0

    def reconfigure(self, config: PlanningServiceConfig) -> None:
        """Parameters changed at run time: timeouts at the next request, the scene's policies now."""
        self.config = config
        self.scene.set_params(config.scene)   # a new scene version

    def warm_up(self) -> bool:
        """Compiled kernels before the first request (cache: tools/setup.sh): the planner's
        free-space plan, then :meth:`warm_up_measured`."""
        t0 = time.perf_counter()
        warm = self.planner.warm_up() and self.warm_up_measured()
        reach = self.planner.reach.describe() if self.planner.reach is not None else "no reach map"
        self.log("info", f"planning kernels warmed up in {1e3 * (time.perf_counter() - t0):.0f} ms; goal "
                         f"search: {self.planner.trunk_region.describe()}; {reach}")
        if not warm:
            self.log("warning", "the warm-up plan (free space) did not succeed: the first request may pay "
                                "for compiling the path checker")
        return warm

    def warm_up_measured(self, budget_s: float = 60.0) -> bool:
        """A free-space plan from half-sitting in a scene of its own that holds what the mapper
        sends (a measured map and both unobserved layers, all far from the robot; the start's body
        marked as swept), so that the kernels of a request on a measured map (the swept body taken
        out of the unobserved blocks and frontier, the trees with the frontier) are compiled
        (``tools/setup.sh``) or loaded (a node's start) before the first request. Why: the
        planner's own warm-up plans on a scene without unobserved layers, and a fresh clone's
        first ``make demo`` compiled them inside the operator's wait (1,247 ms against 158 ms
        for the second run, issue 33; 4.3 s of numba compilation profiled on a loaded machine).
        True when the plan succeeded; the service's scene and the planner's memory of its last
        plan are left as they were."""
        from humanoid_reach_ros.planning.wgr import valve_region
        p = self.planner
        saved = p.scene, p._last_plan_end, p._last_positions
        try:
            far = np.array([[5.0, 5.0, 5.0]])
            p.scene = PlanningScene(p.robot, dataclasses.replace(self.config.scene, unobserved_space="occupied"),
                                    p.collision_model)
            p.scene.set_occupied(far, source="/voxel_map")
            p.scene.set_unobserved(frontier=far - [0.0, 10.0, 0.0], blocks=far - [0.0, 10.0, 0.0])
            out = p.plan(p.robot.half_sitting_joints, PlanRequest(valve_region(), goal_count=1,
                                                                  time_budget_s=float(budget_s)))
            return bool(out.success)
        finally:
            p.scene, p._last_plan_end, p._last_positions = saved

    def ready_line(self) -> str:
        c = self.config
        return (f"reach planner ready: service plan_reach ({c.defaults_text()}); start posture from joint_states "
                f"(stale after {c.joint_states_timeout_s:g} s), marker target from target_pose "
                f"(stale after {c.target_timeout_s:g} s), map frame {c.map_frame!r}")

    # ------------------------------------------------------------ the map
    def load_scene_file(self) -> None:
        """The scene file's voxels (its excluded groups left out) as the map until a measured one arrives."""
        c = self.config
        if not c.scene_file:
            self.log("info", "map source: none yet (scene_file is empty): waiting for /voxel_map; "
                             "requests get NO_MAP until it arrives")
            return
        path = config_path(c.scene_file)
        voxels = load_scene(str(path)).voxelize(c.scene.resolution_m, exclude_groups=c.scene_exclude_groups)
        self.scene.set_occupied(voxels, source=f"scene file {path}")
        build_s = self.scene.snapshot().tree()[1]
        self.map_info = MapInfo(f"scene file {path}", int(len(voxels)), float(build_s))
        self.log("info", f"map source: scene file {path} ({self.map_info.voxels} voxels without groups "
                         f"{list(c.scene_exclude_groups)}, built in {build_s * 1e3:.1f} ms); a /voxel_map replaces it")

    def _check_frame(self, frame_id: str) -> None:
        if frame_id not in ("", self.config.map_frame):
            raise ValueError(f"frame_id {frame_id!r} is not the map frame {self.config.map_frame!r}")

    def set_map(self, cloud: Any) -> None:
        """A measured map (``cloud``: ``points`` (N, 3), ``frame_id``, ``dropped_nonfinite``) replaces the map;
        ValueError (and what the scene refuses) leaves the map as it was: :meth:`map_rejected`."""
        self._check_frame(cloud.frame_id)
        self.scene.set_occupied(cloud.points, source="/voxel_map")
        info = self.map_info
        # build time 0: the sphere trees are built per request (the target's object left out), then cached
        self.map_info = MapInfo("/voxel_map", int(len(cloud.points)), 0.0, info.received + 1, info.rejected,
                                cloud.dropped_nonfinite, info.last_rejection)
        dropped = f", {cloud.dropped_nonfinite} NaN/inf points dropped" if cloud.dropped_nonfinite else ""
        line = (f"map source: /voxel_map ({self.map_info.voxels} voxels{dropped}, planning scene version "
                f"{self.scene.version}; replaces {info.source})")
        self.log("info" if info.source != "/voxel_map" else "debug", line)   # state changes at INFO
        if cloud.dropped_nonfinite:
            self.log("warning", f"/voxel_map had {cloud.dropped_nonfinite} points with NaN/inf coordinates (dropped)")

    def map_rejected(self, exc: Exception) -> None:
        """A malformed measured map, or one the scene refuses: counted, the previous map kept."""
        m = self.map_info
        m.rejected += 1
        m.last_rejection = f"{type(exc).__name__}: {exc}"
        self.log("warning", f"rejected /voxel_map ({m.rejected} so far): {m.last_rejection}; "
                            f"keeping the previous map ({m.source}, {m.voxels} voxels)")

    def set_unobserved(self, topic: str, layer: str, read_cloud: Callable[[], Any]) -> None:
        """An unobserved layer (``layer``: 'frontier' or 'blocks'; ``read_cloud()`` converts the message,
        ValueError when malformed) into the planning scene, for the next request; a bad one is counted
        and the previous one kept."""
        try:
            cloud = read_cloud()
            self._check_frame(cloud.frame_id)
        except ValueError as exc:
            self.map_info.rejected += 1
            self.map_info.last_rejection = f"{topic}: {exc}"
            self.log("warning", f"rejected {topic}: {exc}; keeping the previous one", throttled=True)
            return
        self.scene.set_unobserved(**{layer: cloud.points})

    # ------------------------------------------------------------ inputs
    def fresh_joints(self, converted: tuple[np.ndarray | None, str] | None,
                     age_s: float) -> tuple[np.ndarray | None, str]:
        """The start joints of the newest joint state (``converted``: its joint angles or None and why;
        None: none received) if not older than ``joint_states_timeout_s``, else None and the reason."""
        if converted is None:
            return None, "no /joint_states received"
        timeout = self.config.joint_states_timeout_s
        if age_s > timeout:
            return None, f"/joint_states is stale ({age_s:.2f} s > {timeout:g} s)"
        return converted

    def target_staleness(self, received: bool, age_s: float) -> str:
        """Why the marker target cannot be used ("" = it can)."""
        if not received:
            return "use_marker_target but no /target_pose received"
        timeout = self.config.target_timeout_s
        if age_s > timeout:
            return f"use_marker_target but /target_pose is stale ({age_s:.2f} s > {timeout:g} s)"
        return ""

    def waist(self, joints: np.ndarray | None) -> pin.SE3 | None:
        return self.model.base_on_feet(joints) if joints is not None else None

    # ------------------------------------------------------------ requests
    def begin(self) -> tuple[int, PlanReply | None]:
        """A request arrives: its number, and a BUSY reply when another one is planning (else
        the plan lock is held until :meth:`end`)."""
        n = self.counters.count("requests")
        if self.plan_lock.acquire(blocking=False):
            return n, None
        self.counters.count("busy_rejections")
        reply = PlanReply(PlanError.BUSY, "another /plan_reach request is being planned; try again when it is done")
        self.log("warning", f"plan_reach #{n}: BUSY ({reply.message})")
        return n, reply

    def end(self) -> None:
        self.plan_lock.release()

    def plan(self, n: int, read_request: Callable, read_joints: Callable, read_marker: Callable) -> PlanReply:
        """Request ``n``: validate, check the inputs, plan. ``read_request(waist)``: the validated request
        (``io.msgs.ReachRequest``; RequestError with its code); ``read_joints()``: start joints or None and why;
        ``read_marker()``: ``(to_world, age_s)``, ``to_world(waist)`` the marker target in world
        (RequestError), None when none came. Errors are replies; an exception is INTERNAL_ERROR."""
        try:
            return self._plan(read_request, read_joints, read_marker)
        except Exception as exc:  # the service never dies on a request
            return self.internal_error(n, "while planning", exc)

    def internal_error(self, n: int, what: str, exc: Exception, region: Any = None) -> PlanReply:
        reply = PlanReply(PlanError.INTERNAL_ERROR, f"internal error {what}: {type(exc).__name__}: {exc}",
                          region=region)
        self.log("error", f"plan_reach #{n}: {reply.message}\n{traceback.format_exc()}")
        return reply

    def _plan(self, read_request: Callable, read_joints: Callable, read_marker: Callable) -> PlanReply:
        joints, joints_reason = read_joints()
        waist = self.waist(joints)
        try:
            rr = read_request(waist)
        except RequestError as exc:
            return PlanReply(exc.code, str(exc), joints=joints, waist=waist)
        reply = PlanReply(region=rr.region, joints=joints, waist=waist, execute=rr.execute)
        # Inputs in the order an operator fixes them: the target they asked for, then the robot state.
        to_world = None
        if rr.use_marker_target and not rr.home:
            to_world, age_s = read_marker()
            reason = self.target_staleness(to_world is not None, age_s)
            if reason:
                return reply.answer(PlanError.NO_TARGET, reason)
        if joints is None:
            return reply.answer(PlanError.NO_JOINT_STATES, joints_reason)
        if to_world is not None:
            try:
                reply.region = WorkspaceGoalRegion.from_pose(to_world(waist), rr.region.lower, rr.region.upper)
            except RequestError as exc:
                return reply.answer(exc.code, str(exc))
        if not self.planner.has_map:
            return reply.answer(PlanError.NO_MAP, "no environment map: no /voxel_map received and no scene_file")
        outcome = self.planner.plan(joints, PlanRequest(
            region=reply.region, arm=rr.arm, goal_count=rr.goal_count, planner=rr.planner,
            time_budget_s=rr.time_budget_s, seed=rr.seed, home=rr.home))
        reply.outcome, reply.stats = outcome, dict(outcome.stats or {})
        return reply.answer(int(outcome.error), str(outcome.message))

    def statistics(self, reply: PlanReply, total_s: float) -> dict[str, Any]:
        """The response's statistics (``PlanningStatistics`` fields): the planner's, the map's, the total time."""
        stats = dict(reply.stats)
        stats.setdefault("map_voxels", self.map_info.voxels)
        stats.setdefault("sphere_tree_build_time_s", self.map_info.build_time_s)
        stats["total_time_s"] = total_s
        return stats

    def finish(self, n: int, reply: PlanReply, total_s: float, published: bool) -> None:
        """Request ``n`` answered with ``reply`` (``published``: its trajectory went out): counters, the
        last result, one INFO line (ERROR for INTERNAL_ERROR), and every retreat tried by a refused start."""
        self.counters.count("successes", int(reply.success))
        self.last, self.last_total_s = reply, total_s
        code = int(reply.code)
        head = f"plan_reach #{n}: {code_name(code)} ({code}) in {total_s * 1e3:.0f} ms"
        out = reply.outcome
        if out is not None:
            s = self.statistics(reply, total_s)
            c = {k: int(round(float(s.get(k) or 0))) for k in _COUNTS}
            head += (f" [goal sampling {float(s.get('goal_sampling_time_s') or 0) * 1e3:.0f} ms, "
                     f"{c['goals_found']}/{c['goals_requested']} goals; path "
                     f"{float(s.get('path_planning_time_s') or 0) * 1e3:.0f} ms, {c['path_waypoints']} waypoints; "
                     f"{c['collision_checks']} collision checks]")
        if reply.success:
            times = np.asarray(out.times).reshape(-1)
            dur = float(times[-1]) if len(times) else 0.0
            head += (f"; {ARM_NAMES.get(reply.arm_code, '?')} arm, {len(times)} points over {dur:.2f} s"
                     f"{', published on reach_trajectory' if published else ''}")
        self.log("error" if code == PlanError.INTERNAL_ERROR else "info", head + f": {reply.response_message}")
        tried = getattr(out, "retreats_tried", ()) if not reply.success else ()
        if tried:   # the response keeps six; the log has them all (a refused retreat is found from here)
            self.log("info", f"plan_reach #{n}: the {len(tried)} retreats tried: "
                             + "; ".join(f"{k + 1}) {why}" for k, why in enumerate(tried)))

    # ------------------------------------------------------------ markers
    def hand_positions(self, joints: np.ndarray, limb: str) -> np.ndarray:
        """World positions (K, 3) of a hand for joint vectors (K, n_joints) standing on the feet."""
        tip = self.model.limbs[limb].tip
        out = np.empty((len(joints), 3))
        for i, j in enumerate(joints):
            out[i] = self.model.frame_pose(self.model.config(j, self.model.base_on_feet(j)), tip).translation
        return out

    def _full_configs(self, rows: np.ndarray | None) -> np.ndarray | None:
        """Full configurations (K, nq) of rows given as (K, nq) q or (K, n_joints) joints standing on
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

    def goal_hand_poses(self, reply: PlanReply) -> list[pin.SE3]:
        """The reaching hand's pose at each goal posture (the goal's arm, else the hand nearest the target)."""
        out = reply.outcome
        goals = self._full_configs(getattr(out, "goals", None))
        if goals is None:
            return []
        arms = getattr(out, "goal_arms", None)
        tips = [self.model.limbs[limb].tip for limb in HAND_LIMBS.values()]  # right, left
        poses = []
        for i, q in enumerate(goals):
            if arms is not None and len(arms) == len(goals) and int(arms[i]) in ARM_NAMES:
                poses.append(self.model.frame_pose(q, tips[ARMS.index(ARM_NAMES[int(arms[i])])]))
            elif reply.region is not None:
                hands = [self.model.frame_pose(q, tip) for tip in tips]
                target = np.asarray(reply.region.target_p)
                poses.append(min(hands, key=lambda h: np.linalg.norm(h.translation - target)))
        return poses

    def hand_path(self, reply: PlanReply) -> np.ndarray | None:
        """At most ``marker_path_points`` positions (K, 3) of the moving hand along a planned trajectory."""
        out = reply.outcome
        if out is None or not out.success or out.positions is None or out.arm not in HAND_LIMBS:
            return None
        k = len(out.positions)
        idx = np.unique(np.linspace(0, k - 1, min(k, self.config.marker_path_points)).round().astype(int))
        return self.hand_positions(np.asarray(out.positions)[idx], HAND_LIMBS[out.arm])

    # ------------------------------------------------------------ diagnostics
    def diagnostics(self, joints_reason: str | None, joint_states_age_s: float, target_age_s: float) -> list[tuple]:
        """``(name suffix, level, message, values)`` of the map, planning and inputs statuses;
        ``joints_reason``: why there are no start joints (None: there are)."""
        m = self.map_info
        values = {"source": m.source, "voxels": m.voxels, "build_time_ms": m.build_time_s * 1e3,
                  "maps_received": m.received, "maps_rejected": m.rejected,
                  "dropped_nonfinite_points": m.dropped_nonfinite, "last_rejection": m.last_rejection,
                  "frame_id": self.config.map_frame,
                  **{f"scene_{k}": v for k, v in self.scene.describe().items()}}   # the planning scene's layers
        if self.planner.has_map:
            level, message = OK, f"{m.voxels} voxels from {m.source}"
        else:
            level, message = WARN, "no map yet: waiting for /voxel_map"
        if m.last_rejection and m.rejected:
            message += f"; {m.rejected} /voxel_map rejected, last: {m.last_rejection}"
        statuses = [("map", level, message, values)]

        last = self.last
        values = {**self.counters.values(),
                  "planning": self.plan_lock.locked()}
        if last is None:
            level, message = OK, "no request yet"
        else:
            name = code_name(last.code)
            st = last.stats
            values.update({"last_result": name, "last_error_code": last.code, "last_message": last.message,
                           "last_total_time_s": self.last_total_s,
                           "last_goal_sampling_time_s": float(st.get("goal_sampling_time_s", 0.0) or 0.0),
                           "last_path_planning_time_s": float(st.get("path_planning_time_s", 0.0) or 0.0)})
            level = ERROR if last.code == PlanError.INTERNAL_ERROR else OK
            message = f"last request: {name} in {self.last_total_s * 1e3:.0f} ms"
        statuses.append(("planning", level, message, values))

        values = {"joint_states_age_s": joint_states_age_s if math.isfinite(joint_states_age_s) else "never",
                  "target_pose_age_s": target_age_s if math.isfinite(target_age_s) else "never"}
        statuses.append(("inputs", *((OK, "joint_states current") if joints_reason is None else (WARN, joints_reason)),
                         values))
        return statuses
