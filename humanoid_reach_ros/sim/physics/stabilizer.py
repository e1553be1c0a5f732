"""A foot force stabilizer under the plant's position servos (physics.yaml ``stabilizer``;
docs/physics.md): what HRP-2's own stabilizer does from its ankle force sensors (Kajita et al.,
"Biped walking stabilization based on linear inverted pendulum tracking", IROS 2010), two of its
parts. It corrects the servos' targets each tick of the joint driver (``PhysicsDriver.step``; the
corrections go in without velocity feed-forward: ``PhysicsPlant.advance_ramped``), from what the
plant measures; the executor's commands are not changed. No robot's name here: the legs are the
joints between the base and each sole, the ankles the description's ``ankles`` group.

* **Ankle torque (damping) control**: each ankle joint's target is offset by ``theta`` with
  ``theta' = -(tau_meas - tau_ref) / D - theta / T_return``, ``D = kp T_ankle``. ``tau_meas`` is
  the ground reaction's moment about the joint (its generalised force, MuJoCo's
  ``qfrc_constraint``: what a 6-axis sensor at the ankle gives through the joint's axis),
  ``tau_ref`` the moment of the foot's measured normal force put at the foot's reference CoP.
* **Foot force difference control**: the legs lengthened and shortened by ``-+z/2`` along the
  vertical (each leg's joints through its sole Jacobian, base fixed), ``z' = (dF_meas - dF_ref) /
  D_z - z / T_return`` with ``dF = F_right - F_left`` and ``D_z = k_z T_force`` (``k_z``: the legs'
  vertical stiffness from their servos' gains).

The reference: the static ZMP of the commanded posture (its COM on its feet), split between the
feet by its place on the line between the soles (the force ratio); each foot's reference CoP is
its sole's centre moved by the ZMP's offset from the soles' midpoint, ``cop_margin_m`` inside the
sole. *Simplifications* of Kajita's stabilizer: no ZMP feedback through the COM and no body
posture control (the robot does not walk: the executor holds the COM statically over the soles);
the reference ZMP is the static one (the commanded accelerations' moments left out); the sensors
are exact (MuJoCo's contact forces, no filtering or delay).

No ROS here.
"""
from __future__ import annotations

import mujoco
import numpy as np
import pinocchio as pin

from humanoid_reach_ros.sim.physics.metrics import ContactMetrics, sole_poses
from humanoid_reach_ros.sim.physics.model_builder import PhysicsModel


def _chain(pm: PhysicsModel, body: int) -> list[int]:
    """The robot's joints (robot joint order) between the root and ``body``."""
    model = pm.model
    bodies = set()
    b = body
    while b > 0:
        bodies.add(b)
        b = int(model.body_parentid[b])
    return [k for k, adr in enumerate(pm.dof_adr) if int(model.jnt_bodyid[int(model.dof_jntid[adr])]) in bodies]


class FootStabilizer:
    """Ankle torque control and foot force difference control (module doc)."""

    def __init__(self, pm: PhysicsModel) -> None:
        self.pm = pm
        self.cfg = pm.config.stabilizer
        self.kp = pm.model.actuator_gainprm[pm.actuator_ids, 0].copy()
        names, groups = pm.robot.joint_names, pm.joint_groups
        self.legs = [_chain(pm, b) for b in pm.sole_bodies]
        self.ankles = [[k for k in leg if groups.get(names[k]) == "ankles"] for leg in self.legs]
        if not all(self.legs) or not all(self.ankles):
            raise ValueError(f"{pm.config.path}: stabilizer: each sole needs a leg with joints of the ankles group")
        self.theta = np.zeros(len(names))
        self.z = 0.0
        self.force_ref = (0.0, 0.0)
        self._leg_dq: list[np.ndarray] | None = None
        self._jacp = np.zeros((3, pm.model.nv))
        self._jacr = np.zeros((3, pm.model.nv))
        robot = pm.robot
        self._pin = robot.model.createData()      # its own: the robot model's data serves other threads
        self._sole_frame = robot.frame_id(robot.sole_frames[0])
        self._stance = robot.stance_soles

    def _reference(self, targets: np.ndarray) -> tuple[np.ndarray, float]:
        """(the reference ZMP's offset from the soles' midpoint (x, y), the right foot's share)."""
        robot, data = self.pm.robot, self._pin
        pin.framesForwardKinematics(robot.model, data, robot.config(targets))
        base = self._stance[0] * data.oMf[self._sole_frame].inverse()
        com = pin.centerOfMass(robot.model, data, robot.config(targets, base))[:2]
        r, l_ = (s.translation[:2] for s in self._stance)
        line = l_ - r
        share_r = float(np.clip(np.dot(l_ - com, line) / max(float(np.dot(line, line)), 1e-9), 0.0, 1.0))
        return com - 0.5 * (r + l_), share_r

    def offsets(self, targets: np.ndarray, m: ContactMetrics, data: mujoco.MjData, dt: float) -> np.ndarray:
        """The servo targets' offsets (robot joint order) of this tick (module doc)."""
        pm, cfg, model = self.pm, self.cfg, self.pm.model
        soles = sole_poses(pm, data)
        offset, share_r = self._reference(targets)
        total = m.foot_force_n[0] + m.foot_force_n[1]
        self.force_ref = (share_r * total, (1.0 - share_r) * total)
        x0, x1, y0, y1 = pm.robot.spec.sole_rectangle
        cx, cy, mg = 0.5 * (x0 + x1), 0.5 * (y0 + y1), cfg.cop_margin_m
        out = np.zeros(len(targets))
        for k in range(2 if cfg.ankle_time_constant_s > 0.0 else 0):
            ankles = self.ankles[k]
            fz = m.foot_force_n[k]
            if fz <= 1.0:        # in the air: back to the reference
                self.theta[ankles] *= max(0.0, 1.0 - dt / cfg.ankle_return_time_s)
                continue
            S = soles[k]
            local = S[:3, :2].T @ np.array([offset[0], offset[1], 0.0])
            local = np.clip(local, [x0 - cx + mg, y0 - cy + mg], [x1 - cx - mg, y1 - cy - mg])
            p_ref = S[:3, :3] @ np.array([cx + local[0], cy + local[1], 0.0]) + S[:3, 3]
            mujoco.mj_jac(model, data, self._jacp, self._jacr, p_ref, pm.sole_bodies[k])
            for j in ankles:
                adr = pm.dof_adr[j]
                err = float(data.qfrc_constraint[adr]) - float(self._jacp[2, adr] * fz)
                rate = -err / (self.kp[j] * cfg.ankle_time_constant_s) - self.theta[j] / cfg.ankle_return_time_s
                self.theta[j] = float(np.clip(self.theta[j] + dt * rate, -cfg.ankle_max_rad, cfg.ankle_max_rad))
        out += self.theta
        if cfg.force_time_constant_s > 0.0:
            if min(m.foot_force_n) > 1.0:
                dqs, kz = [], []
                ez = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
                for k in range(2):
                    mujoco.mj_jacBody(model, data, self._jacp, self._jacr, pm.sole_bodies[k])
                    cols = pm.dof_adr[self.legs[k]]
                    J = np.vstack([self._jacp[:, cols], self._jacr[:, cols]])
                    kz.append(1.0 / float(ez @ (J / self.kp[self.legs[k]]) @ J.T @ ez))
                    dqs.append(np.linalg.lstsq(J, ez, rcond=1e-6)[0])      # the joints that raise this sole by 1 m
                err = (m.foot_force_n[0] - m.foot_force_n[1]) - (self.force_ref[0] - self.force_ref[1])
                rate = err / (0.5 * (kz[0] + kz[1]) * cfg.force_time_constant_s) - self.z / cfg.force_return_time_s
                self.z = float(np.clip(self.z + dt * rate, -cfg.leg_length_max_m, cfg.leg_length_max_m))
                self._leg_dq = dqs
            else:                # a foot in the air: back to the reference
                self.z *= max(0.0, 1.0 - dt / cfg.force_return_time_s)
            if self._leg_dq is not None:
                # z > 0: the right foot carries more than its share: raise the right sole, lower the left
                out[self.legs[0]] += 0.5 * self.z * self._leg_dq[0]
                out[self.legs[1]] -= 0.5 * self.z * self._leg_dq[1]
        return out


__all__ = ["FootStabilizer"]
