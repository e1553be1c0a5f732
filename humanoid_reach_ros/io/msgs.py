"""numpy / pinocchio <-> ROS 2 message conversions (the package's one conversions module).

Imports message types only (never ``rclpy.node``), so algorithm code and tests can
use it without a ROS graph. Conventions: stamps are ``builtin_interfaces/Time``;
float seconds go through ``time_from_seconds`` / ``seconds_from_time``; poses are
``pin.SE3``; arrays are float64 numpy arrays.

Sections: time, joint states, poses, diagnostics. Later issues add more here.
"""
from __future__ import annotations

import array
import math
from dataclasses import dataclass
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
import pinocchio as pin
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Pose, PoseStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import Header

NS_PER_S = 1_000_000_000


# ---------------------------------------------------------------- time
def time_from_nanoseconds(ns: int) -> Time:
    """``builtin_interfaces/Time`` from integer nanoseconds (e.g. ``clock.now().nanoseconds``)."""
    ns = int(ns)
    if ns < 0:
        raise ValueError(f"negative time {ns} ns cannot be a ROS stamp")
    sec, nanosec = divmod(ns, NS_PER_S)
    return Time(sec=sec, nanosec=nanosec)


def time_from_seconds(t: float) -> Time:
    """``builtin_interfaces/Time`` from float seconds (rounded to the nanosecond)."""
    if not math.isfinite(t):
        raise ValueError(f"non-finite time {t}")
    return time_from_nanoseconds(round(t * NS_PER_S))


def seconds_from_time(stamp: Time) -> float:
    """Float seconds of a ``builtin_interfaces/Time``."""
    return stamp.sec + stamp.nanosec * 1e-9


def nanoseconds_from_time(stamp: Time) -> int:
    return stamp.sec * NS_PER_S + stamp.nanosec


def header(frame_id: str, stamp: Time | None = None) -> Header:
    return Header(frame_id=frame_id, stamp=stamp if stamp is not None else Time())


# ---------------------------------------------------------------- arrays
def double_array(values: Any) -> array.array:
    """``array.array('d')`` from any float sequence: the fast type for ``float64[]`` fields."""
    return array.array("d", np.ascontiguousarray(values, dtype=np.float64).ravel().tobytes())


# ---------------------------------------------------------------- joint states
@dataclass(frozen=True)
class JointStateArrays:
    """The arrays of a ``sensor_msgs/JointState``; empty optional arrays become ``None``.

    Not validated: lengths may disagree and values may be non-finite exactly as sent.
    Commands go through ``JointSimulator.validate_command`` (the one validator of
    name/position/velocity arrays).
    """

    names: tuple[str, ...]
    positions: np.ndarray
    velocities: np.ndarray | None
    efforts: np.ndarray | None
    stamp_s: float


def parse_joint_state(msg: JointState) -> JointStateArrays:
    """numpy arrays out of a ``sensor_msgs/JointState``."""
    vel = np.asarray(msg.velocity, dtype=float)
    eff = np.asarray(msg.effort, dtype=float)
    return JointStateArrays(
        names=tuple(msg.name),
        positions=np.asarray(msg.position, dtype=float),
        velocities=vel if vel.size else None,
        efforts=eff if eff.size else None,
        stamp_s=seconds_from_time(msg.header.stamp),
    )


def joint_state(
    names: Sequence[str],
    positions: Sequence[float],
    velocities: Sequence[float] | None = None,
    efforts: Sequence[float] | None = None,
    stamp: Time | None = None,
    frame_id: str = "",
) -> JointState:
    """Build a ``sensor_msgs/JointState``; raises ``ValueError`` on inconsistent lengths
    or non-finite values (a message we publish must be one we would accept)."""
    names = [str(n) for n in names]
    arrays = {"position": positions, "velocity": velocities, "effort": efforts}
    msg = JointState(header=header(frame_id, stamp), name=names)
    for field, values in arrays.items():
        if values is None:
            continue
        a = np.asarray(values, dtype=float).ravel()
        if a.size != len(names):
            raise ValueError(f"JointState {field} has {a.size} entries for {len(names)} names")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"JointState {field} has non-finite entries")
        setattr(msg, field, double_array(a))
    return msg


def fill_joint_state(
    msg: JointState,
    positions: np.ndarray,
    velocities: np.ndarray | None = None,
    stamp: Time | None = None,
) -> JointState:
    """Refresh a pre-built ``JointState`` in place (the per-tick path of a publisher:
    names and frame stay, arrays are copied in without per-element checks)."""
    msg.position = double_array(positions)
    if velocities is not None:
        msg.velocity = double_array(velocities)
    if stamp is not None:
        msg.header.stamp = stamp
    return msg


# ---------------------------------------------------------------- poses
def pose_from_se3(pose: pin.SE3) -> Pose:
    """``geometry_msgs/Pose`` from ``pin.SE3`` (quaternion x, y, z, w)."""
    x, y, z, qx, qy, qz, qw = (float(v) for v in pin.SE3ToXYZQUAT(pose))
    msg = Pose()
    msg.position.x, msg.position.y, msg.position.z = x, y, z
    msg.orientation.x, msg.orientation.y, msg.orientation.z, msg.orientation.w = qx, qy, qz, qw
    return msg


def pose_stamped(pose: pin.SE3, frame_id: str, stamp: Time | None = None) -> PoseStamped:
    """``geometry_msgs/PoseStamped`` of ``pose`` expressed in ``frame_id``."""
    return PoseStamped(header=header(frame_id, stamp), pose=pose_from_se3(pose))


def se3_from_pose(msg: Pose | PoseStamped) -> pin.SE3:
    """``pin.SE3`` from a ``Pose`` (or the pose of a ``PoseStamped``).

    Raises ``ValueError`` for non-finite values or a quaternion far from unit
    length (|norm - 1| > 1e-3); near-unit quaternions are normalised.
    """
    p = msg.pose if isinstance(msg, PoseStamped) else msg
    xyz = np.array([p.position.x, p.position.y, p.position.z])
    quat = np.array([p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w])
    if not (np.all(np.isfinite(xyz)) and np.all(np.isfinite(quat))):
        raise ValueError("pose has non-finite values")
    norm = float(np.linalg.norm(quat))
    if abs(norm - 1.0) > 1e-3:
        raise ValueError(f"pose quaternion is not unit length (norm {norm:.6f})")
    return pin.XYZQUATToSE3(np.concatenate([xyz, quat / norm]))


# ---------------------------------------------------------------- diagnostics
LEVEL_OK, LEVEL_WARN, LEVEL_ERROR, LEVEL_STALE = 0, 1, 2, 3
_LEVEL_NAMES = {LEVEL_OK: "OK", LEVEL_WARN: "WARN", LEVEL_ERROR: "ERROR", LEVEL_STALE: "STALE"}


def _value_text(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


def diagnostic_status(
    name: str,
    level: int,
    message: str,
    values: Mapping[str, Any] | None = None,
    hardware_id: str = "",
) -> DiagnosticStatus:
    """``diagnostic_msgs/DiagnosticStatus``; ``level`` is one of ``LEVEL_*``; values become
    key/value strings (floats with 6 significant digits, bools as true/false)."""
    if level not in _LEVEL_NAMES:
        raise ValueError(f"unknown diagnostic level {level}")
    return DiagnosticStatus(
        level=bytes([level]),
        name=name,
        message=message,
        hardware_id=hardware_id,
        values=[KeyValue(key=str(k), value=_value_text(v)) for k, v in (values or {}).items()],
    )


def diagnostic_array(statuses: Iterable[DiagnosticStatus], stamp: Time | None = None) -> DiagnosticArray:
    return DiagnosticArray(header=header("", stamp), status=list(statuses))


def diagnostic_level(status: DiagnosticStatus) -> int:
    """Integer level of a status (the field is a one-byte ``bytes``)."""
    lv = status.level
    return lv[0] if isinstance(lv, (bytes, bytearray)) else int(lv)


def diagnostic_values(status: DiagnosticStatus) -> dict[str, str]:
    """Key/value pairs of a status as a dict."""
    return {kv.key: kv.value for kv in status.values}
