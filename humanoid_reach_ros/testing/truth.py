"""The truth a plan is audited against: the robot's capsules vs a scene file's primitives.

``bench/unseen.py`` (issue 31) checks every trajectory the running graph returned against the
scene file's TRUE geometry (``sim/scene.py``'s primitives), not against any voxel map: exact
signed distances, no padding.

**Capsule vs primitive.** A capsule is the segment ``s(u) = P0 + u (P1 - P0)``, ``u`` in
[0, 1], grown by ``r``. With ``f`` the primitive's signed distance (``Primitive.sdf``: exact
outside, and inside for a box, cylinder, sphere, plane and torus, each alone),

    d = min_u f(s(u)) - r

is the capsule's signed distance to the solid: the exact clearance when positive; when
negative, ``-d`` is how deep the capsule reaches in (its axis's deepest point inside the
solid, plus its radius: the penetration depth reported). ``f`` along a line is convex for
the convex primitives (box, finite cylinder, sphere, plane: the signed distance of a convex
set), so the minimum lies within one step of the best of ``samples`` equally spaced points
and a ternary search in that bracket finds it to ``(2/3)^iters`` of the step. The torus is
not convex: the samples are then spaced at most half its tube radius apart (a local minimum
narrower than that is missed: a simplification, named), and the same refinement follows.

**A trajectory.** Its samples (the ``JointTrajectory`` points) rebuilt as the executor
rebuilds them (``SplineTrajectory`` through them in model joint order), evaluated at every
sample and at ``substeps`` points between two (more where a shape's end moves further than
``step_m`` between samples); the waist put on the feet as the kinematic plant does
(``RobotModel.base_on_feet``); every capsule of the collision model with its file radius
(``CollisionModel.base_radii``, no padding) against every non-floor primitive.

No ROS here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from humanoid_reach_ros.geometry.trajectory import SplineTrajectory
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.shapes import CollisionModel
from humanoid_reach_ros.sim.scene import Primitive, Torus

SEGMENT_SAMPLES = 16      # points along a capsule's axis before the bracket is refined
REFINE_ITERS = 60         # ternary steps in the bracket: (2/3)^60 ~ 3e-11 of a sample step
SUBSTEPS = 8              # trajectory points evaluated between two samples at least ...
STEP_M = 0.01             # ... and more where a shape's end moves further than this between samples


def segment_min_sdf(prim: Primitive, P0: np.ndarray, P1: np.ndarray, samples: int = SEGMENT_SAMPLES,
                    iters: int = REFINE_ITERS) -> tuple[np.ndarray, np.ndarray]:
    """``(min_u f(s(u)), u*)`` (N,) each for segments ``P0 -> P1`` (N, 3) and the primitive's
    signed distance ``f`` (module doc). ValueError on malformed input."""
    P0 = np.asarray(P0, float)
    P1 = np.asarray(P1, float)
    if P0.ndim != 2 or P0.shape[1] != 3 or P1.shape != P0.shape:
        raise ValueError(f"segment ends must both be (N, 3), got {P0.shape} and {P1.shape}")
    if not (np.all(np.isfinite(P0)) and np.all(np.isfinite(P1))):
        raise ValueError("segment ends contain NaN or inf")
    n = len(P0)
    if n == 0:
        return np.zeros(0), np.zeros(0)
    D = P1 - P0
    k = int(samples)
    if isinstance(prim, Torus):   # not convex: samples at most half the tube radius apart
        longest = float(np.linalg.norm(D, axis=1).max())
        k = max(k, int(math.ceil(longest / (0.5 * prim.minor_radius))) + 1)
    k = max(k, 2)
    U = np.linspace(0.0, 1.0, k)
    F = prim.sdf((P0[:, None, :] + U[None, :, None] * D[:, None, :]).reshape(-1, 3)).reshape(n, k)
    best = np.argmin(F, axis=1)
    step = 1.0 / (k - 1)
    lo = np.clip(U[best] - step, 0.0, 1.0)
    hi = np.clip(U[best] + step, 0.0, 1.0)

    def f(u: np.ndarray) -> np.ndarray:
        return prim.sdf(P0 + u[:, None] * D)
    for _ in range(int(iters)):
        a = lo + (hi - lo) / 3.0
        b = hi - (hi - lo) / 3.0
        left = f(a) <= f(b)
        hi = np.where(left, b, hi)
        lo = np.where(left, lo, a)
    u = 0.5 * (lo + hi)
    fu = f(u)
    sampled = F[np.arange(n), best]
    better = sampled < fu           # never worse than the best sample
    return np.where(better, sampled, fu), np.where(better, U[best], u)


def capsule_signed_distance(prim: Primitive, P0: np.ndarray, P1: np.ndarray, radii) -> np.ndarray:
    """Signed distance (N,) of capsules (``P0``, ``P1`` (N, 3), ``radii`` (N,) or scalar) to the
    primitive: ``< 0`` penetrating (its negative is the depth), exact clearance otherwise."""
    d, _ = segment_min_sdf(prim, P0, P1)
    return d - np.broadcast_to(np.asarray(radii, float), d.shape)


@dataclass(frozen=True)
class TruthContact:
    """The nearest (or deepest) pair found: distance [m] (< 0: penetration), the primitive's and
    the shape's names, the time [s, trajectory clock] and the index of the evaluated configuration."""

    distance_m: float
    primitive: str
    shape: str
    time_s: float
    index: int

    @property
    def penetrating(self) -> bool:
        return self.distance_m < 0.0


def shapes_vs_primitives(prims: Sequence[Primitive], P0: np.ndarray, P1: np.ndarray, radii: np.ndarray,
                         near_m: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Per capsule (``P0``, ``P1`` (M, 3), ``radii`` (M,)): the least signed distance to any of
    ``prims`` and the index of that primitive (-1: none within ``near_m``, distance ``near_m``).
    A capsule whose box (grown by ``near_m``) misses a primitive's bounds is not evaluated
    against it (exact: it is farther than ``near_m``)."""
    P0 = np.asarray(P0, float)
    P1 = np.asarray(P1, float)
    R = np.broadcast_to(np.asarray(radii, float), (len(P0),))
    best = np.full(len(P0), float(near_m))
    which = np.full(len(P0), -1, dtype=np.intp)
    lo = np.minimum(P0, P1) - R[:, None] - near_m
    hi = np.maximum(P0, P1) + R[:, None] + near_m
    for k, prim in enumerate(prims):
        plo, phi = prim.bounds()
        sel = np.flatnonzero(np.all(hi >= plo, axis=1) & np.all(lo <= phi, axis=1))
        if not len(sel):
            continue
        d = capsule_signed_distance(prim, P0[sel], P1[sel], R[sel])
        closer = d < best[sel]
        best[sel[closer]] = d[closer]
        which[sel[closer]] = k
    return best, which


def sample_times(times: np.ndarray, segment_substeps: np.ndarray) -> np.ndarray:
    """The sample times and ``segment_substeps[i]`` equally spaced times inside each interval."""
    t = np.asarray(times, float)
    out = [t[:1]]
    for i in range(len(t) - 1):
        m = int(segment_substeps[i])
        out.append(t[i] + (t[i + 1] - t[i]) * np.arange(1, m + 2) / (m + 1))
    return np.concatenate(out)


def model_positions(robot: RobotModel, joint_names: Sequence[str], positions) -> np.ndarray:
    """A trajectory's positions (K, len(joint_names)) in model joint order (K, n); KeyError
    naming a model joint the trajectory lacks."""
    pos = np.asarray(positions, float).reshape(len(positions), -1)
    names = list(joint_names)
    missing = [n for n in robot.joint_names if n not in names]
    if missing:
        raise KeyError(f"the trajectory lacks the joints {missing[:4]}")
    return pos[:, [names.index(n) for n in robot.joint_names]]


class TrajectoryAudit:
    """A robot's capsules along trajectories vs a scene's true primitives (module doc)."""

    def __init__(self, robot: RobotModel, collision_model: CollisionModel, prims: Sequence[Primitive],
                 substeps: int = SUBSTEPS, step_m: float = STEP_M, near_m: float = 0.1) -> None:
        if substeps < 0 or not (step_m > 0) or not (near_m > 0):
            raise ValueError("substeps >= 0, step_m > 0 and near_m > 0 are needed")
        self.robot, self.cm = robot, collision_model
        self.prims = [p for p in prims if not p.floor]
        self.substeps, self.step_m, self.near_m = int(substeps), float(step_m), float(near_m)

    def shapes(self, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World capsule ends (C, S, 3) x 2 of joint vectors (C, n), the waist on the feet."""
        J = np.atleast_2d(np.asarray(joints, float))
        Q = np.array([self.robot.config(j, self.robot.base_on_feet(j)) for j in J])
        P0, P1, _ = self.cm.world_shapes_batch(Q)
        return P0, P1

    def configurations(self, times, positions) -> tuple[np.ndarray, np.ndarray]:
        """``(t (M,), joints (M, n))``: the rebuilt trajectory at its samples and between them."""
        t = np.asarray(times, float)
        Q = np.asarray(positions, float)
        if len(t) != len(Q) or not len(t):
            raise ValueError(f"{len(t)} times for {len(Q)} samples")
        if len(t) == 1:
            return t.copy(), Q.copy()
        spline = SplineTrajectory(Q, t - t[0])
        P0, P1 = self.shapes(Q)
        ends = np.concatenate([P0, P1], axis=1)                       # (K, 2S, 3)
        moved = np.linalg.norm(np.diff(ends, axis=0), axis=2).max(axis=1)   # (K-1,) farthest end move
        sub = np.maximum(self.substeps, np.ceil(moved / self.step_m).astype(int) - 1)
        ts = sample_times(t - t[0], sub)
        return ts + t[0], spline.position(ts)

    def check(self, times, positions) -> tuple[TruthContact, int]:
        """The deepest penetration, or else the nearest approach (``distance_m`` = ``near_m`` when
        nothing comes that near), over the trajectory; and the configurations evaluated."""
        ts, J = self.configurations(times, positions)
        P0, P1 = self.shapes(J)
        C, S = P0.shape[:2]
        R = np.tile(self.cm.base_radii, C)
        d, which = shapes_vs_primitives(self.prims, P0.reshape(-1, 3), P1.reshape(-1, 3), R, self.near_m)
        i = int(np.argmin(d))
        c, s = divmod(i, S)
        name = self.prims[which[i]].name if which[i] >= 0 else ""
        return TruthContact(float(d[i]), name, self.cm.names[s] if name else "", float(ts[c]), c), C

    def clearance(self, joints: np.ndarray) -> TruthContact:
        """:meth:`check` of one posture (time 0)."""
        return self.check(np.zeros(1), np.atleast_2d(joints))[0]


__all__ = ["TruthContact", "TrajectoryAudit", "capsule_signed_distance", "model_positions", "sample_times",
           "segment_min_sdf", "shapes_vs_primitives"]
