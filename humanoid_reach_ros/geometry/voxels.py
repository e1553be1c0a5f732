"""Voxel-set helpers shared by the nodes that take a measured ``/voxel_map``, and the kernel that
marks the voxels inside capsules (the robot's body-swept space, ``geometry/body_sweep.py``)."""
from __future__ import annotations

import math

import numba as nb
import numpy as np


def without_target(points: np.ndarray, center: np.ndarray, radius_m: float) -> np.ndarray:
    """Occupied voxel centres (N, 3) outside the ball of ``radius_m`` around ``center`` (3,)
    (or around each of the centres (K, 3)).

    A measured map contains the object to be reached (the valve); the hand's goal lies inside
    it. The planner and the executor leave the object out of their collision map this way, as
    they leave the scene file's ``valve`` group out. (A simplification: the object is a ball
    around the target, not its segmented shape.)
    """
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    if radius_m <= 0.0 or len(P) == 0:
        return P
    keep = np.ones(len(P), dtype=bool)
    for c in np.asarray(center, dtype=float).reshape(-1, 3):
        keep &= np.sum((P - c) ** 2, axis=1) > radius_m * radius_m
    return P[keep]


@nb.njit(cache=True)
def mark_capsules(P0, P1, R, h, lo, grid):   # pragma: no cover - compiled
    """Set ``grid`` (a box of voxels from index ``lo``) where voxel centres lie within the
    capsules (P0, P1, R); returns how many were newly set."""
    added = 0
    nx, ny, nz = grid.shape
    for s in range(P0.shape[0]):
        ax, ay, az = P0[s, 0], P0[s, 1], P0[s, 2]
        dx, dy, dz = P1[s, 0] - ax, P1[s, 1] - ay, P1[s, 2] - az
        dd = dx * dx + dy * dy + dz * dz
        r2 = R[s] * R[s]
        i0 = max(int(math.floor((min(ax, P1[s, 0]) - R[s]) / h)) - lo[0], 0)
        i1 = min(int(math.floor((max(ax, P1[s, 0]) + R[s]) / h)) - lo[0], nx - 1)
        j0 = max(int(math.floor((min(ay, P1[s, 1]) - R[s]) / h)) - lo[1], 0)
        j1 = min(int(math.floor((max(ay, P1[s, 1]) + R[s]) / h)) - lo[1], ny - 1)
        k0 = max(int(math.floor((min(az, P1[s, 2]) - R[s]) / h)) - lo[2], 0)
        k1 = min(int(math.floor((max(az, P1[s, 2]) + R[s]) / h)) - lo[2], nz - 1)
        for i in range(i0, i1 + 1):
            cx = (i + lo[0] + 0.5) * h - ax
            for j in range(j0, j1 + 1):
                cy = (j + lo[1] + 0.5) * h - ay
                for k in range(k0, k1 + 1):
                    if grid[i, j, k]:
                        continue
                    cz = (k + lo[2] + 0.5) * h - az
                    t = 0.0
                    if dd > 1e-18:
                        t = (cx * dx + cy * dy + cz * dz) / dd
                        t = min(1.0, max(0.0, t))
                    ex, ey, ez = cx - t * dx, cy - t * dy, cz - t * dz
                    if ex * ex + ey * ey + ez * ez <= r2:
                        grid[i, j, k] = True
                        added += 1
    return added


@nb.njit(cache=True)
def points_within_capsules(P, P0, P1, R):   # pragma: no cover - compiled
    """Per point of ``P`` (N, 3): does it lie within one of the capsules (segments ``P0``-``P1``
    (S, 3), radii ``R`` (S,))? A box test per capsule first (a depth map's points are mostly far
    from the body)."""
    n, S = P.shape[0], P0.shape[0]
    out = np.zeros(n, np.bool_)
    lo = np.empty((S, 3))
    hi = np.empty((S, 3))
    for s in range(S):
        for a in range(3):
            lo[s, a] = min(P0[s, a], P1[s, a]) - R[s]
            hi[s, a] = max(P0[s, a], P1[s, a]) + R[s]
    for i in range(n):
        x, y, z = P[i, 0], P[i, 1], P[i, 2]
        for s in range(S):
            if x < lo[s, 0] or x > hi[s, 0] or y < lo[s, 1] or y > hi[s, 1] or z < lo[s, 2] or z > hi[s, 2]:
                continue
            ax, ay, az = P0[s, 0], P0[s, 1], P0[s, 2]
            dx, dy, dz = P1[s, 0] - ax, P1[s, 1] - ay, P1[s, 2] - az
            cx, cy, cz = x - ax, y - ay, z - az
            dd = dx * dx + dy * dy + dz * dz
            t = 0.0
            if dd > 1e-18:
                t = min(1.0, max(0.0, (cx * dx + cy * dy + cz * dz) / dd))
            ex, ey, ez = cx - t * dx, cy - t * dy, cz - t * dz
            if ex * ex + ey * ey + ez * ez <= R[s] * R[s]:
                out[i] = True
                break
    return out
