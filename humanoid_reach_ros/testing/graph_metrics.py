"""Figures of a running graph, computed from what a user can see: /proc, logs, measured joint states.

Used by ``bench/graph.py`` (the headline figures in the running graph) and tested on their own
(``test/test_graph_metrics.py``). No rclpy here.

* :func:`process_tree` / :func:`cpu_seconds`: CPU time (utime + stime, all threads) of a
  process and its descendants (the executor's control loop is a child process);
* :class:`CpuSampler`: % of one core per node over a window;
* :func:`log_lines_at_or_above`: INFO-or-louder rclpy log lines in a slice of a node's log;
* :func:`percentile`, :func:`max_gap_ms`;
* :func:`measured_balance`: feet and exact-COG drift from measured joint positions (the left sole
  relative to the right one, the COG in the right sole's frame), and the final hand error.
"""
from __future__ import annotations

import os
import re
import time
from dataclasses import dataclass, field
from typing import Iterable, Sequence

import numpy as np

LOG_LEVEL = re.compile(r"^\[(DEBUG|INFO|WARN|WARNING|ERROR|FATAL)\]")
LOUD = {"INFO", "WARN", "WARNING", "ERROR", "FATAL"}


# ---------------------------------------------------------------- CPU
def _stat_fields(pid: int) -> list[str] | None:
    try:
        with open(f"/proc/{pid}/stat") as f:
            text = f.read()
    except OSError:
        return None
    return text[text.rindex(")") + 2:].split()   # after "pid (comm) "


def process_tree(pid: int) -> list[int]:
    """``pid`` and all its descendants (by the parent pid in /proc/<pid>/stat)."""
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            f = _stat_fields(int(entry))
            if f is not None:
                children.setdefault(int(f[1]), []).append(int(entry))
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        todo.extend(children.get(p, []))
    return out


def cpu_seconds(pids: Iterable[int]) -> float:
    """utime + stime of ``pids`` (all their threads) in seconds; vanished processes count 0."""
    tck = os.sysconf("SC_CLK_TCK")
    total = 0
    for p in pids:
        f = _stat_fields(p)
        if f is not None:
            total += int(f[11]) + int(f[12])
    return total / tck


@dataclass
class CpuSampler:
    """% of one core of named process trees between :meth:`start` and :meth:`stop`."""

    roots: dict[str, int]
    _t0: float = 0.0
    _c0: dict[str, float] = field(default_factory=dict)
    _trees: dict[str, list[int]] = field(default_factory=dict)

    def start(self) -> None:
        self._trees = {n: process_tree(p) for n, p in self.roots.items()}
        self._c0 = {n: cpu_seconds(t) for n, t in self._trees.items()}
        self._t0 = time.monotonic()

    def stop(self) -> dict[str, float]:
        dt = max(time.monotonic() - self._t0, 1e-9)
        return {n: 100.0 * (cpu_seconds(t) - self._c0[n]) / dt for n, t in self._trees.items()}


# ---------------------------------------------------------------- logs
def log_lines_at_or_above(text: str) -> int:
    """Number of INFO-or-louder rclpy log lines (``[INFO] [stamp] [node]: ...``) in ``text``."""
    return sum(1 for line in text.splitlines() if (m := LOG_LEVEL.match(line)) and m.group(1) in LOUD)


# ---------------------------------------------------------------- numbers
def percentile(values: Sequence[float], q: float) -> float | None:
    v = np.asarray(list(values), dtype=float)
    return float(np.percentile(v, q)) if len(v) else None


def max_gap_ms(stamps_s: Sequence[float]) -> float | None:
    """Largest difference between consecutive times [s] -> ms (None for fewer than 2)."""
    t = np.sort(np.asarray(list(stamps_s), dtype=float))
    return float(np.max(np.diff(t)) * 1e3) if len(t) >= 2 else None


# ---------------------------------------------------------------- what the robot did
def _config(robot, joints: np.ndarray) -> np.ndarray:
    return robot.config(joints, robot.base_on_feet(joints))


def measured_balance(robot, joint_series: Sequence[np.ndarray], arm: str | None = None,
                     final_reference: np.ndarray | None = None, com_reference_xy: np.ndarray | None = None
                     ) -> dict[str, float]:
    """Drifts over a series of measured joint vectors (model order), all relative to the right
    sole (the stance anchor):

    * ``feet_drift_mm``: max change of the left sole's position in the right sole's frame;
    * ``com_drift_mm``: max horizontal distance of the exact COG (right-sole frame) from
      ``com_reference_xy`` (default: its value at the first sample);
    * ``hand_error_final_mm``: the last sample's hand position vs that of ``final_reference``
      (the trajectory's last point), when ``arm`` and ``final_reference`` are given.
    """
    rs, ls = robot.sole_frames
    feet, com = 0.0, 0.0
    left0, com0 = None, None if com_reference_xy is None else np.asarray(com_reference_xy, float)
    for j in joint_series:
        q = _config(robot, np.asarray(j, float))
        R = robot.frame_pose(q, rs)
        left = R.actInv(robot.frame_pose(q, ls)).translation
        c = R.actInv(np.asarray(robot.com(q)))[:2]
        if left0 is None:
            left0 = left
        if com0 is None:
            com0 = c
        feet = max(feet, float(np.linalg.norm(left - left0)))
        com = max(com, float(np.linalg.norm(c - com0)))
    out = {"feet_drift_mm": feet * 1e3, "com_drift_mm": com * 1e3}
    if arm is not None and final_reference is not None and len(joint_series):
        tip = robot.limbs[f"{arm}_arm"].tip

        def hand(j):
            q = _config(robot, np.asarray(j, float))
            return robot.frame_pose(q, rs).actInv(robot.frame_pose(q, tip)).translation
        out["hand_error_final_mm"] = float(np.linalg.norm(hand(joint_series[-1]) - hand(final_reference))) * 1e3
    return out


def nominal_com_in_sole(robot) -> np.ndarray:
    """Half-sitting's COG xy in the right sole's frame: the executor's COG target after an
    off-nominal start (``WholeBodyExecutor``'s recentering)."""
    q = robot.half_sitting()
    return robot.frame_pose(q, robot.sole_frames[0]).actInv(np.asarray(robot.com(q)))[:2]


__all__ = ["process_tree", "cpu_seconds", "CpuSampler", "log_lines_at_or_above", "percentile", "max_gap_ms",
           "measured_balance", "nominal_com_in_sole"]
