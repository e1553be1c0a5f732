"""joint_driver with ``plant: mujoco``: a real process publishes the physics plant's measured joints,
base and metrics; a bad plant name, a missing inertia or an unknown gain key exit 2 with a clear error."""
from __future__ import annotations

import numpy as np
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from humanoid_reach_interfaces.msg import PlantMetrics
from sensor_msgs.msg import JointState

from humanoid_reach_ros.io import msgs
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.sim.physics.touch import touch_force_bound
from test_physics_plant import copy_robot, drop_inertial

PARAMS_FILE = "config/joint_driver.yaml"
READY = r"simulated hrp2: 30 joints .* mujoco plant"


def physics_status(diags):
    for arr in reversed(diags.messages):
        for st in arr.status:
            if st.name.endswith(": physics"):
                return st
    return None


@pytest.mark.node
def test_mujoco_plant_publishes_measured_joints_base_and_metrics(start_node, ros_probe) -> None:
    model = RobotModel()
    driver = start_node("joint_driver", params_file=PARAMS_FILE, params={"plant": "mujoco"}, ready_log=READY,
                        timeout=60.0)
    states = ros_probe.collect(JointState, "/joint_states")
    poses = ros_probe.collect(PoseStamped, "/base_pose")
    diags = ros_probe.collect(DiagnosticArray, "/diagnostics")
    plant = ros_probe.collect(PlantMetrics, "/physics/metrics")
    ros_probe.spin_until(lambda: len(states) > 200 and len(poses) > 200, 30.0, "/joint_states and /base_pose",
                         on_timeout=driver.log_tail)
    st = ros_probe.spin_until(lambda: physics_status(diags), 15.0, "a physics diagnostic", on_timeout=driver.log_tail)
    values = msgs.diagnostic_values(st)
    print(f"\nphysics status: {st.message!r} {values}")
    assert st.level == bytes([0]), (st.message, values)
    assert values["fallen"] == "false"
    assert float(values["cop_margin_mm"]) > 30.0
    assert float(values["foot_slip_mm_max"]) < 1.0
    assert float(values["real_time_factor"]) > 0.5        # paced by the wall clock: about 1
    # the controllers under the servos (physics.yaml): the force guard on at 0.8 x the touch bound, holding
    # nothing while the robot stands; the stabilizer off
    assert float(values["force_guard_n"]) == pytest.approx(0.8 * touch_force_bound(model).bound_n)
    assert values["force_guard_holding"] == "nothing" and values["stabilizer"] == "off"
    # measured, not placed: the joints sag under gravity away from the command, the base is the plant's
    last = np.array(states.last.position)
    assert tuple(states.last.name) == model.joint_names
    assert 1e-5 < np.abs(last - model.half_sitting_joints).max() < 0.05
    base = msgs.se3_from_pose(poses.last)
    feet = model.base_on_feet(last)
    assert 0.0 < np.linalg.norm(base.translation - feet.translation) < 0.01
    # the plant's own topic: the same figures, typed, with the worst since start
    ros_probe.spin_until(lambda: len(plant) > 10, 15.0, "/physics/metrics", on_timeout=driver.log_tail)
    pm = plant.last
    print(f"/physics/metrics: cop margin {pm.cop_margin_m * 1e3:.1f} mm, base vs feet odometry "
          f"{pm.base_vs_feet_odometry_m * 1e3:.2f} mm / {np.degrees(pm.base_vs_feet_odometry_rad):.3f} deg, "
          f"rtf {pm.real_time_factor:.2f}")
    assert pm.cop_valid and pm.right_foot_contact and pm.left_foot_contact and not pm.fallen
    assert pm.right_foot_force_n > 50.0 and pm.left_foot_force_n > 50.0
    assert 0.03 < pm.cop_margin_m and 0.03 < pm.cop_margin_m_worst <= pm.cop_margin_m + 1e-9
    assert pm.foot_slip_m_worst < 1e-3 and pm.joint_tracking_error_rad_worst >= pm.joint_tracking_error_rad > 0.0
    assert 0.0 < pm.base_vs_feet_odometry_m < 0.01 and 0.0 < pm.base_vs_feet_odometry_rad < 0.05
    assert pm.sim_time_s > 1.0 and pm.real_time_factor > 0.5


@pytest.mark.node
def test_bad_plant_name_exits_2(start_node) -> None:
    driver = start_node("joint_driver", params={"plant": "bullet"})
    driver.ok_exit_codes = (2,)
    assert driver.proc.wait(20.0) == 2, driver.log_tail()
    assert driver.log_lines(r"cannot start: ValueError: plant must be one of kinematic, mujoco, got 'bullet'")
    assert "Traceback" not in driver.log()


@pytest.mark.node
def test_missing_inertia_exits_2(start_node, tmp_path) -> None:
    d = copy_robot(tmp_path)
    drop_inertial(d, "LARM_LINK2")
    driver = start_node("joint_driver", params={"plant": "mujoco", "robot_config": str(d / "robot.yaml")})
    driver.ok_exit_codes = (2,)
    assert driver.proc.wait(30.0) == 2, driver.log_tail()
    assert driver.log_lines(r"cannot start: ValueError: .*inertias MuJoCo cannot simulate: LARM_LINK2")
    assert "Traceback" not in driver.log()


@pytest.mark.node
def test_unknown_gain_key_exits_2(start_node, tmp_path) -> None:
    d = copy_robot(tmp_path)
    doc = yaml.safe_load((d / "physics.yaml").read_text())
    doc["gains"]["arms"]["ki"] = 5.0
    (d / "physics.yaml").write_text(yaml.safe_dump(doc))
    driver = start_node("joint_driver", params={"plant": "mujoco", "robot_config": str(d / "robot.yaml")})
    driver.ok_exit_codes = (2,)
    assert driver.proc.wait(30.0) == 2, driver.log_tail()
    assert driver.log_lines(r"cannot start: ValueError: .*gains\.arms: unknown gain key\(s\) \['ki'\]")
    assert "Traceback" not in driver.log()
