"""``reach_operator``'s command line: the parser, its checks, and the plan request's inputs as plain values.

Plans a reaching motion to a Workspace Goal Region (Kanehiro et al. eq. 3: the hand pose
``T_target * Trans(dx, dy, dz) * RPY(droll, dpitch, dyaw)`` with the offsets in
``[lower, upper]``) around either the AR marker's ``/target_pose`` (``--marker``, the
default: ``PlanReach.use_marker_target``) or a pose given on the command line
(``--target x y z [--rpy-deg r p y] [--frame world|base_link]``), and with ``--execute`` sends
the returned trajectory as an ``/execute_reach`` action goal.

The region bounds default to the valve WGR of eq. 3 (``planning.wgr.valve_region``:
position fixed at the target, roll and pitch in [-pi/2, pi/2], yaw free); ``--wgr-deg`` gives
6 lower + 6 upper bounds (x y z [m], roll pitch yaw [deg]). Angles are in degrees where an
operator types them (``--rpy-deg``, ``--wgr-deg``); ``--rpy`` and ``--wgr`` take the same in
radians (kept for scripts), where a typed 3.1416 counts as pi (the planner clamps angle
bounds within ``ANGLE_TOL`` of +-pi). ROS-free: the node turns :class:`PlanInputs` into a
``PlanReach`` request.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass
from typing import Callable, NoReturn

import numpy as np

from humanoid_reach_ros.codes import ARM_REQUESTS, EXIT
from humanoid_reach_ros.planning.wgr import ANGLE_TOL

ARMS = ARM_REQUESTS                     # --arm name -> PlanReach.Request.ARM_*
MARKER_WAIT_S = 15.0         # after turning the head toward the marker: wait this long for a /target_pose


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


class _Parser(argparse.ArgumentParser):
    """argparse whose argument error is one line and a pointer to ``--help`` (not the usage
    block) on stderr; with ``--json`` also the summary object, as the only line on stdout
    (docs/operator.md), its ``error`` the same text and ``exit_code`` 2."""

    json_summary = False

    def error(self, message: str) -> NoReturn:
        if self.json_summary:
            sys.stdout.write(json.dumps({"look": None, "plan": None, "execution": None,
                                         "exit_code": EXIT["usage"], "error": message}) + "\n")
            sys.stdout.flush()
        self.exit(EXIT["usage"], f"{self.prog}: error: {message}\n{self.prog}: --help lists every flag\n")


def planner_names() -> list[str]:
    from humanoid_reach_ros.planning.path import PLANNER_NAMES
    return list(PLANNER_NAMES)


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(
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
    p.json_summary = "--json" in argv
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


@dataclass(frozen=True)
class PlanInputs:
    """The ``PlanReach`` request of the command line as plain values (not validated beyond
    argparse: the planner answers bad bounds with ``INVALID_BOUNDS``)."""

    arm: int                      # PlanReach.Request.ARM_*
    goal_count: int               # 0: the node's
    planner: str                  # "": the node's
    time_budget_s: float          # 0: the node's
    use_marker_target: bool
    seed: int                     # -1: the node's
    home: bool
    target: tuple[np.ndarray, np.ndarray] | None   # (position [m], rotation matrix) of --target, else None
    frame: str                    # frame of the target
    lower: np.ndarray             # (6,) WGR bounds
    upper: np.ndarray


def plan_inputs(args: argparse.Namespace) -> PlanInputs:
    target = None
    if args.target is not None:
        from humanoid_reach_ros.planning.wgr import rpy_matrix
        target = (np.asarray(args.target, float), rpy_matrix(np.asarray(args.rpy or (0.0, 0.0, 0.0), float)))
    lower, upper = region_bounds(args.wgr)
    return PlanInputs(arm=ARMS[args.arm], goal_count=args.goals or 0, planner=args.planner or "",
                      time_budget_s=float(args.budget or 0.0), use_marker_target=bool(args.marker),
                      seed=-1 if args.seed is None else args.seed, home=bool(args.home), target=target,
                      frame=args.frame or "world", lower=lower, upper=upper)
