"""numpy / pinocchio <-> ROS 2 message conversions (the package's one conversions module).

Imports message types only (never ``rclpy.node``), so algorithm code and tests can
use it without a ROS graph. Conventions: stamps are ``builtin_interfaces/Time``;
float seconds go through ``time_from_seconds`` / ``seconds_from_time``; poses are
``pin.SE3``; arrays are float64 numpy arrays.

Sections: time, joint states, images, poses, diagnostics; then planning: durations, point
clouds, joint trajectories, PlanReach requests, planning statistics, markers.
"""
from __future__ import annotations

import array
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Iterable, Mapping, Sequence

import numpy as np
import pinocchio as pin
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, Pose, PoseStamped
from sensor_msgs.msg import CameraInfo, Image, JointState
from std_msgs.msg import Header

from humanoid_reach_ros.geometry.camera import CameraCalibration

if TYPE_CHECKING:  # pragma: no cover
    from humanoid_reach_ros.robot.model import RobotModel

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


def model_joints(msg: JointState, robot: RobotModel) -> tuple[np.ndarray | None, str]:
    """The robot's joint angles (``robot.n_joints``, model order) of a ``sensor_msgs/JointState``,
    or ``None`` and why not. The one parser of measured joint states (``/joint_states``).

    Policy for names: a ``/joint_states`` message may carry joints of other devices
    (grippers, a pan-tilt unit, another robot's ``joint_state_publisher``), so **names the
    model does not know are ignored**; but **every model joint is required**, finite: a
    message missing one (or sending NaN/inf for it) is refused, naming the missing ones, as
    is one with mismatched name/position arrays or a repeated name. Velocities and efforts
    are not read. (Commands are stricter: ``/joint_command`` and trajectories refuse unknown
    names, ``JointSimulator.validate_command`` and ``exec_msgs``.)
    """
    names, pos = list(msg.name), np.asarray(msg.position, dtype=float).ravel()
    if len(names) != pos.size:
        return None, f"joint state has {len(names)} names but {pos.size} positions"
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        return None, f"joint state has duplicate joint names: {', '.join(dup)}"
    joints = np.full(robot.n_joints, np.nan)
    index = robot.joint_index
    for name, v in zip(names, pos):
        i = index.get(name)
        if i is not None:
            joints[i] = v
    if not np.all(np.isfinite(joints)):
        known = set(names)
        missing = [n for n in robot.joint_names if n not in known]
        nonfinite = [n for n in robot.joint_names if n in known and not math.isfinite(joints[index[n]])]
        parts = [f"is missing {len(missing)} of the {robot.n_joints} model joints: {_some(missing)}"] if missing else []
        parts += [f"has NaN/inf for {_some(nonfinite)}"] if nonfinite else []
        return None, f"joint state {'; '.join(parts)}"
    return joints, ""


def _some(names: Sequence[str], most: int = 6) -> str:
    return ", ".join(names[:most]) + (f" ... ({len(names) - most} more)" if len(names) > most else "")


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


# ---------------------------------------------------------------- images
#: 8-bit encodings :func:`gray_from_image` accepts: channels and the conversion to grey
#: (cv2 colour-conversion code name; None: already grey)
IMAGE_ENCODINGS: dict[str, tuple[int, str | None]] = {
    "mono8": (1, None), "8UC1": (1, None), "rgb8": (3, "COLOR_RGB2GRAY"), "bgr8": (3, "COLOR_BGR2GRAY"),
    "rgba8": (4, "COLOR_RGBA2GRAY"), "bgra8": (4, "COLOR_BGRA2GRAY"),
}


def byte_array(data) -> np.ndarray:
    """A uint8 array over a message's byte sequence (``array.array``, ``bytes``: no copy)."""
    if isinstance(data, (np.ndarray, list, tuple)):
        return np.asarray(data, dtype=np.uint8)
    return np.frombuffer(data, dtype=np.uint8)


def check_image(msg: Image) -> tuple[int, int, int, int, str | None]:
    """Height, width, step, channels and OpenCV conversion of a ``sensor_msgs/Image`` from its
    header fields alone (no pixel is read); ``ValueError`` as :func:`gray_from_image`."""
    enc = msg.encoding
    if enc not in IMAGE_ENCODINGS:
        raise ValueError(f"unsupported image encoding {enc!r}; accepted: {', '.join(IMAGE_ENCODINGS)}")
    ch, code = IMAGE_ENCODINGS[enc]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    if h <= 0 or w <= 0:
        raise ValueError(f"empty image ({w} x {h})")
    if step < w * ch:
        raise ValueError(f"image step {step} < width {w} * {ch} channel(s)")
    if len(msg.data) != h * step:
        raise ValueError(f"image data has {len(msg.data)} bytes, expected height {h} * step {step} = {h * step}")
    return h, w, step, ch, code


def gray_from_image(msg: Image) -> np.ndarray:
    """8-bit grey (H, W) array of a ``sensor_msgs/Image`` (the package's one image decoder).

    Accepts :data:`IMAGE_ENCODINGS` (mono8 / 8UC1 as they are; rgb8, bgr8, rgba8, bgra8 through
    OpenCV's ``Y = 0.299 R + 0.587 G + 0.114 B``); rows may be padded (``step > width *
    channels``). ``ValueError`` for another encoding, an empty image, a step shorter than a row
    or a data size other than ``height * step``."""
    h, w, step, ch, code = check_image(msg)
    img = byte_array(msg.data).reshape(h, step)[:, :w * ch].reshape(h, w, ch)
    if code is None:
        return np.ascontiguousarray(img[:, :, 0])
    import cv2  # here: the decoder's only user of OpenCV, kept off the import of this module

    return cv2.cvtColor(np.ascontiguousarray(img), getattr(cv2, code))


def image_msg(img: np.ndarray, encoding: str, frame_id: str, stamp: Time | None = None) -> Image:
    """``sensor_msgs/Image`` of an (H, W) or (H, W, C) uint8 array (rows unpadded)."""
    h, w = img.shape[:2]
    channels = 1 if img.ndim == 2 else img.shape[2]
    return Image(header=header(frame_id, stamp), height=h, width=w, encoding=encoding, is_bigendian=0,
                 step=w * channels, data=np.ascontiguousarray(img, dtype=np.uint8).tobytes())


# ---------------------------------------------------------------- cameras
def camera_calibration(msg: CameraInfo) -> CameraCalibration:
    """A ``sensor_msgs/CameraInfo`` as a validated :class:`~humanoid_reach_ros.geometry.camera.
    CameraCalibration` (``ValueError`` with the reason for an unusable one)."""
    return CameraCalibration(int(msg.width), int(msg.height), np.asarray(msg.k, float), np.asarray(msg.d, float),
                             np.asarray(msg.r, float), np.asarray(msg.p, float))


def camera_info(cal: CameraCalibration, frame_id: str, stamp: Time | None = None) -> CameraInfo:
    """The ``sensor_msgs/CameraInfo`` of ``cal`` (plumb_bob for 5 coefficients, else
    rational_polynomial)."""
    return CameraInfo(header=header(frame_id, stamp), height=cal.height, width=cal.width,
                      distortion_model="plumb_bob" if cal.D.size <= 5 else "rational_polynomial",
                      d=cal.D.tolist(), k=cal.K.ravel().tolist(), r=cal.R.ravel().tolist(),
                      p=cal.P.ravel().tolist())



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


# ================================================================ planning (reach_planner)
# Point clouds, joint trajectories, PlanReach requests, planning statistics and the
# planning markers. Message types are imported here, not at the top, so the sections
# above stay usable on their own.
from builtin_interfaces.msg import Duration  # noqa: E402
from humanoid_reach_interfaces.msg import ErrorCode as ErrorCodeMsg, PlanningStatistics  # noqa: E402
from humanoid_reach_interfaces.srv import PlanReach  # noqa: E402
from sensor_msgs.msg import PointCloud2, PointField  # noqa: E402
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint  # noqa: E402
from visualization_msgs.msg import Marker, MarkerArray  # noqa: E402

from humanoid_reach_ros.planning.reach import check_plan_values  # noqa: E402
from humanoid_reach_ros.codes import ARM_REQUESTS, ErrorCode, RequestError  # noqa: E402
from humanoid_reach_ros.planning.wgr import WorkspaceGoalRegion  # noqa: E402


def error_code(code: int) -> ErrorCodeMsg:
    """The ``msg/ErrorCode`` every interface embeds (``codes.ErrorCode`` value ``code``)."""
    return ErrorCodeMsg(val=int(code))


# ---------------------------------------------------------------- durations
def duration_from_seconds(t: float) -> Duration:
    """``builtin_interfaces/Duration`` from float seconds (>= 0, rounded to the nanosecond)."""
    if not math.isfinite(t) or t < 0.0:
        raise ValueError(f"duration must be finite and >= 0, got {t}")
    sec, nanosec = divmod(round(t * NS_PER_S), NS_PER_S)
    return Duration(sec=int(sec), nanosec=int(nanosec))


def seconds_from_duration(d: Duration) -> float:
    return d.sec + d.nanosec * 1e-9


# ---------------------------------------------------------------- point clouds
_POINT_FIELD_DTYPES = {
    PointField.INT8: "i1", PointField.UINT8: "u1", PointField.INT16: "i2", PointField.UINT16: "u2",
    PointField.INT32: "i4", PointField.UINT32: "u4", PointField.FLOAT32: "f4", PointField.FLOAT64: "f8",
}


@dataclass(frozen=True)
class CloudPoints:
    """The x, y, z of a ``sensor_msgs/PointCloud2``: finite points (N, 3) float64 and how
    many points were dropped for a NaN/inf coordinate."""

    points: np.ndarray
    dropped_nonfinite: int
    frame_id: str
    stamp_s: float


def check_cloud(msg: PointCloud2) -> np.dtype:
    """The record dtype of a ``PointCloud2``'s x, y, z (float fields at their offsets, one
    record per ``point_step``), from its layout alone (no point is read).

    Raises ``ValueError`` for a malformed cloud: a missing or non-float ``x``/``y``/``z``
    field, a field outside ``point_step``, ``row_step < width * point_step``, or a data
    size other than ``height * row_step``.
    """
    fields = {f.name: f for f in msg.fields}
    missing = [n for n in "xyz" if n not in fields]
    if missing:
        raise ValueError(f"PointCloud2 has no {', '.join(missing)} field(s) (fields: "
                         f"{[f.name for f in msg.fields]})")
    step, width, height = int(msg.point_step), int(msg.width), int(msg.height)
    if step <= 0 and width * height > 0:
        raise ValueError(f"PointCloud2 point_step must be positive, got {step}")
    order = ">" if msg.is_bigendian else "<"
    formats, offsets = [], []
    for n in "xyz":
        f = fields[n]
        if f.datatype not in (PointField.FLOAT32, PointField.FLOAT64):
            raise ValueError(f"PointCloud2 field {n!r} must be FLOAT32 or FLOAT64, got datatype {f.datatype}")
        if f.count not in (0, 1):
            raise ValueError(f"PointCloud2 field {n!r} has count {f.count}, expected 1")
        size = 4 if f.datatype == PointField.FLOAT32 else 8
        if f.offset + size > step:
            raise ValueError(f"PointCloud2 field {n!r} (offset {f.offset}, {size} bytes) lies outside "
                             f"point_step {step}")
        formats.append(order + _POINT_FIELD_DTYPES[f.datatype])
        offsets.append(int(f.offset))
    if int(msg.row_step) < width * step:
        raise ValueError(f"PointCloud2 row_step {msg.row_step} < width {width} * point_step {step}")
    if len(msg.data) != height * int(msg.row_step):
        raise ValueError(f"PointCloud2 data has {len(msg.data)} bytes, expected height {height} * row_step "
                         f"{msg.row_step} = {height * int(msg.row_step)}")
    return np.dtype({"names": ["x", "y", "z"], "formats": formats, "offsets": offsets, "itemsize": max(step, 1)})


def points_from_cloud(msg: PointCloud2) -> CloudPoints:
    """Finite x, y, z points of a ``PointCloud2`` (any layout with float x/y/z fields).

    Raises ``ValueError`` for a malformed cloud (:func:`check_cloud`). Points with a
    non-finite coordinate are dropped and counted (``dropped_nonfinite``), as in an
    unorganised cloud.
    """
    dtype = check_cloud(msg)
    stamp_s = seconds_from_time(msg.header.stamp)
    width, height, step = int(msg.width), int(msg.height), int(msg.point_step)
    if width * height == 0:
        return CloudPoints(np.empty((0, 3)), 0, msg.header.frame_id, stamp_s)
    rows = byte_array(msg.data).reshape(height, int(msg.row_step))[:, :width * step]
    rec = np.ascontiguousarray(rows).view(dtype).reshape(-1)
    pts = np.stack([rec["x"], rec["y"], rec["z"]], axis=1).astype(np.float64)
    finite = np.all(np.isfinite(pts), axis=1)
    return CloudPoints(pts[finite], int((~finite).sum()), msg.header.frame_id, stamp_s)


def cloud_from_points(points: np.ndarray, frame_id: str, stamp: Time | None = None) -> PointCloud2:
    """Unorganised ``PointCloud2`` (height 1) of float32 x, y, z (point_step 12)."""
    pts = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    n = len(pts)
    return PointCloud2(
        header=header(frame_id, stamp), height=1, width=n,
        fields=[PointField(name=c, offset=4 * i, datatype=PointField.FLOAT32, count=1) for i, c in enumerate("xyz")],
        is_bigendian=False, point_step=12, row_step=12 * n, data=pts.astype("<f4").tobytes(), is_dense=True,
    )


# ---------------------------------------------------------------- joint trajectories
def joint_trajectory(
    names: Sequence[str],
    times: np.ndarray,
    positions: np.ndarray,
    velocities: np.ndarray | None = None,
    accelerations: np.ndarray | None = None,
    frame_id: str = "world",
    stamp: Time | None = None,
) -> JointTrajectory:
    """``trajectory_msgs/JointTrajectory`` of K points over ``names``.

    ``times`` (K,) [s] from the start, strictly increasing and >= 0; ``positions``,
    ``velocities``, ``accelerations`` (K, n). Raises ``ValueError`` on shapes, non-finite
    values or non-increasing times (a message we publish must be one we would accept).
    """
    names = [str(n) for n in names]
    t = np.asarray(times, dtype=float).reshape(-1)
    k, n = len(t), len(names)
    if len(set(names)) != n:
        raise ValueError("JointTrajectory joint names must be unique")
    if not np.all(np.isfinite(t)) or (k and t[0] < 0.0) or np.any(np.diff(t) <= 0.0):
        raise ValueError("JointTrajectory times must be finite, >= 0 and strictly increasing")
    arrays = {}
    for field_name, a in (("positions", positions), ("velocities", velocities), ("accelerations", accelerations)):
        if a is None:
            continue
        a = np.asarray(a, dtype=float)
        if a.shape != (k, n):
            raise ValueError(f"JointTrajectory {field_name} has shape {a.shape}, expected ({k}, {n})")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"JointTrajectory {field_name} has non-finite values")
        arrays[field_name] = a
    if "positions" not in arrays:
        raise ValueError("JointTrajectory needs positions")
    points = []
    for i in range(k):
        pt = JointTrajectoryPoint(time_from_start=duration_from_seconds(float(t[i])))
        for field_name, a in arrays.items():
            setattr(pt, field_name, double_array(a[i]))
        points.append(pt)
    return JointTrajectory(header=header(frame_id, stamp), joint_names=names, points=points)


@dataclass(frozen=True)
class TrajectoryArrays:
    """The arrays of a ``JointTrajectory``: names, times (K,), positions/velocities/
    accelerations (K, n) (``None`` when a point lacks them)."""

    names: tuple[str, ...]
    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray | None
    accelerations: np.ndarray | None


def parse_joint_trajectory(msg: JointTrajectory) -> TrajectoryArrays:
    """numpy arrays of a ``JointTrajectory``; ``ValueError`` when point sizes disagree."""
    names = tuple(msg.joint_names)
    n = len(names)
    times = np.array([seconds_from_duration(p.time_from_start) for p in msg.points], dtype=float)

    def stack(field_name: str, required: bool) -> np.ndarray | None:
        rows = [np.asarray(getattr(p, field_name), dtype=float) for p in msg.points]
        if not required and all(r.size == 0 for r in rows):
            return None
        if any(r.size != n for r in rows):
            raise ValueError(f"JointTrajectory {field_name} sizes disagree with {n} joint names")
        return np.array(rows).reshape(len(rows), n)

    return TrajectoryArrays(names, times, stack("positions", True), stack("velocities", False),
                            stack("accelerations", False))


# ---------------------------------------------------------------- PlanReach requests
REQUEST_FRAMES = ("", "world", "base_link")
ARM_NAMES = {code: name for name, code in ARM_REQUESTS.items()}   # PlanReach.Request.ARM_* -> name


@dataclass(frozen=True)
class ReachRequest:
    """A validated PlanReach request in numpy terms (``None`` = use the node's default).

    ``region`` is in the world frame; when ``use_marker_target`` it still holds the
    request's own target, to be replaced by :func:`region_with_target`."""

    region: WorkspaceGoalRegion
    arm: str
    goal_count: int | None
    planner: str | None
    time_budget_s: float | None
    seed: int | None
    use_marker_target: bool
    execute: bool
    home: bool = False          # plan back to the rest posture (region ignored: None)


def _pose_arrays(p: Pose) -> np.ndarray:
    return np.array([p.position.x, p.position.y, p.position.z,
                     p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w], dtype=float)


def target_in_world(target: PoseStamped, waist: pin.SE3 | None, what: str = "region.target") -> pin.SE3:
    """World pose of a target ``PoseStamped`` in ``world`` ("" = world) or ``base_link``
    (``waist`` = the current waist pose in world). ``RequestError`` with UNKNOWN_FRAME for
    any other frame, INVALID_REQUEST for a non-finite pose or non-unit quaternion,
    NO_JOINT_STATES when a base_link target comes without a waist pose."""
    E = ErrorCode
    frame = target.header.frame_id
    if frame not in REQUEST_FRAMES:
        raise RequestError(E.UNKNOWN_FRAME, f"{what} frame_id {frame!r} is unknown; use 'world' (or '') or "
                                            "'base_link'")
    try:
        pose = se3_from_pose(target)
    except ValueError as exc:
        raise RequestError(E.INVALID_REQUEST, f"{what}: {exc}") from None
    if frame == "base_link":
        if waist is None:
            raise RequestError(E.NO_JOINT_STATES, f"{what} is in base_link but there is no recent /joint_states "
                                                  "to place the waist")
        pose = waist * pose
    return pose


def reach_request(req: PlanReach.Request, waist: pin.SE3 | None = None) -> ReachRequest:
    """Validate and convert a ``PlanReach`` request (``RequestError`` with the response code).

    Checks, in order: NaN/inf anywhere -> INVALID_REQUEST; arm not 0/1/2 -> INVALID_REQUEST; the
    values the planner's one validator checks (``planning.reach.check_plan_values``: planner,
    goal_count, time budget) -> INVALID_REQUEST;
    target frame not world/""/base_link ->
    UNKNOWN_FRAME (skipped with ``use_marker_target``: the marker's pose replaces it);
    lower > upper or rotation bounds beyond +-pi by more than ``wgr.ANGLE_TOL`` -> INVALID_BOUNDS
    (bounds within it are clamped to +-pi).
    ``waist`` is the current waist pose in world, needed for a ``base_link`` target.
    """
    E = ErrorCode
    lower = np.asarray(req.region.lower, dtype=float)
    upper = np.asarray(req.region.upper, dtype=float)
    values = {"region.target.pose": _pose_arrays(req.region.target.pose), "region.lower": lower,
              "region.upper": upper, "time_budget_s": np.array([req.time_budget_s])}
    bad = [k for k, v in values.items() if not np.all(np.isfinite(v))]
    if bad:
        raise RequestError(E.INVALID_REQUEST, f"non-finite values (NaN/inf) in {', '.join(bad)}")
    if req.arm not in ARM_NAMES:
        raise RequestError(E.INVALID_REQUEST, f"arm {req.arm} is unknown; use 0 (auto), 1 (right) or 2 (left)")
    planner = req.planner.strip()
    check_plan_values(ARM_NAMES[req.arm], planner, int(req.goal_count), float(req.time_budget_s))
    if req.home:   # the way back to the rest posture: no region, no marker
        region = None
    elif req.use_marker_target:
        target = pin.SE3.Identity()
    else:
        target = target_in_world(req.region.target, waist)
    if not req.home:
        try:
            region = WorkspaceGoalRegion.from_pose(target, lower, upper)
        except ValueError as exc:
            raise RequestError(E.INVALID_BOUNDS, str(exc)) from None
    return ReachRequest(
        region=region, arm=ARM_NAMES[req.arm], goal_count=int(req.goal_count) or None,
        planner=planner or None, time_budget_s=float(req.time_budget_s) or None,
        seed=int(req.seed) if req.seed >= 0 else None,
        use_marker_target=bool(req.use_marker_target) and not req.home, execute=bool(req.execute),
        home=bool(req.home),
    )


def points_list(points) -> list:
    """``geometry_msgs/Point`` list of points (K, 3) [m] (e.g. PlanReach's ``unobserved_points``)."""
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    return [Point(x=float(x), y=float(y), z=float(z)) for x, y, z in P]


def points_array(points) -> np.ndarray:
    """(K, 3) array of ``geometry_msgs/Point`` s (ValueError on NaN/inf)."""
    P = np.array([[p.x, p.y, p.z] for p in points], dtype=float).reshape(-1, 3)
    if not np.all(np.isfinite(P)):
        raise ValueError("points contain NaN or inf")
    return P


def plan_reach_request(region: WorkspaceGoalRegion, frame_id: str = "world", arm: int = 0, goal_count: int = 0,
                       planner: str = "", time_budget_s: float = 0.0, use_marker_target: bool = False,
                       execute: bool = False, seed: int = -1, home: bool = False) -> PlanReach.Request:
    """A ``PlanReach`` request for a region whose target is expressed in ``frame_id``
    (the client side of :func:`reach_request`; 0 / "" / -1 = the node's defaults); ``home``:
    the way back to the rest posture (the region is then ignored)."""
    req = PlanReach.Request(arm=int(arm), goal_count=int(goal_count), planner=str(planner),
                            time_budget_s=float(time_budget_s), use_marker_target=bool(use_marker_target),
                            execute=bool(execute), seed=int(seed), home=bool(home))
    req.region.target = pose_stamped(pin.SE3(np.asarray(region.target_R), np.asarray(region.target_p)), frame_id)
    req.region.lower = np.asarray(region.lower, dtype=float)
    req.region.upper = np.asarray(region.upper, dtype=float)
    return req


def region_with_target(region: WorkspaceGoalRegion, target: pin.SE3) -> WorkspaceGoalRegion:
    """The same bounds around another target pose (world)."""
    return WorkspaceGoalRegion.from_pose(target, region.lower, region.upper)


# ---------------------------------------------------------------- planning statistics
_STAT_TYPES = PlanningStatistics.get_fields_and_field_types()


def planning_statistics(stats: Mapping[str, Any]) -> PlanningStatistics:
    """``PlanningStatistics`` from a dict keyed by its field names; missing keys stay 0.

    Raises ``ValueError`` for an unknown key or a negative / non-finite value."""
    unknown = sorted(set(stats) - set(_STAT_TYPES))
    if unknown:
        raise ValueError(f"unknown PlanningStatistics fields: {', '.join(unknown)}")
    msg = PlanningStatistics()
    for key, value in stats.items():
        if value is None:
            continue
        v = float(value)
        if not math.isfinite(v) or v < 0.0:
            raise ValueError(f"PlanningStatistics.{key} must be finite and >= 0, got {value}")
        setattr(msg, key, v if _STAT_TYPES[key] == "double" else int(round(v)))
    return msg


def statistics_dict(msg: PlanningStatistics) -> dict[str, float | int]:
    """The fields of a ``PlanningStatistics`` as a dict (the inverse of :func:`planning_statistics`)."""
    return {k: getattr(msg, k) for k in _STAT_TYPES}


# ---------------------------------------------------------------- markers
RGBA = tuple[float, float, float, float]


def _marker(kind: int, ns: str, marker_id: int, frame_id: str, stamp: Time | None, color: RGBA,
            scale: Sequence[float], pose: pin.SE3 | None = None) -> Marker:
    m = Marker(header=header(frame_id, stamp), ns=ns, id=int(marker_id), type=kind, action=Marker.ADD)
    m.pose = pose_from_se3(pose if pose is not None else pin.SE3.Identity())
    m.scale.x, m.scale.y, m.scale.z = (float(s) for s in scale)
    m.color.r, m.color.g, m.color.b, m.color.a = (float(c) for c in color)
    return m


def line_strip_marker(points: np.ndarray, ns: str, frame_id: str, stamp: Time | None = None,
                      color: RGBA = (0.1, 0.8, 0.1, 1.0), width_m: float = 0.01, marker_id: int = 0) -> Marker:
    """LINE_STRIP through points (N, 3) (e.g. the hand path)."""
    m = _marker(Marker.LINE_STRIP, ns, marker_id, frame_id, stamp, color, (width_m, 0.0, 0.0))
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    if not np.all(np.isfinite(pts)):
        raise ValueError("line strip points must be finite")
    m.points = [Point(x=float(x), y=float(y), z=float(z)) for x, y, z in pts]
    return m


def cube_list_marker(centres: np.ndarray, size_m: float, frame_id: str, stamp: Time | None = None,
                     ns: str = "voxel_map", color: RGBA = (0.3, 0.6, 0.9, 0.8)) -> Marker:
    """One CUBE_LIST marker of cubes of edge ``size_m`` at ``centres`` (N, 3) (a voxel map layer)."""
    m = _marker(Marker.CUBE_LIST, ns, 0, frame_id, stamp, color, (size_m, size_m, size_m))
    m.points = [Point(x=x, y=y, z=z) for x, y, z in np.asarray(centres, dtype=float).tolist()]
    return m


def pose_arrow_markers(poses: Iterable[pin.SE3], ns: str, frame_id: str, stamp: Time | None = None,
                       color: RGBA = (0.9, 0.6, 0.1, 0.9), length_m: float = 0.08, axis: int = 2) -> list[Marker]:
    """One ARROW per pose along the pose's ``axis`` (2 = z, the hand's approach axis)."""
    out = []
    for i, pose in enumerate(poses):
        # an ARROW marker points along its pose's x axis: rotate x onto the chosen axis
        R = np.asarray(pose.rotation)
        if axis == 0:
            Rm = R
        elif axis == 1:
            Rm = R @ np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
        else:
            Rm = R @ np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
        out.append(_marker(Marker.ARROW, ns, i, frame_id, stamp, color, (length_m, 0.012, 0.012),
                           pin.SE3(Rm, np.asarray(pose.translation))))
    return out


def region_markers(region: WorkspaceGoalRegion, ns: str, frame_id: str, stamp: Time | None = None,
                   color: RGBA = (0.2, 0.4, 1.0, 0.4), min_size_m: float = 0.03) -> list[Marker]:
    """The WGR: a translucent CUBE over its translation bounds (at least ``min_size_m``)
    in the target frame, and an ARROW along the target's z axis."""
    lo, hi = np.asarray(region.lower), np.asarray(region.upper)
    centre_local = 0.5 * (lo[:3] + hi[:3])
    target = pin.SE3(np.asarray(region.target_R), np.asarray(region.target_p))
    box_pose = target * pin.SE3(np.eye(3), centre_local)
    size = np.maximum(hi[:3] - lo[:3], min_size_m)
    box = _marker(Marker.CUBE, ns, 0, frame_id, stamp, color, size, box_pose)
    arrow = pose_arrow_markers([target], ns, frame_id, stamp, (color[0], color[1], color[2], 1.0), 0.1)[0]
    arrow.id = 1
    return [box, arrow]


def marker_array(markers: Iterable[Marker], clear: bool = True, frame_id: str = "",
                 stamp: Time | None = None) -> MarkerArray:
    """``MarkerArray``; with ``clear`` a DELETEALL marker first removes the previous plan's markers."""
    out = []
    if clear:
        out.append(Marker(header=header(frame_id, stamp), action=Marker.DELETEALL))
    out.extend(markers)
    return MarkerArray(markers=out)


# ---------------------------------------------------------------- the physics plant (issue 32)
def plant_metrics(snap: Any, frame_id: str, stamp: Time | None = None) -> Any:
    """``msg/PlantMetrics`` of a ``sim.physics.driver.PlantSnapshot``."""
    from humanoid_reach_interfaces.msg import PlantMetrics

    m = snap.metrics

    def point(xy: Any) -> Point:
        return Point() if xy is None else Point(x=float(xy[0]), y=float(xy[1]), z=0.0)
    return PlantMetrics(
        header=header(frame_id, stamp), sim_time_s=float(snap.sim_time_s),
        right_foot_contact=m.foot_cop[0] is not None, right_foot_cop=point(m.foot_cop[0]),
        right_foot_force_n=float(m.foot_force_n[0]),
        left_foot_contact=m.foot_cop[1] is not None, left_foot_cop=point(m.foot_cop[1]),
        left_foot_force_n=float(m.foot_force_n[1]),
        cop_valid=m.cop is not None, cop=point(m.cop), cop_margin_m=float(m.cop_margin_m),
        right_foot_slip_m=float(m.sole_slip_m[0]), left_foot_slip_m=float(m.sole_slip_m[1]),
        base_tilt_rad=math.radians(m.base_tilt_deg), base_height_m=float(m.base_height_m),
        capture_point_out_m=float(m.capture_point_out_m),
        right_hand_force_n=float(m.hand_force_n.get("right", 0.0)),
        left_hand_force_n=float(m.hand_force_n.get("left", 0.0)),
        joint_tracking_error_rad=float(snap.joint_tracking_error_rad),
        base_vs_feet_odometry_m=float(snap.base_vs_feet_odometry_m),
        base_vs_feet_odometry_rad=float(snap.base_vs_feet_odometry_rad),
        fallen=bool(snap.fall_reason), fall_reason=snap.fall_reason,
        real_time_factor=float(snap.real_time_factor), capacity_x_real_time=float(snap.capacity_x_real_time),
        plant_cpu_pct=float(snap.plant_cpu_pct), cop_margin_m_worst=float(snap.cop_margin_m_worst),
        foot_slip_m_worst=float(snap.foot_slip_m_worst), base_tilt_rad_worst=float(snap.base_tilt_rad_worst),
        hand_force_n_worst=float(snap.hand_force_n_worst),
        joint_tracking_error_rad_worst=float(snap.joint_tracking_error_rad_worst),
        real_time_factor_worst=float(snap.real_time_factor_worst))
