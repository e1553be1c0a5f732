"""The execution manager without ROS (issue 25, part 2): ``execution/manager.py`` driven
directly, its loop a stand-in that answers commands with the events the control process sends.

Checked: a trajectory goal followed to its end with feedback; a bad goal and a missing joint
state answered, never raised; a client's cancel sent to the loop as a stop; a look of two head
poses in turn with feedback and holding; the stale-joint-state abort, once per motion; the loop
process exiting ends what is pending ABORTED; a malformed map kept out; run-time configuration;
the diagnostics' values.
"""
from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest

from humanoid_reach_ros.codes import ExecuteCode as C, RequestError
from humanoid_reach_ros.execution.config import ExecutionConfig
from humanoid_reach_ros.execution.manager import (LEVEL_ERROR, LEVEL_OK, LEVEL_WARN, ExecutionManager, LookGoal,
                                                  LookProgress, TrajectoryGoal)
from humanoid_reach_ros.execution.messages import (LoopExited, LoopStatus, MotionFinished, MotionStarted,
                                                   MotionSummary, SetMap, StartMotion, StopMotion)
from humanoid_reach_ros.robot.model import RobotModel

SUMMARY = MotionSummary(0.2, 40, 0, 1e-5, 0.05, 1e-4, 1e-4)


class Log:
    def __init__(self) -> None:
        self.lines: list[tuple[str, str]] = []

    def _add(self, level: str, text: str, **_kw) -> None:
        self.lines.append((level, text))

    def info(self, text, **kw):
        self._add("info", text, **kw)

    def warning(self, text, **kw):
        self._add("warning", text, **kw)

    def error(self, text, **kw):
        self._add("error", text, **kw)

    def debug(self, text, **kw):
        self._add("debug", text, **kw)

    def text(self, level: str | None = None) -> str:
        return "\n".join(t for lv, t in self.lines if level is None or lv == level)


class FakeLoop:
    """Answers StartMotion with a start, a status and (unless ``hold``) a SUCCESS after
    ``run_s``; StopMotion with that code. Events come from another thread, as the reader's do."""

    def __init__(self, run_s: float = 0.15, hold: bool = False) -> None:
        self.manager: ExecutionManager | None = None
        self.sent: list = []
        self.run_s, self.hold, self.up = run_s, hold, True

    def alive(self) -> bool:
        return self.up

    def send(self, command) -> None:
        self.sent.append(command)
        m = self.manager
        match command:
            case StartMotion(motion=motion):
                def run() -> None:
                    m.on_event(MotionStarted(motion.id, "", "/joint_states"))
                    m.on_event(LoopStatus(mode="running", motion_id=motion.id, motion_label=motion.label,
                                          progress=0.5, last=object(), steps=10, ticks=10))
                    if not self.hold:
                        time.sleep(self.run_s)
                        m.on_event(MotionFinished(motion.id, int(C.SUCCESS), "done", SUMMARY, 1.0, ""))
                threading.Thread(target=run, daemon=True).start()
            case StopMotion(motion_id=mid, code=code, message=message):
                m.on_event(MotionFinished(mid, code, message, SUMMARY, 0.5, ""))


class Port:
    def __init__(self, cancel_after: int | None = None) -> None:
        self.feedback_values: list = []
        self.cancel_after = cancel_after

    def cancel_requested(self) -> bool:
        return self.cancel_after is not None and len(self.feedback_values) >= self.cancel_after

    def active(self) -> bool:
        return True

    def feedback(self, value) -> None:
        self.feedback_values.append(value)


@pytest.fixture(scope="module")
def robot() -> RobotModel:
    return RobotModel()


def make(robot, loop: FakeLoop | None = None, joints=True, age: float = 0.01, **config):
    log = Log()
    state = {"age": age}
    j = robot.half_sitting_joints.copy()
    m = ExecutionManager(robot, ExecutionConfig(feedback_period_s=0.01, scan_dwell_s=0.05, **config),
                         (lambda: (j, "")) if joints else (lambda: (None, "no /joint_states received")),
                         lambda: state["age"], log)
    loop = loop or FakeLoop()
    loop.manager = m
    m.attach(loop)
    return m, loop, log, state


def reference(robot, seconds: float = 0.5):
    """What the node makes of a JointTrajectory (``exec_msgs.Reference``), made here without it."""
    from types import SimpleNamespace

    from humanoid_reach_ros.geometry.trajectory import SplineTrajectory
    j0 = robot.half_sitting_joints
    j1 = j0.copy()
    j1[robot.joint_index[robot.spec.head_joints[0]]] += 0.1
    times, positions = np.array([0.0, seconds]), np.stack([j0, j1])
    return SimpleNamespace(times=times, positions=positions, spline=SplineTrajectory(positions, times),
                           time_offset_s=0.0)


def test_a_trajectory_goal_runs_to_its_end_with_feedback(robot) -> None:
    m, loop, log, _ = make(robot)
    port = Port()
    out = m.execute(lambda: TrajectoryGoal(reference(robot)), port)
    assert out.success and out.message == "done" and out.summary["steps"] == 40, (out, log.text())
    assert [type(c) for c in loop.sent] == [StartMotion]
    assert port.feedback_values and all(isinstance(s, LoopStatus) for s in port.feedback_values)
    assert m.counters.successes == 1 and m.counters.goals == 1
    assert "goal #1: accepted" in log.text("info") and "goal #1: SUCCESS" in log.text("info")


def test_bad_goals_are_answered_never_raised(robot) -> None:
    m, loop, log, _ = make(robot)

    def bad():
        raise RequestError(C.INVALID_REQUEST, "trajectory has no points")
    out = m.execute(bad, Port())
    assert out.code == C.INVALID_REQUEST and "no points" in out.message
    out = m.execute(lambda: 1 / 0, Port())                       # a bug in a conversion: ABORTED, said
    assert out.code == C.ABORTED and "internal error: ZeroDivisionError" in out.message
    assert m.counters.goals_rejected == 2 and not loop.sent
    assert "goal #1 rejected (INVALID_REQUEST)" in log.text("warning") and "internal error" in log.text("error")
    blind, loop2, _, _ = make(robot, joints=False)
    out = blind.execute(lambda: TrajectoryGoal(reference(robot)), Port())
    assert out.code == C.NO_JOINT_STATES and "no /joint_states" in out.message and not loop2.sent


def test_a_cancel_becomes_a_stop_for_the_loop(robot) -> None:
    m, loop, _, _ = make(robot, FakeLoop(hold=True))
    out = m.execute(lambda: TrajectoryGoal(reference(robot)), Port(cancel_after=1))
    assert out.code == C.CANCELED and out.message == "canceled by the client"
    assert [type(c) for c in loop.sent] == [StartMotion, StopMotion] and loop.sent[1].code == C.CANCELED


def test_a_look_moves_the_head_pose_by_pose_and_holds(robot) -> None:
    m, loop, log, _ = make(robot)
    port = Port()
    out = m.look(lambda: LookGoal((0.1, -0.1), (0.3, 0.2), None, 0.05), port)
    assert out.success and out.poses_done == 2 and "2 head poses reached and held" in out.message, out
    assert sum(isinstance(c, StartMotion) for c in loop.sent) == 2
    progress = [v for v in port.feedback_values if isinstance(v, LookProgress)]
    assert [(p.pose_index, p.holding) for p in progress] == [(0, False), (0, True), (1, False), (1, True)]
    assert progress[0].pose_count == 2 and math.isclose(progress[2].yaw_rad, -0.1)
    out = m.look(lambda: LookGoal((0.1,), (0.3, 0.2)), Port())          # refused: named, counted
    assert out.code == C.INVALID_REQUEST and "one pitch per yaw" in out.message
    out = m.look(lambda: LookGoal((0.1,), (0.3,), None, 61.0), Port())
    assert out.code == C.INVALID_REQUEST and "longer than 60 s" in out.message
    assert m.counters.goals_rejected == 2 and "look #3" in log.text("warning")


def test_a_scan_gazes_around_the_body_comes_back_then_looks_ahead(robot) -> None:
    """Issue 31: the scan (a look with no poses) first gazes around the body
    (scan_surroundings_looks), comes back to the posture those gazes began in (they turn the chest,
    which a head pose holds), then takes its head poses: it ends looking ahead."""
    class Following(FakeLoop):
        """The measured joints end where each motion does (the fake's joints are one array)."""

        def send(self, command) -> None:
            if isinstance(command, StartMotion):
                spline = command.motion.spline
                self.manager.joints()[0][:] = spline.position(spline.duration)
            super().send(command)

    m, loop, log, _ = make(robot, Following(), scan_surroundings_looks=1, scan_poses_deg=(0.0, 20.0))
    out = m.look(lambda: LookGoal((), (), None, 0.01), Port())
    assert out.success and out.poses_done == 3, out
    assert "1 head pose reached" in out.message and "then 1 gaze around the body" in out.message, out
    starts = [c.motion for c in loop.sent if isinstance(c, StartMotion)]
    assert len(starts) == 3 and "gaze at" in starts[0].note and "back to the posture" in starts[1].note
    assert "head to yaw 0.0, pitch 20.0" in starts[2].note
    gazed = starts[0].spline.position(starts[0].spline.duration)
    assert np.max(np.abs(gazed - robot.half_sitting_joints)) > 0.05          # the gaze moved the body ...
    np.testing.assert_allclose(starts[1].spline.position(starts[1].spline.duration), robot.half_sitting_joints,
                               atol=1e-12)                                    # ... and the way back undid it
    none, _, _, _ = make(robot, scan_surroundings_looks=0, scan_poses_deg=(0.0, 20.0))
    assert none.look(lambda: LookGoal((), (), None, 0.01), Port()).poses_done == 1


def test_a_look_that_comes_back_ends_where_it_began(robot) -> None:
    """The automatic looks (``come_back``): after the last gaze point, back to the posture the look
    began in; without it the look ends at its last gaze, as before."""
    m, loop, log, _ = make(robot)
    point = np.array([[0.7, 0.2, 0.9]])
    out = m.look(lambda: LookGoal((), (), point, 0.01, come_back=True), Port())
    assert out.success and out.poses_done == 2 and "then back to the posture the look began in" in out.message, out
    starts = [c.motion for c in loop.sent if isinstance(c, StartMotion)]
    assert len(starts) == 2 and "back to the posture" in starts[1].note
    np.testing.assert_allclose(starts[1].spline.position(starts[1].spline.duration), robot.half_sitting_joints)
    stay, loop2, _, _ = make(robot)
    out = stay.look(lambda: LookGoal((), (), point, 0.01), Port())
    assert out.success and out.poses_done == 1 and "back" not in out.message
    assert sum(isinstance(c, StartMotion) for c in loop2.sent) == 1


class ShortLoop(FakeLoop):
    """Answers the ``short``-th motion (0-based) with TARGET_NOT_REACHED: a damper held it short."""

    def __init__(self, short: int) -> None:
        super().__init__(hold=True)
        self.short, self.n = short, 0

    def send(self, command) -> None:
        super().send(command)
        if isinstance(command, StartMotion):
            k, self.n = self.n, self.n + 1
            code, text = ((C.TARGET_NOT_REACHED, "the reference ended and the hand stayed 1.2 mm off its end after "
                           "the settle timeout (min distance 0.0100 m); holding here") if k == self.short
                          else (C.SUCCESS, "done"))
            threading.Timer(0.05, lambda: self.manager.on_event(
                MotionFinished(command.motion.id, int(code), text, SUMMARY, 1.0, ""))).start()


def test_a_look_held_short_of_a_pose_looks_from_there_and_goes_on(robot) -> None:
    """A damper or a limit that holds the body a little short of a look's pose (TARGET_NOT_REACHED;
    the loop holds it there) does not end the look: it looks from there, goes on and says so."""
    m, loop, log, _ = make(robot, ShortLoop(short=1))
    out = m.look(lambda: LookGoal((0.1, -0.1, 0.0), (0.3, 0.2, 0.1), None, 0.01), Port())
    assert out.success and out.poses_done == 3, out
    assert "pose 1 held short (the reference ended and the hand stayed 1.2 mm off" in out.message, out.message
    assert sum(isinstance(c, StartMotion) for c in loop.sent) == 3


def test_stale_joint_states_abort_the_running_motion_once(robot) -> None:
    m, loop, log, state = make(robot, FakeLoop(hold=True))
    assert m.trajectory_topic(lambda: TrajectoryGoal(reference(robot)))
    deadline = time.monotonic() + 10.0
    while m.tracker.status.motion_id is None and time.monotonic() < deadline:
        time.sleep(0.01)
    assert not m.watch_joint_states()                      # fresh: nothing
    state["age"] = m.config.joint_states_abort_s + 0.5
    assert m.watch_joint_states()
    assert not m.watch_joint_states()                      # once per motion
    stop = loop.sent[-1]
    assert isinstance(stop, StopMotion) and stop.code == C.ABORTED and "/joint_states stale" in stop.message


def test_the_loop_exiting_ends_pending_motions_aborted(robot) -> None:
    m, loop, log, _ = make(robot, FakeLoop(hold=True))
    result = {}
    worker = threading.Thread(target=lambda: result.update(out=m.execute(lambda: TrajectoryGoal(reference(robot)),
                                                                          Port())))
    worker.start()
    deadline = time.monotonic() + 10.0
    while not any(isinstance(c, StartMotion) for c in loop.sent) and time.monotonic() < deadline:
        time.sleep(0.01)
    loop.up = False
    m.on_event(LoopExited(-9))
    worker.join(10.0)
    assert result["out"].code == C.ABORTED and "control loop process exited" in result["out"].message
    assert "the control loop process exited (-9)" in log.text("error")
    names = {name: (level, message) for name, level, message, _ in m.diagnostics(0.005)}
    assert names["loop"] == (LEVEL_ERROR, "the control loop process is not running")


def test_maps_topics_configuration_and_diagnostics(robot) -> None:
    from types import SimpleNamespace as CloudPoints   # a parsed /voxel_map (io.msgs.CloudPoints' fields)
    m, loop, log, state = make(robot)
    other_frame = CloudPoints(points=np.zeros((2, 3)), dropped_nonfinite=0, frame_id="odom")
    assert not m.map_message(lambda: other_frame)       # another frame: kept out
    assert m.counters.maps_rejected == 1 and "rejected /voxel_map (1 so far)" in log.text("warning")
    voxels = np.array([[0.8, 0.0, 0.9], [0.8, 0.02, 0.9]])
    assert m.map_message(lambda: CloudPoints(points=voxels, dropped_nonfinite=0, frame_id="world"))
    assert isinstance(loop.sent[-1], SetMap) and loop.sent[-1].tree.n_spheres == 2
    assert not m.targets_topic(lambda: None)            # dual_arm_follow is false: ignored, said
    assert m.counters.target_messages_ignored == 1 and "dual_arm_follow is false" in log.text("info")
    m.reconfigure({"dual_arm_follow": True, "scan_dwell_s": 0.2, "not_a_field": 1})
    assert m.config.dual_arm_follow and m.requests.config.scan_dwell_s == 0.2
    ok, message = m.reconfigure({"dual_arm_sequential_count": 0}) or m.sequential()
    assert not ok and "dual_arm_sequential_count must be in 1..1000" in message
    names = {name: (level, message, values) for name, level, message, values in m.diagnostics(0.005)}
    assert set(names) == {"execution", "loop", "inputs"}
    assert names["loop"][0] == LEVEL_OK and names["loop"][2]["nominal_rate_hz"] == pytest.approx(200.0)
    assert names["inputs"][0] == LEVEL_OK and names["inputs"][2]["map_voxels"] == 2
    assert names["inputs"][2]["maps_rejected"] == 1 and names["execution"][2]["target_messages_ignored"] == 1
    state["age"] = math.inf
    blind, _, _, _ = make(robot, joints=False, age=math.inf)
    inputs = {name: (level, values) for name, level, _, values in blind.diagnostics(0.005)}["inputs"]
    assert inputs[0] == LEVEL_WARN and inputs[1]["joint_states_age_s"] == "never"


def pipe(centre, length_m: float = 0.4, radius_m: float = 0.03, h: float = 0.02) -> np.ndarray:
    """Voxel centres (2 cm grid) of a pipe along y through ``centre``."""
    g = np.arange(-0.5 * length_m, 0.5 * length_m + 1e-9, h)
    r = np.arange(-radius_m, radius_m + 1e-9, h)
    pts = np.array([[x, y, z] for y in g for x in r for z in r if x * x + z * z <= radius_m ** 2 + 1e-9])
    return np.round((pts + np.asarray(centre)) / h) * h + h / 2


def test_the_end_of_a_reach_says_whether_a_hand_touches_and_what(robot) -> None:
    """Issue 33, point 4: the result carries the contact at the end, on the WHOLE map (the target's
    object included; min_distance_m leaves it out), by the planner's own test: a reach that ends
    with the hand on a pipe reports the contact, the target's object and its distance; one that
    ends in free air reports none and how far the nearest voxel is. The test is the planner's
    (``RetreatPlanner.classify_start``): a posture it calls in contact is one the next plan
    retreats from first."""
    from types import SimpleNamespace

    from humanoid_reach_ros.planning.retreat import RetreatParams
    hand = robot.frame_pose(robot.config(robot.half_sitting_joints, robot.base_on_feet(robot.half_sitting_joints)),
                            robot.limbs["right_arm"].tip).translation
    reach = RetreatParams().contact_distance_m
    for centre, touching in [(hand + [0.0, 0.0, -0.04], True), (hand + [0.35, 0.0, 0.0], False)]:
        m, _, log, _ = make(robot)
        cloud = SimpleNamespace(points=pipe(centre), dropped_nonfinite=0, frame_id="world")
        assert m.map_message(lambda c=cloud: c)
        out = m.execute(lambda: TrajectoryGoal(reference(robot)), Port())
        s = out.summary
        assert out.success and s["hand_in_contact"] is touching, (s, log.text())
        if touching:
            assert s["contact_distance_m"] < reach and "on the target object (" in s["contact_with"], s
            assert f"voxels within {1e3 * m.config.target_exclusion_radius_m:.0f} mm of the target" in s["contact_with"]
            assert "hand in contact" in log.text("info")
        else:
            assert s["contact_with"] == "" and 0.2 < s["contact_distance_m"] < 0.4, s
            assert "no hand in contact: the nearest voxel is" in log.text("info")
    # no map, or no joint states at the end: no contact claimed, and said why
    m, _, _, _ = make(robot)
    assert m.requests.contact_at(robot.half_sitting_joints).as_dict() == {
        "hand_in_contact": False, "contact_distance_m": math.inf, "contact_with": "no map"}
    c = m.requests.contact_at(None, "no /joint_states received")
    assert not c.in_contact and c.with_what == "unknown: no /joint_states received"


def test_a_touch_away_from_the_target_is_named_by_its_region(robot) -> None:
    """A hand resting on voxels farther than target_exclusion_radius_m from the motion's final
    hand position: the region is named, not the target's object."""
    from types import SimpleNamespace
    m, _, _, _ = make(robot)
    j = robot.half_sitting_joints
    hand = robot.frame_pose(robot.config(j, robot.base_on_feet(j)), robot.limbs["right_arm"].tip).translation
    voxels = pipe(hand + [0.0, 0.0, -0.04])
    assert m.map_message(lambda: SimpleNamespace(points=voxels, dropped_nonfinite=0, frame_id="world"))
    m.requests._target_p = np.array([hand, hand + [0.0, 0.0, 0.5]])   # the motion ended 0.5 m above
    c = m.requests.contact_at(j)
    assert c.in_contact and "on the voxels around [" in c.with_what and "not the target's object" in c.with_what, c
