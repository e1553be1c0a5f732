"""sim/physics/summary.py: a run's figures from /physics/metrics messages (any objects with
msg/PlantMetrics's fields); none measured is None, never a pass."""
from __future__ import annotations

import math
from types import SimpleNamespace

import pytest

from humanoid_reach_ros.sim.physics.summary import FIGURE_KEYS, plant_figures


def message(**kw):
    base = dict(fallen=False, fall_reason="", joint_tracking_error_rad=0.01, cop_margin_m_worst=0.08,
                foot_slip_m_worst=2e-4, base_tilt_rad_worst=math.radians(0.6), joint_tracking_error_rad_worst=0.02,
                hand_force_n_worst=0.0, real_time_factor_worst=1.0, plant_cpu_pct=5.0, base_vs_feet_odometry_m=5e-4,
                base_vs_feet_odometry_rad=1e-4)
    return SimpleNamespace(**{**base, **kw})


def test_extremes_come_from_the_last_message_and_a_fall_from_any() -> None:
    msgs = [message(joint_tracking_error_rad=0.001 * k) for k in range(100)]
    msgs[40] = message(fallen=True, fall_reason="tilted")
    msgs[-1] = message(cop_margin_m_worst=0.012, foot_slip_m_worst=0.0031, hand_force_n_worst=42.0,
                       base_vs_feet_odometry_m=0.02, joint_tracking_error_rad=0.099)
    f = plant_figures(msgs)
    assert set(f) == set(FIGURE_KEYS)
    assert f["falls"] == 1 and f["fall_reason"] == "tilted"
    assert f["cop_margin_mm_min"] == pytest.approx(12.0) and f["foot_slip_mm_max"] == pytest.approx(3.1)
    assert f["hand_contact_force_n_max"] == 42.0 and f["base_vs_feet_odometry_mm_max"] == pytest.approx(20.0)
    assert 0.09 < f["joint_tracking_error_rad_p99"] <= 0.099 and f["plant_messages"] == 100


def test_no_message_is_no_figure_and_no_foot_contact_is_no_margin() -> None:
    f = plant_figures([])
    assert f["plant_messages"] == 0 and all(f[k] is None for k in FIGURE_KEYS if k != "plant_messages")
    assert plant_figures([message(cop_margin_m_worst=math.inf)])["cop_margin_mm_min"] is None
