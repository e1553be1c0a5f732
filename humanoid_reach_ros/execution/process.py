"""The control loop in a process of its own (the ``reach_executor`` node's child process),
without ROS: the child's publishing is the node layer's (``nodes/reach_executor_loop.py``
gives :func:`child_main` its :class:`LoopOutput`, and is the child's entry point).

Why: in one Python interpreter the ROS callbacks (200 Hz ``/joint_states``, the action
server, map messages), the solver and the tick share one global interpreter lock, and the
5 ms deadlines then wait on whatever callback holds it. Here the supervisor, both engines
and the :class:`~humanoid_reach_ros.execution.loop.ControlLoop` run in a child process
(a fresh interpreter, ``python -m <LoopProcess entry>``) that owns nothing else: no
subscriptions, no executor spinning. It publishes ``/joint_command`` and ``/executor/metrics``
itself through its :class:`LoopOutput` (a publish-only rclpy node, ``<node>_loop``), so a
command never crosses the parent's interpreter.

The parent (the ``reach_executor`` node) talks to it through a pipe, in the typed messages
of :mod:`humanoid_reach_ros.execution.messages` (frozen dataclasses, pickled):

* parent -> child: the :class:`LoopConfig` first, then ``StartMotion(motion)``,
  ``StopMotion(motion_id | None, code, message)``, ``SetMap(tree | None)``, ``Close()``;
  the child dispatches on the class (``match``);
* child -> parent: ``LoopReady(warm_up_s, publishing, tick, solver, memory)`` or
  ``LoopFailed(text)`` (set-up error) once, then ``MotionStarted(motion_id, note, source)``,
  ``MotionFinished(motion_id, code, message, summary, progress, note)``, ``LogLine(level,
  text)`` and ``LoopStatus(...)`` (the supervisor's state and counters, named fields) every
  ``status_period_s`` while a motion runs or settles (every second while holding or idle,
  and after each event); the parent's reader adds ``LoopExited(returncode)`` when the pipe
  closes.

The loop's threads (the supervisor's ``on_start`` / ``on_finish`` / ``log`` run on the tick
and solver threads) only queue a tuple ``(message class, *fields)``; the sender thread builds
the message and pickles it, so typing the messages adds nothing to a deadline's work.

The child asks for ``SCHED_FIFO`` for its loop threads and locks its memory where the OS
allows (:mod:`humanoid_reach_ros.execution.realtime`; the parent logs the outcome once),
ignores SIGINT (the parent stops it with ``Close()``) and dies with its parent
(``PR_SET_PDEATHSIG``).
"""
from __future__ import annotations

import ctypes
import os
import queue
import signal
import socket
import subprocess
import sys
import threading
import time
import traceback
from multiprocessing.connection import Connection
from dataclasses import dataclass, field
from typing import Any, Callable

from humanoid_reach_ros.execution.messages import (Close, LogLine, LoopCommand, LoopEvent, LoopExited, LoopFailed,
                                                   LoopReady, LoopStatus, MotionFinished, MotionStarted,
                                                   MotionSummary, SetMap, StartMotion, StopMotion)

PR_SET_PDEATHSIG = 1
IDLE_STATUS_PERIOD_S = 1.0     # status to the node while nothing moves
_WAKE = ("wake",)              # queued on shutdown: the sender stops at once, not after its idle wait


@dataclass
class LoopConfig:
    """What the child needs to build the loop (picklable)."""

    robot_config: str
    executor_params: Any                   # ExecutorParams
    supervisor: Any                        # SupervisorConfig
    dual_arm: dict | None = None           # regression, workspace, max_speed_mps (None: no dual-arm engine)
    node_name: str = "reach_executor_loop"
    namespace: str = "/"
    command_topic: str = "/joint_command"
    metrics_topic: str = "/executor/metrics"
    map_frame: str = "world"
    metrics_decimation: int = 1
    rt_priority: int = 80
    lock_memory: bool = True
    status_period_s: float = 0.05
    domain_id: int | None = None
    ros_args: list[str] = field(default_factory=list)


# ---------------------------------------------------------------- parent side
class LoopProcess:
    """Start the loop process and exchange commands and events with it."""

    def __init__(self, config: LoopConfig, on_event: Callable[[LoopEvent], None], entry: str) -> None:
        """``entry``: the child's module (``python -m entry <fd>``: it calls :func:`child_main`)."""
        # a fresh interpreter (not multiprocessing's spawn, which re-imports the caller's __main__),
        # one end of a socket pair as a multiprocessing Connection; stdout/stderr shared with the node
        ours, theirs = socket.socketpair()
        self.proc = subprocess.Popen([sys.executable, "-m", entry, str(theirs.fileno())],
                                     pass_fds=[theirs.fileno()], stdin=subprocess.DEVNULL, env=dict(os.environ))
        theirs.close()
        self._conn = Connection(ours.detach())
        self._send_lock = threading.Lock()
        self.on_event = on_event
        self.send(config)
        self._ready = threading.Event()
        self.info: LoopReady | None = None
        self.failure = ""
        self._reader = threading.Thread(target=self._read, name="executor_loop_events", daemon=True)
        self._reader.start()

    def wait_ready(self, timeout: float) -> LoopReady:
        """Block until the child reports ready (its info) or failed (RuntimeError)."""
        if not self._ready.wait(timeout):
            raise RuntimeError(f"the control loop process did not start within {timeout:g} s")
        if self.failure:
            raise RuntimeError(f"the control loop process failed to start: {self.failure}")
        if self.info is None:
            raise RuntimeError(f"the control loop process exited before it was ready ({self.proc.poll()})")
        return self.info

    def alive(self) -> bool:
        return self.proc.poll() is None

    def send(self, command: LoopCommand) -> None:
        with self._send_lock:
            self._conn.send(command)

    def request_close(self) -> None:
        """Ask the child to stop (it aborts a motion, tears its node down and exits); returns at
        once, so the parent can tear its own node down meanwhile (:meth:`close` waits)."""
        try:
            self.send(Close())
        except (OSError, EOFError, BrokenPipeError):
            pass

    def close(self, timeout: float = 3.0) -> None:
        """Stop the child and wait for it (``timeout``; then SIGTERM, then SIGKILL)."""
        self.request_close()
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.terminate()
            try:
                self.proc.wait(2.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(2.0)

    def _read(self) -> None:
        while True:
            try:
                event = self._conn.recv()
            except (EOFError, OSError):
                self.on_event(LoopExited(self.proc.poll()))
                self._ready.set()
                return
            if isinstance(event, LoopReady):
                self.info = event
                self._ready.set()
            elif isinstance(event, LoopFailed):
                self.failure = event.text
                self._ready.set()
            try:
                self.on_event(event)
            except Exception:  # a handler's failure must not stop the events
                traceback.print_exc()


# ---------------------------------------------------------------- child side
def _die_with_parent() -> None:
    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    except OSError:
        pass


@dataclass
class LoopOutput:
    """Where the loop's commands go, made in the child by the node layer's factory
    (``make_output(config, joint_names, log)``). ``sink(joints, metrics, overruns)`` runs on the tick thread
    every published step; ``mode``: how it publishes (logged once); ``slow``: the count and the
    longest [s] of the writes that took longer than a period; ``close()`` at the end."""

    sink: Callable[[Any, Any, int], None]
    mode: str
    slow: dict
    close: Callable[[], None]


def child_main(conn, config: LoopConfig, make_output: Callable[..., LoopOutput]) -> None:
    """Entry point of the loop process (``make_output``: see :class:`LoopOutput`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _die_with_parent()
    out: queue.SimpleQueue = queue.SimpleQueue()
    try:
        loop, sup, output, rt = _build(config, out, make_output)
        slow = output.slow
    except Exception as exc:
        conn.send(LoopFailed(f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}"))
        conn.close()
        return
    stop = threading.Event()

    # The threads that feed the loop (this one: commands and maps from the node; the sender:
    # outcomes and status) hold the interpreter lock while they (un)pickle. At normal priority a
    # busy machine can preempt them *while they hold it*, and the real-time solver then waits on
    # a descheduled thread (priority inversion through the GIL: the graph's sporadic 10 ms
    # steps). They run SCHED_FIFO too, well below the loop's threads, where the OS allows; the
    # lock is handed over every 0.5 ms rather than every 5 ms.
    from humanoid_reach_ros.execution.realtime import REALTIME_SWITCH_INTERVAL_S, make_feeder_thread_realtime
    from humanoid_reach_ros.execution.supervisor import RUN, SETTLE
    sys.setswitchinterval(REALTIME_SWITCH_INTERVAL_S)

    def sender() -> None:
        # status every status_period_s while a motion runs or settles; while holding or idle (nothing
        # changes but the hold's age) once per IDLE_STATUS_PERIOD_S, so a standing robot costs no
        # wake-ups here (an outcome or a start wakes the thread at once through the queue)
        make_feeder_thread_realtime(config.rt_priority)
        last_status = -float("inf")

        def period() -> float:
            moving = sup.mode in (RUN, SETTLE)
            return config.status_period_s if moving else max(config.status_period_s, IDLE_STATUS_PERIOD_S)

        while not stop.is_set():
            p = period()
            wait = min(p / 2, max(0.0, last_status + p - time.monotonic()))
            try:
                event = out.get(timeout=wait + 1e-3)
            except queue.Empty:
                event = None
            if event is _WAKE:      # shutting down: no waiting out the idle period
                continue
            try:
                if event is not None:
                    conn.send(event[0](*event[1:]))
                now = time.monotonic()
                if event is not None or now >= last_status + period():
                    last_status = now
                    conn.send(LoopStatus(**sup.status(), slow_publishes=slow["count"],
                                         max_publish_ms=slow["max_s"] * 1e3))
            except (OSError, EOFError, BrokenPipeError):
                stop.set()

    # no collector pause inside a deadline: everything built so far is frozen out of the collector's
    # view, and the young generation is collected rarely (the loop allocates few cyclic objects)
    import gc
    gc.collect()
    gc.freeze()
    gc.set_threshold(100_000, 50, 1000)
    conn.send(rt)
    send_thread = threading.Thread(target=sender, name="executor_loop_sender", daemon=True)
    send_thread.start()
    make_feeder_thread_realtime(config.rt_priority)
    try:
        while not stop.is_set():
            try:
                cmd = conn.recv()
            except (EOFError, OSError):
                break
            match cmd:
                case Close():
                    break
                case StartMotion(motion=motion):
                    sup.submit(motion)
                case StopMotion(motion_id=motion_id, code=code, message=message):
                    sup.stop(motion_id, code, message)
                case SetMap(tree=tree):
                    sup.set_map(tree)
    finally:
        sup.close()
        loop.stop()
        stop.set()
        out.put(_WAKE)
        send_thread.join(1.0)
        # the last outcomes (e.g. ABORTED on shutdown) still reach the parent
        while True:
            try:
                event = out.get_nowait()
                if event is not _WAKE:
                    conn.send(event[0](*event[1:]))
            except (queue.Empty, OSError, EOFError, BrokenPipeError):
                break
        try:
            output.close()
        finally:
            conn.close()


def _build(config: LoopConfig, out: queue.SimpleQueue, make_output):
    """Engines, supervisor, output and the running loop; returns (loop, sup, output,
    :class:`LoopReady`). What the supervisor reports is queued on ``out`` as
    ``(message class, *fields)`` (built by the sender thread, off the deadlines)."""
    from humanoid_reach_ros.control.executor import WholeBodyExecutor
    from humanoid_reach_ros.execution.engines import DualArmEngine, TrajectoryEngine
    from humanoid_reach_ros.execution.loop import ControlLoop
    from humanoid_reach_ros.execution.realtime import lock_memory
    from humanoid_reach_ros.execution.supervisor import ExecutionSupervisor
    from humanoid_reach_ros.robot.model import RobotModel
    from humanoid_reach_ros.robot.shapes import load_collision_model

    t0 = time.perf_counter()
    robot = RobotModel(config.robot_config)
    cm = load_collision_model(None, robot)
    executor = WholeBodyExecutor(robot, cm, config.executor_params)
    executor.warm_up()
    _warm_up_cluttered(WholeBodyExecutor(robot, cm, config.executor_params), robot)
    dual = None
    if config.dual_arm is not None:
        from humanoid_reach_ros.dual_arm.controller import ControllerConfig, DualArmReachController
        from humanoid_reach_ros.dual_arm.torso_regression import ReachWorkspace, TorsoRegression
        d = config.dual_arm
        ctl = DualArmReachController(RobotModel(config.robot_config), TorsoRegression.load(d["regression"]),
                                     ReachWorkspace.load(d["workspace"]),
                                     ControllerConfig(period_s=config.supervisor.period_s,
                                                      max_speed_mps=d["max_speed_mps"]))
        warm_up_dual(ctl, robot)
        dual = DualArmEngine(ctl, RobotModel(config.robot_config))
    warm_s = time.perf_counter() - t0

    def log(level: str, text: str) -> None:
        out.put((LogLine, level, text))

    output = make_output(config, robot.joint_names, log)

    def on_finish(m) -> None:   # the tick or solver thread: a tuple only, the sender builds the message
        out.put((_finished, m.id, int(m.code), m.message, m.summary(time.monotonic()),
                 float(m.last.progress) if m.last is not None else 0.0, m.note))

    def on_start(m) -> None:
        out.put((MotionStarted, m.id, m.note, m.source))

    sup = ExecutionSupervisor(TrajectoryEngine(executor), dual, config.supervisor, time.monotonic, output.sink,
                              on_finish, on_start, log)
    loop = ControlLoop(sup, config.supervisor.period_s, config.rt_priority,
                       on_error=lambda text: log("error", text))
    memory = lock_memory()[1] if config.lock_memory and config.rt_priority > 0 else ""
    threads = loop.start()
    rt = LoopReady(warm_up_s=warm_s, publishing=output.mode, tick=threads.get("tick", ""),
                   solver=threads.get("solver", ""), memory=memory)
    return loop, sup, output, rt


def _finished(motion_id: int, code: int, message: str, summary: dict, progress: float, note: str) -> MotionFinished:
    """The :class:`MotionFinished` of what ``on_finish`` queued (the sender thread builds it)."""
    return MotionFinished(motion_id, code, message, MotionSummary(**summary), progress, note)


def _warm_up_cluttered(executor, robot) -> None:
    """A few steps of a throw-away executor among many spheres within the distance bound, so
    that no first step of a real motion pays a first-call cost (seen: 18 ms)."""
    import numpy as np

    from humanoid_reach_ros.geometry.sphere_tree import SphereTree
    from humanoid_reach_ros.geometry.trajectory import SplineTrajectory
    q = robot.half_sitting()
    hand = robot.frame_pose(q, robot.limbs["right_arm"].tip).translation
    g = np.mgrid[0.08:0.2:0.02, -0.1:0.1:0.02, -0.1:0.1:0.02].reshape(3, -1).T
    executor.set_environment(SphereTree.from_voxels(np.ascontiguousarray(hand + g), 0.02))
    joints = robot.half_sitting_joints
    executor.start(q, SplineTrajectory(np.vstack([joints, joints]), np.array([0.0, 0.05])), "right")
    for _ in range(20):
        executor.step()


def warm_up_dual(ctl, robot) -> None:
    """One target pair planned and stepped on the dual-arm controller (first-call costs)."""
    ctl.reset(robot.half_sitting())
    ws = ctl.ws
    t = ws.targets(0.5 * (ws.right_lower + ws.right_upper), 0.5 * (ws.left_lower + ws.left_upper))
    ctl.set_targets(t.p_right, t.R_right, t.p_left, t.R_left)
    for _ in range(3):
        ctl.step()
    ctl.reset(robot.half_sitting())


__all__ = ["LoopConfig", "LoopOutput", "LoopProcess", "child_main"]
