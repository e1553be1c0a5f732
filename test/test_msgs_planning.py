"""Unit tests of the planning conversions in humanoid_reach_ros.io.msgs (no ROS graph)."""
from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest
from geometry_msgs.msg import PoseStamped
from humanoid_reach_interfaces.msg import PlanningStatistics
from humanoid_reach_interfaces.srv import PlanReach
from sensor_msgs.msg import PointCloud2, PointField
from visualization_msgs.msg import Marker

from humanoid_reach_ros.codes import ErrorCode
from humanoid_reach_ros.io import msgs
from humanoid_reach_ros.planning.reach import MAX_GOAL_COUNT, MAX_TIME_BUDGET_S
from humanoid_reach_ros.planning.wgr import valve_region

E = ErrorCode
H = math.pi / 2


# ---------------------------------------------------------------- point clouds
def test_cloud_round_trip_float32():
    pts = np.random.default_rng(0).uniform(-1, 1, (50, 3))
    msg = msgs.cloud_from_points(pts, "world")
    out = msgs.points_from_cloud(msg)
    assert out.frame_id == "world" and out.dropped_nonfinite == 0
    np.testing.assert_allclose(out.points, pts.astype(np.float32), atol=0)
    assert out.points.dtype == np.float64 and out.points.shape == (50, 3)


def test_cloud_with_padding_float64_big_endian_and_row_padding():
    """x,y,z float64 big-endian at odd offsets, an intensity field, 2 rows with row padding."""
    pts = np.arange(12, dtype=float).reshape(4, 3) * 0.1
    step = 32
    dt = np.dtype({"names": ["i", "x", "y", "z"], "formats": [">f4", ">f8", ">f8", ">f8"],
                   "offsets": [0, 4, 12, 20], "itemsize": step})
    rec = np.zeros(4, dtype=dt)
    rec["x"], rec["y"], rec["z"] = pts.T
    raw = rec.tobytes()
    row_step = 2 * step + 8
    data = b"".join(raw[r * 2 * step:(r + 1) * 2 * step] + b"\0" * 8 for r in range(2))
    msg = PointCloud2(height=2, width=2, point_step=step, row_step=row_step, is_bigendian=True, data=data,
                      fields=[PointField(name="intensity", offset=0, datatype=PointField.FLOAT32, count=1),
                              PointField(name="x", offset=4, datatype=PointField.FLOAT64, count=1),
                              PointField(name="y", offset=12, datatype=PointField.FLOAT64, count=1),
                              PointField(name="z", offset=20, datatype=PointField.FLOAT64, count=1)])
    np.testing.assert_allclose(msgs.points_from_cloud(msg).points, pts)


def test_cloud_nan_points_dropped_and_counted():
    pts = np.array([[0.0, 0.0, 0.0], [np.nan, 1.0, 1.0], [1.0, np.inf, 0.0], [0.5, 0.5, 0.5]])
    out = msgs.points_from_cloud(msgs.cloud_from_points(pts, "world"))
    assert out.dropped_nonfinite == 2
    np.testing.assert_allclose(out.points, pts[[0, 3]])


def test_empty_cloud():
    out = msgs.points_from_cloud(msgs.cloud_from_points(np.empty((0, 3)), "world"))
    assert out.points.shape == (0, 3) and out.dropped_nonfinite == 0


@pytest.mark.parametrize("mutate, match", [
    (lambda m: setattr(m, "fields", m.fields[:2]), "no z field"),
    (lambda m: setattr(m, "point_step", 8), "outside point_step"),
    (lambda m: setattr(m, "row_step", m.row_step - 1), "row_step"),
    (lambda m: setattr(m, "data", bytes(m.data)[:-4]), "bytes"),
    (lambda m: m.fields.__setitem__(0, PointField(name="x", offset=0, datatype=PointField.INT32, count=1)), "FLOAT32"),
    (lambda m: m.fields.__setitem__(2, PointField(name="z", offset=8, datatype=PointField.FLOAT32, count=3)), "count"),
])
def test_malformed_cloud_raises(mutate, match):
    msg = msgs.cloud_from_points(np.ones((5, 3)), "world")
    mutate(msg)
    with pytest.raises(ValueError, match=match):
        msgs.points_from_cloud(msg)


# ---------------------------------------------------------------- joint trajectories
def test_joint_trajectory_round_trip():
    names = [f"J{i}" for i in range(4)]
    t = np.array([0.0, 0.05, 0.1, 1.2345678901])
    q = np.random.default_rng(1).normal(size=(4, 4))
    msg = msgs.joint_trajectory(names, t, q, 2 * q, 3 * q, "world")
    assert msg.header.frame_id == "world" and list(msg.joint_names) == names
    assert msg.points[3].time_from_start.sec == 1 and msg.points[3].time_from_start.nanosec == 234567890
    arr = msgs.parse_joint_trajectory(msg)
    np.testing.assert_allclose(arr.times, t, atol=1e-9)
    np.testing.assert_allclose(arr.positions, q)
    np.testing.assert_allclose(arr.velocities, 2 * q)
    np.testing.assert_allclose(arr.accelerations, 3 * q)
    no_vel = msgs.parse_joint_trajectory(msgs.joint_trajectory(names, t, q))
    assert no_vel.velocities is None and no_vel.accelerations is None


@pytest.mark.parametrize("times, pos, match", [
    ([0.0, 0.0], np.zeros((2, 2)), "increasing"),
    ([0.0, np.nan], np.zeros((2, 2)), "increasing"),
    ([-0.1, 0.1], np.zeros((2, 2)), "increasing"),
    ([0.0, 0.1], np.zeros((2, 3)), "shape"),
    ([0.0, 0.1], np.array([[0.0, np.inf], [0.0, 0.0]]), "non-finite"),
])
def test_joint_trajectory_rejects_bad_arrays(times, pos, match):
    with pytest.raises(ValueError, match=match):
        msgs.joint_trajectory(["a", "b"], times, pos)


def test_duration_conversions():
    assert msgs.seconds_from_duration(msgs.duration_from_seconds(2.5)) == 2.5
    with pytest.raises(ValueError):
        msgs.duration_from_seconds(-1.0)


# ---------------------------------------------------------------- PlanReach requests
def valve_request(**kw) -> PlanReach.Request:
    return msgs.plan_reach_request(valve_region(), "world", **kw)


def test_reach_request_valve():
    r = msgs.reach_request(valve_request())
    ref = valve_region()
    np.testing.assert_allclose(r.region.target_p, ref.target_p)
    np.testing.assert_allclose(r.region.target_R, ref.target_R, atol=1e-12)
    np.testing.assert_allclose(r.region.lower, ref.lower)
    assert (r.arm, r.goal_count, r.planner, r.time_budget_s, r.seed) == ("auto", None, None, None, None)
    r = msgs.reach_request(valve_request(arm=2, goal_count=3, planner="prm", time_budget_s=1.5, seed=7,
                                         execute=True))
    assert (r.arm, r.goal_count, r.planner, r.time_budget_s, r.seed, r.execute) == ("left", 3, "prm", 1.5, 7, True)


def test_reach_request_base_link_uses_waist():
    req = valve_request()
    req.region.target.header.frame_id = "base_link"
    req.region.target.pose.position.x = 0.5
    waist = pin.SE3(np.eye(3), np.array([-0.01, 0.0, 0.74]))
    r = msgs.reach_request(req, waist)
    np.testing.assert_allclose(r.region.target_p, [0.49, 0.03, 1.64])
    with pytest.raises(msgs.RequestError) as exc:
        msgs.reach_request(req, None)
    assert exc.value.code == E.NO_JOINT_STATES


def _nan_target(req):
    req.region.target.pose.position.x = math.nan


def _inf_lower(req):
    req.region.lower = [0.0, 0.0, -math.inf, 0.0, 0.0, 0.0]


def _lower_gt_upper(req):
    req.region.lower = [0.1, 0.0, 0.0, -H, -H, -math.pi]


def _rot_bound(req):
    req.region.upper = [0.0, 0.0, 0.0, H, H, 4.0]


def _frame(req):
    req.region.target.header.frame_id = "map"


def _quat(req):
    req.region.target.pose.orientation.w = 2.0


@pytest.mark.parametrize("mutate, code", [
    (_nan_target, E.INVALID_REQUEST),
    (_inf_lower, E.INVALID_REQUEST),
    (lambda r: setattr(r, "time_budget_s", math.nan), E.INVALID_REQUEST),
    (lambda r: setattr(r, "time_budget_s", -1.0), E.INVALID_REQUEST),
    (lambda r: setattr(r, "time_budget_s", MAX_TIME_BUDGET_S + 1.0), E.INVALID_REQUEST),
    (lambda r: setattr(r, "goal_count", MAX_GOAL_COUNT + 1), E.INVALID_REQUEST),
    (lambda r: setattr(r, "arm", 7), E.INVALID_REQUEST),
    (lambda r: setattr(r, "planner", "foo"), E.INVALID_REQUEST),
    (_quat, E.INVALID_REQUEST),
    (_lower_gt_upper, E.INVALID_BOUNDS),
    (_rot_bound, E.INVALID_BOUNDS),
    (_frame, E.UNKNOWN_FRAME),
])
def test_reach_request_errors(mutate, code):
    req = valve_request()
    mutate(req)
    with pytest.raises(msgs.RequestError) as exc:
        msgs.reach_request(req)
    assert exc.value.code == code and str(exc.value)


def test_reach_request_rotation_bounds_typed_as_3_1416_are_clamped():
    """The README's payload types pi as 3.1416 (and 1.5708): accepted, clamped to +-pi."""
    req = valve_request()
    req.region.lower = [0.0, 0.0, 0.0, -1.5708, -1.5708, -3.1416]
    req.region.upper = [0.0, 0.0, 0.0, 1.5708, 1.5708, 3.1416]
    r = msgs.reach_request(req)
    np.testing.assert_array_equal(r.region.lower[3:], [-1.5708, -1.5708, -math.pi])
    np.testing.assert_array_equal(r.region.upper[3:], [1.5708, 1.5708, math.pi])
    req.region.upper = [0.0, 0.0, 0.0, 1.5708, 1.5708, 3.15]  # 8.4e-3 beyond pi: a real mistake
    with pytest.raises(msgs.RequestError) as exc:
        msgs.reach_request(req)
    assert exc.value.code == E.INVALID_BOUNDS
    assert "upper yaw 3.15" in str(exc.value) and "within [-pi, pi]" in str(exc.value)


def test_marker_target_skips_region_frame_and_takes_marker_pose():
    req = valve_request(use_marker_target=True)
    req.region.target.header.frame_id = "camera"  # ignored: the marker pose replaces it
    r = msgs.reach_request(req)
    assert r.use_marker_target
    marker = PoseStamped()
    marker.header.frame_id = "world"
    marker.pose.position.x, marker.pose.orientation.w = 0.6, 1.0
    region = msgs.region_with_target(r.region, msgs.target_in_world(marker, None, "/target_pose"))
    np.testing.assert_allclose(region.target_p, [0.6, 0.0, 0.0])
    np.testing.assert_allclose(region.upper, r.region.upper)


# ---------------------------------------------------------------- statistics
def test_planning_statistics_from_dict():
    fields = PlanningStatistics.get_fields_and_field_types()
    stats = {k: (0.25 if t == "double" else 3) for k, t in fields.items()}
    msg = msgs.planning_statistics(stats)
    assert msgs.statistics_dict(msg) == stats
    assert msgs.planning_statistics({"goals_found": 2}).goals_found == 2
    with pytest.raises(ValueError, match="unknown"):
        msgs.planning_statistics({"bogus": 1})
    with pytest.raises(ValueError):
        msgs.planning_statistics({"total_time_s": math.nan})


# ---------------------------------------------------------------- markers
def test_markers():
    poses = [pin.SE3(pin.rpy.rpyToMatrix(0.3, -0.2, 1.0), np.array([0.7, 0.0, 0.9])) for _ in range(3)]
    arrows = msgs.pose_arrow_markers(poses, "goals", "world")
    assert [m.id for m in arrows] == [0, 1, 2] and all(m.type == Marker.ARROW for m in arrows)
    # the arrow (marker x axis) points along the pose's z axis
    R = msgs.se3_from_pose(arrows[0].pose).rotation
    np.testing.assert_allclose(R[:, 0], poses[0].rotation[:, 2], atol=1e-9)
    strip = msgs.line_strip_marker(np.array([[0, 0, 0], [1, 2, 3.0]]), "path", "world")
    assert strip.type == Marker.LINE_STRIP and len(strip.points) == 2 and strip.points[1].z == 3.0
    region = msgs.region_markers(valve_region(), "region", "world")
    assert region[0].type == Marker.CUBE and region[0].pose.position.x == pytest.approx(0.71)
    arr = msgs.marker_array(arrows + [strip] + region)
    assert arr.markers[0].action == Marker.DELETEALL and len(arr.markers) == 7
