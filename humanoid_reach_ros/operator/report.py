"""What ``reach_operator`` says: code texts, exit classes, the progress bar, summaries and reports.

Every error code (``msg/ErrorCode``: one numbering for ``PlanReach``, ``ExecuteReach`` and
``Look``) is printed by name with the server's message and a hint; its exit class comes from
``codes.CODE_INFO`` too (``EXIT``): 0 success; 1 internal error of a node; 2 bad command line
(argparse); 3 a server is not available or did not answer within ``--timeout``; 4 the request
was refused as invalid; 5 no motion exists (out of reach, start in collision, no path, timed
out); 6 a node lacks an input or is busy (no map, no marker target, no joint states, busy); 7
execution failed (goal rejected, aborted, preempted, target not reached); 130 canceled with Ctrl-C.
ROS-free: responses, results and feedback are read by attribute (a message or a stand-in).
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, TextIO

from humanoid_reach_ros.codes import ARM_REQUESTS, CODE_INFO, EXIT, code_name

ARM_LABELS = {code: name for name, code in ARM_REQUESTS.items()}


def code_text(code: int, message: str) -> str:
    """``NAME (code): server message -- hint`` (no hint where the server's message gives it;
    ``codes.CODE_INFO``)."""
    info = CODE_INFO.get(code)
    hint = info[1] if info else "a code this client does not know"
    text = f"{code_name(code)} ({code})"
    if message:
        text += f": {message}"
    return text if code == 0 or not hint else f"{text} -- {hint}"


def exit_class(code: int) -> int:
    """The exit code of a failure with ``code`` (``codes.CODE_INFO``; unknown: internal)."""
    info = CODE_INFO.get(code)
    return EXIT[info[0] if info else "internal"]


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


def head_pose_line(fb: Any) -> str:
    """One ``Look`` feedback: ``  head pose 2/5: yaw +10.0, pitch +20.0 deg (holding)``."""
    state = "holding" if fb.holding else "moving"
    return (f"  head pose {fb.pose_index + 1}/{fb.pose_count}: yaw {math.degrees(fb.yaw_rad):+.1f}, pitch "
            f"{math.degrees(fb.pitch_rad):+.1f} deg ({state})")


# ---------------------------------------------------------------- summaries (--json) and reports
def trajectory_duration(traj: Any) -> float:
    """The last point's ``time_from_start`` [s] (0 without points)."""
    pts = traj.points
    return pts[-1].time_from_start.sec + pts[-1].time_from_start.nanosec * 1e-9 if pts else 0.0


def trajectory_summary(traj: Any) -> dict[str, Any]:
    return {"points": len(traj.points), "duration_s": trajectory_duration(traj), "joints": len(traj.joint_names)}


def statistics_fields(st: Any) -> dict[str, Any]:
    """A ``PlanningStatistics`` (a message: its fields in order; or a mapping) as a dict."""
    if isinstance(st, Mapping):
        return dict(st)
    return {k: getattr(st, k) for k in type(st).get_fields_and_field_types()}


def plan_summary(resp: Any) -> dict[str, Any]:
    return {"success": bool(resp.success), "error_code": int(resp.error_code.val),
            "error_name": code_name(resp.error_code.val),
            "message": resp.message, "arm": ARM_LABELS.get(resp.arm, str(resp.arm)),
            "trajectory": trajectory_summary(resp.trajectory), "statistics": statistics_fields(resp.statistics)}


RESULT_FIELDS = ("duration_s", "steps", "overruns", "max_com_error_m", "min_distance_m", "final_hand_error_m",
                 "final_hand_error_rad", "hand_in_contact", "contact_distance_m", "contact_with")
LOOK_FIELDS = ("poses_done", "duration_s", "max_com_error_m")


def execution_summary(outcome: str, result: Any, fields: tuple[str, ...] = RESULT_FIELDS) -> dict[str, Any]:
    """An ``ExecuteReach`` (or, with ``LOOK_FIELDS``, a ``Look``) outcome and result for --json;
    non-finite numbers become null."""
    out: dict[str, Any] = {"outcome": outcome}
    if result is not None:
        out.update({"success": bool(result.success), "error_code": int(result.error_code.val),
                    "error_name": code_name(result.error_code.val),
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
            f"{f('max_com_error_m', 1e3, 'mm', 2)}, min distance {f('min_distance_m', 1e3, 'mm', 1)} (the target's "
            f"object left out), final hand error {f('final_hand_error_m', 1e3, 'mm', 1)} / "
            f"{f('final_hand_error_rad', 1.0, 'rad', 3)}\n  {contact_line(e)}")


def contact_line(e: dict[str, Any]) -> str:
    """Where the hand ended (the result's contact fields): a touch, or how far the nearest voxel is."""
    d = e.get("contact_distance_m")
    if e.get("hand_in_contact"):
        return f"hand IN CONTACT ({'-' if d is None else f'{d * 1e3:.1f} mm'}): {e.get('contact_with', '')}"
    if d is None:
        return "hand contact: " + (e.get("contact_with") or "unknown")
    return f"hand not in contact: the nearest voxel, the target's object included, is {d * 1e3:.1f} mm away"
