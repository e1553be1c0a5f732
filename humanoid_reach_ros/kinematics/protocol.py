"""The limb-solver protocol: what planning, the dual-arm controller and the executor ask of a
limb's inverse kinematics, whichever solver the registry gives it (``kinematics/registry.py``).

No ROS here.
"""
from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from humanoid_reach_ros.kinematics.ik_types import IKResult


@runtime_checkable
class LimbSolver(Protocol):
    """One limb (a serial chain of 6 or 7 revolute joints from a root link to a tip frame):
    batched IK / FK on world poses and the reach geometry the planner's bounds use.

    Poses are batched: ``root_p`` (N, 3) or (3,), ``root_R`` (N, 3, 3) or (3, 3), likewise the
    tip; ``q`` and ``q_ref`` (N, n) or (n,) in the limb's joint order (``joint_names``).

    Reach geometry, in the root link: ``t0`` the root-end centre, ``te`` / ``Re`` the tip in
    the frame whose origin is the tip-end centre, ``l1 + l2`` an upper bound of the distance
    between the two centres and ``|l1 - l2|`` a lower bound (both exact for the closed forms'
    6R chains, bounds otherwise); :meth:`reach_centres` the tightest form of the bound.
    ``kind``: which solver (``hand-derived arm`` / ``leg``, ``general``, ``redundant``,
    ``numerical``); ``compiled``: whether the planner's fused projection kernel can take this
    limb (the hand-derived compiled leg kernel only)."""

    limb_name: str
    joint_names: tuple[str, ...]
    kind: str
    compiled: bool
    lower: np.ndarray
    upper: np.ndarray
    q_default: np.ndarray
    t0: np.ndarray
    te: np.ndarray
    Re: np.ndarray
    l1: float
    l2: float

    def solve(self, root_p, root_R, tip_p, tip_R, q_ref=None) -> IKResult:
        """Joint angles reaching the tip poses (NaN and ``ok`` False where not), nearest
        ``q_ref`` (default: the limb's reference posture) among the solver's candidates."""
        ...

    def fk(self, root_p, root_R, q) -> tuple[np.ndarray, np.ndarray]:
        """Tip positions (N, 3) and rotations (N, 3, 3) in the world."""
        ...

    def maybe_reachable(self, root_p, root_R, tip_p, tip_R) -> np.ndarray:
        """(N,) bool, conservative: False only where no solution can exist."""
        ...

    def reach_centres(self, step_rad: float = 0.05) -> tuple[np.ndarray, float, float]:
        """``(points (K, 3), slack [m], reach [m])`` in the root link: every tip-end centre
        the IK may solve for lies within ``reach`` of a root-end centre within ``slack`` of
        one of the points."""
        ...


__all__ = ["LimbSolver"]
