"""Benchmark: ``make demo`` repeated (issue 23: Talos's operator wait over 10 runs).

Runs the demo (``python -m humanoid_reach_ros.demo``: the whole graph, head scan, marker,
``/plan_reach``, execution, the way home) ``--runs`` times for each ``--robot``, one after the
other, each in its own isolated ROS domain and output directory, and collects from each run's
``demo_report.json`` the operator's wait for the plan (request -> trajectory, without the
automatic looks), the way home's wait and the demo's own verdict (its exit status: it fails
on a missed check). A run that fails or times out counts as a failure with its last lines.

    python bench/demo_runs.py --robot talos --runs 10 [--robot hrp2 ...] [--out out/demo_runs]

Last stdout line: one JSON object; per robot ``operator_wait_ms`` (p50 / p95 / max over the
successful runs), ``home_wait_ms``, ``failures`` and ``success_rate``.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from humanoid_reach_ros.robot.spec import robots  # noqa: E402
from humanoid_reach_ros.testing.machine import describe as describe_machine  # noqa: E402

RUN_TIMEOUT_S = 600.0


def dist_ms(values_s: list[float]) -> dict:
    a = 1e3 * np.asarray(values_s, dtype=float)
    if not len(a):
        return {}
    return {"p50": round(float(np.median(a)), 1), "p95": round(float(np.percentile(a, 95)), 1),
            "max": round(float(a.max()), 1), "n": int(len(a))}


def one_run(robot: str, out: Path) -> dict:
    """One demo; ``{"ok", "report" | "error", "wall_s"}``."""
    out.mkdir(parents=True, exist_ok=True)
    latest = out / robot / "latest"          # the demo's run directory: OUT/<robot>/<date-time>/
    before = latest.resolve() if latest.is_symlink() else None
    t0 = time.monotonic()
    cmd = [sys.executable, "-m", "humanoid_reach_ros.demo", "--robot", robot, "--out", str(out), "--no-record",
           "--keep", "0"]
    try:
        proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=RUN_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        return {"ok": False, "error": f"timed out after {RUN_TIMEOUT_S:g} s", "wall_s": RUN_TIMEOUT_S}
    (out / "demo_stdout.txt").write_text(proc.stdout + proc.stderr)
    wall = round(time.monotonic() - t0, 1)
    run_dir = latest.resolve() if latest.is_symlink() else None
    report_path = run_dir / "demo_report.json" if run_dir is not None and run_dir != before else None
    report = json.loads(report_path.read_text()) if report_path is not None and report_path.is_file() else None
    if proc.returncode != 0 or report is None:
        tail = (proc.stdout + proc.stderr).strip().splitlines()[-3:]
        return {"ok": False, "error": f"exit {proc.returncode}: " + " | ".join(tail), "wall_s": wall,
                "report": report}
    return {"ok": True, "report": report, "wall_s": wall}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    ap.add_argument("--robot", action="append", choices=robots(), help="robot (repeatable; default talos)")
    ap.add_argument("--runs", type=int, default=10, help="demo runs per robot (default 10)")
    ap.add_argument("--out", default="out/demo_runs", help="directory of the runs' logs and reports")
    a = ap.parse_args(argv)
    if a.runs < 1:
        ap.error("--runs must be >= 1")
    result: dict = {"bench": "demo_runs", "machine": describe_machine(), "load_avg_1m_start": os.getloadavg()[0],
                    "runs": a.runs, "robots": {}}
    for robot in a.robot or ["talos"]:
        waits, homes, failures, walls = [], [], [], []
        for k in range(a.runs):
            r = one_run(robot, Path(a.out) / robot / f"run{k}")
            walls.append(r["wall_s"])
            if r["ok"]:
                waits.append(r["report"]["operator_wait_s"])
                if "home_wait_s" in r["report"]:
                    homes.append(r["report"]["home_wait_s"])
                print(f"[demo_runs] {robot} run {k}: ok, operator wait {1e3 * waits[-1]:.0f} ms "
                      f"({r['wall_s']:.0f} s)", flush=True)
            else:
                failures.append({"run": k, "error": r["error"]})
                print(f"[demo_runs] {robot} run {k}: FAILED: {r['error']}", flush=True)
        result["robots"][robot] = {"operator_wait_ms": dist_ms(waits), "home_wait_ms": dist_ms(homes),
                                   "success_rate": round(len(waits) / a.runs, 3), "failures": failures,
                                   "run_wall_s_mean": round(float(np.mean(walls)), 1)}
    result["load_avg_1m_end"] = os.getloadavg()[0]
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    line = json.dumps(result)
    (out / "demo_runs.json").write_text(line + "\n")
    print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
