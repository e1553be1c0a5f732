"""Benchmark: executor overruns during head scans, per ``lookahead_steps`` (issue 21).

A head scan is the busiest time for this machine: the executor's 5 ms loop turns the head
through ten poses while ``scene_sim`` renders the head camera, ``voxel_mapper`` matches stereo
and integrates every cloud and ``marker_localizer`` detects. For each ``--lookahead`` value the
six nodes come up in an isolated ROS domain (``humanoid_reach_ros.graph``, each with its
``config/<name>.yaml``; the executor with ``lookahead_steps`` set), ``reach_operator --scan``
runs ``--scans`` times, and the overruns and steps of every motion are read from the outcome
line the executor logs for each (``[1.31 s, 260 steps, 0 overruns, ...]``).

Usage: ``python bench/scan_loop.py [--lookahead 2 3] [--scans 12] [--out DIR]``.
Last stdout line: one JSON object (per value: motions, steps, overruns, per 10,000 steps, the
scans' wall time and failures).
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from humanoid_reach_ros.graph import GRAPH_NODES, Graph, allocate_domain, graph_env
from humanoid_reach_ros.testing.machine import describe as describe_machine

sys.path.insert(0, str(Path(__file__).resolve().parent))
from session import executor_motion_overruns  # noqa: E402  (bench/session.py: the executor's outcome lines)

READY = {"joint_driver": "simulated", "scene_sim": "scene sensors ready", "voxel_mapper": "voxel mapper ready",
         "marker_localizer": "marker localizer ready", "reach_planner": "reach planner ready",
         "reach_executor": "reach executor ready"}


def run(depth: int, scans: int, out: Path) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    lease = allocate_domain()
    env = graph_env(lease.domain_id)
    graph = Graph(out, env)
    failures = []
    try:
        procs = [graph.start(m, {"lookahead_steps": depth} if m == "reach_executor" else None) for m in GRAPH_NODES]
        for proc, name in zip(procs, GRAPH_NODES):
            proc.wait_for_log(READY[name], 180.0)
        t0 = time.monotonic()
        for k in range(scans):
            r = subprocess.run([sys.executable, "-m", "humanoid_reach_ros.nodes.reach_operator", "--scan"], env=env,
                               capture_output=True, text=True, timeout=300)
            if r.returncode:
                failures.append({"scan": k, "exit_code": r.returncode, "stderr": r.stderr[-300:]})
        wall = time.monotonic() - t0
    finally:
        graph.stop()
        lease.release()
    counts = executor_motion_overruns(out)
    steps, overruns = counts["executor_steps"], counts["executor_overruns"]
    return {"lookahead_steps": depth, "motions": counts["executor_motions"], "steps": steps, "overruns": overruns,
            "overruns_per_10k_steps": round(1e4 * overruns / steps, 2) if steps else None,
            "scans": scans, "scan_failures": failures, "wall_s": round(wall, 1)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    ap.add_argument("--lookahead", type=int, nargs="+", default=[2, 3], help="lookahead_steps values (default 2 3)")
    ap.add_argument("--scans", type=int, default=12, help="head scans per value (default 12)")
    ap.add_argument("--out", type=Path, default=None, help="node logs (default: a temporary directory)")
    args = ap.parse_args(argv)
    if args.scans < 1 or any(not 1 <= d <= 8 for d in args.lookahead):
        ap.error("--scans must be >= 1 and every --lookahead within 1..8")
    base = args.out or Path(tempfile.mkdtemp(prefix="bench_scan_loop_"))
    results = []
    for depth in args.lookahead:
        res = run(depth, args.scans, base / f"lookahead_{depth}")
        print(f"[bench/scan_loop] lookahead_steps {depth}: {res['motions']} motions, {res['steps']} steps, "
              f"{res['overruns']} overruns, {res['wall_s']:.0f} s, {len(res['scan_failures'])} failed scans",
              flush=True)
        results.append(res)
    print(json.dumps({"bench": "scan_loop", "runs": results, "machine": describe_machine(), "logs": str(base)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
