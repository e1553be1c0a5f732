"""The robot model: pinocchio model from the URDF plus the robot description (robot/spec.py).

Conventions used throughout the package:

* ``q`` is pinocchio's configuration of the floating-base model: base position (3),
  base quaternion (x, y, z, w) and the ``n_joints`` joint angles in URDF/pinocchio order
  (``RobotModel.joint_names``; HRP-2: 30, ``model.nq == 37``, ``model.nv == 36``).
* ``joints`` is the vector of joint angles alone (``q[7:]``).
* The description's added ``frames`` (robot/spec.py) are fixed frames of the model like
  the URDF's own (pinocchio OP_FRAMEs).
* The world frame is the stance frame: origin on the floor midway between the
  soles of the half-sitting stance, x forward, z up.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import pinocchio as pin

from humanoid_reach_ros.robot.spec import DEFAULT_ROBOT, check_against_model, load_robot_spec

N_BASE_Q = 7
N_BASE_V = 6


@dataclass(frozen=True)
class LimbSpec:
    """A limb (6 joints; 7 for an arm): joints from ``root`` link to ``tip`` frame."""

    name: str
    root: str
    tip: str
    joints: tuple[str, ...]
    joint_index: tuple[int, ...]  # indices into the vector of joint angles


def _add_frames(model: pin.Model, spec) -> None:
    """The description's ``frames`` as fixed frames of ``model`` (parents the URDF lacks are
    left to :func:`~humanoid_reach_ros.robot.spec.check_against_model` to report)."""
    for name, d in spec.frames.items():
        if model.existFrame(name):
            raise ValueError(f"robot description {spec.path}: frames.{name} is already a frame of "
                             f"{spec.urdf_path.name}")
        if not model.existFrame(d.parent):
            continue
        pf = model.getFrameId(d.parent)
        parent = model.frames[pf]
        local = pin.SE3(pin.rpy.rpyToMatrix(*d.rpy), np.array(d.xyz, float))
        model.addFrame(pin.Frame(name, parent.parentJoint, pf, parent.placement * local, pin.FrameType.OP_FRAME))


def urdf_with_frames(model: pin.Model, urdf_xml: str, names) -> str:
    """``urdf_xml`` with the added frames ``names`` of ``model`` as links on fixed joints (what
    ``/robot_description`` carries, so robot_state_publisher puts them in TF and RViz shows
    them): each hangs off the URDF link moving with its parent joint, at its placement there."""
    import xml.etree.ElementTree as ET

    names = [n for n in names if model.existFrame(n)]
    if not names:
        return urdf_xml
    root = ET.fromstring(urdf_xml)
    links = {e.get("name") for e in root.findall("link")}
    for name in names:
        f = model.frames[model.getFrameId(name)]
        body = next((b for b in model.frames if b.type == pin.FrameType.BODY and b.parentJoint == f.parentJoint
                     and b.name in links and b.placement.isIdentity(1e-12)), None)
        if body is None:
            continue       # no URDF link at the parent joint (cannot happen for a URDF-built model)
        xyz = f.placement.translation
        rpy = pin.rpy.matrixToRpy(f.placement.rotation)
        ET.SubElement(root, "link", name=name)
        joint = ET.SubElement(root, "joint", name=f"{name}_joint", type="fixed")
        ET.SubElement(joint, "parent", link=body.name)
        ET.SubElement(joint, "child", link=name)
        ET.SubElement(joint, "origin", xyz=" ".join(f"{v:.9g}" for v in xyz), rpy=" ".join(f"{v:.9g}" for v in rpy))
    return ET.tostring(root, encoding="unicode")


class RobotModel:
    """Pinocchio model of the robot with the groups and postures the planner needs."""

    def __init__(self, robot: str | Path = DEFAULT_ROBOT) -> None:
        """``robot``: a robot name (``config/robots/<name>/robot.yaml``) or the path of a
        robot description (absolute, or relative to ``config/``)."""
        self.spec, self.semantic = load_robot_spec(robot)
        self.semantic_path = self.spec.path
        self.urdf_path = self.spec.urdf_path
        self.collision_path = self.spec.collision_path
        self.urdf_xml = self.urdf_path.read_text()
        self.model: pin.Model = pin.buildModelFromXML(self.urdf_xml, pin.JointModelFreeFlyer())
        _add_frames(self.model, self.spec)
        self.data: pin.Data = self.model.createData()
        # joint 0 is "universe", joint 1 the free flyer
        self.joint_names: tuple[str, ...] = tuple(self.model.names[2:])
        self.n_joints = len(self.joint_names)
        self.joint_index = {n: i for i, n in enumerate(self.joint_names)}
        check_against_model(self.spec, self.joint_names, self.model.existFrame)
        self.lower = np.array(self.model.lowerPositionLimit[N_BASE_Q:])
        self.upper = np.array(self.model.upperPositionLimit[N_BASE_Q:])
        self.velocity_limit = np.array(self.model.velocityLimit[N_BASE_V:])
        self.mass = float(pin.computeTotalMass(self.model))
        self.limbs: dict[str, LimbSpec] = {
            name: LimbSpec(name, d.root, d.tip, d.joints, tuple(self.joint_index[j] for j in d.joints))
            for name, d in self.spec.limbs.items()}
        self.name = self.spec.name
        self.base_link = self.spec.base_link
        #: arm name -> hand frame; (right, left) sole frames; the head camera's optical frame
        self.hand_frames = self.spec.hand_frames
        self.sole_frames = self.spec.sole_frames
        self.camera_frame = self.spec.camera_frame

    # ------------------------------------------------------------ conversions
    def frame_id(self, name: str) -> int:
        if not self.model.existFrame(name):
            raise KeyError(f"unknown frame {name!r}")
        return self.model.getFrameId(name)

    def joints_from_dict(self, values: Mapping[str, float], default: np.ndarray | None = None) -> np.ndarray:
        """Joint vector from a {joint name: angle [rad]} mapping; missing joints from ``default``."""
        out = np.zeros(self.n_joints) if default is None else np.array(default, dtype=float)
        for name, v in values.items():
            if name not in self.joint_index:
                raise KeyError(f"unknown joint {name!r}")
            out[self.joint_index[name]] = v
        return out

    def config(self, joints: Sequence[float], base: pin.SE3 | None = None) -> np.ndarray:
        """Full configuration q from the joint angles and a base (waist) pose."""
        base = pin.SE3.Identity() if base is None else base
        q = np.empty(self.model.nq)
        q[:N_BASE_Q] = pin.SE3ToXYZQUAT(base)
        q[N_BASE_Q:] = joints
        return q

    @staticmethod
    def base_pose(q: np.ndarray) -> pin.SE3:
        return pin.XYZQUATToSE3(q[:N_BASE_Q])

    # ------------------------------------------------------------ kinematics
    def forward(self, q: np.ndarray) -> pin.Data:
        """Forward kinematics of every frame (and nothing else) into ``self.data``."""
        pin.framesForwardKinematics(self.model, self.data, q)
        return self.data

    def frame_pose(self, q: np.ndarray, frame: str) -> pin.SE3:
        self.forward(q)
        return self.data.oMf[self.frame_id(frame)].copy()

    def com(self, q: np.ndarray) -> np.ndarray:
        """Exact centre of mass of the distributed link masses [m, world]."""
        return pin.centerOfMass(self.model, self.data, q).copy()

    def in_limits(self, joints: np.ndarray, tol: float = 0.0) -> bool:
        return bool(np.all(joints >= self.lower - tol) and np.all(joints <= self.upper + tol))

    # ------------------------------------------------------------ postures
    @cached_property
    def description_xml(self) -> str:
        """The URDF with the description's added frames as fixed links (published as
        ``/robot_description``); built on first use (only the joint driver asks)."""
        return urdf_with_frames(self.model, self.urdf_xml, self.spec.frames)

    @cached_property
    def half_sitting_joints(self) -> np.ndarray:
        deg = {k: np.radians(v) for k, v in self.spec.half_sitting_deg.items()}
        return self.joints_from_dict(deg)

    def base_on_feet(self, joints: np.ndarray) -> pin.SE3:
        """Waist pose that puts the right sole flat on the floor at its stance pose.

        The stance frame has its origin midway between the soles of the half-sitting
        posture; for other leg angles the right foot stays where half-sitting puts it.
        """
        right = self._stance_soles[0]
        q0 = self.config(joints)
        sole_in_base = self.frame_pose(q0, self.sole_frames[0])
        return right * sole_in_base.inverse()

    @cached_property
    def _stance_soles(self) -> tuple[pin.SE3, pin.SE3]:
        q0 = self.config(self.half_sitting_joints)
        r = self.frame_pose(q0, self.sole_frames[0])
        l_ = self.frame_pose(q0, self.sole_frames[1])
        mid = 0.5 * (r.translation + l_.translation)
        shift = pin.SE3(np.eye(3), -mid)
        return shift * r, shift * l_

    @property
    def stance_soles(self) -> tuple[pin.SE3, pin.SE3]:
        """World poses of the right and left sole in the half-sitting stance."""
        return tuple(s.copy() for s in self._stance_soles)  # type: ignore[return-value]

    def half_sitting(self) -> np.ndarray:
        """Full configuration of the half-sitting posture standing in the stance frame."""
        joints = self.half_sitting_joints
        return self.config(joints, self.base_on_feet(joints))
