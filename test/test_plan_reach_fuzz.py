"""Property-based: 1,000 randomized malformed /plan_reach requests against a real reach_planner.

Every request is the valve request with one to three malformations drawn by hypothesis
(non-finite numbers, non-unit quaternions, crossed or oversized bounds, unknown frames, arms and
planners, budgets and goal counts out of range, a marker target that does not exist). Each gets an
error response with the code its malformations imply, in milliseconds (nothing is planned),
and the node keeps serving: a valid request succeeds afterwards.
"""
from __future__ import annotations

import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from humanoid_reach_ros.codes import ErrorCode
from humanoid_reach_ros.planning.reach import MAX_GOAL_COUNT, MAX_TIME_BUDGET_S
from humanoid_reach_ros.planning.space import PLANNER_NAMES
from humanoid_reach_ros.planning.wgr import ANGLE_TOL
from test_reach_planner_node import DRIVER_PARAMS, FAST_DIAG, PARAMS_FILE, READY, SUCCESS_BUDGET_S, Planner, \
    valve_request

E = ErrorCode
N_EXAMPLES = 1000
NON_FINITE = st.sampled_from([math.nan, math.inf, -math.inf])
POSITION = ("x", "y", "z")
# ROS strings are C strings: an embedded NUL would truncate the text on the wire
TEXT = st.characters(blacklist_characters="\x00", blacklist_categories=("Cs",))
QUAT = ("x", "y", "z", "w")


def _set_position(req, axis, value):
    setattr(req.region.target.pose.position, axis, value)


def _set_quat(req, axis, value):
    setattr(req.region.target.pose.orientation, axis, value)


def _set_bound(req, which, i, value):
    b = list(getattr(req.region, which))
    b[i] = value
    setattr(req.region, which, b)


def _cross(req, i, gap):
    _set_bound(req, "lower", i, req.region.upper[i] + gap)


def _scale_quat(req, factor):
    o = req.region.target.pose.orientation
    o.x, o.y, o.z, o.w = o.x * factor, o.y * factor, o.z * factor, o.w * factor


def _rotation_bound(req, i, value):
    _set_bound(req, "upper", 3 + i, value)


# (strategy of a mutation, the error code it implies)
MUTATIONS = [
    (st.tuples(st.just(_set_position), st.sampled_from(POSITION), NON_FINITE), E.INVALID_REQUEST),
    (st.tuples(st.just(_set_quat), st.sampled_from(QUAT), NON_FINITE), E.INVALID_REQUEST),
    (st.tuples(st.just(_set_bound), st.sampled_from(["lower", "upper"]), st.integers(0, 5), NON_FINITE),
     E.INVALID_REQUEST),
    (st.tuples(st.just(setattr), st.just("time_budget_s"), NON_FINITE), E.INVALID_REQUEST),
    (st.tuples(st.just(setattr), st.just("arm"), st.integers(3, 255)), E.INVALID_REQUEST),
    (st.tuples(st.just(setattr), st.just("planner"),
               st.text(TEXT, min_size=1, max_size=20).filter(lambda s: s.strip() and s.strip() not in PLANNER_NAMES)),
     E.INVALID_REQUEST),
    (st.tuples(st.just(setattr), st.just("time_budget_s"),
               st.one_of(st.floats(-1e300, -1e-9), st.floats(MAX_TIME_BUDGET_S + 1e-6, 1e300))),
     E.INVALID_REQUEST),
    (st.tuples(st.just(setattr), st.just("goal_count"), st.integers(MAX_GOAL_COUNT + 1, 2**32 - 1)),
     E.INVALID_REQUEST),
    (st.tuples(st.just(lambda r, f: setattr(r.region.target.header, "frame_id", f)),
               st.text(TEXT, max_size=30).filter(lambda f: f not in ("", "world", "base_link"))),
     E.UNKNOWN_FRAME),
    (st.tuples(st.just(_scale_quat), st.one_of(st.floats(0.0, 0.9), st.floats(1.1, 1e6))), E.INVALID_REQUEST),
    (st.tuples(st.just(_cross), st.integers(0, 5), st.floats(1e-6, 10.0)), E.INVALID_BOUNDS),
    (st.tuples(st.just(_rotation_bound), st.integers(0, 2), st.floats(math.pi + ANGLE_TOL, 100.0, exclude_min=True)),
     E.INVALID_BOUNDS),
]


@st.composite
def malformed_requests(draw):
    """A valve request with 1-3 malformations; returns it with the set of acceptable codes."""
    picks = draw(st.lists(st.integers(0, len(MUTATIONS) - 1), min_size=1, max_size=3, unique=True))
    req = valve_request()
    for i in picks:
        fn, *args = draw(MUTATIONS[i][0])
        fn(req, *args)
    # a later malformation may overwrite an earlier one (same field), so any of their codes is right
    return req, {MUTATIONS[i][1] for i in picks}, [MUTATIONS[i][0] for i in picks]


@pytest.mark.node
def test_malformed_requests_get_errors_and_node_keeps_serving(start_node, ros_probe) -> None:
    start_node("joint_driver", params_file=DRIVER_PARAMS, ready_log=r"simulated hrp2")
    proc = start_node("reach_planner", params_file=PARAMS_FILE, params=FAST_DIAG, ready_log=READY)
    planner = Planner(ros_probe, proc)
    # a first valid request also waits for /joint_states to reach the node
    ros_probe.spin_until(lambda: planner.call(valve_request(goal_count=1, time_budget_s=SUCCESS_BUDGET_S))
                         .error_code.val != E.NO_JOINT_STATES, 30.0, "reach_planner to receive /joint_states",
                         on_timeout=proc.log_tail)
    seen: dict[int, int] = {}

    @settings(max_examples=N_EXAMPLES, deadline=None, derandomize=True, database=None,
              suppress_health_check=list(HealthCheck))
    @given(malformed_requests())
    def check(case) -> None:
        req, expected, _ = case
        resp = planner.call(req)
        assert not resp.success and resp.error_code.val in expected and resp.message, (resp.error_code, resp.message)
        seen[resp.error_code.val] = seen.get(resp.error_code.val, 0) + 1

    check()
    print(f"\nerror codes of {sum(seen.values())} malformed requests: {seen}")
    assert sum(seen.values()) >= N_EXAMPLES
    assert set(seen) == {E.INVALID_REQUEST, E.INVALID_BOUNDS, E.UNKNOWN_FRAME}
    # no marker target was ever published
    resp = planner.call(valve_request(use_marker_target=True))
    assert resp.error_code.val == E.NO_TARGET, resp.message
    assert proc.alive()
    resp = planner.call(valve_request(time_budget_s=SUCCESS_BUDGET_S))
    assert resp.success, (resp.error_code.val, resp.message)
