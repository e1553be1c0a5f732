"""Peers side by side: this project vs HPP, OMPL, pink, placo, coal on the same problems.

Run by ``make bench-peers`` (which first builds .venv-peers / .venv-placo from the pinned
tools/requirements-peers*.txt). This script runs in the project venv: the project side
is measured here, each peer runs as a subprocess in its venv and gets the problem as
files (bench/peers/problem.py: problem.npz, the robot's capsules as URDF/SRDF, the scene
as URDF, goals.npz, coll_configs.npz) in ``--workdir``.

(a) goals for the valve WGR: this project's ``sample_goals`` (Algorithm 1) vs numerical
    projection of the same random seeds onto the same constraints by HPP, pink, placo;
    every side's output through the same ``problem.goal_validity``; figure = (production
    time + check time) / valid goals.
(b) paths from half-sitting to the first ``--path-goals`` goals of (a): this project's
    RRT-connect (planning only, then shortcut timed apart) vs OMPL RRTConnect with the
    same checker/bounds/metric/resolution (interleaved in its worker) vs HPP BiRRT with
    static-stability constraints (its own collision checking).
(c) collision check per configuration on IK-valid configurations: ours (one call per
    configuration, and batched) vs HPP ``isConfigValid`` vs coal directly.

Last stdout line: one JSON object (report.assemble): raw figures, ratios, machine.
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

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(REPO))

import problem as PB  # noqa: E402
import report  # noqa: E402
from humanoid_reach_ros.testing.machine import describe as describe_machine  # noqa: E402
from humanoid_reach_ros.codes import ARM_NAMES  # noqa: E402
from humanoid_reach_ros.planning.goal_sampler import sample_goals  # noqa: E402
from humanoid_reach_ros.planning.path import ShortcutOptions, plan as run_planner, shortcut_path  # noqa: E402
from humanoid_reach_ros.planning.reach import PlanRequest  # noqa: E402

VENV_PEERS = REPO / ".venv-peers"
VENV_PLACO = REPO / ".venv-placo"


def _cmeel_lib(venv: Path) -> str:
    libs = sorted(venv.glob("lib/python3*/site-packages/cmeel.prefix/lib"))
    return str(libs[0]) if libs else ""


def run_worker(venv: Path, script: str, args: list[str], timeout_s: float, ld_cmeel: bool = False) -> dict:
    py = venv / "bin" / "python"
    if not py.exists():
        return {"available": False, "why": f"{venv.name} missing (make bench-peers creates it)"}
    env = dict(os.environ)
    env.pop("PYTHONPATH", None)   # the project venv's path must not leak into a peer venv
    if ld_cmeel:
        lib = _cmeel_lib(venv)
        env["LD_LIBRARY_PATH"] = lib + (":" + env["LD_LIBRARY_PATH"] if env.get("LD_LIBRARY_PATH") else "")
    t0 = time.perf_counter()
    try:
        p = subprocess.run([str(py), str(HERE / script), *args], capture_output=True, text=True, timeout=timeout_s,
                           env=env, cwd=str(REPO))
    except subprocess.TimeoutExpired:
        return {"available": True, "error": f"timed out after {timeout_s:.0f} s"}
    lines = [ln for ln in p.stdout.splitlines() if ln.startswith("{")]
    if not lines:
        return {"available": True, "error": f"exit {p.returncode}, no JSON; stderr tail: {p.stderr[-800:]}"}
    out = json.loads(lines[-1])
    out["worker_wall_s"] = time.perf_counter() - t0
    return out


# ------------------------------------------------------------------ ours
def ours_goals(prob, n_goals: int) -> tuple[dict, object]:
    rp = prob.planner
    trunk = rp.trunk_sampling(prob.region, "auto", rp.start_config(rp.robot.half_sitting_joints))
    sample_goals(prob.region, 2, prob.robot, prob.collision, np.random.default_rng(0),
                 trunk=trunk, projector=prob.projector)   # JIT warm-up
    t0 = time.perf_counter()
    goals = sample_goals(prob.region, n_goals, prob.robot, prob.collision, np.random.default_rng(PB.SEED),
                         trunk=trunk, projector=prob.projector,
                         batch_size=rp.params.goal_batch_size)
    t_gen = time.perf_counter() - t0
    chk = PB.goal_validity(prob, goals.q)
    st = goals.stats
    return {"n_goals": len(goals), "samples": st.n_samples, "generation_time_s": t_gen, "check_time_s": chk["time_s"],
            "n_valid": chk["n_valid"], "failures": chk["failures"],
            "time_per_valid_goal_ms": report.per_valid_goal_ms(t_gen + chk["time_s"], chk["n_valid"]),
            "method": "sample_goals (Algorithm 1, analytic projection + collision), auto arm, batch "
                      f"{rp.params.goal_batch_size}; then the common validity check"}, goals


def ours_paths(prob, goals, k: int) -> dict:
    rp = prob.planner
    pp = rp.params
    q0 = rp.start_config(rp.robot.half_sitting_joints)
    plan_s, sc_s, ok = [], [], 0
    for i in range(min(k, len(goals))):
        arm = ARM_NAMES[int(goals.arm[i])]
        gp = rp.projector.plan_config_of(goals.q[i], arm)
        _, sp = rp._projected_start(q0, arm)
        space = rp.planning_space(arm, np.vstack([sp[None], gp]))
        is_valid = rp.validity_fn(arm, rp.collision)
        rng = np.random.default_rng(i)
        t0 = time.perf_counter()
        r = run_planner("rrt_connect", sp, gp, is_valid, space, rng,
                        rp._planner_options("rrt_connect", pp.time_budget_s))
        dt = time.perf_counter() - t0
        if r.success:
            ok += 1
            plan_s.append(dt)
            t1 = time.perf_counter()
            shortcut_path(r.path, is_valid, space, rng, ShortcutOptions(pp.shortcut_iterations, pp.shortcut_time_s))
            sc_s.append(time.perf_counter() - t1)
    return {"plans": min(k, len(goals)), "success": ok, "time_s": plan_s, "shortcut_time_s": sc_s,
            "plan_ms_mean": None if not plan_s else 1e3 * float(np.mean(plan_s)),
            "plan_ms_p50": None if not plan_s else 1e3 * float(np.median(plan_s)),
            "plan_plus_shortcut_ms_mean": None if not plan_s else 1e3 * float(np.mean(np.add(plan_s, sc_s))),
            "method": f"planning.path.plan('rrt_connect') in q_plan (eq. 2), step {pp.rrt_step}, edge resolution "
                      f"{pp.edge_resolution}, budget {pp.time_budget_s} s, seed = goal index; shortcut timed apart"}


def collision_configs(prob, n: int) -> np.ndarray:
    rng = np.random.default_rng(PB.SEED + 1)
    tr = prob.planner.trunk_sampling(prob.region)
    out = []
    while sum(len(o) for o in out) < n:
        p_e, R_e = prob.region.sample(rng, 4096)
        z_t, rpy_t = tr.sample(rng, 4096)
        res = prob.projector.project_config(p_e, R_e, z_t, rpy_t)
        out.append(res.q[res.ok])
    return np.vstack(out)[:n]


def ours_collision(prob, Q: np.ndarray) -> tuple[dict, list]:
    col = prob.collision
    for q in Q[:20]:
        col.check(q)
    t0 = time.perf_counter()
    verdict = [bool(col.check(q)) for q in Q]
    single = time.perf_counter() - t0
    col.check_batch(Q[:20])
    t0 = time.perf_counter()
    col.check_batch(Q)
    batch = time.perf_counter() - t0
    return {"n_configs": len(Q), "single_us_per_config": 1e6 * single / len(Q),
            "batch_us_per_config": 1e6 * batch / len(Q), "valid_fraction": float(np.mean(verdict)),
            "method": "RobotCollision.check per configuration (FK + capsules vs sphere tree of the 2 cm voxel map "
                      "without the valve + 120 self pairs), and check_batch"}, verdict


def check_candidates(prob, res: dict) -> dict:
    """The common validity check on a goal peer's candidates; adds the per-valid-goal time."""
    if not res.get("available") or "error" in res:
        return res
    Q = np.asarray(res.pop("candidates"), float).reshape(-1, prob.robot.model.nq)
    chk = PB.goal_validity(prob, Q)
    res.update({"n_valid": chk["n_valid"], "check_time_s": chk["time_s"], "failures": chk["failures"],
                "time_per_valid_goal_ms": report.per_valid_goal_ms(res["ik_time_s"] + chk["time_s"], chk["n_valid"])})
    return res


def agreement(ours: list, peer: dict) -> dict | None:
    v = peer.pop("valid", None) if isinstance(peer, dict) else None
    if v is None or len(v) != len(ours):
        return None
    a, b = np.array(ours), np.array(v)
    return {"same_verdict": float(np.mean(a == b)), "ours_free_peer_hit": int(np.sum(a & ~b)),
            "ours_hit_peer_free": int(np.sum(~a & b))}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--workdir", default=str(REPO / "build" / "peers"))
    ap.add_argument("--goals", type=int, default=100, help="our goals for (a)")
    ap.add_argument("--seeds", type=int, default=100, help="random seeds projected by each numerical goal peer")
    ap.add_argument("--path-goals", type=int, default=10, help="goals planned to in (b)")
    ap.add_argument("--coll-configs", type=int, default=1000)
    ap.add_argument("--skip", default="", help="comma-separated peers to skip: hpp,ompl,pink,placo,coal")
    args = ap.parse_args()
    skip = {s for s in args.skip.split(",") if s}
    wd = Path(args.workdir)
    t_all = time.perf_counter()
    prob = PB.build_problem()
    PB.write_problem(prob, wd, args.seeds)
    wd_s = str(wd)
    ours: dict = {}
    ours["goals"], goals = ours_goals(prob, args.goals)
    print(f"ours goals: {json.dumps(ours['goals'])}", flush=True)
    k = min(args.path_goals, len(goals))
    rp = prob.planner
    q0 = rp.start_config(rp.robot.half_sitting_joints)
    PB.add_goals(wd, goals.q[:k], goals.arm[:k],
                 np.vstack([rp.projector.plan_config_of(goals.q[i], ARM_NAMES[int(goals.arm[i])])
                            for i in range(k)]),
                 {a: rp._projected_start(q0, a)[1] for a in ("right", "left")})
    rp.plan(rp.robot.half_sitting_joints, PlanRequest(prob.region, seed=0))   # JIT warm-up of the planner
    ours["paths"] = ours_paths(prob, goals, k)
    print(f"ours paths: {json.dumps(ours['paths'])}", flush=True)
    Q = collision_configs(prob, args.coll_configs)
    np.savez(wd / "coll_configs.npz", q=Q)
    ours["collision"], verdict = ours_collision(prob, Q)
    print(f"ours collision: {json.dumps(ours['collision'])}", flush=True)

    peers: dict = {"hpp": {}, "ompl": {}, "pink": {}, "placo": {}, "coal": {}}
    skipped = {"available": False, "why": "skipped (--skip)"}
    for name, venv, script, argv, part, tmo, ld in (
            ("hpp", VENV_PEERS, "peer_hpp.py", [wd_s, "goals"], "goals", 900, True),
            ("pink", VENV_PEERS, "peer_pink.py", [wd_s], "goals", 900, False),
            ("placo", VENV_PLACO, "peer_placo.py", [wd_s], "goals", 900, False),
            ("ompl", VENV_PEERS, "peer_ompl.py", [wd_s], "paths", 900, False),
            ("hpp", VENV_PEERS, "peer_hpp.py", [wd_s, "paths"], "paths", 900, True),
            ("hpp", VENV_PEERS, "peer_hpp.py", [wd_s, "collision"], "collision", 600, True),
            ("coal", VENV_PEERS, "peer_coal.py", [wd_s], "collision", 600, False)):
        res = dict(skipped) if name in skip else run_worker(venv, script, argv, tmo, ld)
        if part == "goals":
            res = check_candidates(prob, res)
        if part == "collision" and isinstance(res, dict):
            res["agreement_with_ours"] = agreement(verdict, res)
        peers[name][part] = res
        brief = {k2: v for k2, v in res.items() if k2 not in ("trace",)}
        print(f"{name} {part}: {json.dumps(brief)[:600]}", flush=True)
    settings = {"seed": PB.SEED, "our_goals": args.goals, "peer_seeds": args.seeds, "path_goals": k,
                "coll_configs": len(Q), "scene": PB.SCENE, "map": "2 cm voxels, valve group excluded",
                "wall_s": time.perf_counter() - t_all}
    out = report.assemble(ours, peers, describe_machine(), settings)
    print("ratios: " + json.dumps({k2: out[k2] for k2 in report.RATIO_KEYS}), flush=True)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
