"""The figures of a run on the physics plant, from the ``/physics/metrics`` messages a client kept
(``msg/PlantMetrics``; any objects with its fields: no ROS here).

Extremes come from the messages' ``*_worst`` fields (the plant's own, over every 1 ms step since
it started, so nothing between two messages is missed) of the last message; the tracking error's
99th percentile from the per-message values (one per ``physics_metrics_period_s``). A run with no
message has no figures: every value None (a missing measurement, never a pass).
"""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

#: the keys of :func:`plant_figures`
FIGURE_KEYS = ("falls", "fall_reason", "cop_margin_mm_min", "foot_slip_mm_max", "base_tilt_deg_max",
               "joint_tracking_error_rad_p99", "joint_tracking_error_rad_max", "hand_contact_force_n_max",
               "real_time_factor_min", "plant_cpu_pct", "base_vs_feet_odometry_mm_max",
               "base_vs_feet_odometry_deg_max", "plant_messages")


def plant_figures(messages: Sequence[Any]) -> dict[str, Any]:
    """The run's figures (module doc): falls (0 or 1: a plant falls once), the smallest CoP margin
    [mm], the largest slip [mm], tilt [deg], hand force [N], the tracking error's p99 and max [rad],
    the smallest real-time factor (over 1 s windows), the plant's CPU [% of a core] at the end and
    how far the measured base came from the feet odometry's [mm, deg]."""
    if not messages:
        return {k: (0 if k == "plant_messages" else None) for k in FIGURE_KEYS}
    last = messages[-1]
    fallen = next((m for m in messages if m.fallen), None)
    track = np.array([m.joint_tracking_error_rad for m in messages])
    margin = last.cop_margin_m_worst
    return {
        "falls": int(fallen is not None), "fall_reason": fallen.fall_reason if fallen is not None else "",
        "cop_margin_mm_min": round(1e3 * margin, 2) if math.isfinite(margin) else None,
        "foot_slip_mm_max": round(1e3 * last.foot_slip_m_worst, 4),
        "base_tilt_deg_max": round(math.degrees(last.base_tilt_rad_worst), 3),
        "joint_tracking_error_rad_p99": round(float(np.percentile(track, 99)), 5),
        "joint_tracking_error_rad_max": round(float(last.joint_tracking_error_rad_worst), 5),
        "hand_contact_force_n_max": round(float(last.hand_force_n_worst), 2),
        "real_time_factor_min": round(float(last.real_time_factor_worst), 4),
        "plant_cpu_pct": round(float(last.plant_cpu_pct), 2),
        "base_vs_feet_odometry_mm_max": round(1e3 * max(m.base_vs_feet_odometry_m for m in messages), 3),
        "base_vs_feet_odometry_deg_max": round(math.degrees(max(m.base_vs_feet_odometry_rad for m in messages)), 4),
        "plant_messages": len(messages),
    }


__all__ = ["FIGURE_KEYS", "plant_figures"]
