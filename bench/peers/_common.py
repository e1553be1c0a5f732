"""Helpers of the peer workers (no project import: a worker may run in a venv without it)."""
from __future__ import annotations

import json
import os
import sys
import time
import traceback
from pathlib import Path

import numpy as np


def load(workdir: str | Path) -> tuple[dict, dict]:
    workdir = Path(workdir)
    P = dict(np.load(workdir / "problem.npz"))
    meta = json.loads((workdir / "problem.json").read_text())
    g = workdir / "goals.npz"
    if g.exists():
        P.update({f"goals_{k}": v for k, v in np.load(g).items()})
    return P, meta


def emit(obj: dict) -> None:
    """Print the result as the last stdout line and leave at once (nanobind's leak report
    at interpreter exit and slow C++ destructors are skipped)."""
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)


def guarded(fn, *args) -> dict:
    """``fn(*args)``; an ImportError becomes ``{"available": False, "why": ...}``, any
    other exception ``{"available": True, "error": ...}``."""
    try:
        return fn(*args)
    except ImportError as e:
        return {"available": False, "why": f"import failed: {type(e).__name__}: {e}"}
    except Exception as e:  # noqa: BLE001 -- report, never crash the bench
        return {"available": True, "error": f"{type(e).__name__}: {e}", "trace": traceback.format_exc(limit=4)}


def ik_loop(P: dict, solve_one, hands=("r_hand_ee", "l_hand_ee"), limit: int | None = None) -> dict:
    """The protocol of the numerical goal peers: for each sample k, from ``q_seed[k]``,
    project onto {hand = targets[k], soles at the stance, COM xy at the target} with the
    right hand, then with the left hand if that did not converge. ``solve_one(q_seed,
    T_hand (4x4), hand) -> (converged, q (nq,), iterations)``. Returns the candidates
    (every converged q) and the time of the projections."""
    T, Q0 = P["targets"], P["q_seed"]
    n = len(T) if limit is None else min(limit, len(T))
    cands, arms, its = [], [], 0
    t0 = time.perf_counter()
    for k in range(n):
        for a, hand in enumerate(hands):
            ok, q, it = solve_one(Q0[k].copy(), T[k], hand)
            its += it
            if ok:
                cands.append(q)
                arms.append(a)
                break
    dt = time.perf_counter() - t0
    return {"samples": n, "converged": len(cands), "ik_time_s": dt, "iterations": its,
            "candidates": np.array(cands).reshape(-1, len(Q0[0])).tolist(), "arms": arms}
