"""``paths``: output names a person can read, one directory per run, and a bound on the pile-up
(issue 33: the demo's outputs were overwritten by each run and its node logs had opaque names)."""
from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

from humanoid_reach_ros.paths import run_directory, unique_stamp


def test_a_stamp_is_the_local_time_and_never_an_existing_name(tmp_path: Path) -> None:
    first = unique_stamp(tmp_path, ".log", "joint_driver.")
    assert re.fullmatch(r"joint_driver\.\d{8}-\d{6}\.log", first), first
    (tmp_path / first).touch()
    second = unique_stamp(tmp_path, ".log", "joint_driver.")
    if second[:-len(".log")].startswith(first[:-len(".log")]):   # within the same second: a counter
        assert second == first[:-len(".log")] + "-2.log"
    assert second != first


def test_each_run_has_its_own_directory_latest_links_to_it_and_old_runs_go(tmp_path: Path) -> None:
    base = tmp_path / "demo" / "hrp2"
    runs = []
    for k in range(4):
        run = run_directory(base, keep=2)
        (run / "demo_report.json").write_text(str(k))
        os.utime(run, (1e9 + k, 1e9 + k))      # the order of the runs, whatever the clock's second
        runs.append(run)
        assert (base / "latest").resolve() == run.resolve()
    assert len(set(runs)) == 4 and all(re.fullmatch(r"\d{8}-\d{6}(-\d+)?", r.name) for r in runs)
    kept = sorted(p.name for p in base.iterdir() if not p.is_symlink())
    assert kept == sorted(r.name for r in runs[-2:]), kept           # the newest two, nothing overwritten
    assert (base / "latest" / "demo_report.json").read_text() == "3"
    (base / "notes.txt").write_text("mine")                            # only run directories are ever removed
    run_directory(base, keep=1)
    assert (base / "notes.txt").exists() and len([p for p in base.iterdir() if p.is_dir()
                                                  and not p.is_symlink()]) == 1


@pytest.mark.parametrize("keep", [0])
def test_keep_zero_keeps_every_run(tmp_path: Path, keep: int) -> None:
    for _ in range(3):
        run_directory(tmp_path, keep=keep)
    assert len([p for p in tmp_path.iterdir() if not p.is_symlink()]) == 3
