"""Target CoM position from three candidates (dissertation Sec. 4.2, eq. 5-6).

Reachability (eq. 5): ``|p* - p_shoulder| < L_arm`` with ``p_shoulder`` the shoulder centre
of the initial configuration and ``L_arm`` the shoulder-to-wrist length (upper arm +
forearm of the closed-form limb model). Our hand targets are hand end-effector poses, so
``p*`` is taken at the wrist centre the target pose implies, ``p*_w = p* - R* t_e`` (the
same point the closed-form arm IK reaches with the shoulder-to-wrist chain).

Candidates (eq. 6), ``b = (0, 0, 0.1)`` m:

    p*_CoM = p_CoM,init + b   if p*_z - p_shoulder,z >  L_arm   (for either hand)
           = p_CoM,init - b   if p*_z - p_shoulder,z < -L_arm
           = p_CoM,init        otherwise

**Generalisation (named):** when eq. 5 fails for a hand but neither vertical condition of
eq. 6 holds (the target is far mostly forward/sideways), the literal rule keeps the initial
CoM; we instead pick, among the three candidates, the one that minimises the worst excess
``max_hands |p*_w - (p_shoulder + c)| - L_arm`` (a shoulder moves with the CoM shift ``c``),
keeping the initial CoM on ties. In the purely vertical cases this returns eq. 6's choice.
If both hands' vertical conditions contradict each other (one above, one below), the
candidate with the smaller worst excess wins. :attr:`ComTarget.reachable` tells whether
eq. 5 then holds for both hands; the CoM trajectory is the linear interpolation from the
current to the target CoM (:func:`interpolate_com`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from humanoid_reach_ros.dual_arm.targets import HandTargets, as_position
from humanoid_reach_ros.kinematics import LimbIKSet
from humanoid_reach_ros.robot.model import RobotModel

CANDIDATES = ("init", "up", "down")


@dataclass(frozen=True, eq=False)
class ComTarget:
    """Chosen candidate, its CoM position, the worst eq. 5 excess [m] per candidate."""

    label: str
    p_com: np.ndarray
    shift: np.ndarray
    excess: dict
    reachable: bool


class ComTargetSelector:
    """eq. 6 from the initial configuration ``q_init`` (nq)."""

    def __init__(self, robot: RobotModel, q_init: np.ndarray, offset_m: float = 0.1,
                 limb_ik: LimbIKSet | None = None) -> None:
        if not (np.isfinite(offset_m) and offset_m > 0.0):
            raise ValueError(f"CoM offset b must be > 0 m, got {offset_m}")
        self.robot = robot
        ik = LimbIKSet(robot) if limb_ik is None else limb_ik
        d = robot.model.createData()
        pin.framesForwardKinematics(robot.model, d, q_init)
        self.p_com_init = pin.centerOfMass(robot.model, d, q_init).copy()
        self.shoulder = {}
        self.tip_offset = {}
        self.l_arm = {}
        for side in ("right", "left"):
            limb = ik[f"{side}_arm"]
            root = d.oMf[robot.frame_id(robot.limbs[f"{side}_arm"].root)]
            self.shoulder[side] = root.translation + root.rotation @ limb.t0
            self.tip_offset[side] = (limb.Re, limb.te)
            self.l_arm[side] = abs(limb.l1) + abs(limb.l2)
        self.b = np.array([0.0, 0.0, offset_m])

    def wrist(self, side: str, p: np.ndarray, R: np.ndarray) -> np.ndarray:
        """Wrist centre ``p* - R5 t_e`` implied by the hand target (``R5 = R* R_e^T``)."""
        Re, te = self.tip_offset[side]
        return p - (R @ Re.T) @ te

    def select(self, hands: HandTargets) -> ComTarget:
        wr = {"right": self.wrist("right", hands.p_right, hands.R_right),
              "left": self.wrist("left", hands.p_left, hands.R_left)}
        shifts = {"init": np.zeros(3), "up": self.b, "down": -self.b}
        excess = {c: max(float(np.linalg.norm(wr[s] - self.shoulder[s] - shifts[c])) - self.l_arm[s]
                         for s in wr) for c in CANDIDATES}
        if excess["init"] < 0.0:
            label = "init"
        else:
            dz = [wr[s][2] - self.shoulder[s][2] for s in wr]
            up = any(z > self.l_arm[s] for z, s in zip(dz, wr))
            down = any(z < -self.l_arm[s] for z, s in zip(dz, wr))
            if up and not down:
                label = "up"
            elif down and not up:
                label = "down"
            else:       # generalisation (module docstring)
                label = min(CANDIDATES, key=lambda c: (excess[c], CANDIDATES.index(c)))
        return ComTarget(label, self.p_com_init + shifts[label], shifts[label], excess, excess[label] < 0.0)


def interpolate_com(p_start, p_target, s: float) -> np.ndarray:
    """Linear CoM trajectory ``p_start + s (p_target - p_start)``, ``s in [0, 1]``."""
    a = as_position(p_start, "p_start")
    b = as_position(p_target, "p_target")
    if not (np.isfinite(s) and 0.0 <= s <= 1.0):
        raise ValueError(f"interpolation parameter must be in [0, 1], got {s}")
    return a + s * (b - a)
