"""The execution layer's configuration: the parameters ``reach_executor`` declares (defaults
match config/reach_executor.yaml, checked by test_reach_executor_node) and the typed
configurations made of their values: :class:`ExecutionConfig` (what the execution manager and
the requests read at run time), ``ExecutorParams`` (the whole-body executor) and
``SupervisorConfig`` (the loop)."""
from __future__ import annotations

import dataclasses
from typing import Any

from humanoid_reach_ros.control.executor import ExecutorParams
from humanoid_reach_ros.execution.supervisor import SupervisorConfig
from humanoid_reach_ros.params import ParamSpec
from humanoid_reach_ros.robot.spec import DEFAULT_ROBOT

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
    "velocity_scale": ParamSpec(0.5, "fraction of the URDF joint velocity limits a step may use (headroom for the "
                                "joints' own tracking: commands at the limit are tracked with a lag that differs "
                                "joint by joint, seen as feet/COG drift)", (0.01, 1.0)),
    "max_joint_acceleration_rad_s2": ParamSpec(10.0, "bound of every commanded joint "
                                               "acceleration (between 5 ms commands) [rad/s^2]: a real robot's "
                                               "servos follow no more, and the body's momentum tips it; the joint "
                                               "limits are approached on a braking curve, the dampers brake at "
                                               "damper_deceleration_mps2; 0 = none", (0.0, 10000.0)),
    "damper_deceleration_mps2": ParamSpec(_D.damper_deceleration_mps2, "with the acceleration bound, a damper "
                                          "pair's approach speed is kept on the curve from which it stops at "
                                          "security_distance_m decelerating at this [m/s^2] (capped by damper_xi)",
                                          (0.01, 1000.0)),
    "com_recenter_speed_mps": ParamSpec(_D.com_recenter_speed_mps, "mean speed of the COG target back to its "
                                        "nominal point after a start away from it [m/s]", (0.001, 1.0)),
    "blend_min_s": ParamSpec(_D.blend_min_s, "shortest blend of a reference that starts away from the last "
                             "command [s]", (0.0, 10.0)),
    "settle_timeout_s": ParamSpec(_D.settle_timeout_s, "a motion ends at most this long after its reference "
                                  "[s] even if the hand has not converged", (0.0, 60.0)),
    "solver": ParamSpec(_D.solver, "prioritized IK solver", constraints=f"one of {', '.join(SOLVERS)}"),
    "active_set": ParamSpec(_D.active_set, "solve steps with many damper rows by the exact cascade of dual "
                            "active-set QPs (DAQP, control/active_set.py); false: saturation passes + OSQP"),
    "active_set_min_rows": ParamSpec(_D.active_set_min_rows, "damper rows from which a step uses the active-set "
                                     "cascade (fewer: the closed-form saturation)", (0, 100000)),
}

NODE_PARAMETERS: dict[str, ParamSpec] = {
    "robot_config": ParamSpec(DEFAULT_ROBOT, "robot: a name (config/robots/<name>/robot.yaml) or the path of "
                                          "a robot description (relative to config/, or absolute)"),
    "resolution_m": ParamSpec(0.02, "voxel size of the environment map [m] (sphere radius = resolution / 2)",
                              (0.001, 1.0)),
    "safety_margin_m": ParamSpec(0.0, "extra radius added to every environment sphere [m]", (0.0, 0.5)),
    "scene_file": ParamSpec("scenes/plant.yaml", "scene whose voxels are the map until /voxel_map arrives, "
                            "relative to config/ or absolute; empty = no map until /voxel_map"),
    "scene_exclude_groups": ParamSpec(["valve"], "scene primitive groups left out of the scene-file map "
                                      "(the object to be grasped)"),
    "map_frame": ParamSpec("world", "frame of /voxel_map and of the metrics"),
    "target_exclusion_radius_m": ParamSpec(0.15, "voxels of a /voxel_map within this distance of the motion's "
                                           "start or final hand position are the object reached or left, and "
                                           "left out of the collision map [m]; 0 = keep all (as reach_planner)",
                                           (0.0, 1.0)),
    "joint_states_timeout_s": ParamSpec(0.5, "/joint_states older than this [s]: a start is refused (NO_JOINT_STATES)",
                                        (0.001, 3600.0), read_only=False),
    "joint_states_abort_s": ParamSpec(2.0, "/joint_states older than this [s] while a motion runs: it is aborted "
                                      "(ABORTED) and the last command held", (0.001, 3600.0), read_only=False),
    "hold_settle_s": ParamSpec(0.25, "after a cancel or abort the executor keeps solving in hold mode this long [s]",
                               (0.0, 10.0)),
    "hold_timeout_s": ParamSpec(1.0, "republish the held command this long after a motion [s], then stop "
                                "publishing (the joint driver holds its last command; the loop sleeps until the "
                                "next motion); 0 = republish until the next motion", (0.0, 1e6)),
    "resume_tolerance_rad": ParamSpec(0.05, "an idle executor (after hold_timeout_s) starts the next motion from "
                                      "its last command when every measured joint is within this of it [rad] (the "
                                      "driver holds that command; a physics plant's servos hold the joints a little "
                                      "off it under gravity, and starting from the measured ones sank the robot by "
                                      "as much each motion); 0 = always from /joint_states", (0.0, 1.0)),
    "lookahead_steps": ParamSpec(4, "the solver computes this many steps before their deadlines (1: only the "
                                 "next one); each one more absorbs a longer stall of the loop's threads at the "
                                 "cost of one period more before a stop or a new map reaches the command",
                                 (1, 8)),
    "rt_priority": ParamSpec(80, "SCHED_FIFO priority of the control loop's tick thread (solver: one below) where "
                             "the OS allows it; 0 = normal scheduling"),
    "lock_memory": ParamSpec(True, "mlockall the control loop process (with rt_priority > 0) where the OS allows it"),
    "loop_start_timeout_s": ParamSpec(120.0, "the control loop process must be ready within this long [s]",
                                      (1.0, 3600.0)),
    "metrics_decimation": ParamSpec(1, "publish /executor/metrics every this many published steps (>= 1)"),
    "feedback_period_s": ParamSpec(0.05, "period of the action feedback [s]", (0.005, 10.0)),
    "diagnostics_period_s": ParamSpec(1.0, "period of /diagnostics [s]", (0.05, 60.0)),
    "max_overrun_fraction": ParamSpec(0.02, "diagnostics WARN when more than this fraction of the steps of the "
                                      "last window overran", (0.0, 1.0)),
    "scan_poses_deg": ParamSpec([0.0, 35.0, 0.0, 45.0, -35.0, 45.0, -30.0, 30.0, -25.0, 5.0, 0.0, 10.0, 25.0, 5.0,
                                 30.0, 30.0, 35.0, 45.0, 0.0, 25.0],
                                "head scan of the look action with no poses: yaw, pitch pairs [deg] (pitch > 0 looks "
                                "down; the pitch-45 poses see the space in front of the chest the arms and the trunk "
                                "move through), in an order that sweeps the head from one side to the other (210 deg "
                                "of head travel; 375 in the order of the same poses before); the last one looks at "
                                "the workspace in front"),
    "marker_look_deg": ParamSpec([2.0, 40.0], "where the head looks for the target's marker: yaw, pitch [deg] "
                                 "(reach_operator --marker turns it there when /target_pose is stale and no marker "
                                 "position is known; the plant's valve from half-sitting, the demo's aim)"),
    "look_clearance_m": ParamSpec(0.002, "a gaze's reference keeps this much more than security_distance_m to the "
                                  "map and between the robot's shapes; it stops short where it would not [m]",
                                  (0.0, 0.5)),
    "look_avoids_unobserved": ParamSpec(False, "a gaze's reference keeps the body out of the space no sensor has "
                                        "seen (voxel_mapper's frontier, /voxel_map/unobserved, once one came with a "
                                        "measured /voxel_map): it stops short where the body would enter it. Off by "
                                        "default: on, the scan's chest turns stop at 0-60 % and the space beside the "
                                        "hips stays unseen, so make demo's reach ends UNOBSERVED_SPACE after its "
                                        "looks (docs/operator.md, known gap); false: the measured voxels only"),
    "look_distance_m": ParamSpec(1.0, "a robot without a neck looks in a direction (the scan pattern, a look at "
                                 "yaw/pitch) by a whole-body gaze at the point this far from its camera [m]",
                                 (0.1, 20.0)),
    "scan_dwell_s": ParamSpec(1.0, "the look action holds each head pose this long by default [s]", (0.0, 60.0)),
    "scan_surroundings_looks": ParamSpec(8, "after its head poses the scan gazes at the space around the robot's own "
                                         "body (control/gaze.py cover_gazes: the points 6 and 12 cm from its shapes "
                                         "at the reference posture, as many as these gazes see): the space a "
                                         "balanced reach moves the arms and trunk through first, which the head "
                                         "poses do not see; at most this many gazes, 0 = none", (0, 20)),
    "head_speed_rad_s": ParamSpec(1.0, "peak head joint speed of the look action [rad/s]", (0.01, 10.0)),
    "warn_throttle_s": ParamSpec(1.0, "minimum interval between repeated warnings [s]", (0.0, 3600.0)),
    # ---- dual-arm mode (MODE_DUAL_ARM goals, /dual_arm/targets)
    "dual_arm_regression": ParamSpec("", "torso regression model stem (.npz + .yaml), relative to config/ or "
                                     "absolute; empty: the robot description's torso_regression"),
    "dual_arm_workspace": ParamSpec("", "workspace / eq. 6 YAML of the dual-arm controller, relative to config/ "
                                    "or absolute; empty: the robot description's dual_arm_workspace"),
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


def executor_params(values: dict[str, Any]) -> ExecutorParams:
    """``ExecutorParams`` from the declared parameters (validated)."""
    known = {f.name for f in dataclasses.fields(ExecutorParams)}
    return ExecutorParams(**{k: values[k] for k in EXECUTOR_PARAMETERS if k in known}).validate()


def supervisor_config(values: dict[str, Any]) -> SupervisorConfig:
    return SupervisorConfig(period_s=values["period_s"], hold_settle_s=values["hold_settle_s"],
                            hold_timeout_s=values["hold_timeout_s"], dual_arm_brake_s=values["dual_arm_brake_s"],
                            lookahead_steps=values["lookahead_steps"],
                            resume_tolerance_rad=values["resume_tolerance_rad"])


@dataclasses.dataclass(frozen=True)
class ExecutionConfig:
    """The values the execution manager and :class:`~humanoid_reach_ros.execution.requests.
    ExecutionRequests` read while they run, typed (defaults: ``PARAMETERS``). The node makes it
    from its parameters (:meth:`from_values`) and again on a run-time change
    (:meth:`changed`): readers see one consistent set."""

    robot_config: str = NODE_PARAMETERS["robot_config"].default
    resolution_m: float = NODE_PARAMETERS["resolution_m"].default
    safety_margin_m: float = NODE_PARAMETERS["safety_margin_m"].default
    scene_exclude_groups: tuple[str, ...] = tuple(NODE_PARAMETERS["scene_exclude_groups"].default)
    map_frame: str = NODE_PARAMETERS["map_frame"].default
    target_exclusion_radius_m: float = NODE_PARAMETERS["target_exclusion_radius_m"].default
    joint_states_timeout_s: float = NODE_PARAMETERS["joint_states_timeout_s"].default
    joint_states_abort_s: float = NODE_PARAMETERS["joint_states_abort_s"].default
    feedback_period_s: float = NODE_PARAMETERS["feedback_period_s"].default
    max_overrun_fraction: float = NODE_PARAMETERS["max_overrun_fraction"].default
    scan_poses_deg: tuple[float, ...] = tuple(NODE_PARAMETERS["scan_poses_deg"].default)
    look_clearance_m: float = NODE_PARAMETERS["look_clearance_m"].default
    look_avoids_unobserved: bool = NODE_PARAMETERS["look_avoids_unobserved"].default
    look_distance_m: float = NODE_PARAMETERS["look_distance_m"].default
    scan_dwell_s: float = NODE_PARAMETERS["scan_dwell_s"].default
    scan_surroundings_looks: int = NODE_PARAMETERS["scan_surroundings_looks"].default
    head_speed_rad_s: float = NODE_PARAMETERS["head_speed_rad_s"].default
    warn_throttle_s: float = NODE_PARAMETERS["warn_throttle_s"].default
    dual_arm_regression: str = NODE_PARAMETERS["dual_arm_regression"].default
    dual_arm_workspace: str = NODE_PARAMETERS["dual_arm_workspace"].default
    dual_arm_max_speed_mps: float = NODE_PARAMETERS["dual_arm_max_speed_mps"].default
    dual_arm_follow: bool = NODE_PARAMETERS["dual_arm_follow"].default
    dual_arm_retarget_threshold_m: float = NODE_PARAMETERS["dual_arm_retarget_threshold_m"].default
    dual_arm_retarget_threshold_rad: float = NODE_PARAMETERS["dual_arm_retarget_threshold_rad"].default
    dual_arm_sequential_count: int = NODE_PARAMETERS["dual_arm_sequential_count"].default
    dual_arm_sequential_seed: int = NODE_PARAMETERS["dual_arm_sequential_seed"].default
    #: the whole-body executor's parameters of a new motion (``EXECUTOR_PARAMETERS``)
    executor: ExecutorParams = dataclasses.field(default_factory=lambda: _executor_defaults())

    @classmethod
    def from_values(cls, values: dict[str, Any]) -> "ExecutionConfig":
        """From parameter values (every key of ``PARAMETERS`` that is a field; others ignored)."""
        return cls().changed(values)

    def changed(self, values: dict[str, Any]) -> "ExecutionConfig":
        """A copy with ``values`` (name -> value) that are fields applied; lists become tuples."""
        names = {f.name for f in dataclasses.fields(self)} - {"executor"}
        known = {f.name for f in dataclasses.fields(ExecutorParams)}
        executor = {k: v for k, v in values.items() if k in EXECUTOR_PARAMETERS and k in known}
        return dataclasses.replace(
            self, **{k: tuple(v) if isinstance(v, list) else v for k, v in values.items() if k in names},
            executor=dataclasses.replace(self.executor, **executor).validate() if executor else self.executor)


def _executor_defaults() -> ExecutorParams:
    return executor_params({k: spec.default for k, spec in EXECUTOR_PARAMETERS.items()})
