"""Shared pieces of the sampling-based planners: space, results, edges, shortcutting.

The lower layer of :mod:`.path`: :mod:`.rrt_connect` and :mod:`.prm` import from here,
:mod:`.path` re-exports everything and adds the dispatch :func:`~.path.plan` (no import cycle).

The planners (:mod:`.rrt_connect`, :mod:`.prm`) are generic: they work in a
box-bounded configuration space ``R^d`` (for the robot ``d = 10``,
``q_plan = (q_arm, z_t, rpy_t)``, Kanehiro et al. eq. (2)) and only see a batched
validity checker ``is_valid_batch(Q: (n, d)) -> (n,) bool``.

Metric and edge resolution (:class:`PlanningSpace`)::

    d(a, b) = || W (a - b) ||_2 ,   W = diag(weights)

An edge ``a -> b`` is a straight segment in configuration space, discretised into
``m = max(1, ceil(d(a, b) / resolution))`` steps, i.e. ``m + 1`` configurations
``a + (i / m) (b - a)``, so that neighbouring checked configurations are at most
``resolution`` apart *in the weighted metric*. An edge is valid when every one of
those configurations is valid. Edges are always checked with one call of the checker
per edge (:func:`check_edge`) or per batch of edges (:func:`check_edges`), never
configuration by configuration.
"""
from __future__ import annotations

import enum
import functools
import math
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

ValidityFn = Callable[[np.ndarray], np.ndarray]
"""``is_valid_batch(Q: (n, d) float array) -> (n,) bool array``."""

PLANNER_NAMES = ("rrt_connect", "prm", "modified_prm")


# ------------------------------------------------------------------ space
@dataclass(frozen=True, eq=False)
class PlanningSpace:
    """Box-bounded configuration space with a weighted Euclidean metric.

    ``lower``/``upper``: per-dimension bounds ``(d,)``; ``weights``: ``W`` of the
    metric ``d(a, b) = ||W (a - b)||_2`` (default all ones); ``resolution``: the
    largest weighted distance between neighbouring configurations checked on an edge.
    """

    lower: np.ndarray
    upper: np.ndarray
    weights: np.ndarray | None = None
    resolution: float = 0.02

    def __post_init__(self) -> None:
        lo = np.asarray(self.lower, dtype=float).reshape(-1)
        hi = np.asarray(self.upper, dtype=float).reshape(-1)
        if lo.shape != hi.shape or np.any(hi < lo):
            raise ValueError("lower/upper must have the same shape and lower <= upper")
        w = np.ones_like(lo) if self.weights is None else np.asarray(self.weights, dtype=float).reshape(-1)
        if w.shape != lo.shape or np.any(w <= 0):
            raise ValueError("weights must be positive, one per dimension")
        if not self.resolution > 0:
            raise ValueError("resolution must be > 0")
        object.__setattr__(self, "lower", lo)
        object.__setattr__(self, "upper", hi)
        object.__setattr__(self, "weights", w)

    @property
    def dim(self) -> int:
        return int(self.lower.shape[0])

    def distance(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """``||W (a - b)||_2`` broadcast over leading dimensions."""
        diff = (np.asarray(a, dtype=float) - np.asarray(b, dtype=float)) * self.weights
        return np.sqrt(np.einsum("...i,...i->...", diff, diff))

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """``n`` uniform samples in the box, shape ``(n, d)``."""
        return self.lower + rng.random((n, self.dim)) * (self.upper - self.lower)

    def in_bounds(self, Q: np.ndarray, tol: float = 1e-9) -> np.ndarray:
        Q = np.atleast_2d(Q)
        return np.all((Q >= self.lower - tol) & (Q <= self.upper + tol), axis=-1)

    def path_length(self, path: np.ndarray) -> float:
        """Sum of ``d(q_i, q_{i+1})`` along a ``(k, d)`` path."""
        path = np.asarray(path, dtype=float)
        if len(path) < 2:
            return 0.0
        return float(np.sum(self.distance(path[1:], path[:-1])))


# ------------------------------------------------------------------ results
class PlanStatus(str, enum.Enum):
    """Outcome of a planning request (the failure reasons of the brief)."""

    SUCCESS = "SUCCESS"
    TIMED_OUT = "TIMED_OUT"          # time budget or iteration budget exhausted
    NO_PATH = "NO_PATH"              # search finished (e.g. roadmap disconnected)
    START_INVALID = "START_INVALID"
    GOALS_INVALID = "GOALS_INVALID"  # every goal invalid or out of bounds


@dataclass(frozen=True)
class PlanStats:
    iterations: int = 0
    nodes: int = 0
    check_calls: int = 0
    checked_configs: int = 0
    time_s: float = 0.0


@dataclass(frozen=True, eq=False)
class PlanResult:
    """``path`` is ``(k, d)`` from the start to ``goals[goal_index]`` on success, else ``None``."""

    status: PlanStatus
    path: np.ndarray | None = None
    goal_index: int | None = None
    stats: PlanStats = field(default_factory=PlanStats)

    @property
    def success(self) -> bool:
        return self.status is PlanStatus.SUCCESS


class CountingChecker:
    """Wraps ``is_valid_batch`` and counts calls and configurations checked."""

    def __init__(self, is_valid_batch: ValidityFn) -> None:
        self._fn = is_valid_batch
        self.calls = 0
        self.configs = 0

    def __call__(self, Q: np.ndarray) -> np.ndarray:
        Q = np.atleast_2d(np.asarray(Q, dtype=float))
        if len(Q) == 0:
            return np.zeros(0, dtype=bool)
        self.calls += 1
        self.configs += len(Q)
        out = np.asarray(self._fn(Q), dtype=bool).reshape(-1)
        if out.shape[0] != Q.shape[0]:
            raise ValueError("is_valid_batch must return one bool per configuration")
        return out

    @property
    def edge_fn(self):
        """The wrapped checker's ``first_invalid_edge`` (counted), or ``None``."""
        fn = getattr(self._fn, "first_invalid_edge", None)
        if fn is None:
            return None

        def counted(A, B, m, include_endpoints):
            e = int(fn(A, B, m, include_endpoints))
            self.calls += 1
            self.configs += int(getattr(self._fn, "last_examined", 0))
            return e
        return counted

    def first_invalid(self, Q: np.ndarray) -> int:
        """:func:`first_invalid` through the wrapped checker; counts the configurations
        actually examined (up to and including the first invalid one)."""
        Q = np.atleast_2d(np.asarray(Q, dtype=float))
        if len(Q) == 0:
            return 0
        k = first_invalid(self._fn, Q)
        if not 0 <= k <= len(Q):
            raise ValueError("first_invalid must return an index in [0, len(Q)]")
        self.calls += 1
        self.configs += min(k + 1, len(Q))
        return k


def first_invalid(checker: ValidityFn, Q: np.ndarray) -> int:
    """Index of the first invalid configuration of ``Q`` (``len(Q)`` if all are valid).

    A checker may provide ``first_invalid(Q) -> int`` that stops at the first invalid
    configuration (the robot's does: :meth:`ReachPlanner.validity_fn`); otherwise the
    whole batch is checked. Either way the answer is the same."""
    fn = getattr(checker, "first_invalid", None)
    if fn is not None:
        return int(fn(Q))
    ok = np.asarray(checker(Q), dtype=bool)
    return len(ok) if ok.all() else int(np.argmin(ok))


def as_counting(checker: ValidityFn) -> CountingChecker:
    return checker if isinstance(checker, CountingChecker) else CountingChecker(checker)


class Deadline:
    """Wall-clock budget: ``expired()`` once ``max_time_s`` has passed since creation."""

    def __init__(self, max_time_s: float | None) -> None:
        self.t0 = time.perf_counter()
        self.max_time_s = math.inf if max_time_s is None else float(max_time_s)

    def elapsed(self) -> float:
        return time.perf_counter() - self.t0

    def expired(self) -> bool:
        return self.elapsed() > self.max_time_s


def validate_endpoints(start: np.ndarray, goals: np.ndarray, checker: CountingChecker,
                       space: PlanningSpace) -> tuple[np.ndarray, np.ndarray, np.ndarray, PlanStatus | None]:
    """Check start and goals in one call; return ``(start, goals, valid_goal_idx, failure)``."""
    start = np.asarray(start, dtype=float).reshape(-1)
    goals = np.atleast_2d(np.asarray(goals, dtype=float))
    if start.shape[0] != space.dim or goals.shape[1] != space.dim:
        raise ValueError(f"start and goals must have dimension {space.dim}")
    Q = np.vstack([start[None], goals])
    ok = checker(Q) & space.in_bounds(Q)
    valid_goals = np.flatnonzero(ok[1:])
    if not ok[0]:
        return start, goals, valid_goals, PlanStatus.START_INVALID
    if len(valid_goals) == 0:
        return start, goals, valid_goals, PlanStatus.GOALS_INVALID
    return start, goals, valid_goals, None


# ------------------------------------------------------------------ edges
def edge_steps(a: np.ndarray, b: np.ndarray, space: PlanningSpace) -> np.ndarray:
    """Number of steps ``m = max(1, ceil(d(a, b) / resolution))`` (broadcast)."""
    d = space.distance(a, b)
    return np.maximum(1, np.ceil(d / space.resolution - 1e-9)).astype(int)


def interpolate_edge(a: np.ndarray, b: np.ndarray, space: PlanningSpace) -> np.ndarray:
    """Configurations ``a + (i/m)(b - a)``, ``i = 0..m``, shape ``(m + 1, d)``."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    m = int(edge_steps(a, b, space))
    s = np.arange(m + 1)[:, None] / m
    return a + s * (b - a)


def interpolate_path(path: np.ndarray, space: PlanningSpace) -> np.ndarray:
    """Every configuration checked along a path at the space resolution (endpoints included)."""
    path = np.atleast_2d(np.asarray(path, dtype=float))
    if len(path) < 2:
        return path.copy()
    parts = [interpolate_edge(path[i], path[i + 1], space)[:-1] for i in range(len(path) - 1)]
    return np.vstack(parts + [path[-1:]])


def _edges_points(A: np.ndarray, B: np.ndarray, space: PlanningSpace,
                  include_endpoints: bool) -> tuple[np.ndarray, np.ndarray]:
    """Stacked interpolation of the edges ``A[e] -> B[e]`` and the per-edge counts."""
    m = edge_steps(A, B, space)
    first = 0 if include_endpoints else 1
    counts = m + 1 if include_endpoints else m - 1
    total = int(counts.sum())
    edge_of = np.repeat(np.arange(len(A)), counts)
    offsets = np.cumsum(counts) - counts
    i = np.arange(total) - np.repeat(offsets, counts) + first
    s = (i / m[edge_of])[:, None]
    return A[edge_of] + s * (B[edge_of] - A[edge_of]), counts


@functools.lru_cache(maxsize=1024)
def bisect_order(n: int) -> np.ndarray:
    """A permutation of ``range(n)`` that refines coarse to fine: the middle point
    first, then the middles of both halves, and so on (breadth-first), both ends last.

    An obstacle crossed by an edge blocks a run of neighbouring points; visiting the
    points in this order meets such a run after a few checks instead of after every
    point before it (the ordering lesson of VAMP, Thomason et al. 2024). Read-only."""
    if n <= 0:
        return np.zeros(0, dtype=np.int64)
    out: list[int] = []
    queue = [(0, n - 1)]
    head = 0
    while head < len(queue):
        lo, hi = queue[head]
        head += 1
        if hi - lo < 2:
            continue
        mid = (lo + hi) // 2
        out.append(mid)
        queue.append((lo, mid))
        queue.append((mid, hi))
    out += [0] if n == 1 else [0, n - 1]
    order = np.array(out, dtype=np.int64)
    order.setflags(write=False)
    return order


def _within_edge_order(counts: np.ndarray) -> np.ndarray:
    """Permutation of stacked edge points (edge by edge, in order) that visits each
    edge's points in :func:`bisect_order`; edges keep their order."""
    offsets = np.cumsum(counts) - counts
    return np.concatenate([o + bisect_order(int(c)) for o, c in zip(offsets.tolist(), counts.tolist())])


#: the first chunks :func:`_first_invalid_in_chunks` hands an early-exit checker (then the rest)
PREFIX_CHUNKS = (1, 8)


def _first_invalid_in_chunks(checker: ValidityFn, Q: np.ndarray) -> int:
    """:func:`first_invalid` of ``Q`` (the same answer), for a checker that stops at the first
    invalid configuration (``first_invalid``), handed ``Q`` in chunks -- its first row, the next
    8, then the rest -- until one holds an invalid row. The robot's checker without a fused
    kernel (the G1's numerical legs) solves the legs of every row it is handed before its
    collision check stops: on three of the generality suite's cases, 70 % of the G1's edge
    checks met an invalid point, the first of their coarse-to-fine order in 3 of 4 of them.
    A checker without ``first_invalid`` gets ``Q`` whole (it checks every row anyway)."""
    inner = checker._fn if isinstance(checker, CountingChecker) else checker
    if getattr(inner, "first_invalid", None) is None or len(Q) <= PREFIX_CHUNKS[0] + 1:
        return first_invalid(checker, Q)
    start = 0
    for size in PREFIX_CHUNKS + (len(Q),):
        stop = min(start + size, len(Q))
        k = first_invalid(checker, Q[start:stop])
        if k < stop - start or stop == len(Q):
            return start + k
        start = stop
    return len(Q)


def check_edges(A: np.ndarray, B: np.ndarray, checker: ValidityFn, space: PlanningSpace,
                include_endpoints: bool = False, max_configs_per_call: int = 200_000,
                prefix: bool = False) -> np.ndarray:
    """Validity of the straight edges ``A[e] -> B[e]``, shape ``(n_edges,)``.

    All interior points of all edges (and the endpoints when ``include_endpoints``)
    are checked with as few checker calls as possible (one unless more than
    ``max_configs_per_call`` configurations are needed).

    ``prefix=True`` is for callers that only use the edges before the first invalid
    one (RRT CONNECT/EXTEND, shortcuts, "is the whole chain valid"): the points are
    checked through :func:`first_invalid`, which may stop at the first invalid point,
    edge after edge, each edge's points in :func:`bisect_order` (coarse to fine: a
    blocked edge is found after a few points); the edge holding the first invalid
    point met is the first invalid edge (every point of the edges before it was
    checked valid), and it and every later edge are reported ``False`` (later ones
    unchecked), so ``ok`` is exact up to and including the first ``False``, which is
    all those callers read. Same answer as checking the points in order.
    """
    A = np.atleast_2d(np.asarray(A, dtype=float))
    B = np.atleast_2d(np.asarray(B, dtype=float))
    n = len(A)
    ok = np.ones(n, dtype=bool)
    if n == 0:
        return ok
    m = edge_steps(A, B, space)
    if prefix:
        # a checker that generates and checks the edge points itself (PlanChecker): one call
        edge_fn = checker.edge_fn if isinstance(checker, CountingChecker) else getattr(checker, "first_invalid_edge",
                                                                                        None)
        if edge_fn is not None:
            bad = int(edge_fn(A, B, np.atleast_1d(m), include_endpoints))
            ok[bad:] = False
            return ok
    per_edge = m + 1 if include_endpoints else m - 1
    start = 0
    while start < n:
        # chunk edges so that one call stays below the config budget (at least one edge)
        cum = np.cumsum(per_edge[start:])
        stop = start + max(1, int(np.searchsorted(cum, max_configs_per_call, side="right")))
        pts, counts = _edges_points(A[start:stop], B[start:stop], space, include_endpoints)
        if len(pts) and prefix:
            perm = _within_edge_order(counts)
            k = _first_invalid_in_chunks(checker, pts[perm])
            if k < len(pts):
                bad = start + int(np.searchsorted(np.cumsum(counts), perm[k], side="right"))
                ok[bad:] = False
                return ok
        elif len(pts):
            valid = checker(pts)
            bad_edge = np.repeat(np.arange(stop - start), counts)[~valid]
            ok[start + np.unique(bad_edge)] = False
        start = stop
    return ok


def check_edge(a: np.ndarray, b: np.ndarray, checker: ValidityFn, space: PlanningSpace,
               include_endpoints: bool = False) -> bool:
    """Validity of one straight edge ``a -> b`` (one checker call, stops at the first invalid point)."""
    return bool(check_edges(np.asarray(a)[None], np.asarray(b)[None], checker, space, include_endpoints,
                            prefix=True)[0])


def check_path(path: np.ndarray, checker: ValidityFn, space: PlanningSpace) -> bool:
    """Every waypoint and every interpolated configuration valid (one call)."""
    return bool(np.all(checker(interpolate_path(path, space))))


# ------------------------------------------------------------------ post-processing
@dataclass(frozen=True)
class ShortcutOptions:
    """Random shortcutting budget: ``max_iterations`` attempts or ``max_time_s`` seconds."""

    max_iterations: int = 100
    max_time_s: float = 0.2
    remove_redundant: bool = True


def remove_redundant_waypoints(path: np.ndarray, checker: ValidityFn, space: PlanningSpace) -> np.ndarray:
    """Drop waypoint ``q_k`` when the straight edge ``q_prev -> q_{k+1}`` is valid.

    Duplicates are dropped without checks. By the triangle inequality of the metric,
    the length never increases. One checker call per interior waypoint at most.
    """
    path = np.atleast_2d(np.asarray(path, dtype=float))
    if len(path) <= 2:
        return path.copy()
    keep = [path[0]]
    for k in range(1, len(path) - 1):
        if space.distance(keep[-1], path[k]) <= 1e-12:
            continue
        if not check_edge(keep[-1], path[k + 1], checker, space):
            keep.append(path[k])
    if space.distance(keep[-1], path[-1]) > 1e-12 or len(keep) == 1:
        keep.append(path[-1])
    return np.array(keep)


def _point_at(path: np.ndarray, cum: np.ndarray, s: float) -> tuple[int, np.ndarray]:
    """Segment index ``i`` and point at arc length ``s`` (``cum[i] <= s <= cum[i+1]``)."""
    i = int(np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(path) - 2))
    seg = cum[i + 1] - cum[i]
    t = 0.0 if seg <= 0 else (s - cum[i]) / seg
    return i, path[i] + t * (path[i + 1] - path[i])


def shortcut_path(path: np.ndarray, checker: ValidityFn, space: PlanningSpace,
                  rng: np.random.Generator, options: ShortcutOptions = ShortcutOptions()) -> np.ndarray:
    """Random shortcutting.

    Pick arc lengths ``s1 < s2`` uniformly, the points ``p1 = q(s1)`` on segment ``i``
    and ``p2 = q(s2)`` on segment ``j > i``; replace ``q_{i+1} .. q_j`` by
    ``p1, p2`` when the edges ``q_i -> p1``, ``p1 -> p2``, ``p2 -> q_{j+1}`` are all
    valid (one checker call; the two pieces of old edges are rechecked because
    their discretisation differs from the old one). A valid path stays valid and
    never gets longer (triangle inequality).
    """
    path = np.atleast_2d(np.asarray(path, dtype=float)).copy()
    deadline = Deadline(options.max_time_s)
    for _ in range(options.max_iterations):
        if len(path) < 3 or deadline.expired():
            break
        cum = np.concatenate([[0.0], np.cumsum(space.distance(path[1:], path[:-1]))])
        s1, s2 = np.sort(rng.random(2) * cum[-1])
        i, p1 = _point_at(path, cum, s1)
        j, p2 = _point_at(path, cum, s2)
        if j <= i:
            continue
        new_len = space.distance(path[i], p1) + space.distance(p1, p2) + space.distance(p2, path[j + 1])
        if new_len >= cum[j + 1] - cum[i] - 1e-12:
            continue
        A = np.array([path[i], p1, p2])
        B = np.array([p1, p2, path[j + 1]])
        if np.all(check_edges(A, B, checker, space, include_endpoints=True, prefix=True)):
            path = np.vstack([path[: i + 1], p1, p2, path[j + 1:]])
    if options.remove_redundant:
        path = remove_redundant_waypoints(path, checker, space)
    return path
