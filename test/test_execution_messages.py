"""The messages between the executor node and its loop process (``execution/messages.py``),
without ROS: every command and event survives ``multiprocessing``'s pickling through a real
pipe, the status carries every field the supervisor reports and the node reads, and the
messages cannot be changed after they are made."""
from __future__ import annotations

import dataclasses
import math
import multiprocessing
import pickle
from multiprocessing.reduction import ForkingPickler

import numpy as np
import pytest

from humanoid_reach_ros.codes import ExecuteCode as C
from humanoid_reach_ros.execution.engines import DualArmMetrics
from humanoid_reach_ros.execution.messages import (Close, LogLine, LoopExited, LoopFailed, LoopReady, LoopStatus,
                                                   MotionFinished, MotionStarted, MotionSummary, SetMap, StartMotion,
                                                   StopMotion)
from humanoid_reach_ros.execution.supervisor import IDLE, RUN, ExecutionSupervisor, Motion

#: the status fields the manager reads (execution/manager.py: the tracker, the feedback, the diagnostics)
PARENT_READS = {"mode": str, "engine": str, "motion_id": (int, type(None)), "motion_label": str, "progress": float,
                "last": object, "dual_targets": object, "ticks": int, "published": int, "steps": int,
                "overruns": int, "missed_deadlines": int, "last_joints": (np.ndarray, type(None)),
                "step_p50_ms": float, "step_p99_ms": float, "step_max_ms": float, "hold_step_p99_ms": float,
                "slow_publishes": int, "max_publish_ms": float}


def _through_pipe(message):
    """``message`` sent through a multiprocessing pipe (the loop process's way: a Connection)."""
    ours, theirs = multiprocessing.Pipe()
    try:
        ours.send(message)
        return theirs.recv()
    finally:
        ours.close()
        theirs.close()


def _equal(a, b) -> bool:
    """Field-wise equality, numpy arrays by value."""
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        return type(a) is type(b) and all(_equal(getattr(a, f.name), getattr(b, f.name))
                                          for f in dataclasses.fields(a))
    if isinstance(a, np.ndarray):
        return isinstance(b, np.ndarray) and a.dtype == b.dtype and np.array_equal(a, b)
    return a == b or (isinstance(a, float) and math.isnan(a) and math.isnan(b))


def _motion() -> Motion:
    return Motion(7, "goal #7", kind="dual", arm="both", q_measured=np.linspace(0.0, 1.0, 37), note="a note")


def _status() -> LoopStatus:
    return LoopStatus(mode=RUN, engine="dual", motion_id=7, motion_label="goal #7", progress=0.25,
                      last=DualArmMetrics(0.1, 0.25, 1e-3, 2e-3, 3e-3, 4e-3), dual_targets=None, ticks=100,
                      published=99, steps=98, overruns=1, missed_deadlines=2, last_joints=np.arange(30.0),
                      step_p50_ms=1.5, step_p99_ms=3.0, step_max_ms=4.5, hold_step_p99_ms=0.5, slow_publishes=3,
                      max_publish_ms=6.5)


def _summary() -> MotionSummary:
    return MotionSummary(duration_s=1.5, steps=300, overruns=2, max_com_error_m=1e-3, min_distance_m=math.inf,
                         final_hand_error_m=2e-4, final_hand_error_rad=1e-3)


ALL_MESSAGES = [
    StopMotion(7, int(C.CANCELED), "canceled by the client"),
    StopMotion(None, int(C.ABORTED), "stopped: /joint_states stale"),
    SetMap(None),
    Close(),
    LoopReady(warm_up_s=2.5, publishing="gil-free", tick="SCHED_FIFO 80", solver="SCHED_FIFO 79", memory="locked"),
    LoopFailed("RuntimeError: no robot\ntraceback"),
    LoopStatus(),
    _status(),
    MotionStarted(7, "12 steps", "the last command"),
    MotionFinished(7, int(C.SUCCESS), "both hands at their targets", _summary(), 1.0, "12 steps"),
    LogLine("warning", "goal #7: overrun at step 3"),
    LoopExited(None),
    LoopExited(-15),
]


@pytest.mark.parametrize("message", ALL_MESSAGES, ids=lambda m: type(m).__name__)
def test_every_command_and_event_survives_the_pipe(message) -> None:
    back = _through_pipe(message)
    assert type(back) is type(message) and _equal(back, message)
    assert _equal(ForkingPickler.loads(bytes(ForkingPickler.dumps(message))), message)


def test_a_start_carries_the_motion_and_a_map_its_tree() -> None:
    back = _through_pipe(StartMotion(_motion()))
    assert isinstance(back, StartMotion) and back.motion.id == 7 and back.motion.label == "goal #7"
    assert back.motion.dual and np.array_equal(back.motion.q_measured, np.linspace(0.0, 1.0, 37))
    tree = {"centers": np.zeros((5, 3)), "radius": 0.02}      # any picklable tree goes as it is
    back = _through_pipe(SetMap(tree))
    assert np.array_equal(back.tree["centers"], tree["centers"]) and back.tree["radius"] == 0.02


def test_every_kind_is_covered_and_the_child_dispatches_on_the_class() -> None:
    kinds = {type(m) for m in ALL_MESSAGES} | {StartMotion}
    assert kinds == {StartMotion, StopMotion, SetMap, Close, LoopReady, LoopFailed, LoopStatus, MotionStarted,
                     MotionFinished, LogLine, LoopExited}

    def dispatch(cmd) -> str:       # as child_main does
        match cmd:
            case Close():
                return "close"
            case StartMotion(motion=motion):
                return f"start {motion.id}"
            case StopMotion(motion_id=mid, code=code, message=message):
                return f"stop {mid} {code} {message}"
            case SetMap(tree=tree):
                return f"map {tree}"
        return "unknown"

    assert [dispatch(_through_pipe(c)) for c in (StartMotion(_motion()), StopMotion(None, 4, "x"), SetMap(None),
                                                  Close(), ("close",))] == \
        ["start 7", "stop None 4 x", "map None", "close", "unknown"]


def test_the_status_has_every_field_the_supervisor_reports_and_the_node_reads() -> None:
    sup = ExecutionSupervisor(object())
    reported = sup.status()
    st = LoopStatus(**reported, slow_publishes=2, max_publish_ms=7.0)     # as the loop process builds it
    assert {f.name for f in dataclasses.fields(LoopStatus)} == set(reported) | {"slow_publishes", "max_publish_ms"}
    assert st.mode == IDLE and st.motion_id is None and st.slow_publishes == 2 and st.max_publish_ms == 7.0
    full = _through_pipe(_status())
    for name, kind in PARENT_READS.items():
        assert isinstance(getattr(full, name), kind), name
    assert full.last.hand_error_m == 3e-3 and np.array_equal(full.last_joints, np.arange(30.0))
    before = LoopStatus()              # the node's status before the loop's first
    assert before.mode == IDLE and before.motion_id is None and before.last is None and before.steps == 0


def test_the_summary_is_the_supervisors_and_the_ready_lists_the_realtime_outcomes() -> None:
    m = _motion()
    m.started, m.steps = 10.0, 5
    summary = MotionSummary(**m.summary(12.0))
    assert summary.duration_s == pytest.approx(2.0) and summary.steps == 5
    assert summary.as_dict() == m.summary(12.0)
    ready = LoopReady(warm_up_s=1.0, publishing="gil-free", tick="SCHED_FIFO 80", solver="SCHED_OTHER (EPERM)")
    assert ready.realtime() == [("publishing", "gil-free"), ("tick", "SCHED_FIFO 80"),
                                ("solver", "SCHED_OTHER (EPERM)")]
    assert dataclasses.replace(ready, memory="locked").realtime()[1] == ("memory", "locked")


def test_messages_are_frozen_and_the_status_pickles_no_bigger_than_the_dict() -> None:
    st = _status()
    with pytest.raises(dataclasses.FrozenInstanceError):
        st.mode = IDLE          # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        StopMotion(1, 2, "x").code = 3       # type: ignore[misc]
    as_dict = {f.name: getattr(st, f.name) for f in dataclasses.fields(st)}
    size = len(pickle.dumps(st, pickle.HIGHEST_PROTOCOL))
    dict_size = len(pickle.dumps(as_dict, pickle.HIGHEST_PROTOCOL))
    assert size <= dict_size + 120, (size, dict_size)      # the class reference only
