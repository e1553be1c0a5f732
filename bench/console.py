"""The operator console's cost and its whole flow in a real browser (issue 34; long form of
test/test_operator_console.py).

Starts the six nodes of the graph (an isolated domain, as bench/graph.py), then:

1. **idle without the console**: CPU of every node (% of one core, /proc: utime + stime of each
   process tree) for ``--idle-s``;
2. **idle with the console and one page** (headless chromium through Playwright, the controls
   taken, everything drawn): the same nodes and ``operator_console`` for ``--idle-s``, and the
   bytes the console sent the page (its ``/stats``) -> Mbit/s. Targets: the console adds
   <= 10 % of one core to the idle graph (the console's own CPU, and the graph's total with it
   minus without it), it sends <= 2 Mbit/s to one idle page;
3. **the flow**, as an operator does it in the page: Scan, click near the valve, Plan (ghost and
   statistics), Execute, Home; each result and its time, the Mbit/s sent while it ran;
4. **idle after the session** (the scanned map drawn): the console's CPU and Mbit/s again.

Last line: one JSON object. Usage: ``python bench/console.py [--idle-s 30] [--out out/bench_console]``.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
import urllib.request
from pathlib import Path
from typing import Any

from humanoid_reach_ros.graph import allocate_domain, graph_env
from humanoid_reach_ros.testing.console_page import (
    VALVE, Browser, ConsolePage, canvas_variance, free_port, start_console, start_graph)
from humanoid_reach_ros.testing.graph_metrics import CpuSampler
from humanoid_reach_ros.testing.machine import describe as machine

READY = {"joint_driver": r"simulated", "scene_sim": r"scene sensors ready", "voxel_mapper": r"voxel mapper ready",
         "marker_localizer": r"marker localizer ready", "reach_planner": r"reach planner ready",
         "reach_executor": r"reach executor ready"}
CPU_TARGET_PCT = 10.0
MBIT_TARGET = 2.0


def sent_bytes(port: int) -> int:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/stats", timeout=10.0) as r:
        return int(json.load(r)["sent_bytes"])


def idle(graph, seconds: float, port: int | None, page: ConsolePage | None) -> dict[str, Any]:
    """CPU of each process of ``graph`` (and Mbit/s to the page) over ``seconds`` of standing still."""
    sampler = CpuSampler({p.name: p.pid for p in graph.procs})
    b0 = sent_bytes(port) if port else 0
    sampler.start()
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:       # the page keeps receiving meanwhile
        if page is not None:
            page.page.wait_for_timeout(500)
        else:
            time.sleep(0.5)
    cpu = sampler.stop()
    dt = time.monotonic() - t0
    out: dict[str, Any] = {"seconds": round(dt, 1), "cpu_pct": {k: round(v, 2) for k, v in cpu.items()},
                           "graph_cpu_pct": round(sum(v for k, v in cpu.items() if k != "operator_console"), 2)}
    if port:
        out["mbit_s"] = round((sent_bytes(port) - b0) * 8 / dt / 1e6, 4)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--idle-s", type=float, default=30.0, help="seconds of each idle measurement (default 30)")
    ap.add_argument("--out", default="out/bench_console", help="node logs (default out/bench_console)")
    ap.add_argument("--screenshot", default=None, help="also save the page after Plan here (a PNG)")
    a = ap.parse_args(argv)
    out = Path(a.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    lease = allocate_domain()
    env = graph_env(lease.domain_id)
    port = free_port()
    graph = start_graph(out, env, None)
    browser = None
    report: dict[str, Any] = {"bench": "console", "machine": machine(), "idle_s": a.idle_s,
                              "command": "python bench/console.py " + " ".join(argv or sys.argv[1:])}
    try:
        for p in graph.procs:
            p.wait_for_log(READY[p.name], 180.0)
        time.sleep(5.0)   # start-up work (the first clouds into the map) is not idle
        report["idle_without_console"] = idle(graph, a.idle_s, None, None)
        console = start_console(graph, port, {"scan_dwell_s": 0.5, "plan_budget_s": 10.0})
        console.wait_for_log("operator console ready", 120.0)
        browser = Browser()
        page = ConsolePage(browser.page(f"http://127.0.0.1:{port}/"))
        page.wait(lambda: page.hr("counts.occupied") > 200 and page.hr("counts.robotFrames"), 60.0, "the map drawn")
        page.take()
        page.page.wait_for_timeout(5000)
        report["idle_with_console"] = w = idle(graph, a.idle_s, port, page)
        base = report["idle_without_console"]["graph_cpu_pct"]
        w["console_cpu_pct"] = w["cpu_pct"]["operator_console"]
        w["added_cpu_pct"] = round(w["graph_cpu_pct"] + w["console_cpu_pct"] - base, 2)
        report["canvas_variance"] = round(canvas_variance(page.page), 1)

        steps: list[dict[str, Any]] = []

        def step(name: str, button: str, timeout_s: float) -> dict:
            b0, t0 = sent_bytes(port), time.monotonic()
            res, secs = page.act(button, timeout_s)
            steps.append({"step": name, "ok": res["ok"], "seconds": round(secs, 2), "text": res["text"].split("\n")[0],
                          "mbit_s": round((sent_bytes(port) - b0) * 8 / (time.monotonic() - t0) / 1e6, 3)})
            print(f"[console bench] {name}: {'ok' if res['ok'] else 'FAILED'} in {secs:.1f} s: {steps[-1]['text']}",
                  flush=True)
            return res
        step("scan", "scan", 180.0)
        picked = page.click_at(VALVE)
        steps.append({"step": "click near the valve", "ok": picked is not None, "picked": picked})
        if picked is not None and step("plan", "plan", 180.0)["ok"]:
            steps[-1]["ghost_frames"] = page.hr("counts.ghostFrames")
            if a.screenshot:
                page.page.wait_for_timeout(1500)
                page.page.screenshot(path=a.screenshot)
            step("execute", "execute", 120.0)
        step("home", "home", 180.0)
        report["session"] = steps
        page.page.wait_for_timeout(3000)
        report["idle_after_session"] = after = idle(graph, a.idle_s, port, page)
        after["console_cpu_pct"] = after["cpu_pct"]["operator_console"]
        report["targets"] = {
            "console_cpu_le_10pct": max(w["console_cpu_pct"], after["console_cpu_pct"]) <= CPU_TARGET_PCT,
            "added_cpu_le_10pct": w["added_cpu_pct"] <= CPU_TARGET_PCT,
            "idle_mbit_le_2": w["mbit_s"] <= MBIT_TARGET and after["mbit_s"] <= MBIT_TARGET,
            "flow": all(s["ok"] for s in steps)}
        report["page_errors"] = [c for c in browser.console if c.startswith("pageerror")]
    finally:
        if browser is not None:
            browser.close()
        report["exit_codes"] = graph.stop()
        lease.release()
    print(json.dumps(report))
    return 0 if all(report.get("targets", {"ran": False}).values()) else 1


if __name__ == "__main__":
    sys.exit(main())
