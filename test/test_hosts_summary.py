"""bench/hosts.py's figures from recorded steps and cuts, without namespaces or a graph:
``step_record`` on the events a ``reach_operator`` child records, ``summarize``, ``not_run_targets``
and ``judge``.

The rule (issue 33): a missing measurement is a missed target (a cut whose trigger never came, a
cut without the executor's diagnostics); every step counts in the wait's denominator (a plan call
never answered waits until the CLI ended); only what the run's options left out is not judged.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "bench"
sys.path.insert(0, str(BENCH))

import graph as bench_graph  # noqa: E402
import hosts  # noqa: E402


def ev(event: str, t: float) -> dict:
    return {"event": event, "t": t, "wall": t + 1000.0}


def step(args: list[str], events: list[dict], t_start: float, t_end: float, exit_code: int = 0) -> dict:
    summary = {"plan": {"error_name": "SUCCESS" if exit_code == 0 else "NO_JOINT_STATES",
                        "statistics": {"total_time_s": 0.08}}, "execution": None} if exit_code != 3 else {}
    run = {"args": args, "exit_code": exit_code, "hung": False, "t_start": t_start, "t_end": t_end,
           "duration_s": t_end - t_start, "summary": summary, "events": events, "stderr_last": ""}
    return hosts.step_record(run, 0.0)


def cut(name: str, came: bool = True, overruns: int | None = 0, drift: float | None = 1e-4,
        recovery: float | None = 0.8) -> dict:
    c = {"name": name, "link": "operator", "exit_code": 0, "hung": False, "success": True}
    if not came:
        return {**c, "error": "'look_start' never came: no cut"}
    return {**c, "t_down": 10.0, "t_up": 15.0, "executor_overruns": overruns, "feet_drift_mm": drift,
            "recovery_s": recovery}


def placement(steps: list[dict], cuts: list[dict]) -> dict:
    return {"placement": "compute", "steps": steps, "cuts": cuts, "map": {"ratio": 1.001},
            "idle": {"operator": {"both": 15e3}}, "operator_link_peak": {"both": 6e6},
            "compute_link_during_scan": {"both": 1e7}}


FLOW = [step(["--scan"], [], 0.0, 8.0),
        step(["--target", "0.71", "0.03", "0.90"], [ev("plan_sent", 9.0), ev("plan_response", 9.15)], 8.5, 10.0)]


def test_a_plan_call_never_answered_waits_until_the_cli_ended() -> None:
    lost = step(["--target", "0.71", "0.03", "0.90"], [ev("plan_sent", 20.0)], 19.0, 24.0, exit_code=3)
    assert lost["plan_waits_ms"] == [pytest.approx(4000.0)] and lost["plan_waits_to_failure"] == 1
    never = step(["--home"], [], 30.0, 36.0, exit_code=3)        # /plan_reach never found: the whole run
    assert never["plan_waits_ms"] == [pytest.approx(6000.0)] and never["plan_waits_to_failure"] == 1
    assert FLOW[0]["plan_waits_ms"] == [] and FLOW[1]["plan_waits_ms"] == [pytest.approx(150.0)]
    f = hosts.summarize([placement([*FLOW, lost, never], [cut("scan")])])
    assert f["plan_calls"]["remote"] == 3 and f["plan_waits_to_failure"] == 2
    assert f["plan_wait_ms_p95_remote_planner"] > 4000.0 and f["hosts_flow_success_rate"] == 0.5
    assert not bench_graph.judge(f, hosts.TARGETS)["plan_wait_ms_p95_remote_planner"]["met"]


def test_a_cut_that_never_came_or_lacks_diagnostics_is_a_missed_target() -> None:
    ok = hosts.summarize([placement(FLOW, [cut("scan"), cut("plan")])])
    assert ok["link_cut_executor_overruns"] == 0 and ok["link_cut_recovery_s"] == 0.8 and ok["cuts_not_done"] == 0
    judged = bench_graph.judge(ok, hosts.TARGETS)
    assert all(judged[k]["met"] for k in hosts.CUT_KEYS)

    for cuts, expected, keys in (
            ([cut("scan"), cut("plan", came=False)], None, hosts.CUT_KEYS),       # a trigger never came
            ([cut("scan")], 2, hosts.CUT_KEYS),                                    # a cut asked for, not recorded
            ([cut("scan", overruns=None), cut("plan")], None, ("link_cut_executor_overruns",)),  # no diagnostics
            ([cut("scan", drift=None), cut("plan")], None, ("link_cut_feet_drift_measured_mm_max",))):
        f = hosts.summarize([placement(FLOW, cuts)], cuts_expected=expected)
        judged = bench_graph.judge(f, hosts.TARGETS)
        for k in keys:
            assert f[k] is None and judged[k] == {"value": None, "target": judged[k]["target"], "met": False,
                                                 "missing": True}, (k, cuts)
    f = hosts.summarize([placement(FLOW, [cut("scan", recovery=None)])])
    assert f["link_cut_recovery_s"] == hosts.RECOVERY_DEADLINE_S        # no recovery: counted as the deadline


def test_only_what_the_options_left_out_is_not_judged() -> None:
    args = argparse.Namespace(no_flow=False, placements=["compute", "robot"], cuts=[])     # --no-cuts
    not_run = hosts.not_run_targets(args)
    assert set(not_run) == set(hosts.CUT_KEYS) and set(not_run.values()) == {"--no-cuts"}
    f = hosts.summarize([placement(FLOW, [])], cuts_expected=0)
    judged = bench_graph.judge(f, hosts.TARGETS, not_run)
    assert not set(judged) & set(hosts.CUT_KEYS) and all(t["met"] for t in judged.values())
    # the same run with the cuts asked for and none recorded: every cut figure missed
    judged = bench_graph.judge(hosts.summarize([placement(FLOW, [])], cuts_expected=4), hosts.TARGETS)
    assert all(judged[k]["met"] is False and judged[k]["missing"] for k in hosts.CUT_KEYS)
    args = argparse.Namespace(no_flow=True, placements=["robot"], cuts=["scan"])
    assert set(hosts.not_run_targets(args)) == {*hosts.FLOW_KEYS, *hosts.CUT_KEYS}
