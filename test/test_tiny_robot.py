"""A robot is its description (issue 13 part 5): a small synthetic humanoid -- URDF, robot.yaml
and collision.yaml written by this test into a temporary directory, nothing in config/ --
loads, gets its limbs solved (legs by the compiled closed form; arms of an axis pattern the
hand-derived solvers do not know, x z | y | z x y, by the general one), stands balanced and
free of self-collision, and the planner plans a reach with it. Nothing else in the package
names or numbers a robot (test_robot_spec.py greps for it)."""
from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from humanoid_reach_ros.dual_arm.balance import polygon_margin, support_polygon
from humanoid_reach_ros.kinematics.general_limb import GeneralLimb
from humanoid_reach_ros.kinematics.hand_derived import LimbIK
from humanoid_reach_ros.kinematics.registry import LimbIKSet
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.shapes import load_collision_model
from humanoid_reach_ros.robot.spec import robots

AXES = {"x": "1 0 0", "y": "0 1 0", "z": "0 0 1"}


def _box_link(name: str, mass: float, size, centre=(0.0, 0.0, 0.0)) -> str:
    a, b, c = size
    ixx, iyy, izz = (mass * (b * b + c * c) / 12, mass * (a * a + c * c) / 12, mass * (a * a + b * b) / 12)
    xyz = " ".join(map(str, centre))
    return (f'<link name="{name}"><inertial><origin xyz="{xyz}"/><mass value="{mass}"/>'
            f'<inertia ixx="{ixx:.6g}" ixy="0" ixz="0" iyy="{iyy:.6g}" iyz="0" izz="{izz:.6g}"/></inertial>'
            f'<visual><origin xyz="{xyz}"/><geometry><box size="{a} {b} {c}"/></geometry></visual></link>')


def _joint(name, parent, child, axis, xyz, lo, hi) -> str:
    return (f'<joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{xyz[0]} {xyz[1]} {xyz[2]}"/><axis xyz="{AXES[axis]}"/>'
            f'<limit lower="{lo}" upper="{hi}" velocity="3" effort="50"/></joint>')


def _limb(side: str, parent: str, joints, links: dict, tip: str, tip_z: float) -> list[str]:
    """A serial limb: ``joints`` (name, axis, xyz, lo, hi) from ``parent``, each child link a box
    (``links``: joint index -> (mass, size, centre)), then a fixed ``tip``
    frame ``tip_z`` below the last link."""
    parts = []
    for k, (j, ax, xyz, lo, hi) in enumerate(joints):
        child = f"{side}_{j}_link"
        mass, size, centre = links[k]
        parts += [_box_link(child, mass, size, centre), _joint(f"{side}_{j}", parent, child, ax, xyz, lo, hi)]
        parent = child
    return parts + [f'<link name="{side}_{tip}"/><joint name="{side}_{tip}_fix" type="fixed"><parent link="{parent}"/>'
                    f'<child link="{side}_{tip}"/><origin xyz="0 0 {tip_z:g}"/></joint>']


def tiny_urdf() -> str:
    """0.9 m tall, 14 kg: waist, legs z x y | y | y x (thigh and shank 0.2 m), chest yaw and
    pitch, arms x z | y | z x y (upper arm and forearm 0.14 m, spherical wrist), head yaw and
    pitch; no camera frame (robot.yaml adds one)."""
    parts = [_box_link("waist", 3.0, (0.14, 0.18, 0.10))]
    for s, sy in (("r", -1), ("l", 1)):
        leg = [("hip_yaw", "z", (0, sy * 0.06, -0.06), -0.5, 0.5), ("hip_roll", "x", (0, 0, 0), -0.4, 0.4),
               ("hip_pitch", "y", (0, 0, 0), -1.8, 0.6), ("knee", "y", (0, 0, -0.2), 0.0, 2.4),
               ("ankle_pitch", "y", (0, 0, -0.2), -1.2, 0.8), ("ankle_roll", "x", (0, 0, 0), -0.4, 0.4)]
        small = (0.2, (0.04, 0.04, 0.04), (0, 0, 0))
        links = {0: small, 1: small, 2: (1.5, (0.07, 0.07, 0.2), (0, 0, -0.1)),
                 3: (1.0, (0.06, 0.06, 0.2), (0, 0, -0.1)), 4: small, 5: (0.6, (0.14, 0.08, 0.03), (0.01, 0, -0.025))}
        parts += _limb(s, "waist", leg, links, "sole", -0.04)
    parts += [_box_link("chest_yaw_link", 0.3, (0.05, 0.05, 0.05)), _joint("chest_yaw", "waist", "chest_yaw_link", "z",
                                                                          (0, 0, 0.08), -0.8, 0.8),
              _box_link("chest", 3.0, (0.12, 0.2, 0.22), (0, 0, 0.11)),
              _joint("chest_pitch", "chest_yaw_link", "chest", "y", (0, 0, 0), -0.3, 0.8),
              _box_link("head_yaw_link", 0.1, (0.03, 0.03, 0.03)),
              _joint("head_yaw", "chest", "head_yaw_link", "z", (0, 0, 0.26), -1.2, 1.2),
              _box_link("head", 0.8, (0.1, 0.1, 0.1), (0.01, 0, 0.05)),
              _joint("head_pitch", "head_yaw_link", "head", "y", (0, 0, 0), -0.5, 0.9)]
    for s, sy in (("r", -1), ("l", 1)):
        arm = [("shoulder_roll", "x", (0, sy * 0.13, 0.18), -1.6, 1.6), ("shoulder_yaw", "z", (0, 0, 0), -1.6, 1.6),
               ("elbow", "y", (0, 0, -0.14), -2.4, 0.0), ("wrist_yaw", "z", (0, 0, -0.14), -1.6, 1.6),
               ("wrist_roll", "x", (0, 0, 0), -1.6, 1.6), ("wrist_pitch", "y", (0, 0, 0), -1.6, 1.6)]
        small = (0.1, (0.03, 0.03, 0.03), (0, 0, 0))
        links = {0: small, 1: (0.5, (0.05, 0.05, 0.14), (0, 0, -0.07)), 2: (0.4, (0.045, 0.045, 0.14), (0, 0, -0.07)),
                 3: small, 4: small, 5: (0.2, (0.03, 0.05, 0.06), (0, 0, -0.03))}
        parts += _limb(s, "chest", arm, links, "hand", -0.08)
    return '<?xml version="1.0"?><robot name="tiny">' + "".join(parts) + "</robot>"


def tiny_description() -> dict:
    deg = {"hip_pitch": -25.0, "knee": 50.0, "ankle_pitch": -25.0, "elbow": -40.0}
    hs = {f"{s}_{j}": v for s in "rl" for j, v in deg.items()}
    hs.update(r_shoulder_roll=-12.0, l_shoulder_roll=12.0)
    leg = ["hip_yaw", "hip_roll", "hip_pitch", "knee", "ankle_pitch", "ankle_roll"]
    arm = ["shoulder_roll", "shoulder_yaw", "elbow", "wrist_yaw", "wrist_roll", "wrist_pitch"]
    return {
        "robot_name": "tiny", "urdf": "tiny.urdf", "collision_model": "collision.yaml", "base_link": "waist",
        "frames": {"head_camera": {"parent": "head", "xyz": [0.06, 0.0, 0.06],
                                   "rpy": [-math.pi / 2, 0.0, -math.pi / 2]}},
        "limbs": {f"{side}_leg": {"root": "waist", "tip": f"{s}_sole", "joints": [f"{s}_{j}" for j in leg]}
                  for side, s in (("right", "r"), ("left", "l"))}
        | {f"{side}_arm": {"root": "chest", "tip": f"{s}_hand", "joints": [f"{s}_{j}" for j in arm]}
           for side, s in (("right", "r"), ("left", "l"))},
        "chest": {"yaw": "chest_yaw", "pitch": "chest_pitch"},
        "head": {"yaw": "head_yaw", "pitch": "head_pitch", "camera_frame": "head_camera"},
        "sole_rectangle_m": [-0.06, 0.08, -0.04, 0.04],
        "half_sitting": hs,
    }


def tiny_collision() -> dict:
    def cap(name, p0, p1, r):
        return {"name": name, "capsule": {"p0": list(p0), "p1": list(p1), "radius": r}}

    links = {"waist": [cap("waist", (0, -0.05, 0), (0, 0.05, 0), 0.07)],
             "chest": [cap("chest", (0, -0.05, 0.06), (0, 0.05, 0.16), 0.08)],
             "head": [{"name": "head", "sphere": {"center": [0.01, 0.0, 0.05], "radius": 0.065}}]}
    for s in "rl":
        links |= {f"{s}_hip_pitch_link": [cap(f"{s}_thigh", (0, 0, -0.03), (0, 0, -0.17), 0.045)],
                  f"{s}_knee_link": [cap(f"{s}_shank", (0, 0, -0.03), (0, 0, -0.17), 0.04)],
                  f"{s}_ankle_roll_link": [cap(f"{s}_foot", (-0.04, 0, -0.022), (0.06, 0, -0.022), 0.016)],
                  f"{s}_shoulder_yaw_link": [cap(f"{s}_upper_arm", (0, 0, -0.03), (0, 0, -0.12), 0.03)],
                  f"{s}_elbow_link": [cap(f"{s}_forearm", (0, 0, -0.02), (0, 0, -0.12), 0.028)],
                  f"{s}_wrist_pitch_link": [cap(f"{s}_hand", (0, 0, 0), (0, 0, -0.04), 0.025)]}
    pairs = [[f"{s}_{a}", t] for s in "rl" for a in ("forearm", "hand") for t in ("chest", "waist", "head")]
    pairs += [[f"{s}_{a}", f"{x}_{t}"]
              for s in "rl" for a in ("forearm", "hand") for x in "rl" for t in ("thigh", "foot")]
    pairs += [["r_hand", "l_hand"], ["r_forearm", "l_forearm"], ["r_hand", "l_forearm"], ["l_hand", "r_forearm"]]
    pairs += [[f"r_{a}", f"l_{b}"] for a in ("thigh", "shank", "foot") for b in ("thigh", "shank", "foot")]
    return {"padding_m": 0.0, "links": links, "self_collision_pairs": pairs}


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    d = tmp_path_factory.mktemp("tiny")
    (d / "tiny.urdf").write_text(tiny_urdf())
    (d / "robot.yaml").write_text(yaml.safe_dump(tiny_description(), sort_keys=False))
    (d / "collision.yaml").write_text(yaml.safe_dump(tiny_collision(), sort_keys=False))
    return RobotModel(d / "robot.yaml")


def test_the_tiny_robot_loads_from_its_description_alone(tiny):
    assert tiny.name == "tiny" and "tiny" not in robots()
    assert tiny.n_joints == 28 and tiny.spec.package_dirs == ()
    cam = tiny.frame_pose(tiny.half_sitting(), tiny.camera_frame).rotation
    assert cam[:, 2] @ [1, 0, 0] > 0.99 and cam[:, 1] @ [0, 0, -1] > 0.99   # optical: z forward, y down
    q = tiny.half_sitting()
    r, l_ = (tiny.frame_pose(q, f) for f in tiny.sole_frames)
    np.testing.assert_allclose([r.translation, l_.translation], [[0, -0.06, 0], [0, 0.06, 0]], atol=1e-12)
    assert polygon_margin(support_polygon(tiny), tiny.com(q)[:2])[0] > 0.03
    cm = load_collision_model(None, tiny)
    P0, P1, rad = cm.world_shapes(tiny.forward(q))
    assert not cm.in_self_collision(P0, P1, rad)


def test_the_tiny_robots_limbs_are_solved_in_closed_form(tiny):
    ik = LimbIKSet(tiny)
    assert all(isinstance(ik[n], LimbIK) and ik[n].compiled for n in ("right_leg", "left_leg"))
    assert all(isinstance(ik[n], GeneralLimb) and ik[n].kind == "general" for n in ("right_arm", "left_arm"))
    rng = np.random.default_rng(2)
    for name in ik:
        limb = ik[name]
        q = rng.uniform(limb.lower, limb.upper, size=(500, 6))
        p, R = limb.fk(np.zeros(3), np.eye(3), q)
        res = ik.solve(name, np.zeros(3), np.eye(3), p, R, q_ref=q)
        assert res.ok.mean() > 0.97, (name, res.ok.mean())
        p2, R2 = limb.fk(np.zeros(3), np.eye(3), res.q[res.ok])
        assert np.abs(p2 - p[res.ok]).max() < 1e-8 and np.abs(R2 - R[res.ok]).max() < 1e-8, name


def test_the_planner_plans_a_reach_for_the_tiny_robot(tiny):
    from humanoid_reach_ros.planning.reach import PlanRequest, ReachPlanner
    from humanoid_reach_ros.planning.wgr import valve_region

    planner = ReachPlanner(tiny)
    planner.set_map(np.zeros((0, 3)))
    region = valve_region(target_p=(0.22, -0.12, 0.5))
    out = planner.plan(tiny.half_sitting_joints, PlanRequest(region, arm="right", seed=0, time_budget_s=10.0))
    assert out.success, out.message
    hand = tiny.frame_pose(out.waypoints[-1], tiny.hand_frames["right"])
    np.testing.assert_allclose(hand.translation, region.target_p, atol=1e-6)
    cm = planner.collision_model
    for q in out.waypoints:
        P0, P1, rad = cm.world_shapes(tiny.forward(q))
        assert not cm.in_self_collision(P0, P1, rad)
        for s in tiny.sole_frames:   # the feet stay where they stand
            np.testing.assert_allclose(tiny.frame_pose(q, s).translation[2], 0.0, atol=1e-6)
