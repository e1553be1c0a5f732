"""Reachability maps of the arms, and their inverse over the balanced trunk manifold
(capability map, Zacharias et al. 2007; inverse reachability, Vahrenkamp et al. 2013).

Trained offline per robot (``tools/train_reach_map.py``) into ``config/robots/<name>/``
(robot.yaml ``reach_map``), read at start-up by the planner. Per arm, in the arm's root link
(the chest: fixed in the trunk, Algorithm 1's fixed chest joints), two grids:

* **The outer bound** (``clearance``, the proof of ``TARGET_OUT_OF_REACH``). For every
  voxel centre ``c`` a *lower bound* of the distance from ``c`` to any tip position the arm can
  take within its joint limits. How it stays a lower bound (conservative, never a false "no"):
  the chain is split after joint ``s``: the origin ``o`` of joint ``s + 1`` depends on joints
  ``1..s`` only, and the tip is within ``d_tail = sum |t_k| (k > s + 1) + |t_e|`` of ``o``
  whatever the joints after it do (triangle inequality over the placements). Joints ``1..s``
  are enumerated on a grid of cell centres (``n_j`` values, spacing ``delta_j``): any joint
  vector within the limits is within ``delta_j / 2`` of a grid point in each joint, and turning
  joint ``j`` by ``delta`` moves ``o`` by at most ``delta`` times its lever
  ``L_j = sum |t_k| (j < k <= s + 1)`` (``o``'s distance from joint ``j``'s origin, on its
  axis), so every reachable ``o`` is within ``eps = sum_j delta_j L_j / 2`` of a grid point's.
  The grid points are marked in a fine occupancy grid (cell ``f``); the distance from ``c`` to
  the nearest marked cell's centre minus ``f sqrt(3) / 2``, minus ``eps + d_tail``, is the
  stored bound (floored to ``CLEARANCE_UNIT_M``). A query point ``x`` in voxel ``c`` loses
  ``h sqrt(3) / 2`` more (``h`` the voxel); outside the grid, its distance to the box holding
  the whole outer set. Simplification, named: position only (the hand's orientation and
  collisions are not in the bound), so a target the bound keeps may still have no goal.
* **The capability map** (``pose_start`` / ``pose_rpy``, the sampler's inverse). Uniform
  random joint vectors within the limits through forward kinematics: per voxel
  (``cap_voxel_m``), hand orientations the arm reached there, one per orientation bin reached
  (``ORIENTATION_BINS``: the hand z axis in one of 54 cube-map cells x its x axis in one of 4
  quarter turns about it), at most ``per_voxel`` of them, stored as roll, pitch, yaw in 256
  steps. An inner approximation (a voxel or orientation no sample hit reads as unreached):
  used only to propose goal samples, never to refuse.

The inverse (:class:`InverseReach`): the balanced trunk manifold the planner searches
(:class:`~humanoid_reach_ros.planning.trunk_region.TrunkRegion`'s leg-feasible height x pitch
cells, x roll and yaw cells over their ranges) is gridded into 4-D cells; per target, each
cell's centre puts the target at a point of each arm's root frame. A cell is ruled out for an
arm when the outer bound there exceeds what the trunk can move the target within the cell
(height ``dz / 2``; an orientation within ``theta = (droll + dpitch + dyaw) / 2`` of the
centre's turns ``a = T - p_t`` by at most ``theta |a|`` and moves ``p_t`` (``R_t v``) by at
most ``theta |v|``) plus the region's half diagonal; cells whose bound only that slack spoils
are split in 16 and tried again (``REFINE_LEVELS`` times). No cell left for any allowed arm:
``TARGET_OUT_OF_REACH``, with the smallest gap (the margin) in the message. The cells left
are the goal sampler's trunk cells. A goal sample (:meth:`PoseProposals.propose`) is a trunk
draw from them and a hand position from the region; the hand orientation is one the map
stored in the voxel the position falls in (in the arm's root frame at that trunk pose), kept
when it lies in the region; each sample takes the first of ``candidates`` such proposals (a
plain draw from the region when none fits). Algorithm 1 then decides every sample as before:
the map proposes, the IK disposes. Simplification, named: the proposals' orientations come
from the map's store, not uniformly from the region (every goal is still in the region).

No ROS here.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numba as nb
import numpy as np

from humanoid_reach_ros.codes import ARMS
from humanoid_reach_ros.planning.projector import rpy_into
from humanoid_reach_ros.planning.wgr import WorkspaceGoalRegion, rpy_matrix

MAP_VERSION = 2
CLEARANCE_UNIT_M = 0.005        # the stored bound's unit (uint8, floored: 0 .. 1.275 m)
ORIENTATION_BINS = 54 * 4       # z axis: 6 cube faces x 3 x 3; x axis: 4 quarter turns about z
REFINE_LEVELS = 2               # cells whose bound the slack spoils are split in 16, this many times
_SQRT3_2 = math.sqrt(3.0) / 2.0


# ------------------------------------------------------------------ orientation bins
@nb.njit(cache=True)
def orientation_bin(R) -> int:
    """Bin of a rotation (3, 3) among ``ORIENTATION_BINS``: the z axis's cube-map cell (the
    face of its largest component, its other two components over that one in thirds) x the
    quarter turn of the x axis about z, measured from ``cross(w, z)`` with ``w`` the face's
    next coordinate axis (never parallel to z within its face)."""
    zx, zy, zz = R[0, 2], R[1, 2], R[2, 2]
    ax = 0
    m = abs(zx)
    if abs(zy) > m:
        ax, m = 1, abs(zy)
    if abs(zz) > m:
        ax, m = 2, abs(zz)
    z = (zx, zy, zz)
    neg = 1 if z[ax] < 0.0 else 0
    u = z[(ax + 1) % 3] / m
    v = z[(ax + 2) % 3] / m
    iu = min(2, max(0, int((u + 1.0) * 1.5)))
    iv = min(2, max(0, int((v + 1.0) * 1.5)))
    zbin = (2 * ax + neg) * 9 + iu * 3 + iv
    # e1 = cross(w, z) / |.|, w the unit axis (ax + 1) % 3; e2 = cross(z, e1)
    w0, w1, w2 = 0.0, 0.0, 0.0
    if ax == 0:
        w1 = 1.0
    elif ax == 1:
        w2 = 1.0
    else:
        w0 = 1.0
    e1x, e1y, e1z = w1 * zz - w2 * zy, w2 * zx - w0 * zz, w0 * zy - w1 * zx
    n = math.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
    e1x, e1y, e1z = e1x / n, e1y / n, e1z / n
    e2x, e2y, e2z = zy * e1z - zz * e1y, zz * e1x - zx * e1z, zx * e1y - zy * e1x
    xx, xy, xz = R[0, 0], R[1, 0], R[2, 0]
    ang = math.atan2(xx * e2x + xy * e2y + xz * e2z, xx * e1x + xy * e1y + xz * e1z)
    rbin = int((ang + math.pi) / (0.5 * math.pi)) % 4
    return zbin * 4 + rbin


@nb.njit(cache=True)
def _orientation_bins(R, out) -> None:
    for i in range(R.shape[0]):
        out[i] = orientation_bin(R[i])


def orientation_bins(R: np.ndarray) -> np.ndarray:
    """(N,) bins of rotations (N, 3, 3) (:func:`orientation_bin`)."""
    R = np.ascontiguousarray(np.asarray(R, float).reshape(-1, 3, 3))
    out = np.empty(len(R), np.int64)
    _orientation_bins(R, out)
    return out


# ------------------------------------------------------------------ one arm's map
@dataclass(frozen=True, eq=False)
class ArmMap:
    """One arm's two grids (module doc), in its root link. ``clearance`` (nx, ny, nz) uint8 in
    ``CLEARANCE_UNIT_M``: lower bound of the distance from each voxel centre (``origin + (i +
    0.5) voxel_m``) to the outer set of tip positions; ``box_lo`` / ``box_hi``: a box holding
    that outer set; the capability map on the grid ``cap_origin``, ``cap_voxel_m``,
    ``cap_shape``: voxel ``v`` (flat index) holds the orientations ``pose_rpy[pose_start[v]:
    pose_start[v + 1]]`` (roll, pitch, yaw in 256 steps of 2 pi, :func:`decode_rpy`)."""

    joints: tuple[str, ...]
    origin: np.ndarray
    voxel_m: float
    clearance: np.ndarray
    box_lo: np.ndarray
    box_hi: np.ndarray
    cap_origin: np.ndarray
    cap_voxel_m: float
    cap_shape: np.ndarray
    pose_start: np.ndarray
    pose_rpy: np.ndarray
    meta: dict = field(default_factory=dict)

    def lower_bound(self, x: np.ndarray) -> np.ndarray:
        """(N,) lower bound [m] of the distance from points ``x`` (N, 3) (root frame) to any
        tip position of the arm (<= 0: maybe reachable)."""
        x = np.asarray(x, float).reshape(-1, 3)
        idx = np.floor((x - self.origin) / self.voxel_m).astype(np.int64)
        shape = np.array(self.clearance.shape)
        inside = np.all((idx >= 0) & (idx < shape), axis=1)
        out = np.maximum(0.0, np.max(np.maximum(self.box_lo - x, x - self.box_hi), axis=1))
        i = idx[inside]
        out[inside] = self.clearance[i[:, 0], i[:, 1], i[:, 2]] * CLEARANCE_UNIT_M - self.voxel_m * _SQRT3_2
        return out

    def poses_at(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(first, count)`` (N,) each: where the stored orientations of the voxel of each
        point ``x`` (N, 3) (root frame) start in ``pose_rpy``, and how many (0 outside)."""
        x = np.asarray(x, float).reshape(-1, 3)
        idx = np.floor((x - self.cap_origin) / self.cap_voxel_m).astype(np.int64)
        inside = np.all((idx >= 0) & (idx < self.cap_shape), axis=1)
        v = np.zeros(len(x), np.int64)
        v[inside] = np.ravel_multi_index(idx[inside].T, tuple(self.cap_shape))
        first = self.pose_start[v].astype(np.int64)
        count = np.where(inside, self.pose_start[v + 1] - first, 0)
        return first, count


def encode_rpy(rpy: np.ndarray) -> np.ndarray:
    """Angles (..., 3) [rad] -> uint8 in 256 steps of 2 pi (nearest)."""
    return (np.round((np.asarray(rpy, float) + math.pi) * (256 / (2 * math.pi))).astype(np.int64) % 256).astype(
        np.uint8)


def decode_rpy(code: np.ndarray) -> np.ndarray:
    """:func:`encode_rpy`'s inverse (within pi / 256 of the angle encoded, modulo 2 pi)."""
    return np.asarray(code, float) * (2 * math.pi / 256) - math.pi


@dataclass(frozen=True, eq=False)
class ReachMap:
    """Both arms' maps of one robot (``arms``: arm name -> :class:`ArmMap`), loaded from or
    saved to one ``.npz`` (:meth:`load`, :meth:`save`)."""

    robot: str
    arms: dict
    meta: dict = field(default_factory=dict)

    def save(self, path: str | Path) -> Path:
        path = Path(path).with_suffix(".npz")
        arrays = {}
        for arm, m in self.arms.items():
            for name in ("origin", "clearance", "box_lo", "box_hi", "cap_origin", "cap_shape", "pose_start",
                         "pose_rpy"):
                arrays[f"{arm}.{name}"] = getattr(m, name)
            arrays[f"{arm}.meta"] = np.array(json.dumps({**m.meta, "joints": list(m.joints), "voxel_m": m.voxel_m,
                                                         "cap_voxel_m": m.cap_voxel_m}))
        arrays["meta"] = np.array(json.dumps({**self.meta, "robot": self.robot, "version": MAP_VERSION,
                                              "arms": list(self.arms)}))
        np.savez_compressed(path, **arrays)
        return path

    @classmethod
    def load(cls, path: str | Path, robot=None) -> "ReachMap":
        """The map at ``path`` (``.npz`` added when missing). ValueError naming the file and the
        remedy (``tools/train_reach_map.py``) when it is missing, unreadable, of another
        version or robot, or its arms' joints are not ``robot``'s (a ``RobotModel``)."""
        path = Path(path)
        if path.suffix != ".npz":
            path = path.with_name(path.name + ".npz")
        fix = f"regenerate it: python tools/train_reach_map.py --robot {getattr(robot, 'name', '<name>')}"
        if not path.is_file():
            raise ValueError(f"reach map {path} does not exist: {fix}")
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
            meta = json.loads(str(data["meta"]))
            if meta.get("version") != MAP_VERSION:
                raise ValueError(f"reach map {path} has version {meta.get('version')}, this code reads "
                                 f"{MAP_VERSION}")
            arms = {}
            for arm in meta["arms"]:
                am = json.loads(str(data[f"{arm}.meta"]))
                m = ArmMap(tuple(am["joints"]), data[f"{arm}.origin"].astype(float), float(am["voxel_m"]),
                           data[f"{arm}.clearance"], data[f"{arm}.box_lo"].astype(float),
                           data[f"{arm}.box_hi"].astype(float), data[f"{arm}.cap_origin"].astype(float),
                           float(am["cap_voxel_m"]), data[f"{arm}.cap_shape"].astype(np.int64),
                           data[f"{arm}.pose_start"], data[f"{arm}.pose_rpy"], am)
                _check_arm_map(m)
                arms[arm] = m
        except ValueError as e:
            if str(e).startswith(f"reach map {path}"):
                raise ValueError(f"{e}: {fix}") from None
            if str(e).startswith("reach map"):
                raise ValueError(f"{e} ({path}): {fix}") from None
            raise ValueError(f"reach map {path} is not a readable map ({e}): {fix}") from None
        except (OSError, KeyError, TypeError, json.JSONDecodeError, EOFError) as e:
            raise ValueError(f"reach map {path} is not a readable map ({type(e).__name__}: {e}): {fix}") from None
        if set(arms) != set(ARMS):
            raise ValueError(f"reach map {path} holds arms {sorted(arms)}, expected {list(ARMS)}: {fix}")
        if robot is not None:
            for arm, m in arms.items():
                want = tuple(robot.limbs[f"{arm}_arm"].joints)
                if m.joints != want:
                    raise ValueError(f"reach map {path} was trained for {arm} arm joints {list(m.joints)}, robot "
                                     f"{robot.name!r} has {list(want)}: {fix}")
        return cls(str(meta.get("robot", "")), arms, meta)


def _check_arm_map(m: ArmMap) -> None:
    if m.clearance.ndim != 3 or m.clearance.dtype != np.uint8 or min(m.clearance.shape) < 1:
        raise ValueError(f"reach map: clearance must be a non-empty 3-D uint8 grid, got {m.clearance.shape} "
                         f"{m.clearance.dtype}")
    if m.cap_shape.shape != (3,) or np.any(m.cap_shape < 1):
        raise ValueError(f"reach map: cap_shape must be 3 positive counts, got {m.cap_shape}")
    nv = int(np.prod(m.cap_shape))
    if (m.pose_start.shape != (nv + 1,) or m.pose_rpy.ndim != 2 or m.pose_rpy.shape[1] != 3
            or m.pose_rpy.dtype != np.uint8 or m.pose_start[0] != 0 or m.pose_start[-1] != len(m.pose_rpy)
            or np.any(np.diff(m.pose_start) < 0)):
        raise ValueError(f"reach map: pose_start ({m.pose_start.shape}) must index pose_rpy ({m.pose_rpy.shape} "
                         f"{m.pose_rpy.dtype}) over {nv} voxels")
    for name in ("origin", "box_lo", "box_hi", "cap_origin"):
        a = getattr(m, name)
        if a.shape != (3,) or not np.all(np.isfinite(a)):
            raise ValueError(f"reach map: {name} must be 3 finite numbers, got {a}")
    if not (m.voxel_m > 0 and m.cap_voxel_m > 0):
        raise ValueError(f"reach map: voxel sizes must be > 0, got {m.voxel_m}, {m.cap_voxel_m}")


# ------------------------------------------------------------------ training
def _chain_points(chain, s: int, Q: np.ndarray) -> np.ndarray:
    """Origins of joint ``s + 1`` (0-based index ``s``) in the root for joints ``Q`` (N, s)."""
    from humanoid_reach_ros.kinematics import chain_rotations

    n = len(Q)
    p, R = np.zeros((n, 3)), np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    for k in range(s):
        p = p + R @ chain.t[k]
        R = R @ chain.R[k] @ chain_rotations(chain.axes[k], Q[:, k])
    return p + R @ chain.t[s]


def outer_grid(chain, s: int, max_points: float) -> tuple[list[np.ndarray], float, float]:
    """Joint values of the proof's grid over joints ``1..s`` (cell centres; at most
    ``max_points`` combinations), its ``eps`` and the tail ``d_tail`` (module doc)."""
    norms = np.linalg.norm(chain.t, axis=1)
    n = len(chain.axes)
    tail = float(norms[s + 1:].sum() + np.linalg.norm(chain.te)) if s + 1 <= n else float(np.linalg.norm(chain.te))
    span = chain.upper[:s] - chain.lower[:s]
    lever = np.array([norms[j + 1:s + 1].sum() for j in range(s)])
    w = np.maximum(span * lever, 1e-9)
    lo, hi = 1e-6, 10.0          # c: each joint's eps share is c / 2; bisect so prod(n_j) <= max_points

    def counts(c):
        return np.maximum(1, np.ceil(w / c)).astype(np.int64)

    for _ in range(60):
        mid = math.sqrt(lo * hi)
        if float(np.prod(counts(mid).astype(float))) > max_points:
            lo = mid
        else:
            hi = mid
    nj = counts(hi)
    eps = float(np.sum(span / nj * lever) / 2)
    return [chain.lower[j] + (np.arange(nj[j]) + 0.5) * span[j] / nj[j] for j in range(s)], eps, tail


def train_arm_map(chain, joints, rng: np.random.Generator, *, split: int | None = None, max_points: float = 2e7,
                  fine_m: float = 0.01, voxel_m: float = 0.025, cap_voxel_m: float = 0.04,
                  cap_samples: int = 2_000_000, per_voxel: int = 24,
                  cap_box: tuple[np.ndarray, np.ndarray] | None = None,
                  chunk: int = 500_000, log=print) -> ArmMap:
    """One arm's :class:`ArmMap` from its chain (``kinematics.Chain6``: placements, axes,
    tip, limits; module doc for the method). ``split``: joints gridded (None: the one of
    3..n-1 with the least ``eps + d_tail``); ``cap_box``: the capability grid's box (both arms
    share one); ``cap_samples`` random joint vectors for it, ``per_voxel`` orientations kept
    per voxel."""
    from scipy.spatial import cKDTree

    n = len(chain.axes)
    if split is None:
        best = None
        for s in range(3, n):
            g, eps, tail = outer_grid(chain, s, max_points)
            if best is None or eps + tail < best[1] + best[2] - 1e-9:
                best = (s, eps, tail, g)
        split, eps, tail, grid = best
    else:
        grid, eps, tail = outer_grid(chain, split, max_points)
    r = eps + tail + 1e-3
    reach = float(np.linalg.norm(chain.t, axis=1).sum())
    f_lo = -reach - fine_m
    nf = int(math.ceil(2 * (reach + fine_m) / fine_m))
    occ = np.zeros((nf, nf, nf), bool)
    sizes = [len(g) for g in grid]
    total = int(np.prod(sizes))
    for a in range(0, total, chunk):
        idx = np.unravel_index(np.arange(a, min(total, a + chunk)), sizes)
        Q = np.stack([grid[j][idx[j]] for j in range(split)], axis=1)
        o = _chain_points(chain, split, Q)
        k = np.floor((o - f_lo) / fine_m).astype(np.int64)
        occ[k[:, 0], k[:, 1], k[:, 2]] = True
    cells = np.argwhere(occ)
    centres = f_lo + (cells + 0.5) * fine_m
    box_lo, box_hi = centres.min(axis=0) - fine_m * _SQRT3_2 - r, centres.max(axis=0) + fine_m * _SQRT3_2 + r
    origin = box_lo - 2 * voxel_m
    shape = np.ceil((box_hi + 2 * voxel_m - origin) / voxel_m).astype(np.int64)
    vc = origin + (np.stack(np.meshgrid(*[np.arange(s_) for s_ in shape], indexing="ij"), -1).reshape(-1, 3)
                   + 0.5) * voxel_m
    d, _ = cKDTree(centres).query(vc, workers=1)
    low = np.maximum(0.0, d - fine_m * _SQRT3_2 - r)
    clearance = np.minimum(255, np.floor(low / CLEARANCE_UNIT_M)).astype(np.uint8).reshape(tuple(shape))
    log(f"  outer bound: joints 1..{split} on a {'x'.join(map(str, sizes))} grid ({total:,} points), "
        f"eps {eps:.3f} m, tail {tail:.3f} m, {len(cells):,} fine cells; {np.count_nonzero(clearance == 0):,} of "
        f"{clearance.size:,} voxels maybe reachable")
    meta = {"split": int(split), "eps_m": eps, "tail_m": tail, "grid": sizes, "fine_m": fine_m}
    if cap_box is None:
        cap_box = (box_lo, box_hi)
    shape, start, rpy = capability_poses(chain, rng, cap_box, cap_voxel_m, cap_samples, per_voxel, chunk)
    log(f"  capability: {cap_samples:,} samples, {int(np.count_nonzero(np.diff(start))):,} voxels reached, "
        f"{len(rpy):,} orientations kept")
    return ArmMap(tuple(joints), origin, float(voxel_m), clearance, box_lo, box_hi, np.asarray(cap_box[0], float),
                  float(cap_voxel_m), shape, start, rpy, {**meta, "cap_samples": int(cap_samples),
                                                          "per_voxel": int(per_voxel)})


def capability_poses(chain, rng: np.random.Generator, box, voxel_m: float, samples: int, per_voxel: int = 24,
                     chunk: int = 500_000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The capability map (module doc): ``samples`` uniform random joint vectors within the
    limits through the chain's forward kinematics; per voxel of the grid from ``box[0]``
    (``voxel_m``), the first orientation reached in each orientation bin, at most
    ``per_voxel`` of them (a random subset). Returns ``(shape (3,), start (V + 1,) int32,
    rpy (M, 3) uint8)``."""
    from humanoid_reach_ros.planning.wgr import matrix_rpy

    origin = np.asarray(box[0], float)
    shape = np.ceil((np.asarray(box[1], float) - origin) / voxel_m).astype(np.int64)
    n = len(chain.axes)
    keys, codes = [np.zeros(0, np.int64)], [np.zeros((0, 3), np.uint8)]
    for a in range(0, samples, chunk):
        m = min(chunk, samples - a)
        q = rng.uniform(chain.lower, chain.upper, size=(m, n))
        p, R = chain.fk(q)
        k = np.floor((p - origin) / voxel_m).astype(np.int64)
        ok = np.all((k >= 0) & (k < shape), axis=1)
        key = np.ravel_multi_index(k[ok].T, tuple(shape)) * ORIENTATION_BINS + orientation_bins(R[ok])
        u, i = np.unique(key, return_index=True)
        keys.append(u)
        codes.append(encode_rpy(matrix_rpy(R[ok][i])))
    key, code = np.concatenate(keys), np.concatenate(codes)
    u, i = np.unique(key, return_index=True)       # the first of each (voxel, bin)
    code = code[i]
    vox = u // ORIENTATION_BINS
    keep = np.ones(len(u), bool)                    # at most per_voxel per voxel: a random subset
    order = np.lexsort((rng.random(len(u)), vox))
    vs = vox[order]
    rank = np.arange(len(vs)) - np.searchsorted(vs, vs)
    keep[order[rank >= per_voxel]] = False
    vox, code = vox[keep], code[keep]
    start = np.searchsorted(vox, np.arange(int(np.prod(shape)) + 1)).astype(np.int32)
    return shape, start, code


# ------------------------------------------------------------------ the inverse over the trunk manifold
@nb.njit(cache=True, nogil=False, fastmath=False)
def _cell_gaps(cells, half, T, v, cog_xy, chest_p, chest_R, extent, clearance, origin, voxel, box_lo, box_hi,
               cap_origin, cap_voxel, cap_shape, pose_start, centre, gap, held):
    """:meth:`InverseReach._gaps`, compiled: per cell (z, roll, pitch, yaw) the trunk pose of
    Algorithm 1's lines 2-4, the target ``T`` in the arm's root frame, the outer bound there
    (:meth:`ArmMap.lower_bound`) minus ``extent`` (``centre``), and minus the cell's slack
    (``gap``): ``dz + theta |v| + theta (|a| + dz + theta |v|)``, ``theta`` the half sizes'
    roll + pitch + yaw, ``a = T - p_t``; ``held``: the orientations the capability map holds
    in the voxel of the target's point (:meth:`ArmMap.poses_at`)."""
    R = np.empty((3, 3))
    nx, ny, nz = clearance.shape
    theta = half[1] + half[2] + half[3]
    dz = half[0]
    vn = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    for i in range(cells.shape[0]):
        rpy_into(R, cells[i, 1], cells[i, 2], cells[i, 3])
        a0 = T[0] - (R[0, 0] * v[0] + R[0, 1] * v[1] + R[0, 2] * v[2] + cog_xy[0])
        a1 = T[1] - (R[1, 0] * v[0] + R[1, 1] * v[1] + R[1, 2] * v[2] + cog_xy[1])
        a2 = T[2] - cells[i, 0]
        # R^T a - chest_p, then chest_R^T of it
        b0 = R[0, 0] * a0 + R[1, 0] * a1 + R[2, 0] * a2 - chest_p[0]
        b1 = R[0, 1] * a0 + R[1, 1] * a1 + R[2, 1] * a2 - chest_p[1]
        b2 = R[0, 2] * a0 + R[1, 2] * a1 + R[2, 2] * a2 - chest_p[2]
        x0 = chest_R[0, 0] * b0 + chest_R[1, 0] * b1 + chest_R[2, 0] * b2
        x1 = chest_R[0, 1] * b0 + chest_R[1, 1] * b1 + chest_R[2, 1] * b2
        x2 = chest_R[0, 2] * b0 + chest_R[1, 2] * b1 + chest_R[2, 2] * b2
        ix = int(math.floor((x0 - origin[0]) / voxel))
        iy = int(math.floor((x1 - origin[1]) / voxel))
        iz = int(math.floor((x2 - origin[2]) / voxel))
        if 0 <= ix < nx and 0 <= iy < ny and 0 <= iz < nz:
            lb = clearance[ix, iy, iz] * CLEARANCE_UNIT_M - voxel * _SQRT3_2
        else:
            lb = max(0.0, box_lo[0] - x0, x0 - box_hi[0], box_lo[1] - x1, x1 - box_hi[1], box_lo[2] - x2,
                     x2 - box_hi[2])
        jx = int(math.floor((x0 - cap_origin[0]) / cap_voxel))
        jy = int(math.floor((x1 - cap_origin[1]) / cap_voxel))
        jz = int(math.floor((x2 - cap_origin[2]) / cap_voxel))
        if 0 <= jx < cap_shape[0] and 0 <= jy < cap_shape[1] and 0 <= jz < cap_shape[2]:
            f = (jx * cap_shape[1] + jy) * cap_shape[2] + jz
            held[i] = pose_start[f + 1] - pose_start[f]
        else:
            held[i] = 0
        na = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
        centre[i] = lb - extent
        gap[i] = lb - extent - (dz + theta * vn + theta * (na + dz + theta * vn))


@dataclass(frozen=True, eq=False)
class PoseProposals:
    """Goal samples the capability map proposes (module doc): Algorithm 1's trunk pose (``v``,
    ``COG_approx``), the trunk -> chest transform and the arms' maps (``codes.ARMS`` order)."""

    v: np.ndarray
    cog_xy: np.ndarray
    chest_p: np.ndarray
    chest_R: np.ndarray
    arms: dict

    def propose(self, rng: np.random.Generator, region: WorkspaceGoalRegion, z: np.ndarray, rpy: np.ndarray,
                p_e: np.ndarray, arm_names) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For trunk poses ``z`` (N,), ``rpy`` (N, 3) and hand positions ``p_e`` (N, 3): hand
        rotations (N, 3, 3) one of ``arm_names`` (each sample's at random) reached in the
        voxel of ``p_e`` in its root frame, ``ok`` (N,): a stored orientation exists there
        and lies in ``region``, and how many orientations that voxel holds (N,): few at the
        reachable set's border, where a voxel is reachable only in part."""
        n = len(z)
        R_t = rpy_matrix(rpy)
        p_t = np.einsum("nij,j->ni", R_t, self.v)
        p_t[:, :2] += self.cog_xy
        p_t[:, 2] = z
        c_R = R_t @ self.chest_R
        c_p = p_t + R_t @ self.chest_p
        x = np.einsum("nji,nj->ni", c_R, p_e - c_p)
        which = rng.integers(0, len(arm_names), n)
        code = np.zeros((n, 3), np.uint8)
        has = np.zeros(n, bool)
        held = np.zeros(n, np.int64)
        for k, a in enumerate(arm_names):
            rows = np.flatnonzero(which == k)
            m = self.arms[a]
            first, count = m.poses_at(x[rows])
            got = count > 0
            pick = first + np.floor(rng.random(len(rows)) * np.maximum(count, 1)).astype(np.int64)
            code[rows[got]] = m.pose_rpy[pick[got]]
            has[rows] = got
            held[rows] = count
        R_e = c_R @ rpy_matrix(decode_rpy(code))
        ok = has.copy()
        if has.any():
            ok[has] = region.contains(p_e[has], R_e[has], tol=1e-9)
        return R_e, ok, held


class InverseReach:
    """The map's inverse over a :class:`~humanoid_reach_ros.planning.trunk_region.TrunkRegion`
    (module doc): :meth:`for_target` proves a region out of reach or gives the trunk cells a
    goal may have. ``step_rad``: the roll and yaw cells' size (the region's height x pitch
    cells are its own)."""

    def __init__(self, reach_map: ReachMap, region, step_rad: float = 0.05) -> None:
        self.map = reach_map
        self.region = region
        pj = region.projector
        self.v = np.array(pj.v, float)
        self.cog_xy = np.array(pj.cog_approx_xy, float)
        self.chest_p = np.array(pj.chest_p_in_trunk, float)
        self.chest_R = np.array(pj.chest_R_in_trunk, float)
        rolls, self.droll = _cells(region.roll, step_rad)
        yaws, self.dyaw = _cells(region.yaw, step_rad)
        zs, ps = region.z_grid[region.feasible], region.pitch_grid[region.feasible]
        Z, R_, Y = (g.ravel() for g in np.meshgrid(np.arange(len(zs)), np.arange(len(rolls)), np.arange(len(yaws)),
                                                    indexing="ij"))
        #: (N, 4) cell centres (z, roll, pitch, yaw) and half sizes
        self.cells = np.stack([zs[Z], rolls[R_], ps[Z], yaws[Y]], axis=1)
        self.half = np.array([region.dz / 2, self.droll / 2, region.dpitch / 2, self.dyaw / 2])
        self.proposals = PoseProposals(self.v, self.cog_xy, self.chest_p, self.chest_R, dict(reach_map.arms))

    def _gaps(self, arm: str, T: np.ndarray, cells: np.ndarray, half: np.ndarray,
              extent: float) -> tuple[np.ndarray, np.ndarray]:
        """``(centre, gap)`` (N,) each: the bound at each cell's centre pose (<= 0: the centre
        itself may reach a point within ``extent`` of ``T``), and a lower bound of how far
        ``arm``'s hand stays from such a point at any trunk pose of the cell (centre ``cells``,
        half sizes ``half``; <= 0: not ruled out)."""
        centre, gap, _ = self._cell_bounds(arm, T, cells, half, extent)
        return centre, gap

    def _cell_bounds(self, arm, T, cells, half, extent) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`_gaps` and the capability map's orientations at the target per cell centre."""
        m = self.map.arms[arm]
        n = len(cells)
        centre, gap, held = np.empty(n), np.empty(n), np.empty(n, np.int64)
        _cell_gaps(np.ascontiguousarray(cells, dtype=float), np.asarray(half, float), np.asarray(T, float), self.v,
                   self.cog_xy, self.chest_p, self.chest_R, float(extent), m.clearance, m.origin, m.voxel_m,
                   m.box_lo, m.box_hi, m.cap_origin, m.cap_voxel_m, m.cap_shape, m.pose_start, centre, gap, held)
        return centre, gap, held

    def held(self, region: WorkspaceGoalRegion, cells: np.ndarray, arm_names) -> np.ndarray:
        """(M,) orientations the capability map holds at the region's centre from each cell's
        centre pose (the most of ``arm_names``): few where the target is at the border of the
        reachable set (a voxel reachable only in part), where proposals seldom solve."""
        T = region_centre(region)
        return np.max([self._cell_bounds(a, T, cells, self.half, 0.0)[2] for a in arm_names], axis=0)

    def _refine(self, arm: str, T: np.ndarray, extent: float, todo: np.ndarray) -> tuple[np.ndarray, float]:
        """The cells ``todo`` (indices) that their slack alone keeps (centre ruled out), split in
        16 and tried again ``REFINE_LEVELS`` times: (indices still kept, smallest gap of the
        sub-cells ruled out)."""
        cells, half, owner = self.cells[todo], self.half, todo
        kept, best = [], math.inf
        offs = np.array(np.meshgrid(*[[-0.5, 0.5]] * 4, indexing="ij")).reshape(4, -1).T   # 16 sub-cells
        for level in range(REFINE_LEVELS):
            if not len(cells):
                break
            half = half / 2
            sub = (cells[:, None, :] + offs[None] * 2 * half).reshape(-1, 4)
            own = np.repeat(owner, len(offs))
            c, g = self._gaps(arm, T, sub, half, extent)
            alive = g <= 0
            if (~alive).any():
                best = min(best, float(g[~alive].min()))
            done = alive & ((c <= 0) | (level == REFINE_LEVELS - 1))   # kept for good
            kept.append(own[done])
            more = alive & ~done
            cells, owner = sub[more], own[more]
        return np.unique(np.concatenate(kept)) if kept else np.zeros(0, np.int64), best

    def for_target(self, region: WorkspaceGoalRegion, arm_names) -> tuple[str | None, np.ndarray, dict]:
        """``(message, cells, per_arm)``: a message naming the margin when no cell is left for
        any of ``arm_names`` (the proof), else None; the cells (M, 4) left for any of them (the
        sampler's: cells only their slack keeps are kept too, unless a proof needs them split);
        per arm the cells left and the smallest gap [m] of those ruled out."""
        lo, hi = np.asarray(region.lower[:3], float), np.asarray(region.upper[:3], float)
        T = region_centre(region)
        extent = float(np.linalg.norm(hi - lo) / 2)
        first = {a: self._gaps(a, T, self.cells, self.half, extent) for a in arm_names}
        per = {}
        keep = np.zeros(len(self.cells), bool)
        for a, (_, g) in first.items():
            k = g <= 0
            per[a] = (int(k.sum()), float(g[~k].min()) if (~k).any() else math.inf)
            keep |= k
        if any(bool((c <= 0).any()) for c, _ in first.values()):   # a centre pose may reach: no proof
            return None, self.cells[keep], per
        keep[:] = False     # every centre is ruled out: split the cells their slack keeps
        for a, (_, g) in first.items():
            idx, best = self._refine(a, T, extent, np.flatnonzero(g <= 0))
            keep[idx] = True
            per[a] = (len(idx), min(per[a][1], best))
        if keep.any():
            return None, self.cells[keep], per
        gap = min(g for _, g in per.values())
        eps = max(self.map.arms[a].meta.get("eps_m", 0.0) for a in arm_names)
        both = " and ".join(arm_names)
        msg = (f"the reach map proves the {both} hand{'s' if len(arm_names) > 1 else ''} at least {gap:.3f} m short "
               f"at every balanced trunk posture searched ({len(self.cells)} cells: trunk z "
               f"{self.region.z_span[0]:.2f}..{self.region.trunk_z_max:.2f} m, roll {self.region.roll[0]:.2f}.."
               f"{self.region.roll[1]:.2f}, pitch {self.region.pitch_span[0]:.2f}..{self.region.pitch_span[1]:.2f}, "
               f"yaw {self.region.yaw[0]:.2f}..{self.region.yaw[1]:.2f} rad; the bound errs long by its joint grid "
               f"{eps:.3f} m, its voxels and each cell's trunk motion)")
        return msg, self.cells[:0], per

    def describe(self) -> str:
        m = self.map.arms[ARMS[0]]
        return (f"reach map ({len(self.cells)} trunk cells of {self.droll:.3f} x {self.dyaw:.3f} rad roll x yaw; "
                f"bound eps {m.meta.get('eps_m', 0):.3f} m + voxel {m.voxel_m:.3f} m)")


def _cells(r: tuple[float, float], step: float) -> tuple[np.ndarray, float]:
    n = max(1, int(math.ceil((r[1] - r[0]) / step - 1e-9)))
    d = (r[1] - r[0]) / n
    return r[0] + (np.arange(n) + 0.5) * d, d


def region_centre(region: WorkspaceGoalRegion) -> np.ndarray:
    """World centre of the region's position box."""
    lo, hi = np.asarray(region.lower[:3], float), np.asarray(region.upper[:3], float)
    return np.asarray(region.target_p, float) + np.asarray(region.target_R, float) @ ((lo + hi) / 2)


__all__ = ["ArmMap", "ReachMap", "InverseReach", "PoseProposals", "train_arm_map", "capability_poses",
           "orientation_bin", "orientation_bins", "encode_rpy", "decode_rpy", "ORIENTATION_BINS", "MAP_VERSION"]
