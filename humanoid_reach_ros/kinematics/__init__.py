"""Inverse kinematics of a humanoid's limbs, one capability (issue 23).

* ``protocol.py`` -- ``LimbSolver``, what every limb solver answers;
* ``registry.py`` -- the solver a limb gets, from its chain's structure, and ``LimbIKSet``;
* ``hand_derived.py`` (+ ``hand_derived_compiled.py``) -- HRP-2's two axis patterns;
* ``general_ik.py`` (+ ``general_ik_compiled.py``) and ``general_limb.py`` -- the general
  closed form of 6R chains (Pieper's class) and 7R arms on it;
* ``numerical_ik.py`` -- damped least squares for any other 6R / 7R chain, and its tracking
  form for control steps (``NumericalLimbTracker``; ``numerical_ik_track`` inside the dual-arm
  method's compiled lower body);
* ``redundant_tracker.py`` -- a 7-joint arm's control step (the self-motion kept continuous);
* ``ik_types.py`` -- the outcome types.

``Chain6`` (a limb's placements, axes and limits) is exported for the planner's reach map,
which is trained on the chain's forward kinematics (``planning/reach_map.py``).

Each compiled (numba) solver sits beside its numpy reference and is tested against it.

The rest of the package imports from here only (``test_layering.py`` holds it to that): the
protocol and the registry, and the compiled pieces the fused kernels of planning and of the
dual-arm step call -- the hand-derived leg kernel (``leg_ik_pose``, ``LEG_WORK_SIZE``; a limb
has it when it is a ``LimbIK``), the hand-derived arm kernel (``CompiledArmIK``) and the
redundant arm's tracker, the numerical solver's tracking kernel and limb tracker.

No ROS here.
"""
from humanoid_reach_ros.kinematics.general_ik import Chain6, rotations as chain_rotations
from humanoid_reach_ros.kinematics.general_ik_compiled import _rot as chain_axis_rotation
from humanoid_reach_ros.kinematics.hand_derived import LEG_WORK_SIZE, LimbIK, LimbStructureError, leg_ik_pose
from humanoid_reach_ros.kinematics.hand_derived_compiled import CompiledArmIK
from humanoid_reach_ros.kinematics.ik_types import IKReason, IKResult
from humanoid_reach_ros.kinematics.numerical_ik import (NumericalLimbTracker, numerical_ik_pose, numerical_ik_track,
                                                        numerical_leg_constants, work_size as numerical_work_size)
from humanoid_reach_ros.kinematics.protocol import LimbSolver
from humanoid_reach_ros.kinematics.redundant_tracker import RedundantArmTracker
from humanoid_reach_ros.kinematics.registry import SOLVERS, LimbIKSet, limb_solver, warm_up

__all__ = ["Chain6", "chain_rotations", "chain_axis_rotation", "NumericalLimbTracker", "numerical_ik_pose",
           "numerical_ik_track",
           "numerical_leg_constants", "numerical_work_size", "CompiledArmIK", "IKReason", "IKResult", "LEG_WORK_SIZE",
           "LimbIK", "LimbIKSet", "LimbSolver", "LimbStructureError", "RedundantArmTracker", "SOLVERS", "leg_ik_pose",
           "limb_solver", "warm_up"]
