"""The planning scene: the one world model the planner, the executor and the nodes share.

Kanehiro et al. (Sec. II) plan and execute in a voxel map measured by the robot's own
sensors. Everything the package knows about the world is held here, once:

* **occupied** voxel centres (N, 3) [m, world] -- a measured ``/voxel_map`` or, until one
  arrives, a scene file's voxels (the node loads the file: the core never reads the
  simulator's scene description);
* **unobserved** space -- the mapper's frontier (unobserved voxels next to observed free
  space, ``/voxel_map/unobserved``) and its coarse blocks no ray reached
  (``/voxel_map/unobserved_blocks``), everywhere in the mapped extent: behind and beside the
  robot as well as in front of it;
* **body-swept** space -- the voxels within the robot's collision shapes grown by
  ``body_clearance_m`` (the depth sensor's self-filter margin, 0.03 m: the robot-volume policy
  of ``geometry/body_sweep.py``) at every posture the scene was told of
  (:meth:`PlanningScene.mark_body`: the planner marks each request's start posture, which the
  voxel mapper may not have swept yet; the mapper's layers already leave out what the body
  swept between reported postures, and its stance zone), counted as observed free: nothing
  else can be where the robot was. The space *around* the body is not observed by being near
  it. Frontier voxels and blocks inside it are not unobserved any more;
* **allowed contacts** -- a hand may touch the voxels around the object it rests on (the
  retreat of ``planning/retreat.py`` asks for them per plan: :class:`AllowedContact`);
* a **version**, bumped by every change, and cheap immutable :class:`SceneSnapshot`\\ s: a
  plan or a motion works on the snapshot it started with while the layers change beside it.
  Sphere trees (Quinlan, ``geometry/sphere_tree.py``) and robot-vs-map checkers are built
  on demand and cached per (version, what was left out, whether unobserved space counts).

Policies that used to live in three places (the planner node, ``ReachPlanner.set_map``,
the executor's requests) are parameters of :class:`SceneParams`:

* ``target_exclusion_radius_m``: the voxels within this distance of a target are the object
  to be reached and left out of the collision map (a simplification, named: the object is a
  ball around the target, not its segmented shape);
* ``unobserved_space``: ``"occupied"`` (plans never enter unobserved space: the frontier is an
  obstacle and a target in an unobserved block is refused) or ``"free"``.

No ROS here; thread-safe (one lock around the layers; snapshots are immutable).
"""
from __future__ import annotations

import math
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, field

import numba as nb
import numpy as np

from humanoid_reach_ros.geometry.body_sweep import DEFAULT_SELF_FILTER_MARGIN_M
from humanoid_reach_ros.geometry.distance import RobotCollision
from humanoid_reach_ros.geometry.sphere_tree import SphereTree
from humanoid_reach_ros.geometry.voxels import mark_capsules, without_target
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.shapes import CollisionModel, load_collision_model

UNOBSERVED_POLICIES = ("occupied", "free")


@dataclass(frozen=True)
class SceneParams:
    """Policies of the scene (units in the names).

    ``resolution_m``: voxel size (environment sphere diameter); ``safety_margin_m``: added to
    every environment sphere radius; ``target_exclusion_radius_m``: the object around a target
    left out (0: keep all); ``unobserved_space``: ``occupied`` | ``free``;
    ``unobserved_block_m``: edge of the mapper's unobserved blocks; ``body_clearance_m``: the
    robot's shapes grown by this at each posture count as observed free space (the self-filter
    margin of ``geometry/body_sweep.py``; more counts unseen space as seen);
    ``body_extent_min_m`` / ``body_extent_max_m``: the box (world) in which body-swept space is
    remembered (a dense grid: 150 x 150 x 130 voxels at 0.02 m, 2.9 MB); ``tree_cache_size``:
    sphere trees kept (per version and exclusion)."""

    resolution_m: float = 0.02
    safety_margin_m: float = 0.0
    target_exclusion_radius_m: float = 0.0
    unobserved_space: str = "occupied"
    unobserved_block_m: float = 0.1
    body_clearance_m: float = DEFAULT_SELF_FILTER_MARGIN_M
    body_extent_min_m: tuple[float, float, float] = (-1.5, -1.5, -0.1)
    body_extent_max_m: tuple[float, float, float] = (1.5, 1.5, 2.5)
    tree_cache_size: int = 8

    def __post_init__(self) -> None:
        for name in ("resolution_m", "unobserved_block_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"SceneParams.{name} must be finite and > 0, got {v}")
        for name in ("safety_margin_m", "target_exclusion_radius_m", "body_clearance_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"SceneParams.{name} must be finite and >= 0, got {v}")
        if self.unobserved_space not in UNOBSERVED_POLICIES:
            raise ValueError(f"SceneParams.unobserved_space must be one of {UNOBSERVED_POLICIES}, "
                             f"got {self.unobserved_space!r}")
        if self.tree_cache_size < 1:
            raise ValueError("SceneParams.tree_cache_size must be >= 1")


@dataclass(frozen=True, eq=False)
class AllowedContact:
    """The shapes ``shapes`` (indices into the collision model) may touch the occupied voxels
    within ``radius_m`` of ``point`` (world): a hand resting on the object it reached."""

    shapes: tuple[int, ...]
    point: np.ndarray
    radius_m: float


def voxel_points(voxels, what: str = "voxels") -> np.ndarray:
    """An (N, 3) finite float array of voxel centres; ValueError otherwise (N = 0 allowed)."""
    V = np.asarray(voxels, dtype=float)
    if V.size == 0:
        V = V.reshape(0, 3)
    if V.ndim != 2 or V.shape[1] != 3:
        raise ValueError(f"{what} must be an (N, 3) array of centres, got shape {V.shape}")
    if not np.all(np.isfinite(V)):
        raise ValueError(f"{what} contain NaN or inf")
    return np.ascontiguousarray(V)


@nb.njit(cache=True)
def _boxes_touch_grid(C, half, h, lo, grid):   # pragma: no cover - compiled
    """Per box (centres C (M, 3), half-edge ``half``): does a True voxel of ``grid`` lie in it?"""
    out = np.zeros(C.shape[0], np.bool_)
    nx, ny, nz = grid.shape
    for m in range(C.shape[0]):
        i0 = max(int(math.ceil((C[m, 0] - half) / h - 0.5 - 1e-9)) - lo[0], 0)
        i1 = min(int(math.floor((C[m, 0] + half) / h - 0.5 + 1e-9)) - lo[0], nx - 1)
        j0 = max(int(math.ceil((C[m, 1] - half) / h - 0.5 - 1e-9)) - lo[1], 0)
        j1 = min(int(math.floor((C[m, 1] + half) / h - 0.5 + 1e-9)) - lo[1], ny - 1)
        k0 = max(int(math.ceil((C[m, 2] - half) / h - 0.5 - 1e-9)) - lo[2], 0)
        k1 = min(int(math.floor((C[m, 2] + half) / h - 0.5 + 1e-9)) - lo[2], nz - 1)
        hit = False
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                for k in range(k0, k1 + 1):
                    if grid[i, j, k]:
                        hit = True
                        break
                if hit:
                    break
            if hit:
                break
        out[m] = hit
    return out


class BodySweptSpace:
    """Voxels the robot's body (grown by a clearance) has been in: a dense boolean grid over
    ``extent_min_m`` .. ``extent_max_m`` [m, world] (voxel ``i`` covers ``[i h, (i+1) h)``, as
    the map); space outside the box is never marked."""

    def __init__(self, resolution_m: float, extent_min_m, extent_max_m) -> None:
        h = float(resolution_m)
        self.h = h
        self.lo = np.floor(np.asarray(extent_min_m, float) / h).astype(np.int64)
        hi = np.floor(np.asarray(extent_max_m, float) / h).astype(np.int64)
        if np.any(hi < self.lo):
            raise ValueError(f"body extent {extent_min_m} .. {extent_max_m} is empty")
        self.grid = np.zeros(tuple(int(x) for x in hi - self.lo + 1), dtype=np.bool_)
        self.count = 0

    def mark(self, P0: np.ndarray, P1: np.ndarray, radii: np.ndarray) -> int:
        """Mark the voxels whose centres lie within the capsules; returns how many are new."""
        added = int(mark_capsules(np.ascontiguousarray(P0, dtype=np.float64),
                                   np.ascontiguousarray(P1, dtype=np.float64),
                                   np.ascontiguousarray(radii, dtype=np.float64), self.h, self.lo, self.grid))
        self.count += added
        return added

    def contains(self, points: np.ndarray) -> np.ndarray:
        """Per point (N, 3): is its voxel marked?"""
        idx = np.floor(np.asarray(points, float).reshape(-1, 3) / self.h).astype(np.int64) - self.lo
        ok = np.all((idx >= 0) & (idx < np.array(self.grid.shape)), axis=1)
        out = np.zeros(len(idx), bool)
        i = idx[ok]
        out[ok] = self.grid[i[:, 0], i[:, 1], i[:, 2]]
        return out

    def touches_boxes(self, centres: np.ndarray, edge_m: float) -> np.ndarray:
        """Per cube (centres (M, 3), edge ``edge_m``): does a marked voxel centre lie in it?"""
        C = np.ascontiguousarray(np.asarray(centres, float).reshape(-1, 3))
        return _boxes_touch_grid(C, 0.5 * float(edge_m), self.h, self.lo, self.grid)


@dataclass(frozen=True, eq=False)
class SceneSnapshot:
    """The scene at one version (immutable; see the module doc). Arrays are read-only."""

    version: int
    source: str
    params: SceneParams
    occupied: np.ndarray              # (N, 3)
    frontier: np.ndarray | None       # (K, 3) unobserved frontier outside the body-swept space; None: unknown
    blocks: np.ndarray | None         # (M, 3) centres of unobserved blocks outside it; None: unknown
    swept_voxels: int
    contacts: tuple[AllowedContact, ...] = ()
    _owner: "PlanningScene | None" = field(default=None, repr=False)

    @property
    def has_map(self) -> bool:
        return self.source != "none"

    @property
    def knows_unobserved(self) -> bool:
        """Whether the scene can tell observed from unobserved space (the mapper's layers arrived)."""
        return self.frontier is not None and self.blocks is not None

    @property
    def avoids_unobserved(self) -> bool:
        """Plans keep out of unobserved space (policy ``occupied``, layers known, a measured map:
        any source but a scene file)."""
        return self.params.unobserved_space == "occupied" and self.knows_unobserved and self.measured

    @property
    def measured(self) -> bool:
        """The occupied voxels come from sensors (not a scene file's model of the world)."""
        return self.has_map and not self.source.startswith("scene file")

    def obstacles(self, exclude: np.ndarray | None = None, unobserved: bool = False) -> np.ndarray:
        """Voxel centres a collision map holds: the occupied ones (and the unobserved frontier
        with ``unobserved``) outside ``target_exclusion_radius_m`` of each ``exclude`` point."""
        r = 0.0 if exclude is None else self.params.target_exclusion_radius_m
        c = np.zeros(3) if exclude is None else exclude
        V = without_target(self.occupied, c, r)
        if unobserved and self.frontier is not None and len(self.frontier):
            V = np.vstack([V, self._frontier_without_object(c, r)])
        return V

    def _frontier_without_object(self, c: np.ndarray, r: float) -> np.ndarray:
        """The frontier less its voxels in the object's shadow: within ``r`` of a target AND next
        to (within 1.5 voxels of) an occupied voxel left out as that object -- the unseen back of
        the valve the hand reaches into. The rest of the frontier near a target stays an obstacle
        (issue 31: leaving all of it out opened a 15 cm hole into unseen space around a target
        beside the body, and a plan went through a hidden pipe there)."""
        F = self.frontier
        if r <= 0.0 or not len(F):
            return F
        C = np.asarray(c, float).reshape(-1, 3)
        near = np.zeros(len(F), bool)
        for p in C:
            near |= np.sum((F - p) ** 2, axis=1) <= r * r
        if not near.any():
            return F
        obj = self.occupied[np.any(np.sum((self.occupied[:, None, :] - C[None]) ** 2, axis=2) <= r * r, axis=1)] \
            if len(self.occupied) else np.zeros((0, 3))
        shadow = np.zeros(len(F), bool)
        if len(obj):
            from scipy.spatial import cKDTree
            d, _ = cKDTree(obj).query(F[near], k=1)
            shadow[np.flatnonzero(near)] = d <= 1.5 * self.params.resolution_m
        return F[~shadow]

    def collision(self, robot: RobotModel, collision_model: CollisionModel, exclude: np.ndarray | None = None,
                  unobserved: bool = False) -> tuple[RobotCollision, float]:
        """A robot-vs-map checker of :meth:`obstacles` (cached per version, exclusion and
        robot) and the sphere tree's build time [s] (0 when cached)."""
        tree, dt = self.tree(exclude, unobserved)
        if self._owner is None:
            return RobotCollision(robot, collision_model, tree), dt
        return self._owner._checker(self, robot, collision_model, tree, exclude, unobserved), dt

    def tree(self, exclude: np.ndarray | None = None, unobserved: bool = False) -> tuple[SphereTree, float]:
        """Sphere tree of :meth:`obstacles` (radius h/2 + safety margin) and its build time [s]."""
        key = _exclusion_key(exclude, self.params.target_exclusion_radius_m, unobserved)
        if self._owner is not None:
            hit = self._owner._cached_tree(self.version, key)
            if hit is not None:
                return hit, 0.0
        t0 = time.perf_counter()
        tree = SphereTree.from_voxels(self.obstacles(exclude, unobserved), self.params.resolution_m,
                                      self.params.safety_margin_m)
        dt = time.perf_counter() - t0
        if self._owner is not None:
            self._owner._store_tree(self.version, key, tree)
        return tree, dt

    def unobserved_target(self, target_p: np.ndarray) -> str:
        """Why ``target_p`` lies in space nobody has observed ('' if it does not, the policy is
        ``free`` or the map is not measured)."""
        if self.params.unobserved_space != "occupied" or not self.measured:
            return ""
        if not self.knows_unobserved:
            if self.source != "/voxel_map":
                return ""
            return ("no /voxel_map/unobserved(_blocks) received: the map cannot tell observed from unobserved "
                    "space (is voxel_mapper running? a mapper without them: set unobserved_space:=free)")
        c = self.unobserved_block_at(target_p)
        if c is None:
            return ""
        return (f"the target {np.round(target_p, 3).tolist()} lies in space the head has not observed (the "
                f"{self.params.unobserved_block_m:g} m block around {np.round(c, 2).tolist()} m)")

    def unobserved_block_at(self, p: np.ndarray) -> np.ndarray | None:
        """Centre of the unobserved block holding ``p`` (None: observed, or unknown)."""
        if self.blocks is None or not len(self.blocks):
            return None
        half = 0.5 * self.params.unobserved_block_m
        inside = np.all(np.abs(self.blocks - np.asarray(p, float)) <= half, axis=1)
        return self.blocks[int(np.argmax(inside))].copy() if np.any(inside) else None


def _exclusion_key(exclude, radius, unobserved) -> tuple:
    pts = () if exclude is None or radius <= 0 else tuple(np.round(np.asarray(exclude, float).reshape(-1), 4))
    return (pts, bool(unobserved))


class PlanningScene:
    """The world model (module doc): layers in, snapshots out.

    ``robot`` and its collision model place the body for :meth:`mark_body`."""

    def __init__(self, robot: RobotModel, params: SceneParams = SceneParams(),
                 collision_model: CollisionModel | None = None) -> None:
        self.robot = robot
        self.params = params
        self.collision_model = collision_model if collision_model is not None else load_collision_model(None, robot)
        self._lock = threading.Lock()
        self._version = 0
        self._source = "none"
        self._occupied = np.zeros((0, 3))
        self._frontier_raw: np.ndarray | None = None
        self._blocks_raw: np.ndarray | None = None
        self._swept = BodySweptSpace(params.resolution_m, params.body_extent_min_m, params.body_extent_max_m)
        self._last_body: np.ndarray | None = None
        self._contacts: tuple[AllowedContact, ...] = ()
        self._snapshot: SceneSnapshot | None = None
        self._trees: OrderedDict = OrderedDict()
        self._checkers: OrderedDict = OrderedDict()

    # ------------------------------------------------------------ layers in
    def set_occupied(self, voxels, source: str = "/voxel_map") -> int:
        """Replace the occupied voxels (N, 3); returns the new version. ValueError on a bad array."""
        V = voxel_points(voxels)
        V.setflags(write=False)
        with self._lock:
            self._occupied, self._source = V, str(source)
            return self._bump()

    def set_unobserved(self, frontier=None, blocks=None) -> int:
        """Replace the unobserved frontier (K, 3) and/or the unobserved blocks' centres (M, 3)
        (None: keep that layer); returns the new version."""
        F = None if frontier is None else voxel_points(frontier, "unobserved voxels")
        B = None if blocks is None else voxel_points(blocks, "unobserved blocks")
        with self._lock:
            if F is not None:
                self._frontier_raw = F
            if B is not None:
                self._blocks_raw = B
            return self._bump()

    def forget_unobserved(self) -> int:
        """Back to 'unobserved space unknown' (e.g. the mapper was cleared)."""
        with self._lock:
            self._frontier_raw = self._blocks_raw = None
            return self._bump()

    def clear(self) -> int:
        """No map at all (requests get NO_MAP); the body-swept space is kept."""
        with self._lock:
            self._occupied, self._source = np.zeros((0, 3)), "none"
            self._frontier_raw = self._blocks_raw = None
            return self._bump()

    def mark_body(self, joints: np.ndarray, tol_rad: float = 1e-3) -> int:
        """Remember the space the body takes at ``joints`` (standing on its feet), grown by
        ``body_clearance_m``, as observed free; returns the voxels newly marked (0 when the
        posture is within ``tol_rad`` of the last one marked)."""
        j = np.asarray(joints, dtype=float).reshape(-1)
        if j.shape[0] != self.robot.n_joints or not np.all(np.isfinite(j)):
            raise ValueError(f"mark_body needs {self.robot.n_joints} finite joint angles")
        with self._lock:
            if self._last_body is not None and np.max(np.abs(self._last_body - j)) <= tol_rad:
                return 0
        q = self.robot.config(j, self.robot.base_on_feet(j))
        P0, P1, R = self.collision_model.world_shapes(q)
        with self._lock:
            added = self._swept.mark(P0, P1, np.asarray(R) + self.params.body_clearance_m)
            self._last_body = j.copy()
            if added:
                self._bump()
            return int(added)

    def allow_contacts(self, contacts: tuple[AllowedContact, ...]) -> int:
        """Replace the allowed contacts; returns the new version."""
        with self._lock:
            self._contacts = tuple(contacts)
            return self._bump()

    def set_params(self, params: SceneParams) -> int:
        """New policies (e.g. a node's parameter changed at run time); the resolution and the
        body box stay (the body-swept grid is built on them); returns the new version."""
        if (params.resolution_m, params.body_extent_min_m, params.body_extent_max_m) != (
                self.params.resolution_m, self.params.body_extent_min_m, self.params.body_extent_max_m):
            raise ValueError("the scene's resolution_m and body extent cannot change at run time")
        with self._lock:
            self.params = params
            self._trees.clear()
            self._checkers.clear()
            return self._bump()

    def _bump(self) -> int:
        self._version += 1
        self._snapshot = None
        return self._version

    # ------------------------------------------------------------ out
    @property
    def version(self) -> int:
        return self._version

    @property
    def has_map(self) -> bool:
        return self._source != "none"

    @property
    def source(self) -> str:
        return self._source

    @property
    def swept_voxels(self) -> int:
        return int(self._swept.count)

    def snapshot(self) -> SceneSnapshot:
        """The scene now (cached until the next change)."""
        with self._lock:
            if self._snapshot is not None:
                return self._snapshot
            frontier = blocks = None
            if self._frontier_raw is not None:
                F = self._frontier_raw
                frontier = F[~self._swept.contains(F)] if self._swept.count else F.copy()
                frontier.setflags(write=False)
            if self._blocks_raw is not None:
                B = self._blocks_raw
                blocks = B[~self._swept.touches_boxes(B, self.params.unobserved_block_m)] if self._swept.count \
                    else B.copy()
                blocks.setflags(write=False)
            snap = SceneSnapshot(self._version, self._source, self.params, self._occupied, frontier, blocks,
                                 int(self._swept.count), self._contacts, self)
            self._snapshot = snap
            return snap

    def describe(self) -> dict:
        """Figures for diagnostics and log lines."""
        s = self.snapshot()
        return {"source": s.source, "version": s.version, "occupied_voxels": int(len(s.occupied)),
                "frontier_voxels": -1 if s.frontier is None else int(len(s.frontier)),
                "unobserved_blocks": -1 if s.blocks is None else int(len(s.blocks)),
                "body_swept_voxels": s.swept_voxels, "unobserved_space": self.params.unobserved_space}

    # ------------------------------------------------------------ caches (SceneSnapshot calls these)
    def _cached_tree(self, version: int, key: tuple) -> SphereTree | None:
        with self._lock:
            tree = self._trees.get((version, key))
            if tree is not None:
                self._trees.move_to_end((version, key))
            return tree

    def _store_tree(self, version: int, key: tuple, tree: SphereTree) -> None:
        with self._lock:
            self._trees[(version, key)] = tree
            while len(self._trees) > self.params.tree_cache_size:
                self._trees.popitem(last=False)

    def _checker(self, snap: SceneSnapshot, robot, collision_model, tree, exclude, unobserved) -> RobotCollision:
        key = (snap.version, _exclusion_key(exclude, self.params.target_exclusion_radius_m, unobserved), id(robot),
               id(collision_model))
        with self._lock:
            hit = self._checkers.get(key)
            if hit is not None and hit.tree is tree:
                return hit
        checker = RobotCollision(robot, collision_model, tree)
        with self._lock:
            self._checkers[key] = checker
            while len(self._checkers) > self.params.tree_cache_size:
                self._checkers.popitem(last=False)
        return checker


__all__ = ["SceneParams", "PlanningScene", "SceneSnapshot", "AllowedContact", "UNOBSERVED_POLICIES", "voxel_points",
           "BodySweptSpace"]
