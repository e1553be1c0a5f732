"""The limb-solver registry: the solver each limb of a robot gets, picked from its chain's
structure (first match of ``SOLVERS``), and the set of a robot's four limbs.

1. **hand-derived closed form** (``kinematics/hand_derived.py``, ``LimbIK``): HRP-2's two axis
   patterns (legs ``z x y | y | y x``, arms ``y x z | y | z y``), legs compiled (the planner's
   fused projection kernel), arms compiled for the control steps
   (``kinematics/hand_derived_compiled.py``);
2. **general closed form** (``kinematics/general_limb.py`` over ``kinematics/general_ik.py``
   and its numba twin ``general_ik_compiled.py``): any 6R chain with three intersecting axes
   at one end and two at the other, and 7R arms whose joints 2..7 are such a chain (joint 1
   sampled);
3. **numerical** (``kinematics/numerical_ik.py``, behind the same ``GeneralLimb``): any other
   chain of 6 or 7 revolute joints (damped least squares with restarts: a named
   simplification, a local method that can miss a solution).

Every solver answers the protocol of ``kinematics/protocol.py`` (``LimbSolver``); planning,
the dual-arm controller and the executor use only that and this registry.

No ROS here.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Iterator, Mapping

import numpy as np

from humanoid_reach_ros.kinematics.general_limb import GeneralLimb
from humanoid_reach_ros.kinematics.hand_derived import LimbIK, LimbStructureError
from humanoid_reach_ros.kinematics.ik_types import IKResult
from humanoid_reach_ros.kinematics.protocol import LimbSolver
from humanoid_reach_ros.robot.model import RobotModel

#: (what, constructor (model, limb name, compiled) -> LimbSolver), tried in order: the first
#: constructor that accepts the chain (no LimbStructureError / ValueError) gives the solver.
#: GeneralLimb falls back to the numerical solver itself when neither closed form applies.
SOLVERS: tuple[tuple[str, Callable[[RobotModel, str, bool], LimbSolver]], ...] = (
    ("hand-derived closed form", LimbIK),
    ("general closed form, else numerical", GeneralLimb),
)


def limb_solver(model: RobotModel, name: str, compiled: bool = True) -> LimbSolver:
    """The solver of limb ``name`` of ``model``: the first of ``SOLVERS`` that accepts its
    chain. ``LimbStructureError`` naming every solver's reason when none does (a joint that is
    not revolute about a fixed axis, joints that are not one serial chain, other than 6 or 7
    joints)."""
    reasons = []
    for what, make in SOLVERS:
        try:
            return make(model, name, compiled)
        except ValueError as exc:     # LimbStructureError is a ValueError
            reasons.append(f"{what}: {exc}")
    raise LimbStructureError("; ".join(reasons))


@dataclass(frozen=True, eq=False)
class LimbIKSet:
    """The solver of every limb of ``model`` (``model.limbs``), by name (:func:`limb_solver`):
    one protocol (:class:`~humanoid_reach_ros.kinematics.protocol.LimbSolver`) whichever
    solver a limb gets."""

    model: RobotModel
    compiled: bool = True
    limbs: Mapping[str, LimbSolver] = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "limbs", {n: limb_solver(self.model, n, self.compiled) for n in self.model.limbs})

    def __getitem__(self, limb: str) -> LimbSolver:
        return self.limbs[limb]

    def __iter__(self) -> Iterator[str]:
        return iter(self.limbs)

    def __len__(self) -> int:
        return len(self.limbs)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.limbs)

    def solve(self, limb: str, root_p, root_R, tip_p, tip_R, q_ref=None) -> IKResult:
        return self.limbs[limb].solve(root_p, root_R, tip_p, tip_R, q_ref)

    def fk(self, limb: str, root_p, root_R, q) -> tuple[np.ndarray, np.ndarray]:
        return self.limbs[limb].fk(root_p, root_R, q)


def warm_up() -> None:
    """Compile (or load from the numba cache) every solver's kernels: the hand-derived leg
    kernel, the general closed form's twins, the numerical solver's and the redundant arm's
    tracking step."""
    from humanoid_reach_ros.kinematics import general_ik_compiled, hand_derived, numerical_ik, redundant_tracker

    hand_derived.warm_up()
    general_ik_compiled.warm_up()
    numerical_ik.warm_up()
    redundant_tracker.warm_up()


__all__ = ["SOLVERS", "LimbIKSet", "limb_solver", "warm_up"]
