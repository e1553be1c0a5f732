"""Execution messages <-> numpy: the ``reach_executor``'s side of ``io/msgs.py``.

* :func:`reference_from_trajectory` validates a ``trajectory_msgs/JointTrajectory`` (from
  ``/reach_trajectory`` or an ``ExecuteReach`` goal) and turns it into the executor's
  reference: the 30 joints in model order as a monotone cubic (PCHIP, zero end slopes)
  ``SplineTrajectory`` (``geometry/trajectory.py``, the planner's interpolant class) through
  the points at their ``time_from_start``, shifted so that the first point is at ``t = 0``.
  Simplification: the paper's executor evaluates the planner's spline itself; here the
  reference is rebuilt from the transmitted samples (every ``output_period_s``, 50 ms, and
  every waypoint), so between samples it differs from the planner's curve by the
  interpolation error of a cubic through its samples. Every defect is an
  :class:`ExecInputError` whose message says what is wrong (empty or single point, unknown
  / missing / duplicate joints, point sizes, NaN/inf, times not strictly increasing,
  positions outside the joint limits at a point or between points -- the latter checked
  exactly on the interpolant, :meth:`SplineTrajectory.check_limits`, as the planner's
  trajectory is built to satisfy).
* :func:`arm_motion` / :func:`resolve_arm`: which arm a trajectory moves (its hand is the
  task of level 3), and the check that a requested arm is the one the trajectory moves.
* (``msgs.model_joints`` gives the 30 measured joints of a ``/joint_states`` message in model order)
  (the same rules as ``reach_planner``'s start posture).
* :func:`executor_metrics` / :func:`execute_feedback` fill ``ExecutorMetrics`` and the
  ``ExecuteReach`` feedback from the executor's ``StepMetrics`` (or a
  :class:`DualArmMetrics`, the same fields for a step of the dual-arm controller).
* :func:`hand_target` / :func:`goal_hand_targets` / :func:`array_hand_targets` validate the
  two hand targets of a ``MODE_DUAL_ARM`` goal (``PoseStamped`` each) or of a
  ``/dual_arm/targets`` ``geometry_msgs/PoseArray`` (exactly 2 poses, right then left):
  frame ``world`` or ``base_link`` (explicit), finite values, unit quaternion;
  :func:`targets_in_world` maps base_link targets through the waist pose.
* :func:`look_goal_at` builds the ``Look`` goal that looks at world points with the executor's
  balanced whole-body gaze (e.g. ``PlanReach``'s ``unobserved_points``: where the plan needs to
  see); :func:`gaze_points` validates such a goal's ``gaze_points`` on the executor's side.

Imports message types only (never ``rclpy.node``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Pose, PoseArray, PoseStamped
from humanoid_reach_interfaces.action import ExecuteReach, Look
from humanoid_reach_interfaces.msg import ExecutorMetrics
from trajectory_msgs.msg import JointTrajectory

from humanoid_reach_ros.codes import ARM_AUTO, ARM_LEFT, ARM_NAMES, ARM_RIGHT  # noqa: F401 (re-exported)
from humanoid_reach_ros.codes import ErrorCode, RequestError as ExecInputError
from humanoid_reach_ros.execution.engines import DualArmMetrics  # noqa: F401 (re-exported)
from humanoid_reach_ros.execution.requests import (ArmMotion, HandTarget, arm_motion, needs_waist,  # noqa: F401
                                                   resolve_arm, targets_in_world)
from humanoid_reach_ros.io import msgs
from humanoid_reach_ros.io.msgs import error_code
from humanoid_reach_ros.geometry.trajectory import SplineTrajectory
from humanoid_reach_ros.robot.model import RobotModel



@dataclass(frozen=True, eq=False)
class Reference:
    """A validated trajectory: model-order ``positions`` (K, 30) at ``times`` (K,) from 0,
    the monotone cubic through them, and the input's original first time [s]."""

    times: np.ndarray
    positions: np.ndarray
    spline: SplineTrajectory
    time_offset_s: float

    @property
    def duration(self) -> float:
        return float(self.times[-1])


def reference_from_trajectory(msg: JointTrajectory, robot: RobotModel, limit_tol_rad: float = 1e-6,
                              what: str = "trajectory") -> Reference:
    """Validate ``msg`` and build the executor reference (see the module docstring).

    Raises :class:`ExecInputError` (``INVALID_REQUEST``) with a message naming the defect.
    Velocities / accelerations, when present, are checked for NaN/inf but not used: the
    monotone cubic through the positions is the reference (at rest at both ends). The joint
    limits (``limit_tol_rad``) are checked at the points, then on that cubic between them,
    exactly (extrema of each segment from the roots of its derivative, not by sampling).
    """
    bad = ErrorCode.INVALID_REQUEST
    names = list(msg.joint_names)
    if not msg.points:
        raise ExecInputError(bad, f"{what} is empty (no points)")
    if len(msg.points) < 2:
        raise ExecInputError(bad, f"{what} has a single point; a reference needs at least 2 points")
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise ExecInputError(bad, f"{what} has duplicate joint names: {', '.join(dup)}")
    unknown = [n for n in names if n not in robot.joint_index]
    if unknown:
        raise ExecInputError(bad, f"{what} has unknown joint(s): {', '.join(unknown)}")
    missing = [n for n in robot.joint_names if n not in set(names)]
    if missing:
        raise ExecInputError(bad, f"{what} lacks {len(missing)} of the {robot.n_joints} robot joints "
                                  f"(all are required): {', '.join(missing)}")
    try:
        arrays = msgs.parse_joint_trajectory(msg)
    except ValueError as exc:
        raise ExecInputError(bad, f"{what}: {exc}") from None
    t = arrays.times
    for field, a in (("time_from_start", t), ("positions", arrays.positions), ("velocities", arrays.velocities),
                     ("accelerations", arrays.accelerations)):
        if a is not None and not np.all(np.isfinite(a)):
            raise ExecInputError(bad, f"{what} has NaN/inf in {field}")
    if t[0] < 0.0:
        raise ExecInputError(bad, f"{what} starts at a negative time_from_start ({t[0]:g} s)")
    steps = np.diff(t)
    if np.any(steps <= 0.0):
        i = int(np.argmax(steps <= 0.0))
        raise ExecInputError(bad, f"{what} times are not strictly increasing: point {i + 1} at {t[i + 1]:g} s "
                                  f"follows point {i} at {t[i]:g} s")
    order = np.array([names.index(n) for n in robot.joint_names])
    pos = arrays.positions[:, order]
    low = pos < robot.lower - limit_tol_rad
    high = pos > robot.upper + limit_tol_rad
    if np.any(low | high):
        j = int(np.argmax(np.any(low | high, axis=0)))
        k = int(np.argmax(low[:, j] | high[:, j]))
        raise ExecInputError(bad, f"{what} leaves the joint limits: {robot.joint_names[j]} = {pos[k, j]:.4f} rad "
                                  f"at point {k} (limits [{robot.lower[j]:.4f}, {robot.upper[j]:.4f}])")
    pos = np.clip(pos, robot.lower, robot.upper)
    times = t - t[0]
    spline = SplineTrajectory(pos, times)
    # Between the points: PCHIP keeps each segment within its end points, so with the points
    # clipped this cannot fire; it is the guard that the followed curve, not just its samples,
    # is within the limits (the clamped spline it replaced overshot its waypoints by up to
    # 0.28 rad on 20 plant reaches, and left the limits by 0.012 rad at point 99 of one)
    v = spline.check_limits(robot.lower, robot.upper, limit_tol_rad)
    if v is not None:
        raise ExecInputError(bad, f"{what} leaves the joint limits between points {v.segment} and "
                                  f"{v.segment + 1}: {robot.joint_names[v.joint]} reaches {v.value:.4f} rad "
                                  f"at t = {v.time:.3f} s (limits [{robot.lower[v.joint]:.4f}, "
                                  f"{robot.upper[v.joint]:.4f}])")
    return Reference(times, pos, spline, float(t[0]))


# ---------------------------------------------------------------- metrics and feedback
def _finite_or(v: float, default: float) -> float:
    return float(v) if math.isfinite(v) else default


def executor_metrics(m, overruns: int, stamp: Time | None = None, frame_id: str = "world",
                     slack_tol: float = 1e-6) -> ExecutorMetrics:
    """``ExecutorMetrics`` of one executor step (``StepMetrics`` ``m``).

    ``active_levels`` lists the priority levels (1..n) solved exactly: those whose
    least-squares slack is at most ``slack_tol`` (all ``m.active_levels`` levels when the
    step reports no slacks). A minimum distance of ``inf`` (no map) is sent as ``inf``.
    """
    out = ExecutorMetrics(header=msgs.header(frame_id, stamp))
    out.time_from_start_s = float(m.t)
    out.progress = float(min(max(m.progress, 0.0), 1.0))
    out.step_time_s = float(m.solve_time_s)
    out.distance_query_time_s = float(m.distance_time_s)
    out.ik_time_s = float(m.ik_time_s)
    out.overruns = int(overruns)
    out.spheres_in_bound = int(m.spheres_in_bound)
    out.active_constraints = int(m.active_constraints)
    slack = tuple(m.level_slack)
    if slack:
        levels = [i + 1 for i, s in enumerate(slack[:int(m.active_levels)] or slack) if abs(s) <= slack_tol]
    else:
        levels = list(range(1, int(m.active_levels) + 1))
    out.active_levels = bytes(levels)
    out.com_error_m = float(m.com_error_m)
    out.min_distance_m = float(m.min_distance_m)
    out.hand_error_m = float(m.hand_error_m)
    out.hand_error_rad = float(m.hand_error_rad)
    return out


def execute_feedback(m) -> ExecuteReach.Feedback:
    """``ExecuteReach`` feedback from a ``StepMetrics``."""
    return ExecuteReach.Feedback(progress=float(min(max(m.progress, 0.0), 1.0)), time_from_start_s=float(m.t),
                                 min_distance_m=float(m.min_distance_m), com_error_m=float(m.com_error_m),
                                 hand_error_m=float(m.hand_error_m))


def result_message(code: int, message: str, summary: dict[str, float] | None = None) -> ExecuteReach.Result:
    """``ExecuteReach.Result`` with ``code``/``message`` and the figures of ``summary``
    (keys: the result's fields; missing ones stay 0 / false / empty)."""
    r = ExecuteReach.Result(success=code == ErrorCode.SUCCESS, error_code=error_code(code), message=message)
    for key, value in (summary or {}).items():
        if key in ("steps", "overruns"):
            setattr(r, key, int(value))
        elif key == "hand_in_contact":
            setattr(r, key, bool(value))
        elif key == "contact_with":
            setattr(r, key, str(value))
        else:
            setattr(r, key, float(value))
    return r


def result_names() -> dict[int, str]:
    """``ExecuteReach.Result`` code -> constant name."""
    R = ExecuteReach.Result
    return {getattr(R, n): n for n in dir(R)
            if n.isupper() and not n.startswith("_") and isinstance(getattr(R, n), int)}



# ---------------------------------------------------------------- dual-arm targets
TARGET_FRAMES = ("world", "base_link")     # explicit: an empty header is a goal whose targets were never set


def hand_target(pose: Pose, frame_id: str, what: str) -> HandTarget:
    """Validate one hand target: frame 'world' or 'base_link' (explicit: "" is refused, an
    unset header means the targets were never filled in), finite position and
    orientation, unit quaternion (|norm - 1| <= 1e-3, then normalised). ``ExecInputError``
    (``INVALID_REQUEST``) naming ``what`` and the defect otherwise."""
    bad = ErrorCode.INVALID_REQUEST
    if frame_id not in TARGET_FRAMES:
        raise ExecInputError(bad, f"{what} frame_id {frame_id!r} is unknown; use 'world' or 'base_link'")
    try:
        se3 = msgs.se3_from_pose(pose)
    except ValueError as exc:
        msg = str(exc).replace("non-finite values", "NaN/inf values")
        raise ExecInputError(bad, f"{what}: {msg}") from None
    return HandTarget(frame_id, se3)


def goal_hand_targets(right: PoseStamped, left: PoseStamped) -> tuple[HandTarget, HandTarget]:
    """The (right, left) targets of a ``MODE_DUAL_ARM`` goal (see :func:`hand_target`)."""
    return (hand_target(right.pose, right.header.frame_id, "right_hand_target"),
            hand_target(left.pose, left.header.frame_id, "left_hand_target"))


def array_hand_targets(msg: PoseArray) -> tuple[HandTarget, HandTarget]:
    """The (right, left) targets of a ``/dual_arm/targets`` ``PoseArray``: exactly 2 poses,
    right then left, both in ``msg.header.frame_id``."""
    if len(msg.poses) != 2:
        raise ExecInputError(ErrorCode.INVALID_REQUEST,
                             f"PoseArray has {len(msg.poses)} poses; exactly 2 are required (right hand, left hand)")
    frame = msg.header.frame_id
    return (hand_target(msg.poses[0], frame, "poses[0] (right hand)"),
            hand_target(msg.poses[1], frame, "poses[1] (left hand)"))


# ---------------------------------------------------------------- look at points
def _point_rows(points) -> np.ndarray:
    """(K, 3) float array of ``geometry_msgs/Point`` s or of an array-like (K, 3) / (3,)."""
    pts = list(points) if not isinstance(points, np.ndarray) else points
    if len(pts) and all(hasattr(p, "x") for p in pts):
        return np.array([[p.x, p.y, p.z] for p in pts], dtype=float)
    return np.asarray(pts, dtype=float)


def look_goal_at(points, dwell_s: float = 0.0) -> Look.Goal:
    """The ``/look`` goal that looks at each of ``points`` in turn -- (K, 3) [m, world] as an
    array-like or ``geometry_msgs/Point`` s, e.g. ``PlanReach``'s ``unobserved_points`` -- with the
    executor's balanced whole-body gaze (chest and head aimed, feet and exact COG held;
    ``control/gaze.py``), holding each ``dwell_s`` (<= 0: the executor's ``scan_dwell_s``).
    ``yaw_rad`` / ``pitch_rad`` stay empty, as the action requires. ``ValueError`` for no points,
    a shape other than (K, 3) (one point (3,) is taken as K = 1) or NaN/inf: the executor would
    refuse such a goal (``INVALID_REQUEST``)."""
    P = _point_rows(points)
    if P.ndim == 1 and P.shape == (3,):
        P = P[None]
    if P.ndim != 2 or P.shape[1] != 3 or len(P) == 0:
        raise ValueError(f"gaze points must have shape (K, 3) with K >= 1, got {P.shape}")
    if not np.all(np.isfinite(P)):
        raise ValueError("gaze points contain NaN or inf")
    if not math.isfinite(dwell_s):
        raise ValueError(f"dwell_s must be finite, got {dwell_s}")
    return Look.Goal(gaze_points=[Point(x=float(x), y=float(y), z=float(z)) for x, y, z in P],
                     dwell_s=float(dwell_s))


def gaze_points(goal: Look.Goal) -> np.ndarray | None:
    """The ``gaze_points`` (K, 3) [m, world] of a ``Look`` goal, None when it has none (a head
    pose goal). ``ExecInputError`` (``INVALID_REQUEST``) when it also gives ``yaw_rad`` /
    ``pitch_rad`` (one or the other) or a point has NaN/inf coordinates, naming the point."""
    if not goal.gaze_points:
        return None
    bad = ErrorCode.INVALID_REQUEST
    if len(goal.yaw_rad) or len(goal.pitch_rad):
        raise ExecInputError(bad, f"the goal gives {len(goal.gaze_points)} gaze_points and {len(goal.yaw_rad)} yaw / "
                                  f"{len(goal.pitch_rad)} pitch angles: give gaze_points or yaw_rad/pitch_rad, "
                                  "not both")
    P = _point_rows(goal.gaze_points)
    finite = np.all(np.isfinite(P), axis=1)
    if not finite.all():
        k = int(np.argmin(finite))
        raise ExecInputError(bad, f"gaze point {k} has NaN/inf coordinates ({P[k].tolist()})")
    return P
