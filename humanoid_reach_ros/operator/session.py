"""``reach_operator``'s flow: scan or look -> marker -> plan with automatic looks -> execute.

Written against :class:`OperatorClient` (plan, execute, look, watch the marker, read the
executor's parameters; ``nodes/reach_operator.py`` implements it with rclpy), so that the
flow, its lines and its exit codes run, and are tested, without ROS. A client's wait raises
:class:`Canceled` on Ctrl-C; outcomes of goals are ``"done" | "unavailable" | "rejected" |
"timeout" | "canceled"`` with the result (or None). Responses and results are read by
attribute (messages, or stand-ins in tests).
"""
from __future__ import annotations

import json
import math
import time
from contextlib import AbstractContextManager
from typing import Any, Callable, Protocol, TextIO

import numpy as np

from humanoid_reach_ros.codes import ExecuteCode, PlanError
from humanoid_reach_ros.operator.report import (
    EXIT, LOOK_FIELDS, Progress, ProgressPrinter, code_text, execution_report,
    execution_summary, exit_class, head_pose_line, plan_report, plan_summary)
from humanoid_reach_ros.operator.marker import MarkerWatch

WAIT_NOTE_FIRST_S = 2.0   # waiting for a server: the first line after this long [s] (discovery can take 1 s) ...
WAIT_NOTE_EVERY_S = 5.0   # ... then one every this long, with the seconds left
MARKER_FRESH_WAIT_S = 2.0    # a /target_pose within this long of finding its publisher: seen now (>= 2 Hz in view)
MARKER_DISCOVERY_S = 5.0     # a marker_localizer (a /target_pose publisher) gets this long to be discovered
# then its diagnostics (1 Hz, the last marker position) this long at most (2.5 s: ci46's fresh CLI fell back to
# marker_look_deg with the marker's position known)
MARKER_DIAGNOSTICS_WAIT_S = 5.0
MAP_REPORT_WAIT_S = 2.5     # after --scan / --look: the voxel mapper's diagnostics (1 Hz, the map's size) this long
MARKER_LOOK_DWELL_S = 0.1    # the head's hold there (the wait for the marker follows)


class Canceled(Exception):
    """Ctrl-C during a wait of the client."""


class Countdown:
    """The lines of a long wait on ``err``: ``reach_operator: waiting for WHAT ... 55 s left``, the
    first ``first_s`` after the start, then at each multiple of ``WAIT_NOTE_EVERY_S``."""

    def __init__(self, err: TextIO, what: str, total_s: float, first_s: float = WAIT_NOTE_FIRST_S) -> None:
        self.err, self.what, self.total_s = err, what, total_s
        self.t0 = time.monotonic()
        self.note = self.t0 + first_s

    def tick(self) -> None:
        now = time.monotonic()
        if now >= self.note:   # at 2 s, then at 5, 10, 15 ... s
            self.note = self.t0 + WAIT_NOTE_EVERY_S * (math.floor((now - self.t0) / WAIT_NOTE_EVERY_S) + 1)
            self.err.write(f"reach_operator: waiting for {self.what} ... "
                           f"{max(0.0, self.total_s - (now - self.t0)):.0f} s left\n")
            self.err.flush()


class OperatorClient(Protocol):
    timeout_s: float

    def spin_until(self, done: Callable[[], bool], timeout_s: float | None, cancelable: bool = True) -> bool: ...

    def plan(self, req: Any) -> Any | None:
        """The planner's response; None when it is missing or does not answer (said on ``err``)."""

    def execute(self, trajectory: Any, arm: int, args: Any,
                on_feedback: Callable[[Progress], None]) -> tuple[str, Any]: ...

    def look(self, yaw_rad: list[float], pitch_rad: list[float], dwell_s: float, on_feedback: Callable[[Any], None],
             gaze_points: np.ndarray | None = None, come_back: bool = False) -> tuple[str, Any]: ...

    def wait_for_look(self, owner: str) -> bool:
        """Wait (``timeout_s``, with waiting lines) for the /look server; False when it did not come."""

    def watch_marker(self) -> AbstractContextManager[MarkerWatch]: ...

    def watch_map(self) -> AbstractContextManager[MarkerWatch]:
        """A watch fed by ``/diagnostics`` only (the voxel mapper's map size)."""

    def executor_parameters(self, names: list[str]) -> dict[str, Any]: ...


class OperatorSession:
    """One command line's run on ``client``: lines on ``text``, failures on ``err``, the --json
    summary in ``summary``; each step returns the exit code to stop with (``EXIT["success"]``: go on)."""

    def __init__(self, client: OperatorClient, args: Any, text: TextIO, err: TextIO,
                 summary: dict[str, Any] | None = None) -> None:
        self.client, self.args, self.text, self.err = client, args, text, err
        self.summary = {"look": None, "plan": None, "execution": None} if summary is None else summary

    def say(self, line: str) -> None:
        self.text.write(line + "\n")
        self.text.flush()

    def run(self, req: Any, out: TextIO) -> int:
        """The whole flow; with --json the summary (and exit code) as one line on ``out``."""
        code = self.steps(req)
        self.summary["exit_code"] = code
        if self.args.json:
            out.write(json.dumps(self.summary) + "\n")
            out.flush()
        return code

    def steps(self, req: Any) -> int:
        a = self.args
        if a.scan or a.look is not None:
            code = self.look()
            if code != EXIT["success"] or not a.plan:
                return code
        if a.marker and (code := self.ensure_marker_target()) != EXIT["success"]:
            return code
        target = "the rest posture (home)" if a.home else "the marker's /target_pose" if a.marker else \
            f"({', '.join(f'{v:g}' for v in a.target)}) in {a.frame or 'world'}"
        self.say(f"planning to {target}" + ("" if a.home else f", arm {a.arm}") + " ...")
        resp, code = self.plan_with_looks(req)
        if resp is None:
            return code
        self.summary["plan"] = plan_summary(resp)
        if not resp.success or resp.error_code.val != 0:
            self.err.write(f"plan failed: {code_text(resp.error_code.val, resp.message)}\n")
            return exit_class(resp.error_code.val) or EXIT["internal"]
        self.text.write(plan_report(self.summary["plan"]) + "\n")
        return self.execute(resp) if a.execute else EXIT["success"]

    def execute(self, resp: Any) -> int:
        """``--execute``: the plan's trajectory through the client, a progress bar from its feedback."""
        self.text.write("executing ...\n")
        printer = ProgressPrinter(self.text)
        try:
            outcome, result = self.client.execute(resp.trajectory, resp.arm, self.args, printer.update)
        finally:
            printer.close()
        e = self.summary["execution"] = execution_summary(outcome, result)
        if outcome == "unavailable":
            return EXIT["unavailable"]
        if outcome == "timeout":
            self.err.write(f"execution: no answer from /execute_reach within the trajectory duration + "
                           f"{self.args.timeout:g} s\n")
            return EXIT["unavailable"]
        if outcome == "rejected":
            self.err.write("execution failed: the goal was rejected by /execute_reach\n")
            return EXIT["execution"]
        if result is not None:
            if result.error_code.val == 0 and result.success:
                self.text.write(execution_report(e) + "\n")
            else:
                self.err.write(f"execution {'canceled' if outcome == 'canceled' else 'failed'}: "
                               f"{code_text(result.error_code.val, result.message)}\n")
                if result.steps:
                    self.err.write(execution_report(e) + "\n")
        if outcome == "canceled":
            return EXIT["canceled"]
        return (exit_class(result.error_code.val) if result.success or result.error_code.val
                else EXIT["execution"])

    def look(self, gaze_points: np.ndarray | None = None, come_back: bool = False) -> int:
        """``--scan`` / ``--look`` (or a look at ``gaze_points``): the /look action with a line per head
        pose; ``come_back`` (the automatic looks): then back to the posture the look began in."""
        a = self.args
        yaw, pitch = ([], []) if a.scan or gaze_points is not None else (
            [math.radians(a.look[0])], [math.radians(a.look[1])])
        if gaze_points is None:
            self.say("scanning with the head (the executor's scan pattern) ..." if a.scan else
                     f"turning the head to yaw {a.look[0]:g}, pitch {a.look[1]:g} deg ...")
        outcome, result = self.client.look(yaw, pitch, a.dwell or 0.0, lambda fb: self.say(head_pose_line(fb)),
                                           gaze_points, come_back)
        if gaze_points is None and result is not None and result.success:
            self.summary["map_voxels"] = self.map_size()
        looked = execution_summary(outcome, result, LOOK_FIELDS)
        if gaze_points is None:
            self.summary["look"] = looked
        else:
            self.summary.setdefault("auto_looks", []).append(looked)
        if outcome == "unavailable":
            return EXIT["unavailable"]
        if outcome == "timeout":
            self.err.write("look: no answer from /look in time\n")
            return EXIT["unavailable"]
        if outcome == "rejected":
            self.err.write("look failed: the goal was rejected by /look\n")
            return EXIT["execution"]
        if result is None:
            return EXIT["canceled"]
        if result.success and result.error_code.val == 0:
            self.say(f"look: {result.message} [{result.duration_s:.1f} s, max COG drift "
                     f"{result.max_com_error_m * 1e3:.2f} mm]")
            return EXIT["success"]
        self.err.write(f"look {'canceled' if outcome == 'canceled' else 'failed'}: "
                       f"{code_text(result.error_code.val, result.message)}\n")
        return EXIT["canceled"] if outcome == "canceled" else (exit_class(result.error_code.val)
                                                               or EXIT["execution"])

    def wait_for_look(self, owner: str) -> bool:
        return self.client.wait_for_look(owner)

    def map_size(self) -> int | None:
        """After a scan or look: the voxel mapper's occupied voxels from its diagnostics (1 Hz) heard
        after it ended (``MAP_REPORT_WAIT_S`` at most), said in a line; None (said too) when none came."""
        try:
            with self.client.watch_map() as watch:
                self.client.spin_until(lambda: watch.map_voxels is not None, MAP_REPORT_WAIT_S)
        except Canceled:
            return None
        if watch.map_voxels is not None:
            self.say(f"map: {watch.map_voxels:,} occupied voxels")
            return watch.map_voxels
        self.say(f"map: size unknown (no voxel_mapper diagnostics within {MAP_REPORT_WAIT_S:g} s)")
        return None

    def plan_with_looks(self, req: Any) -> tuple[Any | None, int]:
        """``/plan_reach``; while it answers UNOBSERVED_SPACE with the points where the target or the
        best path meets unobserved space, look there (a balanced whole-body gaze through /look,
        head and chest) and plan again, at most ``--max-looks`` times (``--no-auto-look``: never).
        ``(response, exit code)``; the response is None when the planner could not be asked."""
        a, looks = self.args, 0
        while True:
            try:
                resp = self.client.plan(req)
            except Canceled:
                self.err.write("reach_operator: canceled while planning\n")
                return None, EXIT["canceled"]
            if resp is None:
                return None, EXIT["unavailable"]
            if resp.error_code.val != PlanError.UNOBSERVED_SPACE or not resp.unobserved_points:
                return resp, EXIT["success"]
            pts = np.array([[p.x, p.y, p.z] for p in resp.unobserved_points], dtype=float)
            where = ", ".join(str(np.round(p, 2).tolist()) for p in pts)
            if a.no_auto_look or looks >= a.max_looks:
                if not a.no_auto_look:
                    self.err.write(f"reach_operator: still unobserved after {looks} automatic look(s) at {where}\n")
                return resp, EXIT["success"]
            # /look waited for up to --timeout, like every server: on a busy machine a fresh CLI took over 3 s to
            # discover the action's five endpoints (bench/session), so no shorter guess tells "no executor" from
            # "not discovered yet"; a graph without an executor (a planner fed by a bag) says --no-auto-look
            try:
                up = self.wait_for_look("reach_executor, for an automatic look; --no-auto-look skips it")
            except Canceled:
                self.err.write("reach_operator: canceled while waiting for /look\n")
                return None, EXIT["canceled"]
            if not up:
                self.err.write(f"reach_operator: /look not available after {self.client.timeout_s:g} s (is "
                               f"reach_executor running? --no-auto-look plans without looking): no automatic look "
                               f"at {where}\n")
                return resp, EXIT["success"]
            looks += 1
            self.say(f"the plan needs to see {where} m (unobserved): looking there, automatic look {looks}/"
                     f"{a.max_looks} (--no-auto-look turns this off) ...")
            # and back: the next plan starts where the robot stood, and the head looks where it did
            code = self.look(gaze_points=pts, come_back=True)
            if code != EXIT["success"]:
                return None, code
            if a.marker and (code := self.ensure_marker_target()) != EXIT["success"]:
                return None, code   # the look turned the head away from the marker: find it again
            self.say("planning again ...")

    def ensure_marker_target(self) -> int:
        """``--marker``: the planner takes the marker's ``/target_pose`` only while it is recent (1 s,
        its ``target_timeout_s``), and ``marker_localizer`` publishes only while the marker is in the
        camera's view. When no ``/target_pose`` comes within ``MARKER_FRESH_WAIT_S`` (of discovering its
        publisher, within ``MARKER_DISCOVERY_S``), the head is turned (``/look``) toward the marker's
        last known position (from ``marker_localizer``'s diagnostics, aimed from the current posture)
        or, with none known, to the executor's ``marker_look_deg``; then a fresh pose is awaited for
        ``--marker-wait`` with a countdown. Without a ``marker_localizer`` it leaves the answer to the
        planner (``NO_TARGET`` with its hint); without an executor the look says so (exit 3)."""
        report: dict[str, Any] = {"fresh": False, "looked_deg": None, "toward": None}
        try:
            with self.client.watch_marker() as watch:
                self.summary["marker"] = report
                return self._find_marker(watch, report)
        except Canceled:
            self.err.write("reach_operator: canceled while waiting for the marker\n")
            return EXIT["canceled"]

    def _find_marker(self, watch: MarkerWatch, report: dict[str, Any]) -> int:
        client, t0 = self.client, time.monotonic()
        found: list[float] = []   # when the client discovered a /target_pose publisher (it lags on a busy machine)

        def settled() -> bool:
            now = time.monotonic()
            if not found and watch.publishers() > 0:
                found.append(now)
            return watch.pose_t >= t0 or now > (found[0] + MARKER_FRESH_WAIT_S if found else t0 + MARKER_DISCOVERY_S)
        client.spin_until(settled, None)
        if watch.pose_t >= t0:
            report["fresh"] = True
            return EXIT["success"]
        if watch.publishers() == 0:
            return EXIT["success"]   # no marker_localizer: the planner answers (NO_TARGET and its hint)
        # its diagnostics (1 Hz) hold the last position: wait for one that does, up to the deadline (a fresh
        # CLI on a busy machine once heard a status without it first, and looked at marker_look_deg instead)
        t_diag = time.monotonic() + MARKER_DIAGNOSTICS_WAIT_S
        client.spin_until(lambda: (watch.last is not None and watch.joints is not None) or watch.pose_t >= t0
                          or time.monotonic() > t_diag, None)   # the aim needs both
        if watch.pose_t >= t0:
            report["fresh"] = True
            return EXIT["success"]
        params = client.executor_parameters(["marker_look_deg", "robot_config"])
        if watch.last is not None and watch.joints is not None:
            from humanoid_reach_ros.robot.head_aim import aim_head_deg
            from humanoid_reach_ros.robot.model import RobotModel

            robot = RobotModel(params["robot_config"])
            yaw, pitch = aim_head_deg(robot, watch.last, robot.joints_from_dict(watch.joints))
            report["toward"] = watch.last
            where = (f"toward the marker's last known position ({', '.join(f'{v:.2f}' for v in watch.last)}) m: "
                     f"yaw {yaw:g}, pitch {pitch:g} deg")
        else:
            yaw, pitch = (float(v) for v in params["marker_look_deg"])
            why = ("no marker position known" if watch.last is None and watch.diagnostics else
                   "no diagnostics from marker_localizer" if watch.last is None else "no /joint_states")
            where = f"where the executor looks for it (marker_look_deg; {why}): yaw {yaw:g}, pitch {pitch:g} deg"
        report["looked_deg"] = [yaw, pitch]
        self.say(f"no /target_pose within {MARKER_FRESH_WAIT_S:g} s (the marker is out of view): turning the head "
                 f"{where} ...")
        outcome, result = client.look([math.radians(yaw)], [math.radians(pitch)], MARKER_LOOK_DWELL_S, lambda fb: None)
        if outcome == "canceled" or (result is not None and result.error_code.val == ExecuteCode.CANCELED):
            self.err.write("reach_operator: canceled while turning the head toward the marker\n")
            return EXIT["canceled"]
        if outcome != "done" or result is None or not result.success:
            why = code_text(result.error_code.val, result.message) if result is not None else outcome
            self.err.write(f"look toward the marker failed: {why}\n")
            return EXIT["unavailable"] if outcome in ("unavailable", "timeout") else EXIT["execution"]
        wait_s = self.args.marker_wait
        notes = Countdown(self.err, "/target_pose (marker_localizer)", wait_s, first_s=0.0)

        def fresh() -> bool:
            if watch.pose_t >= notes.t0:
                return True
            notes.tick()
            return False
        if not client.spin_until(fresh, wait_s):
            self.err.write(f"reach_operator: no /target_pose within {wait_s:g} s after turning the head {where}: "
                           "is the marker in view? Scan (--scan), look (--look YAW PITCH) or give --target\n")
            return EXIT["no_input"]
        report["fresh"] = True
        x, y, z = watch.position
        self.say(f"marker seen at ({x:.3f}, {y:.3f}, {z:.3f}) m")
        return EXIT["success"]
