"""``reach_operator``: the operator's command line (client of ``/plan_reach`` and ``/execute_reach``).

Plans a reaching motion to a Workspace Goal Region (Kanehiro et al. eq. 3: the hand pose
``T_target * Trans(dx, dy, dz) * RPY(droll, dpitch, dyaw)`` with the offsets in
``[lower, upper]``) around either the AR marker's ``/target_pose`` (``--marker``, the
default: ``PlanReach.use_marker_target``) or a pose given on the command line
(``--target x y z [--rpy-deg r p y] [--frame world|base_link]``), and with ``--execute`` sends
the returned trajectory as an ``/execute_reach`` action goal, drawing a progress bar from
its feedback (Ctrl-C cancels the goal and waits for the executor to hold the robot).

The region bounds default to the valve WGR of eq. 3 (``planning.wgr.valve_region``:
position fixed at the target, roll and pitch in [-pi/2, pi/2], yaw free); ``--wgr-deg`` gives
6 lower + 6 upper bounds (x y z [m], roll pitch yaw [deg]). Angles are in degrees where an
operator types them (``--rpy-deg``, ``--wgr-deg``); ``--rpy`` and ``--wgr`` take the same in
radians (kept for scripts), where a typed 3.1416 counts as pi (the planner clamps angle
bounds within ``ANGLE_TOL`` of +-pi).

Usage::

    python -m humanoid_reach_ros.nodes.reach_operator --target 0.71 0.03 0.90 --execute
    python -m humanoid_reach_ros.nodes.reach_operator --marker --arm left --json
    reach_operator --target 0.5 -0.2 1.0 --rpy-deg 0 -90 0 --wgr-deg 0 0 0 -10 -10 -180 0 0 0 10 10 180

Every ``PlanReach`` error code and every ``ExecuteReach`` result code is printed by name
with the server's message and a hint (``PLAN_HINTS``, ``EXECUTE_HINTS``). Exit codes by
failure class (``EXIT``): 0 success; 1 internal error of a node; 2 bad command line
(argparse); 3 a server is not available or did not answer within ``--timeout``; 4 the
request was refused as invalid; 5 no motion exists (out of reach, start in collision, no
path, timed out); 6 the planner lacks an input or is busy (no map, no marker target, no
joint states, busy); 7 execution failed (goal rejected, invalid, aborted, preempted);
130 canceled with Ctrl-C. ``--json`` prints one JSON object (the plan, the execution and
the exit code) as the only line on stdout; messages and progress then go to stderr.
"""
from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import time
from dataclasses import dataclass
from typing import Any, Callable, TextIO

import numpy as np

from humanoid_reach_ros.codes import ARM_REQUESTS, ExecuteCode, PlanError
from humanoid_reach_ros.planning.wgr import ANGLE_TOL

EXIT = {"success": 0, "internal": 1, "usage": 2, "unavailable": 3, "invalid": 4, "no_motion": 5,
        "no_input": 6, "execution": 7, "canceled": 130}

SCAN_POSES_ASSUMED = 20   # for the result deadline of a scan: poses of the executor's scan_poses_deg at most
WAIT_NOTE_FIRST_S = 2.0   # waiting for a server: the first line after this long [s] (discovery can take 1 s) ...
WAIT_NOTE_EVERY_S = 5.0   # ... then one every this long, with the seconds left
# action_msgs/GoalStatus: any status of our goal id means the server accepted it; these three end it
GOAL_KNOWN = frozenset(range(1, 7))        # ACCEPTED, EXECUTING, CANCELING, SUCCEEDED, CANCELED, ABORTED
GOAL_DONE = frozenset((4, 5, 6))           # SUCCEEDED, CANCELED, ABORTED
LOST_RESPONSE_GRACE_S = 1.0   # the status said so this long and the response did not come: taken as lost
ARMS = ARM_REQUESTS                     # --arm name -> PlanReach.Request.ARM_*
ARM_LABELS = {code: name for name, code in ARM_REQUESTS.items()}

# PlanReach.Response codes (codes.PlanError): exit class and hint per code.
_PLAN_HINTS = {
    PlanError.SUCCESS: ("success", "planned"),
    PlanError.INVALID_REQUEST: ("invalid", "a NaN/inf value, or an unknown arm or planner: check the arguments"),
    PlanError.INVALID_BOUNDS: ("invalid", "WGR lower > upper, or a rotation bound outside [-pi, pi] (+-180 deg): "
        "check --wgr-deg / --wgr"),
    PlanError.UNKNOWN_FRAME: ("invalid", "the target frame is not known to the planner: use --frame world or "
        "base_link"),
    PlanError.TARGET_OUT_OF_REACH: ("no_motion", "proven out of the arms' reach from any stance-keeping trunk pose: "
        "move the target closer (or the robot nearer)"),
    # the planner's message names the links, the nearest voxels and the retreats it tried
    PlanError.START_IN_COLLISION: ("no_motion", ""),
    PlanError.NO_MAP: ("no_input", "the planner has no environment model: start voxel_mapper (or give reach_planner "
        "a scene_file)"),
    PlanError.TIMED_OUT: ("no_motion", "the time budget ran out: raise --budget"),
    PlanError.NO_PATH: ("no_motion", "goal postures were found but no path to them: raise --budget or --goals"),
    PlanError.NO_TARGET: ("no_input", "no recent /target_pose from the marker: is marker_localizer running and the "
        "marker in view? Or give --target"),
    PlanError.NO_JOINT_STATES: ("no_input", "no recent /joint_states: is joint_driver running?"),
    PlanError.BUSY: ("no_input", "another request is being planned: try again"),
    # the planner's message names the place and the remedies (the automatic look ran out, or was off)
    PlanError.UNOBSERVED_SPACE: ("no_input", ""),
    PlanError.UNOBSERVABLE_SPACE: ("no_motion", ""),
    # the planner's message says which arms were tried and what to change: no hint of our own
    PlanError.NO_GOAL_FOUND: ("no_motion", ""),
    PlanError.INTERNAL_ERROR: ("internal", "the planner failed internally: see its log"),
}

# ExecuteReach.Result codes (codes.ExecuteCode)
_EXECUTE_HINTS = {
    ExecuteCode.SUCCESS: ("success", "executed"),
    ExecuteCode.INVALID_GOAL: ("execution", "the executor refused the trajectory or targets"),
    ExecuteCode.NO_JOINT_STATES: ("execution", "the executor has no current /joint_states: is joint_driver running?"),
    ExecuteCode.PREEMPTED: ("execution", "replaced by a newer goal or /reach_trajectory"),
    ExecuteCode.CANCELED: ("canceled", ""),   # the executor's message says it holds the last command
    ExecuteCode.ABORTED: ("execution", "the executor stopped the motion and holds the robot (e.g. stale joint states)"),
    ExecuteCode.TARGET_NOT_REACHED: ("execution", "the hand was held off the trajectory's end (a collision damper or a "
        "joint limit); the robot holds there: plan again from here"),
}
PLAN_CODES: dict[int, tuple[str, str, str]] = {int(c): (c.name, *v) for c, v in _PLAN_HINTS.items()}
EXECUTE_CODES: dict[int, tuple[str, str, str]] = {int(c): (c.name, *v) for c, v in _EXECUTE_HINTS.items()}


def code_text(codes: dict[int, tuple[str, str, str]], code: int, message: str) -> str:
    """``NAME (code): server message -- hint`` (no hint where the server's message gives it)."""
    name, _, hint = codes.get(code, (f"UNKNOWN_CODE_{code}", "internal", "a code this client does not know"))
    text = f"{name} ({code})"
    if message:
        text += f": {message}"
    return text if code == 0 or not hint else f"{text} -- {hint}"


def exit_class(codes: dict[int, tuple[str, str, str]], code: int) -> int:
    return EXIT[codes.get(code, ("", "internal", ""))[1]]


# ---------------------------------------------------------------- progress
@dataclass(frozen=True)
class Progress:
    """One ``ExecuteReach`` feedback in the operator's terms."""

    progress: float
    time_from_start_s: float
    min_distance_m: float
    com_error_m: float
    hand_error_m: float

    @classmethod
    def from_feedback(cls, fb: Any) -> "Progress":
        return cls(float(fb.progress), float(fb.time_from_start_s), float(fb.min_distance_m),
                   float(fb.com_error_m), float(fb.hand_error_m))


def progress_bar(p: Progress, width: int = 30) -> str:
    """``[##########..........]  50%  t 1.20 s  min dist 52.0 mm  COG 0.30 mm  hand 12.0 mm``;
    progress outside [0, 1] or NaN is clamped (a bar never overflows)."""
    frac = p.progress if math.isfinite(p.progress) else 0.0
    frac = min(1.0, max(0.0, frac))
    filled = int(round(frac * width))

    def mm(v: float) -> str:
        return f"{v * 1e3:.1f} mm" if math.isfinite(v) else "-"

    return (f"[{'#' * filled}{'.' * (width - filled)}] {frac * 100:3.0f}%  t {p.time_from_start_s:5.2f} s  "
            f"min dist {mm(p.min_distance_m)}  COG {mm(p.com_error_m)}  hand {mm(p.hand_error_m)}")


class ProgressPrinter:
    """Draws the bar in place on a terminal (carriage return); elsewhere (logs, pipes) one
    line per ``step`` of progress so that a log stays short."""

    def __init__(self, out: TextIO, step: float = 0.1) -> None:
        self.out, self.step = out, step
        self.tty = bool(getattr(out, "isatty", lambda: False)())
        self.next_level = 0  # the next multiple of ``step`` that gets a line
        self.drawn = False

    def update(self, p: Progress) -> None:
        if self.tty:
            self.out.write("\r" + progress_bar(p))
            self.drawn = True
        else:
            frac = min(1.0, max(0.0, p.progress)) if math.isfinite(p.progress) else 0.0
            level = math.floor(frac / self.step + 1e-9)
            if level >= self.next_level:
                self.out.write(progress_bar(p) + "\n")
                self.next_level = level + 1
        self.out.flush()

    def close(self) -> None:
        if self.tty and self.drawn:
            self.out.write("\n")
            self.out.flush()
        self.drawn = False


# ---------------------------------------------------------------- command line
def _finite(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return v


def _positive(text: str) -> float:
    v = _finite(text)
    if v <= 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be > 0")
    return v


def _int_in(lo: int, hi: int, hi_text: str) -> Callable[[str], int]:
    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
        if not lo <= v <= hi:
            raise argparse.ArgumentTypeError(f"{text!r} must be in {lo}..{hi_text}")
        return v
    return parse


_count = _int_in(1, 2**32 - 1, "4294967295")
_seed = _int_in(0, 2**63 - 1, "2^63-1")


def planner_names() -> list[str]:
    from humanoid_reach_ros.io.msgs import PLANNERS
    return list(PLANNERS)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="reach_operator", allow_abbrev=False,   # it moves a robot: --exec is not taken for --execute
        description="Plan (and with --execute, execute) a whole-body reaching motion to the AR marker or a "
                    "given pose through /plan_reach and /execute_reach.",
        epilog="Exit codes: 0 success, 1 internal error, 2 bad arguments, 3 server unavailable / no answer, "
               "4 invalid request, 5 no motion found, 6 planner input missing or busy, 7 execution failed, "
               "130 canceled.")
    tgt = p.add_mutually_exclusive_group()
    tgt.add_argument("--marker", action="store_true", help="reach the AR marker's /target_pose (default)")
    tgt.add_argument("--target", nargs=3, type=_finite, metavar=("X", "Y", "Z"), help="target position [m]")
    tgt.add_argument("--home", action="store_true", help="plan back to the rest posture (half-sitting), from any "
                     "posture, a hand resting on something included (a retreat comes first)")
    rpy = p.add_mutually_exclusive_group()
    rpy.add_argument("--rpy-deg", nargs=3, type=_finite, metavar=("R", "P", "Y"),
                     help="target orientation, fixed-axis roll pitch yaw in DEGREES (with --target; default 0 0 0)")
    rpy.add_argument("--rpy", nargs=3, type=_finite, metavar=("R", "P", "Y"),
                     help="the same in radians")
    p.add_argument("--frame", choices=("world", "base_link"), help="frame of --target (default world)")
    p.add_argument("--arm", choices=tuple(ARMS), default="auto", help="arm to reach with (default auto: right, "
                   "then left)")
    p.add_argument("--planner", choices=planner_names(), help="path planner (default: the node's)")
    p.add_argument("--goals", type=_count, help="goal postures to sample (default: the node's)")
    p.add_argument("--budget", type=_positive, help="planning time budget [s] (default: the node's)")
    p.add_argument("--seed", type=_seed, help="random seed (default: the node's)")
    wgr = p.add_mutually_exclusive_group()
    wgr.add_argument("--wgr-deg", nargs=12, type=_finite, metavar="B",
                     help="region bounds around the target: 6 lower then 6 upper, x y z in m and roll pitch yaw in "
                          "DEGREES, each angle within [-180, 180]; default the valve WGR of eq. 3: "
                          "0 0 0 -90 -90 -180  0 0 0 90 90 180")
    wgr.add_argument("--wgr", nargs=12, type=_finite, metavar="B",
                     help="the same with roll pitch yaw in radians, within [-pi, pi] (3.1416 is taken as pi: angles "
                          f"within {ANGLE_TOL:g} rad of +-pi are clamped by the planner)")
    head = p.add_mutually_exclusive_group()
    head.add_argument("--scan", action="store_true", help="first turn the head through the executor's scan pattern "
                      "(/look, feet and COG held) so the voxel map and the marker are seen; alone: only the scan")
    head.add_argument("--look", nargs=2, type=_finite, metavar=("YAW", "PITCH"),
                      help="first turn the head to YAW PITCH in DEGREES (pitch > 0 looks down); alone: only that")
    p.add_argument("--dwell", type=_positive, help="hold each head pose this long [s] (default: the executor's)")
    p.add_argument("--execute", action="store_true", help="execute the plan through /execute_reach")
    p.add_argument("--no-auto-look", action="store_true", help="when the only plans cross unobserved space, fail "
                   "(UNOBSERVED_SPACE) instead of looking there with a balanced whole-body gaze and planning again")
    p.add_argument("--max-looks", type=_int_in(0, 10, "10"), default=3,
                   help="automatic looks per request at most (default 3)")
    p.add_argument("--marker-wait", type=_positive, default=None, metavar="S",
                   help=f"with --marker: after turning the head, wait this long [s] for a fresh /target_pose "
                        f"(default {MARKER_WAIT_S:g})")
    p.add_argument("--no-collision-avoidance", action="store_true", help="execute without velocity dampers")
    p.add_argument("--no-com-compensation", action="store_true", help="execute without the exact-COG task")
    p.add_argument("--smooth-reshaping", action="store_true", help="reshape colliding segments before executing")
    p.add_argument("--timeout", type=_positive, default=60.0,
                   help="wait at most this long [s] for each server and for the plan (default 60); while waiting "
                        "for a server, a line every few seconds says which one and how long is left")
    p.add_argument("--json", action="store_true", help="print a machine-readable JSON summary on stdout")
    return p


def wgr_from_degrees(bounds: list[float]) -> list[float]:
    """12 bounds (x y z [m], roll pitch yaw [deg]; lower then upper) -> the same with radians.
    ValueError for an angle outside [-180, 180] beyond the planner's tolerance."""
    if len(bounds) != 12:
        raise ValueError(f"--wgr-deg takes 12 values (6 lower, 6 upper), got {len(bounds)}")
    tol_deg = math.degrees(ANGLE_TOL)
    out = list(map(float, bounds))
    for side, base in (("lower", 0), ("upper", 6)):
        for k, name in enumerate(("roll", "pitch", "yaw")):
            v = out[base + 3 + k]
            if abs(v) > 180.0 + tol_deg:
                raise ValueError(f"--wgr-deg: {side} {name} {v:g} deg lies outside [-180, 180]")
            out[base + 3 + k] = math.radians(v)
    return out


def parse_args(argv: list[str]) -> argparse.Namespace:
    """The command line; angles given in degrees (``--rpy-deg``, ``--wgr-deg``) are stored in
    radians in ``rpy`` and ``wgr``, so the rest of the tool sees radians only."""
    p = build_parser()
    a = p.parse_args(argv)
    if a.rpy_deg is not None:
        a.rpy = [math.radians(v) for v in a.rpy_deg]
    if a.wgr_deg is not None:
        try:
            a.wgr = wgr_from_degrees(a.wgr_deg)
        except ValueError as exc:
            p.error(str(exc))
    if a.target is None and (a.rpy is not None or a.frame is not None):
        p.error("--rpy/--rpy-deg and --frame need --target (the marker's pose comes with its own frame)")
    # --scan / --look alone move the head only; with --marker, --target or --execute a plan follows
    a.plan = not (a.scan or a.look is not None) or a.marker or a.target is not None or a.execute or a.home
    if a.dwell is not None and not (a.scan or a.look is not None):
        p.error("--dwell needs --scan or --look")
    if a.marker_wait is not None and not a.marker:
        p.error("--marker-wait needs --marker")
    a.marker_wait = MARKER_WAIT_S if a.marker_wait is None else a.marker_wait
    if a.home and (a.rpy is not None or a.wgr is not None or a.arm != "auto"):
        p.error("--home takes no --rpy/--wgr/--arm: it goes back to the rest posture")
    if a.target is None and not a.home:
        a.marker = True
    if not a.execute and (a.no_collision_avoidance or a.no_com_compensation or a.smooth_reshaping):
        p.error("--no-collision-avoidance, --no-com-compensation and --smooth-reshaping need --execute")
    return a


def region_bounds(wgr: list[float] | None) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) of the WGR: ``--wgr`` or the valve WGR of eq. 3."""
    if wgr is None:
        from humanoid_reach_ros.planning.wgr import valve_region
        v = valve_region()
        return np.asarray(v.lower, float), np.asarray(v.upper, float)
    return np.asarray(wgr[:6], float), np.asarray(wgr[6:], float)


def plan_request(args: argparse.Namespace) -> Any:
    """The ``PlanReach`` request of the command line (not validated beyond argparse: the
    planner answers bad bounds with ``INVALID_BOUNDS``)."""
    import pinocchio as pin

    from humanoid_reach_interfaces.srv import PlanReach
    from humanoid_reach_ros.io import msgs
    from humanoid_reach_ros.planning.wgr import rpy_matrix

    req = PlanReach.Request(arm=ARMS[args.arm], goal_count=args.goals or 0, planner=args.planner or "",
                            time_budget_s=float(args.budget or 0.0), use_marker_target=bool(args.marker),
                            execute=False, seed=-1 if args.seed is None else args.seed, home=bool(args.home))
    if args.target is not None:
        R = rpy_matrix(np.asarray(args.rpy or (0.0, 0.0, 0.0), float))
        req.region.target = msgs.pose_stamped(pin.SE3(R, np.asarray(args.target, float)), args.frame or "world")
    lower, upper = region_bounds(args.wgr)
    req.region.lower, req.region.upper = lower, upper
    return req


# ---------------------------------------------------------------- the client
class Canceled(Exception):
    pass


class Operator:
    """The rclpy side: one node, service + action clients, waits that honour Ctrl-C."""

    def __init__(self, timeout_s: float, err: TextIO) -> None:
        import rclpy
        from rclpy.action import ActionClient
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        from humanoid_reach_interfaces.action import ExecuteReach, Look
        from humanoid_reach_interfaces.srv import PlanReach

        self.rclpy = rclpy
        self.timeout_s = timeout_s
        self.err = err
        self.interrupted = False
        rclpy.init(args=sys.argv, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(f"reach_operator_{int(time.time() * 1e3) % 10**9}")
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self.plan_client = self.node.create_client(PlanReach, "/plan_reach")
        self.exec_client = ActionClient(self.node, ExecuteReach, "/execute_reach")
        self.look_client = ActionClient(self.node, Look, "/look")
        self.ExecuteReach, self.Look = ExecuteReach, Look
        # the goals' status as the servers publish it (by goal id): it tells a goal accepted, or finished,
        # when the service response that should have said so was lost (:meth:`_await`)
        from action_msgs.msg import GoalStatusArray
        from rclpy.qos import qos_profile_action_status_default
        self.goal_status: dict[bytes, tuple[int, float]] = {}    # goal id -> (status, when first seen)
        for name in ("/execute_reach", "/look"):
            self.node.create_subscription(GoalStatusArray, f"{name}/_action/status", self._on_status,
                                          qos_profile_action_status_default)

    def _on_status(self, msg: Any) -> None:
        now = time.monotonic()
        for st in msg.status_list:
            key = bytes(st.goal_info.goal_id.uuid)
            old = self.goal_status.get(key)
            self.goal_status[key] = (int(st.status), old[1] if old and old[0] == st.status else now)

    def send_goal(self, client: Any, goal: Any, feedback_callback: Callable[[Any], None]) -> tuple[Any, Any, Any]:
        """``client.send_goal_async`` with a goal id of our own, so that the goal's status can stand in
        for a lost response; (client, goal id, future of the goal response)."""
        import uuid

        from unique_identifier_msgs.msg import UUID
        goal_id = UUID(uuid=list(uuid.uuid4().bytes))
        return client, goal_id, client.send_goal_async(goal, feedback_callback=feedback_callback, goal_uuid=goal_id)

    def close(self) -> None:
        self.look_client.destroy()
        self.exec_client.destroy()
        self.node.destroy_node()
        self.rclpy.try_shutdown()

    def spin_until(self, done: Callable[[], bool], timeout_s: float | None, cancelable: bool = True) -> bool:
        """Spin until ``done()``; False on timeout; ``Canceled`` on Ctrl-C when ``cancelable``."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while not done():
            if cancelable and self.interrupted:
                raise Canceled()
            if deadline is not None and time.monotonic() > deadline:
                return False
            self.executor.spin_once(timeout_sec=0.02)
        return True

    def wait_for_server(self, ready: Callable[[], bool], name: str, owner: str) -> bool:
        """Spin until ``ready()`` (a service or action server is there), at most ``timeout_s``;
        after ``WAIT_NOTE_FIRST_S`` and then every ``WAIT_NOTE_EVERY_S`` a line on stderr says what
        is awaited: ``waiting for /look (reach_executor) ... 55 s left``. False on timeout;
        ``Canceled`` on Ctrl-C."""
        t0 = time.monotonic()
        note = [t0 + WAIT_NOTE_FIRST_S]

        def done() -> bool:
            if ready():
                return True
            now = time.monotonic()
            if now >= note[0]:   # at 2 s, then at 5, 10, 15 ... s
                note[0] = t0 + WAIT_NOTE_EVERY_S * (math.floor((now - t0) / WAIT_NOTE_EVERY_S) + 1)
                self.err.write(f"reach_operator: waiting for {name} ({owner}) ... "
                               f"{max(0.0, self.timeout_s - (now - t0)):.0f} s left\n")
                self.err.flush()
            return False
        return self.spin_until(done, self.timeout_s)

    def plan(self, req: Any) -> Any | None:
        """The response, or None if the service is missing / does not answer."""
        if not self.wait_for_server(self.plan_client.service_is_ready, "/plan_reach", "reach_planner"):
            self.err.write(f"reach_operator: /plan_reach not available after {self.timeout_s:g} s: is reach_planner "
                           "running (same ROS_DOMAIN_ID)?\n")
            return None
        future = self.plan_client.call_async(req)
        budget = float(req.time_budget_s)
        if not self.spin_until(future.done, self.timeout_s + budget):
            self.err.write(f"reach_operator: no /plan_reach response within {self.timeout_s + budget:g} s\n")
            return None
        return future.result()

    def execute(self, trajectory: Any, arm: int, args: argparse.Namespace,
                on_feedback: Callable[[Progress], None]) -> tuple[str, Any]:
        """("done", result) | ("unavailable" | "rejected" | "timeout", None) | ("canceled", result or None)."""
        try:
            up = self.wait_for_server(self.exec_client.server_is_ready, "/execute_reach", "reach_executor")
        except Canceled:
            return "canceled", None
        if not up:
            self.err.write(f"reach_operator: /execute_reach not available after {self.timeout_s:g} s: is "
                           "reach_executor running?\n")
            return "unavailable", None
        goal = self.ExecuteReach.Goal(mode=self.ExecuteReach.Goal.MODE_TRAJECTORY, trajectory=trajectory, arm=arm,
                                      disable_collision_avoidance=args.no_collision_avoidance,
                                      disable_com_compensation=args.no_com_compensation,
                                      smooth_reshaping=args.smooth_reshaping)
        send = self.send_goal(self.exec_client, goal, lambda m: on_feedback(Progress.from_feedback(m.feedback)))
        pts = trajectory.points
        duration = pts[-1].time_from_start.sec + pts[-1].time_from_start.nanosec * 1e-9 if pts else 0.0
        return self._await(send, duration + self.timeout_s)

    def look(self, yaw_rad: list[float], pitch_rad: list[float], dwell_s: float,
             on_feedback: Callable[[Any], None], gaze_points: np.ndarray | None = None) -> tuple[str, Any]:
        """The /look action (head angles, or ``gaze_points`` (K, 3) [m, world] for a whole-body
        gaze at each): same outcomes as :meth:`execute`."""
        try:
            up = self.wait_for_server(self.look_client.server_is_ready, "/look", "reach_executor")
        except Canceled:
            return "canceled", None
        if not up:
            self.err.write(f"reach_operator: /look not available after {self.timeout_s:g} s: is reach_executor "
                           "running?\n")
            return "unavailable", None
        goal = self.Look.Goal(yaw_rad=list(yaw_rad), pitch_rad=list(pitch_rad), dwell_s=float(dwell_s))
        if gaze_points is not None:
            from humanoid_reach_ros.io.msgs import points_list
            goal.gaze_points = points_list(gaze_points)
        poses = len(yaw_rad) or (len(gaze_points) if gaze_points is not None else SCAN_POSES_ASSUMED)
        deadline = time.monotonic() + LOOK_START_GRACE_S
        while True:
            send = self.send_goal(self.look_client, goal, lambda m: on_feedback(m.feedback))
            outcome, result = self._await(send, self.timeout_s + poses * ((dwell_s or 1.0) + 5.0))
            # right after the graph came up the executor may not have taken a /joint_states yet (bench/session,
            # a --scan at once after start-up: NO_JOINT_STATES): ask again, for a few seconds only
            if result is None or result.error_code != ExecuteCode.NO_JOINT_STATES or time.monotonic() > deadline:
                return outcome, result
            self.spin_until(lambda: False, 0.5)   # a pause that Ctrl-C ends (Canceled)

    def _await(self, sent: tuple[Any, Any, Any], result_timeout_s: float) -> tuple[str, Any]:
        """The goal's response, then its result. A service response can be lost when the server's
        response writer has not yet matched this fresh client's reader (the server logs
        "failed to send response (timeout): client will not receive response"; bench/session saw
        it once for /look's goal response: the scan ran to the end and the CLI timed out). So
        the goal's status (a topic, transient local) stands in: accepted for
        ``LOST_RESPONSE_GRACE_S`` without a response means accepted; finished for as long
        without a result means the result request is sent again (the server keeps results)."""
        client, goal_id, send = sent
        key = bytes(goal_id.uuid)

        def status_for(at_least: frozenset[int]) -> bool:
            st = self.goal_status.get(key)
            return st is not None and st[0] in at_least and time.monotonic() - st[1] > LOST_RESPONSE_GRACE_S
        handle = None
        try:
            if not self.spin_until(lambda: send.done() or status_for(GOAL_KNOWN), self.timeout_s):
                return "timeout", None
            if send.done():
                handle = send.result()
                if not handle.accepted:
                    return "rejected", None
            else:
                from rclpy.action.client import ClientGoalHandle
                self.err.write("reach_operator: the goal's acceptance never arrived (a response lost while the "
                               "server discovered this client); its status says accepted: waiting for its result\n")
                handle = ClientGoalHandle(client, goal_id, client._action_type.Impl.SendGoalService.Response(
                    accepted=True))
            result_future = handle.get_result_async()
            deadline = time.monotonic() + result_timeout_s
            if not self.spin_until(lambda: result_future.done() or status_for(GOAL_DONE),
                                   deadline - time.monotonic()):
                return "timeout", None
            while not result_future.done():   # finished, and no result for LOST_RESPONSE_GRACE_S: ask again
                self.err.write("reach_operator: the goal finished but its result did not arrive: asking again\n")
                result_future = handle.get_result_async()
                if not self.spin_until(result_future.done,
                                       min(self.timeout_s, max(0.0, deadline - time.monotonic()))):
                    return "timeout", None
            return "done", result_future.result().result
        except Canceled:
            if handle is None and send.done() and send.result().accepted:
                handle = send.result()
            if handle is None:
                return "canceled", None
            self.err.write("\nreach_operator: Ctrl-C: canceling the goal ...\n")
            cancel = handle.cancel_goal_async()
            self.spin_until(cancel.done, self.timeout_s, cancelable=False)
            result_future = handle.get_result_async()
            self.spin_until(result_future.done, self.timeout_s, cancelable=False)
            return "canceled", result_future.result().result if result_future.done() else None


def trajectory_summary(traj: Any) -> dict[str, Any]:
    pts = traj.points
    end = pts[-1].time_from_start.sec + pts[-1].time_from_start.nanosec * 1e-9 if pts else 0.0
    return {"points": len(pts), "duration_s": end, "joints": len(traj.joint_names)}


def plan_summary(resp: Any) -> dict[str, Any]:
    from humanoid_reach_ros.io.msgs import statistics_dict

    name = PLAN_CODES.get(resp.error_code, (f"UNKNOWN_CODE_{resp.error_code}",))[0]
    return {"success": bool(resp.success), "error_code": int(resp.error_code), "error_name": name,
            "message": resp.message, "arm": ARM_LABELS.get(resp.arm, str(resp.arm)),
            "trajectory": trajectory_summary(resp.trajectory), "statistics": statistics_dict(resp.statistics)}


RESULT_FIELDS = ("duration_s", "steps", "overruns", "max_com_error_m", "min_distance_m", "final_hand_error_m",
                 "final_hand_error_rad")


LOOK_FIELDS = ("poses_done", "duration_s", "max_com_error_m")


def execution_summary(outcome: str, result: Any, fields: tuple[str, ...] = RESULT_FIELDS) -> dict[str, Any]:
    """An ``ExecuteReach`` (or, with ``LOOK_FIELDS``, a ``Look``) outcome and result for --json;
    non-finite numbers become null."""
    out: dict[str, Any] = {"outcome": outcome}
    if result is not None:
        name = EXECUTE_CODES.get(result.error_code, (f"UNKNOWN_CODE_{result.error_code}",))[0]
        out.update({"success": bool(result.success), "error_code": int(result.error_code), "error_name": name,
                    "message": result.message})
        out.update({k: getattr(result, k) for k in fields})
        out = {k: (v if not isinstance(v, float) or math.isfinite(v) else None) for k, v in out.items()}
    return out


def plan_report(s: dict[str, Any]) -> str:
    st, tr = s["statistics"], s["trajectory"]
    return (f"plan: {s['arm']} arm, {tr['points']} points, {tr['duration_s']:.2f} s of motion\n"
            f"  goal sampling {st['goal_sampling_time_s'] * 1e3:.0f} ms ({st['goals_found']}/{st['goals_requested']}"
            f" goals), path {st['path_planning_time_s'] * 1e3:.0f} ms ({st['path_waypoints']} waypoints, "
            f"{st['tree_nodes']} tree nodes), total {st['total_time_s'] * 1e3:.0f} ms\n"
            f"  {st['collision_checks']} collision checks in {st['collision_time_s'] * 1e3:.0f} ms, "
            f"map {st['map_voxels']} voxels\n  {s['message']}")


def execution_report(e: dict[str, Any]) -> str:
    def f(k: str, scale: float, unit: str, nd: int) -> str:
        v = e.get(k)
        return "-" if v is None else f"{v * scale:.{nd}f} {unit}"

    return (f"execution: {e['duration_s']:.2f} s, {e['steps']} steps ({e['overruns']} overruns); max COG drift "
            f"{f('max_com_error_m', 1e3, 'mm', 2)}, min distance {f('min_distance_m', 1e3, 'mm', 1)}, final hand "
            f"error {f('final_hand_error_m', 1e3, 'mm', 1)} / {f('final_hand_error_rad', 1.0, 'rad', 3)}")


def look(op: Operator, args: argparse.Namespace, text: TextIO, err: TextIO, summary: dict[str, Any],
         gaze_points: np.ndarray | None = None) -> int:
    """``--scan`` / ``--look`` (or an automatic look at ``gaze_points``): the /look action with a
    line per head pose; the exit code."""
    yaw, pitch = ([], []) if args.scan or gaze_points is not None else (
        [math.radians(args.look[0])], [math.radians(args.look[1])])
    if gaze_points is None:
        text.write("scanning with the head (the executor's scan pattern) ...\n" if args.scan else
                   f"turning the head to yaw {args.look[0]:g}, pitch {args.look[1]:g} deg ...\n")
        text.flush()

    def feedback(fb: Any) -> None:
        state = "holding" if fb.holding else "moving"
        text.write(f"  head pose {fb.pose_index + 1}/{fb.pose_count}: yaw {math.degrees(fb.yaw_rad):+.1f}, pitch "
                   f"{math.degrees(fb.pitch_rad):+.1f} deg ({state})\n")
        text.flush()
    outcome, result = op.look(yaw, pitch, args.dwell or 0.0, feedback, gaze_points)
    looked = execution_summary(outcome, result, LOOK_FIELDS)
    if gaze_points is None:
        summary["look"] = looked
    else:
        summary.setdefault("auto_looks", []).append(looked)
    if outcome == "unavailable":
        return EXIT["unavailable"]
    if outcome == "timeout":
        err.write("look: no answer from /look in time\n")
        return EXIT["unavailable"]
    if outcome == "rejected":
        err.write("look failed: the goal was rejected by /look\n")
        return EXIT["execution"]
    if result is None:
        return EXIT["canceled"]
    if result.success and result.error_code == 0:
        text.write(f"look: {result.message} [{result.duration_s:.1f} s, max COG drift "
                   f"{result.max_com_error_m * 1e3:.2f} mm]\n")
        return EXIT["success"]
    err.write(f"look {'canceled' if outcome == 'canceled' else 'failed'}: "
              f"{code_text(EXECUTE_CODES, result.error_code, result.message)}\n")
    return EXIT["canceled"] if outcome == "canceled" else (exit_class(EXECUTE_CODES, result.error_code)
                                                           or EXIT["execution"])


# ---------------------------------------------------------------- look where the plan needs to see
LOOK_START_GRACE_S = 5.0        # /look answered NO_JOINT_STATES: asked again for this long (a graph just up)
EXECUTOR_NODE = "/reach_executor"       # the executor node the CLI talks to (its parameters)


def plan_with_looks(op: Operator, args: argparse.Namespace, req: Any, text: TextIO, err: TextIO,
                    summary: dict[str, Any]) -> tuple[Any | None, int]:
    """``/plan_reach``; while it answers UNOBSERVED_SPACE with the points where the target or the
    best path meets unobserved space, look there (a balanced whole-body gaze through /look,
    head and chest) and plan again, at most ``--max-looks`` times (``--no-auto-look``: never).
    ``(response, exit code)``; the response is None when the planner could not be asked."""
    looks = 0
    while True:
        try:
            resp = op.plan(req)
        except Canceled:
            err.write("reach_operator: canceled while planning\n")
            return None, EXIT["canceled"]
        if resp is None:
            return None, EXIT["unavailable"]
        if resp.error_code != PlanError.UNOBSERVED_SPACE or not resp.unobserved_points:
            return resp, EXIT["success"]
        pts = np.array([[p.x, p.y, p.z] for p in resp.unobserved_points], dtype=float)
        where = ", ".join(str(np.round(p, 2).tolist()) for p in pts)
        if args.no_auto_look or looks >= args.max_looks:
            if not args.no_auto_look:
                err.write(f"reach_operator: still unobserved after {looks} automatic look(s) at {where}\n")
            return resp, EXIT["success"]
        # /look waited for up to --timeout, like every server: on a busy machine a fresh CLI took over 3 s to
        # discover the action's five endpoints (bench/session), so no shorter guess tells "no executor" from
        # "not discovered yet"; a graph without an executor (a planner fed by a bag) says --no-auto-look
        try:
            up = op.wait_for_server(op.look_client.server_is_ready, "/look",
                                    "reach_executor, for an automatic look; --no-auto-look skips it")
        except Canceled:
            err.write("reach_operator: canceled while waiting for /look\n")
            return None, EXIT["canceled"]
        if not up:
            err.write(f"reach_operator: /look not available after {op.timeout_s:g} s (is reach_executor running? "
                      f"--no-auto-look plans without looking): no automatic look at {where}\n")
            return resp, EXIT["success"]
        looks += 1
        text.write(f"the plan needs to see {where} m (unobserved): looking there, automatic look {looks}/"
                   f"{args.max_looks} (--no-auto-look turns this off) ...\n")
        text.flush()
        code = look(op, args, text, err, summary, gaze_points=pts)
        if code != EXIT["success"]:
            return None, code
        if args.marker and (code := ensure_marker_target(op, args, text, err, summary)) != EXIT["success"]:
            return None, code   # the look turned the head away from the marker: find it again
        text.write("planning again ...\n")
        text.flush()


# ---------------------------------------------------------------- the marker, fresh
MARKER_FRESH_WAIT_S = 2.0    # a /target_pose within this long of finding its publisher: seen now (>= 2 Hz in view)
MARKER_DISCOVERY_S = 5.0     # a marker_localizer (a /target_pose publisher) gets this long to be discovered
MARKER_DIAGNOSTICS_WAIT_S = 2.5   # then its diagnostics (1 Hz, the last marker position) this long at most
MARKER_WAIT_S = 15.0         # after turning the head toward the marker: wait this long for a /target_pose
MARKER_LOOK_DWELL_S = 0.1    # the head's hold there (the wait for the marker follows)


def executor_parameters(op: Operator, names: list[str], timeout_s: float = 2.0) -> dict[str, Any]:
    """``names`` of the executor's parameters (``/reach_executor/get_parameters``); the declared
    defaults (``reach_executor_params.PARAMETERS``) for those it does not answer in time."""
    from rcl_interfaces.srv import GetParameters
    from rclpy.parameter import parameter_value_to_python

    from humanoid_reach_ros.nodes.reach_executor_params import PARAMETERS

    values = {n: PARAMETERS[n].default for n in names}
    client = op.node.create_client(GetParameters, f"{EXECUTOR_NODE}/get_parameters")
    try:
        if op.spin_until(client.service_is_ready, timeout_s):
            future = client.call_async(GetParameters.Request(names=names))
            if op.spin_until(future.done, timeout_s) and future.result() is not None:
                for n, v in zip(names, future.result().values):
                    if v.type != 0:   # PARAMETER_NOT_SET
                        values[n] = parameter_value_to_python(v)
    finally:
        op.node.destroy_client(client)
    return values


def ensure_marker_target(op: Operator, args: argparse.Namespace, text: TextIO, err: TextIO,
                         summary: dict[str, Any]) -> int:
    """``--marker``: the planner takes the marker's ``/target_pose`` only while it is recent (1 s,
    its ``target_timeout_s``), and ``marker_localizer`` publishes only while the marker is in the
    camera's view. When no ``/target_pose`` comes within ``MARKER_FRESH_WAIT_S`` (of discovering its
    publisher, within ``MARKER_DISCOVERY_S``), the head is turned
    (``/look``) toward the marker's last known position (from ``marker_localizer``'s diagnostics,
    aimed from the current posture) or, with none known, to the executor's ``marker_look_deg``;
    then a fresh pose is awaited for ``--marker-wait`` (``MARKER_WAIT_S``) with a countdown. Returns the exit code to
    stop with, or ``EXIT["success"]`` to plan. Without a ``marker_localizer`` it leaves the answer
    to the planner (``NO_TARGET`` with its hint); without an executor the look says so (exit 3)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseStamped
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import JointState

    seen: dict[str, Any] = {"pose_t": -math.inf, "pose": None, "last": None, "joints": None, "diagnostics": False}

    def on_pose(m: Any) -> None:
        seen["pose_t"], seen["pose"] = time.monotonic(), m

    def on_diagnostics(m: Any) -> None:
        for st in m.status:
            v = {kv.key: kv.value for kv in st.values}
            if st.name.startswith("marker_localizer"):
                seen["diagnostics"] = True
                if "target_x_m" in v:
                    seen["last"] = [float(v["target_x_m"]), float(v["target_y_m"]), float(v["target_z_m"])]

    def since(t: float) -> Callable[[], bool]:
        return lambda: seen["pose_t"] >= t

    subs = [op.node.create_subscription(PoseStamped, "/target_pose", on_pose, qos_profile_sensor_data),
            op.node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 20),
            op.node.create_subscription(JointState, "/joint_states", lambda m: seen.__setitem__("joints", m),
                                        qos_profile_sensor_data)]
    report: dict[str, Any] = {"fresh": False, "looked_deg": None, "toward": None}
    summary["marker"] = report
    t0 = time.monotonic()
    try:
        found: list[float] = []   # when this node discovered a /target_pose publisher (it lags on a busy machine)

        def settled() -> bool:
            now = time.monotonic()
            if not found and op.node.count_publishers("/target_pose") > 0:
                found.append(now)
            return since(t0)() or now > (found[0] + MARKER_FRESH_WAIT_S if found else t0 + MARKER_DISCOVERY_S)
        op.spin_until(settled, None)
        if since(t0)():
            report["fresh"] = True
            return EXIT["success"]
        if op.node.count_publishers("/target_pose") == 0:
            return EXIT["success"]   # no marker_localizer: the planner answers (NO_TARGET and its hint)
        t_diag = time.monotonic() + MARKER_DIAGNOSTICS_WAIT_S   # its diagnostics (1 Hz) hold the last position
        op.spin_until(lambda: seen["diagnostics"] or since(t0)() or time.monotonic() > t_diag, None)
        if since(t0)():
            report["fresh"] = True
            return EXIT["success"]
        params = executor_parameters(op, ["marker_look_deg", "robot_config"])
        if seen["last"] is not None and seen["joints"] is not None:
            from humanoid_reach_ros.io import msgs
            from humanoid_reach_ros.robot.head_aim import aim_head_deg
            from humanoid_reach_ros.robot.model import RobotModel

            robot = RobotModel(params["robot_config"])
            js = msgs.parse_joint_state(seen["joints"])
            yaw, pitch = aim_head_deg(robot, seen["last"], robot.joints_from_dict(dict(zip(js.names, js.positions))))
            report["toward"] = seen["last"]
            where = (f"toward the marker's last known position ({', '.join(f'{v:.2f}' for v in seen['last'])}) m: "
                     f"yaw {yaw:g}, pitch {pitch:g} deg")
        else:
            yaw, pitch = (float(v) for v in params["marker_look_deg"])
            why = ("no marker position known" if seen["last"] is None and seen["diagnostics"] else
                   "no diagnostics from marker_localizer" if seen["last"] is None else "no /joint_states")
            where = f"where the executor looks for it (marker_look_deg; {why}): yaw {yaw:g}, pitch {pitch:g} deg"
        report["looked_deg"] = [yaw, pitch]
        text.write(f"no /target_pose within {MARKER_FRESH_WAIT_S:g} s (the marker is out of view): turning the head "
                   f"{where} ...\n")
        text.flush()
        outcome, result = op.look([math.radians(yaw)], [math.radians(pitch)], MARKER_LOOK_DWELL_S, lambda fb: None)
        if outcome == "canceled" or (result is not None and result.error_code == ExecuteCode.CANCELED):
            err.write("reach_operator: canceled while turning the head toward the marker\n")
            return EXIT["canceled"]
        if outcome != "done" or result is None or not result.success:
            why = code_text(EXECUTE_CODES, result.error_code, result.message) if result is not None else outcome
            err.write(f"look toward the marker failed: {why}\n")
            return EXIT["unavailable"] if outcome in ("unavailable", "timeout") else EXIT["execution"]
        t1 = time.monotonic()
        note = [t1]
        wait_s = args.marker_wait

        def fresh() -> bool:
            if since(t1)():
                return True
            now = time.monotonic()
            if now >= note[0]:
                note[0] += WAIT_NOTE_EVERY_S
                err.write(f"reach_operator: waiting for /target_pose (marker_localizer) ... "
                          f"{max(0.0, wait_s - (now - t1)):.0f} s left\n")
                err.flush()
            return False
        if not op.spin_until(fresh, wait_s):
            err.write(f"reach_operator: no /target_pose within {wait_s:g} s after turning the head {where}: "
                      "is the marker in view? Scan (--scan), look (--look YAW PITCH) or give --target\n")
            return EXIT["no_input"]
        report["fresh"] = True
        p = seen["pose"].pose.position
        text.write(f"marker seen at ({p.x:.3f}, {p.y:.3f}, {p.z:.3f}) m\n")
        text.flush()
        return EXIT["success"]
    except Canceled:
        err.write("reach_operator: canceled while waiting for the marker\n")
        return EXIT["canceled"]
    finally:
        for sub in subs:
            op.node.destroy_subscription(sub)


def run(args: argparse.Namespace, out: TextIO = sys.stdout, err: TextIO = sys.stderr) -> int:
    text = err if args.json else out  # with --json, stdout holds only the JSON line
    summary: dict[str, Any] = {"look": None, "plan": None, "execution": None}

    def finish(code: int) -> int:
        summary["exit_code"] = code
        if args.json:
            out.write(json.dumps(summary) + "\n")
            out.flush()
        return code

    req = plan_request(args) if args.plan else None
    op = Operator(args.timeout, err)
    old = {s: signal.signal(s, lambda *_: setattr(op, "interrupted", True)) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        if args.scan or args.look is not None:
            code = look(op, args, text, err, summary)
            if code != EXIT["success"] or not args.plan:
                return finish(code)
        if args.marker and (code := ensure_marker_target(op, args, text, err, summary)) != EXIT["success"]:
            return finish(code)
        target = "the rest posture (home)" if args.home else "the marker's /target_pose" if args.marker else \
            f"({', '.join(f'{v:g}' for v in args.target)}) in {args.frame or 'world'}"
        text.write(f"planning to {target}" + ("" if args.home else f", arm {args.arm}") + " ...\n")
        text.flush()
        resp, code = plan_with_looks(op, args, req, text, err, summary)
        if resp is None:
            return finish(code)
        summary["plan"] = plan_summary(resp)
        if not resp.success or resp.error_code != 0:
            err.write(f"plan failed: {code_text(PLAN_CODES, resp.error_code, resp.message)}\n")
            return finish(exit_class(PLAN_CODES, resp.error_code) or EXIT["internal"])
        text.write(plan_report(summary["plan"]) + "\n")
        if not args.execute:
            return finish(EXIT["success"])

        text.write("executing ...\n")
        printer = ProgressPrinter(text)
        try:
            outcome, result = op.execute(resp.trajectory, resp.arm, args, printer.update)
        finally:
            printer.close()
        summary["execution"] = execution_summary(outcome, result)
        if outcome == "unavailable":
            return finish(EXIT["unavailable"])
        if outcome == "timeout":
            err.write(f"execution: no answer from /execute_reach within the trajectory duration + {args.timeout:g} s\n")
            return finish(EXIT["unavailable"])
        if outcome == "rejected":
            err.write("execution failed: the goal was rejected by /execute_reach\n")
            return finish(EXIT["execution"])
        if result is not None:
            e = summary["execution"]
            if result.error_code == 0 and result.success:
                text.write(execution_report(e) + "\n")
            else:
                err.write(f"execution {'canceled' if outcome == 'canceled' else 'failed'}: "
                          f"{code_text(EXECUTE_CODES, result.error_code, result.message)}\n")
                if result.steps:
                    err.write(execution_report(e) + "\n")
        if outcome == "canceled":
            return finish(EXIT["canceled"])
        return finish(exit_class(EXECUTE_CODES, result.error_code) if result.success or result.error_code
                      else EXIT["execution"])
    finally:
        op.close()
        for s, h in old.items():
            signal.signal(s, h)


def main(argv: list[str] | None = None) -> int:
    from rclpy.utilities import remove_ros_args

    argv = sys.argv if argv is None else argv
    args = parse_args(remove_ros_args(argv)[1:])
    try:
        return run(args)
    except (KeyboardInterrupt, Canceled):   # Ctrl-C before run() took the signal over, or between its steps
        sys.stderr.write("\nreach_operator: canceled (Ctrl-C)\n")
        return EXIT["canceled"]


if __name__ == "__main__":
    sys.exit(main())
