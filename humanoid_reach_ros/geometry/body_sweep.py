"""The robot's own volume as observed free space: the **robot-volume policy** (issue 31).

A head camera never sees behind the robot's back, beside its hips or under its arms; what the
package may still count as observed there is only where the robot itself has been:

* **observed free** = the voxels whose centres lie within the robot's collision capsules grown
  by the self-filter margin ``m`` (below), at every posture ``/joint_states`` reported;
* **between two reported postures** (consecutive states at most ``max_gap_s`` apart) the
  postures on the straight joint-space line between them, spaced so that no capsule end moves
  more than ``step_m`` from one to the next: what the shapes swept, at the map's resolution. Two
  states further apart than ``max_gap_s`` (lost messages) are each marked, the space between
  them is not (nobody knows the path taken: it stays unobserved);
* nothing else: the space *around* the body is not observed by being near it. (Before issue 31
  the shapes were grown by 0.25 m, and plans passed through pipes the head never saw, 7-89 mm
  inside them.)

**The self-filter margin.** A depth sensor sees the robot's own links; the voxel mapper drops the
points within ``m`` of the capsules at the depth map's stamp (a self filter, as MoveIt's
``robot_self_filter`` pads the links). A point measured on a link's surface must fall inside
the filtered shell, so ``m`` covers (:func:`self_filter_margin_m`):

* the range noise, 3 sigma at the farthest link the head camera sees: ``sigma = k r^2``
  (``range_noise_per_m`` k = 0.0025 /m of ``config/scene_sim.yaml``, r = 1.5 m to the feet):
  16.9 mm;
* the body's pose error at the image's stamp: the joint-state look-up accepts an
  interpolation error of ``pose_tolerance_rad`` = 2 mrad (``JointStateBuffer``), over a 1.5 m
  lever: 3 mm;
* half a voxel, ``h / 2`` = 10 mm at 0.02 m: the voxel holding a surface point has its centre
  up to that far outside the surface along the normal;

30 mm in all (rounded up from 29.9). The space within ``m`` of the body is space the sensor
cannot tell from the body; it is counted with the body, and no more. The capsules themselves are
fitted to enclose the links (``tools/fit_collision_shapes.py``).

No ROS here.
"""
from __future__ import annotations

import math
from typing import Iterable

import numpy as np

from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.shapes import CollisionModel


def self_filter_margin_m(range_noise_per_m: float = 0.0025, farthest_link_m: float = 1.5,
                         pose_tolerance_rad: float = 2e-3, lever_m: float = 1.5,
                         resolution_m: float = 0.02) -> float:
    """The self-filter margin ``m = 3 k r^2 + e_q L + h / 2`` [m] (module docstring): the depth
    noise at the farthest link seen, the body's pose error at a stamp, half a voxel."""
    for name, v in (("range_noise_per_m", range_noise_per_m), ("farthest_link_m", farthest_link_m),
                    ("pose_tolerance_rad", pose_tolerance_rad), ("lever_m", lever_m),
                    ("resolution_m", resolution_m)):
        if not (math.isfinite(v) and v >= 0.0):
            raise ValueError(f"{name} must be finite and >= 0, got {v}")
    return 3.0 * range_noise_per_m * farthest_link_m ** 2 + pose_tolerance_rad * lever_m + 0.5 * resolution_m


#: the default margin of the voxel mapper and the planning scene [m] (the derivation, rounded up to mm)
DEFAULT_SELF_FILTER_MARGIN_M = math.ceil(self_filter_margin_m() * 1e3) / 1e3


class BodySweep:
    """The postures whose shapes count as observed free, from the reported joint states
    (module docstring), and those shapes grown by ``margin_m``.

    :meth:`postures` is stateful: it remembers the last state fed and the last posture marked,
    so that a stream of states can be fed in pieces (a mapper's publish period at a time).
    A posture whose capsule ends are within ``step_m`` of the last one marked adds nothing worth
    marking and is left out (a conservative loss of at most ``step_m`` of swept space)."""

    def __init__(self, model: RobotModel, collision_model: CollisionModel, margin_m: float,
                 step_m: float = 0.01, max_gap_s: float = 0.1) -> None:
        for name, v in (("margin_m", margin_m), ("step_m", step_m), ("max_gap_s", max_gap_s)):
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"BodySweep.{name} must be finite and >= 0, got {v}")
        if step_m <= 0.0:
            raise ValueError(f"BodySweep.step_m must be > 0, got {step_m}")
        self.model, self.collision_model = model, collision_model
        self.margin_m, self.step_m, self.max_gap_s = float(margin_m), float(step_m), float(max_gap_s)
        self.reset()

    def reset(self) -> None:
        """Forget the last state and posture (the next state fed is marked)."""
        self._prev: tuple[float, np.ndarray, np.ndarray] | None = None    # stamp, joints, capsule ends
        self._mark: tuple[np.ndarray, np.ndarray] | None = None           # joints, capsule ends
        self.interpolated = 0         # postures added between reported states (diagnostics)
        self.gaps = 0                 # consecutive states too far apart to interpolate

    def _ends(self, joints: np.ndarray) -> np.ndarray:
        P0, P1, _ = self.capsules(joints)
        return np.vstack([P0, P1])

    def capsules(self, joints, margin_m: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The shapes at ``joints`` (standing on the feet) grown by ``margin_m`` (None: this
        sweep's): P0, P1 (S, 3), radii (S,)."""
        j = np.asarray(joints, dtype=float).reshape(-1)
        P0, P1, R = self.collision_model.world_shapes(self.model.config(j, self.model.base_on_feet(j)))
        return P0, P1, np.asarray(R, float) + (self.margin_m if margin_m is None else float(margin_m))

    def capsules_of(self, postures: Iterable[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The grown shapes of several postures stacked: P0, P1 (K S, 3), radii (K S,)."""
        parts = [self.capsules(j) for j in postures]
        if not parts:
            return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)
        return tuple(np.concatenate(x) for x in zip(*parts))   # type: ignore[return-value]

    def postures(self, states: Iterable[tuple[float, np.ndarray]]) -> list[np.ndarray]:
        """The postures to mark for the reported ``(stamp [s], joints)`` states, in stamp order
        (a state older than the last one fed restarts the sweep)."""
        out: list[np.ndarray] = []
        for stamp, joints in states:
            q = np.asarray(joints, dtype=float).reshape(-1)
            t = float(stamp)
            if self._prev is not None and t < self._prev[0]:
                self.reset()
            if self._mark is not None and np.max(np.abs(q - self._mark[0])) < 1e-6:
                self._prev = (t, q, self._mark[1])
                continue
            E = self._ends(q)
            if self._prev is None or self._mark is None:
                out.append(q)
                self._prev, self._mark = (t, q, E), (q, E)
                continue
            if float(np.max(np.linalg.norm(E - self._mark[1], axis=1))) <= self.step_m:
                self._prev = (t, q, E)
                continue
            tp, qp, Ep = self._prev
            d = float(np.max(np.linalg.norm(E - Ep, axis=1)))
            if d > self.step_m:
                if t - tp <= self.max_gap_s:
                    n = int(math.ceil(d / self.step_m))
                    out.extend(qp + (k / n) * (q - qp) for k in range(1, n))
                    self.interpolated += n - 1
                else:
                    self.gaps += 1
            out.append(q)
            self._prev, self._mark = (t, q, E), (q, E)
        return out


__all__ = ["DEFAULT_SELF_FILTER_MARGIN_M", "BodySweep", "self_filter_margin_m"]
