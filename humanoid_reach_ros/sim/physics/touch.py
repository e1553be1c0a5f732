"""How hard a touching hand may push: a bound from the robot's own wrist.

A force ``F`` at the hand's tip loads each arm joint ``j`` with ``tau_j = J_j^T F``, ``J_j`` the
joint's column of the tip's translational Jacobian (``axis_j x (tip - origin_j)``). In its worst
direction a unit force loads the joint with ``|J_j|``, the tip's distance from the joint's axis
(its lever). The **wrist joints** are the arm's joints past the elbow (the limb's joints after its
fourth); the weakest of them, ``min_j effort_j / |J_j|`` over the URDF's effort limits, is the
largest force the wrist resists in every direction before a servo saturates and the hand gives
way. A touch may push with half of it (:data:`TOUCH_FRACTION`): the other half stays for holding
the hand against gravity and the motion. Both arms at half-sitting; the weaker arm's figure counts.

No ROS here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from humanoid_reach_ros.robot.model import RobotModel

#: the share of the weakest wrist joint's strength a touch may use
TOUCH_FRACTION = 0.5
#: joints of an arm limb up to and including the elbow (shoulder 3, elbow 1); the rest are the wrist's
ELBOW_JOINTS = 4


@dataclass(frozen=True)
class TouchBound:
    bound_n: float          # the bound [N]
    arm: str                # the weaker arm
    joint: str              # its weakest wrist joint
    effort_nm: float        # that joint's effort limit [N m]
    lever_m: float          # the hand tip's distance from its axis [m]


def touch_force_bound(robot: RobotModel) -> TouchBound:
    """The touch bound of ``robot`` (module doc); ValueError when no wrist joint has an effort limit."""
    q = robot.config(robot.half_sitting_joints, robot.base_on_feet(robot.half_sitting_joints))
    data = robot.model.createData()
    pin.computeJointJacobians(robot.model, data, q)
    pin.updateFramePlacements(robot.model, data)
    best: TouchBound | None = None
    for side in ("right", "left"):
        limb = robot.limbs[f"{side}_arm"]
        J = pin.getFrameJacobian(robot.model, data, robot.frame_id(limb.tip), pin.LOCAL_WORLD_ALIGNED)[:3]
        for name in limb.joints[ELBOW_JOINTS:]:
            jid = robot.model.getJointId(name)
            col = robot.model.joints[jid].idx_v
            lever = float(np.linalg.norm(J[:, col]))
            effort = float(robot.model.effortLimit[col])
            if lever < 1e-3 or not math.isfinite(effort) or effort <= 0.0:
                continue
            b = TouchBound(round(TOUCH_FRACTION * effort / lever, 1), side, name, effort, round(lever, 4))
            if best is None or b.bound_n < best.bound_n:
                best = b
    if best is None:
        raise ValueError(f"{robot.name}: no wrist joint (arm joints past the elbow) with an effort limit and a lever "
                         "to the hand: no touch bound")
    return best


__all__ = ["ELBOW_JOINTS", "TOUCH_FRACTION", "TouchBound", "touch_force_bound"]
