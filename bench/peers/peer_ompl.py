"""OMPL peer (ompl 2.0.1 Python bindings, .venv-peers, with the project importable).

Usage: ``python peer_ompl.py WORKDIR``; last stdout line: JSON.

For each goal of ``goals.npz`` (from half-sitting): OMPL ``RRTConnect`` in the project's
planning space q_plan = (q_arm (6), z_t, rpy_t) (eq. 2) of the goal's arm, with

* the same validity: the project's ``ReachPlanner.validity_fn`` (projection by
  Algorithm 1 lines 3-4 + closed-form leg IK + limits, then the project's collision
  checker on the same map) as OMPL's state validity checker, one state per call;
* the same bounds (``ReachPlanner.planning_space``: arm joint limits, trunk ranges);
* the same metric and edge resolution: OMPL works in scaled coordinates y = W q_plan, so
  its L2 distance is the project's weighted metric, range = ``rrt_step`` and the
  discrete motion validator checks every ``edge_resolution`` (as a fraction of the
  space's maximum extent);
* the same time budget (``time_budget_s``).

Interleaved with it, on the same goal in the same process: the project's RRT-connect
(``planning.path.plan``, seed k) with the same checker (batched, as the project calls it).
Times are planning only (no shortcut / simplification on either side); the project's
shortcut time is reported separately.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from _common import emit, guarded, load  # noqa: E402


def run(workdir) -> dict:
    import ompl.base as ob
    import ompl.geometric as og
    import ompl.util as ou

    from problem import build_problem  # noqa: E402  (the project, via bench/peers/problem.py)
    from humanoid_reach_ros.planning.path import ShortcutOptions, plan as run_planner, shortcut_path

    ou.setLogLevel(ou.LogLevel.LOG_WARN) if hasattr(ou, "setLogLevel") else None
    P, meta = load(workdir)
    prob = build_problem()
    rp = prob.planner
    pp = rp.params
    q0 = rp.start_config(rp.robot.half_sitting_joints)
    out = {"ours": {"time_s": [], "success": 0, "shortcut_time_s": []}, "ompl": {"time_s": [], "success": 0,
                                                                                  "state_checks": []}}
    W = pp.weights
    # JIT warm-up of the project's kernels
    rp.plan(rp.robot.half_sitting_joints, __import__("humanoid_reach_ros.planning.reach", fromlist=["x"]).PlanRequest(
        prob.region, seed=0))
    for k, (qg, arm_code) in enumerate(zip(P["goals_q"], P["goals_arm"])):
        arm = {1: "right", 2: "left"}[int(arm_code)]   # the project's arm codes (codes.ARM_*; no import here)
        goal_plan = rp.projector.plan_config_of(qg, arm)
        _, start_plan = rp._projected_start(q0, arm)
        space_ours = rp.planning_space(arm, np.vstack([start_plan[None], goal_plan]))
        is_valid = rp.validity_fn(arm, rp.collision)
        # ---- ours
        rng = np.random.default_rng(k)
        t0 = time.perf_counter()
        r = run_planner("rrt_connect", start_plan, goal_plan, is_valid, space_ours, rng,
                        rp._planner_options("rrt_connect", pp.time_budget_s))
        dt = time.perf_counter() - t0
        if r.success:
            out["ours"]["success"] += 1
            out["ours"]["time_s"].append(dt)
            t1 = time.perf_counter()
            shortcut_path(r.path, is_valid, space_ours, rng,
                          ShortcutOptions(pp.shortcut_iterations, pp.shortcut_time_s))
            out["ours"]["shortcut_time_s"].append(time.perf_counter() - t1)
        # ---- OMPL
        d = len(W)
        space = ob.RealVectorStateSpace(d)
        b = ob.RealVectorBounds(d)
        for i in range(d):
            b.setLow(i, float(space_ours.lower[i] * W[i]))
            b.setHigh(i, float(space_ours.upper[i] * W[i]))
        space.setBounds(b)
        ss = og.SimpleSetup(space)
        n_checks = [0]
        buf = np.empty((1, d))

        def valid(s, _buf=buf, _v=is_valid, _n=n_checks, _d=d):
            _n[0] += 1
            for i in range(_d):
                _buf[0, i] = s[i] / W[i]
            return bool(_v(_buf)[0])

        ss.setStateValidityChecker(valid)
        si = ss.getSpaceInformation()
        si.setStateValidityCheckingResolution(pp.edge_resolution / si.getMaximumExtent())
        st, gl = space.allocState(), space.allocState()
        for i in range(d):
            st[i] = float(start_plan[i] * W[i])
            gl[i] = float(goal_plan[0, i] * W[i]) if goal_plan.ndim == 2 else float(goal_plan[i] * W[i])
        ss.setStartAndGoalStates(st, gl)
        pl = og.RRTConnect(si)
        pl.setRange(pp.rrt_step)
        ss.setPlanner(pl)
        ss.setup()
        t0 = time.perf_counter()
        solved = ss.solve(pp.time_budget_s)
        dt = time.perf_counter() - t0
        exact = bool(solved) and str(solved) == "Exact solution"
        if exact:
            out["ompl"]["success"] += 1
            out["ompl"]["time_s"].append(dt)
            out["ompl"]["state_checks"].append(n_checks[0])
    from importlib.metadata import version

    return {"available": True, "version": version("ompl"), "plans": len(P["goals_q"]), **out,
            "method": "OMPL RRTConnect, range = rrt_step, state validity = the project's validity_fn (one state per "
                      "call), scaled space (weighted metric), motion check every edge_resolution; interleaved with "
                      "the project's RRT-connect on the same goal (seed k); planning time only"}


if __name__ == "__main__":
    emit(guarded(run, sys.argv[1]))
