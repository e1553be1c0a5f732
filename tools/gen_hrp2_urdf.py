#!/usr/bin/env python3
"""Generate ``config/robots/hrp2/hrp2.urdf``: an HRP-2-class humanoid with 30 DOF.

Run ``python tools/gen_hrp2_urdf.py`` after editing the tables below; the URDF is
committed, this script is how it is made and why its numbers are what they are.

Published figures followed (Kaneko et al., "Humanoid Robot HRP-2", ICRA 2004, and
the Kanehiro / Yoshida papers, listed in docs/paper_map.md):

* 30 DOF: legs 6+6 (hip yaw, roll, pitch; knee; ankle pitch, roll), chest 2
  (yaw, pitch), neck 2 (yaw, pitch), arms 6+6 (shoulder pitch, roll, yaw; elbow;
  wrist yaw, pitch) and one gripper joint per hand. Joint names follow the
  OpenHRP HRP-2 model (RLEG_JOINT0..5, CHEST_JOINT0..1, HEAD_JOINT0..1,
  RARM_JOINT0..6, ...).
* Height 1.54 m standing straight (sole to top of head), mass 58 kg.
* Support polygon of both feet side by side: 23 x 34 cm (foot 23 x 14 cm, feet
  centred 20 cm apart).

Approximations (this is an HRP-2-*class* model, not the manufacturer's data):

* All three hip axes intersect, both ankle axes intersect, all three shoulder
  axes intersect and both wrist axes intersect; the thigh, shank, upper arm and
  forearm carry no lateral offsets. The real HRP-2 has small offsets (and a
  cantilevered hip); dropping them is what makes the closed-form 6-DOF limb IK
  of humanoid_reach_ros.kinematics.hand_derived exact for this model.
* Link lengths (thigh 0.30 m, shank 0.30 m, ankle height 0.105 m, upper arm
  0.25 m, forearm 0.25 m) are the published HRP-2 figures rounded; the hand
  end-effector point is 0.17 m past the wrist centre (middle of the grasp).
* Link masses are distributed to sum to 58 kg in HRP-2's proportions (heavy
  waist and chest with the backpack computer); inertias are those of uniform
  boxes / cylinders of the link's size, not measured values.
* Joint limits are HRP-2 catalogue values rounded to the degree.

Frames follow REP 103: x forward, y left, z up. At q = 0 the robot stands
straight with arms hanging down; every link frame is then parallel to the
waist frame. Extra fixed frames: r_sole/l_sole (sole centre, on the floor),
r_hand_ee/l_hand_ee (grasp point, frame parallel to the wrist-pitch link),
head_camera_link and head_camera_optical_frame (REP 103 optical: z forward).
"""
from __future__ import annotations

import math
from pathlib import Path

D = math.radians

# ---------------------------------------------------------------- dimensions
HIP_Y = 0.10          # hip centre lateral offset from the waist origin [m]
HIP_Z = -0.09         # hip centre height below the waist origin [m]
THIGH = 0.30          # hip centre -> knee axis [m]
SHANK = 0.30          # knee axis -> ankle centre [m]
ANKLE_H = 0.105       # ankle centre -> sole [m]
FOOT_LX, FOOT_LY = 0.23, 0.14
CHEST_X, CHEST_Z = 0.032, 0.35    # waist -> chest yaw/pitch centre [m]
SHOULDER = (0.008, 0.25, 0.18)    # chest -> shoulder centre (y mirrored) [m]
UPPER_ARM = 0.25      # shoulder centre -> elbow axis [m]
FOREARM = 0.25        # elbow axis -> wrist centre [m]
HAND = 0.17           # wrist centre -> grasp point [m]
NECK_Z = 0.26         # chest -> neck centre [m]
CAMERA = (0.09, 0.0, 0.10)         # neck-pitch link -> camera [m]

# ------------------------------------------------- joint limits [deg], effort
# (lower, upper, velocity [rad/s], effort [N m]) for the right side; the left
# side mirrors roll and yaw limits.
LEG = [
    ("yaw", "0 0 1", (-45, 30), 3.0, 150),
    ("roll", "1 0 0", (-35, 20), 3.0, 300),
    ("pitch", "0 1 0", (-125, 42), 3.0, 300),
    ("knee", "0 1 0", (0, 150), 4.0, 300),
    ("ankle_pitch", "0 1 0", (-75, 42), 3.0, 300),
    ("ankle_roll", "1 0 0", (-20, 35), 3.0, 200),
]
ARM = [
    ("shoulder_pitch", "0 1 0", (-180, 60), 3.5, 100),
    ("shoulder_roll", "1 0 0", (-95, 10), 3.5, 100),
    ("shoulder_yaw", "0 0 1", (-92, 92), 4.0, 60),
    ("elbow", "0 1 0", (-130, 4), 4.0, 60),
    ("wrist_yaw", "0 0 1", (-92, 92), 4.0, 30),
    ("wrist_pitch", "0 1 0", (-92, 92), 4.0, 30),
]
GRIPPER = ((-30, 30), 2.0, 10)
CHEST = [("yaw", "0 0 1", (-45, 45), 3.0, 300), ("pitch", "0 1 0", (-5, 60), 3.0, 300)]
HEAD = [("yaw", "0 0 1", (-45, 45), 4.0, 20), ("pitch", "0 1 0", (-30, 45), 4.0, 20)]

# ------------------------------------------ masses [kg] and centres of mass
# (mass, com in link frame, box size for the inertia (x, y, z))
M_WAIST = (10.0, (-0.01, 0.0, 0.0), (0.20, 0.26, 0.20))
M_CHEST0 = (1.0, (0.0, 0.0, 0.0), (0.10, 0.10, 0.08))
M_CHEST1 = (13.4, (-0.04, 0.0, 0.15), (0.30, 0.32, 0.30))
M_HEAD0 = (0.4, (0.0, 0.0, 0.0), (0.06, 0.06, 0.06))
M_HEAD1 = (1.6, (0.02, 0.0, 0.08), (0.20, 0.16, 0.20))
M_LEG = [
    (1.0, (0.0, 0.0, 0.0), (0.10, 0.08, 0.08)),
    (1.5, (0.0, 0.0, 0.0), (0.12, 0.10, 0.10)),
    (3.6, (0.0, 0.0, -0.15), (0.12, 0.12, THIGH)),
    (2.4, (0.0, 0.0, -0.14), (0.11, 0.11, SHANK)),
    (0.6, (0.0, 0.0, 0.0), (0.08, 0.08, 0.06)),
    (1.3, (0.01, 0.0, -0.07), (FOOT_LX, FOOT_LY, 0.07)),
]
M_ARM = [
    (0.8, (0.0, 0.0, 0.0), (0.10, 0.10, 0.10)),
    (0.8, (0.0, 0.0, 0.0), (0.08, 0.08, 0.08)),
    (1.6, (0.0, 0.0, -0.12), (0.09, 0.09, UPPER_ARM)),
    (1.0, (0.0, 0.0, -0.12), (0.08, 0.08, FOREARM)),
    (0.5, (0.0, 0.0, 0.0), (0.06, 0.06, 0.06)),
    (0.6, (0.0, 0.0, -0.06), (0.06, 0.08, 0.12)),
]
M_FINGER = (0.1, (0.0, 0.0, -0.05), (0.02, 0.02, 0.10))


def fmt(v) -> str:
    return " ".join(f"{x:.6g}" for x in v)


def box_inertia(m: float, size) -> tuple[float, float, float]:
    x, y, z = size
    return (m * (y * y + z * z) / 12.0, m * (x * x + z * z) / 12.0, m * (x * x + y * y) / 12.0)


class Urdf:
    def __init__(self) -> None:
        self.out: list[str] = []

    def link(self, name: str, mass=None, visual=None) -> None:
        self.out.append(f'  <link name="{name}">')
        if mass is not None:
            m, com, size = mass
            ixx, iyy, izz = box_inertia(m, size)
            self.out.append(
                f'    <inertial><origin xyz="{fmt(com)}" rpy="0 0 0"/><mass value="{m:.6g}"/>'
                f'<inertia ixx="{ixx:.6g}" ixy="0" ixz="0" iyy="{iyy:.6g}" iyz="0" izz="{izz:.6g}"/></inertial>'
            )
            if visual is None:
                visual = ("box", com, size)
        if visual is not None:
            kind, centre, size = visual
            geom = f'<box size="{fmt(size)}"/>'
            self.out.append(
                f'    <visual><origin xyz="{fmt(centre)}" rpy="0 0 0"/><geometry>{geom}</geometry>'
                f'<material name="grey"/></visual>'
            )
        self.out.append("  </link>")

    def joint(self, name, parent, child, xyz, axis=None, limit=None, rpy=(0, 0, 0)) -> None:
        kind = "revolute" if axis else "fixed"
        self.out.append(f'  <joint name="{name}" type="{kind}">')
        self.out.append(f'    <parent link="{parent}"/><child link="{child}"/>')
        self.out.append(f'    <origin xyz="{fmt(xyz)}" rpy="{fmt(rpy)}"/>')
        if axis:
            lo, hi, vel, eff = limit
            self.out.append(f'    <axis xyz="{axis}"/>')
            self.out.append(
                f'    <limit lower="{D(lo)!r}" upper="{D(hi)!r}" velocity="{vel:.6g}" effort="{eff:.6g}"/>'
            )
        self.out.append("  </joint>")


def mirror(limits, axis: str, left: bool):
    lo, hi = limits
    if left and axis in ("1 0 0", "0 0 1"):
        return (-hi, -lo)
    return (lo, hi)


def build() -> str:
    u = Urdf()
    u.out.append('<?xml version="1.0"?>')
    u.out.append("<!-- Generated by tools/gen_hrp2_urdf.py: edit that script, not this file. -->")
    u.out.append("<!-- HRP-2-class humanoid, 30 DOF; see the generator's docstring for the figures it follows"
                 " and where it is approximate. -->")
    u.out.append('<robot name="hrp2">')
    u.out.append('  <material name="grey"><color rgba="0.7 0.7 0.75 1"/></material>')
    u.link("base_link", M_WAIST)

    for side, s, prefix in (("r", -1.0, "RLEG"), ("l", 1.0, "LLEG")):
        parent = "base_link"
        offsets = [(0, s * HIP_Y, HIP_Z), (0, 0, 0), (0, 0, 0), (0, 0, -THIGH), (0, 0, -SHANK), (0, 0, 0)]
        for i, ((_, axis, lim, vel, eff), off, mass) in enumerate(zip(LEG, offsets, M_LEG)):
            child = f"{prefix}_LINK{i}"
            lo, hi = mirror(lim, axis, s > 0)
            u.link(child, mass)
            u.joint(f"{prefix}_JOINT{i}", parent, child, off, axis, (lo, hi, vel, eff))
            parent = child
        u.link(f"{side}_sole")
        u.joint(f"{prefix}_SOLE", parent, f"{side}_sole", (0, 0, -ANKLE_H))

    u.link("CHEST_LINK0", M_CHEST0)
    u.joint("CHEST_JOINT0", "base_link", "CHEST_LINK0", (CHEST_X, 0, CHEST_Z), CHEST[0][1],
            (*CHEST[0][2], CHEST[0][3], CHEST[0][4]))
    u.link("CHEST_LINK1", M_CHEST1)
    u.joint("CHEST_JOINT1", "CHEST_LINK0", "CHEST_LINK1", (0, 0, 0), CHEST[1][1],
            (*CHEST[1][2], CHEST[1][3], CHEST[1][4]))
    u.link("HEAD_LINK0", M_HEAD0)
    u.joint("HEAD_JOINT0", "CHEST_LINK1", "HEAD_LINK0", (0, 0, NECK_Z), HEAD[0][1],
            (*HEAD[0][2], HEAD[0][3], HEAD[0][4]))
    u.link("HEAD_LINK1", M_HEAD1)
    u.joint("HEAD_JOINT1", "HEAD_LINK0", "HEAD_LINK1", (0, 0, 0), HEAD[1][1],
            (*HEAD[1][2], HEAD[1][3], HEAD[1][4]))
    u.link("head_camera_link")
    u.joint("HEAD_CAMERA", "HEAD_LINK1", "head_camera_link", CAMERA)
    u.link("head_camera_optical_frame")
    u.joint("HEAD_CAMERA_OPTICAL", "head_camera_link", "head_camera_optical_frame", (0, 0, 0),
            rpy=(-math.pi / 2, 0, -math.pi / 2))

    for side, s, prefix in (("r", -1.0, "RARM"), ("l", 1.0, "LARM")):
        parent = "CHEST_LINK1"
        offsets = [(SHOULDER[0], s * SHOULDER[1], SHOULDER[2]), (0, 0, 0), (0, 0, 0),
                   (0, 0, -UPPER_ARM), (0, 0, -FOREARM), (0, 0, 0)]
        for i, ((_, axis, lim, vel, eff), off, mass) in enumerate(zip(ARM, offsets, M_ARM)):
            child = f"{prefix}_LINK{i}"
            lo, hi = mirror(lim, axis, s > 0)
            u.link(child, mass)
            u.joint(f"{prefix}_JOINT{i}", parent, child, off, axis, (lo, hi, vel, eff))
            parent = child
        u.link(f"{prefix}_LINK6", M_FINGER)
        (glo, ghi), gvel, geff = GRIPPER
        u.joint(f"{prefix}_JOINT6", parent, f"{prefix}_LINK6", (0, s * 0.03, -0.06), "0 1 0",
                (glo, ghi, gvel, geff))
        u.link(f"{side}_hand_ee")
        u.joint(f"{prefix}_EE", parent, f"{side}_hand_ee", (0, 0, -HAND))

    u.out.append("</robot>")
    return "\n".join(u.out) + "\n"


def main() -> None:
    root = Path(__file__).resolve().parents[1]
    path = root / "config" / "robots" / "hrp2" / "hrp2.urdf"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(build())
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
