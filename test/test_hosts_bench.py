"""bench/hosts.py in its reduced mode (issue 24): the operator's link cut for 5 s during a scan.

What test_hosts.py does not cover: a cut of the *operator's* link while a long action runs on
the robot (the scan's /look goal, ~20 s of head motion). The bench's own cleanup is checked
too (namespaces gone, nothing left running in them). ``--placements compute --no-flow --cuts
scan --idle 3``: hr_graph on robot and compute, the probe on the robot's host, the pinger on
the operator's, one scan with the cut: about 60-70 s here.

Asserted: the run finishes (exit 0) with the bench's JSON last (every required key); the cut
happened during the scan; the CLI rode it out or exited with a clear error (never hung); the
graph answered again after the link came back (recovery measured, within the bench's 60 s);
the executor reported its overruns; ``tools/hosts.sh down`` ran. The issue's targets
themselves (recovery <= 5 s, no overruns) are the bench's to judge, on a machine that is not
loaded by others.

Needs root (network namespaces): skipped otherwise, saying so.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from nodetools import REPO_ROOT

pytestmark = pytest.mark.node

BENCH = REPO_ROOT / "bench" / "hosts.py"
RUN_DEADLINE_S = 600.0      # generous: a loaded machine (the run is ~65 s on an idle one)


@pytest.mark.skipif(os.geteuid() != 0, reason="bench/hosts.py needs root: network namespaces, veth and tc "
                    "(tools/hosts.sh); CI runs as root")
def test_bench_hosts_cut_of_the_operators_link_during_a_scan(ros_env, tmp_path: Path) -> None:
    out = tmp_path / "bench_hosts"
    r = subprocess.run([sys.executable, str(BENCH), "--placements", "compute", "--no-flow", "--cuts", "scan",
                        "--idle", "3", "--timeout", "20", "--wait-hosts", "300", "--out", str(out)],
                       env=dict(ros_env), cwd=REPO_ROOT, capture_output=True, text=True, timeout=RUN_DEADLINE_S)
    assert r.returncode == 0, (r.returncode, r.stdout[-3000:], r.stderr[-3000:])
    result = json.loads(r.stdout.strip().splitlines()[-1])
    for key in ("hosts_flow_success_rate", "plan_wait_ms_p95_remote_planner", "map_voxels_remote_over_local",
                "operator_link_idle_kbit_s", "operator_link_peak_mbit_s", "robot_compute_link_mbit_s_during_scan",
                "link_cut_executor_overruns", "link_cut_feet_drift_measured_mm_max", "link_cut_recovery_s",
                "link_cut_operator_hangs"):
        assert key in result, key
    assert json.loads((out / "hosts.json").read_text())["link_cut_recovery_s"] == result["link_cut_recovery_s"]
    (placement,) = result["placements"]
    (cut,) = placement["cuts"]
    assert "t_down" in cut, cut                                  # the cut came during the scan
    assert cut["outcome"] in ("rode out the cut", "clear error"), cut
    assert result["link_cut_operator_hangs"] == 0, cut
    assert cut["recovery_s"] is not None, cut                    # the graph answered after the link came back
    assert cut["executor_overruns"] is not None and cut["feet_drift_mm"] is not None, cut
    assert result["operator_link_idle_kbit_s"] is not None
    print(f"\ncut of the operator's link during a scan: {cut['outcome']} (exit {cut['exit_code']}), recovery "
          f"{cut['recovery_s']} s, {cut['executor_overruns']} overruns, feet drift {cut['feet_drift_mm']:.5f} mm; "
          f"operator link idle {result['operator_link_idle_kbit_s']} kbit/s")
    # the bench cleaned up: the namespaces are gone (and with them anything that ran inside)
    assert subprocess.run(["ip", "link", "show", "hr_br0"], capture_output=True).returncode != 0
    assert not any(n.startswith("hr_") for n in subprocess.run(["ip", "netns", "list"], capture_output=True,
                                                               text=True).stdout.split())
