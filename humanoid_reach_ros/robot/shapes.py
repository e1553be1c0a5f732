"""Sphere / capsule approximation of the robot for collision checks and distances.

Kanehiro et al. (Sec. II, Fig. 2) approximate the humanoid by spheres and capped
cylinders (capsules) because distances between them and the environment's sphere
tree are cheap. The model lives in the robot description's ``collision_model``
(``config/robots/hrp2/collision.yaml``); this module
loads and validates it and evaluates it in numpy (no ROS).

Every shape is stored as a *capsule*: a segment ``p0 -> p1`` swept by a ball of
``radius``; a sphere is a zero-length segment (``p0 == p1``). One segment formula
then serves both kinds, so the code that uses the model can stay vectorised:

* distance from a shape to a point (an environment sphere centre):
  :func:`point_segment_distance` minus the radii;
* distance between two shapes (self-collision): :func:`segment_segment_distance`
  minus the radii.

Array conventions: ``S`` shapes, ``L`` links carrying shapes, ``K`` self-collision
pairs; functions accept any leading batch dimensions ``...`` (e.g. ``N``
configurations) and broadcast over them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml

from humanoid_reach_ros.yaml_checks import named_entry, number, top_level, vec3

if TYPE_CHECKING:  # pragma: no cover
    from humanoid_reach_ros.robot.model import RobotModel

SHAPE_KINDS = ("sphere", "capsule")
_TOP_KEYS = {"padding_m", "links", "self_collision_pairs"}


# ------------------------------------------------------------------ the model
@dataclass(frozen=True)
class Shape:
    """One collision primitive in the frame of ``link``.

    ``kind`` is ``"sphere"`` (then ``p0 == p1`` is the centre) or ``"capsule"``.
    ``radius`` is the radius written in the file, without the model's padding.
    """

    name: str
    link: str
    kind: str
    p0: tuple[float, float, float]
    p1: tuple[float, float, float]
    radius: float

    @property
    def is_sphere(self) -> bool:
        return self.kind == "sphere"

    @property
    def length(self) -> float:
        """Length of the segment (0 for a sphere) [m]."""
        return math.dist(self.p0, self.p1)


@dataclass(frozen=True, eq=False)
class CollisionModel:
    """The robot's shapes, their self-collision pairs and numpy views of both.

    Build it with :func:`load_collision_model`. The arrays are read-only:

    * ``links`` (L,): distinct frames carrying shapes; ``frame_ids`` (L,) their
      pinocchio frame ids;
    * ``shape_link`` (S,): index into ``links`` of each shape's frame;
    * ``p0_local``, ``p1_local`` (S, 3): segment ends in the link frame;
    * ``radii`` (S,): radius *including* ``padding_m``; ``base_radii`` (S,) without it
      (e.g. for self-collision with a smaller margin than against the environment:
      ``self_distances(P0, P1, cm.base_radii + margin)``);
    * ``pair_index`` (K, 2): shape indices of the self-collision pairs.
    """

    robot: "RobotModel" = field(repr=False)
    shapes: tuple[Shape, ...]
    pairs: tuple[tuple[str, str], ...]
    padding_m: float = 0.0
    links: tuple[str, ...] = field(init=False)
    frame_ids: np.ndarray = field(init=False, repr=False)
    shape_link: np.ndarray = field(init=False, repr=False)
    p0_local: np.ndarray = field(init=False, repr=False)
    p1_local: np.ndarray = field(init=False, repr=False)
    radii: np.ndarray = field(init=False, repr=False)
    base_radii: np.ndarray = field(init=False, repr=False)
    pair_index: np.ndarray = field(init=False, repr=False)
    _index: dict = field(init=False, repr=False)
    _frame_list: list = field(init=False, repr=False)

    def __post_init__(self) -> None:
        links: list[str] = []
        for s in self.shapes:
            if s.link not in links:
                links.append(s.link)
        index = {s.name: i for i, s in enumerate(self.shapes)}
        if len(index) != len(self.shapes):
            raise ValueError("collision model: shape names are not unique")
        set_ = object.__setattr__
        set_(self, "links", tuple(links))
        set_(self, "_index", index)
        set_(self, "frame_ids", _ro(np.array([self.robot.frame_id(n) for n in links], dtype=np.intp)))
        set_(self, "_frame_list", [int(i) for i in self.frame_ids])
        set_(self, "shape_link", _ro(np.array([links.index(s.link) for s in self.shapes], dtype=np.intp)))
        set_(self, "p0_local", _ro(np.array([s.p0 for s in self.shapes], dtype=float).reshape(-1, 3)))
        set_(self, "p1_local", _ro(np.array([s.p1 for s in self.shapes], dtype=float).reshape(-1, 3)))
        set_(self, "base_radii", _ro(np.array([s.radius for s in self.shapes], dtype=float)))
        set_(self, "radii", _ro(self.base_radii + self.padding_m))
        set_(self, "pair_index", _ro(np.array([(index[a], index[b]) for a, b in self.pairs],
                                             dtype=np.intp).reshape(-1, 2)))

    # ------------------------------------------------------------ lookup
    @property
    def names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.shapes)

    @property
    def n_shapes(self) -> int:
        return len(self.shapes)

    @property
    def n_pairs(self) -> int:
        return len(self.pairs)

    def index(self, name: str) -> int:
        """Index of the shape called ``name`` (KeyError if none)."""
        try:
            return self._index[name]
        except KeyError:
            raise KeyError(f"unknown collision shape {name!r}") from None

    def shape(self, name: str) -> Shape:
        return self.shapes[self.index(name)]

    def shapes_of_link(self, link: str) -> tuple[Shape, ...]:
        return tuple(s for s in self.shapes if s.link == link)

    # ------------------------------------------------------------ kinematics
    def link_poses(self, source: Any) -> tuple[np.ndarray, np.ndarray]:
        """World rotations (L, 3, 3) and translations (L, 3) of the shape-carrying links.

        ``source`` is a configuration ``q`` (runs the robot's forward kinematics), a
        ``pinocchio.Data`` whose ``oMf`` is already filled, or such an ``oMf`` vector.
        """
        oMf = self._oMf(source)
        H = np.array([oMf[i].homogeneous for i in self._frame_list])  # one copy per link
        return H[:, :3, :3], H[:, :3, 3]

    def link_poses_batch(self, qs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Stacked link poses of many configurations: R (N, L, 3, 3), t (N, L, 3)."""
        qs = np.asarray(qs, dtype=float)
        if qs.ndim != 2:
            raise ValueError(f"expected configurations of shape (N, nq), got {qs.shape}")
        R = np.empty((len(qs), len(self.links), 3, 3))
        t = np.empty((len(qs), len(self.links), 3))
        for n, q in enumerate(qs):
            R[n], t[n] = self.link_poses(q)
        return R, t

    def shapes_from_poses(self, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World segment ends from link poses R (..., L, 3, 3), t (..., L, 3).

        Returns P0, P1 (..., S, 3) and the padded radii (S,) (shared by every batch
        element: radii do not depend on the posture).
        """
        R = np.asarray(R, dtype=float)
        t = np.asarray(t, dtype=float)
        Rs = R[..., self.shape_link, :, :]
        ts = t[..., self.shape_link, :]
        P0 = np.einsum("...sij,sj->...si", Rs, self.p0_local) + ts
        P1 = np.einsum("...sij,sj->...si", Rs, self.p1_local) + ts
        return P0, P1, self.radii

    def world_shapes(self, source: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All shapes in the world from one forward kinematics: P0, P1 (S, 3), radii (S,).

        ``source`` as in :meth:`link_poses` (``q``, ``pinocchio.Data`` or ``oMf``).
        """
        return self.shapes_from_poses(*self.link_poses(source))

    def world_shapes_batch(self, qs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`world_shapes` for N configurations (N, nq): P0, P1 (N, S, 3), radii (S,)."""
        return self.shapes_from_poses(*self.link_poses_batch(qs))

    # ------------------------------------------------------------ self-collision
    def self_distances(self, P0: np.ndarray, P1: np.ndarray, radii: np.ndarray | None = None) -> np.ndarray:
        """Signed distances (..., K) of the self-collision pairs (negative: penetration).

        ``P0``, ``P1`` (..., S, 3) from :meth:`world_shapes` / :meth:`shapes_from_poses`;
        ``radii`` (S,) defaults to the model's padded radii.
        """
        P0 = np.asarray(P0, dtype=float)
        P1 = np.asarray(P1, dtype=float)
        r = self.radii if radii is None else np.asarray(radii, dtype=float)
        i, j = self.pair_index[:, 0], self.pair_index[:, 1]
        d, _, _ = segment_segment_distance(P0[..., i, :], P1[..., i, :], P0[..., j, :], P1[..., j, :])
        return d - r[..., i] - r[..., j]

    def in_self_collision(
        self, P0: np.ndarray, P1: np.ndarray, radii: np.ndarray | None = None, margin: float = 0.0
    ) -> bool | np.ndarray:
        """True where some pair is closer than ``margin`` (bool, or (...,) bool array for batches)."""
        hit = np.any(self.self_distances(P0, P1, radii) < margin, axis=-1)
        return bool(hit) if np.ndim(hit) == 0 else hit

    def self_distances_at(self, source: Any) -> np.ndarray:
        """:meth:`self_distances` of one posture (``q``, ``pinocchio.Data`` or ``oMf``): (K,)."""
        return self.self_distances(*self.world_shapes(source))

    def in_self_collision_at(self, source: Any, margin: float = 0.0) -> bool:
        """:meth:`in_self_collision` of one posture (``q``, ``pinocchio.Data`` or ``oMf``)."""
        return bool(self.in_self_collision(*self.world_shapes(source), margin=margin))

    def colliding_pairs(self, P0: np.ndarray, P1: np.ndarray, radii: np.ndarray | None = None,
                        margin: float = 0.0) -> list[tuple[str, str, float]]:
        """The pairs of one posture closer than ``margin``: (name, name, signed distance)."""
        d = self.self_distances(P0, P1, radii)
        if d.ndim != 1:
            raise ValueError("colliding_pairs takes one posture, not a batch")
        return [(*self.pairs[k], float(d[k])) for k in np.flatnonzero(d < margin)]

    # ------------------------------------------------------------ helpers
    def _oMf(self, source: Any):
        if isinstance(source, np.ndarray) or isinstance(source, (list, tuple)):
            q = np.asarray(source, dtype=float)
            if q.shape != (self.robot.model.nq,):
                raise ValueError(f"expected a configuration of shape ({self.robot.model.nq},), got {q.shape}")
            return self.robot.forward(q).oMf
        if hasattr(source, "oMf"):
            return source.oMf
        return source


# ------------------------------------------------------------------ geometry
def point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance from points ``p`` to segments ``a -> b`` (all (..., 3), broadcast).

    Returns ``(dist, u)`` with the closest segment point ``a + u (b - a)``,
    ``u`` in [0, 1]; a zero-length segment gives ``u = 0``.
    """
    p, a, b = np.asarray(p, float), np.asarray(a, float), np.asarray(b, float)
    d = b - a
    dd = np.einsum("...i,...i->...", d, d)
    w = p - a
    num = np.einsum("...i,...i->...", w, d)
    safe = np.where(dd > 0.0, dd, 1.0)
    u = np.clip(np.where(dd > 0.0, num / safe, 0.0), 0.0, 1.0)
    diff = w - u[..., None] * d
    return np.sqrt(np.einsum("...i,...i->...", diff, diff)), u


def segment_segment_distance(
    a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact distance between segments ``a0 -> a1`` and ``b0 -> b1`` (all (..., 3), broadcast).

    Returns ``(dist, s, t)``: closest points ``a0 + s (a1 - a0)`` and
    ``b0 + t (b1 - b0)`` with ``s, t`` in [0, 1].

    The squared distance is a convex quadratic on the unit square [0, 1]^2; its
    minimum is either the unconstrained stationary point (when that lies inside) or
    on an edge of the square, i.e. the distance from one segment's end to the other
    segment. Taking the minimum over these five candidates is exact and stays robust
    for parallel segments (no unique stationary point: an edge candidate attains the
    minimum) and for zero-length segments (spheres), without branching.
    """
    a0, a1, b0, b1 = (np.asarray(x, dtype=float) for x in (a0, a1, b0, b1))
    shape = np.broadcast_shapes(a0.shape, a1.shape, b0.shape, b1.shape)
    a0, a1, b0, b1 = (np.broadcast_to(x, shape) for x in (a0, a1, b0, b1))
    d1 = a1 - a0
    d2 = b1 - b0
    r = a0 - b0
    a = _dot(d1, d1)
    e = _dot(d2, d2)
    b = _dot(d1, d2)
    c = _dot(d1, r)
    f = _dot(d2, r)

    # candidates 0-3, the edges of the parameter square: a0 and a1 against segment B,
    # b0 and b1 against segment A (one stacked point-segment computation)
    pts = np.stack([a0, a1, b0, b1])
    base = np.stack([b0, b0, a0, a0])
    dirs = np.stack([d2, d2, d1, d1])
    lens = np.stack([e, e, a, a])
    w = pts - base
    nonzero = lens > 0.0
    u = np.clip(np.where(nonzero, _dot(w, dirs) / np.where(nonzero, lens, 1.0), 0.0), 0.0, 1.0)
    diff = w - u[..., None] * dirs
    sq = np.empty((5,) + shape[:-1])
    sq[:4] = _dot(diff, diff)

    # candidate 4: the stationary point of |r + s d1 - t d2|^2, when the segments are
    # not parallel (nor degenerate) and it lies inside the square
    denom = a * e - b * b
    ok = denom > 1e-12 * a * e
    safe = np.where(ok, denom, 1.0)
    s_in = (b * f - c * e) / safe
    t_in = (a * f - b * c) / safe
    ok &= (s_in >= 0.0) & (s_in <= 1.0) & (t_in >= 0.0) & (t_in <= 1.0)
    s_in = np.where(ok, s_in, 0.0)
    t_in = np.where(ok, t_in, 0.0)
    diff_in = r + s_in[..., None] * d1 - t_in[..., None] * d2
    sq[4] = np.where(ok, _dot(diff_in, diff_in), np.inf)

    best = np.argmin(sq, axis=0)[None]
    zeros = np.zeros(shape[:-1])
    ones = np.ones(shape[:-1])
    s_all = np.stack([zeros, ones, u[2], u[3], s_in])
    t_all = np.stack([u[0], u[1], zeros, ones, t_in])
    dist = np.sqrt(np.take_along_axis(sq, best, axis=0)[0])
    return dist, np.take_along_axis(s_all, best, axis=0)[0], np.take_along_axis(t_all, best, axis=0)[0]


def _dot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", x, y)


def capsule_distance(a0, a1, ra, b0, b1, rb) -> np.ndarray:
    """Signed distance between capsules (spheres when an ``a0 == a1``), broadcast."""
    d, _, _ = segment_segment_distance(a0, a1, b0, b1)
    return d - np.asarray(ra, float) - np.asarray(rb, float)


# ------------------------------------------------------------------ loading
def load_collision_model(
    path: str | Path | None, model: "RobotModel", padding_m: float | None = None
) -> CollisionModel:
    """Load and validate a collision model YAML (``None``: ``model.collision_path``).

    ``padding_m`` overrides the file's global safety margin (added to every radius).
    Raises ValueError naming the offending entry for: unknown top-level keys,
    unknown links, malformed shapes, non-positive radii, duplicate shape names,
    pairs naming unknown shapes, a shape paired with itself or a repeated pair.
    """
    path = Path(model.collision_path if path is None else path)
    with open(path) as f:
        doc = yaml.safe_load(f)
    return collision_model_from_dict(doc, model, padding_m, source=str(path))


def collision_model_from_dict(
    doc: Any, model: "RobotModel", padding_m: float | None = None, source: str = "<dict>"
) -> CollisionModel:
    """:func:`load_collision_model` from an already parsed document."""
    where = f"collision model {source}"
    top_level(doc, _TOP_KEYS, where)
    if padding_m is None:
        padding_m = doc.get("padding_m", 0.0)
    padding = number(padding_m, f"{where}: padding_m")
    if padding < 0.0:
        raise ValueError(f"{where}: padding_m must be >= 0, got {padding}")

    links = doc.get("links")
    if not isinstance(links, dict) or not links:
        raise ValueError(f"{where}: 'links' must be a non-empty mapping link -> list of shapes")
    shapes: list[Shape] = []
    seen: dict[str, str] = {}
    for link, entries in links.items():
        if not model.model.existFrame(str(link)):
            raise ValueError(f"{where}: unknown link {link!r} (not a frame of {model.urdf_path.name})")
        if not isinstance(entries, list) or not entries:
            raise ValueError(f"{where}: link {link!r}: expected a non-empty list of shapes")
        for k, entry in enumerate(entries):
            shape = _parse_shape(entry, str(link), f"{where}: link {link!r} shape #{k}")
            if shape.name in seen:
                raise ValueError(
                    f"{where}: duplicate shape name {shape.name!r} (links {seen[shape.name]!r} and {link!r})"
                )
            seen[shape.name] = str(link)
            shapes.append(shape)

    raw_pairs = doc.get("self_collision_pairs", []) or []
    if not isinstance(raw_pairs, list):
        raise ValueError(f"{where}: 'self_collision_pairs' must be a list of [shape, shape]")
    pairs: list[tuple[str, str]] = []
    seen_pairs: set[frozenset[str]] = set()
    for k, p in enumerate(raw_pairs):
        if not isinstance(p, (list, tuple)) or len(p) != 2:
            raise ValueError(f"{where}: self_collision_pairs #{k}: expected [shape, shape], got {p!r}")
        a, b = (str(x) for x in p)
        for n in (a, b):
            if n not in seen:
                raise ValueError(f"{where}: self_collision_pairs #{k} {[a, b]}: unknown shape {n!r}")
        if a == b:
            raise ValueError(f"{where}: self_collision_pairs #{k}: shape {a!r} paired with itself")
        if seen[a] == seen[b]:
            raise ValueError(f"{where}: self_collision_pairs #{k} {[a, b]}: both shapes are on link {seen[a]!r}")
        key = frozenset((a, b))
        if key in seen_pairs:
            raise ValueError(f"{where}: self_collision_pairs #{k}: pair {[a, b]} listed twice")
        seen_pairs.add(key)
        pairs.append((a, b))
    return CollisionModel(model, tuple(shapes), tuple(pairs), padding)


def _parse_shape(entry: Any, link: str, where: str) -> Shape:
    name, where = named_entry(entry, where, f"one of {SHAPE_KINDS}")
    kinds = [k for k in SHAPE_KINDS if k in entry]
    extra = set(entry) - {"name", *SHAPE_KINDS}
    if extra:
        raise ValueError(f"{where}: unknown key(s) {sorted(extra)}")
    if len(kinds) != 1:
        raise ValueError(f"{where}: expected exactly one of {SHAPE_KINDS}, got {kinds or 'none'}")
    kind = kinds[0]
    body = entry[kind]
    if not isinstance(body, dict):
        raise ValueError(f"{where}: {kind} must be a mapping")
    expected = {"center", "radius"} if kind == "sphere" else {"p0", "p1", "radius"}
    if set(body) != expected:
        raise ValueError(f"{where}: {kind} needs keys {sorted(expected)}, got {sorted(body)}")
    radius = number(body["radius"], f"{where}: radius")
    if not radius > 0.0:
        raise ValueError(f"{where}: radius must be > 0, got {radius}")
    if kind == "sphere":
        c = vec3(body["center"], f"{where}: center")
        return Shape(name, link, kind, c, c, radius)
    return Shape(name, link, kind, vec3(body["p0"], f"{where}: p0"), vec3(body["p1"], f"{where}: p1"), radius)


def _ro(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


__all__ = [
    "Shape",
    "CollisionModel",
    "SHAPE_KINDS",
    "load_collision_model",
    "collision_model_from_dict",
    "point_segment_distance",
    "segment_segment_distance",
    "capsule_distance",
]
