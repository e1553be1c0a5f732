"""``sim/driver.py`` without ROS: postures, commands, staleness, loop statistics and diagnostics.

The driver runs on a fake clock, so the staleness timeout, the measured periods and the
overrun count are exact.
"""
from __future__ import annotations

import numpy as np
import pytest

from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.sim.driver import OK, WARN, SimulatedDriver, initial_joints

PERIOD = 0.005


class Clock:
    def __init__(self) -> None:
        self.now = 10.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture(scope="module")
def model() -> RobotModel:
    return RobotModel()


def make(model: RobotModel, **kw) -> tuple[SimulatedDriver, Clock]:
    clock = Clock()
    kw.setdefault("command_timeout_s", 0.5)
    return SimulatedDriver(model, "half_sitting", period_s=PERIOD, clock=clock, **kw), clock


def run(driver: SimulatedDriver, clock: Clock, seconds: float, period: float = PERIOD) -> list:
    """Ticks every ``period`` for ``seconds``; returns the notices."""
    notices = []
    for _ in range(round(seconds / period)):
        clock.now += period
        t, dt, notice = driver.begin_tick()
        driver.sim.step(dt)
        driver.end_tick(t)
        if notice is not None:
            notices.append(notice)
    return notices


def by_name(statuses) -> dict:
    return {suffix: (level, message, values) for suffix, level, message, values in statuses}


def test_postures(model: RobotModel) -> None:
    np.testing.assert_allclose(initial_joints(model, "half_sitting"), model.half_sitting_joints)
    assert list(initial_joints(model, "zero")) == [0.0] * model.n_joints
    with pytest.raises(ValueError, match="initial_posture must be one of"):
        initial_joints(model, "crouch")
    driver, _ = make(model)
    np.testing.assert_allclose(driver.sim.q, model.half_sitting_joints)


def test_first_tick_steps_one_period_then_the_measured_one(model: RobotModel) -> None:
    driver, clock = make(model)
    clock.now += 0.004
    assert driver.begin_tick()[1] == pytest.approx(PERIOD)
    clock.now += 0.006
    assert driver.begin_tick()[1] == pytest.approx(0.006)
    assert driver.ticks == 2 and driver.overruns == 0


def test_overruns_counted_past_the_factor(model: RobotModel) -> None:
    driver, clock = make(model, overrun_factor=1.5)
    run(driver, clock, 0.05)                 # 10 regular ticks
    clock.now += 2.0 * PERIOD                 # one long period (2 periods > 1.5)
    driver.begin_tick()
    assert driver.overruns == 1
    loop = by_name(driver.statuses(clock.now, "world", "base_link"))["loop"]
    assert loop[2]["overruns_total"] == 1 and loop[2]["overruns_recent"] == 1
    assert loop[2]["max_period_ms"] == pytest.approx(2 * PERIOD * 1e3)
    assert loop[2]["ticks_total"] == 11
    # a new window after each diagnostics message
    run(driver, clock, 0.05)
    loop = by_name(driver.statuses(clock.now, "world", "base_link"))["loop"]
    assert loop[2]["overruns_recent"] == 0 and loop[2]["overruns_total"] == 1
    assert loop[2]["achieved_rate_hz"] == pytest.approx(1 / PERIOD)
    assert loop[0] == OK


def test_slow_loop_warns(model: RobotModel) -> None:
    driver, clock = make(model)
    run(driver, clock, 0.2, period=2 * PERIOD)     # 100 Hz of 200
    level, message, values = by_name(driver.statuses(clock.now, "world", "base_link"))["loop"]
    assert level == WARN and "of 200 Hz" in message
    assert values["nominal_rate_hz"] == pytest.approx(200.0)


def test_command_tracks_then_goes_stale_while_moving_and_resumes(model: RobotModel) -> None:
    driver, clock = make(model, command_timeout_s=0.1)
    status = by_name(driver.statuses(clock.now, "world", "base_link"))["commands"]
    assert status[1] == "no joint_command yet: holding the initial posture"
    assert status[2]["command_age_s"] == "never"
    name = model.joint_names[0]
    q0 = float(driver.sim.q[0])
    result, resumed = driver.command([name], [q0 + 1.0])
    assert result.accepted and not resumed
    notices = run(driver, clock, 0.2)
    assert len(notices) == 1
    warn, text = notices[0]
    assert warn and text.startswith("joint_command stale (nothing for 0.1 s) while moving")
    assert driver.stale and driver.stopped_short_rad > 0.0
    np.testing.assert_allclose(driver.sim.target, driver.sim.q)     # held where it was
    level, message, values = by_name(driver.statuses(clock.now, "world", "base_link"))["commands"]
    assert level == WARN and "while moving" in message and values["stale"] is True
    result, resumed = driver.command([name], [q0])
    assert result.accepted and resumed and not driver.stale
    assert driver.command([name], [q0])[1] is False


def test_idle_command_goes_stale_quietly(model: RobotModel) -> None:
    driver, clock = make(model, command_timeout_s=0.1)
    driver.command([model.joint_names[0]], [float(driver.sim.q[0])])
    notices = run(driver, clock, 0.2)
    assert notices == [(False, "joint_command idle for 0.1 s: holding position")]
    level, message, _ = by_name(driver.statuses(clock.now, "world", "base_link"))["commands"]
    assert level == OK and message.startswith("joint_command idle")


def test_rejections_and_clipping_reported_once(model: RobotModel) -> None:
    driver, clock = make(model)
    result, _ = driver.command(["NO_SUCH_JOINT"], [0.0])
    assert not result.accepted
    name = model.joint_names[0]
    result, _ = driver.command([name], [100.0])
    assert result.accepted and result.clipped == (name,)
    s = by_name(driver.statuses(clock.now, "world", "base_link"))
    assert s["commands"][0] == WARN and s["commands"][2]["rejected_recent"] == 1
    assert s["limits"][0] == WARN and s["limits"][2][f"clipped_targets.{name}"] == 1
    s = by_name(driver.statuses(clock.now, "world", "base_link"))
    assert s["commands"][0] == OK and s["commands"][2]["rejected_total"] == 1
    assert s["limits"][0] == OK and s["limits"][2]["clip_events_total"] == 1


def test_odometry_status_names_the_frames(model: RobotModel) -> None:
    driver, clock = make(model)
    level, _, values = by_name(driver.statuses(clock.now, "odom", "waist"))["odometry"]
    assert level == OK and values["frame_id"] == "odom" and values["child_frame_id"] == "waist"
    assert values["left_foot_slip_m"] == pytest.approx(0.0, abs=1e-6)
    assert [s[0] for s in driver.statuses(clock.now, "w", "b")] == ["commands", "limits", "loop", "odometry"]
