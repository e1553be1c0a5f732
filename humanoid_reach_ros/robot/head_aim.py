"""Where to turn the head to see a point: the head yaw and pitch that point the camera at it.

Used where the operator turns the head to find the marker: ``make demo`` (the head aimed at
the scene's valve from half-sitting) and ``reach_operator --marker`` (toward the marker's last
known position from the current posture, when ``/target_pose`` is stale).
"""
from __future__ import annotations

import math

import numpy as np

from humanoid_reach_ros.robot.model import RobotModel


def aim_head_deg(robot: RobotModel, point, joints: np.ndarray | None = None,
                 step_deg: float = 1.0) -> tuple[float, float]:
    """Head yaw and pitch [deg] (within the head's limits, on a ``step_deg`` grid) that point the
    camera's optical axis closest to ``point`` [m, world] with the other joints at ``joints``
    (default: half-sitting) and the base on the feet's stance. ValueError naming the robot
    when it has no neck (its camera is aimed by the chest: ``control/gaze.py``)."""
    idx = [robot.joint_index[n] for n in robot.spec.require_neck("aiming the head by its yaw and pitch")]
    lo, hi = np.degrees(robot.lower[idx]), np.degrees(robot.upper[idx])
    joints = (robot.half_sitting_joints if joints is None else np.asarray(joints, float)).copy()
    point = np.asarray(point, float)
    best = (-2.0, 0.0, 0.0)
    for yaw in np.arange(math.ceil(lo[0] / step_deg), math.floor(hi[0] / step_deg) + 1) * step_deg:
        for pitch in np.arange(math.ceil(lo[1] / step_deg), math.floor(hi[1] / step_deg) + 1) * step_deg:
            joints[idx] = np.radians([yaw, pitch])
            cam = robot.frame_pose(robot.config(joints, robot.base_on_feet(joints)), robot.camera_frame)
            d = point - cam.translation
            c = float(cam.rotation[:, 2] @ d) / max(float(np.linalg.norm(d)), 1e-9)
            if c > best[0]:
                best = (c, float(yaw), float(pitch))
    return best[1], best[2]
