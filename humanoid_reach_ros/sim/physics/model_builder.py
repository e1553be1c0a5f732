"""The MuJoCo model of a robot standing in a scene, built from the robot's own files.

Inputs: the robot description (:class:`~humanoid_reach_ros.robot.model.RobotModel`: URDF,
collision capsules, sole frames and rectangle, hand frames), its ``physics.yaml``
(:mod:`.config`) and a scene (:mod:`humanoid_reach_ros.sim.scene`, the file ``scene_sim``
renders). Nothing here knows a robot by name.

* **Kinematics, inertias, effort limits**: the URDF through ``mujoco.MjSpec.from_string``
  (links and joints, joint ranges, ``effort`` as the joint's actuator force range). Its
  ``<visual>`` and ``<collision>`` elements are removed first: a package's meshes are DAE as
  often as STL, and the project's capsules are the contact model, so no mesh path has to
  resolve. Every ``<inertial>`` is checked (:func:`check_inertias`): a moving link whose rigid
  cluster has no mass, a mass <= 0, an inertia not positive definite or breaking the triangle
  inequality is a ``ValueError`` naming the link (MuJoCo would otherwise refuse it with a
  compiler message, or ``balanceinertia`` would silently change it).
* **Floating base**: a free joint on the URDF's root body, which must be the description's
  ``base_link``.
* **Contact geometry**: the capsules and spheres of ``collision.yaml``, each on the body
  moved by the joint its link hangs from (placed with pinocchio's frame placement), and one
  box per sole: the description's ``sole_rectangle_m`` about the sole frame, ``sole_thickness_m``
  thick, its bottom face on the sole plane. The robot's own shapes do not touch each other
  (no self-collision: the planner keeps them apart), and the feet touch the floor through the
  sole boxes only (the foot capsules round the plate's edges off; on the floor they would make
  the sole rock); foot capsules do touch obstacles.
* **Hand tool points**: a sphere of ``hand_sphere_radius_m`` about each hand frame (the arm limb's
  tip), where the hand touches what it reaches (the capsules of collision.yaml end short of it).
* **Servos**: one position actuator per joint, ``kp`` and damping per joint group from
  ``physics.yaml``, its force limited to the URDF's effort, its target to the joint's range.
* **World**: the scene's planes, boxes, cylinders and spheres as static geoms; a torus as a
  ring of ``torus_segments`` capsules. One friction coefficient for every contact.
* **Options**: ``implicitfast`` integration (the servos' damping implicit, so stiff gains
  hold at a 1 ms step), the timestep of ``physics.yaml``.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

import mujoco
import numpy as np
import pinocchio as pin

from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.shapes import load_collision_model
from humanoid_reach_ros.sim.physics.config import PhysicsConfig
from humanoid_reach_ros.sim.scene import Box, Cylinder, Plane, Scene, Sphere, Torus

#: contact bits (contype / conaffinity): two geoms touch when either's contype meets the other's
#: conaffinity. Robot shapes (ROBOT) touch the floor and obstacles; foot capsules (FOOT) obstacles only;
#: robot shapes never touch each other (neither bit in a robot geom's conaffinity).
ROBOT, FLOOR, OBSTACLE, FOOT = 1, 2, 4, 8
#: relative tolerance of the inertia checks (URDF inertias are printed with a few digits)
_INERTIA_RTOL = 1e-6


@dataclass
class PhysicsModel:
    """A compiled MuJoCo model and the maps between it and the robot model's conventions.

    Arrays over joints are in :attr:`RobotModel.joint_names` order (pinocchio's), which may
    differ from MuJoCo's.
    """

    model: mujoco.MjModel
    robot: RobotModel
    config: PhysicsConfig
    qpos_adr: np.ndarray            # (n_joints,) MuJoCo qpos index of each joint
    dof_adr: np.ndarray             # (n_joints,) MuJoCo qvel index of each joint
    actuator_ids: np.ndarray        # (n_joints,) actuator of each joint
    root_body: int
    sole_bodies: tuple[int, int]    # right, left foot body
    sole_in_body: tuple[np.ndarray, np.ndarray]   # 4x4 placement of each sole frame in its body
    sole_geoms: tuple[int, int]     # the sole boxes
    foot_body_sets: tuple[frozenset, frozenset]   # bodies of each foot (the foot body and its subtree)
    hand_body_sets: dict[str, frozenset]          # "right"/"left" -> hand bodies (the hand's body and subtree)
    world_geoms: frozenset          # static geoms of the scene
    floor_geoms: frozenset
    joint_groups: dict[str, str] = field(default_factory=dict)   # joint -> gain group

    @property
    def timestep_s(self) -> float:
        return float(self.model.opt.timestep)


# ------------------------------------------------------------------ the URDF
def strip_geometry(urdf_xml: str) -> ET.Element:
    """The URDF's XML tree without ``<visual>``, ``<collision>`` and ``<mujoco>`` elements."""
    root = ET.fromstring(urdf_xml)
    for link in root.iter("link"):
        for tag in ("visual", "collision"):
            for e in link.findall(tag):
                link.remove(e)
    for e in root.findall("mujoco"):
        root.remove(e)
    return root


def _floats(text: str | None, n: int, where: str) -> list[float]:
    try:
        vals = [float(v) for v in (text or "").split()]
    except ValueError:
        vals = []
    if len(vals) != n or not all(math.isfinite(v) for v in vals):
        raise ValueError(f"{where}: expected {n} finite numbers, got {text!r}")
    return vals


def check_inertias(root: ET.Element, where: str) -> None:
    """ValueError naming each link whose inertia MuJoCo cannot simulate (module doc).

    A link is *moving* when the joint above it is not ``fixed`` (or it is the root, on the free
    joint). A moving link needs an ``<inertial>`` with a mass > 0 and an inertia tensor whose
    principal moments are > 0 and satisfy ``I_a + I_b >= I_c``. A link welded to its parent by a
    fixed joint may be massless (a frame: no ``<inertial>``, or mass 0 and a zero tensor) or a point
    mass; a mass present must be finite and >= 0, a tensor positive semi-definite.
    """
    moving_joint = {}
    for j in root.iter("joint"):
        c = j.find("child")
        if c is not None:
            moving_joint[c.get("link")] = j.get("type", "") != "fixed"
    bad: list[str] = []
    for link in root.iter("link"):
        name = link.get("name")
        moving = moving_joint.get(name, True)
        inertial = link.find("inertial")
        m_el = inertial.find("mass") if inertial is not None else None
        i_el = inertial.find("inertia") if inertial is not None else None
        if m_el is None:
            if moving:
                bad.append(f"{name}: a moving link without <inertial> mass")
            continue
        try:
            m = float(m_el.get("value"))
        except (TypeError, ValueError):
            m = math.nan
        if not math.isfinite(m) or m < 0.0 or (moving and m <= 0.0):
            bad.append(f"{name}: mass {m_el.get('value')!r} (must be {'> 0' if moving else '>= 0'})")
            continue
        keys = ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")
        try:
            ixx, iyy, izz, ixy, ixz, iyz = (float(i_el.get(k, "0")) for k in keys) if i_el is not None \
                else (math.nan,) * 6
        except (TypeError, ValueError):
            ixx = iyy = izz = ixy = ixz = iyz = math.nan
        tensor = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
        if not np.all(np.isfinite(tensor)):
            if moving or m > 0.0:
                bad.append(f"{name}: inertia missing or not finite")
            continue
        ev = np.linalg.eigvalsh(tensor)
        tol = _INERTIA_RTOL * max(float(np.abs(ev).max()), 1e-12)
        if moving and ev.min() <= 0.0:
            bad.append(f"{name}: inertia not positive definite (principal moments {np.round(ev, 9).tolist()})")
        elif ev.min() < -tol:
            bad.append(f"{name}: inertia not positive semi-definite (principal moments {np.round(ev, 9).tolist()})")
        elif ev[0] + ev[1] < ev[2] - tol:
            bad.append(f"{name}: inertia breaks the triangle inequality (principal moments {np.round(ev, 9).tolist()})")
    if bad:
        raise ValueError(f"{where}: inertias MuJoCo cannot simulate: " + "; ".join(bad))


# ------------------------------------------------------------------ joint groups
def joint_groups(robot: RobotModel) -> dict[str, str]:
    """Each joint's gain group (config.JOINT_GROUPS) from the description's roles."""
    spec = robot.spec
    out: dict[str, str] = {}
    for limb_name, limb in spec.limbs.items():
        if limb_name.endswith("leg"):
            for i, j in enumerate(limb.joints):
                out[j] = "ankles" if i >= len(limb.joints) - 2 else "legs"
        else:
            out.update({j: "arms" for j in limb.joints})
    out.update({j: "torso" for j in spec.torso_joints})
    out.update({j: "neck" for j in spec.neck_joints})
    out.update({j: "grippers" for j in spec.gripper_joints})
    return {j: out.get(j, "other") for j in robot.joint_names}


# ------------------------------------------------------------------ geometry helpers
def _quat_from_matrix(R: np.ndarray) -> np.ndarray:
    q = np.empty(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(R, dtype=float).reshape(9))
    return q


def _frame_z_to(axis: np.ndarray) -> np.ndarray:
    """A rotation whose z axis is the unit vector ``axis``."""
    z = np.asarray(axis, float) / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def torus_ring(center, axis, major_radius: float, segments: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """The ``segments`` chords (p0, p1) of a torus's centre circle: capsules of the tube's
    radius along them approximate the torus (a 24-gon's chords sag 1.0 % of R inwards)."""
    R = _frame_z_to(np.asarray(axis, float))
    c = np.asarray(center, float)
    th = np.linspace(0.0, 2.0 * math.pi, segments + 1)
    pts = c + major_radius * (np.cos(th)[:, None] * R[:, 0] + np.sin(th)[:, None] * R[:, 1])
    return [(pts[i], pts[i + 1]) for i in range(segments)]


def _add_scene(spec: mujoco.MjSpec, scene: Scene, cfg: PhysicsConfig) -> tuple[list[str], list[str]]:
    """The scene's primitives as static geoms of the world body; returns (all names, floor names)."""
    wb = spec.worldbody
    friction = [cfg.friction, 0.005, 0.0001]
    names, floors = [], []

    def geom(name: str, prim, **kw):
        contype = FLOOR if prim.floor else OBSTACLE
        conaff = ROBOT if prim.floor else ROBOT | FOOT
        g = wb.add_geom(name=name, contype=contype, conaffinity=conaff, friction=friction, condim=3,
                        rgba=[*prim.color, 1.0], **kw)
        names.append(name)
        if prim.floor:
            floors.append(name)
        return g

    for prim in scene.primitives:
        if isinstance(prim, Plane):
            n = np.asarray(prim.normal, float)
            geom(prim.name, prim, type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0.0, 0.0, 1.0],
                 pos=n * prim.offset, quat=_quat_from_matrix(_frame_z_to(n)))
        elif isinstance(prim, Box):
            geom(prim.name, prim, type=mujoco.mjtGeom.mjGEOM_BOX, size=0.5 * np.asarray(prim.size, float),
                 pos=np.asarray(prim.center, float), quat=_quat_from_matrix(prim.rotation))
        elif isinstance(prim, Cylinder):
            geom(prim.name, prim, type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[prim.radius, 0.0, 0.0],
                 fromto=[*prim.p0, *prim.p1])
        elif isinstance(prim, Sphere):
            geom(prim.name, prim, type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[prim.radius, 0.0, 0.0],
                 pos=np.asarray(prim.center, float))
        elif isinstance(prim, Torus):
            for k, (a, b) in enumerate(torus_ring(prim.center, prim.axis, prim.major_radius, cfg.torus_segments)):
                geom(f"{prim.name}#{k}", prim, type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                     size=[prim.minor_radius, 0.0, 0.0], fromto=[*a, *b])
        else:   # pragma: no cover - load_scene knows no other kind
            raise ValueError(f"scene {scene.name!r}: primitive {prim.name!r} of kind {prim.kind!r} has no MuJoCo geom")
    return names, floors


# ------------------------------------------------------------------ the model
def _body_of_frame(robot: RobotModel, frame: str) -> tuple[str, np.ndarray]:
    """(MuJoCo body name, 4x4 placement of ``frame`` in it): the body moved by the frame's parent joint."""
    f = robot.model.frames[robot.frame_id(frame)]
    joint = f.parentJoint
    body = robot.base_link if joint <= 1 else robot.model.names[joint]
    return body, f.placement.homogeneous


def build_physics_model(robot: RobotModel, cfg: PhysicsConfig, scene: Scene) -> PhysicsModel:
    """The MuJoCo model of ``robot`` in ``scene`` with the settings ``cfg`` (module doc);
    ValueError for a description MuJoCo cannot simulate (inertias, a root that is not the base link,
    a joint without a gain)."""
    where = str(robot.urdf_path)
    root = strip_geometry(robot.urdf_xml)
    check_inertias(root, where)
    spec = mujoco.MjSpec.from_string(ET.tostring(root, encoding="unicode"))
    spec.compiler.discardvisual = True
    spec.compiler.fusestatic = False     # every URDF link stays a body (frames hang off them by name)
    spec.option.timestep = cfg.timestep_s
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    # elliptic friction cones with impratio > 1: friction harder than the normal contact's softness,
    # so a sole under a steady sideways load does not creep (MuJoCo's recommendation against slip)
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.option.impratio = cfg.impratio
    base = spec.worldbody.first_body()
    if base.name != robot.base_link:
        raise ValueError(f"{where}: the URDF's root link is {base.name!r}, the description's base_link "
                         f"{robot.base_link!r}: the free joint goes on the base link, which must be the root")
    base.add_freejoint(name="floating_base")
    # a joint body by its name: the body moved by URDF joint j is the joint's child link
    joint_body = {j.name: j.parent.name for j in spec.joints}
    body_by_name = {b.name: b for b in spec.bodies}

    def body_named(name: str):
        return body_by_name[joint_body.get(name, name)] if name != robot.base_link else base

    friction = [cfg.friction, 0.005, 0.0001]
    # contact geometry: the collision model's shapes
    soles = robot.sole_frames
    foot_bodies = {_body_of_frame(robot, s)[0] for s in soles}
    collision = load_collision_model(robot.collision_path, robot)
    for shape in collision.shapes:
        body_name, T = _body_of_frame(robot, shape.link)
        p0 = T[:3, :3] @ np.asarray(shape.p0) + T[:3, 3]
        p1 = T[:3, :3] @ np.asarray(shape.p1) + T[:3, 3]
        on_foot = body_name in foot_bodies
        kw = dict(name=shape.name, contype=FOOT if on_foot else ROBOT,
                  conaffinity=OBSTACLE if on_foot else FLOOR | OBSTACLE, friction=friction, condim=3,
                  rgba=[0.7, 0.7, 0.75, 1.0])
        if shape.is_sphere:
            body_named(body_name).add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[shape.radius, 0, 0], pos=p0, **kw)
        else:
            body_named(body_name).add_geom(type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=[shape.radius, 0, 0],
                                           fromto=[*p0, *p1], **kw)
    # the hands' tool points: a sphere about each hand frame (collision.yaml's hand capsules end short of
    # it, so a hand whose frame rests on a surface would not touch it: no touch force to measure)
    if cfg.hand_sphere_radius_m > 0.0:
        for side, frame in robot.hand_frames.items():
            body_name, T = _body_of_frame(robot, frame)
            body_named(body_name).add_geom(
                name=f"{side}_hand_point", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[cfg.hand_sphere_radius_m, 0, 0],
                pos=T[:3, 3], contype=ROBOT, conaffinity=FLOOR | OBSTACLE, friction=friction, condim=3,
                rgba=[0.8, 0.6, 0.5, 1.0])
    # the sole boxes: the sole rectangle about each sole frame, bottom face on the sole plane
    x0, x1, y0, y1 = robot.spec.sole_rectangle
    half = np.array([0.5 * (x1 - x0), 0.5 * (y1 - y0), 0.5 * cfg.sole_thickness_m])
    sole_placements, sole_geom_names, sole_body_names = [], [], []
    for k, sole in enumerate(soles):
        body_name, T = _body_of_frame(robot, sole)
        centre_in_sole = np.array([0.5 * (x0 + x1), 0.5 * (y0 + y1), half[2]])
        name = f"sole_box_{k}"
        body_named(body_name).add_geom(
            name=name, type=mujoco.mjtGeom.mjGEOM_BOX, size=half, pos=T[:3, :3] @ centre_in_sole + T[:3, 3],
            quat=_quat_from_matrix(T[:3, :3]), contype=ROBOT, conaffinity=FLOOR | OBSTACLE, friction=friction,
            condim=3, rgba=[0.2, 0.2, 0.2, 1.0])
        sole_placements.append(T)
        sole_geom_names.append(name)
        sole_body_names.append(body_named(body_name).name)
    # servos
    groups = joint_groups(robot)
    for jname in cfg.joint_gains:
        if jname not in robot.joint_index:
            raise ValueError(f"{cfg.path}: joint_gains.{jname}: the robot has no joint {jname!r}")
    limits = {j.name: (j.range, j.actfrcrange) for j in spec.joints if j.name in robot.joint_index}
    for jname in robot.joint_names:
        gain = cfg.gain_of(jname, groups[jname])
        rng, frc = limits[jname]
        act = spec.add_actuator(name=f"servo_{jname}", target=jname, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        if gain.kv is not None:
            act.set_to_position(kp=gain.kp, kv=gain.kv)
        else:
            act.set_to_position(kp=gain.kp, dampratio=gain.dampratio)
        act.ctrllimited = True
        act.ctrlrange = [float(rng[0]), float(rng[1])]
        if frc[1] > frc[0]:
            act.forcelimited = True
            act.forcerange = [float(frc[0]), float(frc[1])]
    for j in spec.joints:
        if j.name in robot.joint_index:
            j.armature = cfg.armature_kgm2
    world_names, floor_names = _add_scene(spec, scene, cfg)
    try:
        model = spec.compile()
    except ValueError as exc:
        raise ValueError(f"{where}: MuJoCo cannot compile the model: {exc}") from None

    def subtree(body_id: int) -> frozenset:
        ids = {body_id}
        for b in range(body_id + 1, model.nbody):
            if model.body_parentid[b] in ids:
                ids.add(b)
        return frozenset(ids)

    def body_id(name: str) -> int:
        return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)

    jid = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in robot.joint_names]
    hands = {}
    for side, frame in robot.hand_frames.items():
        hands[side] = subtree(body_id(body_named(_body_of_frame(robot, frame)[0]).name))
    sole_ids = tuple(body_id(n) for n in sole_body_names)
    return PhysicsModel(
        model=model, robot=robot, config=cfg,
        qpos_adr=np.array([model.jnt_qposadr[i] for i in jid]), dof_adr=np.array([model.jnt_dofadr[i] for i in jid]),
        actuator_ids=np.array([mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, f"servo_{j}")
                               for j in robot.joint_names]),
        root_body=body_id(robot.base_link), sole_bodies=sole_ids,  # type: ignore[arg-type]
        sole_in_body=tuple(sole_placements),  # type: ignore[arg-type]
        sole_geoms=tuple(mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, n) for n in sole_geom_names),  # type: ignore[arg-type]
        foot_body_sets=tuple(subtree(b) for b in sole_ids),  # type: ignore[arg-type]
        hand_body_sets=hands,
        world_geoms=frozenset(mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, n) for n in world_names),
        floor_geoms=frozenset(mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, n) for n in floor_names),
        joint_groups=groups)


def base_pose_from_se3(pose: pin.SE3) -> np.ndarray:
    """A free joint's qpos (x, y, z, qw, qx, qy, qz) from a pinocchio pose."""
    xyzw = pin.SE3ToXYZQUAT(pose)
    return np.array([*xyzw[:3], xyzw[6], *xyzw[3:6]])




def build_for_robot(robot: RobotModel, scene_file: str | None = None) -> PhysicsModel:
    """The model of ``robot`` with its description's ``physics.yaml`` in ``scene_file`` (a scene
    YAML, config/-relative or absolute; None: the description's demo scene)."""
    from humanoid_reach_ros.sim.physics.config import load_physics_config
    from humanoid_reach_ros.sim.scene import load_scene

    cfg = load_physics_config(robot.spec.path.parent)
    return build_physics_model(robot, cfg, load_scene(scene_file or robot.spec.demo_scene))


__all__ = ["FLOOR", "FOOT", "OBSTACLE", "ROBOT", "PhysicsModel", "base_pose_from_se3", "build_for_robot",
           "build_physics_model",
           "check_inertias", "joint_groups", "strip_geometry", "torus_ring"]
