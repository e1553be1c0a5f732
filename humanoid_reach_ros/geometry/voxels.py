"""Voxel-set helpers shared by the nodes that take a measured ``/voxel_map``."""
from __future__ import annotations

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
