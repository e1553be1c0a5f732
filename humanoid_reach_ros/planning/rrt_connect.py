"""RRT-connect (Kuffner & LaValle, ICRA 2000) seeded with the start and all sampled goals.

Kanehiro et al. Sec. III-C: "The initial configuration and goals obtained in III-B
are used as seeds for search trees." Tree ``T_a`` is rooted at ``q_start``; tree
``T_b`` has one root per valid goal ``q_goal^g``. Each iteration::

    q_rand ~ U(box)
    EXTEND(T_a, q_rand):  q_near = argmin_{q in T_a} d(q, q_rand)
                          q_new  = q_near + min(1, eps / d(q_near, q_rand)) (q_rand - q_near)
                          add q_new if the edge q_near -> q_new is valid
    CONNECT(T_b, q_new):  repeat EXTEND(T_b, q_new) until reached or trapped
    if reached: path = root_a .. q_new .. root_b ; else swap(T_a, T_b)

``eps`` is :attr:`RRTConnectOptions.step` (weighted metric of the
:class:`~.path.PlanningSpace`). CONNECT is done in one checker call: the whole
straight line ``q_near -> q_new`` is cut into sub-edges of length ``<= eps``, all
sub-edges are discretised at the edge resolution and checked together in order
(``check_edges(prefix=True)``: a checker with ``first_invalid`` stops at the first
invalid point), and the nodes are added up to the first invalid sub-edge (the tree an iterated EXTEND
would grow; tree edges are exactly the edges of the returned path, so every
configuration :func:`~.path.interpolate_path` produces has been checked).

Nearest neighbours: vectorised ``O(n)`` numpy over a preallocated node array.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from humanoid_reach_ros.planning.space import (
    CountingChecker, Deadline, PlanningSpace, PlanResult, PlanStats, PlanStatus, ShortcutOptions,
    ValidityFn, as_counting, check_edges, shortcut_path, validate_endpoints,
)


@dataclass(frozen=True)
class RRTConnectOptions:
    """``step``: EXTEND step ``eps`` (weighted metric); budgets: iterations, nodes, wall time.

    ``shortcut``: post-process the path with :func:`~.path.shortcut_path` (``None``: raw path).
    """

    step: float = 0.3
    max_iterations: int = 5000
    max_nodes: int = 20000
    max_time_s: float = 1.0
    shortcut: ShortcutOptions | None = None


class _Tree:
    """Growing tree: nodes ``(n, d)`` in a preallocated array, parent and root index."""

    def __init__(self, roots: np.ndarray, root_ids: np.ndarray, space: PlanningSpace, capacity: int = 256) -> None:
        self.space = space
        d = roots.shape[1]
        self.nodes = np.empty((max(capacity, 2 * len(roots)), d))
        self.parent = np.empty(len(self.nodes), dtype=np.int64)
        self.root = np.empty(len(self.nodes), dtype=np.int64)
        self.n = len(roots)
        self.nodes[: self.n] = roots
        self.parent[: self.n] = -1
        self.root[: self.n] = root_ids
        self._w2 = space.weights ** 2

    def nearest(self, q: np.ndarray) -> int:
        diff = self.nodes[: self.n] - q
        return int(np.argmin((diff * diff) @ self._w2))

    def add_chain(self, parent: int, Q: np.ndarray) -> int:
        """Append ``Q`` as a chain hanging from ``parent``; return the last index."""
        k = len(Q)
        if self.n + k > len(self.nodes):
            cap = max(2 * len(self.nodes), self.n + k)
            self.nodes = np.resize(self.nodes, (cap, self.nodes.shape[1]))
            self.parent = np.resize(self.parent, cap)
            self.root = np.resize(self.root, cap)
        idx = np.arange(self.n, self.n + k)
        self.nodes[idx] = Q
        self.parent[idx] = np.concatenate([[parent], idx[:-1]])
        self.root[idx] = self.root[parent]
        self.n += k
        return int(idx[-1])

    def branch(self, i: int) -> np.ndarray:
        """Configurations from node ``i`` back to its root."""
        out = []
        while i >= 0:
            out.append(self.nodes[i])
            i = int(self.parent[i])
        return np.array(out)


def _grow(tree: _Tree, target: np.ndarray, step: float, checker: CountingChecker,
          space: PlanningSpace, connect: bool) -> tuple[str, int]:
    """EXTEND (one step of at most ``step``) or CONNECT (steps until reached/trapped).

    Returns ``(status, index)`` with status ``"reached"``, ``"advanced"`` or
    ``"trapped"`` and the index of the last node added (or of ``q_near``).
    """
    i_near = tree.nearest(target)
    q_near = tree.nodes[i_near]
    dist = float(space.distance(q_near, target))
    if dist <= 1e-12:
        return "reached", i_near
    length = dist if connect else min(dist, step)
    n_seg = max(1, int(np.ceil(length / step - 1e-9)))
    # nodes every `step` (the last one at q_end); each sub-edge checked as it will be interpolated
    chain = q_near + (np.arange(1, n_seg + 1)[:, None] / n_seg) * ((length / dist) * (target - q_near))
    if length >= dist - 1e-12:
        chain[-1] = target
    ok = check_edges(np.vstack([q_near[None], chain[:-1]]), chain, checker, space, include_endpoints=True,
                     prefix=True)
    n_ok = n_seg if ok.all() else int(np.argmin(ok))
    if n_ok == 0:
        return "trapped", i_near
    idx = tree.add_chain(i_near, chain[:n_ok])
    reached = n_ok == n_seg and length >= dist - 1e-12
    return ("reached" if reached else "advanced"), idx


def plan_rrt_connect(start: np.ndarray, goals: np.ndarray, is_valid_batch: ValidityFn,
                     space: PlanningSpace, rng: np.random.Generator,
                     options: RRTConnectOptions = RRTConnectOptions()) -> PlanResult:
    """Plan from ``start`` (d,) to any of ``goals`` (g, d).

    Returns a :class:`~.path.PlanResult` whose ``path`` goes from ``start`` to
    ``goals[goal_index]`` (exactly), every edge valid at ``space.resolution``.
    Failure reasons: ``START_INVALID``, ``GOALS_INVALID`` (all goals invalid or
    out of bounds), ``TIMED_OUT`` (time, iteration or node budget exhausted).
    """
    deadline = Deadline(options.max_time_s)
    checker = as_counting(is_valid_batch)
    start, goals, valid_goals, failure = validate_endpoints(start, goals, checker, space)

    def result(status: PlanStatus, path=None, goal_index=None, iterations=0, nodes=0) -> PlanResult:
        stats = PlanStats(iterations, nodes, checker.calls, checker.configs, deadline.elapsed())
        return PlanResult(status, path, goal_index, stats)

    if failure is not None:
        return result(failure)
    t_start = _Tree(start[None], np.array([-1]), space)
    t_goal = _Tree(goals[valid_goals], valid_goals, space)
    tree_a, tree_b = t_start, t_goal
    it = 0
    while True:
        if it >= options.max_iterations or deadline.expired() or tree_a.n + tree_b.n >= options.max_nodes:
            return result(PlanStatus.TIMED_OUT, iterations=it, nodes=t_start.n + t_goal.n)
        it += 1
        # first iteration: try the straight connection start -> nearest goal
        q_rand = t_goal.nodes[t_goal.nearest(start)] if it == 1 else space.sample(rng, 1)[0]
        status, i_new = _grow(tree_a, q_rand, options.step, checker, space, connect=False)
        if status != "trapped":
            q_new = tree_a.nodes[i_new]
            status_b, i_b = _grow(tree_b, q_new, options.step, checker, space, connect=True)
            if status_b == "reached":
                i_s, i_g = (i_new, i_b) if tree_a is t_start else (i_b, i_new)
                from_start = t_start.branch(i_s)[::-1]
                to_goal = t_goal.branch(i_g)
                path = np.vstack([from_start, to_goal])
                # drop the duplicated meeting configuration (keep the last of equal neighbours)
                keep = np.append(space.distance(path[1:], path[:-1]) > 1e-12, True)
                path = path[keep]
                goal_index = int(t_goal.root[i_g])
                if options.shortcut is not None:
                    path = shortcut_path(path, checker, space, rng, options.shortcut)
                return result(PlanStatus.SUCCESS, path, goal_index, it, t_start.n + t_goal.n)
        tree_a, tree_b = tree_b, tree_a
