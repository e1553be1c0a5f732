"""The robot description: ``config/robots/<name>/robot.yaml`` read into one object.

A :class:`RobotSpec` names everything the package needs to know about a robot beyond
its URDF: the four limbs (root link, tip frame, six joints each -- seven allowed for an
arm: the hands are the arm limbs' tips, the soles the leg limbs' tips), the floating-base
link, the chest joints by role (yaw and pitch; a roll where the robot has one), the neck
joints by role (yaw and pitch; none for a robot without a neck, whose camera the chest
aims), the head camera frame, the grippers, the
half-sitting posture, the sole rectangle (the support polygon is the hull of both soles),
the collision model file, the dual-arm torso regression model and the dual-arm workspace
file it was trained on (box, hand orientation rule, initial CoM drop: fitted to one robot's
arms and legs, so each robot names its own), and fixed frames the description adds to the
URDF's (``frames``: e.g. a grasp point the URDF lacks).

The URDF is a file beside ``robot.yaml`` or a packaged resource
``package://<package>/<path>`` (:func:`resolve_package_uri`: the package's ament share
directory, else the ``cmeel.prefix/share`` of a pip-installed cmeel wheel on ``sys.path``),
so a third-party model is read where its package installs it, not copied.
:class:`~humanoid_reach_ros.robot.model.RobotModel`
loads it and every layer receives it from there: no robot-specific name or number is
written anywhere else in the package (``test/test_robot_spec.py`` checks).

No ROS here.
"""
from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path

import yaml

from humanoid_reach_ros.paths import config_path

#: the robot the nodes, demo and benches use unless told otherwise
DEFAULT_ROBOT = "hrp2"
LIMB_NAMES = ("right_leg", "left_leg", "right_arm", "left_arm")
#: joints per limb the description accepts (legs: the planner's compiled leg IK needs six;
#: arms: six, or seven solved by kinematics/general_ik.py's RedundantLimbIK)
LIMB_JOINTS = {"right_leg": (6,), "left_leg": (6,), "right_arm": (6, 7), "left_arm": (6, 7)}
PACKAGE_SCHEME = "package://"
#: the dual-arm workspace file of a description that names none (config/; the first robot's,
#: kept as the default so that descriptions written before the key read as before)
DEFAULT_DUAL_ARM_WORKSPACE = "robots/hrp2/dual_arm_workspace.yaml"   # config/-relative: HRP-2's
_KEYS = {"robot_name", "urdf", "collision_model", "base_link", "limbs", "chest", "head", "gripper_joints",
         "sole_rectangle_m", "torso_regression", "dual_arm_workspace", "half_sitting", "frames", "demo_scene",
         "reach_map"}
_REQUIRED = _KEYS - {"gripper_joints", "torso_regression", "dual_arm_workspace", "frames", "demo_scene", "reach_map"}
DEFAULT_DEMO_SCENE = "scenes/plant.yaml"   # config/-relative: the plant, made for HRP-2's and Talos's size
#: roles of the ``chest`` entry: required, then optional
_CHEST_ROLES, _CHEST_OPTIONAL = ("yaw", "pitch"), ("roll",)
#: roles of the ``head`` entry: the camera frame, required; the neck's joints, both or neither
_NECK_ROLES = ("yaw", "pitch")


@dataclass(frozen=True)
class LimbDef:
    """A limb of the description: joints (6; 7 for an arm) from the ``root`` link to the ``tip`` frame."""

    root: str
    tip: str
    joints: tuple[str, ...]


@dataclass(frozen=True)
class FrameDef:
    """A fixed frame the description adds to the URDF's: ``xyz`` [m] and ``rpy`` [rad]
    (URDF convention: R = Rz(yaw) Ry(pitch) Rx(roll)) in frame ``parent``."""

    parent: str
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]


@dataclass(frozen=True)
class RobotSpec:
    """One robot's description (module doc). Paths are absolute."""

    name: str
    path: Path
    urdf_path: Path
    collision_path: Path
    base_link: str
    limbs: dict
    chest_yaw: str
    chest_pitch: str
    #: the neck's yaw and pitch joints; both None for a robot without a neck (its description's
    #: ``head`` names the camera frame only): :attr:`has_neck`, :attr:`neck_joints`
    head_yaw: str | None
    head_pitch: str | None
    camera_frame: str
    gripper_joints: tuple[str, ...]
    sole_rectangle: tuple[float, float, float, float]
    half_sitting_deg: dict
    #: the dual-arm torso regression model: the absolute stem (no .npz/.yaml) of the
    #: description's ``torso_regression``, which names it relative to robot.yaml's directory
    torso_regression: str | None
    #: the dual-arm workspace YAML, absolute (robot.yaml names it relative to its directory;
    #: dual_arm/torso_regression.py's ReachWorkspace reads it)
    dual_arm_workspace: str
    #: name -> FrameDef: fixed frames added to the URDF's by RobotModel
    frames: dict
    #: directories holding the URDF's package (pinocchio's ``package_dirs`` for its meshes);
    #: empty for a URDF file beside robot.yaml
    package_dirs: tuple[Path, ...] = ()
    #: the chest's roll joint where the description names one (``chest.roll``), else None
    chest_roll: str | None = None
    #: the scene ``make demo`` reaches in, absolute: the description's ``demo_scene`` (beside
    #: robot.yaml), else the plant (``DEFAULT_DEMO_SCENE``); a robot too small for the plant's
    #: valve names a scene made for its size
    demo_scene: str = ""
    #: the planner's reachability map (planning/reach_map.py), absolute: the description's
    #: ``reach_map`` (a .npz beside robot.yaml, trained by tools/train_reach_map.py), else None
    reach_map: str | None = None

    @property
    def hand_frames(self) -> dict[str, str]:
        """Arm name ("right", "left") -> hand frame (the arm limb's tip)."""
        return {"right": self.limbs["right_arm"].tip, "left": self.limbs["left_arm"].tip}

    @property
    def sole_frames(self) -> tuple[str, str]:
        """Right and left sole frames (the leg limbs' tips)."""
        return self.limbs["right_leg"].tip, self.limbs["left_leg"].tip

    @property
    def chest_link(self) -> str:
        """The link both arms hang from."""
        return self.limbs["right_arm"].root

    @property
    def chest_joints(self) -> tuple[str, str]:
        """Chest yaw, then pitch: the torso the reaching algorithms and the gaze move (a roll,
        where the chest has one, is in :attr:`torso_joints` only)."""
        return self.chest_yaw, self.chest_pitch

    @property
    def torso_joints(self) -> tuple[str, ...]:
        """Every chest joint by role: yaw, pitch, then the roll where the description has one."""
        return (self.chest_yaw, self.chest_pitch) + (() if self.chest_roll is None else (self.chest_roll,))

    @property
    def has_neck(self) -> bool:
        """Whether the head turns on a neck (yaw and pitch joints) or sits fixed on the chest."""
        return self.head_yaw is not None

    @property
    def neck_joints(self) -> tuple[str, ...]:
        """Neck yaw, then pitch (pitch > 0 looks down); empty for a robot without a neck."""
        return (self.head_yaw, self.head_pitch) if self.has_neck else ()

    @property
    def head_joints(self) -> tuple[str, str]:
        """Head yaw, then pitch (pitch > 0 looks down); ValueError for a robot without a neck
        (:meth:`require_neck`): for callers that turn the head by its own angles. Callers that
        merely treat the head joints apart use :attr:`neck_joints`, which may be empty."""
        return self.require_neck("turning the head by its yaw and pitch")

    def require_neck(self, what: str) -> tuple[str, str]:
        """The neck's (yaw, pitch) joints, or ValueError naming the robot, its description and
        ``what`` (e.g. "a look at head angles") when the robot has no neck."""
        if not self.has_neck:
            raise ValueError(f"robot {self.name!r} has no neck: its description {self.path} names no head yaw and "
                             f"pitch joints (head: camera_frame only), and {what} needs them; aim the camera at a "
                             "point instead (control/gaze.py: the chest aims it)")
        return self.head_yaw, self.head_pitch

    def names(self) -> set[str]:
        """Every joint and frame name the description gives (robot-specific by nature)."""
        out = {self.camera_frame, *self.torso_joints, *self.neck_joints, *self.gripper_joints, *self.frames}
        for limb in self.limbs.values():
            out |= {limb.root, limb.tip, *limb.joints}
        return out - {self.base_link}


def robots() -> list[str]:
    """The robots of ``config/robots`` (directories with a ``robot.yaml``)."""
    return sorted(p.name for p in config_path("robots").iterdir() if (p / "robot.yaml").is_file())


def robot_config_path(robot: str | Path) -> Path:
    """``hrp2`` -> ``config/robots/hrp2/robot.yaml``; a path (absolute, or relative to
    ``config/``) to a robot YAML is taken as it is."""
    s = str(robot)
    if "/" not in s and not s.endswith((".yaml", ".yml")):
        return config_path("robots", s, "robot.yaml")
    p = Path(s)
    return p if p.is_absolute() else config_path(s)


def resolve_package_uri(uri: str, where: str = "resource") -> tuple[Path, Path]:
    """``package://<package>/<path>`` -> (the file, the directory holding the package's share
    directory: pinocchio's ``package_dirs`` entry for the package's meshes). Looked up in the
    ament index (a ROS install of the package), then in every ``<entry>/cmeel.prefix/share``
    of ``sys.path`` (a pip-installed cmeel wheel, e.g. ``example-robot-data``). ValueError
    naming the package and how to install it when it is not there, or naming the directory
    searched when the package is there without the file."""
    rest = uri[len(PACKAGE_SCHEME):]
    package, _, rel = rest.partition("/")
    if not uri.startswith(PACKAGE_SCHEME) or not package or not rel:
        raise ValueError(f"{where}: {uri!r} is not package://<package>/<path>")
    shares: list[Path] = []
    try:
        from ament_index_python.packages import get_package_share_directory

        shares.append(Path(get_package_share_directory(package)))
    except Exception:   # not a ROS install of the package (or no ament index at all)
        pass
    for entry in sys.path:
        d = Path(entry or ".") / "cmeel.prefix" / "share" / package
        if d.is_dir() and d not in shares:
            shares.append(d)
    for share in shares:
        if (share / rel).is_file():
            return (share / rel).resolve(), share.parent.resolve()
    if shares:
        raise ValueError(f"{where}: {uri}: no {rel} in package {package!r} ({', '.join(map(str, shares))}); "
                         f"another version of {package!r}? (tools/requirements.txt pins the one the description needs)")
    raise ValueError(f"{where}: {uri}: package {package!r} is not installed (neither in the ament index nor a "
                     f"pip cmeel prefix on sys.path): pip install {package} (pinned in tools/requirements.txt; "
                     f"tools/setup.sh installs it), or install its ROS package")


def _frames(doc, where: str) -> dict[str, FrameDef]:
    raw = doc.get("frames", {}) or {}
    if not isinstance(raw, dict):
        raise ValueError(f"{where}: frames must map frame names to {{parent, xyz, rpy}}")
    out = {}
    for name, d in raw.items():
        ok = isinstance(d, dict) and set(d) == {"parent", "xyz", "rpy"} and isinstance(d["parent"], str)
        for k in ("xyz", "rpy"):
            v = d.get(k) if isinstance(d, dict) else None
            ok = ok and isinstance(v, list) and len(v) == 3 and all(
                isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)
        if not ok:
            raise ValueError(f"{where}: frames.{name} must be {{parent: frame, xyz: [3 m], rpy: [3 rad]}}")
        out[str(name)] = FrameDef(d["parent"], tuple(float(x) for x in d["xyz"]), tuple(float(x) for x in d["rpy"]))
    return out


def _dual_arm_workspace(doc, robot_dir: Path, where: str) -> str:
    """The ``dual_arm_workspace`` entry, as an absolute path: a YAML file beside robot.yaml
    (or absolute) that exists and holds a mapping with a ``workspace`` box; without the key,
    HRP-2's (``DEFAULT_DUAL_ARM_WORKSPACE``). Its full content is checked by
    ``ReachWorkspace.load`` when the dual-arm mode starts (the robot layer does not import
    dual_arm/); this catches a wrong or missing path when the description is read."""
    ws = doc.get("dual_arm_workspace")
    if ws is not None and (not isinstance(ws, str) or not ws.endswith((".yaml", ".yml"))):
        raise ValueError(f"{where}: dual_arm_workspace must be a YAML file beside robot.yaml (or absolute), "
                         f"got {ws!r}")
    p = config_path(DEFAULT_DUAL_ARM_WORKSPACE) if ws is None else (robot_dir / ws).resolve()
    if not p.is_file():
        raise ValueError(f"{where}: dual_arm_workspace {ws!r}: no such file {p}")
    with open(p) as f:
        try:
            body = yaml.safe_load(f)
        except yaml.YAMLError as exc:
            raise ValueError(f"{where}: dual_arm_workspace {p}: not YAML ({exc})") from None
    if not isinstance(body, dict) or "workspace" not in body:
        raise ValueError(f"{where}: dual_arm_workspace {p}: not a dual-arm workspace file (no 'workspace' boxes)")
    return str(p)


def _demo_scene(doc, robot_dir: Path, where: str) -> str:
    """The ``demo_scene`` entry, as an absolute path: a scene YAML beside robot.yaml (or
    absolute) that exists; without the key, the plant (``DEFAULT_DEMO_SCENE``). Its content is
    checked by ``sim.scene.load_scene`` when the demo starts (the robot layer does not read scenes)."""
    scene = doc.get("demo_scene")
    if scene is None:
        return str(config_path(DEFAULT_DEMO_SCENE))
    if not isinstance(scene, str) or not scene.endswith((".yaml", ".yml")):
        raise ValueError(f"{where}: demo_scene must be a scene YAML file beside robot.yaml (or absolute), "
                         f"got {scene!r}")
    p = (robot_dir / scene).resolve()
    if not p.is_file():
        raise ValueError(f"{where}: demo_scene {scene!r}: no such file {p}")
    return str(p)


def _chest_and_head(doc, where: str) -> tuple[dict, dict]:
    """The ``chest`` and ``head`` entries, checked: the chest's yaw and pitch joints (and
    optionally its roll); the head's camera frame and either no neck or a neck's yaw and pitch
    joints, both (half a neck is refused, naming the half that is missing)."""
    chest, head = doc["chest"], doc["head"]
    ok = isinstance(chest, dict) and set(_CHEST_ROLES) <= set(chest) <= {*_CHEST_ROLES, *_CHEST_OPTIONAL}
    if not ok or not all(isinstance(v, str) for v in chest.values()):
        raise ValueError(f"{where}: chest must be {{{', '.join(_CHEST_ROLES)}}} or {{{', '.join(_CHEST_ROLES)}, "
                         f"{', '.join(_CHEST_OPTIONAL)}}} (joint names), got {chest!r}")
    ok = isinstance(head, dict) and "camera_frame" in head and set(head) <= {*_NECK_ROLES, "camera_frame"}
    if not ok or not all(isinstance(v, str) for v in head.values()):
        raise ValueError(f"{where}: head must be {{camera_frame}} (a robot without a neck) or "
                         f"{{{', '.join(_NECK_ROLES)}, camera_frame}} (a neck's joints; the frame), got {head!r}")
    neck = [k for k in _NECK_ROLES if k in head]
    if neck and len(neck) != len(_NECK_ROLES):
        missing = [k for k in _NECK_ROLES if k not in head]
        raise ValueError(f"{where}: head names a neck {' and '.join(neck)} joint but no {' and '.join(missing)} "
                         f"joint: a neck needs both ({', '.join(_NECK_ROLES)}); a robot without a neck names only "
                         "the camera_frame")
    return chest, head


def load_robot_spec(robot: str | Path = DEFAULT_ROBOT) -> tuple[RobotSpec, dict]:
    """Read and validate a robot description; returns the spec and the raw document.

    ValueError naming the key for: unknown or missing keys, a limb without root, tip or
    six joints (six or seven for an arm), a URDF ``package://`` resource that is not
    installed, a malformed added frame, a chest without yaw and pitch (a roll is optional), a
    head without a camera frame or with half a neck (yaw and pitch: both or neither), a chest
    or neck joint named twice or that is also a limb or gripper joint, a sole rectangle that is not four finite
    numbers with min < max, a half-sitting entry that is not a finite angle, a
    ``dual_arm_workspace`` that is not an existing workspace YAML. Names are
    checked against the URDF by :class:`~humanoid_reach_ros.robot.model.RobotModel`."""
    path = robot_config_path(robot)
    if not path.exists():
        raise ValueError(f"robot description {path} does not exist (robots: {robots()})")
    with open(path) as f:
        doc = yaml.safe_load(f)
    where = f"robot description {path}"
    if not isinstance(doc, dict):
        raise ValueError(f"{where}: expected a mapping")
    extra, missing = set(doc) - _KEYS, _REQUIRED - set(doc)
    if extra or missing:
        raise ValueError(f"{where}: unknown key(s) {sorted(extra)}, missing key(s) {sorted(missing)}")
    limbs = {}
    if not isinstance(doc["limbs"], dict) or set(doc["limbs"]) != set(LIMB_NAMES):
        raise ValueError(f"{where}: limbs must be exactly {LIMB_NAMES}")
    for name in LIMB_NAMES:
        d = doc["limbs"][name]
        if not isinstance(d, dict) or set(d) != {"root", "tip", "joints"} or not isinstance(d["joints"], list) \
                or len(d["joints"]) not in LIMB_JOINTS[name] \
                or not all(isinstance(x, str) for x in [d["root"], d["tip"], *d["joints"]]):
            counts = "" if len(LIMB_JOINTS[name]) == 1 else ", or 7: an arm may be redundant"
            raise ValueError(f"{where}: limbs.{name} must be {{root, tip, joints: [6 joint names{counts}]}}")
        limbs[name] = LimbDef(d["root"], d["tip"], tuple(d["joints"]))
    if limbs["right_arm"].root != limbs["left_arm"].root:
        raise ValueError(f"{where}: both arms must hang from the same (chest) link")
    chest, head = _chest_and_head(doc, where)
    rect = doc["sole_rectangle_m"]
    finite = isinstance(rect, list) and all(isinstance(x, (int, float)) and math.isfinite(x) for x in rect)
    if not (finite and len(rect) == 4 and rect[0] < rect[1] and rect[2] < rect[3]):
        raise ValueError(f"{where}: sole_rectangle_m must be [x_min, x_max, y_min, y_max] [m], min < max")
    hs = doc["half_sitting"]
    if not isinstance(hs, dict) or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in hs.values()):
        raise ValueError(f"{where}: half_sitting must map joint names to finite angles [deg]")
    grippers = doc.get("gripper_joints", [])
    if not isinstance(grippers, list) or not all(isinstance(g, str) for g in grippers):
        raise ValueError(f"{where}: gripper_joints must be a list of joint names")
    roles = [*chest.values(), *(head[k] for k in _NECK_ROLES if k in head)]
    twice = sorted({n for n in roles if roles.count(n) > 1})
    if twice:
        raise ValueError(f"{where}: chest and head joints must be distinct joints, named twice: {twice}")
    taken = {j for limb in limbs.values() for j in limb.joints} | set(grippers)
    if shared := sorted(set(roles) & taken):
        raise ValueError(f"{where}: chest or head joint(s) {shared} are also limb or gripper joints")
    reg = doc.get("torso_regression")
    if reg is not None and not isinstance(reg, str):
        raise ValueError(f"{where}: torso_regression must be a model path (beside robot.yaml, no extension)")
    if reg is not None:
        reg = str((path.parent / reg).resolve())
    rmap = doc.get("reach_map")
    if rmap is not None and not (isinstance(rmap, str) and rmap):
        raise ValueError(f"{where}: reach_map must be a .npz file name beside robot.yaml")
    if rmap is not None:
        rmap = str((path.parent / rmap).resolve())
    workspace = _dual_arm_workspace(doc, path.parent, where)
    frames = _frames(doc, where)
    urdf = doc["urdf"]
    if not isinstance(urdf, str):
        raise ValueError(f"{where}: urdf must be a file name beside robot.yaml or package://<package>/<path>")
    if urdf.startswith(PACKAGE_SCHEME):
        urdf_path, package_dir = resolve_package_uri(urdf, f"{where}: urdf")
        package_dirs: tuple[Path, ...] = (package_dir,)
    else:
        urdf_path, package_dirs = (path.parent / urdf).resolve(), ()
    spec = RobotSpec(
        name=str(doc["robot_name"]), path=path, urdf_path=urdf_path, package_dirs=package_dirs, frames=frames,
        collision_path=(path.parent / doc["collision_model"]).resolve(), base_link=str(doc["base_link"]),
        limbs=limbs, chest_yaw=chest["yaw"], chest_pitch=chest["pitch"], chest_roll=chest.get("roll"),
        head_yaw=head.get("yaw"), head_pitch=head.get("pitch"), camera_frame=head["camera_frame"],
        gripper_joints=tuple(grippers), sole_rectangle=tuple(float(x) for x in rect),
        half_sitting_deg={str(k): float(v) for k, v in hs.items()}, torso_regression=reg,
        dual_arm_workspace=workspace, demo_scene=_demo_scene(doc, path.parent, where), reach_map=rmap)
    return spec, doc


def check_against_model(spec: RobotSpec, joint_names, has_frame) -> None:
    """ValueError naming every joint or frame of ``spec`` the URDF does not have."""
    joints = set(joint_names)
    bad = [j for j in (*spec.torso_joints, *spec.neck_joints, *spec.gripper_joints, *spec.half_sitting_deg)
           if j not in joints]
    for name, limb in spec.limbs.items():
        bad += [f"{name}.{j}" for j in limb.joints if j not in joints]
        bad += [f"{name} frame {f}" for f in (limb.root, limb.tip) if not has_frame(f)]
    bad += [f"frame {f}" for f in (spec.base_link, spec.camera_frame) if not has_frame(f)]
    bad += [f"frames.{n} parent {d.parent}" for n, d in spec.frames.items() if not has_frame(d.parent)]
    if bad:
        raise ValueError(f"robot description {spec.path}: not in {spec.urdf_path.name}: {', '.join(bad)}")


__all__ = ["RobotSpec", "LimbDef", "FrameDef", "load_robot_spec", "robot_config_path", "robots",
           "check_against_model", "resolve_package_uri", "DEFAULT_ROBOT", "DEFAULT_DUAL_ARM_WORKSPACE", "LIMB_NAMES",
           "LIMB_JOINTS"]
