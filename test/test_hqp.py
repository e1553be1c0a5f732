"""Tests of humanoid_reach_ros.control.hqp (lexicographic QP on OSQP)."""
from __future__ import annotations

import numpy as np
import pytest

from humanoid_reach_ros.control.hqp import HierarchicalQP, Level, SaturatedNullSpaceHQP, solve_dense_reference

E = np.eye(4)


def row(*idx_val):
    r = np.zeros(4)
    for i, v in idx_val:
        r[i] = v
    return r


def test_priority_ordering_conflicting_equalities():
    # level 1 empty (n given), level 2: x0 = 1, level 3: x0 = -1 and x1 = 2
    hqp = HierarchicalQP()
    res = hqp.solve([Level(A=E[[0]], b=[1.0]), Level(A=E[[0, 1]], b=[-1.0, 2.0])], n=4)
    assert res.x[0] == pytest.approx(1.0, abs=1e-6)
    assert res.x[1] == pytest.approx(2.0, abs=1e-6)
    assert res.slacks[0] == pytest.approx(0.0, abs=1e-6)
    assert res.slacks[1] == pytest.approx(2.0, abs=1e-6)
    # minimal norm in the free dimensions
    assert np.allclose(res.x[2:], 0.0, atol=1e-6)


def test_inequality_beats_lower_equality():
    hqp = HierarchicalQP()
    levels = [Level(C=E[[0]], d=[0.5]), Level(A=E[[0]], b=[1.0]), Level(A=E[[1, 2]], b=[3.0, -1.0])]
    res = hqp.solve(levels)
    assert res.x[0] == pytest.approx(0.5, abs=1e-6)
    assert res.x[1] == pytest.approx(3.0, abs=1e-6)
    assert res.x[2] == pytest.approx(-1.0, abs=1e-6)
    assert res.slacks[0] == pytest.approx(0.0, abs=1e-6)
    assert res.slacks[1] == pytest.approx(0.5, abs=1e-6)
    assert res.n_active_inequalities == 1


def test_infeasible_first_level_is_relaxed_not_failed():
    # x0 <= -1 and x0 >= 1: least violation x0 = 0 (slacks 1, 1); x1 = 1 still solved below
    hqp = HierarchicalQP()
    levels = [Level(C=np.vstack([E[0], -E[0]]), d=[-1.0, -1.0]), Level(A=E[[1]], b=[1.0])]
    res = hqp.solve(levels)
    assert res.x[0] == pytest.approx(0.0, abs=1e-5)
    assert res.x[1] == pytest.approx(1.0, abs=1e-6)
    assert res.slacks[0] == pytest.approx(np.sqrt(2.0), abs=1e-5)
    assert res.levels[1].slack_norm == pytest.approx(0.0, abs=1e-6)


def _random_levels(rng, n):
    levels = []
    for _ in range(3):
        me, mi = rng.integers(0, 3), rng.integers(0, 3)
        A = rng.normal(size=(me, n)) if me else None
        b = rng.normal(size=me) if me else None
        C = rng.normal(size=(mi, n)) if mi else None
        d = rng.normal(size=mi) if mi else None
        levels.append(Level(A, b, C, d))
    # a conflicting pair somewhere, sometimes
    if rng.random() < 0.5:
        c = rng.normal(size=n)
        levels[0] = Level.stack(levels[0], Level(C=np.vstack([c, -c]), d=[-0.5, -0.5]))
    return levels


@pytest.mark.parametrize("seed", range(25))
def test_matches_dense_reference(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(3, 6))
    levels = _random_levels(rng, n)
    _, ref = solve_dense_reference(levels, n)
    res = HierarchicalQP(eps=1e-8, damping=1e-10).solve(levels, n=n)
    assert np.allclose(res.slacks, ref, atol=1e-5), (res.slacks, ref, [r.status for r in res.levels])


def _moving_problem(t):
    A2 = np.array([[1.0, 1.0, 0.0, 0.0, 0.0], [0.0, 1.0, -1.0, 0.0, 0.0]])
    C1 = np.array([[1.0, 0.0, 0.0, 0.5, 0.0], [0.0, 0.0, 1.0, 0.0, 1.0], [-1.0, 0.2, 0.0, 0.0, 0.0]])
    return [Level(C=C1, d=[0.3 + 0.01 * np.sin(t), 0.2, 0.4]),
            Level(A=A2, b=[1.0 + 0.01 * t, 0.5]),
            Level(A=np.eye(5), b=np.full(5, 0.3 + 0.01 * t))]


def test_warm_start_same_answer_fewer_iterations():
    warm, cold = HierarchicalQP(warm_start=True), HierarchicalQP(warm_start=False)
    it_w = it_c = 0
    for t in range(20):
        lv = _moving_problem(t)
        rw, rc = warm.solve(lv), cold.solve(lv)
        assert np.allclose(rw.x, rc.x, atol=1e-5)
        assert np.allclose(rw.slacks, rc.slacks, atol=1e-6)
        if t > 0:
            it_w += sum(r.iterations for r in rw.levels)
            it_c += sum(r.iterations for r in rc.levels)
    print(f"\niterations over 19 steps: warm {it_w}, cold {it_c}")
    assert it_w < it_c


def test_variable_row_counts():
    rng = np.random.default_rng(3)
    hqp = HierarchicalQP()
    n = 5
    setups = []
    for k in [2, 0, 5, 1, 9, 3, 9, 0]:
        C = rng.normal(size=(k, n))
        d = rng.uniform(0.1, 1.0, size=k)  # x = 0 feasible
        levels = [Level(C=C, d=d), Level(A=np.eye(n), b=rng.normal(size=n) * 3)]
        res = hqp.solve(levels)
        _, ref = solve_dense_reference(levels, n) if k <= 5 else (None, None)
        assert res.ok
        assert res.slacks[0] == pytest.approx(0.0, abs=1e-6)
        if k:
            assert np.all(C @ res.x <= d + 1e-5)
        if ref is not None:
            assert np.allclose(res.slacks, ref, atol=1e-5)
        setups.append(res.setups)
    # re-setup only when a capacity grows
    assert setups[0] > 0 and setups[1] == 0 and setups[3] == 0 and setups[5] == 0 and setups[6] == 0


# ---------------------------------------------------------------- SaturatedNullSpaceHQP (executor fast path)
def _eq_levels(rng, n, sizes):
    return [(rng.normal(size=(m, n)), rng.normal(size=m)) for m in sizes]


def test_saturated_conflicting_equalities_keep_priority():
    s = SaturatedNullSpaceHQP(damping=0.0)
    # level 2: x0 = 1; level 3: x0 = -1, x1 = 2 (conflict on x0: level 2 wins)
    r = s.solve(None, None, [(E[[0]], np.array([1.0])), (E[[0, 1]], np.array([-1.0, 2.0]))])
    assert r.x[0] == pytest.approx(1.0, abs=1e-12)
    assert r.x[1] == pytest.approx(2.0, abs=1e-12)
    assert r.slacks[1] == pytest.approx(0.0, abs=1e-12)
    assert r.slacks[2] == pytest.approx(2.0, abs=1e-12)
    assert np.allclose(r.x[2:], 0.0)
    assert not r.fallback


def test_saturated_inequality_beats_equalities():
    s = SaturatedNullSpaceHQP(damping=0.0)
    G, h = E[[0]], np.array([0.5])
    r = s.solve(G, h, [(E[[0]], np.array([1.0])), (E[[1, 2]], np.array([3.0, -1.0]))])
    assert r.x[0] == pytest.approx(0.5, abs=1e-12)
    assert r.x[1:3] == pytest.approx([3.0, -1.0], abs=1e-12)
    assert r.slacks == pytest.approx((0.0, 0.5, 0.0, ), abs=1e-12)
    assert r.n_active == 1 and r.saturated == 1


@pytest.mark.parametrize("seed", range(20))
def test_saturated_equalities_match_dense_reference(seed):
    rng = np.random.default_rng(100 + seed)
    n = int(rng.integers(4, 8))
    eq = _eq_levels(rng, n, rng.integers(1, 4, size=3))
    _, ref = solve_dense_reference([Level(A=A, b=b) for A, b in eq], n)
    r = SaturatedNullSpaceHQP(damping=0.0).solve(np.zeros((0, n)), np.zeros(0), eq)
    assert np.allclose(r.slacks[1:], ref, rtol=1e-6, atol=1e-6), (r.slacks, ref)  # ref: damping 1e-10


@pytest.mark.parametrize("seed", range(20))
def test_saturated_single_inequality_is_exact(seed):
    # one inequality row: saturating it when violated is the exact lexicographic optimum
    rng = np.random.default_rng(200 + seed)
    n = int(rng.integers(4, 7))
    eq = _eq_levels(rng, n, rng.integers(1, 3, size=2))
    G = rng.normal(size=(1, n))
    h = np.array([rng.normal()])
    levels = [Level(C=G, d=h)] + [Level(A=A, b=b) for A, b in eq]
    _, ref = solve_dense_reference(levels, n)
    r = SaturatedNullSpaceHQP(damping=0.0).solve(G, h, eq)
    assert float(G[0] @ r.x - h[0]) <= 1e-9
    assert np.allclose(r.slacks, ref, rtol=1e-6, atol=1e-7), (r.slacks, ref)


@pytest.mark.parametrize("seed", range(15))
def test_saturated_feasible_level_one_is_never_violated(seed):
    # box rows (joint-limit like, group -1) + random rows with x = 0 strictly feasible
    rng = np.random.default_rng(300 + seed)
    n = 8
    box = 0.2
    G = np.vstack([np.eye(n), -np.eye(n), rng.normal(size=(6, n))])
    h = np.concatenate([np.full(2 * n, box), rng.uniform(0.05, 0.3, 6)])
    groups = np.concatenate([np.full(2 * n, -1), rng.integers(0, 2, 6)])
    eq = [(rng.normal(size=(3, n)), 3 * rng.normal(size=3)), (np.eye(n), 3 * rng.normal(size=n))]
    r = SaturatedNullSpaceHQP().solve(G, h, eq, fallback=HierarchicalQP(polish=False), groups=groups)
    assert np.all(G @ r.x <= h + 1e-9)
    assert r.slacks[0] <= 1e-9
    # the OSQP cascade's level-2 slack is a lower bound (up to its tolerance): the closed
    # form may be sub-optimal (no release of saturated rows) but never "better"
    ref = HierarchicalQP(polish=False).solve([Level(C=G, d=h)] + [Level(A=A, b=b) for A, b in eq], n=n)
    assert r.slacks[1] >= ref.slacks[1] - 1e-4


def test_saturated_inconsistent_level_one_uses_fallback_least_violation():
    # x0 <= -1 and x0 >= 1 cannot both hold: the result is the least-violation point
    s = SaturatedNullSpaceHQP()
    G = np.vstack([E[0], -E[0]])
    h = np.array([-1.0, -1.0])
    r = s.solve(G, h, [(E[[1]], np.array([1.0]))], fallback=HierarchicalQP(polish=False))
    assert r.fallback
    assert abs(r.x[0]) <= 1e-3
    assert r.x[1] == pytest.approx(1.0, abs=1e-6)
    assert s.fallbacks == 1
