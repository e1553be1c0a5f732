"""Tests of humanoid_reach_ros.geometry.voxels (the object left out of a measured map)."""
from __future__ import annotations

import numpy as np

from humanoid_reach_ros.geometry.voxels import without_target


def test_one_centre_removes_its_ball_only() -> None:
    P = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.2, 0.0, 0.0], [0.0, 0.3, 0.0]])
    kept = without_target(P, np.zeros(3), 0.15)
    assert kept.tolist() == [[0.2, 0.0, 0.0], [0.0, 0.3, 0.0]]
    assert without_target(P, np.zeros(3), 0.0).shape == (4, 3)       # radius 0: keep all
    assert without_target(np.zeros((0, 3)), np.zeros(3), 0.15).shape == (0, 3)


def test_several_centres_remove_each_ball() -> None:
    """A motion's start and final hand positions (the object left and the one reached)."""
    rng = np.random.default_rng(0)
    P = rng.uniform(-1.0, 1.0, (2000, 3))
    C = np.array([[0.5, 0.0, 0.0], [-0.5, 0.2, 0.1]])
    kept = without_target(P, C, 0.2)
    d = np.linalg.norm(kept[:, None, :] - C[None], axis=2)
    assert np.all(d > 0.2)
    expected = int(np.sum(np.all(np.linalg.norm(P[:, None, :] - C[None], axis=2) > 0.2, axis=1)))
    assert len(kept) == expected < len(P)
    one = without_target(without_target(P, C[0], 0.2), C[1], 0.2)
    assert np.array_equal(kept, one)
