"""The console's actions: one operator at a time, each request checked, each action run by the
operator's own flow (``session.OperatorSession``) against the same client as ``reach_operator``.

A page sends JSON requests (``{"op": "plan", "target": [x, y, z], "arm": "auto"}``, ...: ``OPS``);
every one is answered: refused with a ``{"t": "error"}`` message that says why (malformed, not
holding the controls, busy, a target off the map, nothing to execute), or run in the one worker
thread, which reports ``progress``, ``log`` lines (the CLI's own lines), ``looked`` (the points
an automatic look turned to) and a final ``result``. Plan keeps the response as the preview
(its ghost goes to every page); Execute sends exactly that trajectory, and only while the robot
still stands where the plan started. ROS-free: the client is ``session.OperatorClient``.
"""
from __future__ import annotations

import math
import threading
import time
from typing import Any, Callable

import numpy as np

from humanoid_reach_ros.codes import ARM_REQUESTS
from humanoid_reach_ros.operator.cli import parse_args
from humanoid_reach_ros.operator.report import (
    EXIT, Progress, code_text, execution_summary, head_pose_line, plan_report, plan_summary, progress_bar)
from humanoid_reach_ros.operator.session import OperatorSession

OPS = ("take", "release", "plan", "execute", "cancel", "scan", "look", "home")
CONTROL_OPS = ("plan", "execute", "cancel", "scan", "look", "home")   # need the controls
START_TOLERANCE_RAD = 0.01   # Execute: the robot's joints within this of the plan's start (else plan again)
COORD_LIMIT_M = 10.0         # a point farther than this from the origin is refused before any map look-up

Emit = Callable[[dict[str, Any]], None]


class RequestRefused(ValueError):
    """A request answered with a message and not run."""


class _Lines:
    """A text stream (``write``/``flush``) that emits each complete line as a ``log`` message."""

    def __init__(self, emit: Emit, level: str) -> None:
        self.emit, self.level, self.buf = emit, level, ""

    def write(self, s: str) -> int:
        self.buf += s.replace("\r", "\n")
        *lines, self.buf = self.buf.split("\n")
        for line in lines:
            if line.strip():
                self.emit({"t": "log", "level": self.level, "text": line})
        return len(s)

    def flush(self) -> None:
        pass

    def isatty(self) -> bool:
        return False


class _Reporting:
    """The client as the session sees it, with each feedback also sent as ``progress`` and each
    automatic look's points as ``looked``."""

    def __init__(self, client: Any, emit: Emit, op: str) -> None:
        self._client, self._emit, self._op = client, emit, op

    def __getattr__(self, name: str) -> Any:
        return getattr(self._client, name)

    def execute(self, trajectory, arm, args, on_feedback):
        def fb(p: Progress) -> None:
            on_feedback(p)
            self._emit({"t": "progress", "op": self._op, "fraction": _finite(p.progress), "text": progress_bar(p)})
        return self._client.execute(trajectory, arm, args, fb)

    def look(self, yaw_rad, pitch_rad, dwell_s, on_feedback, gaze_points=None, come_back=False):
        if gaze_points is not None:
            self._emit({"t": "looked", "points": np.round(np.asarray(gaze_points, float), 3).tolist()})

        def fb(m: Any) -> None:
            on_feedback(m)
            n = max(int(m.pose_count), 1)
            self._emit({"t": "progress", "op": self._op, "fraction": min(1.0, (int(m.pose_index) + 1) / n),
                        "text": head_pose_line(m).strip()})
        return self._client.look(yaw_rad, pitch_rad, dwell_s, fb, gaze_points, come_back)


def _failed(outcome: str | None) -> str:
    """How an action that did not succeed ended: ``failed`` (its server said so), else the outcome
    (``canceled``, ``rejected``, ``unavailable``, ``timeout``)."""
    return "failed" if outcome in (None, "done") else outcome


def _finite(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def _point(value: Any, what: str) -> list[float]:
    """Three finite numbers within ``COORD_LIMIT_M``, or ``RequestRefused``."""
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise RequestRefused(f"{what} must be [x, y, z] in metres, got {value!r}"[:200])
    out = []
    for v in value:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise RequestRefused(f"{what} must hold three finite numbers, got {value!r}"[:200])
        out.append(float(v))
    if math.hypot(*out) > COORD_LIMIT_M:
        raise RequestRefused(f"{what} {out} lies {math.hypot(*out):.1f} m from the stance: not a point of the map")
    return out


class ConsoleControl:
    """The controls of the console: who holds them, which action runs, the plan under preview.

    ``client``: the ``OperatorClient`` (``nodes/reach_operator.Operator``); ``plan_request``:
    arguments -> ``PlanReach`` request (the CLI's); ``joints``: the robot's joints now (or None);
    ``map_distance``: a point's distance to the nearest occupied voxel [m] (inf: no map);
    ``ghost``: (trajectory, start joints) -> the ghost frame (``views.RobotView.ghost``);
    ``emit(message, to)``: a JSON message to every page (``to`` None) or to one; ``emit_frame``: a
    binary frame to every page."""

    def __init__(self, client: Any, plan_request: Callable[[Any], Any], joints: Callable[[], np.ndarray | None],
                 map_distance: Callable[[list[float]], float], ghost: Callable[[Any, np.ndarray], tuple[bytes, dict]],
                 emit: Callable[[dict[str, Any], Any], None], emit_frame: Callable[[bytes], None],
                 target_map_distance_m: float, log: Callable[[str], None] = lambda s: None,
                 scan_dwell_s: float = 0.0, plan_budget_s: float = 0.0) -> None:
        self.client, self.plan_request, self.joints, self.map_distance = client, plan_request, joints, map_distance
        self.ghost, self._emit, self.emit_frame, self.log = ghost, emit, emit_frame, log
        self.target_map_distance_m = float(target_map_distance_m)
        self.scan_dwell_s = float(scan_dwell_s)    # each head pose of a Scan held this long [s]; 0: the executor's
        self.plan_budget_s = float(plan_budget_s)  # the planning time budget of Plan and Home [s]; 0: the planner's
        self.lock = threading.Lock()
        self.holder: Any = None          # the page holding the controls (None: nobody)
        self.holder_since = 0.0
        self.busy: str | None = None     # the action running
        self.preview: Any = None         # the PlanReach response under review
        self.preview_start: np.ndarray | None = None
        self.target: list[float] | None = None
        self.last_error: dict[str, Any] | None = None
        self.worker: threading.Thread | None = None

    def emit(self, message: dict[str, Any], to: Any = None) -> None:
        self._emit(message, to)

    # ------------------------------------------------------------ the pages
    def state(self) -> dict[str, Any]:
        """What every page shows of the controls (part of the status message)."""
        with self.lock:
            return {"holder": self.holder, "busy": self.busy, "preview": self.preview is not None,
                    "target": self.target, "last_error": self.last_error}

    def left(self, page: Any) -> None:
        """A page closed: its controls are released (an action it started runs on)."""
        with self.lock:
            if self.holder != page:
                return
            self.holder = None
        self.log(f"page {page} closed: the controls are free")

    def handle(self, page: Any, request: Any) -> None:
        """One request of ``page``: refused with a message, or done / started."""
        try:
            self._handle(page, request)
        except RequestRefused as exc:
            self.emit({"t": "error", "op": request.get("op") if isinstance(request, dict) else None,
                       "text": str(exc)}, page)

    def _handle(self, page: Any, request: Any) -> None:
        if not isinstance(request, dict):
            raise RequestRefused("a request is a JSON object with an \"op\"")
        op = request.get("op")
        if op not in OPS:
            raise RequestRefused(f"unknown op {op!r}: one of {', '.join(OPS)}"[:200])
        if op == "take":
            return self._take(page)
        if op == "release":
            return self._release(page)
        with self.lock:
            if self.holder != page:
                who = "nobody holds them: Take the controls first" if self.holder is None else \
                    f"another page holds them (since {time.strftime('%H:%M:%S', time.localtime(self.holder_since))})"
                raise RequestRefused(f"{op}: this page does not hold the controls ({who})")
            if op == "cancel":
                if self.busy is None:
                    raise RequestRefused("cancel: nothing is running")
                self.client.interrupted = True   # the client's wait raises Canceled: the goal is canceled
                self.emit({"t": "log", "level": "info", "text": f"canceling {self.busy} ..."})
                return None
            if self.busy is not None:
                raise RequestRefused(f"{op}: busy with {self.busy} (Cancel stops it)")
            job = self._job(op, request)
            self.busy = op
            self.client.interrupted = False
        self.worker = threading.Thread(target=self._run, args=(op, job), name=f"console-{op}", daemon=True)
        self.worker.start()
        return None

    def _take(self, page: Any) -> None:
        with self.lock:
            if self.holder not in (None, page):
                raise RequestRefused("take: another page holds the controls; this one shows the robot until they "
                                     "are released (Release, or that page closes)")
            self.holder, self.holder_since = page, time.time()
        self.log(f"page {page} holds the controls")

    def _release(self, page: Any) -> None:
        with self.lock:
            if self.holder != page:
                raise RequestRefused("release: this page does not hold the controls")
            self.holder = None
        self.log(f"page {page} released the controls")

    # ------------------------------------------------------------ the actions
    def _job(self, op: str, request: dict[str, Any]) -> Callable[[], None]:
        """The action of a checked request (``RequestRefused`` when it cannot be run)."""
        if op == "plan":
            target = _point(request.get("target"), "plan: target")
            arm = request.get("arm", "auto")
            if arm not in ARM_REQUESTS:
                raise RequestRefused(f"plan: arm must be one of {', '.join(ARM_REQUESTS)}, got {arm!r}"[:200])
            self._on_map(target, "plan: target")
            return lambda: self._plan(["--target", *map(repr, target), "--arm", arm], target)
        if op == "look":
            point = _point(request.get("point"), "look: point")
            self._on_map(point, "look: point")
            return lambda: self._look(np.array([point]))
        if op == "execute":
            if self.preview is None:
                raise RequestRefused("execute: no plan to execute: Plan first (Execute runs the plan shown)")
            now = self.joints()
            if now is None:
                raise RequestRefused("execute: no /joint_states yet: the robot's posture is unknown")
            moved = float(np.max(np.abs(now - self.preview_start)))
            if moved > START_TOLERANCE_RAD:
                raise RequestRefused(f"execute: the robot moved {moved:.3f} rad since the plan: plan again")
            return self._execute
        if op == "scan":
            return self._scan
        return lambda: self._plan(["--home"], None, execute=True)   # home

    def _on_map(self, point: list[float], what: str) -> None:
        d = self.map_distance(point)
        if not d <= self.target_map_distance_m:
            where = "the map is empty (no /voxel_map yet: Scan first)" if not math.isfinite(d) else \
                f"the nearest occupied voxel is {d * 1e3:.0f} mm away"
            raise RequestRefused(f"{what} {[round(v, 3) for v in point]} is not on the map: {where}; click on a "
                                 f"voxel (within {self.target_map_distance_m * 1e3:.0f} mm)")

    def _session(self, op: str, argv: list[str]) -> OperatorSession:
        args = parse_args(argv)
        return OperatorSession(_Reporting(self.client, self.emit, op), args, _Lines(self.emit, "info"),
                               _Lines(self.emit, "error"))

    def _run(self, op: str, job: Callable[[], None]) -> None:
        t0 = time.monotonic()
        try:
            job()
        except Exception as exc:   # an action's failure is reported, never the end of the console
            self._result(op, False, f"{op} failed: {type(exc).__name__}: {exc}", error={
                "name": "INTERNAL_ERROR", "code": None, "message": str(exc)})
        finally:
            with self.lock:
                self.busy = None
            self.log(f"{op} ended after {time.monotonic() - t0:.1f} s")

    def _result(self, op: str, ok: bool, text: str, error: dict[str, Any] | None = None, **extra: Any) -> None:
        if error is not None:
            with self.lock:
                self.last_error = error
        self.emit({"t": "result", "op": op, "ok": ok, "text": text, "error": error, **extra})

    def _plan(self, argv: list[str], target: list[float] | None, execute: bool = False) -> None:
        op = "home" if execute else "plan"
        budget = ["--budget", repr(self.plan_budget_s)] if self.plan_budget_s > 0.0 else []
        session = self._session(op, [*argv, *budget])
        start = self.joints()
        with self.lock:
            self.preview, self.preview_start, self.target = None, None, target
        self.emit({"t": "ghost_clear"})
        resp, code = session.plan_with_looks(self.plan_request(session.args))
        if resp is None:
            what = "canceled" if code == EXIT["canceled"] else "the planner did not answer (is reach_planner running?)"
            return self._result(op, False, f"{op}: {what}", error=None if code == EXIT["canceled"] else {
                "name": "UNAVAILABLE", "code": None, "message": what})
        summary = plan_summary(resp)
        if not resp.success or resp.error_code.val != 0:
            return self._result(op, False, f"{op} failed: {code_text(resp.error_code.val, resp.message)}",
                                error={"name": summary["error_name"], "code": summary["error_code"],
                                       "message": resp.message}, plan=summary)
        if start is None:
            start = self.joints()
        frame, ghost = self.ghost(resp.trajectory, start)
        self.emit_frame(frame)
        if not execute:
            with self.lock:
                self.preview, self.preview_start = resp, np.array(start, dtype=float)
            return self._result(op, True, plan_report(summary), plan=summary, ghost=ghost)
        self.emit({"t": "log", "level": "info", "text": plan_report(summary)})
        self._execute_response(op, session, resp)

    def _execute(self) -> None:
        with self.lock:
            resp = self.preview
        self._execute_response("execute", self._session("execute", ["--target", "0", "0", "0", "--execute"]), resp)

    def _execute_response(self, op: str, session: OperatorSession, resp: Any) -> None:
        code = session.execute(resp)
        with self.lock:
            self.preview = self.preview_start = None
        self.emit({"t": "ghost_clear"})
        e = session.summary["execution"] or {}
        ok = code == EXIT["success"]
        text = (f"{op}: done in {e.get('duration_s', 0.0):.2f} s, {e.get('overruns', 0)} overruns" if ok else
                f"{op} {_failed(e.get('outcome'))}: " + (code_text(e["error_code"], e.get("message", ""))
                                                         if "error_code" in e else "no result"))
        error = None if ok else {"name": e.get("error_name", e.get("outcome", "FAILED")),
                                 "code": e.get("error_code"), "message": e.get("message", e.get("outcome", ""))}
        self._result(op, ok, text, error=error, execution=e)

    def _scan(self) -> None:
        dwell = ["--dwell", repr(self.scan_dwell_s)] if self.scan_dwell_s > 0.0 else []
        self._look_result("scan", self._session("scan", ["--scan", *dwell]), None)

    def _look(self, points: np.ndarray) -> None:
        self._look_result("look", self._session("look", ["--scan"]), points)

    def _look_result(self, op: str, session: OperatorSession, points: np.ndarray | None) -> None:
        code = session.look(points)
        looked = session.summary["look"] if points is None else session.summary["auto_looks"][-1]
        looked = looked or execution_summary("canceled", None)
        ok = code == EXIT["success"]
        text = f"{op}: {looked.get('message', looked['outcome'])}" if ok else \
            f"{op} {_failed(looked['outcome'])}: " + (code_text(looked["error_code"], looked.get("message", ""))
                                            if "error_code" in looked else "no result")
        error = None if ok else {"name": looked.get("error_name", looked["outcome"]),
                                 "code": looked.get("error_code"), "message": looked.get("message", "")}
        self._result(op, ok, text, error=error, look=looked, map_voxels=session.summary.get("map_voxels"))
