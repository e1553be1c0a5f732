"""``hr_record`` says what it takes in as it goes and at the end (issue 33: ``--all`` wrote about
6 MB/s and said nothing). The recording itself: test_mcap_bag.py."""
from __future__ import annotations

import re
import subprocess
import sys

import pytest

from humanoid_reach_ros.nodes.bag_record import parse_args, volume_text

LINE = re.compile(r"hr_record: ([\d.]+) s, ([\d,]+) messages, ([\d.]+) MB \(([\d.]+) MB/s\), file ([\d.]+) MB")


def test_the_volume_line() -> None:
    assert volume_text(12.0, 3210, 72_000_000, 9_400_000) == "12.0 s, 3,210 messages, 72.0 MB (6.0 MB/s), file 9.4 MB"
    assert volume_text(0.0, 0, 0, None) == "0.0 s, 0 messages, 0.0 MB (0.0 MB/s)"
    assert parse_args(["--all"]).report_every == 5.0
    with pytest.raises(SystemExit):
        parse_args(["--all", "--report-every", "-1"])


@pytest.mark.node
def test_record_all_reports_its_rate_and_size_as_it_goes(start_node, ros_env, tmp_path) -> None:
    start_node("joint_driver", params_file="config/joint_driver.yaml", ready_log=r"simulated hrp2")
    # 6 s: on a loaded machine (CI beside a helper's physics runs) the recorder's subscriptions matched
    # the driver's publishers only after 3 s, and a 3 s recording held none of its messages
    r = subprocess.run([sys.executable, "-m", "humanoid_reach_ros.nodes.bag_record", "--all", "-o",
                        str(tmp_path / "all.mcap"), "--duration", "6", "--report-every", "1"],
                       env=dict(ros_env), capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    lines = [m for m in map(LINE.match, r.stdout.splitlines()) if m]
    assert len(lines) >= 3, r.stdout       # at least two on the way (1 s apart) and one at the end
    last = lines[-1]
    assert float(last[3]) > 0 and float(last[4]) > 0 and int(last[2].replace(",", "")) > 100, r.stdout
    assert float(last[5]) == pytest.approx((tmp_path / "all.mcap").stat().st_size / 1e6, abs=0.06)
