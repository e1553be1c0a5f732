"""Lexicographic (hierarchical) QP: prioritized IK with equalities and inequalities.

Kanoun, Lamiraux and Wieber (2011), the solver of Sec. IV of Kanehiro et al.:
levels ``k = 1..p``, each with equality rows ``A_k x = b_k`` and inequality rows
``C_k x <= d_k``. Level ``k`` solves

    min_{x, w}  ||A_k x - b_k||^2 + ||w||^2 + eps ||x||^2
    s.t.        C_k x - d_k <= w                                  (own inequalities)
                A_j x  = b_j + w_j*          for all j < k        (higher equalities)
                C_j x <= d_j + max(w_j*, 0)  for all j < k        (higher inequalities)

where ``w_j*`` are the optimal slacks of the higher levels, frozen once level ``j``
is solved: a lower level never degrades a higher one, and an infeasible level is
never an error, it is solved in the least-squares sense (equalities) or with the
least violation (inequalities) and the lower levels use the remaining freedom.
``eps`` (``damping``) makes every level strictly convex; a final level
``min ||x||^2`` under all frozen rows picks the minimal-norm solution.

Implementation: one OSQP instance per level, kept across calls, with a *fixed dense
sparsity pattern*: the x-columns of every constraint row are stored densely, and each
level reserves capacities for its equality and inequality rows; unused rows are
inactive (``0 x = 0`` / ``0 x <= +inf``). Changing row counts (collision dampers
that come and go) then only needs ``OSQP.update`` (new values, same pattern); a
re-``setup`` happens only when a capacity grows. Each solver warm-starts from its
own previous primal/dual solution (previous control step; the default) or, with
``level_warm_start=True``, from the previous level's ``x`` (feasible for the frozen
rows); the first solve of each level always starts from the previous level's ``x``.

Frozen right-hand sides are taken at the latest solution (``A_j x_k`` and
``max(d_j + w_j*, C_j x_k)``) so the frozen set is always exactly feasible even
though OSQP solves to a tolerance (the drift is of the order of that tolerance).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Sequence

import numpy as np
import osqp
import scipy.sparse as sp

if TYPE_CHECKING:
    from humanoid_reach_ros.control.active_set import ActiveSetCascade

_INF = 1e30


@dataclass(frozen=True)
class Level:
    """One priority level: equality rows ``A x = b`` and inequality rows ``C x <= d``.

    Either part may be empty (``None`` or zero rows). ``n`` is inferred from the rows.
    """

    A: np.ndarray | None = None
    b: np.ndarray | None = None
    C: np.ndarray | None = None
    d: np.ndarray | None = None
    name: str = ""

    def parts(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        A = np.zeros((0, n)) if self.A is None else np.atleast_2d(np.asarray(self.A, float))
        b = np.zeros(len(A)) if self.b is None else np.asarray(self.b, float).reshape(-1)
        C = np.zeros((0, n)) if self.C is None else np.atleast_2d(np.asarray(self.C, float))
        d = np.zeros(len(C)) if self.d is None else np.asarray(self.d, float).reshape(-1)
        if A.shape[0] == 0:
            A = A.reshape(0, n)
        if C.shape[0] == 0:
            C = C.reshape(0, n)
        if A.shape != (len(b), n) or C.shape != (len(d), n):
            raise ValueError(f"level {self.name!r}: inconsistent shapes A{A.shape} b{b.shape} "
                             f"C{C.shape} d{d.shape} for n={n}")
        return A, b, C, d

    @staticmethod
    def stack(*levels: "Level", name: str = "") -> "Level":
        """One level holding all rows of ``levels`` (same priority)."""
        def cat(mats, vecs):
            mats = [np.atleast_2d(m) for m, v in zip(mats, vecs) if m is not None and np.size(v)]
            vecs = [np.ravel(v) for v in vecs if v is not None and np.size(v)]
            return (np.vstack(mats), np.concatenate(vecs)) if mats else (None, None)
        A, b = cat([lv.A for lv in levels], [lv.b for lv in levels])
        C, d = cat([lv.C for lv in levels], [lv.d for lv in levels])
        return Level(A, b, C, d, name)


@dataclass(frozen=True)
class LevelReport:
    """Outcome of one level: OSQP status, slack norms, iterations, solve time."""

    status: str
    eq_slack: np.ndarray        # A_k x - b_k
    ineq_slack: np.ndarray      # max(C_k x - d_k, 0)
    iterations: int
    time_s: float

    @property
    def slack_norm(self) -> float:
        return float(np.sqrt(self.eq_slack @ self.eq_slack + self.ineq_slack @ self.ineq_slack))


@dataclass(frozen=True)
class HQPResult:
    """Solution ``x`` and per-level reports (the final minimal-norm level excluded)."""

    x: np.ndarray
    levels: tuple[LevelReport, ...]
    n_active_inequalities: int   # inequality rows at their bound (|C x - d| <= tol or violated)
    time_s: float
    setups: int                  # number of OSQP re-setups done in this call

    @property
    def slacks(self) -> tuple[float, ...]:
        return tuple(r.slack_norm for r in self.levels)

    @property
    def ok(self) -> bool:
        return all(r.status in ("solved", "solved inaccurate") for r in self.levels)


@dataclass
class _LevelSolver:
    """The OSQP instance of one level and its fixed pattern."""

    n: int
    n_fixed: int          # frozen rows from higher levels (capacity)
    n_ineq: int           # own inequality capacity (slack variables)
    reg: float
    settings: dict
    level_warm: bool = False
    solved_once: bool = False
    solver: osqp.OSQP = field(init=False)
    _p_rows: np.ndarray = field(init=False, repr=False)
    _p_cols: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        n, mi = self.n, self.n_ineq
        cols = np.concatenate([np.full(j + 1, j) for j in range(n)]) if n else np.zeros(0, int)
        rows = np.concatenate([np.arange(j + 1) for j in range(n)]) if n else np.zeros(0, int)
        self._p_rows, self._p_cols = rows, cols
        N = n + mi
        # P: dense upper triangle of the x block, identity on the slacks
        p_indptr = np.concatenate([[0], np.cumsum(np.arange(1, n + 1)), (n * (n + 1)) // 2 + np.arange(1, mi + 1)])
        p_indices = np.concatenate([rows, n + np.arange(mi)])
        H = np.eye(n)
        self._P = sp.csc_matrix((self._p_data(H), p_indices, p_indptr), shape=(N, N))
        # A: dense x columns over all rows, -I on the slack columns
        M = self.n_rows
        a_indptr = np.concatenate([np.arange(n + 1) * M, n * M + np.arange(1, mi + 1)])
        a_indices = np.concatenate([np.tile(np.arange(M), n), self.n_fixed + np.arange(mi)])
        a_data = np.concatenate([np.zeros(M * n), -np.ones(mi)])
        self._A = sp.csc_matrix((a_data, a_indices, a_indptr), shape=(M, N))
        self._neg = -np.ones(mi)
        self.solver = osqp.OSQP()
        self.solver.setup(self._P, np.zeros(N), self._A, np.full(M, -_INF), np.full(M, _INF), **self.settings)

    @property
    def n_rows(self) -> int:
        return max(self.n_fixed + self.n_ineq, 1)

    def _p_data(self, H: np.ndarray) -> np.ndarray:
        return np.concatenate([H[self._p_rows, self._p_cols], np.ones(self.n_ineq)])

    def solve(self, H, g, F, lF, uF, C, d, x0, warm_level: bool):
        """min 1/2 x'Hx + g'x + 1/2|w|^2 s.t. lF <= F x <= uF, C x - w <= d (all padded)."""
        n, mi = self.n, self.n_ineq
        M = self.n_rows
        Ad = np.zeros((M, n))
        Ad[: self.n_fixed] = F
        Ad[self.n_fixed: self.n_fixed + mi] = C
        lower = np.full(M, -_INF)
        upper = np.full(M, _INF)
        lower[: self.n_fixed] = lF
        upper[: self.n_fixed] = uF
        upper[self.n_fixed: self.n_fixed + mi] = d
        q = np.concatenate([g, np.zeros(mi)])
        self.solver.update(q=q, l=lower, u=upper, Px=self._p_data(H),
                           Ax=np.concatenate([Ad.ravel(order="F"), self._neg]))
        if warm_level and x0 is not None and (self.level_warm or not self.solved_once):
            w0 = np.maximum(C @ x0 - d, 0.0)
            self.solver.warm_start(x=np.concatenate([x0, w0]))
        res = self.solver.solve(raise_error=False)
        self.solved_once = True
        return res


class HierarchicalQP:
    """Lexicographic QP solver with persistent per-level OSQP instances.

    ``solve(levels)`` takes the levels in priority order (first = highest). The
    number of levels and ``n`` should stay the same between calls (changing them
    re-creates the solvers); row counts may change freely.
    """

    def __init__(self, damping: float = 1e-8, min_norm: bool = True, eps: float = 1e-6,
                 polish: bool = True, warm_start: bool = True, max_iter: int = 4000,
                 active_tol: float = 1e-6, growth: float = 1.5, level_warm_start: bool = False, rank_tol: float = 1e-9,
                 **osqp_settings) -> None:
        self.damping = float(damping)
        self.min_norm = bool(min_norm)
        self.warm = bool(warm_start)
        self.level_warm = bool(level_warm_start)
        self.active_tol = float(active_tol)
        self.growth = float(growth)
        self.rank_tol = float(rank_tol)
        self.settings = dict(eps_abs=eps, eps_rel=eps, polishing=polish, warm_starting=warm_start,
                             max_iter=max_iter, verbose=False, polish_refine_iter=5,
                             # every level is feasible (slacks, relaxed frozen bounds) and bounded
                             # (P > 0) by construction: switch off the certificates, which the
                             # tiny damping otherwise triggers falsely
                             eps_prim_inf=1e-15, eps_dual_inf=1e-15)
        self.settings.update(osqp_settings)
        self._n: int | None = None
        self._cap: list[int] = []                  # inequality row capacity per level
        self._solvers: list[_LevelSolver] = []

    # ------------------------------------------------------------ structure
    def _ensure(self, n: int, sizes: Sequence[int]) -> int:
        """(Re)build solvers whose pattern cannot hold the inequality row counts ``sizes``;
        returns the number of OSQP setups done."""
        if self._n != n or len(self._cap) != len(sizes):
            self._n, self._solvers = n, []
            first_bad = 0
            new_cap = [int(mi) for mi in sizes]
        else:
            first_bad = None
            new_cap = list(self._cap)
            for k, (mi, ci) in enumerate(zip(sizes, self._cap)):
                if mi > ci:
                    new_cap[k] = max(int(mi), int(np.ceil(ci * self.growth)))
                    first_bad = k if first_bad is None else first_bad
            if first_bad is None:
                return 0
        self._cap = new_cap
        self._solvers = self._solvers[:first_bad]
        fixed = sum(new_cap[:first_bad])
        count = 0
        for k in range(first_bad, len(new_cap)):
            self._solvers.append(_LevelSolver(n, fixed, new_cap[k], self.damping, self.settings, self.level_warm))
            fixed += new_cap[k]
            count += 1
        self._solvers.append(_LevelSolver(n, fixed, 0, self.damping, self.settings, self.level_warm))
        return count + 1

    # ------------------------------------------------------------ solve
    def solve(self, levels: Sequence[Level], n: int | None = None) -> HQPResult:
        """Solve the hierarchy; ``levels[0]`` has the highest priority.

        Frozen equalities are eliminated exactly: after level ``k`` the solution is
        ``x = x_k + N_k y`` with ``N_k`` the orthogonal projector onto the null space
        of all equality rows so far (``N_k = N_{k-1} - (A_k N_{k-1})^+ A_k N_{k-1}``),
        so OSQP only ever sees inequality rows (frozen ones with relaxed bounds and the
        level's own ones with slacks) and the higher equalities cannot drift.
        """
        t0 = time.perf_counter()
        if n is None:
            n = next((np.shape(m)[1] for lv in levels for m in (lv.A, lv.C) if m is not None and np.ndim(m) == 2), None)
            if n is None:
                raise ValueError("cannot infer n from empty levels; pass n")
        parts = [lv.parts(n) for lv in levels]
        setups = self._ensure(n, [len(d) for _, _, _, d in parts])

        n_fixed = sum(self._cap)
        F = np.zeros((n_fixed, n))            # frozen inequality rows (padded)
        uF = np.full(n_fixed, _INF)
        row = 0
        x = np.zeros(n)
        N = np.eye(n)
        reports = []
        eye = np.eye(n)
        for k, ((A, b, C, d), ci) in enumerate(zip(parts, self._cap)):
            s = self._solvers[k]
            AN = A @ N
            H = AN.T @ AN + s.reg * eye
            g = AN.T @ (A @ x - b)
            CN = np.zeros((ci, n))
            dp = np.full(ci, _INF)
            CN[: len(C)] = C @ N
            dp[: len(d)] = d - C @ x
            ts = time.perf_counter()
            res = s.solve(H, g, F[:row] @ N, np.full(row, -_INF), uF[:row] - F[:row] @ x, CN, dp,
                          np.zeros(n), warm_level=self.warm)
            dt = time.perf_counter() - ts
            if _usable(res):
                x = x + N @ res.x[:n]
            eq_s = A @ x - b
            viol = C @ x - d
            in_s = np.maximum(viol, 0.0)
            reports.append(LevelReport(res.info.status, eq_s, in_s, int(res.info.iter), dt))
            # freeze: inequalities at their relaxed bound (never tighter than x), equalities in N
            F[row: row + len(d)] = C
            uF[row: row + len(d)] = d + in_s
            row += ci
            if len(A):
                N = _project_out(N, AN, self.rank_tol)
        if self.min_norm and row + 1 <= len(F) + 1:
            s = self._solvers[len(levels)]
            # min |x + N y|^2 + damping |y|^2 under the frozen inequalities
            res = s.solve(N.T @ N + s.reg * eye, N.T @ x, F[:row] @ N, np.full(row, -_INF),
                          uF[:row] - F[:row] @ x, np.zeros((0, n)), np.zeros(0), np.zeros(n),
                          warm_level=self.warm)
            if _usable(res):
                x_new = x + N @ res.x[:n]
                if row == 0 or np.all(F[:row] @ x_new <= uF[:row] + 1e-7):
                    x = x_new
        n_active = sum(int(np.count_nonzero(C @ x - d >= -self.active_tol)) for _, _, C, d in parts)
        return HQPResult(x, tuple(reports), n_active, time.perf_counter() - t0, setups)


_USABLE = ("solved", "solved inaccurate", "maximum iterations reached", "run time limit reached")


def _usable(res) -> bool:
    """An OSQP iterate worth taking (not an infeasibility certificate)."""
    return res.info.status in _USABLE and res.x is not None and bool(np.all(np.isfinite(res.x)))


def _project_out(N: np.ndarray, AN: np.ndarray, rank_tol: float) -> np.ndarray:
    """``N - (A N)^+ (A N)`` with a rank-revealing SVD (``N`` an orthogonal projector)."""
    _, S, Vt = np.linalg.svd(AN, full_matrices=False)
    if len(S) == 0:
        return N
    r = int(np.sum(S > rank_tol * max(S[0], 1.0)))
    V = Vt[:r]
    return N - V.T @ V


# ---------------------------------------------------------------- dense reference
def solve_dense_reference(levels: Sequence[Level], n: int, damping: float = 1e-10,
                          tol: float = 1e-9) -> tuple[np.ndarray, list[float]]:
    """Exact lexicographic solve by active-set enumeration (small problems only; tests).

    For each level and each candidate set of active inequality rows (own rows counted
    in the least squares, frozen rows held at their bound) the equality-constrained
    least squares is solved by null-space projection; the best feasible candidate
    under the true (strictly convex, ``damping``-regularised) objective is exact.
    Returns ``(x, slack norm per level)``.
    """
    import itertools

    parts = [lv.parts(n) for lv in levels]
    FE = np.zeros((0, n))      # frozen equalities
    fe = np.zeros(0)
    FI = np.zeros((0, n))      # frozen inequalities
    fi = np.zeros(0)
    x = np.zeros(n)
    norms = []

    def objective(A, b, C, d, y):
        r = A @ y - b
        w = np.maximum(C @ y - d, 0.0)
        return r @ r + w @ w + damping * y @ y

    for A, b, C, d in parts:
        best, best_val = None, np.inf
        mi, mf = len(d), len(fi)
        for act_own in itertools.product((False, True), repeat=mi):
            M = np.vstack([A, C[list(act_own)]]) if mi else A
            r = np.concatenate([b, d[list(act_own)]]) if mi else b
            for act_fix in itertools.product((False, True), repeat=mf):
                E = np.vstack([FE, FI[list(act_fix)]])
                e = np.concatenate([fe, fi[list(act_fix)]])
                y = _eq_lsq(M, r, E, e, damping, tol)
                if y is None:
                    continue
                if len(FI) and np.any(FI @ y > fi + 1e-9):
                    continue
                if len(FE) and np.any(np.abs(FE @ y - fe) > 1e-8):
                    continue
                val = objective(A, b, C, d, y)
                if val < best_val - 1e-15:
                    best, best_val = y, val
        x = best
        eq_s = A @ x - b
        in_s = np.maximum(C @ x - d, 0.0)
        norms.append(float(np.sqrt(eq_s @ eq_s + in_s @ in_s)))
        FE = np.vstack([FE, A])
        fe = np.concatenate([fe, A @ x])
        FI = np.vstack([FI, C])
        fi = np.concatenate([fi, d + in_s])
    return x, norms


def _eq_lsq(M, r, E, e, damping, tol):
    """argmin |M y - r|^2 + damping |y|^2 s.t. E y = e (None if E y = e inconsistent)."""
    n = M.shape[1]
    if len(E):
        U, S, Vt = np.linalg.svd(E)
        rank = int(np.sum(S > 1e-10 * max(1.0, S[0])))
        y0 = Vt[:rank].T @ ((U[:, :rank].T @ e) / S[:rank])
        if np.linalg.norm(E @ y0 - e) > tol * max(1.0, np.linalg.norm(e)) * 10:
            return None
        Z = Vt[rank:].T
    else:
        y0 = np.zeros(n)
        Z = np.eye(n)
    if Z.shape[1] == 0:
        return y0
    K = np.vstack([M @ Z, np.sqrt(damping) * Z])
    t = np.concatenate([r - M @ y0, -np.sqrt(damping) * y0])
    z, *_ = np.linalg.lstsq(K, t, rcond=None)
    return y0 + Z @ z


# ---------------------------------------------------------------- closed-form fast path
@dataclass(frozen=True)
class SaturatedResult:
    """Outcome of :meth:`SaturatedNullSpaceHQP.solve`.

    ``slacks``: level 1 ``|max(G x - h, 0)|`` then ``|A_k x - b_k|`` per equality level;
    ``n_active``: level-1 rows at their bound; ``iterations``: saturation passes;
    ``fallback``: the OSQP cascade produced ``x``; ``active_set``: the dual active-set
    cascade did (``iterations`` are then its active-set iterations).
    """

    x: np.ndarray
    slacks: tuple[float, ...]
    n_active: int
    iterations: int
    saturated: int
    fallback: bool
    active_set: bool = False


class SaturatedNullSpaceHQP:
    """Fast prioritized solver for the executor's structure: one *inequality* level on
    top (``G x <= h``: joint/velocity limits, velocity dampers) and equality levels
    below (``A_k x = b_k``, k = 2..p).

    Method (an active-set variant of the lexicographic QP of Kanoun et al., in the
    spirit of the *Saturation in the Null Space* scheme of Flacco, De Luca, Khatib
    2012):

    1. solve the equality levels in closed form by successive null-space projections,
       ``x_k = x_{k-1} + (A_k N_{k-1})^# (b_k - A_k x_{k-1})``,
       ``N_k = N_{k-1} - (A_k N_{k-1})^# (A_k N_{k-1})`` (rank-revealing SVD, tiny
       damping ``damping`` on the kept singular values);
    2. if ``G x <= h + tol`` the result *is* the lexicographic optimum (the level-1
       inequalities are inactive, so levels 2..p are plain equality tasks);
    3. otherwise the levels are added one at a time and every row violated by the
       solution so far is *saturated*: held at its bound as an equality placed just
       above the level that pushed it (rows already violated at ``x = 0``, ``h < 0``,
       above all tasks), and the stage is repeated until nothing new is violated (at
       most ``max_iter`` passes per level); a row pushed by the hand task thus never
       takes freedom from the feet; at most ``max_add`` rows (the most violated) are
       saturated per pass, so rows whose violation disappears once others are held are
       not saturated needlessly a pass of stage ``k`` restarts from the cached
       ``(x, Z)`` after the stages above it (unchanged within the stage: only the new
       saturated rows and level ``k`` are solved again);
    4. if rows are still violated (inconsistent saturated set), the OSQP cascade
       :class:`HierarchicalQP` (``fallback``) is solved on the level-1 rows within
       ``fallback_margin`` of activity, level 1 tightened by ``fallback_tighten`` so its
       tolerance cannot leave a row violated; its active set seeds more exact
       saturation passes and the candidate of least violation is kept (without a
       fallback: the least-violation iterate);
    5. if a row with ``h >= 0`` is still violated, the step is scaled down,
       ``x <- x_1 + alpha (x - x_1)`` with the largest ``alpha`` in [0, 1] satisfying
       those rows, ``x_1`` the closed-form solution of the first equality level alone
       when it meets level 1, else ``0`` (task scaling: ``x_1`` resp. ``x = 0`` is
       feasible for them), so joint limits and dampers hold even then and the first
       level (feet, COG) keeps its exact solution whenever it can;
    6. lexicographic order among level-1 points: when a fallback candidate holds the first
       equality level only approximately (OSQP's tolerance, or saturated rows held as
       equalities above it), the step is scaled from the first level's own solution
       (closed form, its level-1 rows saturated if needed) toward the candidate moved onto
       that level's solution set, so the feet and the COG never keep a residual while a
       lower level is infeasible (their error does not accumulate: position feedback
       removes the linearisation error of the previous step exactly).

    Simplifications with respect to Kanoun's lexicographic QP (named as required):
    rows are only ever *added* to the saturated set within a step (no release test on
    the sign of the multipliers), so when a saturated row would be inactive at the
    exact optimum the result is feasible and respects the priorities of levels 2..p
    among themselves but may be slightly sub-optimal for them; all violated joint rows
    are saturated at once (only the most violated damper row per robot shape); an
    inconsistent saturated set goes to the OSQP fallback rather than being solved in
    closed form, and step 5 (scaling) trades the lower levels' progress for level 1
    when nothing else satisfies it.
    """

    def __init__(self, max_iter: int = 30, tol: float = 1e-9, rank_tol: float = 1e-8,
                 damping: float = 1e-6, active_tol: float = 1e-7, saturated_rank_tol: float = 1e-2,
                 fallback_margin: float = 0.01, fallback_tighten: float = 1e-5, max_add: int = 3,
                 active_set_min_rows: int = 24) -> None:
        self.active_set_min_rows = int(active_set_min_rows)
        self.max_iter = int(max_iter)
        self.saturated_rank_tol = float(saturated_rank_tol)
        self.fallback_margin = float(fallback_margin)
        self.fallback_tighten = float(fallback_tighten)
        self.max_add = int(max_add)
        self.tol = float(tol)
        self.rank_tol = float(rank_tol)
        self.damping = float(damping)
        self.active_tol = float(active_tol)
        self.fallbacks = 0

    def equality_cascade(self, levels: Sequence[tuple[np.ndarray, np.ndarray]], n: int,
                         exact_first: bool = False, states: list | None = None) -> np.ndarray:
        """Closed-form hierarchy of equality levels ``[(A_k, b_k)]`` (first = highest).

        Works on an orthonormal basis ``Z_k`` of the null space of the levels above
        (``x = x_{k-1} + Z_{k-1} y``), so every SVD is of the reduced ``A_k Z_{k-1}``
        (``m_k x dim``) and the dimension shrinks level by level; equivalent to the
        projector form ``N_k = N_{k-1} - (A_k N_{k-1})^+ A_k N_{k-1}`` with ``N = Z Z^T``.
        Singular values below ``rank_tol * max(s_1, 1)`` are dropped (their directions
        stay free for the lower levels), the kept ones are inverted with the damping
        ``s / (s^2 + damping^2)`` (``exact_first``: the first level without damping).
        ``states`` (optional list) receives ``(x_k, Z_k)`` after every non-empty level
        (``Z`` is ``None`` after the last one): the cached start of later stages.
        """
        x, Z = np.zeros(n), None
        nonempty = [k for k, (A, _) in enumerate(levels) if A is not None and len(A)]
        for k in nonempty:
            A, b = levels[k]
            x, Z = self._stage(x, Z, A, b, exact_first and k == 0, k != nonempty[-1])
            if states is not None:
                states.append((x, Z))
            if Z is not None and Z.shape[1] == 0:
                break
        return x

    def _stage(self, x: np.ndarray, Z: np.ndarray | None, A: np.ndarray, b: np.ndarray, exact: bool,
               need_z: bool) -> tuple[np.ndarray, np.ndarray | None]:
        """One level of the cascade from ``(x, Z)``: ``x + Z (A Z)^# (b - A x)`` and the basis of
        the remaining null space (``need_z``; ``Z is None``: the whole space)."""
        if A is None or len(A) == 0:
            return x, Z
        M = A if Z is None else A @ Z
        if M.shape[1] == 0:
            return x, Z
        U, S, Vt = np.linalg.svd(M, full_matrices=need_z)
        tol = self.saturated_rank_tol if exact else self.rank_tol
        r = int(np.count_nonzero(S > tol * max(S[0], 1.0))) if len(S) else 0
        if r:
            Sr = S[:r]
            inv = 1.0 / Sr if exact else Sr / (Sr * Sr + self.damping * self.damping)
            y = Vt[:r].T @ (inv * (U[:, :r].T @ (b - A @ x)))
            x = x + (y if Z is None else Z @ y)
        if not need_z:
            return x, None
        Zk = Vt[r:].T
        return x, (Zk if Z is None else Z @ Zk)

    def _cascade_staged(self, G, h, S, levels, n):
        """Cascade ``[S_0, L_1, S_1, L_2, ...]``: the rows saturated because of level ``k``
        (``S[k]`` boolean masks) sit right above level ``k``, below the higher levels.
        (Reference form of the cached stages of :meth:`_saturate`.)"""
        stack = []
        if np.any(S[0]):
            stack.append((G[S[0]], h[S[0]]))
        for k, lv in enumerate(levels):
            if np.any(S[k + 1]):
                stack.append((G[S[k + 1]], h[S[k + 1]]))
            stack.append(lv)
        return self.equality_cascade(stack, n, exact_first=bool(np.any(S[0])))

    def _many_rows(self, h: np.ndarray, groups: np.ndarray | None) -> bool:
        """Enough grouped (damper) rows that the saturation passes would be slow or cycle:
        the active-set cascade goes first."""
        n = len(h) if groups is None else int(np.count_nonzero(groups >= 0))
        return n >= self.active_set_min_rows

    def _try_active_set(self, active_set: "ActiveSetCascade", G, h, levels) -> "SaturatedResult | None":
        """The exact cascade's answer when it solved every level within ``tol``, else None."""
        res = active_set.solve(G, h, levels)
        if not res.ok or (len(h) and float((G @ res.x - h).max()) > self.tol):
            return None
        return self._result(G, h, levels, res.x, res.iterations, 0, False, active_set=True)

    def _scale_into(self, G: np.ndarray, h: np.ndarray, base: np.ndarray, x: np.ndarray) -> np.ndarray:
        """``base + alpha (x - base)`` with the largest ``alpha`` in [0, 1] keeping the rows with
        ``h >= 0`` that ``base`` satisfies (``x`` itself when none is violated)."""
        g0 = G @ base
        dg = G @ x - g0
        over = (g0 + dg > h + self.tol) & (h >= -self.tol) & (dg > 0.0)
        if not np.any(over):
            return x
        alpha = float(np.min(np.maximum(h[over] - g0[over], 0.0) / dg[over]))
        return base + min(max(alpha, 0.0), 1.0) * (x - base)

    @staticmethod
    def _onto_first_level(x: np.ndarray, levels) -> np.ndarray:
        """``x`` moved (least norm) onto the solution set of the first equality level
        ``A_1 x = b_1`` (the feet and the COG in the executor): an approximate answer
        (OSQP's tolerance, or one found with the lower levels pulling hard) must not leave
        a residual on the top task, which would show as a foot drifting while a lower task
        is infeasible. No-op without levels."""
        if not levels or levels[0][0] is None or not len(levels[0][0]):
            return x
        A, b = levels[0]
        r = A @ x - b
        if not np.any(np.abs(r) > 0.0):
            return x
        return x - np.linalg.lstsq(A, r, rcond=1e-10)[0]

    def _new_rows(self, viol, W, groups):
        new = (viol > self.tol) & ~W
        if groups is not None and np.any(new):
            cand = np.flatnonzero(new)
            g = groups[cand]
            grouped = cand[g >= 0]
            if len(grouped):
                order = grouped[np.argsort(-viol[grouped], kind="stable")]
                _, first = np.unique(groups[order], return_index=True)
                new = np.zeros(len(viol), dtype=bool)
                new[cand[g < 0]] = True
                new[order[first]] = True
        if self.max_add and np.count_nonzero(new) > self.max_add:
            idx = np.flatnonzero(new)
            keep = idx[np.argsort(-viol[idx], kind="stable")[: self.max_add]]
            new = np.zeros(len(viol), dtype=bool)
            new[keep] = True
        return new

    def _saturate(self, G, h, levels, n, W0, groups, states=None):
        """Staged saturation: (best x, its max violation, passes, saturated mask).

        Rows violated at ``x = 0`` (``h < 0``) and those of ``W0`` are saturated above
        every task; then the levels are added one by one and the rows their solution
        violates are saturated *just above that level* (a row pushed by the hand task
        never constrains the feet), each stage repeated until no new row is violated.

        The cascade is cached: a pass of stage ``k`` only redoes ``[S_{k+1}, L_k]`` from
        the state ``(x, Z)`` reached after ``[S_0, L_0, ..., S_k, L_{k-1}]`` (unchanged
        within the stage), the same numbers as :meth:`_cascade_staged` for ``levels[:k+1]``.
        ``states``: the ``(x, Z)`` after each level of the unconstrained cascade."""
        m = len(h)
        nl = len(levels)
        S = [np.zeros(m, dtype=bool) for _ in range(nl + 1)]
        S[0] = W0 | (h < -self.tol)
        W = S[0].copy()
        best_x, best_v = None, np.inf
        it = 0
        base = (np.zeros(n), None)
        if np.any(S[0]):
            base = self._stage(base[0], None, G[S[0]], h[S[0]], True, True)
        for k in range(nl):
            last = k == nl - 1
            if (states is not None and not last and not np.any(W)
                    and float((G @ states[k][0] - h).max(initial=0.0)) <= self.tol):
                base = states[k]   # levels <= k alone violate nothing: no stage needed yet
                continue
            A, b = levels[k]
            stale = False
            for _ in range(self.max_iter):
                it += 1
                x, Z = base
                if np.any(S[k + 1]):
                    x, Z = self._stage(x, Z, G[S[k + 1]], h[S[k + 1]], False, True)
                x, Z = self._stage(x, Z, A, b, False, not last)
                viol = G @ x - h
                vmax = float(viol.max()) if m else 0.0
                if last and vmax < best_v:
                    best_x, best_v = x, vmax
                new = self._new_rows(viol, W, groups)
                stale = bool(np.any(new))
                if not stale:
                    break
                S[k + 1] |= new
                W |= new
            if not last:
                if stale:   # the pass budget ran out after adding rows: the stage with them
                    x, Z = base
                    x, Z = self._stage(x, Z, G[S[k + 1]], h[S[k + 1]], False, True)
                    x, Z = self._stage(x, Z, A, b, False, True)
                base = (x, Z)
        return best_x, best_v, it, W

    def solve(self, G: np.ndarray, h: np.ndarray, levels: Sequence[tuple[np.ndarray, np.ndarray]],
              fallback: HierarchicalQP | None = None, groups: np.ndarray | None = None,
              active_set: "ActiveSetCascade | None" = None) -> SaturatedResult:
        """Level 1 ``G x <= h`` above the equality ``levels`` (see the class docstring).

        ``groups`` (len(h),) ints: violated rows of the same group ``>= 0`` are saturated
        one per pass (the most violated first: e.g. the dampers of one robot shape, whose
        rows are nearly parallel), rows of group ``-1`` all at once (joint limits, which
        never conflict with each other).

        ``active_set``: the exact lexicographic optimum by a cascade of dual active-set QPs
        (:class:`~humanoid_reach_ros.control.active_set.ActiveSetCascade`). When the
        closed-form hierarchy violates a level-1 row and there are at least
        ``active_set_min_rows`` grouped (damper) rows -- a robot among many obstacles, whose
        nearly parallel rows make the saturation passes cycle -- it replaces steps 3-6 (they
        run only if it fails); with fewer rows the saturation passes and their OSQP fallback
        run as before: cheaper there, and their task scaling damps a hierarchy pushed
        against its limits, where the exact optimum of every step can alternate between two
        postures at full joint speed (seen with a hand target 1.6 m out of reach: the COG
        then moves the free arm along weak directions)."""
        n = G.shape[1] if G is not None and G.ndim == 2 and G.shape[1] else next(A.shape[1] for A, _ in levels)
        G = np.zeros((0, n)) if G is None else G
        h = np.zeros(0) if h is None else h
        states: list = []
        x = self.equality_cascade(levels, n, states=states)
        v0 = float((G @ x - h).max()) if len(h) else 0.0
        if v0 <= self.tol:       # no level-1 row active: the unconstrained hierarchy is the optimum
            best_x, best_v, it, W = x, v0, 1, np.zeros(len(h), dtype=bool)
        elif active_set is not None and self._many_rows(h, groups) \
                and (res_as := self._try_active_set(active_set, G, h, levels)) is not None:
            return res_as
        else:
            ok = len(states) == len(levels)     # one state per (non-empty) level
            best_x, best_v, it, W = self._saturate(G, h, levels, n, np.zeros(len(h), dtype=bool), groups,
                                                   states if ok else None)
        used_fallback = False
        if best_v > self.tol and fallback is not None:
            # the saturated set is inconsistent (e.g. nearly parallel damper rows): the OSQP
            # cascade on the rows near activity (the others cannot become active within
            # ``fallback_margin``), with level 1 tightened by ``fallback_tighten`` so that
            # OSQP's tolerance cannot leave a row violated; its active rows also seed more
            # exact saturation passes. The best candidate (least violation) is kept.
            self.fallbacks += 1
            used_fallback = True
            near_mask = G @ best_x - h > -self.fallback_margin
            for _ in range(4):
                near = np.flatnonzero(near_mask)
                Gn, hn = G[near], h[near]
                res = fallback.solve([Level(C=Gn, d=hn - self.fallback_tighten)]
                                     + [Level(A=A, b=b) for A, b in levels], n=n)
                grow = (G @ res.x - h > -self.fallback_margin) & ~near_mask
                if not np.any(grow):
                    break
                near_mask |= grow      # rows left out came near activity: solve again with them
            Wf = np.zeros(len(h), dtype=bool)
            Wf[near[Gn @ res.x - hn >= -2.0 * self.fallback_tighten]] = True
            x_f, v_f, it_f, W_f = self._saturate(G, h, levels, n, Wf, groups)
            it += it_f
            x_o = self._onto_first_level(res.x, levels)
            v_o = float((G @ x_o - h).max(initial=-np.inf))
            if v_f <= self.tol or v_f <= v_o:
                if v_f < best_v:
                    best_x, best_v, W = x_f, v_f, W_f
            elif v_o < best_v:
                best_x, best_v = x_o, v_o
        first = None    # the first level's own solution on level 1 (closed form, rows saturated if needed)
        if (used_fallback or best_v > self.tol) and states and len(states) == len(levels):
            first = states[0][0]
            if len(h) and float((G @ first - h).max()) > self.tol:
                x1, v1, _, _ = self._saturate(G, h, levels[:1], n, np.zeros(len(h), dtype=bool), groups)
                first = x1 if x1 is not None and v1 <= self.tol else None
        if first is not None and best_v <= self.tol:
            # lexicographic order: among points of level 1, the first equality level (feet,
            # COG) comes before everything below it. A fallback candidate may hold it only
            # approximately (OSQP's tolerance; saturated rows held as equalities above it):
            # then scale from the first level's own solution toward the candidate moved onto
            # that level's solution set, which keeps the first level exactly.
            A1, b1 = levels[0]
            if float(np.linalg.norm(A1 @ best_x - b1)) > self.tol:
                x_s = self._scale_into(G, h, first, self._onto_first_level(best_x, levels))
                v_s = float((G @ x_s - h).max()) if len(h) else 0.0
                if v_s <= self.tol:
                    best_x, best_v = x_s, v_s
        if best_v > self.tol and len(h):
            # last resort, task scaling: x = 0 satisfies every row with h >= 0, so the
            # largest alpha in [0, 1] keeping those rows gives a point of level 1 (rows
            # with h < 0, e.g. a damper already inside d_s, keep their least violation)
            # the step is scaled from the first level's own solution when that one meets
            # level 1 (the feet/COG then stay exact and only the lower levels are scaled)
            base = np.zeros(n)
            if first is not None:
                base = first
                best_x = self._onto_first_level(best_x, levels)   # both ends on the first level's set
            x_s = self._scale_into(G, h, base, best_x)
            if x_s is not best_x:
                # rows with h >= 0 (joint limits, dampers outside d_s) are kept exactly; a
                # damper already inside d_s may miss its push-away for this step
                best_x, best_v = x_s, float((G @ x_s - h).max())
                used_fallback = True
        return self._result(G, h, levels, best_x, it, int(np.count_nonzero(W)), used_fallback)

    def _result(self, G, h, levels, x: np.ndarray, iterations: int, saturated: int, fallback: bool,
                active_set: bool = False) -> SaturatedResult:
        """``x`` with its slacks per level and its active level-1 rows."""
        viol = G @ x - h
        slacks = [float(np.linalg.norm(np.maximum(viol, 0.0)))]
        slacks += [float(np.linalg.norm(A @ x - b)) for A, b in levels]
        n_active = int(np.count_nonzero(viol >= -self.active_tol))
        return SaturatedResult(x, tuple(slacks), n_active, iterations, saturated, fallback, active_set)


__all__ = ["Level", "LevelReport", "HQPResult", "HierarchicalQP", "solve_dense_reference",
           "SaturatedResult", "SaturatedNullSpaceHQP"]
