"""The controllers under the physics plant's servos (issue 32): the foot force stabilizer
(sim/physics/stabilizer.py) on each robot standing on a bare floor, and the servo targets' corrections
going in without velocity feed-forward (``PhysicsPlant.advance_ramped``'s offsets). The wrist force
guard's touch: test_physics_touch.py."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.sim.physics.driver import PhysicsDriver
from humanoid_reach_ros.sim.physics.stabilizer import FootStabilizer

FLOOR = """name: bare_floor
frame_id: world
primitives:
  - {name: floor, type: plane, normal: [0.0, 0.0, 1.0], offset: 0.0, floor: true}
"""
TICK_S = 0.005


@pytest.fixture(scope="module")
def floor(tmp_path_factory) -> str:
    p = tmp_path_factory.mktemp("scene") / "bare_floor.yaml"
    p.write_text(FLOOR)
    return str(p)


def stand(robot: RobotModel, floor: str, seconds: float, stabilizer: dict | None = None) -> tuple[PhysicsDriver, dict]:
    """``seconds`` of half-sitting on the driver; ``stabilizer``: its settings changed from physics.yaml's
    (None: without it)."""
    driver = PhysicsDriver(robot, robot.half_sitting_joints, floor)
    if stabilizer is not None:
        pm = driver.plant.pm
        driver.stabilizer = FootStabilizer(pm)
        driver.stabilizer.cfg = dataclasses.replace(pm.config.stabilizer, enabled=True, **stabilizer)
    worst = {"margin_m": np.inf, "tilt_deg": 0.0, "fallen": ""}
    for _ in range(round(seconds / TICK_S)):
        driver.step(robot.half_sitting_joints, TICK_S)
        m = driver.metrics
        worst["margin_m"] = min(worst["margin_m"], m.cop_margin_m)
        worst["tilt_deg"] = max(worst["tilt_deg"], m.base_tilt_deg)
        worst["fallen"] = worst["fallen"] or m.fall_reason
    return driver, worst


@pytest.mark.parametrize("name", ["hrp2", "talos", "g1"])
def test_foot_force_difference_control_brings_the_load_to_the_reference_split(name, floor) -> None:
    robot = RobotModel(name)
    plain, _ = stand(robot, floor, 2.0)
    driver, worst = stand(robot, floor, 2.0, {"ankle_time_constant_s": 0.0})
    s, m = driver.stabilizer, driver.metrics
    err = abs((m.foot_force_n[0] - m.foot_force_n[1]) - (s.force_ref[0] - s.force_ref[1]))
    err_plain = abs((plain.metrics.foot_force_n[0] - plain.metrics.foot_force_n[1]) - (s.force_ref[0] - s.force_ref[1]))
    print(f"\n{name}: force difference off the reference split {err_plain:.1f} N without, {err:.1f} N with; "
          f"leg length offset {1e3 * s.z:.3f} mm; CoP margin min {1e3 * worst['margin_m']:.1f} mm")
    assert not worst["fallen"] and worst["margin_m"] > 0.03
    assert err < max(5.0, 0.5 * err_plain)
    assert abs(s.z) < s.cfg.leg_length_max_m


def test_ankle_torque_control_stands_hrp2_more_upright(floor) -> None:
    robot = RobotModel("hrp2")
    _, plain = stand(robot, floor, 3.0)
    driver, worst = stand(robot, floor, 3.0, {})
    print(f"\nhrp2: tilt max {plain['tilt_deg']:.2f} deg without the stabilizer, {worst['tilt_deg']:.2f} with; "
          f"ankle offsets max {np.abs(driver.stabilizer.theta).max():.4f} rad")
    assert not worst["fallen"] and worst["margin_m"] > 0.05
    assert np.abs(driver.stabilizer.theta).max() < driver.stabilizer.cfg.ankle_max_rad
    # settled: the last second's tilt below the plain stand's
    assert driver.metrics.base_tilt_deg < plain["tilt_deg"]


def test_corrections_go_in_without_velocity_feed_forward(floor) -> None:
    """A correction that alternates every tick (as a noisy sensor's would) moves the servos' targets by
    itself, not 27 times over: the robot stays on both feet."""
    robot = RobotModel("hrp2")
    driver = PhysicsDriver(robot, robot.half_sitting_joints, floor)
    plant, hs = driver.plant, robot.half_sitting_joints
    legs = [robot.joint_index[j] for limb in ("right_leg", "left_leg") for j in robot.spec.limbs[limb].joints]
    low = np.inf
    for k in range(200):
        off = np.zeros(len(hs))
        off[legs] = 2e-4 * (1 if k % 2 else -1)
        plant.advance_ramped(hs, TICK_S, off)
        low = min(low, min(plant.metrics().foot_force_n))
        np.testing.assert_allclose(plant.servo_targets, np.clip(hs + off, *plant.model.actuator_ctrlrange[
            plant.pm.actuator_ids].T), atol=1e-12)
    assert low > 100.0, f"a foot unloaded to {low:.1f} N"
    with pytest.raises(ValueError, match="offsets must be"):
        plant.advance_ramped(hs, TICK_S, np.full(3, 0.1))
