"""The target's object in a reach's path: the hand comes to it from outside.

The planner leaves the occupied voxels within ``target_exclusion_radius_m`` of the target out
of its collision map (the object to be reached: a hand must be able to touch it; planning
scene, ``SceneParams``). Goal sampling needs that. The path search used to check the whole
path against the same map, so an approach could pass through the object's own voxels (a
valve's rim or spoke) well before its end, where no real hand can go; the way back along that
approach was then (rightly) refused by the retreat (planning/retreat.py: "the hand would
press into the contact's voxels at sample 5"), and home failed START_IN_COLLISION (the
operator console's test: a left-arm reach into the valve, then Home, 1 run in 3).

:class:`ObjectDepthCheck` wraps the path search's validity checker: a configuration is valid
when the wrapped checker says so and no robot shape is deeper in the object's voxels (spheres
of the voxel's half size, no margin: the retreat's measure) than the ends of the search allow
it: per shape, ``min(margin_m, its distance at the start and at the arm's goals) - tolerance_m``
(``margin_m`` the planning margin). A shape clear of the object at every end keeps the margin
from it all the way; the hand and forearm that rest in it at a goal may be that deep, no
deeper. :meth:`ObjectDepthCheck.path_ok` checks a path found against the one goal it reached
(the search knows only the deepest goal of the arm's set). Simplifications, named: the object
is the planner's ball around the target, not its segmented shape; the depth bound is per
shape and taken from the ends, not from a model of the contact (a goal whose forearm lies
30 mm in lets the whole approach graze it that deep).
No ROS here.
"""
from __future__ import annotations

import numpy as np

from humanoid_reach_ros.geometry.distance import RobotCollision
from humanoid_reach_ros.geometry.sphere_tree import SphereTree
from humanoid_reach_ros.planning.space import first_invalid


class ObjectDepthCheck:
    """``is_valid_batch`` of q_plan rows for one arm: ``base`` (the planner's checker, the
    object left out) and the object's depth bound (module doc). ``voxels``: the object's voxel
    centres [m]; ``project``: q_plan rows -> (full configurations, ok); ``collision``: its
    compiled forward kinematics of the shapes."""

    def __init__(self, base, project, collision: RobotCollision, voxels: np.ndarray, resolution_m: float,
                 tolerance_m: float, margin_m: float = 0.0) -> None:
        self.base = base
        self.project = project
        self.collision = collision
        V = np.asarray(voxels, float).reshape(-1, 3)
        self.tree = SphereTree.from_voxels(V, resolution_m, 0.0)
        # the object's bounding ball: shapes farther from it than the margin skip the tree
        self.centre = V.mean(axis=0) if len(V) else np.zeros(3)
        self.reach = (float(np.max(np.linalg.norm(V - self.centre, axis=1))) if len(V) else 0.0) + 0.5 * resolution_m
        self.radii = np.asarray(collision.cm.radii, float)
        self.tolerance_m = float(tolerance_m)
        self.margin_m = float(margin_m)
        self.bound = np.full(len(self.radii), -np.inf)
        if getattr(base, "first_invalid_edge", None) is None:
            self.first_invalid_edge = None      # the callers then check the edges' points through first_invalid
        self.last_examined = 0

    # ------------------------------------------------------------ depths
    def depths(self, Q_full: np.ndarray) -> np.ndarray:
        """(C, S) signed distances [m] of every shape to the object's voxels (negative: in them)."""
        Q_full = np.atleast_2d(np.asarray(Q_full, float))
        if not len(Q_full) or not self.tree.n_spheres:
            return np.full((len(Q_full), len(self.radii)), np.inf)
        P0, P1 = self.collision.world_shapes_batch(Q_full)
        C, S = P0.shape[:2]
        P0, P1, R = P0.reshape(-1, 3), P1.reshape(-1, 3), np.tile(self.radii, C)
        # a lower bound of each shape's distance (segment to the ball's centre): the exact one only
        # where it could be within the margin (the bound is never above the margin)
        u = P1 - P0
        t = np.clip(np.einsum("ij,ij->i", self.centre - P0, u) / np.maximum(np.einsum("ij,ij->i", u, u), 1e-18), 0, 1)
        d = np.linalg.norm(P0 + t[:, None] * u - self.centre, axis=1) - R - self.reach
        near = np.flatnonzero(d <= self.margin_m + 1e-3)
        if near.size:
            d[near] = self.tree.nearest_batch(P0[near], P1[near], R[near])[0]
        return d.reshape(C, S)

    def bound_of(self, Q_full: np.ndarray) -> np.ndarray:
        """(S,) the deepest each shape may go: ``min(margin_m, its distance in Q_full) - tolerance_m``."""
        D = self.depths(Q_full)
        return np.minimum(self.margin_m, D.min(axis=0) if len(D) else self.margin_m) - self.tolerance_m

    def set_ends(self, Q_full: np.ndarray) -> None:
        """The search's ends (the start, the goals): the bound of :meth:`bound_of`."""
        self.bound = self.bound_of(Q_full)

    def ok_full(self, Q_full: np.ndarray, bound: np.ndarray | None = None) -> np.ndarray:
        """(C,) bool: no shape deeper than ``bound`` (default the ends')."""
        b = self.bound if bound is None else bound
        return np.all(self.depths(Q_full) >= b[None, :], axis=1)

    def _ok_plan(self, Q: np.ndarray) -> np.ndarray:
        if not len(Q):
            return np.zeros(0, bool)
        q, ok = self.project(Q)
        ok = np.asarray(ok, bool).copy()
        idx = np.flatnonzero(ok)
        if idx.size:
            ok[idx] = self.ok_full(q[idx])
        return ok

    # ------------------------------------------------------------ the checker protocol (planning/space.py)
    def __call__(self, Q: np.ndarray) -> np.ndarray:
        ok = np.asarray(self.base(Q), bool).copy()
        idx = np.flatnonzero(ok)
        if idx.size:
            ok[idx] = self._ok_plan(np.asarray(Q, float)[idx])
        return ok

    def first_invalid(self, Q: np.ndarray) -> int:
        Q = np.atleast_2d(np.asarray(Q, float))
        k = first_invalid(self.base, Q)
        if k:
            bad = ~self._ok_plan(Q[:k])
            if bad.any():
                k = int(np.argmax(bad))
        return k

    def first_invalid_edge(self, A: np.ndarray, B: np.ndarray, m: np.ndarray, include_endpoints: bool) -> int:
        """The base's first invalid edge, or an earlier one whose points go too deep (the points
        of ``planning/space.check_edges``)."""
        e = int(self.base.first_invalid_edge(A, B, m, include_endpoints))
        self.last_examined = int(getattr(self.base, "last_examined", 0))
        if e == 0:
            return e
        A, B = np.atleast_2d(A)[:e], np.atleast_2d(B)[:e]
        m = np.atleast_1d(np.asarray(m, np.int64))[:e]
        first = 0 if include_endpoints else 1
        counts = m + 1 if include_endpoints else m - 1
        if counts.sum() <= 0:
            return e
        edge_of = np.repeat(np.arange(len(A)), counts)
        offsets = np.cumsum(counts) - counts
        i = np.arange(int(counts.sum())) - np.repeat(offsets, counts) + first
        s = (i / m[edge_of])[:, None]
        ok = self._ok_plan(A[edge_of] + s * (B[edge_of] - A[edge_of]))
        return e if ok.all() else int(edge_of[int(np.argmin(ok))])

    def path_ok(self, Q_full: np.ndarray, goal_full: np.ndarray, start_full: np.ndarray) -> bool:
        """A path's configurations (dense) against the bound of its own ends (the goal it reached)."""
        return bool(np.all(self.ok_full(Q_full, self.bound_of(np.vstack([start_full[None], goal_full[None]])))))


__all__ = ["ObjectDepthCheck"]
