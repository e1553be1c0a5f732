"""The MuJoCo physics plant (sim/physics/): each robot stands, the model is built from the robot's
files, the metrics' geometry, and clear errors for bad physics settings and inertias."""
from __future__ import annotations

import math
import shutil
from pathlib import Path

import mujoco
import numpy as np
import pytest
import yaml

from humanoid_reach_ros.paths import config_path
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.sim.physics import check_plant
from humanoid_reach_ros.sim.physics.config import load_physics_config, physics_config_from_dict
from humanoid_reach_ros.sim.physics.metrics import convex_hull, polygon_margin
from humanoid_reach_ros.sim.physics.model_builder import (build_for_robot, build_physics_model, check_inertias,
                                                          strip_geometry, torus_ring)
from humanoid_reach_ros.sim.physics.stepper import PhysicsPlant
from humanoid_reach_ros.sim.scene import Torus, load_scene

STAND_S = 5.0
CHUNK_S = 0.05
#: the stand's figures: CoP at least this far inside the support polygon, soles within SLIP_M of
#: where they started, the base within TILT_DEG of upright
MARGIN_M = 0.03
SLIP_M = 1e-3
TILT_DEG = 2.0


@pytest.fixture(scope="module")
def models() -> dict[str, RobotModel]:
    return {}


def robot_model(models: dict, name: str) -> RobotModel:
    if name not in models:
        models[name] = RobotModel(name)
    return models[name]


def stand(plant: PhysicsPlant, duration_s: float) -> dict:
    """Run the plant without pacing; the worst figures over every chunk, and the first fall."""
    worst = {"margin_m": math.inf, "slip_m": 0.0, "tilt_deg": 0.0, "fall": ""}
    while plant.sim_time_s < duration_s - 1e-9:
        plant.advance(CHUNK_S)
        m = plant.metrics()
        worst["margin_m"] = min(worst["margin_m"], m.cop_margin_m)
        worst["slip_m"] = max(worst["slip_m"], *m.sole_slip_m)
        worst["tilt_deg"] = max(worst["tilt_deg"], m.base_tilt_deg)
        if m.fallen:
            worst["fall"] = f"{m.fall_reason} at {plant.sim_time_s:.2f} s"
            break
    return worst


@pytest.mark.parametrize("robot", ["hrp2", "talos", "g1"])
def test_each_robot_stands_five_seconds_at_half_sitting(models, robot: str) -> None:
    model = robot_model(models, robot)
    plant = PhysicsPlant(build_for_robot(model))
    worst = stand(plant, STAND_S)
    timing = plant.timing()
    print(f"\n{robot}: {STAND_S:g} s standing: CoP margin min {1e3 * worst['margin_m']:.1f} mm, slip max "
          f"{1e3 * worst['slip_m']:.3f} mm, tilt max {worst['tilt_deg']:.2f} deg; {timing.step_cost_us:.0f} us/step")
    assert not worst["fall"], worst
    assert plant.sim_time_s == pytest.approx(STAND_S, abs=1e-6)
    assert worst["margin_m"] >= MARGIN_M, worst
    assert worst["slip_m"] < SLIP_M, worst
    assert worst["tilt_deg"] < TILT_DEG, worst
    m = plant.metrics()
    # both feet carry the robot's weight, the joints hold half-sitting within a sag
    total_n = model.mass * 9.81
    assert sum(m.foot_force_n) == pytest.approx(total_n, rel=0.05)
    assert min(m.foot_force_n) > 0.3 * total_n
    assert np.abs(plant.joints - model.half_sitting_joints).max() < 0.05
    # the measured base is where kinematic odometry would put it, within the servos' sag
    assert np.linalg.norm(plant.base_pose.translation - model.base_on_feet(plant.joints).translation) < 0.01


def test_without_servo_stiffness_the_robot_falls(models) -> None:
    """The stand test can fail: kp = 0 everywhere (the servos only damp) and the robot collapses."""
    model = robot_model(models, "hrp2")
    doc = yaml.safe_load(config_path("robots", "hrp2", "physics.yaml").read_text())
    for g in doc["gains"].values():
        g["kp"] = 0.0
    cfg = physics_config_from_dict(doc, Path("limp.yaml"))
    plant = PhysicsPlant(build_physics_model(model, cfg, load_scene(model.spec.demo_scene)))
    worst = stand(plant, 3.0)
    assert worst["fall"], worst


def test_model_is_built_from_the_robot_files(models) -> None:
    model = robot_model(models, "hrp2")
    pm = build_for_robot(model)
    mj = pm.model
    # the URDF's joints, a free joint, one position servo per joint limited to the URDF effort
    assert mj.njnt == model.n_joints + 1 and mj.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE
    assert mj.nu == model.n_joints
    assert mj.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    assert mj.opt.timestep == pm.config.timestep_s
    assert float(mj.body_mass.sum()) == pytest.approx(model.mass)
    efforts = {j.get("name"): float(j.find("limit").get("effort"))
               for j in strip_geometry(model.urdf_xml).iter("joint") if j.find("limit") is not None}
    for i, name in enumerate(model.joint_names):
        a = pm.actuator_ids[i]
        assert mj.actuator_forcerange[a, 1] == pytest.approx(efforts[name]), name
        np.testing.assert_allclose(mj.actuator_ctrlrange[a], [model.lower[i], model.upper[i]])
    # gains: the group's (the ankles are the legs' last two joints)
    right_leg = model.spec.limbs["right_leg"].joints
    kp = mj.actuator_gainprm[pm.actuator_ids, 0]
    assert kp[model.joint_index[right_leg[-1]]] == pm.config.gains["ankles"].kp
    assert kp[model.joint_index[right_leg[0]]] == pm.config.gains["legs"].kp
    # contact geometry: every collision shape, two sole boxes, and the scene (a torus as a ring of capsules)
    scene = load_scene(model.spec.demo_scene)
    n_torus = sum(isinstance(p, Torus) for p in scene.primitives)
    links = yaml.safe_load(model.collision_path.read_text())["links"]
    n_shapes = sum(len(shapes) for shapes in links.values())
    assert len(pm.world_geoms) == len(scene.primitives) + n_torus * (pm.config.torus_segments - 1)
    assert mj.ngeom == len(pm.world_geoms) + n_shapes + 2 + 2    # + the sole boxes + the hands' tool points
    assert pm.config.hand_sphere_radius_m > 0.0
    # the sole boxes lie flat on the floor at the start: the soles' frames on z = 0
    plant = PhysicsPlant(pm)
    for sole in plant.metrics().support_polygon:
        assert np.all(np.isfinite(sole))
    data = plant.data
    for g in pm.sole_geoms:
        bottom = data.geom_xpos[g][2] - mj.geom_size[g][2]
        assert bottom == pytest.approx(0.0, abs=1e-6)


# ------------------------------------------------------------------ metrics geometry
def test_polygon_margin_inside_outside_and_hull() -> None:
    square = convex_hull(np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0.5], [1, 0.5]], float))
    assert len(square) == 4
    assert polygon_margin(square, np.array([0.5, 0.5])) == pytest.approx(0.5)
    assert polygon_margin(square, np.array([0.9, 0.5])) == pytest.approx(0.1)
    assert polygon_margin(square, np.array([1.3, 0.5])) == pytest.approx(-0.3)
    assert polygon_margin(square, np.array([1.3, 1.4])) == pytest.approx(-0.5)   # nearest: the corner


def test_torus_ring_lies_on_the_centre_circle() -> None:
    segs = torus_ring((1.0, 2.0, 3.0), (1.0, 0.0, 0.0), 0.12, 24)
    assert len(segs) == 24
    pts = np.array([a for a, _ in segs])
    np.testing.assert_allclose(pts[:, 0], 1.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(pts[:, 1:] - [2.0, 3.0], axis=1), 0.12, atol=1e-12)
    np.testing.assert_allclose(segs[-1][1], segs[0][0], atol=1e-12)    # closed


# ------------------------------------------------------------------ clear errors
def test_bad_plant_name() -> None:
    assert check_plant("mujoco") == "mujoco"
    with pytest.raises(ValueError, match=r"plant must be one of kinematic, mujoco, got 'bullet'"):
        check_plant("bullet")


@pytest.mark.parametrize("edit, message", [
    (lambda d: d["gains"]["legs"].update(kd=3.0), r"gains\.legs: unknown gain key\(s\) \['kd'\]"),
    (lambda d: d["gains"].update(wrists={"kp": 1.0, "kv": 1.0}), r"unknown gain group\(s\) \['wrists'\]"),
    (lambda d: d["gains"]["legs"].update(dampratio=1.0), r"gains\.legs: needs kp and exactly one of dampratio, kv"),
    (lambda d: d.update(friction=-1.0), r"friction: must be > 0"),
    (lambda d: d.update(timestep_s=0.05), r"timestep_s 0.05 is too long"),
    (lambda d: d.update(solver="newton"), r"unknown top-level key\(s\) \['solver'\]"),
    (lambda d: d["gains"].pop("ankles"), r"has no gain: add gains\.ankles"),
    (lambda d: d.update(joint_gains={"NO_SUCH_JOINT": {"kp": 1.0, "kv": 1.0}}),
     r"the robot has no joint 'NO_SUCH_JOINT'"),
    (lambda d: d["force_guard"].update(gain=1.0), r"force_guard: unknown key\(s\) \['gain'\]"),
    (lambda d: d["force_guard"].update(bound_fraction=1.5), r"force_guard\.bound_fraction: at most 1"),
    (lambda d: d["force_guard"].update(release_s=0.001), r"force_guard\.release_s: at least 0\.01 s"),
    (lambda d: d["force_guard"].update(enabled="yes"), r"force_guard\.enabled: expected true or false"),
    (lambda d: d.update(force_guard=[0.8]), r"force_guard: expected a mapping"),
    (lambda d: d["stabilizer"].update(gain=1.0), r"stabilizer: unknown key\(s\) \['gain'\]"),
    (lambda d: d["stabilizer"].update(ankle_time_constant_s=0.002), r"stabilizer\.ankle_time_constant_s: at least"),
    (lambda d: d["stabilizer"].update(ankle_max_rad=-0.1), r"stabilizer\.ankle_max_rad: must be > 0"),
])
def test_bad_physics_settings_are_clear_errors(models, edit, message) -> None:
    model = robot_model(models, "hrp2")
    doc = yaml.safe_load(config_path("robots", "hrp2", "physics.yaml").read_text())
    edit(doc)
    with pytest.raises(ValueError, match=message):
        cfg = physics_config_from_dict(doc, Path("bad_physics.yaml"))
        build_physics_model(model, cfg, load_scene(model.spec.demo_scene))


def test_missing_physics_file_is_a_clear_error(tmp_path) -> None:
    with pytest.raises(ValueError, match=r"no physics settings .*physics\.yaml"):
        load_physics_config(tmp_path)


def copy_robot(tmp_path: Path, robot: str = "hrp2") -> Path:
    """A copy of a robot description directory (robot.yaml, URDF, collision model, physics.yaml)."""
    dst = tmp_path / robot
    shutil.copytree(config_path("robots", robot), dst)
    return dst


def drop_inertial(robot_dir: Path, link: str) -> None:
    """Remove the ``<inertial>`` of ``link`` from the URDF (``urdf`` of robot.yaml) in ``robot_dir``."""
    urdf = robot_dir / yaml.safe_load((robot_dir / "robot.yaml").read_text())["urdf"]
    text = urdf.read_text()
    i0 = text.index("<inertial>", text.index(f'<link name="{link}">'))
    i1 = text.index("</inertial>", i0) + len("</inertial>")
    urdf.write_text(text[:i0] + text[i1:])


def test_missing_inertia_is_a_clear_error(tmp_path) -> None:
    d = copy_robot(tmp_path)
    drop_inertial(d, "RLEG_LINK3")    # the right knee link
    model = RobotModel(d / "robot.yaml")
    with pytest.raises(ValueError, match=r"inertias MuJoCo cannot simulate: RLEG_LINK3: a moving link without"):
        build_for_robot(model)


@pytest.mark.parametrize("inertia, message", [
    ('ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.05"', "triangle inequality"),
    ('ixx="0.01" ixy="0" ixz="0" iyy="-0.01" iyz="0" izz="0.01"', "not positive definite"),
    ('ixx="nan" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"', "missing or not finite"),
])
def test_invalid_inertia_is_named(inertia: str, message: str) -> None:
    import xml.etree.ElementTree as ET

    urdf = ('<robot name="r"><link name="a"><inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" '
            f'iyz="0" izz="1"/></inertial></link><link name="b"><inertial><mass value="1"/><inertia {inertia}/>'
            '</inertial></link><joint name="j" type="revolute"><parent link="a"/><child link="b"/></joint></robot>')
    with pytest.raises(ValueError, match=rf"b: .*{message}"):
        check_inertias(ET.fromstring(urdf), "r.urdf")


def test_hand_pressing_on_an_obstacle_is_a_measured_force(models) -> None:
    """A ball 1 cm into the right hand's tool point (the sphere about its frame): the hand's contact force on it is
    measured, the left's is zero, and the feet carry what the ball does not."""
    from humanoid_reach_ros.sim.scene import scene_from_dict

    model = robot_model(models, "hrp2")
    hand = model.frame_pose(model.half_sitting(), model.hand_frames["right"]).translation
    below = 0.06 + load_physics_config(model.spec.path.parent).hand_sphere_radius_m - 0.01
    doc = {"name": "ball", "primitives": [
        {"name": "floor", "type": "plane", "normal": [0.0, 0.0, 1.0], "offset": 0.0, "floor": True},
        {"name": "ball", "type": "sphere", "center": [float(hand[0]), float(hand[1]), float(hand[2]) - below],
         "radius": 0.06}]}
    pm = build_physics_model(model, load_physics_config(model.spec.path.parent), scene_from_dict(doc))
    plant = PhysicsPlant(pm)
    plant.run(0.5)
    m = plant.metrics()
    assert not m.fallen, m.fall_reason
    assert m.hand_force_n["right"] > 1.0, m.hand_force_n
    assert m.hand_force_n["left"] == 0.0
    assert sum(m.foot_force_n) < model.mass * 9.81 * 1.02
