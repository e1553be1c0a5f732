"""Ratio and JSON assembly of bench/peers (no peer, no project import: the fast test uses it).

Every ratio is peer time / our time: > 1 means this project is faster; ``None`` when a
side is missing (peer not available, no valid goal, no successful plan).
"""
from __future__ import annotations

import math

RATIO_KEYS = ("ratio_goal_vs_hpp", "ratio_goal_vs_placo", "ratio_goal_vs_pink", "ratio_path_vs_ompl",
              "ratio_path_vs_hpp", "ratio_collision_vs_hpp", "ratio_collision_vs_coal")


def ratio(peer: float | None, ours: float | None) -> float | None:
    if peer is None or ours is None:
        return None
    if not (math.isfinite(peer) and math.isfinite(ours)) or ours <= 0 or peer <= 0:
        return None
    return float(peer) / float(ours)


def mean(xs) -> float | None:
    xs = [float(x) for x in xs or []]
    return sum(xs) / len(xs) if xs else None


def per_valid_goal_ms(total_time_s: float, n_valid: int) -> float | None:
    return 1e3 * total_time_s / n_valid if n_valid > 0 else None


def _get(d: dict | None, *keys):
    for k in keys:
        if not isinstance(d, dict) or k not in d:
            return None
        d = d[k]
    return d


def assemble(ours: dict, peers: dict, machine: str, settings: dict | None = None) -> dict:
    """``ours``: {"goals": {"time_per_valid_goal_ms"}, "paths": {"plan_ms_mean"},
    "collision": {"single_us_per_config"}}; ``peers``: {"hpp": {"goals", "paths", "collision"},
    "placo": {"goals"}, "pink": {"goals"}, "ompl": {"paths"}, "coal": {"collision"}}, each
    part a worker's dict (``available`` false with ``why`` when it could not run)."""
    our_goal = _get(ours, "goals", "time_per_valid_goal_ms")
    our_path = _get(ours, "paths", "plan_ms_mean")
    our_coll = _get(ours, "collision", "single_us_per_config")
    ompl = _get(peers, "ompl", "paths") or {}
    # OMPL is compared with our planner run interleaved in the same process on the same goals
    ompl_ms = mean(_get(ompl, "ompl", "time_s") or [])
    ompl_ours_ms = mean(_get(ompl, "ours", "time_s") or [])
    hpp_path_ms = mean(_get(peers, "hpp", "paths", "time_s") or [])
    out = {
        "bench": "peers",
        "machine": machine,
        "settings": settings or {},
        "ours": ours,
        "peers": peers,
        "ratio_goal_vs_hpp": ratio(_get(peers, "hpp", "goals", "time_per_valid_goal_ms"), our_goal),
        "ratio_goal_vs_placo": ratio(_get(peers, "placo", "goals", "time_per_valid_goal_ms"), our_goal),
        "ratio_goal_vs_pink": ratio(_get(peers, "pink", "goals", "time_per_valid_goal_ms"), our_goal),
        "ratio_path_vs_ompl": ratio(None if ompl_ms is None else 1e3 * ompl_ms,
                                    None if ompl_ours_ms is None else 1e3 * ompl_ours_ms),
        "ratio_path_vs_hpp": ratio(None if hpp_path_ms is None else 1e3 * hpp_path_ms, our_path),
        "ratio_collision_vs_hpp": ratio(_get(peers, "hpp", "collision", "us_per_config"), our_coll),
        "ratio_collision_vs_coal": ratio(_get(peers, "coal", "collision", "us_per_config"), our_coll),
    }
    return out
