"""Tests of humanoid_reach_ros.control.active_set (lexicographic QP by dual active-set solves)."""
from __future__ import annotations

import numpy as np
import pytest

from humanoid_reach_ros.control.active_set import ActiveSetCascade
from humanoid_reach_ros.control.hqp import HierarchicalQP, Level, SaturatedNullSpaceHQP, solve_dense_reference


def _problem(rng, n=10, m=40, parallel=0, box=True):
    """Feasible level 1 (``x = 0`` strictly inside; a box and random rows, ``parallel`` of them
    nearly parallel copies of one row, as a robot shape's dampers near a wall) above three
    equality levels that pull hard against it."""
    c = rng.normal(size=n)
    rand = rng.normal(size=(m, n))
    rand[:parallel] = c + 1e-3 * rng.normal(size=(parallel, n))
    G = np.vstack([np.eye(n), -np.eye(n), rand]) if box else rand
    h = np.concatenate([np.full(2 * n, 0.3) if box else np.zeros(0), rng.uniform(0.01, 0.2, m)])
    eq = [(rng.normal(size=(3, n)), 0.5 * rng.normal(size=3)), (rng.normal(size=(4, n)), 3 * rng.normal(size=4)),
          (np.eye(n), rng.normal(size=n))]
    return G, h, eq


@pytest.mark.parametrize("seed", range(12))
def test_matches_the_dense_lexicographic_reference(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(4, 7))
    G, h, eq = _problem(rng, n=n, m=7, box=False)   # (the reference enumerates active sets)
    res = ActiveSetCascade(eps=1e-9, eps_lower=1e-9).solve(G, h, eq)
    assert res.ok and res.level_failed == -1
    assert np.all(G @ res.x <= h + 1e-9)
    _, ref = solve_dense_reference([Level(C=G, d=h)] + [Level(A=A, b=b) for A, b in eq], n)
    slacks = [float(np.linalg.norm(np.maximum(G @ res.x - h, 0.0)))] + [float(np.linalg.norm(A @ res.x - b))
                                                                       for A, b in eq]
    # level by level: never worse than the reference where the levels above tie
    assert slacks[1] <= ref[1] + 1e-6, (slacks, ref)
    if abs(slacks[1] - ref[1]) < 1e-6:
        assert slacks[2] <= ref[2] + 1e-5, (slacks, ref)


@pytest.mark.parametrize("seed", range(8))
def test_nearly_parallel_rows_never_violated_and_no_worse_than_osqp(seed):
    """Many nearly parallel rows (what makes the saturation passes cycle): every row holds,
    the first level is met as well as OSQP's cascade meets it, the second no worse."""
    rng = np.random.default_rng(50 + seed)
    G, h, eq = _problem(rng, n=12, m=200, parallel=150)
    res = ActiveSetCascade().solve(G, h, eq)
    assert res.ok
    assert float((G @ res.x - h).max()) <= 1e-9
    ref = HierarchicalQP(polish=False).solve([Level(C=G, d=h)] + [Level(A=A, b=b) for A, b in eq], n=12)
    ours = [float(np.linalg.norm(A @ res.x - b)) for A, b in eq]
    assert ours[0] <= ref.slacks[1] + 1e-4
    if abs(ours[0] - ref.slacks[1]) < 1e-4:     # (the second level is damped: eps_lower)
        assert ours[1] <= ref.slacks[2] * (1 + 1e-3) + 1e-3


def test_first_level_kept_exactly_when_feasible():
    rng = np.random.default_rng(7)
    G, h, eq = _problem(rng, n=12, m=100, parallel=60)
    A1 = eq[0][0]
    eq[0] = (A1, A1 @ rng.uniform(-0.01, 0.01, 12))  # reachable inside the box, the rows permitting
    x0 = np.linalg.lstsq(A1, eq[0][1], rcond=None)[0]
    if np.all(G @ x0 <= h):
        res = ActiveSetCascade().solve(G, h, eq)
        assert res.ok and np.linalg.norm(A1 @ res.x - eq[0][1]) <= 1e-9


def test_infeasible_level_one_is_reported_not_returned():
    G = np.array([[1.0, 0.0], [-1.0, 0.0]])
    h = np.array([-1.0, -1.0])                      # x0 <= -1 and x0 >= 1
    res = ActiveSetCascade().solve(G, h, [(np.eye(2), np.ones(2))])
    assert not res.ok and res.level_failed == 0


def test_no_inequality_rows_is_the_closed_form():
    rng = np.random.default_rng(3)
    eq = [(rng.normal(size=(2, 5)), rng.normal(size=2)), (np.eye(5), rng.normal(size=5))]
    res = ActiveSetCascade(eps=1e-9, eps_lower=1e-9).solve(np.zeros((0, 5)), np.zeros(0), eq)
    ref = SaturatedNullSpaceHQP(damping=0.0).equality_cascade(eq, 5)
    assert res.ok and np.allclose(res.x, ref, atol=1e-7)


def test_saturated_solver_uses_the_cascade_for_many_grouped_rows():
    """SaturatedNullSpaceHQP.solve: with >= active_set_min_rows grouped rows and a level-1 row
    active, the cascade answers (result flagged), every row holds; with fewer, it does not."""
    rng = np.random.default_rng(11)
    G, h, eq = _problem(rng, n=12, m=200, parallel=150)
    groups = np.concatenate([np.full(24, -1), rng.integers(0, 5, 200)])
    ns = SaturatedNullSpaceHQP(active_set_min_rows=24)
    r = ns.solve(G, h, eq, fallback=HierarchicalQP(polish=False), groups=groups, active_set=ActiveSetCascade())
    assert r.active_set and not r.fallback and r.slacks[0] <= 1e-9
    few = SaturatedNullSpaceHQP(active_set_min_rows=1000)
    r2 = few.solve(G, h, eq, fallback=HierarchicalQP(polish=False), groups=groups, active_set=ActiveSetCascade())
    assert not r2.active_set and r2.slacks[0] <= 1e-9
