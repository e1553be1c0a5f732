"""What every limb IK solver answers (``kinematics/hand_derived.py``, ``kinematics/general_ik.py``)."""
from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np


class IKReason(enum.IntEnum):
    """Per-pose outcome of :meth:`LimbIK.solve`."""

    OK = 0
    UNREACHABLE = 1      # no real solution: beyond reach or impossible orientation
    JOINT_LIMITS = 2     # real solutions exist, none within the joint limits
    INVALID_INPUT = 3    # non-finite input or a rotation that is not a rotation


@dataclass(frozen=True, eq=False)
class IKResult:
    """Batched IK outcome.

    ``q``: (N, 6) joint angles in limb order (``LimbSpec.joints``), NaN where failed;
    ``ok``: (N,) bool; ``reason``: (N,) int8 :class:`IKReason` codes;
    ``branch``: (N,) index of the chosen closed-form branch (-1 where failed):
    ``4 * knee_or_elbow + 2 * ankle_roll_or_wrist_pitch + hip_or_shoulder_euler``
    (0 = first/``+`` branch of each).
    """

    q: np.ndarray
    ok: np.ndarray
    reason: np.ndarray
    branch: np.ndarray

    def __len__(self) -> int:
        return int(self.ok.shape[0])

    @property
    def n_failed(self) -> int:
        return int(np.count_nonzero(~self.ok))

    def failure_counts(self) -> dict[str, int]:
        """Number of poses per failure reason, e.g. ``{"UNREACHABLE": 3, ...}``."""
        return {r.name: int(np.count_nonzero(self.reason == r)) for r in IKReason if r != IKReason.OK}


__all__ = ["IKReason", "IKResult"]
