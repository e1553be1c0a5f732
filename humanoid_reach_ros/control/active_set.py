"""Lexicographic QP by a cascade of dual active-set solves in shrinking null spaces.

The executor's hierarchy (Kanehiro et al., Sec. IV; Kanoun, Lamiraux and Wieber 2011):
one inequality level on top, ``G x <= h`` (joint position and velocity limits, velocity
dampers), then equality levels ``A_k x = b_k``, k = 2..p (feet and COG, hand, posture).
Level ``k`` is

    min_y  ||A_k (x_{k-1} + Z_{k-1} y) - b_k||^2 + eps ||y||^2
    s.t.   G (x_{k-1} + Z_{k-1} y) <= h

with ``x_{k-1}`` the solution of the levels above and ``Z_{k-1}`` an orthonormal basis of
the null space of their matrices ``[A_2; ...; A_{k-1}]`` (so ``A_j x`` keeps the value
level ``j`` reached: its optimum is kept exactly, whatever ``G`` did to it); then
``x_k = x_{k-1} + Z_{k-1} y*`` and ``Z_k = Z_{k-1} null(A_k Z_{k-1})``. The unknowns
shrink level by level (34 -> 20 -> 14 for the executor). Every level is a small dense
strictly convex QP solved by DAQP (Arnström, Bemporad, Axehill 2022: a dual active-set
method that is exact, cheap to start from nothing, and robust to the many nearly
parallel constraint rows a robot close to a pipe produces, where the closed-form
saturation of :class:`~humanoid_reach_ros.control.hqp.SaturatedNullSpaceHQP` cycles).

Named simplifications with respect to Kanoun's lexicographic QP: the inequality level
is hard (DAQP reports an infeasible level 1 as a failure and the caller falls back,
instead of minimising its violation; the executor's level 1 contains ``x = 0`` by
construction, so this does not happen there); an equality level's optimum is kept by
fixing ``A_j x`` rather than its residual norm (the same set: the objective is strictly
convex in ``A_j x``); ``eps`` / ``eps_lower`` bias each level toward the smallest ``y``
by ``O(eps / sigma^2)`` (damped least squares below the first level).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import daqp
import numpy as np

_MINUS_INF = -1e30


@dataclass(frozen=True)
class CascadeResult:
    """``x``; ``ok``: every level solved (else ``x`` is the solution of the levels that were,
    feasible for ``G x <= h`` when ``level_failed > 0``); ``iterations``: active-set
    iterations of all levels; ``level_failed``: index of the first level DAQP did not
    solve (-1: none), ``exitflag`` its DAQP exit flag."""

    x: np.ndarray
    ok: bool
    iterations: int
    level_failed: int = -1
    exitflag: int = 1


class ActiveSetCascade:
    """Sequential dual active-set solves of the levels (see the module docstring).

    ``eps``: regularisation of the first equality level's Hessian (kept tiny: that level,
    the feet and the COG, is solved exactly); ``eps_lower``: that of the levels below, a
    damped least squares (``lambda^2``) that keeps a task pulled toward a singular or
    unreachable target from taking full-velocity steps along its near-singular directions
    (without it the arm chatters at its velocity limits and the second-order effect of
    those steps shows on the feet); ``rank_tol``: singular values of
    ``A_k Z_{k-1}`` below ``rank_tol * max(s_1, 1)`` leave their direction to the lower
    levels; ``primal_tol``: DAQP's feasibility tolerance (the rows hold to it: 1e-10 m over
    a 5 ms step; a level DAQP calls infeasible at it, as happens at degenerate vertices, is
    solved again at ten times it); ``iter_limit``: active-set iterations per level."""

    def __init__(self, eps: float = 1e-8, eps_lower: float = 1e-6, rank_tol: float = 1e-8,
                 primal_tol: float = 1e-10, iter_limit: int = 2000) -> None:
        self.eps = float(eps)
        self.eps_lower = float(eps_lower)
        self.rank_tol = float(rank_tol)
        self.primal_tol = float(primal_tol)
        self.iter_limit = int(iter_limit)

    def solve(self, G: np.ndarray, h: np.ndarray, levels: Sequence[tuple[np.ndarray, np.ndarray]]) -> CascadeResult:
        """The cascade on ``G x <= h`` (rows of ``G``: any number, may be 0) above the
        equality ``levels`` ``[(A_k, b_k)]`` (first = highest priority)."""
        n = G.shape[1] if G.ndim == 2 and G.shape[1] else next(A.shape[1] for A, _ in levels)
        x = np.zeros(n)
        Z: np.ndarray | None = None          # None: the whole space
        iters = 0
        sense = np.zeros(len(h), dtype=np.int32)
        lower = np.full(len(h), _MINUS_INF)
        nonempty = [k for k, (A, _) in enumerate(levels) if A is not None and len(A)]
        first, last = (nonempty[0], nonempty[-1]) if nonempty else (-1, -1)
        for k, (A, b) in enumerate(levels):
            if A is None or not len(A):
                continue
            M = A if Z is None else A @ Z
            d = M.shape[1]
            if d == 0:
                break
            r = b - A @ x
            H = M.T @ M
            H[np.diag_indices(d)] += self.eps if k == first else self.eps_lower
            f = -(M.T @ r)
            GZ = G if Z is None else G @ Z
            # rows with no component left in the free space cannot change: out of the QP; the
            # others start from the previous level's point, feasible to DAQP's tolerance (a
            # residual violation of that size is not asked to be undone)
            live = np.flatnonzero(np.abs(GZ).max(axis=1, initial=0.0) > 1e-12) if len(h) else np.zeros(0, int)
            if len(live):
                hz = h[live] - G[live] @ x
                if k != first:
                    hz[(hz < 0.0) & (hz > -10.0 * self.primal_tol)] = 0.0
                Gl = np.ascontiguousarray(GZ[live])
                for tol in (self.primal_tol, 10.0 * self.primal_tol):   # a degenerate vertex (more
                    y, _, flag, info = daqp.solve(H, f, Gl, hz, lower[:len(live)], sense[:len(live)],
                                                  primal_tol=tol, eps_prox=0, iter_limit=self.iter_limit)
                    iters += int(info["iterations"])     # active rows than free dimensions) may
                    if flag >= 1:                        # need the looser tolerance
                        break
                if flag < 1:
                    return CascadeResult(x, False, iters, k, int(flag))
            else:
                y = np.linalg.solve(H, -f)
            x = x + (y if Z is None else Z @ y)
            if k != last:
                _, S, Vt = np.linalg.svd(M, full_matrices=True)
                rank = int(np.count_nonzero(S > self.rank_tol * max(S[0], 1.0))) if len(S) else 0
                Zk = Vt[rank:].T
                Z = Zk if Z is None else Z @ Zk
        return CascadeResult(x, True, iters)


__all__ = ["ActiveSetCascade", "CascadeResult"]
