"""The sampling-based planners behind one call: :func:`plan` dispatches to
:mod:`.rrt_connect` or :mod:`.prm`.

The shared pieces (space, results, edges, shortcutting) live in the lower module
:mod:`.space`, which both planners import; they are re-exported here, so
``from humanoid_reach_ros.planning.path import PlanningSpace, check_edges, ...`` keeps
working (see :mod:`.space` for the metric and the edge discretisation).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from humanoid_reach_ros.planning.prm import PRMOptions, plan_prm
from humanoid_reach_ros.planning.rrt_connect import RRTConnectOptions, plan_rrt_connect
from humanoid_reach_ros.planning.space import (  # noqa: F401 -- re-exported
    ValidityFn, PLANNER_NAMES, PlanningSpace, PlanStatus, PlanStats, PlanResult, CountingChecker, first_invalid,
    as_counting, Deadline, validate_endpoints, edge_steps, interpolate_edge, interpolate_path,
    check_edges, check_edge, check_path, ShortcutOptions, remove_redundant_waypoints, shortcut_path,
)


# ------------------------------------------------------------------ dispatch
def plan(planner: str, start: np.ndarray, goals: np.ndarray, is_valid_batch: ValidityFn,
         space: PlanningSpace, rng: np.random.Generator, options: object | None = None) -> PlanResult:
    """Run the planner named ``planner`` (one of :data:`PLANNER_NAMES`).

    ``options`` is a :class:`~.rrt_connect.RRTConnectOptions` or
    :class:`~.prm.PRMOptions` (defaults when ``None``; for ``"prm"`` /
    ``"modified_prm"`` the name overrides ``options.variant``).
    """
    if planner == "rrt_connect":
        return plan_rrt_connect(start, goals, is_valid_batch, space, rng, options or RRTConnectOptions())
    if planner in ("prm", "modified_prm"):
        opts = replace(options or PRMOptions(), variant=planner)
        return plan_prm(start, goals, is_valid_batch, space, rng, opts)
    raise ValueError(f"unknown planner {planner!r}; expected one of {PLANNER_NAMES}")

