"""The force guard: no part of the robot pushes on the world harder than the robot's touch bound
(physics.yaml ``force_guard``; docs/physics.md). What a real humanoid's controller does from its
wrist force/torque sensors and its joint torque residuals (collision detection and reaction) under
its position servos; here it corrects the physics plant's servo targets each tick of the joint
driver (``PhysicsDriver.step``) from the measured contact forces, and leaves the executor's
commands as they are. No robot's name here: the joints are the description's limbs and roles.

**The guard** (:class:`ContactForceGuard`). The bound is ``touch.py``'s: half the force the
weakest wrist joint resists at the hand. When the contact force of the world on one of the robot's
bodies (a hand, an upper arm, the head; not a foot) exceeds ``bound_fraction`` of the bound, the
joints that move that body -- those between the base and it, **the legs' left out** (they keep
the balance the executor commands) -- have their servo targets **held at their measured angles**
of that instant: the servos stop pushing it on, so the force falls to what the limbs' own weight
and sag give, whatever the executor commands further. A hold ends when the command takes the
contact point back out (with the held joints at their command, the point lies further along the
contact force than where it was held: the retreat), or when the body no longer touches and the
command is back within ``release_rad`` of the held angles; the held offset then fades over
``release_s`` (no jump to the command).

*Simplifications*: a hold, not an admittance (a body does not keep a set force; it rests where it
was when the force crossed the guard); the contact forces are MuJoCo's, exact and undelayed (a
real robot's wrist sensor and torque residuals are filtered and slower); the executor is not told
that a body stopped short (its reference and the measured joints differ by the command's
remaining way, which /physics/metrics' tracking error shows), and the legs it commands for a
posture the upper body no longer reaches keep the COG where that posture would have had it.

No ROS here.
"""
from __future__ import annotations

import mujoco
import numpy as np
import pinocchio as pin

from humanoid_reach_ros.sim.physics.model_builder import PhysicsModel


class ContactForceGuard:
    """The joints moving a body held at their measured angles while it pushes beyond the guard (module doc)."""

    def __init__(self, pm: PhysicsModel, bound_n: float) -> None:
        cfg = pm.config.force_guard
        self.pm = pm
        self.cfg = cfg
        self.bound_n = float(bound_n)
        self.guard_n = cfg.bound_fraction * self.bound_n
        robot, model = pm.robot, pm.model
        legs = {robot.joint_index[j] for name, limb in robot.spec.limbs.items() if name.endswith("leg")
                for j in limb.joints}
        feet = set().union(*pm.foot_body_sets)
        body_of_dof = {k: int(model.jnt_bodyid[int(model.dof_jntid[adr])]) for k, adr in enumerate(pm.dof_adr)}
        self.chains: dict[int, np.ndarray] = {}      # body -> the joints that move it, legs left out
        self.frames: dict[int, int] = {}             # body -> its pinocchio frame (the URDF link's)
        for b in range(1, model.nbody):
            name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b)
            if b in feet or not name or not robot.model.existFrame(name):
                continue
            path = set()
            a = b
            while a > 0:
                path.add(a)
                a = int(model.body_parentid[a])
            chain = [k for k, body in body_of_dof.items() if body in path and k not in legs]
            if chain:
                self.chains[b] = np.array(sorted(chain))
                self.frames[b] = robot.model.getFrameId(name)
        self.hand_bodies = {side: min(bodies) for side, bodies in pm.hand_body_sets.items()}
        self._pin = robot.model.createData()       # its own: the robot model's data serves other threads
        self.holds_active: dict[int, dict] = {}      # body -> {joints, held, u, point (in the body frame)}
        self.fade = np.zeros(robot.n_joints)
        self.holds = 0                              # holds begun since start
        self.held_bodies: list[str] = []            # the bodies held since start, by name (first ones)
        self.held_now = np.zeros(robot.n_joints, bool)   # the joints held at the last tick

    @property
    def holding(self) -> dict[str, bool]:
        """Per hand: is the hand (or a body on its way) held now?"""
        return {side: any(h["hand"] == side for h in self.holds_active.values()) for side in self.hand_bodies}

    @property
    def holding_bodies(self) -> list[str]:
        return [mujoco.mj_id2name(self.pm.model, mujoco.mjtObj.mjOBJ_BODY, b) for b in self.holds_active]

    def _point(self, joints: np.ndarray, body: int, local: np.ndarray) -> np.ndarray:
        robot = self.pm.robot
        pin.framesForwardKinematics(robot.model, self._pin, robot.config(joints))
        return self._pin.oMf[self.frames[body]].act(local)

    def offsets(self, targets: np.ndarray, measured: np.ndarray, contacts: dict[int, tuple[np.ndarray, np.ndarray]],
                dt: float) -> np.ndarray:
        """The servo targets' offsets (robot joint order) of this tick: ``targets`` the commanded joints,
        ``measured`` the plant's, ``contacts`` body -> (force of the world on it [N], its point) in the world."""
        out = np.zeros(len(targets))
        held_now = np.zeros(len(targets), bool)
        for body, (F, point) in contacts.items():
            fn = float(np.linalg.norm(F))
            if fn <= self.guard_n or body in self.holds_active or body not in self.chains:
                continue
            joints = self.chains[body]
            self._point(measured, body, np.zeros(3))
            local = self._pin.oMf[self.frames[body]].actInv(point)
            hand = next((side for side, hb in self.hand_bodies.items() if hb == body or
                         body in self.pm.hand_body_sets[side]), "")
            self.holds_active[body] = {"joints": joints, "held": measured[joints].copy(), "u": F / fn,
                                       "point": local, "hand": hand}
            self.holds += 1
            name = mujoco.mj_id2name(self.pm.model, mujoco.mjtObj.mjOBJ_BODY, body)
            if name not in self.held_bodies and len(self.held_bodies) < 20:
                self.held_bodies.append(name)
        for body, h in list(self.holds_active.items()):
            joints, held = h["joints"], h["held"]
            with_held = targets.copy()
            with_held[joints] = held
            out_along = float((self._point(targets, body, h["point"]) - self._point(with_held, body, h["point"]))
                              @ h["u"])
            touching = body in contacts and float(np.linalg.norm(contacts[body][0])) > 1e-6
            if out_along > 0.0 or (not touching and np.abs(targets[joints] - held).max() <= self.cfg.release_rad):
                free = ~held_now[joints]
                self.fade[joints[free]] = (held - targets[joints])[free]      # released: fades from here
                del self.holds_active[body]
                continue
            free = ~held_now[joints]         # a joint two holds share: the first one's
            out[joints[free]] = (held - targets[joints])[free]
            self.fade[joints[free]] = 0.0
            held_now[joints] = True
        if np.any(self.fade):
            self.fade *= max(0.0, 1.0 - dt / self.cfg.release_s)
            self.fade[np.abs(self.fade) < 1e-6] = 0.0
            out[~held_now] += self.fade[~held_now]
        self.held_now = held_now
        return out


def body_contacts(pm: PhysicsModel, data: mujoco.MjData) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """body -> (the world's contact force on it (3,) [N], the force-weighted point where it acts), for
    every robot body touching the world; the feet's contacts left out."""
    out: dict[int, list] = {}
    force6 = np.zeros(6)
    world = pm.world_geoms
    feet = set().union(*pm.foot_body_sets)
    for i in range(data.ncon):
        c = data.contact[i]
        ga, gb = int(c.geom1), int(c.geom2)
        if (ga in world) == (gb in world):
            continue
        robot_geom = gb if ga in world else ga
        body = int(pm.model.geom_bodyid[robot_geom])
        if body in feet:
            continue
        mujoco.mj_contactForce(pm.model, data, i, force6)
        f = force6[:3] @ c.frame.reshape(3, 3)          # on geom2, from geom1, in the world
        if robot_geom == ga:
            f = -f
        acc = out.setdefault(body, [np.zeros(3), np.zeros(3), 0.0])
        acc[0] += f
        acc[1] += abs(force6[0]) * c.pos
        acc[2] += abs(force6[0])
    return {b: (v[0], v[1] / v[2] if v[2] > 0.0 else data.xpos[b].copy()) for b, v in out.items()}


__all__ = ["ContactForceGuard", "body_contacts"]
