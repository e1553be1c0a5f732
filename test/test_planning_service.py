"""The reach planner's core without ROS (``planning/service.py``): the node's parameters as a typed
config, the map's bookkeeping, the order in which a request's inputs are checked, BUSY, an
exception as INTERNAL_ERROR, the log lines, the markers' geometry and the diagnostics' content.

Requests are the validated ``io.msgs.ReachRequest`` s the node converts, here plain namespaces;
clouds are ``io.msgs.CloudPoints``-like namespaces. The node around it: test_reach_planner_node.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pinocchio as pin
import pytest
import yaml

from humanoid_reach_ros.codes import ARM_RIGHT, PlanError, RequestError
from humanoid_reach_ros.planning.reach import PlanOutcome
from humanoid_reach_ros.planning.service import OK, WARN, PlanningService, PlanningServiceConfig, \
    PlanReply
from humanoid_reach_ros.planning.wgr import valve_region
from nodetools import REPO_ROOT

VALUES = yaml.safe_load((REPO_ROOT / "config/reach_planner.yaml").read_text())["/**"]["ros__parameters"]
VALVE = valve_region()


def config(**changes) -> PlanningServiceConfig:
    return PlanningServiceConfig.from_parameters({**VALUES, **changes})


class Log(list):
    """The service's log sink: (level, text, throttled) per line."""

    def __call__(self, level: str, text: str, throttled: bool = False) -> None:
        self.append((level, text, throttled))

    def texts(self, level: str | None = None) -> list[str]:
        return [t for lv, t, _ in self if level is None or lv == level]


@pytest.fixture
def log() -> Log:
    return Log()


@pytest.fixture
def service(log) -> PlanningService:
    """No map: the scene file is empty."""
    return PlanningService(config(scene_file=""), log=log)


def request(**kw):
    """A validated request (``io.msgs.ReachRequest``'s fields) for the valve."""
    fields = dict(region=VALVE, arm="auto", goal_count=None, planner=None, time_budget_s=None, seed=None,
                  use_marker_target=False, execute=False, home=False)
    return SimpleNamespace(**{**fields, **kw})


def cloud(points, frame_id: str = "world", dropped: int = 0):
    return SimpleNamespace(points=np.asarray(points, dtype=float).reshape(-1, 3), frame_id=frame_id,
                           dropped_nonfinite=dropped)


def standing(service):
    return lambda: (service.model.half_sitting_joints.copy(), "")


def no_marker():
    return None, float("inf")


def plan(service, req=None, joints=None, marker=no_marker, n: int = 1) -> PlanReply:
    return service.plan(n, lambda waist: req or request(), joints or standing(service), marker)


# ---------------------------------------------------------------- config
def test_config_from_the_node_parameters() -> None:
    c = config()
    assert c.planner.goal_count == VALUES["goal_count"] and c.planner.safety_margin_m == VALUES["safety_margin_m"]
    assert c.scene.target_exclusion_radius_m == VALUES["target_exclusion_radius_m"]
    assert c.scene.unobserved_space == VALUES["unobserved_space"] and c.map_frame == VALUES["map_frame"]
    assert c.scene_exclude_groups == tuple(VALUES["scene_exclude_groups"])
    assert c.defaults_text() == (f"defaults: {VALUES['planner']}, {VALUES['goal_count']} goals, budget "
                                 f"{VALUES['time_budget_s']:g} s, seed {VALUES['seed']}")
    with pytest.raises(ValueError, match="planner must be one of"):
        config(planner="astar")
    with pytest.raises(ValueError, match="unobserved_space must be one of"):
        config(unobserved_space="maybe")
    with pytest.raises(ValueError, match="goal_count must be >= 1"):
        config(goal_count=0)
    assert PlanningServiceConfig.refusal("unobserved_space", "free") == ""
    assert "unobserved_space must be one of" in PlanningServiceConfig.refusal("unobserved_space", "maybe")
    assert PlanningServiceConfig.refusal("target_timeout_s", 3.0) == ""


def test_a_reply_without_a_message_is_named_by_its_code() -> None:
    assert PlanReply(PlanError.NO_MAP).response_message == "NO_MAP"
    assert PlanReply(123).response_message == "UNKNOWN_CODE_123"


# ---------------------------------------------------------------- inputs
def test_start_joints_and_marker_freshness(service) -> None:
    joints = service.model.half_sitting_joints
    assert service.fresh_joints(None, 0.0) == (None, "no /joint_states received")
    j, reason = service.fresh_joints((joints, ""), 0.6)
    assert j is None and reason == "/joint_states is stale (0.60 s > 0.5 s)"
    j, reason = service.fresh_joints((joints, ""), 0.1)
    assert j is joints and reason == ""
    assert service.fresh_joints((None, "missing RARM_JOINT0"), 0.1) == (None, "missing RARM_JOINT0")
    assert service.target_staleness(False, 0.0) == "use_marker_target but no /target_pose received"
    assert service.target_staleness(True, 2.0) == "use_marker_target but /target_pose is stale (2.00 s > 1 s)"
    assert service.target_staleness(True, 0.5) == ""
    service.reconfigure(config(scene_file="", target_timeout_s=3.0, joint_states_timeout_s=1.0))
    assert service.target_staleness(True, 2.0) == "" and service.fresh_joints((joints, ""), 0.6)[0] is joints


def test_inputs_in_the_order_an_operator_fixes_them(service) -> None:
    """The marker target first, then the joint states, then the marker's frame, then the map."""
    missing = lambda: (None, "no /joint_states received")   # noqa: E731
    reply = plan(service, request(use_marker_target=True), joints=missing)
    assert reply.code == PlanError.NO_TARGET and "no /target_pose received" in reply.message
    reply = plan(service, request(use_marker_target=True), joints=missing, marker=lambda: (lambda w: None, 5.0))
    assert reply.code == PlanError.NO_TARGET and "stale" in reply.message
    reply = plan(service, request(), joints=missing)
    assert reply.code == PlanError.NO_JOINT_STATES and reply.message == "no /joint_states received"

    def bad_frame(waist):
        raise RequestError(PlanError.UNKNOWN_FRAME, "/target_pose frame_id 'map' is unknown")
    reply = plan(service, request(use_marker_target=True), marker=lambda: (bad_frame, 0.0))
    assert reply.code == PlanError.UNKNOWN_FRAME and "'map'" in reply.message
    assert reply.waist.isApprox(service.model.base_on_feet(service.model.half_sitting_joints))
    moved = pin.SE3(np.eye(3), np.array([0.6, -0.2, 1.0]))
    reply = plan(service, request(use_marker_target=True), marker=lambda: (lambda waist: moved, 0.0))
    assert reply.code == PlanError.NO_MAP and reply.message.startswith("no environment map")
    np.testing.assert_allclose(reply.region.target_p, moved.translation)   # the marker replaced the target

    def refused(waist):
        raise RequestError(PlanError.INVALID_BOUNDS, "lower > upper")
    reply = service.plan(1, refused, standing(service), no_marker)
    assert (reply.code, reply.message, reply.region) == (PlanError.INVALID_BOUNDS, "lower > upper", None)
    assert not service.log                                      # refusals are the request line's


def test_an_exception_is_internal_error_and_logged(service, log) -> None:
    def broken(waist):
        raise KeyError("boom")
    reply = service.plan(7, broken, standing(service), no_marker)
    assert reply.code == PlanError.INTERNAL_ERROR and reply.message == "internal error while planning: KeyError: 'boom'"
    (level, text, _), = log
    assert level == "error" and text.startswith("plan_reach #7: internal error while planning") and "Traceback" in text
    reply = service.internal_error(7, "building the response", ValueError("bad"), region=VALVE)
    assert reply.message == "internal error building the response: ValueError: bad" and reply.region is VALVE


def test_one_request_at_a_time(service, log) -> None:
    n, busy = service.begin()
    assert (n, busy) == (1, None) and service.plan_lock.locked()
    n2, busy = service.begin()
    assert n2 == 2 and busy.code == PlanError.BUSY and "being planned" in busy.message
    assert log.texts("warning") == [f"plan_reach #2: BUSY ({busy.message})"]
    service.end()
    assert not service.plan_lock.locked() and (service.counters.requests, service.counters.busy_rejections) == (2, 1)
    assert service.begin()[1] is None
    service.end()


# ---------------------------------------------------------------- the map
def test_map_bookkeeping(service, log) -> None:
    assert service.map_info.source == "none" and not service.planner.has_map
    service.load_scene_file()
    assert log.texts("info")[-1].startswith("map source: none yet (scene_file is empty)")
    box = np.random.default_rng(0).uniform(-1, 1, (50, 3)) + [3.0, 0.0, 0.0]
    service.set_map(cloud(box, "", dropped=2))
    m = service.map_info
    assert (m.source, m.voxels, m.received, m.dropped_nonfinite) == ("/voxel_map", 50, 1, 2)
    assert service.planner.has_map and service.scene.source == "/voxel_map"
    assert log.texts("info")[-1].startswith("map source: /voxel_map (50 voxels, 2 NaN/inf points dropped")
    assert log.texts("warning")[-1] == "/voxel_map had 2 points with NaN/inf coordinates (dropped)"
    service.set_map(cloud(box[:40]))
    assert log[-1][0] == "debug" and "replaces /voxel_map" in log[-1][1]   # repetition at DEBUG
    with pytest.raises(ValueError, match="frame_id 'map' is not the map frame 'world'"):
        service.set_map(cloud(box, "map"))
    service.map_rejected(ValueError("no z field"))
    m = service.map_info
    assert (m.voxels, m.received, m.rejected, m.last_rejection) == (40, 2, 1, "ValueError: no z field")
    assert log.texts("warning")[-1] == ("rejected /voxel_map (1 so far): ValueError: no z field; keeping the "
                                        "previous map (/voxel_map, 40 voxels)")

    service.set_unobserved("/voxel_map/unobserved_blocks", "blocks", lambda: cloud([[5.0, 5.0, 5.0]]))
    assert service.scene.describe()
    service.set_unobserved("/voxel_map/unobserved", "frontier", lambda: cloud([[5.0, 5.0, 5.0]], "map"))
    assert log[-1] == ("warning", "rejected /voxel_map/unobserved: frame_id 'map' is not the map frame 'world'; "
                                  "keeping the previous one", True)
    assert service.map_info.rejected == 2 and service.map_info.last_rejection.startswith("/voxel_map/unobserved:")


def test_scene_file_map(log) -> None:
    service = PlanningService(config(), log=log)
    service.load_scene_file()
    m = service.map_info
    assert m.source.startswith("scene file ") and m.source.endswith("plant.yaml") and m.voxels > 10_000
    assert m.build_time_s > 0 and service.planner.has_map
    assert f"({m.voxels} voxels without groups ['valve'], built in" in log.texts("info")[-1]
    assert service.ready_line().startswith("reach planner ready: service plan_reach (defaults: rrt_connect")


# ---------------------------------------------------------------- a plan, its answer
def test_a_plan_its_statistics_log_markers_and_diagnostics(log) -> None:
    service = PlanningService(config(unobserved_space="free"), log=log)
    service.load_scene_file()
    n, _ = service.begin()
    reply = plan(service, request(arm="right", goal_count=3, time_budget_s=20.0, seed=1), n=n)
    assert reply.success and reply.code == PlanError.SUCCESS, reply.message
    assert reply.arm_code == ARM_RIGHT and reply.waist_start is not None and reply.retreat == ""
    stats = service.statistics(reply, 1.5)
    assert stats["total_time_s"] == 1.5 and stats["goals_requested"] == 3 and stats["map_voxels"] > 10_000
    service.finish(n, reply, 1.5, published=True)
    service.end()
    line = log.texts("info")[-1]
    assert line.startswith(f"plan_reach #{n}: SUCCESS (0) in 1500 ms [goal sampling ")
    assert "/3 goals; path " in line and "; right arm, " in line and ", published on reach_trajectory: " in line
    assert (service.counters.requests, service.counters.successes, service.last) == (1, 1, reply)

    poses = service.goal_hand_poses(reply)
    assert len(poses) == int(stats["goals_found"]) and all(isinstance(p, pin.SE3) for p in poses)
    path = service.hand_path(reply)
    assert 2 <= len(path) <= VALUES["marker_path_points"]
    assert np.linalg.norm(path[-1] - VALVE.target_p) < 0.05

    statuses = {s[0]: s for s in service.diagnostics(None, 0.01, float("inf"))}
    _, level, message, values = statuses["map"]
    assert level == OK and message.startswith(f"{values['voxels']} voxels from scene file")
    assert {"source", "voxels", "build_time_ms", "maps_received", "maps_rejected", "dropped_nonfinite_points",
            "last_rejection", "frame_id"} <= set(values) and any(k.startswith("scene_") for k in values)
    _, level, message, values = statuses["planning"]
    assert level == OK and message == "last request: SUCCESS in 1500 ms"
    assert values["last_result"] == "SUCCESS" and values["successes"] == 1 and values["planning"] is False
    assert {"last_error_code", "last_message", "last_total_time_s", "last_goal_sampling_time_s",
            "last_path_planning_time_s", "busy_rejections", "requests"} <= set(values)
    _, level, message, values = statuses["inputs"]
    assert (level, message, values["target_pose_age_s"]) == (OK, "joint_states current", "never")


def test_refused_answers_log_and_diagnose(service, log) -> None:
    statuses = {s[0]: s for s in service.diagnostics("no /joint_states received", float("inf"), float("inf"))}
    assert statuses["map"][1] == WARN and statuses["map"][2] == "no map yet: waiting for /voxel_map"
    assert statuses["planning"][2] == "no request yet"
    assert statuses["inputs"][1:3] == (WARN, "no /joint_states received")
    assert statuses["inputs"][3]["joint_states_age_s"] == "never"

    tried = tuple(f"direction {k}" for k in range(9))
    service.set_map(cloud([[3.0, 0.0, 0.0]]))
    service.planner.plan = lambda joints, req: PlanOutcome(False, PlanError.START_IN_COLLISION, "touches",
                                                           None, service.model.joint_names, retreats_tried=tried)
    reply = plan(service, n=4)
    service.finish(4, reply, 0.02, published=False)
    assert log.texts("info")[-2].startswith("plan_reach #4: START_IN_COLLISION (5) in 20 ms [goal sampling 0 ms")
    assert log.texts("info")[-2].endswith(": touches")
    assert log.texts("info")[-1] == "plan_reach #4: the 9 retreats tried: " + "; ".join(
        f"{k + 1}) direction {k}" for k in range(9))
    assert service.goal_hand_poses(reply) == [] and service.hand_path(reply) is None

    reply = service.internal_error(5, "while planning", RuntimeError("boom"))
    service.finish(5, reply, 0.001, published=False)
    assert log.texts("error")[-1] == "plan_reach #5: INTERNAL_ERROR (99) in 1 ms: internal error while planning: " \
                                     "RuntimeError: boom"
    statuses = {s[0]: s for s in service.diagnostics(None, 0.0, 0.0)}
    assert statuses["planning"][1] == 2 and statuses["planning"][3]["last_error_code"] == 99
    assert (service.counters.successes, service.last_total_s) == (0, 0.001)


def test_scene_policies_follow_reconfigure(service) -> None:
    version = service.scene.version
    service.reconfigure(config(scene_file="", unobserved_space="free", target_exclusion_radius_m=0.0))
    assert service.scene.version > version and service.scene.params.unobserved_space == "free"



def test_the_warm_up_covers_a_request_on_a_measured_map() -> None:
    """Issue 33, point 5: a fresh clone's first ``make demo`` plan compiled the kernels of a
    measured map with unobserved layers inside the operator's wait (the planner's own warm-up plans
    without them). ``warm_up_measured`` runs that path (here: the kernel that takes the swept body
    out of the unobserved blocks gets its signature, in a process of its own so that no other test
    has called it) and leaves the service's scene and the planner's memory as they were."""
    import subprocess
    import sys
    code = """
import numpy as np
from humanoid_reach_ros.planning.service import PlanningService, PlanningServiceConfig
from humanoid_reach_ros.scene import planning_scene
svc = PlanningService(PlanningServiceConfig())
assert svc.planner.warm_up()
before = len(planning_scene._boxes_touch_grid.signatures)
scene, version = svc.planner.scene, svc.scene.version
assert svc.warm_up_measured()
assert svc.planner.scene is scene is svc.scene and svc.scene.version == version and svc.scene.source == "none"
assert svc.planner._last_positions is None and svc.planner._last_plan_end is None
print(before, len(planning_scene._boxes_touch_grid.signatures))
"""
    r = subprocess.run([sys.executable, "-c", code], cwd=REPO_ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    assert r.stdout.split()[-2:] == ["0", "1"], r.stdout
