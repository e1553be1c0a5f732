"""bench/session.py's figures from recorded steps, without a graph: ``step_figures`` on the events a
``reach_operator`` child records, ``summarize`` and ``judge`` over the sessions.

The rule (issue 33): a missing measurement is a missed target; every step counts in every
figure's denominator (a failed step waits its time to failure); a fallback (the motion's start
taken from the goal's sending when no executor step stamp is found) is counted and reported.
"""
from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace as NS

import pytest

BENCH = Path(__file__).resolve().parents[1] / "bench"
sys.path.insert(0, str(BENCH))

import session  # noqa: E402


def ev(event: str, t: float, **kw) -> dict:
    """An event as the child writes it: monotonic ``t`` and system-clock ``wall`` (here 1000 s apart)."""
    return {"event": event, "t": t, "wall": t + 1000.0, **kw}


def response(t: float, code: int = 0) -> dict:
    return ev("plan_response", t, error_code=code, success=code == 0, message="", retreat="", arm=1,
              unobserved_points=[], total_time_s=0.1, joint_names=[], times=[], positions=[])


def run(args: list[str], events: list[dict], t_start: float, t_end: float, exit_code: int = 0,
        execution: dict | None = None, look: dict | None = None) -> dict:
    summary = {"look": look, "plan": {"error_name": "SUCCESS"} if exit_code == 0 else {"error_name": "NO_PATH"},
               "execution": execution, "exit_code": exit_code}
    return {"args": args, "exit_code": exit_code, "summary": summary, "events": events, "t_start": t_start,
            "t_end": t_end, "stderr": "" if exit_code == 0 else "plan failed: NO_PATH (8): no path"}


EXECUTED = {"outcome": "done", "success": True, "error_name": "SUCCESS", "steps": 600, "overruns": 0}


def figures(sess, kind: str, r: dict, name: str, retreat_expected: bool = False) -> dict:
    fig = session.step_figures(sess, kind, r)
    fig["name"], fig["retreat_expected"] = name, retreat_expected
    return fig


def recorded_session(metric_starts: list[float], motions: int | None = 3) -> dict:
    """A scan, a reach that moved, a reach whose plan failed, home: as run_session records them."""
    sess = NS(robot=None, metric_starts=metric_starts)
    scan = run(["--scan"], [ev("look_start", 1.0), ev("look_end", 9.0)], 0.5, 9.5, look={"success": True})
    reach = run(["--target", "0.7", "0", "0.9", "--execute"],
                [ev("plan_sent", 10.0), response(10.2), ev("execute_sent", 10.25)], 9.6, 14.0, execution=EXECUTED)
    failed = run(["--target", "0.2", "0.5", "0.9", "--execute"], [ev("plan_sent", 20.0), response(21.0, code=8)],
                 19.5, 21.5, exit_code=5)
    home = run(["--home", "--execute"], [ev("plan_sent", 30.0), response(30.1), ev("execute_sent", 30.15)],
               29.6, 33.0, execution=EXECUTED)
    steps = [figures(sess, "scan", scan, "scan"), figures(sess, "plain", reach, "reach"),
             figures(sess, "plain", failed, "failed"), figures(sess, "home", home, "home")]
    s = {"scene": "plant", "seed": 1, "steps": steps, "feet_drift_mm": 0.0002}
    if motions is not None:
        s.update(executor_motions=motions, executor_steps=1800, executor_overruns=0)
    return s


def test_a_failed_step_waits_its_time_to_failure_and_stays_in_every_denominator() -> None:
    s = recorded_session(metric_starts=[1010.3, 1030.2])
    reach, failed = s["steps"][1], s["steps"][2]
    assert reach["operator_wait_ms"] == pytest.approx(300.0) and not reach.get("wait_to_failure")
    assert reach["motion_start_from"] == "executor_metrics_stamp"
    assert failed["operator_wait_ms"] == pytest.approx(1500.0) and failed["wait_to_failure"] and not failed["success"]
    f = session.summarize([s])
    assert f["operator_waits"] == f["operator_wait_steps"] == 3 and f["operator_waits_to_failure"] == 1
    assert f["operator_wait_ms_max"] == pytest.approx(1500.0)      # the failure's wait is in the percentiles
    assert f["operator_wait_ms_p95"] > 1000.0 and f["session_steps_succeeded_rate"] == 0.75
    assert f["motion_start_fallbacks"] == 0 and f["session_overruns"] == 0
    judged = session.judge({k: f[k] for k in session.TARGETS})
    assert not judged["operator_wait_ms_p95"]["met"] and not judged["session_steps_succeeded_rate"]["met"]


def test_a_motion_start_from_the_goal_sending_is_counted() -> None:
    s = recorded_session(metric_starts=[1010.3])        # home's first executor step was never stamped
    home = s["steps"][3]
    assert home["motion_start_from"] == "goal_sent"
    assert home["operator_wait_ms"] == pytest.approx(150.0)      # 100 ms plan + 50 ms to the goal's sending
    f = session.summarize([s])
    assert f["motion_start_fallbacks"] == 1 and f["operator_waits"] == 3


def test_executor_motions_not_found_leave_the_overruns_missing_and_the_target_missed() -> None:
    # no executor log at all (no outcome line matched), or fewer motions than goals that ran (2 executions + scan)
    for motions in (None, 0, 2):
        f = session.summarize([recorded_session([1010.3, 1030.2], motions=motions)])
        assert f["session_overruns"] is None and f["executor_motions_expected"] == 3, motions
        judged = session.judge({k: f[k] for k in session.TARGETS})
        assert judged["session_overruns"] == {"value": None, "target": "== 0", "met": False, "missing": True}
    f = session.summarize([recorded_session([1010.3, 1030.2], motions=3)])
    assert f["session_overruns"] == 0 and session.judge(f)["session_overruns"]["met"]


def test_a_session_that_broke_has_its_figures_missing_never_skipped() -> None:
    broke = {"scene": "plant", "seed": 2, "steps": [session.failed_step("graph", "hr_graph did not come up")],
             "error": "hr_graph did not come up"}
    f = session.summarize([recorded_session([1010.3, 1030.2]), broke])
    # the step that never ran has no wait: the wait percentiles are missing, not computed without it
    assert f["operator_wait_ms_p50"] is None and f["operator_wait_ms_p95"] is None
    assert f["session_feet_drift_measured_mm_max"] is None and f["session_overruns"] is None
    judged = session.judge({k: f[k] for k in session.TARGETS})
    missed = {k for k, t in judged.items() if not t["met"]}
    assert {"operator_wait_ms_p50", "operator_wait_ms_p95", "session_feet_drift_measured_mm_max",
            "session_overruns", "session_steps_succeeded_rate"} <= missed
    assert all(t["met"] is False for t in judged.values() if t.get("missing"))
    # nothing ran at all: every rate is missing, and missed
    judged = session.judge(session.summarize([broke]))
    assert not any(t["met"] for t in judged.values())
