"""The messages between the executor node and its control loop process, as typed values.

What: one frozen dataclass per command the node sends the loop process (:class:`StartMotion`,
:class:`StopMotion`, :class:`SetMap`, :class:`Close`) and per event the loop process sends
back (:class:`LoopReady`, :class:`LoopFailed`, :class:`LoopStatus`, :class:`MotionStarted`,
:class:`MotionFinished` with its :class:`MotionSummary`, :class:`LogLine`), plus
:class:`LoopExited`, which the node's reader makes up when the pipe closes.

Why: the two processes used to exchange untyped tuples (``("stop", id, code, message)``)
and a 17-key status dict read with ``.get()``; a renamed key or a reordered tuple failed
silently on the other side. Here every field is named, typed and has its unit, the child
dispatches on the class (``match``) and the parent reads attributes.

Pickling stays cheap: plain dataclasses of numbers, strings, numpy arrays, the supervisor's
``Motion`` and the map's ``SphereTree`` as before (no ``__slots__``: unpickling a frozen
dataclass then is one ``__dict__`` update). ROS-free: nothing here imports rclpy, ``io/`` or
``nodes/``.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Union

import numpy as np

from humanoid_reach_ros.execution.supervisor import IDLE, Motion


# ---------------------------------------------------------------- node -> loop process
@dataclass(frozen=True)
class StartMotion:
    """Start ``motion`` (it preempts the running one)."""

    motion: Motion


@dataclass(frozen=True)
class StopMotion:
    """Stop motion ``motion_id`` (``None``: whichever runs) with ``code`` and hold."""

    motion_id: int | None
    code: int                              # ExecuteCode
    message: str


@dataclass(frozen=True)
class SetMap:
    """The new collision map, applied before the next step (``None``: no obstacles)."""

    tree: Any                              # SphereTree | None


@dataclass(frozen=True)
class Close:
    """Abort a running motion, tear the loop process's node down and exit."""


LoopCommand = Union[StartMotion, StopMotion, SetMap, Close]


# ---------------------------------------------------------------- loop process -> node
@dataclass(frozen=True)
class LoopReady:
    """The loop runs: how long the kernels' warm-up took and what scheduling it got."""

    warm_up_s: float                       # building and warming up the engines [s]
    publishing: str                        # "gil-free" | "rclpy (<why>)" (GilFreePublisher.mode)
    tick: str                              # the tick thread's scheduling ("SCHED_FIFO ..." or why not)
    solver: str                            # the solver thread's scheduling
    memory: str = ""                       # the outcome of locking memory ("": not asked)

    def realtime(self) -> list[tuple[str, str]]:
        """(what, outcome) of the publishing, memory (when asked), tick and solver set-up."""
        out = [("publishing", self.publishing)]
        if self.memory:
            out.append(("memory", self.memory))
        return out + [("tick", self.tick), ("solver", self.solver)]


@dataclass(frozen=True)
class LoopFailed:
    """The loop process could not start (the exception and its traceback)."""

    text: str


@dataclass(frozen=True)
class LoopStatus:
    """The supervisor's state and the loop's counters, sent every ``status_period_s`` while a
    motion runs or settles, every second while holding or idle, and after each event. The
    defaults are the state before the first status (idle, nothing counted)."""

    mode: str = IDLE                       # "idle" | "running" | "settling" | "holding"
    engine: str = ""                       # "executor" | "dual": which engine made the last command ("": no status yet)
    motion_id: int | None = None           # the running motion (None: none runs)
    motion_label: str = ""                 # its label ("goal #3", ...), "" when none runs
    progress: float = 0.0                  # of the running motion, 0..1
    last: Any = None                       # StepMetrics | DualArmMetrics of its last published step, or None
    dual_targets: Any = None               # (right, left) pin.SE3 in world the dual-arm engine follows, or None
    ticks: int = 0                         # deadlines ticked since the loop started
    published: int = 0                     # commands published
    steps: int = 0                         # steps computed and published
    overruns: int = 0                      # deadlines whose step was not ready (last command held)
    missed_deadlines: int = 0              # deadlines the tick thread skipped (more than a period late)
    last_joints: np.ndarray | None = None  # the last commanded joints [rad], None before the first command
    step_p50_ms: float = 0.0               # median step time over the recent steps [ms]
    step_p99_ms: float = 0.0               # 99th percentile step time [ms]
    step_max_ms: float = 0.0               # longest recent step [ms]
    hold_step_p99_ms: float = 0.0          # 99th percentile step time while holding / settling [ms]
    slow_publishes: int = 0                # command publishes that took longer than a period
    max_publish_ms: float = 0.0            # the longest of them [ms]


@dataclass(frozen=True)
class MotionStarted:
    """Motion ``motion_id`` started (from ``source``: "the last command" | "/joint_states")."""

    motion_id: int
    note: str                              # the engine's note (dual arm: the plan), "" if none
    source: str


@dataclass(frozen=True)
class MotionSummary:
    """The figures of a finished motion (the ``ExecuteReach`` result's fields)."""

    duration_s: float                      # from its start to its end [s]
    steps: int                             # steps published
    overruns: int                          # its deadlines whose step was not ready
    max_com_error_m: float                 # largest horizontal COG error [m]
    min_distance_m: float                  # smallest distance to the map [m] (inf: no map / dual arm)
    final_hand_error_m: float              # at its last step [m]
    final_hand_error_rad: float            # at its last step [rad]

    def as_dict(self) -> dict[str, float]:
        """Field -> value (``io/exec_msgs.result_message``'s ``summary``)."""
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class MotionFinished:
    """Motion ``motion_id`` ended with ``code`` (an ExecuteCode), once per motion."""

    motion_id: int
    code: int                              # ExecuteCode
    message: str
    summary: MotionSummary
    progress: float                        # at its last step, 0..1
    note: str                              # the engine's note (as in MotionStarted)


@dataclass(frozen=True)
class LogLine:
    """A line for the node's log."""

    level: str                             # "info" | "warning" | "error"
    text: str


@dataclass(frozen=True)
class LoopExited:
    """The pipe closed: the loop process exited (made up by the node's reader, never sent)."""

    returncode: int | None                 # the process's exit status (None: not reaped yet)


LoopEvent = Union[LoopReady, LoopFailed, LoopStatus, MotionStarted, MotionFinished, LogLine, LoopExited]

__all__ = ["StartMotion", "StopMotion", "SetMap", "Close", "LoopCommand", "LoopReady", "LoopFailed", "LoopStatus",
           "MotionStarted", "MotionSummary", "MotionFinished", "LogLine", "LoopExited", "LoopEvent"]
