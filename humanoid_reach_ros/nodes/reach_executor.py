"""``reach_executor``: the 5 ms whole-body execution loop of Kanehiro et al. (Sec. IV-V).

A thin node around ``humanoid_reach_ros.control.executor.WholeBodyExecutor`` (the
prioritized IK step: joint limits + velocity dampers, feet + exact COG, hand, posture):

* serves the ``/execute_reach`` action (humanoid_reach_interfaces/action/ExecuteReach).
  ``MODE_TRAJECTORY`` executes ``goal.trajectory`` with the hand of ``goal.arm`` (0 = the
  arm whose joints the trajectory moves) and the flags ``disable_collision_avoidance``,
  ``disable_com_compensation`` (Figs. 8 and 7 "without") and ``smooth_reshaping`` (Yoshida
  et al., ``planning/reshape.py``: run in the goal's callback thread before the motion is
  handed to the loop -- it takes seconds, the running motion or hold goes on meanwhile);
  ``MODE_DUAL_ARM`` runs the real-time dual-arm whole-body reaching controller of the
  dissertation (``reach/controller.py``: torso regression, eq. 6 CoM, Algorithm 3 legs +
  closed-form arms, 0.38 m/s) to ``right_hand_target`` / ``left_hand_target``
  (PoseStamped in ``world`` or ``base_link``; the waist from /joint_states by
  ``RobotModel.base_on_feet``); a pair the controller finds infeasible is refused with
  ``INVALID_GOAL`` and its reason (the robot holds); SUCCESS when both hands are at their
  targets. Feedback: progress, time, min distance, COG error, hand error; the result
  carries the figures of the execution;
* subscribes ``/dual_arm/targets`` (geometry_msgs/PoseArray, exactly 2 poses: right hand
  then left hand, ``header.frame_id`` world | base_link): while the parameter
  ``dual_arm_follow`` is true (settable at run time) each message retargets the dual-arm
  controller from the last command (follow-targets mode, Sec. 5.3: e.g. AR markers);
  targets within ``dual_arm_retarget_threshold_m`` / ``_rad`` of the current ones are
  ignored (marker noise must not restart the interpolation); an infeasible pair or a bad
  message gets a throttled warning and a diagnostic counter, the robot holds. When
  ``dual_arm_follow`` is false the messages are counted and ignored. A followed pair
  preempts whatever runs (goals included). ``marker_localizer`` publishes this topic from
  two AR markers when its ``hand_marker_ids`` parameter names them (Sec. 5.3);
* serves ``~/dual_arm_sequential`` (std_srvs/Trigger): sequential random targets
  (Sec. 5.4): ``dual_arm_sequential_count`` (1..1000) pairs, each hand's target drawn in the
  workspace box among those the method reaches from the initial posture
  (``DualArmReachController.sample_reachable``, about 30 ms per pair, in the service call;
  seed ``dual_arm_sequential_seed``), each started as soon as the previous one is
  reached; pairs the controller finds infeasible are skipped (counted). Runs as a motion
  like the others (a goal or a followed pair preempts it; SUCCESS when all were tried);
* subscribes ``/reach_trajectory`` (trajectory_msgs/JointTrajectory, reliable, depth 1,
  from ``reach_planner``): executed like a goal with ``arm = 0`` and both constraints on;
* subscribes ``/joint_states`` (the start posture when nothing was commanded yet; stale
  after ``joint_states_timeout_s``: a start is refused with ``NO_JOINT_STATES``; after
  ``joint_states_abort_s`` a running motion is stopped with ``ABORTED`` and held) and
  ``/voxel_map`` (sensor_msgs/PointCloud2 of occupied voxel centres, transient local,
  reliable, depth 1): each map becomes the executor's sphere
  tree (``SphereTree.from_voxels`` at ``resolution_m``); until one arrives the map is the
  ``scene_file`` voxelized like ``reach_planner`` does (without ``scene_exclude_groups``);
* publishes ``/joint_command`` (sensor_msgs/JointState, the 30 joints in model order)
  every ``period_s`` while a motion runs and while holding after one (the joint driver's
  ``command_timeout_s`` never expires meanwhile), ``/executor/metrics``
  (humanoid_reach_interfaces/msg/ExecutorMetrics every ``metrics_decimation`` published
  steps) and ``/diagnostics``.

Timing (two dedicated threads, the ROS callbacks run in a MultiThreadedExecutor):

* the **tick thread** wakes at absolute deadlines ``t_0 + k period_s`` (no drift; when it
  falls more than one period behind, the missed deadlines are skipped and counted, never
  burst). At each deadline it publishes the step the solver finished since the previous
  deadline. When the solver has not finished (the step overran its period) it publishes
  the last safe command again, counts an overrun, and the late result goes out at the
  next deadline: a half-computed command is never sent (one period of latency, as in a
  real-time pipeline);
* the **solver thread** owns the executor: it applies start / hold / map commands queued
  by the callbacks and computes the next step as soon as the previous one was consumed.

Dual-arm mode (named simplifications): the controller works in free space (no collision
avoidance, as the dissertation's experiments; obstacles need waypoints, Sec. 5.5), so the
metrics report ``min_distance_m = inf``; ``com_error_m`` is the horizontal distance of the
commanded CoM from the controller's CoM reference of the step, ``hand_error_m`` /
``hand_error_rad`` the larger hand error w.r.t. the step's interpolated hand references.
Set-up of a target pair (regression, eq. 6, path check; a few to tens of ms) runs in the
solver thread: meanwhile the tick thread republishes the last command (not counted as
overruns). A cancel, a stale-/joint_states abort or an infeasible new pair stops a running
dual-arm motion by braking it on its path over ``dual_arm_brake_s``
(``DualArmReachController.brake``), then it holds. A feasible new pair (goal or followed
message) re-plans from the current reference as the controller's follow-targets mode does:
the minimum-jerk profile restarts at zero speed (a velocity discontinuity, never a
position jump). A trajectory goal after a dual-arm motion starts the whole-body executor
from the last command; a dual-arm start after a trajectory resets the controller to the
last command (``DualArmReachController.reset``).

Continuity: every start (a new goal, a new ``/reach_trajectory`` preempting a goal, or a
goal after a cancel) begins from the last *commanded* configuration
(``executor.start(q_last_cmd, ...)``; the measured ``/joint_states`` only when nothing
was commanded yet), the executor blends the reference in; a cancel or an abort calls
``executor.hold()`` and keeps solving for ``hold_settle_s``; afterwards the last command
is republished every period (for ``hold_timeout_s``, 0 = until the next motion).

Bad inputs never stop the node: an invalid goal gets ``INVALID_GOAL`` (or
``NO_JOINT_STATES``) with a message and does not disturb the running motion; an invalid
``/reach_trajectory`` gets a throttled warning and a diagnostic.

Run: ``python -m humanoid_reach_ros.nodes.reach_executor --ros-args --params-file
config/reach_executor.yaml`` (``ros2 run humanoid_reach_ros reach_executor`` on an install).
"""
from __future__ import annotations

import dataclasses
import itertools
import math
import sys
import threading
import time
import traceback
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray
from humanoid_reach_interfaces.action import ExecuteReach
from humanoid_reach_interfaces.msg import ExecutorMetrics
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import JointState, PointCloud2
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory

from humanoid_reach_ros.control.executor import ExecutorParams, StepResult, WholeBodyExecutor
from humanoid_reach_ros.geometry.sphere_tree import SphereTree
from humanoid_reach_ros.geometry.voxels import without_target
from humanoid_reach_ros.io import exec_msgs, msgs
from humanoid_reach_ros.io.exec_msgs import ExecInputError, Reference
from humanoid_reach_ros.nodes.common import LATCHED, RELIABLE_LATEST, ParamSpec, declare_parameters, run_node
from humanoid_reach_ros.paths import config_path
from humanoid_reach_ros.planning.trajectory import SplineTrajectory
from humanoid_reach_ros.reach.controller import ControllerConfig, ControlStep, DualArmReachController
from humanoid_reach_ros.reach.torso_regression import ReachWorkspace, TorsoRegression
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.shapes import load_collision_model
from humanoid_reach_ros.sim.scene import load_scene

NODE_NAME = "reach_executor"
R = ExecuteReach.Result
RESULT_NAMES = exec_msgs.result_names()
SOLVERS = ("nullspace", "osqp")

# Defaults match config/reach_executor.yaml (checked by test_reach_executor_node). The first
# group maps one to one onto ``ExecutorParams`` fields and takes its defaults from it.
_D = ExecutorParams()
#: upper bound of dual_arm_sequential_count (the pairs are drawn in the service call, ~30 ms each)
MAX_SEQUENTIAL = 1000

EXECUTOR_PARAMETERS: dict[str, ParamSpec] = {
    "period_s": ParamSpec(_D.period_s, "control period dt [s]: one executor step and one /joint_command each",
                          (0.001, 0.1)),
    "distance_bound_m": ParamSpec(_D.distance_bound_m, "d_i: environment spheres / self pairs closer than this "
                                  "enter level 1 as velocity dampers [m]", (0.001, 1.0)),
    "security_distance_m": ParamSpec(_D.security_distance_m, "d_s of the velocity damper [m]", (0.0, 0.5)),
    "damper_xi": ParamSpec(_D.damper_xi, "xi of the velocity damper (per-step fraction)", (0.001, 1.0)),
    "hand_gain": ParamSpec(_D.hand_gain, "per-step gain of the hand task (level 3)", (0.001, 1.0)),
    "com_gain": ParamSpec(_D.com_gain, "per-step gain of the exact-COG task (level 2)", (0.001, 1.0)),
    "feet_gain": ParamSpec(_D.feet_gain, "per-step gain of the feet tasks (level 2)", (0.001, 1.0)),
    "posture_gain": ParamSpec(_D.posture_gain, "per-step gain of the posture task (level 4)", (0.001, 1.0)),
    "velocity_scale": ParamSpec(_D.velocity_scale, "fraction of the URDF joint velocity limits allowed", (0.01, 1.0)),
    "com_recenter_speed_mps": ParamSpec(_D.com_recenter_speed_mps, "mean speed of the COG target back to its "
                                        "nominal point after a start away from it [m/s]", (0.001, 1.0)),
    "blend_min_s": ParamSpec(_D.blend_min_s, "shortest blend of a reference that starts away from the last "
                             "command [s]", (0.0, 10.0)),
    "settle_timeout_s": ParamSpec(_D.settle_timeout_s, "a motion ends at most this long after its reference "
                                  "[s] even if the hand has not converged", (0.0, 60.0)),
    "solver": ParamSpec(_D.solver, "prioritized IK solver", constraints=f"one of {', '.join(SOLVERS)}"),
}

NODE_PARAMETERS: dict[str, ParamSpec] = {
    "robot_config": ParamSpec("robots/hrp2.yaml", "robot semantic YAML, relative to config/ or absolute"),
    "resolution_m": ParamSpec(0.02, "voxel size of the environment map [m] (sphere radius = resolution / 2)",
                              (0.001, 1.0)),
    "safety_margin_m": ParamSpec(0.0, "extra radius added to every environment sphere [m]", (0.0, 0.5)),
    "scene_file": ParamSpec("scenes/plant.yaml", "scene whose voxels are the map until /voxel_map arrives, "
                            "relative to config/ or absolute; empty = no map until /voxel_map"),
    "scene_exclude_groups": ParamSpec(["valve"], "scene primitive groups left out of the scene-file map "
                                      "(the object to be grasped)"),
    "map_frame": ParamSpec("world", "frame of /voxel_map and of the metrics"),
    "target_exclusion_radius_m": ParamSpec(0.15, "voxels of a /voxel_map within this distance of the motion's "
                                           "final hand position are the object to be reached and left out of "
                                           "the collision map [m]; 0 = keep all (as reach_planner)", (0.0, 1.0)),
    "joint_states_timeout_s": ParamSpec(0.5, "/joint_states older than this [s]: a start is refused (NO_JOINT_STATES)",
                                        (0.001, 3600.0), read_only=False),
    "joint_states_abort_s": ParamSpec(2.0, "/joint_states older than this [s] while a motion runs: it is aborted "
                                      "(ABORTED) and the last command held", (0.001, 3600.0), read_only=False),
    "hold_settle_s": ParamSpec(0.25, "after a cancel or abort the executor keeps solving in hold mode this long [s]",
                               (0.0, 10.0)),
    "hold_timeout_s": ParamSpec(0.0, "republish the held command this long after a motion [s]; 0 = until the "
                                "next motion", (0.0, 1e6)),
    "metrics_decimation": ParamSpec(1, "publish /executor/metrics every this many published steps (>= 1)"),
    "feedback_period_s": ParamSpec(0.05, "period of the action feedback [s]", (0.005, 10.0)),
    "diagnostics_period_s": ParamSpec(1.0, "period of /diagnostics [s]", (0.05, 60.0)),
    "max_overrun_fraction": ParamSpec(0.02, "diagnostics WARN when more than this fraction of the steps of the "
                                      "last window overran", (0.0, 1.0)),
    "warn_throttle_s": ParamSpec(1.0, "minimum interval between repeated warnings [s]", (0.0, 3600.0)),
    # ---- dual-arm mode (MODE_DUAL_ARM goals, /dual_arm/targets)
    "dual_arm_regression": ParamSpec("torso_regression/hrp2_torso_svr", "torso regression model stem (.npz + "
                                     ".yaml), relative to config/ or absolute"),
    "dual_arm_workspace": ParamSpec("torso_regression/workspace.yaml", "workspace / eq. 6 YAML of the dual-arm "
                                    "controller, relative to config/ or absolute"),
    "dual_arm_max_speed_mps": ParamSpec(0.38, "speed limit of the hands and the CoM in dual-arm mode [m/s]",
                                        (0.01, 2.0)),
    "dual_arm_brake_s": ParamSpec(0.2, "a canceled / preempted dual-arm motion stops on its path over this "
                                  "long [s]", (0.0, 5.0)),
    "dual_arm_follow": ParamSpec(False, "follow /dual_arm/targets: each message retargets the dual-arm "
                                 "controller (settable at run time)", read_only=False),
    "dual_arm_retarget_threshold_m": ParamSpec(0.005, "/dual_arm/targets whose hand positions are all within "
                                               "this of the current targets are ignored [m]", (0.0, 1.0),
                                               read_only=False),
    "dual_arm_retarget_threshold_rad": ParamSpec(0.02, "... and whose hand orientations are within this [rad]",
                                                 (0.0, 3.2), read_only=False),
    "dual_arm_sequential_count": ParamSpec(10, "random target pairs of one ~/dual_arm_sequential run (1..1000)",
                                           read_only=False),
    "dual_arm_sequential_seed": ParamSpec(0, "seed of the random target pairs of ~/dual_arm_sequential",
                                          read_only=False),
}

PARAMETERS: dict[str, ParamSpec] = {**EXECUTOR_PARAMETERS, **NODE_PARAMETERS}

IDLE, RUN, SETTLE, HOLD = "idle", "running", "settling", "holding"


def executor_params(values: dict[str, Any]) -> ExecutorParams:
    """``ExecutorParams`` from the declared parameters (validated)."""
    known = {f.name for f in dataclasses.fields(ExecutorParams)}
    return ExecutorParams(**{k: values[k] for k in EXECUTOR_PARAMETERS if k in known}).validate()


@dataclass(eq=False)
class Motion:
    """One execution (an action goal or a /reach_trajectory message) and its figures."""

    label: str                                  # "goal #3" | "/reach_trajectory #2" | "/dual_arm/targets #4"
    reference: Reference | None                 # None for a dual-arm motion
    arm: str                                    # "right" | "left" | "both" (dual arm)
    params: ExecutorParams
    goal: bool
    note: str = ""                              # e.g. what smooth reshaping did
    targets: tuple[pin.SE3, pin.SE3] | None = None   # dual arm: (right, left) hand targets in world
    follow: bool = False                        # dual arm from /dual_arm/targets
    sequential: tuple | None = None             # dual arm, sequential random targets: (count, seed, (PR, PL))
    pairs_reached: int = 0                      # sequential: pairs reached / skipped as infeasible
    pairs_skipped: int = 0

    @property
    def dual(self) -> bool:
        return self.targets is not None or self.sequential is not None
    started: float = math.nan                   # monotonic time the executor started it
    steps: int = 0
    overruns: int = 0
    max_com_error_m: float = 0.0
    min_distance_m: float = math.inf
    last: Any = None                            # StepMetrics of the last published step
    code: int | None = None                     # ExecuteReach.Result code once finished
    message: str = ""
    ended: float = math.nan
    finished: threading.Event = field(default_factory=threading.Event)

    def summary(self) -> dict[str, float]:
        last = self.last
        return {"duration_s": (self.ended if math.isfinite(self.ended) else time.monotonic()) - self.started
                if math.isfinite(self.started) else 0.0,
                "steps": self.steps, "overruns": self.overruns, "max_com_error_m": self.max_com_error_m,
                "min_distance_m": self.min_distance_m,
                "final_hand_error_m": last.hand_error_m if last is not None else 0.0,
                "final_hand_error_rad": last.hand_error_rad if last is not None else 0.0}

    def figures(self) -> str:
        s = self.summary()
        return (f"{s['duration_s']:.2f} s, {self.steps} steps, {self.overruns} overruns, max COG error "
                f"{s['max_com_error_m'] * 1e3:.2f} mm, min distance {s['min_distance_m']:.4f} m, final hand "
                f"error {s['final_hand_error_m'] * 1e3:.2f} mm / {s['final_hand_error_rad']:.4f} rad")


@dataclass(frozen=True, eq=False)
class DualStepResult:
    """One step of the dual-arm controller in the shape the tick thread publishes
    (``q``, ``joints``, ``metrics``, ``done`` as the executor's ``StepResult``) plus the
    controller's ``ok`` / ``reason``."""

    q: np.ndarray
    joints: np.ndarray
    metrics: exec_msgs.DualArmMetrics
    done: bool                  # the motion is over (sequential: the last pair's last step)
    ok: bool = True
    reason: str = ""
    pair_done: bool = False     # the last step of a target pair (reached, or skipped when not ok)


@dataclass
class Counters:
    goals: int = 0
    goals_rejected: int = 0
    trajectories: int = 0
    trajectories_rejected: int = 0
    successes: int = 0
    last_rejection: str = ""
    last_result: str = ""
    maps_received: int = 0
    dual_arm_goals: int = 0
    dual_arm_infeasible: int = 0
    target_messages: int = 0
    target_messages_rejected: int = 0
    target_messages_ignored: int = 0
    target_messages_unchanged: int = 0
    last_infeasible: str = ""
    maps_rejected: int = 0
    map_source: str = "none"
    map_voxels: int = 0
    map_build_s: float = 0.0


class ReachExecutorNode(Node):
    """Thin node around ``WholeBodyExecutor``: conversions, threads, logging and diagnostics."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = declare_parameters(self, PARAMETERS)
        self._p = p
        if p["solver"] not in SOLVERS:
            raise ValueError(f"solver must be one of {SOLVERS}, got {p['solver']!r}")
        if p["metrics_decimation"] < 1:
            raise ValueError(f"metrics_decimation must be >= 1, got {p['metrics_decimation']}")
        self.params = executor_params(p)
        self.period_s: float = self.params.period_s
        self.map_frame: str = p["map_frame"]
        self.robot = RobotModel(p["robot_config"])
        self.collision_model = load_collision_model(None, self.robot)
        self.hardware_id = str(self.robot.semantic.get("robot_name", "robot"))
        t0 = time.perf_counter()
        self._warm_up()
        self.get_logger().info(f"executor kernels warmed up in {1e3 * (time.perf_counter() - t0):.0f} ms")
        self.executor_ = WholeBodyExecutor(self.robot, self.collision_model, self.params)
        t0 = time.perf_counter()
        # the dual-arm controller has its own RobotModel (pinocchio data): owned by the solver thread
        self.dual_ = DualArmReachController(
            RobotModel(p["robot_config"]), TorsoRegression.load(p["dual_arm_regression"]),
            ReachWorkspace.load(p["dual_arm_workspace"]),
            ControllerConfig(period_s=self.period_s, max_speed_mps=p["dual_arm_max_speed_mps"]))
        self._warm_up_dual()
        # a second controller (own RobotModel; regression and workspace are read-only) draws the
        # reachable target pairs of ~/dual_arm_sequential in the service callback, off the solver
        # thread; built on the first call (most runs never use it)
        self._sampler: DualArmReachController | None = None
        self._sampler_lock = threading.Lock()
        self.get_logger().info(f"dual-arm controller (torso regression {p['dual_arm_regression']}) ready in "
                               f"{1e3 * (time.perf_counter() - t0):.0f} ms")
        self._engine = "executor"                    # which solver made the last command: executor | dual
        self._dual_targets: tuple[pin.SE3, pin.SE3] | None = None   # of the last started dual-arm motion
        self._dual_data = self.robot.model.createData()   # solver thread: metrics of dual-arm steps
        self._fid_hand = {s: self.robot.frame_id(self.robot.limbs[f"{s}_arm"].tip) for s in ("right", "left")}
        self._follow_ids = itertools.count(1)
        self._sequential_ids = itertools.count(1)
        self.counters = Counters()
        self._tree: SphereTree | None = None          # the latest map (for reshaping; the solver has its own copy)
        self._map_points: np.ndarray | None = None    # the last /voxel_map, before the target is left out
        self._target_p: np.ndarray | None = None      # final hand position of the latest motion (world)
        self._fk_lock = threading.Lock()              # self.robot's pinocchio data: callbacks vs solver thread
        self._reshape_lock = threading.Lock()
        self._reshaper = None
        self.last_motion: Motion | None = None       # the last finished motion (figures for diagnostics/tests)
        self._goal_ids = itertools.count(1)          # next() is atomic: unique labels across callback threads
        self._trajectory_ids = itertools.count(1)

        # shared state (self._cond guards everything below)
        self._cond = threading.Condition()
        self._pending: list[tuple] = []        # commands for the solver thread
        self._mode = IDLE
        self._motion: Motion | None = None     # the motion being executed (RUN) or None
        self._ready: tuple[Motion | None, StepResult] | None = None   # computed, not yet published
        self._starting = False                 # the solver is inside executor.start(): ticks hold, no overrun
        self._last_q: np.ndarray | None = None       # last commanded full configuration
        self._last_joints: np.ndarray | None = None  # ... its 30 joints
        self._settle_until = 0.0
        self._hold_since = 0.0
        self._stop = False
        self._published = 0
        self._ticks = 0
        self._overruns = 0
        self._missed_ticks = 0
        self._step_times: deque[float] = deque(maxlen=2000)
        self._window = self._new_window()
        self._state_lock = threading.Lock()
        self._joint_msg: JointState | None = None
        self._joint_time = -math.inf

        if p["scene_file"]:
            path = config_path(p["scene_file"])
            voxels = load_scene(str(path)).voxelize(p["resolution_m"], exclude_groups=tuple(p["scene_exclude_groups"]))
            build_s = self._set_map(voxels)
            self.counters.map_source = f"scene file {path}"
            self.get_logger().info(
                f"map source: scene file {path} ({len(voxels)} voxels without groups "
                f"{list(p['scene_exclude_groups'])}, "
                f"sphere tree built in {build_s * 1e3:.1f} ms); a /voxel_map replaces it")
        else:
            self.get_logger().info("map source: none yet (scene_file is empty): executing without environment "
                                   "until /voxel_map arrives")

        self._state_group = MutuallyExclusiveCallbackGroup()
        self._map_group = MutuallyExclusiveCallbackGroup()
        self._traj_group = MutuallyExclusiveCallbackGroup()
        self._action_group = ReentrantCallbackGroup()
        self.command_pub = self.create_publisher(JointState, "joint_command", 10)
        self.metrics_pub = self.create_publisher(ExecutorMetrics, "executor/metrics", 10)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_subscription(JointState, "joint_states", self._on_joint_states, qos_profile_sensor_data,
                                 callback_group=self._state_group)
        self.create_subscription(PointCloud2, "voxel_map", self._on_map, LATCHED, callback_group=self._map_group)
        self.create_subscription(JointTrajectory, "reach_trajectory", self._on_trajectory, RELIABLE_LATEST,
                                 callback_group=self._traj_group)
        # best effort depth 1: the latest pair only; matches reliable and sensor-data publishers
        self.create_subscription(PoseArray, "dual_arm/targets", self._on_targets,
                                 QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT),
                                 callback_group=self._traj_group)
        self.create_service(Trigger, "~/dual_arm_sequential", self._on_sequential, callback_group=self._traj_group)
        # deeper request queues than the default 10: a burst of goals / result requests is answered, not dropped
        requests = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.action_server = ActionServer(self, ExecuteReach, "execute_reach", execute_callback=self._execute,
                                          goal_callback=lambda _goal: GoalResponse.ACCEPT,
                                          cancel_callback=self._on_cancel, callback_group=self._action_group,
                                          goal_service_qos_profile=requests, result_service_qos_profile=requests,
                                          cancel_service_qos_profile=requests)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(p["diagnostics_period_s"], self._publish_diagnostics, clock=steady,
                          callback_group=self._state_group)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self._command = msgs.joint_state(self.robot.joint_names, np.zeros(self.robot.n_joints))
        self._solver_thread = threading.Thread(target=self._run_solver, name="reach_executor_solver", daemon=True)
        self._tick_thread = threading.Thread(target=self._run_ticks, name="reach_executor_ticks", daemon=True)
        self._solver_thread.start()
        self._tick_thread.start()
        self.get_logger().info(
            f"reach executor ready: action execute_reach (trajectory, dual arm), topics reach_trajectory, "
            f"dual_arm/targets (follow {'on' if p['dual_arm_follow'] else 'off'}); /joint_command every "
            f"{self.period_s * 1e3:g} ms while executing or holding; solver {self.params.solver}, distance bound "
            f"{self.params.distance_bound_m:g} m, velocity scale {self.params.velocity_scale:g}; joint_states stale "
            f"after {p['joint_states_timeout_s']:g} s")

    # ------------------------------------------------------------ set-up
    def _warm_up(self) -> None:
        """Compile the numba kernels and load the solver on a throw-away executor so the
        first motion's steps are not slow."""
        ex = WholeBodyExecutor(self.robot, self.collision_model, self.params)
        ex.set_environment(SphereTree.from_voxels(np.array([[0.5, -0.3, 0.9], [5.0, 5.0, 5.0]]), 0.02))
        hs = self.robot.half_sitting_joints
        ref = SplineTrajectory(np.vstack([hs, hs]), np.array([0.0, 2 * self.params.period_s]))
        ex.start(self.robot.half_sitting(), ref, "right")
        for _ in range(5):
            ex.step()

    def _warm_up_dual(self) -> None:
        """One target pair planned and stepped on the dual-arm controller (first-call costs)."""
        ctl = self.dual_
        ctl.reset(self.robot.half_sitting())
        ws = ctl.ws
        t = ws.targets(0.5 * (ws.right_lower + ws.right_upper), 0.5 * (ws.left_lower + ws.left_upper))
        ctl.set_targets(t.p_right, t.R_right, t.p_left, t.R_left)
        for _ in range(3):
            ctl.step()
        ctl.reset(self.robot.half_sitting())

    def _set_map(self, voxels: np.ndarray) -> float:
        """Sphere tree of voxel centres (N, 3) -> the solver (applied before its next step)."""
        V = np.asarray(voxels, dtype=float).reshape(-1, 3)
        t0 = time.perf_counter()
        tree = SphereTree.from_voxels(np.ascontiguousarray(V), self._p["resolution_m"], self._p["safety_margin_m"])
        build_s = time.perf_counter() - t0
        self._queue(("map", tree))
        self._tree = tree
        self.counters.map_voxels, self.counters.map_build_s = len(V), build_s
        return build_s

    def _carved(self, points: np.ndarray, target: np.ndarray | None) -> np.ndarray:
        """A measured map without the object at the motion's target (as reach_planner leaves it out)."""
        if target is None:
            return points
        return without_target(points, target, float(self._p["target_exclusion_radius_m"]))

    def _aim_map_at(self, positions: np.ndarray, arm: str) -> None:
        """Before a motion: leave the voxels around its final hand position out of a measured map."""
        end = positions[-1]
        with self._fk_lock:
            q_end = self.robot.config(end, self.robot.base_on_feet(end))
            target = self.robot.frame_pose(q_end, self.robot.limbs[f"{arm}_arm"].tip).translation.copy()
        with self._state_lock:
            self._target_p, points = target, self._map_points
        if points is not None:
            kept = self._carved(points, target)
            self._set_map(kept)
            if len(kept) < len(points):
                self.get_logger().info(f"/voxel_map: {len(points) - len(kept)} of {len(points)} voxels within "
                                       f"{self._p['target_exclusion_radius_m']:g} m of the final hand position "
                                       f"{np.round(target, 3).tolist()} left out (the object to be reached)")

    # ------------------------------------------------------------ subscriptions
    def _on_joint_states(self, msg: JointState) -> None:
        with self._state_lock:
            self._joint_msg, self._joint_time = msg, time.monotonic()

    def _on_map(self, msg: PointCloud2) -> None:
        log, c = self.get_logger(), self.counters
        try:
            cloud = msgs.points_from_cloud(msg)
            if cloud.frame_id not in ("", self.map_frame):
                raise ValueError(f"frame_id {cloud.frame_id!r} is not the map frame {self.map_frame!r}")
            previous = c.map_source
            with self._state_lock:
                self._map_points, target = cloud.points, self._target_p
            build_s = self._set_map(self._carved(cloud.points, target))
        except Exception as exc:  # malformed cloud: keep the previous map
            c.maps_rejected += 1
            c.last_rejection = f"/voxel_map: {type(exc).__name__}: {exc}"
            log.warning(f"rejected /voxel_map ({c.maps_rejected} so far): {exc}; keeping the previous map "
                        f"({c.map_source}, {c.map_voxels} voxels)", throttle_duration_sec=self._p["warn_throttle_s"])
            return
        c.maps_received += 1
        c.map_source = "/voxel_map"
        dropped = f", {cloud.dropped_nonfinite} NaN/inf points dropped" if cloud.dropped_nonfinite else ""
        log.info(f"map source: /voxel_map ({len(cloud.points)} voxels{dropped}, sphere tree built in "
                 f"{build_s * 1e3:.1f} ms; replaces {previous})")

    def _on_trajectory(self, msg: JointTrajectory) -> None:
        c = self.counters
        c.trajectories = n = next(self._trajectory_ids)
        label = f"/reach_trajectory #{n}"
        try:
            motion = self._prepare(label, msg, exec_msgs.ARM_AUTO, False, False, False, goal=False)
        except ExecInputError as exc:
            name = RESULT_NAMES.get(exc.code, str(exc.code))
            self._count_rejection("trajectories_rejected", f"{label}: {name}: {exc}")
            self.get_logger().warning(f"rejected {label} ({name}): {exc}",
                                      throttle_duration_sec=self._p["warn_throttle_s"])
            return
        except Exception as exc:  # never die on an input
            self._count_rejection("trajectories_rejected", f"{label}: internal error: {exc}")
            self.get_logger().error(f"{label}: internal error: {exc}\n{traceback.format_exc()}")
            return
        self._submit(motion)

    def _count_rejection(self, counter: str, reason: str) -> None:
        with self._cond:
            setattr(self.counters, counter, getattr(self.counters, counter) + 1)
            self.counters.last_rejection = reason

    # ------------------------------------------------------------ inputs
    def joint_states_age(self) -> float:
        """Seconds since the last /joint_states (inf: never)."""
        with self._state_lock:
            return time.monotonic() - self._joint_time

    def current_joints(self) -> tuple[np.ndarray | None, str]:
        """The latest valid 30 measured joint angles (model order), or None and the reason."""
        with self._state_lock:
            msg, t = self._joint_msg, self._joint_time
        if msg is None:
            return None, "no /joint_states received"
        age = time.monotonic() - t
        if age > self._p["joint_states_timeout_s"]:
            return None, f"/joint_states is stale ({age:.2f} s > {self._p['joint_states_timeout_s']:g} s)"
        return msgs.model_joints(msg, self.robot)

    def _prepare(self, label: str, trajectory: JointTrajectory, arm_code: int, no_avoidance: bool, no_com: bool,
                 reshaping: bool, goal: bool) -> Motion:
        """Validate an execution request and build its motion (``ExecInputError`` otherwise)."""
        ref = exec_msgs.reference_from_trajectory(trajectory, self.robot, what="trajectory")
        if trajectory.header.frame_id not in ("", self.map_frame):
            raise ExecInputError(R.INVALID_GOAL, f"trajectory frame_id {trajectory.header.frame_id!r} is not the "
                                                 f"map frame {self.map_frame!r}")
        with self._fk_lock:
            arm = exec_msgs.resolve_arm(int(arm_code), exec_msgs.arm_motion(self.robot, ref.positions))
        joints, reason = self.current_joints()
        if joints is None:
            raise ExecInputError(R.NO_JOINT_STATES, reason)
        self._aim_map_at(ref.positions, arm)
        note = ""
        if reshaping:
            ref, note = self._reshape(label, ref, arm)
        # reshaping, when asked for, is done here (seconds, outside the control loop), never in start()
        params = dataclasses.replace(self.params, collision_avoidance=not no_avoidance, com_compensation=not no_com,
                                     smooth_reshaping=False)
        return Motion(label, ref, arm, params, goal, note=note)

    def _prepare_dual(self, label: str, targets: tuple[exec_msgs.HandTarget, exec_msgs.HandTarget], goal: bool,
                      follow: bool = False) -> Motion:
        """A dual-arm motion to validated hand targets (world or base_link; ``ExecInputError``
        NO_JOINT_STATES without recent /joint_states: the waist of base_link targets and the
        start posture come from them). Feasibility is the controller's, at the start."""
        joints, reason = self.current_joints()
        if joints is None:
            raise ExecInputError(R.NO_JOINT_STATES, reason)
        waist = None
        if exec_msgs.needs_waist(targets):
            with self._fk_lock:
                waist = self.robot.base_on_feet(joints)
        right, left = exec_msgs.targets_in_world(targets, waist)
        return Motion(label, None, "both", self.params, goal, targets=(right, left), follow=follow)

    def _on_targets(self, msg: PoseArray) -> None:
        """``/dual_arm/targets``: validate; while ``dual_arm_follow`` retarget the controller."""
        c, log = self.counters, self.get_logger()
        c.target_messages = n = next(self._follow_ids)
        label = f"/dual_arm/targets #{n}"
        try:
            targets = exec_msgs.array_hand_targets(msg)
            if not self._p["dual_arm_follow"]:
                c.target_messages_ignored += 1
                log.info(f"{label} ignored: dual_arm_follow is false (set it true to follow the targets)",
                         throttle_duration_sec=self._p["warn_throttle_s"])
                return
            motion = self._prepare_dual(label, targets, goal=False, follow=True)
        except ExecInputError as exc:
            name = RESULT_NAMES.get(exc.code, str(exc.code))
            self._count_rejection("target_messages_rejected", f"{label}: {name}: {exc}")
            log.warning(f"rejected {label} ({name}): {exc}", throttle_duration_sec=self._p["warn_throttle_s"])
            return
        except Exception as exc:  # never die on an input
            self._count_rejection("target_messages_rejected", f"{label}: internal error: {exc}")
            log.error(f"{label}: internal error: {exc}\n{traceback.format_exc()}")
            return
        if self._unchanged(motion.targets):
            c.target_messages_unchanged += 1
            return
        self._submit(motion)

    def _on_sequential(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """``~/dual_arm_sequential``: start sequential random targets (see the module docstring)."""
        count, seed = int(self._p["dual_arm_sequential_count"]), int(self._p["dual_arm_sequential_seed"])
        label = f"sequential #{next(self._sequential_ids)}"
        if not 1 <= count <= MAX_SEQUENTIAL:
            response.success, response.message = False, (f"dual_arm_sequential_count must be in 1..{MAX_SEQUENTIAL}, "
                                                         f"got {count}")
        elif seed < 0:
            response.success, response.message = False, f"dual_arm_sequential_seed must be >= 0, got {seed}"
        else:
            joints, reason = self.current_joints()
            if joints is None:
                response.success, response.message = False, f"NO_JOINT_STATES: {reason}"
            else:
                t0 = time.perf_counter()
                with self._sampler_lock:
                    if self._sampler is None:
                        self._sampler = DualArmReachController(RobotModel(self._p["robot_config"]),
                                                               self.dual_.regression, self.dual_.ws, self.dual_.config)
                    pairs = self._sampler.sample_reachable(np.random.default_rng(seed), count)
                self._submit(Motion(label, None, "both", self.params, False, sequential=(count, seed, pairs)))
                response.success, response.message = True, (f"{label}: {count} random target pairs (seed {seed}, "
                                                             f"drawn in {time.perf_counter() - t0:.2f} s)")
        if not response.success:
            self._count_rejection("goals_rejected", f"~/dual_arm_sequential: {response.message}")
            self.get_logger().warning(f"~/dual_arm_sequential refused: {response.message}",
                                      throttle_duration_sec=self._p["warn_throttle_s"])
        return response

    def _unchanged(self, targets: tuple[pin.SE3, pin.SE3]) -> bool:
        """The dual-arm controller is already running to / holding at (nearly) these targets."""
        with self._cond:
            current = self._dual_targets if self._engine == "dual" and self._mode != IDLE else None
        if current is None:
            return False
        p_tol, r_tol = self._p["dual_arm_retarget_threshold_m"], self._p["dual_arm_retarget_threshold_rad"]
        return all(np.linalg.norm(a.translation - b.translation) <= p_tol
                   and np.linalg.norm(pin.log3(a.rotation.T @ b.rotation)) <= r_tol
                   for a, b in zip(targets, current))

    def _reshape(self, label: str, ref: Reference, arm: str) -> tuple[Reference, str]:
        """Smooth reshaping (Yoshida et al.) of ``ref`` against the current map, in the calling
        callback thread with the node's own reshaper (one at a time). ``ExecInputError``
        (ABORTED) when the reshaper fails."""
        tree = self._tree
        if tree is None or tree.n_spheres == 0:
            return ref, "smooth reshaping: no map, trajectory unchanged"
        t0 = time.perf_counter()
        if not self._reshape_lock.acquire(blocking=False):  # one at a time; never tie up the callback threads
            raise ExecInputError(R.ABORTED, "smooth reshaping busy: another goal is being reshaped; send it again "
                                            "when that one has started")
        try:
            if self._reshaper is None:
                from humanoid_reach_ros.planning.reshape import SmoothReshaper

                robot = RobotModel(self._p["robot_config"])   # its own pinocchio data: thread safety
                self._reshaper = SmoothReshaper(robot, load_collision_model(None, robot))
            out = self._reshaper.reshape(ref.spline, tree, arm)
        except Exception as exc:
            raise ExecInputError(R.ABORTED, f"smooth reshaping failed: {type(exc).__name__}: {exc}") from None
        finally:
            self._reshape_lock.release()
        spline = out.trajectory
        times = np.asarray(spline.times, dtype=float) - float(spline.times[0])
        new = Reference(times, np.asarray(spline.waypoints, dtype=float), spline, ref.time_offset_s)
        before = float(np.min(out.distance_before)) if len(out.distance_before) else math.inf
        after = float(np.min(out.distance_after)) if len(out.distance_after) else math.inf
        note = (f"smooth reshaping: {len(out.portions)} portion(s) reshaped in {time.perf_counter() - t0:.2f} s, "
                f"min distance {before:.4f} -> {after:.4f} m{'' if out.success else ' (collisions remain)'}")
        self.get_logger().info(f"{label}: {note}")
        return new, note

    # ------------------------------------------------------------ action
    def _on_cancel(self, goal_handle) -> CancelResponse:
        return CancelResponse.ACCEPT

    def _execute(self, goal_handle) -> ExecuteReach.Result:
        c = self.counters
        c.goals = max(c.goals, n := next(self._goal_ids))
        label = f"goal #{n}"
        req = goal_handle.request
        log = self.get_logger()
        try:
            if req.mode == ExecuteReach.Goal.MODE_DUAL_ARM:
                try:
                    targets = exec_msgs.goal_hand_targets(req.right_hand_target, req.left_hand_target)
                    motion = self._prepare_dual(label, targets, goal=True)
                except ExecInputError as exc:
                    raise ExecInputError(exc.code, f"MODE_DUAL_ARM goal: {exc}") from None
                c.dual_arm_goals += 1
            elif req.mode != ExecuteReach.Goal.MODE_TRAJECTORY:
                raise ExecInputError(R.INVALID_GOAL, f"mode {req.mode} is unknown; use 0 (TRAJECTORY) or "
                                                     "1 (DUAL_ARM)")
            else:
                motion = self._prepare(label, req.trajectory, req.arm, req.disable_collision_avoidance,
                                       req.disable_com_compensation, req.smooth_reshaping, goal=True)
        except ExecInputError as exc:
            name = RESULT_NAMES.get(exc.code, str(exc.code))
            self._count_rejection("goals_rejected", f"{label}: {name}: {exc}")
            log.warning(f"{label} rejected ({name}): {exc}")
            goal_handle.abort()
            return exec_msgs.result_message(exc.code, str(exc))
        except Exception as exc:  # never die on a goal
            self._count_rejection("goals_rejected", f"{label}: internal error: {exc}")
            log.error(f"{label}: internal error while validating: {exc}\n{traceback.format_exc()}")
            goal_handle.abort()
            return exec_msgs.result_message(R.ABORTED, f"internal error: {type(exc).__name__}: {exc}")

        if goal_handle.is_cancel_requested:  # while it was being validated / reshaped
            log.info(f"{label}: CANCELED before execution started")
            goal_handle.canceled()
            return exec_msgs.result_message(R.CANCELED, "canceled before execution started")
        self._submit(motion)
        cancel_sent = False
        while not motion.finished.wait(self._p["feedback_period_s"]):
            if self._stop:
                break
            if goal_handle.is_cancel_requested and not cancel_sent:
                cancel_sent = True
                self._queue(("hold", motion, R.CANCELED, "canceled by the client"))
            last = motion.last
            if last is not None and goal_handle.is_active:
                goal_handle.publish_feedback(exec_msgs.execute_feedback(last))
        if not motion.finished.is_set():  # shutting down
            motion.code, motion.message = R.ABORTED, "the reach_executor node is shutting down"
        result = exec_msgs.result_message(motion.code, motion.message, motion.summary())
        if motion.code == R.SUCCESS:
            goal_handle.succeed()
        elif motion.code == R.CANCELED and goal_handle.is_cancel_requested:
            goal_handle.canceled()
        else:
            goal_handle.abort()
        return result

    # ------------------------------------------------------------ commands to the solver
    def _queue(self, command: tuple) -> None:
        with self._cond:
            self._pending.append(command)
            self._cond.notify_all()

    def _submit(self, motion: Motion) -> None:
        ref = motion.reference
        if ref is None and motion.sequential is not None:
            self.get_logger().info(f"{motion.label}: accepted: {motion.sequential[0]} sequential random target pairs "
                                   f"(seed {motion.sequential[1]})")
            self._queue(("start", motion))
            return
        if ref is None:
            r, l_ = motion.targets
            line = (f"{motion.label}: accepted: dual-arm reach, right hand to {np.round(r.translation, 3).tolist()}, "
                    f"left hand to {np.round(l_.translation, 3).tolist()} (world)")
            if motion.follow:
                self.get_logger().info(line, throttle_duration_sec=self._p["warn_throttle_s"])
            else:
                self.get_logger().info(line)
            self._queue(("start", motion))
            return
        self.get_logger().info(
            f"{motion.label}: accepted: {motion.arm}-arm trajectory, {len(ref.times)} points over "
            f"{ref.duration:.2f} s; collision avoidance {'on' if motion.params.collision_avoidance else 'OFF'}, "
            f"COM compensation {'on' if motion.params.com_compensation else 'OFF'}"
            f"{'; ' + motion.note if motion.note else ''}")
        self._queue(("start", motion))

    def _finish(self, motion: Motion, code: int, message: str) -> None:
        """Record the outcome of ``motion`` (once) and log it. Caller holds ``self._cond``."""
        if motion.code is not None:
            return
        motion.code, motion.message, motion.ended = int(code), message, time.monotonic()
        self.last_motion = motion
        name = RESULT_NAMES.get(code, str(code))
        self.counters.last_result = f"{motion.label}: {name}"
        self.counters.successes += int(code == R.SUCCESS)
        progress = motion.last.progress if motion.last is not None else 0.0
        line = f"{motion.label}: {name} at progress {progress:.2f}: {message} [{motion.figures()}]"
        if code in (R.SUCCESS, R.PREEMPTED, R.CANCELED):
            self.get_logger().info(line)
        else:
            self.get_logger().warning(line)
        motion.finished.set()

    # ------------------------------------------------------------ solver thread
    def _run_solver(self) -> None:
        while True:
            with self._cond:
                while not self._stop and not self._pending and not (
                        self._mode in (RUN, SETTLE) and self._ready is None):
                    self._cond.wait(0.1)
                if self._stop:
                    return
                commands, self._pending = self._pending, []
            try:
                for cmd in commands:
                    self._apply(cmd)
                self._maybe_step()
            except Exception as exc:  # an executor error must not kill the loop: stop and hold
                self.get_logger().error(f"executor step failed: {type(exc).__name__}: {exc}\n{traceback.format_exc()}")
                with self._cond:
                    motion = self._motion
                    if motion is not None:
                        self._finish(motion, R.ABORTED, f"executor error: {type(exc).__name__}: {exc}")
                    self._motion = None
                    self._ready = None
                    self._mode = HOLD if self._last_q is not None else IDLE
                    self._hold_since = time.monotonic()
                    self._starting = False

    def _apply(self, cmd: tuple) -> None:
        kind = cmd[0]
        if kind == "map":
            self.executor_.set_environment(cmd[1])
        elif kind == "start":
            self._start(cmd[1])
        elif kind == "hold":
            _, motion, code, message = cmd
            with self._cond:
                if motion is not None and motion is not self._motion:
                    # finished or replaced already (no-op), or not started yet: it never will be
                    self._finish(motion, code, message + " before it started")
                    return
                current = self._motion
                self._motion = None
                if current is not None:
                    self._finish(current, code, message + "; holding the last command")
                if self._mode == IDLE or self._last_q is None:
                    return
                self._mode = SETTLE
                self._settle_until = time.monotonic() + self._p["hold_settle_s"]
            self._stop_engine()

    def _stop_engine(self) -> None:
        """Stop the running solver smoothly (solver thread): the executor's hold mode, or the
        dual-arm controller braking on its path (``dual_arm_brake_s``)."""
        if self._engine == "dual":
            self.dual_.brake(self._p["dual_arm_brake_s"])
            with self._cond:
                self._dual_targets = None        # stopped short: the same targets again must restart
        else:
            self.executor_.hold()

    def _start(self, motion: Motion) -> None:
        """Start ``motion`` from the last commanded configuration (measured when none)."""
        if motion.dual:
            self._start_dual(motion)
            return
        with self._cond:
            if motion.code is not None:
                return  # canceled while queued
            previous = self._motion
            if self._last_q is not None and self._mode != IDLE:
                q0, source = self._last_q.copy(), "the last command"
            else:
                q0, source = None, "/joint_states"
            self._ready = None       # a step of the previous motion not yet sent is dropped
            self._motion = None
            self._starting = True    # ticks republish the last command meanwhile (not an overrun)
        if q0 is None:
            q0 = self._measured_start(motion)
            if q0 is None:
                return
        try:
            self.executor_.start(q0, motion.reference.spline, motion.arm, motion.params)
        except Exception as exc:
            with self._cond:
                self._starting = False
                self._finish(motion, R.ABORTED, f"executor refused the reference: {type(exc).__name__}: {exc}")
                if previous is not None:
                    self._finish(previous, R.PREEMPTED, f"replaced by {motion.label}, which failed to start")
                    self._stop_engine()
                    self._mode = SETTLE
                    self._settle_until = time.monotonic() + self._p["hold_settle_s"]
            return
        with self._cond:
            if previous is not None:
                self._finish(previous, R.PREEMPTED, f"preempted by {motion.label} (blended from the last command)")
            motion.started = time.monotonic()
            self._motion = motion
            self._mode = RUN
            self._starting = False
            self._engine = "executor"
        self.get_logger().info(f"{motion.label}: started from {source}")

    def _measured_start(self, motion: Motion) -> np.ndarray | None:
        """The configuration of the current /joint_states to start ``motion`` from; without
        one, ``motion`` ends with NO_JOINT_STATES and the result is None."""
        joints, reason = self.current_joints()
        if joints is None:
            with self._cond:
                self._starting = False
                self._finish(motion, R.NO_JOINT_STATES, reason)
            return None
        with self._fk_lock:
            return self.robot.config(joints, self.robot.base_on_feet(joints))

    def _start_dual(self, motion: Motion) -> None:
        """Plan ``motion``'s target pair on the dual-arm controller from the last command
        (measured when none). Infeasible: ``INVALID_GOAL`` with the controller's reason, the
        controller's previous state restored and a running motion stopped smoothly (hold)."""
        with self._cond:
            if motion.code is not None:
                return  # canceled while queued
            previous = self._motion
            q0 = self._last_q.copy() if self._last_q is not None and self._mode != IDLE else None
            mode_before = self._mode
            self._ready = None
            self._motion = None
            self._starting = True
        source = "the last command"
        if q0 is None:
            q0 = self._measured_start(motion)
            if q0 is None:
                return
            source = "/joint_states"
        ctl = self.dual_
        saved = ctl.save_state()
        t0 = time.perf_counter()
        try:
            if self._engine != "dual" or not np.array_equal(ctl.q, q0):
                ctl.reset(q0)
            if motion.sequential is not None:
                plan = ctl.start_sequential(*motion.sequential)
                feasible, reason = True, ""          # infeasible random pairs are skipped, not refused
            else:
                r, l_ = motion.targets
                plan = ctl.set_targets(r.translation, r.rotation, l_.translation, l_.rotation)
                feasible, reason = plan.feasible, plan.reason
        except Exception as exc:   # e.g. a target the controller refuses as a value
            plan, feasible, reason = None, False, f"{type(exc).__name__}: {exc}"
        plan_s = time.perf_counter() - t0
        if not feasible:
            ctl.restore_state(saved)
            with self._cond:
                self._starting = False
                self.counters.dual_arm_infeasible += 1
                self.counters.last_infeasible = f"{motion.label}: {reason}"
                self._finish(motion, R.INVALID_GOAL, f"infeasible target pair: {reason}; holding")
                if previous is not None:
                    self._finish(previous, R.PREEMPTED, f"preempted by {motion.label}, which is infeasible; "
                                                        "stopping smoothly and holding")
                    self._mode = SETTLE
                    self._settle_until = time.monotonic() + self._p["hold_settle_s"]
                elif mode_before in (RUN, SETTLE):
                    self._mode = mode_before
            if previous is not None:
                self._stop_engine()
            return
        with self._cond:
            if previous is not None:
                self._finish(previous, R.PREEMPTED, f"preempted by {motion.label} (from the last command)")
            motion.started = time.monotonic()
            motion.note = (f"{plan.n_steps} steps, CoM candidate {plan.com.label!r}, chest target "
                           f"{np.round(plan.chest_target, 3).tolist()} rad, planned in {plan_s * 1e3:.0f} ms")
            self._motion = motion
            self._mode = RUN
            self._starting = False
            self._engine = "dual"
            self._dual_targets = motion.targets
        if motion.sequential is not None:
            motion.note = f"{motion.sequential[0]} random target pairs (seed {motion.sequential[1]})"
        log = self.get_logger()
        if motion.follow:
            log.info(f"{motion.label}: started from {source}: {motion.note}",
                     throttle_duration_sec=self._p["warn_throttle_s"])
        else:
            log.info(f"{motion.label}: started from {source}: {motion.note}")

    def _dual_step(self, motion: Motion | None) -> DualStepResult:
        """One step of the dual-arm controller and its metrics (solver thread)."""
        t0 = time.perf_counter()
        st: ControlStep = self.dual_.step(measure=False)
        solve_s = time.perf_counter() - t0
        m, d = self.robot.model, self._dual_data
        pin.framesForwardKinematics(m, d, st.q)
        com = pin.centerOfMass(m, d, st.q, False)
        com_err = float(np.linalg.norm(com[:2] - st.com_ref[:2]))
        e_p, e_r = 0.0, 0.0
        hands = st.hands
        if hands is not None:
            for side, p, Rt in (("right", hands.p_right, hands.R_right), ("left", hands.p_left, hands.R_left)):
                M = d.oMf[self._fid_hand[side]]
                e_p = max(e_p, float(np.linalg.norm(M.translation - p)))
                e_r = max(e_r, float(np.linalg.norm(pin.log3(M.rotation.T @ Rt))))
        elif motion is not None and motion.last is not None:
            e_p, e_r = motion.last.hand_error_m, motion.last.hand_error_rad
        t = (motion.steps + 1) * self.period_s if motion is not None else 0.0
        metrics = exec_msgs.DualArmMetrics(t, float(st.s), solve_s, com_err, e_p, e_r, ik_time_s=solve_s)
        final = bool(st.done) and self.dual_.sequential_remaining == 0
        return DualStepResult(st.q, st.joints, metrics, final, bool(st.ok), st.reason, bool(st.done))

    def _maybe_step(self) -> None:
        with self._cond:
            if self._mode not in (RUN, SETTLE) or self._ready is not None:
                return
            engine = self._engine
            settled = time.monotonic() >= self._settle_until if engine == "executor" else not self.dual_.busy
            if self._mode == SETTLE and settled:
                self._mode = HOLD
                self._hold_since = time.monotonic()
                return
            motion = self._motion
        if motion is not None:
            age = self.joint_states_age()
            if age > self._p["joint_states_abort_s"]:
                self._apply(("hold", motion, R.ABORTED, f"stopped: /joint_states stale ({age:.2f} s > "
                                                        f"{self._p['joint_states_abort_s']:g} s)"))
                return
        result = self.executor_.step() if engine == "executor" else self._dual_step(motion)
        with self._cond:
            if motion is self._motion and self._mode in (RUN, SETTLE):
                self._ready = (motion, result)

    # ------------------------------------------------------------ tick thread
    def _run_ticks(self) -> None:
        period = self.period_s
        t0 = time.monotonic()
        k = 0
        while not self._stop:
            deadline = t0 + k * period
            delay = deadline - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            try:
                self._tick()
            except Exception as exc:  # e.g. publishing while Ctrl-C shuts the context down
                if self._stop or not self.context.ok():
                    return
                self.get_logger().error(f"tick failed: {type(exc).__name__}: {exc}",
                                        throttle_duration_sec=self._p["warn_throttle_s"])
            k += 1
            behind = time.monotonic() - (t0 + k * period)
            if behind > period:  # more than a whole period late: skip the missed deadlines
                skipped = int(behind // period)
                k += skipped
                self._missed_ticks += skipped
                self._window["missed"] += skipped

    def _tick(self) -> None:
        publish_metrics = None
        with self._cond:
            self._ticks += 1
            mode = self._mode
            if mode == IDLE:
                return
            if mode == HOLD and self._p["hold_timeout_s"] > 0 and \
                    time.monotonic() - self._hold_since > self._p["hold_timeout_s"]:
                self._mode = IDLE
                self.get_logger().info(f"held the last command for {self._p['hold_timeout_s']:g} s: stop publishing "
                                       "joint_command")
                return
            ready, self._ready = self._ready, None
            if ready is not None:
                motion, res = ready
                self._last_q, self._last_joints = res.q, res.joints
                m = res.metrics
                self._step_times.append(m.solve_time_s)
                self._window["steps"] += 1
                self._window["max_step_s"] = max(self._window["max_step_s"], m.solve_time_s)
                if motion is not None:
                    motion.steps += 1
                    motion.last = m
                    motion.max_com_error_m = max(motion.max_com_error_m, m.com_error_m)
                    motion.min_distance_m = min(motion.min_distance_m, m.min_distance_m)
                    if self._published % self._p["metrics_decimation"] == 0:
                        publish_metrics = (m, motion.overruns)
                    if isinstance(res, DualStepResult) and motion.sequential is not None:
                        if res.pair_done:
                            motion.pairs_reached += int(res.ok)
                            motion.pairs_skipped += int(not res.ok)
                        if res.done and motion is self._motion:
                            n = motion.sequential[0]
                            self._finish(motion, R.SUCCESS, f"{n} random target pairs: {motion.pairs_reached} "
                                                            f"reached, {motion.pairs_skipped} infeasible (skipped)")
                            self._motion = None
                            self._mode = HOLD
                            self._hold_since = time.monotonic()
                    elif isinstance(res, DualStepResult) and motion is self._motion and (res.done or not res.ok):
                        if res.ok:
                            self._finish(motion, R.SUCCESS, "both hands at their targets")
                        else:
                            self._finish(motion, R.ABORTED, f"dual-arm step failed: {res.reason}; holding")
                            self._dual_targets = None
                        self._motion = None
                        self._mode = HOLD
                        self._hold_since = time.monotonic()
                    elif res.done and motion is self._motion:
                        self._finish(motion, R.SUCCESS, "trajectory executed, hand converged"
                                     if m.hand_error_m <= self.params.converge_position_m
                                     else "trajectory executed (settle timeout before the hand converged)")
                        self._motion = None
                        self._mode = HOLD
                        self._hold_since = time.monotonic()
                elif self._published % self._p["metrics_decimation"] == 0:
                    publish_metrics = (m, 0)
            elif mode in (RUN, SETTLE) and self._last_q is not None and not self._starting:
                # the step for this deadline is not ready (it overran): hold the last safe command
                self._overruns += 1
                self._window["overruns"] += 1
                if self._motion is not None:
                    self._motion.overruns += 1
            joints = self._last_joints
            self._published += 1
            self._cond.notify_all()
        if joints is None:
            return
        stamp = self.get_clock().now().to_msg()
        self.command_pub.publish(msgs.fill_joint_state(self._command, joints, stamp=stamp))
        if publish_metrics is not None:
            self.metrics_pub.publish(exec_msgs.executor_metrics(publish_metrics[0], publish_metrics[1], stamp,
                                                                self.map_frame))

    # ------------------------------------------------------------ diagnostics
    @staticmethod
    def _new_window() -> dict[str, float]:
        return {"start": time.monotonic(), "steps": 0, "overruns": 0, "missed": 0, "max_step_s": 0.0,
                "ticks_at_start": 0}

    def diagnostic_statuses(self) -> list:
        name, c, p = self.get_name(), self.counters, self._p
        now = time.monotonic()
        with self._cond:
            mode, motion = self._mode, self._motion
            w, self._window = self._window, self._new_window()
            self._window["ticks_at_start"] = self._ticks
            ticks = self._ticks - w["ticks_at_start"]
            last_joints = None if self._last_joints is None else self._last_joints.copy()
            step_times = np.array(self._step_times) if self._step_times else np.zeros(0)
        statuses = []
        values = {"state": mode, "motion": motion.label if motion is not None else "",
                  "progress": motion.last.progress if motion is not None and motion.last is not None else 0.0,
                  "goals": c.goals, "goals_rejected": c.goals_rejected, "trajectories": c.trajectories,
                  "trajectories_rejected": c.trajectories_rejected, "successes": c.successes,
                  "last_result": c.last_result, "last_rejection": c.last_rejection,
                  "engine": self._engine, "dual_arm_follow": bool(p["dual_arm_follow"]),
                  "dual_arm_goals": c.dual_arm_goals, "dual_arm_infeasible": c.dual_arm_infeasible,
                  "last_infeasible": c.last_infeasible, "target_messages": c.target_messages,
                  "target_messages_rejected": c.target_messages_rejected,
                  "target_messages_ignored": c.target_messages_ignored,
                  "target_messages_unchanged": c.target_messages_unchanged}
        level, message = msgs.LEVEL_OK, f"{mode}" + (f": {motion.label}" if motion is not None else "")
        if c.last_rejection:
            message += f"; last rejection: {c.last_rejection}"
        statuses.append(msgs.diagnostic_status(f"{name}: execution", level, message, values, self.hardware_id))

        elapsed = max(now - w["start"], 1e-9)
        steps = w["steps"]
        overrun_frac = w["overruns"] / max(steps + w["overruns"], 1)
        values = {"nominal_rate_hz": 1.0 / self.period_s, "tick_rate_hz": ticks / elapsed,
                  "steps_recent": steps, "overruns_recent": w["overruns"], "overruns_total": self._overruns,
                  "missed_deadlines_recent": w["missed"], "missed_deadlines_total": self._missed_ticks,
                  "max_step_ms": w["max_step_s"] * 1e3,
                  "step_p50_ms": float(np.percentile(step_times, 50)) * 1e3 if len(step_times) else 0.0,
                  "step_p99_ms": float(np.percentile(step_times, 99)) * 1e3 if len(step_times) else 0.0,
                  "published_total": self._published}
        level, message = msgs.LEVEL_OK, f"{ticks / elapsed:.0f} Hz ticks, {steps} steps, {w['overruns']} overruns"
        if steps and overrun_frac > p["max_overrun_fraction"]:
            level = msgs.LEVEL_WARN
            message = (f"{w['overruns']} of {steps + w['overruns']} periods overran (last command held), "
                       f"max step {w['max_step_s'] * 1e3:.1f} ms")
        statuses.append(msgs.diagnostic_status(f"{name}: loop", level, message, values, self.hardware_id))

        joints, reason = self.current_joints()
        with self._state_lock:
            jt = self._joint_time
        tracking = float(np.max(np.abs(joints - last_joints))) if joints is not None and last_joints is not None \
            else 0.0
        values = {"joint_states_age_s": now - jt if math.isfinite(jt) else "never", "map_source": c.map_source,
                  "map_voxels": c.map_voxels, "map_build_time_ms": c.map_build_s * 1e3,
                  "maps_received": c.maps_received, "maps_rejected": c.maps_rejected,
                  "tracking_error_rad": tracking}
        level, message = (msgs.LEVEL_OK, "joint_states current") if joints is not None else (msgs.LEVEL_WARN, reason)
        statuses.append(msgs.diagnostic_status(f"{name}: inputs", level, message, values, self.hardware_id))
        return statuses

    def _publish_diagnostics(self) -> None:
        self.diagnostics_pub.publish(msgs.diagnostic_array(self.diagnostic_statuses(),
                                                           self.get_clock().now().to_msg()))

    # ------------------------------------------------------------ parameters / shutdown
    def _apply_parameters(self, params) -> None:
        for prm in params:
            self._p[prm.name] = prm.value

    def destroy_node(self) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify_all()
            if self._motion is not None:
                self._finish(self._motion, R.ABORTED, "the reach_executor node is shutting down")
        for t in (self._tick_thread, self._solver_thread):
            t.join(timeout=2.0)
        try:
            self.action_server.destroy()
        except Exception:
            pass
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """Run the node until Ctrl-C / SIGTERM (exit 0); a configuration error exits 2."""
    sys.setswitchinterval(0.0005)  # let the tick thread take the GIL within its period
    return run_node(ReachExecutorNode, NODE_NAME, args, executor=lambda: MultiThreadedExecutor(num_threads=6))


if __name__ == "__main__":
    sys.exit(main())
