"""The wrist force guard: a touch pushes with at most the robot's touch bound (physics.yaml
``force_guard``; docs/physics.md). What a real humanoid's arm controller does from its wrist
force/torque sensor under its position servos; here it corrects the physics plant's servo targets
each tick of the joint driver (``PhysicsDriver.step``) from the hands' measured contact forces,
and leaves the executor's commands as they are. No robot's name here: the arm joints are the
description's arm limbs'.

**The guard** (:class:`WristForceGuard`): a touch pushes with at most the robot's touch bound
(``touch.py``: half the force the weakest wrist joint resists at the hand). When a hand's measured
contact force exceeds ``bound_fraction`` of the bound, the arm's servo targets are **held at the
arm's measured joints** of that instant (the servos stop pushing: the force falls to what the arm's
own weight and sag give), whatever the executor commands deeper. The hold ends when the command
takes the hand back out of the contact -- its hand position, with the held arm, lies further along
the contact force's direction than the held hand (the retreat) -- or when the hand no longer
touches and the command is back within ``release_rad`` of the held joints; the held offset then
fades over ``release_s`` (no jump to the command). *Simplifications*: a hold, not an admittance
(the hand does not keep a set force; it rests where it was when the force crossed the guard); the
executor is not told that its hand stopped short (its reference and the measured hand differ by
the command's remaining depth, which /physics/metrics' tracking error shows).

No ROS here.
"""
from __future__ import annotations

import mujoco
import numpy as np
import pinocchio as pin

from humanoid_reach_ros.sim.physics.model_builder import PhysicsModel


class WristForceGuard:
    """Each arm held at its measured joints while its hand pushes beyond the guard (module doc)."""

    def __init__(self, pm: PhysicsModel, bound_n: float) -> None:
        cfg = pm.config.force_guard
        self.pm = pm
        self.cfg = cfg
        self.bound_n = float(bound_n)
        self.guard_n = cfg.bound_fraction * self.bound_n
        robot = pm.robot
        index = robot.joint_index
        self.arms: dict[str, np.ndarray] = {}
        self.hand_frames: dict[str, int] = {}
        for side in pm.hand_body_sets:
            limb = robot.spec.limbs.get(f"{side}_arm")
            if limb is None:
                raise ValueError(f"{pm.config.path}: force_guard: the robot has no {side}_arm limb for its {side} hand")
            self.arms[side] = np.array([index[j] for j in limb.joints])
            self.hand_frames[side] = robot.frame_id(robot.hand_frames[side])
        self._pin = robot.model.createData()       # its own: the robot model's data serves other threads
        self.held: dict[str, np.ndarray | None] = {side: None for side in self.arms}
        self.u = {side: np.zeros(3) for side in self.arms}
        self.fade = {side: np.zeros(len(arm)) for side, arm in self.arms.items()}
        self.holds = 0                              # holds begun since start

    @property
    def holding(self) -> dict[str, bool]:
        return {side: h is not None for side, h in self.held.items()}

    def _hand(self, joints: np.ndarray, side: str) -> np.ndarray:
        robot = self.pm.robot
        pin.framesForwardKinematics(robot.model, self._pin, robot.config(joints))
        return self._pin.oMf[self.hand_frames[side]].translation.copy()

    def offsets(self, targets: np.ndarray, measured: np.ndarray, forces: dict[str, np.ndarray],
                dt: float) -> np.ndarray:
        """The servo targets' offsets (robot joint order) of this tick: ``targets`` the commanded joints,
        ``measured`` the plant's, ``forces`` each hand's contact force [N, world]."""
        out = np.zeros(len(targets))
        for side, arm in self.arms.items():
            F = np.asarray(forces[side], float)
            fn = float(np.linalg.norm(F))
            held = self.held[side]
            if held is None and fn > self.guard_n:
                held = self.held[side] = measured[arm].copy()
                self.u[side] = F / fn
                self.holds += 1
            if held is not None:
                with_held = targets.copy()
                with_held[arm] = held
                out_along = float((self._hand(targets, side) - self._hand(with_held, side)) @ self.u[side])
                if out_along > 0.0 or (fn <= 1e-6 and np.abs(targets[arm] - held).max() <= self.cfg.release_rad):
                    self.fade[side] = held - targets[arm]          # released: the offset fades from here
                    self.held[side] = None
                else:
                    out[arm] = held - targets[arm]
                    continue
            fade = self.fade[side]
            if np.any(fade):
                fade *= max(0.0, 1.0 - dt / self.cfg.release_s)
                if np.abs(fade).max() < 1e-6:
                    fade[:] = 0.0
                out[arm] = fade
        return out


def hand_contacts(pm: PhysicsModel, data: mujoco.MjData) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Each hand's total contact force on it from the world (3,) [N, world] and the force-weighted
    point where it acts (the hand frame's body origin without contact)."""
    forces = {side: np.zeros(3) for side in pm.hand_body_sets}
    moments = {side: np.zeros(3) for side in pm.hand_body_sets}
    weights = {side: 0.0 for side in pm.hand_body_sets}
    force6 = np.zeros(6)
    world = pm.world_geoms
    for i in range(data.ncon):
        c = data.contact[i]
        ga, gb = int(c.geom1), int(c.geom2)
        if (ga in world) == (gb in world):
            continue
        robot_geom = gb if ga in world else ga
        body = int(pm.model.geom_bodyid[robot_geom])
        for side, bodies in pm.hand_body_sets.items():
            if body in bodies:
                mujoco.mj_contactForce(pm.model, data, i, force6)
                f = force6[:3] @ c.frame.reshape(3, 3)          # on geom2, from geom1, in the world
                if robot_geom == ga:
                    f = -f
                forces[side] += f
                moments[side] += abs(force6[0]) * c.pos
                weights[side] += abs(force6[0])
    points = {}
    for side, bodies in pm.hand_body_sets.items():
        points[side] = moments[side] / weights[side] if weights[side] > 0.0 else data.xpos[min(bodies)].copy()
    return forces, points


__all__ = ["WristForceGuard", "hand_contacts"]
