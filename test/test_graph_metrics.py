"""The running-graph figures' arithmetic (humanoid_reach_ros/testing/graph_metrics.py), without a graph."""
from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np
import pytest

from humanoid_reach_ros.testing.graph_metrics import (CpuSampler, cpu_seconds, log_lines_at_or_above, max_gap_ms,
                                              measured_balance, nominal_com_in_sole, percentile, process_tree)


def test_log_lines_counts_info_and_louder_only() -> None:
    text = "\n".join(["[INFO] [1.0] [a]: x", "[DEBUG] [1.1] [a]: y", "[WARN] [1.2] [a]: z", "plain output",
                      "[ERROR] [1.3] [a]: e", "  [INFO] indented is not a log line", "[FATAL] [1.4] [a]: f"])
    assert log_lines_at_or_above(text) == 4
    assert log_lines_at_or_above("") == 0


def test_percentile_and_gaps() -> None:
    assert percentile([], 50) is None
    assert percentile([1.0, 2.0, 3.0], 50) == 2.0
    assert max_gap_ms([0.0]) is None
    assert max_gap_ms([0.0, 0.005, 0.010, 0.040, 0.045]) == pytest.approx(30.0)
    assert max_gap_ms([0.04, 0.0, 0.01]) == pytest.approx(30.0)       # order does not matter


def test_cpu_of_a_process_tree_includes_children() -> None:
    """The tree's figure counts a busy child: the sampler's % covers at least the CPU the child
    itself used in the window (the window stays open until the child has used 0.3 s of CPU, however
    busy the machine is)."""
    child = subprocess.Popen([sys.executable, "-c", "import time\nt=time.time()\nwhile time.time()-t<60: pass"])
    try:
        me = os.getpid()
        assert child.pid in process_tree(me)
        c0 = cpu_seconds([child.pid])
        sampler = CpuSampler({"me": me})
        sampler.start()
        t0 = time.monotonic()
        deadline = t0 + 50.0
        while cpu_seconds([child.pid]) - c0 < 0.3 and time.monotonic() < deadline:
            time.sleep(0.05)
        child_pct = 100.0 * (cpu_seconds([child.pid]) - c0) / (time.monotonic() - t0)
        pct = sampler.stop()["me"]
        assert child_pct > 0.0
        assert 0.8 * child_pct <= pct < 220.0, (pct, child_pct)   # the busy child is counted
        assert cpu_seconds([2 ** 30]) == 0.0          # a vanished process counts 0
    finally:
        child.kill()
        child.wait(10)


def test_measured_balance_zero_for_a_still_robot_and_sees_a_moving_foot(robot) -> None:
    hs = robot.half_sitting_joints
    still = measured_balance(robot, [hs, hs, hs], arm="right", final_reference=hs)
    assert still["feet_drift_mm"] < 1e-9 and still["com_drift_mm"] < 1e-9 and still["hand_error_final_mm"] < 1e-9
    moved = hs.copy()
    moved[robot.joint_index["LLEG_JOINT3"]] += 0.05                  # the left knee bends: the left sole moves
    out = measured_balance(robot, [hs, moved], arm="right", final_reference=hs)
    assert out["feet_drift_mm"] > 1.0 and out["com_drift_mm"] > 0.0
    arm = hs.copy()
    arm[robot.joint_index["RARM_JOINT3"]] -= 0.1                     # the right elbow: the hand moves
    assert measured_balance(robot, [hs, arm], arm="right", final_reference=hs)["hand_error_final_mm"] > 5.0
    # the COG reference can be given (the executor's nominal point)
    ref = nominal_com_in_sole(robot)
    assert measured_balance(robot, [hs], com_reference_xy=ref)["com_drift_mm"] < 1e-9
    assert np.shape(ref) == (2,)
