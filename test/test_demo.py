"""`make demo` as it stands: joint_driver as a process, an IK reach, a report, clean shutdown."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from nodetools import REPO_ROOT

pytestmark = pytest.mark.node


def run_demo(tmp_path, *args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "humanoid_reach_ros.demo", "--out", str(tmp_path), *args],
                          cwd=REPO_ROOT, capture_output=True, text=True, timeout=timeout)


def test_demo_reaches_and_stops_cleanly(tmp_path):
    proc = run_demo(tmp_path, "--arm", "left")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    report = json.loads((tmp_path / "demo_report.json").read_text())
    assert report["final_hand_error_m"] < 1e-3
    assert report["limit_violations"] == 0 and report["max_speed_over_limit"] <= 1.0 + 1e-6
    assert report["joint_states_rate_hz"] >= 100  # 200 Hz nominal; loose for a loaded CI machine
    assert (tmp_path / "demo_joints.png").stat().st_size > 10_000
    assert "joint_driver stopped (exit code 0)" in proc.stdout


def test_demo_rejects_bad_options(tmp_path):
    proc = run_demo(tmp_path, "--duration", "0")
    assert proc.returncode == 2 and "--duration" in proc.stderr
    proc = run_demo(tmp_path, "--target", "nan", "0", "1")
    assert proc.returncode == 2 and "finite" in proc.stderr


def test_demo_reports_an_unreachable_target(tmp_path):
    proc = run_demo(tmp_path, "--target", "2.0", "0", "1")
    assert proc.returncode == 1 and "not reachable" in proc.stderr
    assert "joint_driver stopped (exit code 0)" in proc.stdout
