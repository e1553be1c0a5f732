"""The joint driver's physics plant (``joint_driver`` with ``plant: mujoco``), without ROS.

The kinematic :class:`~humanoid_reach_ros.sim.joint_sim.JointSimulator` keeps doing what it
does for the kinematic plant -- validating commands, rate-limiting and smoothing them, holding
on a stale command -- and its joint angles become the servos' position targets here: the
interpolator of a real joint controller, with the physics plant as the hardware under it. Each
loop tick advances the plant by the tick's measured period (so simulated time follows the wall
clock), the servos' targets ramped over its 1 ms steps (``PhysicsPlant.advance_ramped``: a tick
that came late under load moves them in small steps, not one jump), and publishes what the
plant measures: joint angles and velocities, and the floating base's pose (not placed on the feet).

:meth:`PhysicsDriver.statuses` adds one ``physics`` diagnostics status: the plant's timing
(real-time factor, capacity, own CPU, step cost), the contact metrics now and their extremes
since start (CoP, its margin to the support polygon, sole slip, base tilt, hand forces, fall),
and how far the measured base is from the base the kinematic odometry would place on the right
sole (what the rest of the graph assumed before the plant existed).
"""
from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.sim.physics.metrics import ContactMetrics
from humanoid_reach_ros.sim.physics.model_builder import build_for_robot
from humanoid_reach_ros.sim.physics.stabilizer import FootStabilizer
from humanoid_reach_ros.sim.physics.force_guard import ContactForceGuard, body_contacts
from humanoid_reach_ros.sim.physics.stepper import PhysicsPlant
from humanoid_reach_ros.sim.physics.touch import touch_force_bound

OK, WARN, ERROR = 0, 1, 2     # diagnostic_msgs/DiagnosticStatus levels
#: the real-time factor's worst is taken over windows this long [s], after the first one
RTF_WINDOW_S = 1.0


@dataclass(frozen=True)
class PlantSnapshot:
    """What the plant measured, now and worst since start (``msg/PlantMetrics``; no ROS here).
    Points in the world frame [m], forces [N], angles [rad]."""

    sim_time_s: float
    metrics: ContactMetrics
    joint_tracking_error_rad: float
    base_vs_feet_odometry_m: float
    base_vs_feet_odometry_rad: float
    real_time_factor: float
    capacity_x_real_time: float
    plant_cpu_pct: float
    cop_margin_m_worst: float
    foot_slip_m_worst: float
    base_tilt_rad_worst: float
    hand_force_n_worst: float
    joint_tracking_error_rad_worst: float
    real_time_factor_worst: float
    fall_reason: str


class PhysicsDriver:
    """A :class:`PhysicsPlant` tracking the kinematic simulator's joints (module doc)."""

    def __init__(self, model: RobotModel, joints: np.ndarray, scene_file: str | None = None) -> None:
        self.model = model
        self.plant = PhysicsPlant(build_for_robot(model, scene_file), np.asarray(joints, float))
        pm = self.plant.pm
        # under the servos, from the plant's force sensors (stabilizer.py, force_guard.py): off in physics.yaml: none
        self.stabilizer = FootStabilizer(pm) if pm.config.stabilizer.enabled else None
        self.guard = ContactForceGuard(pm, touch_force_bound(model).bound_n) if pm.config.force_guard.enabled else None
        self.correction = np.zeros(model.n_joints)      # the servo targets' offsets of the last tick
        self.lock = threading.Lock()        # the loop thread steps, the diagnostics timer reads
        self.metrics: ContactMetrics = self.plant.metrics()
        self._worst = {"cop_margin_mm_min": math.inf, "foot_slip_mm_max": 0.0, "base_tilt_deg_max": 0.0,
                       "hand_contact_force_n_max": 0.0, "joint_tracking_error_rad_max": 0.0}
        self.fallen_reason = ""
        self.tracking_error_rad = 0.0
        self._rtf_window: tuple[float, float] | None = None    # (wall, sim) at the window's start
        self._rtf_worst = math.inf
        self._rtf_windows = 0

    def step(self, targets: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray, pin.SE3]:
        """Set the servos' targets, simulate ``dt`` and measure; returns (joints, velocities, base pose)."""
        with self.lock:
            plant = self.plant
            targets = np.asarray(targets, float)
            corr = np.zeros(len(targets))
            if self.stabilizer is not None:
                corr += self.stabilizer.offsets(targets, self.metrics, plant.data, dt)
            if self.guard is not None:
                corr += self.guard.offsets(targets, plant.joints, body_contacts(plant.pm, plant.data), dt)
            self.correction = corr
            plant.advance_ramped(targets, dt, corr, None if self.guard is None else self.guard.held_now)
            m = self.metrics = plant.metrics()
            w = self._worst
            if m.cop is not None:
                w["cop_margin_mm_min"] = min(w["cop_margin_mm_min"], 1e3 * m.cop_margin_m)
            w["foot_slip_mm_max"] = max(w["foot_slip_mm_max"], 1e3 * max(m.sole_slip_m))
            w["base_tilt_deg_max"] = max(w["base_tilt_deg_max"], m.base_tilt_deg)
            w["hand_contact_force_n_max"] = max(w["hand_contact_force_n_max"], *m.hand_force_n.values())
            joints = plant.joints
            self.tracking_error_rad = float(np.abs(plant.servo_targets - joints).max())
            w["joint_tracking_error_rad_max"] = max(w["joint_tracking_error_rad_max"], self.tracking_error_rad)
            if m.fallen and not self.fallen_reason:
                self.fallen_reason = m.fall_reason
            return joints, plant.joint_velocities, plant.base_pose

    def base_vs_feet(self) -> tuple[float, float]:
        """How far the measured base is from the base kinematic odometry puts on the right sole
        (``RobotModel.base_on_feet`` of the measured joints: what every node but the plant assumes):
        (distance [m], rotation angle [rad])."""
        with self.lock:
            joints, base = self.plant.joints, self.plant.base_pose
        feet = self.model.base_on_feet(joints)
        d = feet.actInv(base)
        return float(np.linalg.norm(base.translation - feet.translation)), float(np.linalg.norm(pin.log3(d.rotation)))

    def snapshot(self) -> PlantSnapshot:
        """The figures of now and the worst since start (``msg/PlantMetrics``). The real-time
        factor's worst is over windows of :data:`RTF_WINDOW_S` (the first one, while the graph
        starts, left out)."""
        offset_m, offset_rad = self.base_vs_feet()
        with self.lock:
            m, t, w = self.metrics, self.plant.timing(), dict(self._worst)
            err = self.tracking_error_rad
            now = (time.perf_counter(), t.sim_time_s)
            if self._rtf_window is None:
                self._rtf_window = now
            elif now[0] - self._rtf_window[0] >= RTF_WINDOW_S:
                if self._rtf_windows:     # the first window (the graph starting) is left out
                    rtf = (now[1] - self._rtf_window[1]) / (now[0] - self._rtf_window[0])
                    self._rtf_worst = min(self._rtf_worst, rtf)
                self._rtf_windows += 1
                self._rtf_window = now
            rtf_worst = self._rtf_worst
        return PlantSnapshot(
            sim_time_s=t.sim_time_s, metrics=m, joint_tracking_error_rad=err, base_vs_feet_odometry_m=offset_m,
            base_vs_feet_odometry_rad=offset_rad, real_time_factor=t.real_time_factor,
            capacity_x_real_time=t.capacity, plant_cpu_pct=t.cpu_pct,
            cop_margin_m_worst=1e-3 * w["cop_margin_mm_min"], foot_slip_m_worst=1e-3 * w["foot_slip_mm_max"],
            base_tilt_rad_worst=math.radians(w["base_tilt_deg_max"]), hand_force_n_worst=w["hand_contact_force_n_max"],
            joint_tracking_error_rad_worst=w["joint_tracking_error_rad_max"],
            real_time_factor_worst=rtf_worst if math.isfinite(rtf_worst) else t.real_time_factor,
            fall_reason=self.fallen_reason)

    def statuses(self) -> list[tuple[str, int, str, dict]]:
        """The ``physics`` status (module doc), as (name suffix, level, message, values)."""
        offset_m, offset_rad = self.base_vs_feet()
        with self.lock:
            m, t, w = self.metrics, self.plant.timing(), dict(self._worst)
        values = {
            "real_time_factor": t.real_time_factor, "capacity_x_real_time": t.capacity, "plant_cpu_pct": t.cpu_pct,
            "step_cost_us": t.step_cost_us, "sim_time_s": t.sim_time_s, "timestep_s": self.plant.pm.timestep_s,
            "cop_x_m": m.cop[0] if m.cop is not None else "no foot contact",
            "cop_y_m": m.cop[1] if m.cop is not None else "no foot contact",
            "cop_margin_mm": 1e3 * m.cop_margin_m if m.cop is not None else "no foot contact",
            "right_foot_force_n": m.foot_force_n[0], "left_foot_force_n": m.foot_force_n[1],
            "right_foot_slip_mm": 1e3 * m.sole_slip_m[0], "left_foot_slip_mm": 1e3 * m.sole_slip_m[1],
            "base_tilt_deg": m.base_tilt_deg, "base_z_m": m.base_height_m,
            "capture_point_out_mm": 1e3 * m.capture_point_out_m,
            "base_vs_feet_odometry_mm": 1e3 * offset_m, "base_vs_feet_odometry_deg": math.degrees(offset_rad),
            **{f"{side}_hand_force_n": f for side, f in m.hand_force_n.items()},
            **{k: (v if math.isfinite(v) else "no foot contact yet") for k, v in w.items()},
            "fallen": bool(self.fallen_reason), "fall_reason": self.fallen_reason,
            "stabilizer": "on" if self.stabilizer is not None else "off",
            "force_guard_n": self.guard.guard_n if self.guard is not None else "off",
            "servo_target_correction_rad_max": float(np.abs(self.correction).max()),
        }
        if self.stabilizer is not None:
            values["stabilizer_leg_length_offset_mm"] = 1e3 * self.stabilizer.z
            values["stabilizer_ankle_offset_rad_max"] = float(np.abs(self.stabilizer.theta).max())
        if self.guard is not None:
            values["force_guard_holding"] = ", ".join(self.guard.holding_bodies) or "nothing"
            values["force_guard_holds"] = self.guard.holds
            values["force_guard_held_bodies"] = ", ".join(self.guard.held_bodies) or "none"
        for side, cop in zip(("right", "left"), m.foot_cop):
            if cop is not None:
                values[f"{side}_foot_cop_x_m"], values[f"{side}_foot_cop_y_m"] = float(cop[0]), float(cop[1])
        if self.fallen_reason:
            return [("physics", ERROR, f"fallen: {self.fallen_reason}", values)]
        if m.cop is None or m.cop_margin_m < 0.0:
            return [("physics", WARN, "centre of pressure outside the support polygon" if m.cop is not None
                     else "no foot on the ground", values)]
        return [("physics", OK, f"standing: CoP {1e3 * m.cop_margin_m:.0f} mm inside the support polygon, "
                 f"real time x{t.real_time_factor:.2f}", values)]


__all__ = ["RTF_WINDOW_S", "PhysicsDriver", "PlantSnapshot"]
