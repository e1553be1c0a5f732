"""Probabilistic roadmaps: PRM (Kavraki et al. 1996) and the modified PRM (Das, 003).

Roadmap construction (batched; the order of the pseudo-code does not matter for
the resulting graph)::

    V = N valid uniform samples                       (one checker call per batch)
    E = { (u, v) : v in Near(u) , edge u -> v valid }

* ``variant="prm"``: ``Near(u) = { v : d(u, v) <= r }``;
* ``variant="modified_prm"``: the same set limited to the ``max_neighbors`` nearest
  (Das: "nearest neighbours are found within a radius and limited to
  max_neighbors"), which bounds the density of the graph and the number of edge checks.

Default radius when ``connection_radius`` is ``None`` (PRM*, Karaman & Frazzoli)::

    r = 2 (1 + 1/d)^(1/d) (V_box / zeta_d)^(1/d) (log n / n)^(1/d)

with ``V_box`` the weighted volume of the box and ``zeta_d`` the unit-ball volume.

Query: start and goals are connected with the same rule, then Dijkstra from the
start (``scipy.sparse.csgraph``) gives the nearest reachable goal. With ``lazy``
edges are only checked when they lie on a shortest path; invalid ones are removed
and the search is repeated (Bohlin & Kavraki's Lazy PRM).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from humanoid_reach_ros.planning.space import (
    CountingChecker, Deadline, PlanningSpace, PlanResult, PlanStats, PlanStatus, ShortcutOptions,
    ValidityFn, as_counting, check_edges, shortcut_path, validate_endpoints,
)

PRM_VARIANTS = ("prm", "modified_prm")
_UNKNOWN, _VALID, _INVALID = 0, 1, 2


@dataclass(frozen=True)
class PRMOptions:
    """Roadmap size, connection rule, budgets.

    ``num_samples``: valid roadmap nodes wanted; ``max_sample_batches`` bounds the
    sampling effort; ``connection_radius`` ``r`` (weighted metric, ``None``: PRM*
    default); ``max_neighbors`` ``k`` (``modified_prm`` only); ``lazy``: lazy edge checks.
    """

    variant: str = "modified_prm"
    num_samples: int = 500
    connection_radius: float | None = None
    max_neighbors: int = 10
    lazy: bool = False
    sample_batch: int = 500
    max_sample_batches: int = 100
    max_time_s: float = 2.0
    shortcut: ShortcutOptions | None = None

    def __post_init__(self) -> None:
        if self.variant not in PRM_VARIANTS:
            raise ValueError(f"unknown PRM variant {self.variant!r}; expected one of {PRM_VARIANTS}")


@dataclass(frozen=True, eq=False)
class Roadmap:
    """Nodes ``(n, d)``, undirected edges ``(e, 2)`` with lengths and check status."""

    nodes: np.ndarray
    edges: np.ndarray
    lengths: np.ndarray
    status: np.ndarray  # _UNKNOWN / _VALID / _INVALID per edge
    radius: float


def default_radius(space: PlanningSpace, n: int) -> float:
    """PRM* radius ``2 (1+1/d)^(1/d) (V/zeta_d)^(1/d) (log n / n)^(1/d)``."""
    d = space.dim
    vol = float(np.prod((space.upper - space.lower) * space.weights))
    zeta = math.pi ** (d / 2) / math.gamma(d / 2 + 1)
    n = max(n, 2)
    return 2.0 * (1 + 1 / d) ** (1 / d) * (vol / zeta) ** (1 / d) * (math.log(n) / n) ** (1 / d)


def _near_pairs(P: np.ndarray, Q: np.ndarray, space: PlanningSpace, radius: float,
                k: int | None, exclude_self: bool, deadline: Deadline | None = None,
                max_block: int = 2_000_000) -> tuple[np.ndarray, np.ndarray]:
    """Pairs ``(i, j)``: ``Q[j]`` within ``radius`` of ``P[i]``, at most ``k`` nearest per ``i``.

    Distances by blocks of at most ``max_block`` entries; stops early (fewer pairs)
    when ``deadline`` expires.
    """
    chunk = max(1, max_block // max(len(Q), 1))
    w = space.weights
    Pw, Qw = P * w, Q * w
    qq = np.einsum("ij,ij->i", Qw, Qw)
    rows, cols = [], []
    for s in range(0, len(P), chunk):
        if deadline is not None and deadline.expired():
            break
        A = Pw[s:s + chunk]
        d2 = np.einsum("ij,ij->i", A, A)[:, None] + qq[None] - 2 * A @ Qw.T
        if exclude_self:
            d2[np.arange(len(A)), np.arange(s, s + len(A))] = np.inf
        d2[d2 > radius * radius] = np.inf
        if k is not None and k < Q.shape[0]:
            nn = np.argpartition(d2, k - 1, axis=1)[:, :k] if k > 0 else np.zeros((len(A), 0), int)
            r = np.repeat(np.arange(len(A)), nn.shape[1])
            c = nn.reshape(-1)
            keep = np.isfinite(d2[r, c])
            rows.append(r[keep] + s)
            cols.append(c[keep])
        else:
            r, c = np.nonzero(np.isfinite(d2))
            rows.append(r + s)
            cols.append(c)
    if not rows:
        return np.zeros(0, int), np.zeros(0, int)
    return np.concatenate(rows), np.concatenate(cols)


def _unique_edges(i: np.ndarray, j: np.ndarray) -> np.ndarray:
    e = np.stack([np.minimum(i, j), np.maximum(i, j)], axis=1)
    e = e[e[:, 0] != e[:, 1]]
    return np.unique(e, axis=0) if len(e) else e.reshape(0, 2)


def _neighbour_limit(options: PRMOptions) -> int | None:
    return options.max_neighbors if options.variant == "modified_prm" else None


def build_roadmap(is_valid_batch: ValidityFn, space: PlanningSpace, rng: np.random.Generator,
                  options: PRMOptions = PRMOptions(), deadline: Deadline | None = None) -> Roadmap:
    """Sample ``num_samples`` valid nodes and connect them (edges checked unless ``lazy``).

    When ``deadline`` expires the roadmap is returned incomplete (fewer nodes or
    edges, unchecked edges left ``_UNKNOWN``).
    """
    checker = as_counting(is_valid_batch)
    deadline = deadline or Deadline(options.max_time_s)
    found: list[np.ndarray] = []
    n_found = 0
    for _ in range(options.max_sample_batches):
        if n_found >= options.num_samples or deadline.expired():
            break
        Q = space.sample(rng, options.sample_batch)
        Q = Q[checker(Q)]
        found.append(Q)
        n_found += len(Q)
    nodes = np.vstack(found)[: options.num_samples] if found else np.zeros((0, space.dim))
    radius = options.connection_radius or default_radius(space, max(len(nodes), 2))
    i, j = _near_pairs(nodes, nodes, space, radius, _neighbour_limit(options), exclude_self=True,
                       deadline=deadline)
    edges = _unique_edges(i, j)
    lengths = space.distance(nodes[edges[:, 0]], nodes[edges[:, 1]]) if len(edges) else np.zeros(0)
    status = np.full(len(edges), _UNKNOWN, dtype=np.int8)
    if not options.lazy and len(edges) and not deadline.expired():
        ok = check_edges(nodes[edges[:, 0]], nodes[edges[:, 1]], checker, space)
        status[:] = np.where(ok, _VALID, _INVALID)
    return Roadmap(nodes, edges, lengths, status, float(radius))


def query_roadmap(roadmap: Roadmap, start: np.ndarray, goals: np.ndarray, is_valid_batch: ValidityFn,
                  space: PlanningSpace, options: PRMOptions = PRMOptions(),
                  deadline: Deadline | None = None,
                  valid_goals: np.ndarray | None = None) -> tuple[PlanStatus, np.ndarray | None, int | None]:
    """Connect start and (valid) goals to ``roadmap`` and search it.

    Returns ``(status, path, goal_index)``; the roadmap is not modified.
    """
    checker = as_counting(is_valid_batch)
    deadline = deadline or Deadline(options.max_time_s)
    start = np.asarray(start, dtype=float).reshape(-1)
    goals = np.atleast_2d(np.asarray(goals, dtype=float))
    if valid_goals is None:
        valid_goals = np.arange(len(goals))
    n = len(roadmap.nodes)
    ends = np.vstack([start[None], goals[valid_goals]])
    nodes = np.vstack([roadmap.nodes, ends])
    k = _neighbour_limit(options)
    # +1: each end finds itself at distance 0 (the self pair is dropped below)
    i, j = _near_pairs(ends, nodes, space, roadmap.radius, None if k is None else k + 1, exclude_self=False)
    new = _unique_edges(i + n, j)
    # always also try the direct edges start -> goals
    direct = np.stack([np.full(len(valid_goals), n), n + 1 + np.arange(len(valid_goals))], axis=1)
    new = np.unique(np.vstack([new, direct]), axis=0)
    edges = np.vstack([roadmap.edges, new])
    lengths = np.concatenate([roadmap.lengths, space.distance(nodes[new[:, 0]], nodes[new[:, 1]])])
    status = np.concatenate([roadmap.status, np.full(len(new), _UNKNOWN, dtype=np.int8)])
    if not options.lazy and len(new):
        ok = check_edges(nodes[new[:, 0]], nodes[new[:, 1]], checker, space)
        status[len(roadmap.edges):] = np.where(ok, _VALID, _INVALID)
    goal_nodes = n + 1 + np.arange(len(valid_goals))
    while True:
        if deadline.expired():
            return PlanStatus.TIMED_OUT, None, None
        use = status != _INVALID
        e = edges[use]
        # tiny positive weight so that zero-length edges are not dropped as "no edge"
        w = np.maximum(lengths[use], 1e-12)
        graph = coo_matrix((w, (e[:, 0], e[:, 1])), shape=(len(nodes), len(nodes))).tocsr()
        dist, pred = dijkstra(graph, directed=False, indices=n, return_predecessors=True)
        g = int(np.argmin(dist[goal_nodes]))
        if not np.isfinite(dist[goal_nodes[g]]):
            return PlanStatus.NO_PATH, None, None
        seq = [int(goal_nodes[g])]
        while seq[-1] != n:
            seq.append(int(pred[seq[-1]]))
        seq = np.array(seq[::-1])
        # lazy (or incomplete roadmap): check the still unknown edges of this path
        a, b = np.minimum(seq[:-1], seq[1:]), np.maximum(seq[:-1], seq[1:])
        key = edges[:, 0].astype(np.int64) * len(nodes) + edges[:, 1]  # edges unique, sorted per row
        order = np.argsort(key)
        ids = order[np.searchsorted(key[order], a.astype(np.int64) * len(nodes) + b)]
        todo = ids[status[ids] == _UNKNOWN]
        if len(todo):
            ok = check_edges(nodes[edges[todo, 0]], nodes[edges[todo, 1]], checker, space)
            status[todo] = np.where(ok, _VALID, _INVALID)
            if not ok.all():
                continue
        return PlanStatus.SUCCESS, nodes[seq], int(valid_goals[g])


def plan_prm(start: np.ndarray, goals: np.ndarray, is_valid_batch: ValidityFn, space: PlanningSpace,
             rng: np.random.Generator, options: PRMOptions = PRMOptions()) -> PlanResult:
    """Build a roadmap (:func:`build_roadmap`) and query it (:func:`query_roadmap`).

    Same result type and failure reasons as :func:`~.rrt_connect.plan_rrt_connect`;
    ``NO_PATH`` when the roadmap does not connect the start to any goal.
    ``stats.iterations`` and ``stats.nodes``: graph nodes (roadmap, start and valid goals).
    """
    deadline = Deadline(options.max_time_s)
    checker: CountingChecker = as_counting(is_valid_batch)
    start, goals, valid_goals, failure = validate_endpoints(start, goals, checker, space)

    def result(status: PlanStatus, path=None, goal_index=None, nodes=0) -> PlanResult:
        stats = PlanStats(nodes, nodes, checker.calls, checker.configs, deadline.elapsed())
        return PlanResult(status, path, goal_index, stats)

    if failure is not None:
        return result(failure)
    roadmap = build_roadmap(checker, space, rng, options, deadline)
    if deadline.expired():  # the roadmap may be incomplete
        return result(PlanStatus.TIMED_OUT, nodes=len(roadmap.nodes))
    status, path, goal_index = query_roadmap(roadmap, start, goals, checker, space, options, deadline, valid_goals)
    n_nodes = len(roadmap.nodes) + 1 + len(valid_goals)
    if status is not PlanStatus.SUCCESS:
        if status is PlanStatus.NO_PATH and deadline.expired():
            status = PlanStatus.TIMED_OUT
        return result(status, nodes=n_nodes)
    if options.shortcut is not None:
        path = shortcut_path(path, checker, space, rng, options.shortcut)
    return result(PlanStatus.SUCCESS, path, goal_index, n_nodes)
