"""``config/robots/<name>/physics.yaml``: the physics plant's settings for one robot.

The file holds the simulation settings (timestep, friction coefficient, sole box thickness),
the position servos' gains per joint group and per joint, and the fall thresholds. Joint
groups are named by the robot description's roles, not by joint names, so one file layout
serves every robot (:data:`JOINT_GROUPS`):

* ``legs``: the first four joints of each leg limb (hip yaw, roll, pitch; knee);
* ``ankles``: the last two joints of each leg limb (ankle pitch and roll: they carry the
  whole robot's moment about the sole, hence the stiffest servos);
* ``torso``: the chest's yaw, pitch (and roll); ``neck``: the head's joints;
* ``arms``: the arm limbs' joints; ``grippers``: the description's gripper joints;
* ``other``: every joint none of the above names (optional; required only when such joints exist).

``joint_gains`` overrides the group's gains of single joints, by URDF joint name. Each gain
entry is ``{kp: N m/rad, dampratio: ...}`` (MuJoCo's position actuator: damping ``kv`` chosen
so that the joint alone is damped with that ratio) or ``{kp, kv: N m s/rad}``.

An unknown key anywhere, a joint of the model without a gain, a ``joint_gains`` entry naming a
joint the model lacks, or a non-finite or negative number is a ``ValueError`` naming the file
and the key. No ROS here.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from humanoid_reach_ros.yaml_checks import number, positive, top_level

PHYSICS_FILE = "physics.yaml"
JOINT_GROUPS = ("legs", "ankles", "torso", "neck", "arms", "grippers", "other")
_TOP = {"timestep_s", "friction", "impratio", "sole_thickness_m", "torus_segments", "armature_kgm2", "gains",
        "joint_gains", "fall", "hand_sphere_radius_m", "force_guard", "stabilizer"}
_GAIN_KEYS = {"kp", "dampratio", "kv"}
_FALL_KEYS = {"base_drop_m", "tilt_deg", "capture_point_out_m"}
_STABILIZER_KEYS = {"enabled", "ankle_time_constant_s", "ankle_return_time_s", "ankle_max_rad", "cop_margin_m",
                    "force_time_constant_s", "force_return_time_s", "leg_length_max_m"}
_GUARD_KEYS = {"enabled", "bound_fraction", "release_s", "release_rad"}


@dataclass(frozen=True)
class Gain:
    """One position servo: ``kp`` [N m/rad] and either ``dampratio`` or ``kv`` [N m s/rad]."""

    kp: float
    dampratio: float | None = None
    kv: float | None = None


@dataclass(frozen=True)
class FallThresholds:
    """The robot has fallen when its base drops ``base_drop_m`` below where its joints hold it on
    its feet (metrics.py), tilts by
    more than ``tilt_deg``, or its capture point leaves the support polygon by more than
    ``capture_point_out_m`` (IHMC's rule: 5 cm)."""

    base_drop_m: float = 0.15
    tilt_deg: float = 30.0
    capture_point_out_m: float = 0.05


@dataclass(frozen=True)
class StabilizerConfig:
    """The foot force stabilizer (sim/physics/stabilizer.py): ankle torque control (time constant of the
    foot torque's error, 0: off; return time; bound of the offset; the reference CoP ``cop_margin_m``
    inside the sole) and foot force difference control (time constant, 0: off; return time; bound of the
    legs' length difference)."""

    enabled: bool = False
    ankle_time_constant_s: float = 0.1
    ankle_return_time_s: float = 1.0
    ankle_max_rad: float = 0.05
    cop_margin_m: float = 0.03
    force_time_constant_s: float = 0.1
    force_return_time_s: float = 1.0
    leg_length_max_m: float = 0.01


@dataclass(frozen=True)
class ForceGuardConfig:
    """The wrist force guard (sim/physics/force_guard.py): an arm is held at its measured joints while its
    hand pushes beyond ``bound_fraction`` of the robot's touch bound (sim/physics/touch.py); released,
    the held offset fades over ``release_s``; a hand that no longer touches is released once the
    command is back within ``release_rad`` of the held joints."""

    enabled: bool = True
    bound_fraction: float = 0.8
    release_s: float = 0.2
    release_rad: float = 0.02


def _section(raw: Any, cls, keys: set, where: str):
    """The ``stabilizer`` / ``force_guard`` mapping of physics.yaml as ``cls`` (absent: the defaults)."""
    if raw is None:
        return cls()
    if not isinstance(raw, dict):
        raise ValueError(f"{where}: expected a mapping with keys among {sorted(keys)}, got {raw!r}")
    unknown = set(raw) - keys
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {sorted(unknown)}; expected among {sorted(keys)}")
    values: dict[str, Any] = {}
    for k, v in raw.items():
        if k == "enabled":
            if not isinstance(v, bool):
                raise ValueError(f"{where}.enabled: expected true or false, got {v!r}")
            values[k] = v
        elif k in ("ankle_time_constant_s", "force_time_constant_s"):
            values[k] = _non_negative(v, f"{where}.{k}")
        else:
            values[k] = positive(v, f"{where}.{k}")
    if values.get("bound_fraction", 0.0) > 1.0:
        raise ValueError(f"{where}.bound_fraction: at most 1 (a share of the touch bound), "
                         f"got {values['bound_fraction']}")
    for k in ("ankle_time_constant_s", "force_time_constant_s"):
        if 0.0 < values.get(k, 1.0) < 0.01:
            raise ValueError(f"{where}.{k}: at least 0.01 s (two ticks of the joint driver's 5 ms loop), "
                             f"got {values[k]}")
    if values.get("release_s", 1.0) < 0.01:
        raise ValueError(f"{where}.release_s: at least 0.01 s (two ticks of the joint driver's 5 ms loop), "
                         f"got {values['release_s']}")
    return cls(**values)


@dataclass(frozen=True)
class PhysicsConfig:
    """The settings of one robot's physics plant (module doc)."""

    path: Path
    timestep_s: float
    friction: float
    impratio: float
    sole_thickness_m: float
    torus_segments: int
    armature_kgm2: float
    hand_sphere_radius_m: float      # the hands' tool point spheres (0: none)
    gains: dict[str, Gain]           # group -> gain
    joint_gains: dict[str, Gain]     # joint -> gain (overrides its group)
    fall: FallThresholds
    force_guard: ForceGuardConfig = ForceGuardConfig()
    stabilizer: StabilizerConfig = StabilizerConfig()

    def gain_of(self, joint: str, group: str) -> Gain:
        """The gain of ``joint`` (of ``group``): its own entry, else its group's; ValueError when neither."""
        if joint in self.joint_gains:
            return self.joint_gains[joint]
        if group in self.gains:
            return self.gains[group]
        raise ValueError(f"{self.path}: joint {joint!r} (group {group!r}) has no gain: add gains.{group} or "
                         f"joint_gains.{joint}")


def _gain(d: Any, where: str) -> Gain:
    if not isinstance(d, dict):
        raise ValueError(f"{where}: expected {{kp, dampratio}} or {{kp, kv}}, got {d!r}")
    unknown = set(d) - _GAIN_KEYS
    if unknown:
        raise ValueError(f"{where}: unknown gain key(s) {sorted(unknown)}; expected kp with dampratio or kv")
    if "kp" not in d or ("dampratio" in d) == ("kv" in d):
        raise ValueError(f"{where}: needs kp and exactly one of dampratio, kv; got {sorted(d)}")
    kp = number(d["kp"], f"{where}.kp")
    if kp < 0.0:
        raise ValueError(f"{where}.kp: must be >= 0, got {kp}")
    damp = d.get("dampratio")
    kv = d.get("kv")
    if damp is not None and number(damp, f"{where}.dampratio") < 0.0:
        raise ValueError(f"{where}.dampratio: must be >= 0, got {damp}")
    if kv is not None and number(kv, f"{where}.kv") < 0.0:
        raise ValueError(f"{where}.kv: must be >= 0, got {kv}")
    return Gain(kp, None if damp is None else float(damp), None if kv is None else float(kv))


def _non_negative(v: Any, where: str) -> float:
    x = number(v, where)
    if x < 0.0:
        raise ValueError(f"{where}: must be >= 0, got {x}")
    return x


def physics_config_from_dict(doc: Any, path: Path) -> PhysicsConfig:
    """Validate a parsed physics.yaml (module doc); ``path`` names it in errors."""
    where = str(path)
    top_level(doc, _TOP, where)
    for key in ("timestep_s", "friction", "gains"):
        if key not in doc:
            raise ValueError(f"{where}: missing key {key!r}")
    dt = positive(doc["timestep_s"], f"{where}: timestep_s")
    if dt > 0.005:
        raise ValueError(f"{where}: timestep_s {dt} is too long for stiff servos (at most 0.005 s; 0.001-0.002 usual)")
    gains_raw = doc["gains"]
    if not isinstance(gains_raw, dict):
        raise ValueError(f"{where}: gains must map joint groups ({', '.join(JOINT_GROUPS)}) to gains")
    unknown = set(gains_raw) - set(JOINT_GROUPS)
    if unknown:
        raise ValueError(f"{where}: unknown gain group(s) {sorted(unknown)}; the groups are {', '.join(JOINT_GROUPS)}")
    joint_raw = doc.get("joint_gains") or {}
    if not isinstance(joint_raw, dict):
        raise ValueError(f"{where}: joint_gains must map joint names to gains")
    fall_raw = doc.get("fall") or {}
    if not isinstance(fall_raw, dict) or set(fall_raw) - _FALL_KEYS:
        raise ValueError(f"{where}: fall must be a mapping with keys among {sorted(_FALL_KEYS)}, got {fall_raw!r}")
    fall = FallThresholds(**{k: positive(v, f"{where}: fall.{k}") for k, v in fall_raw.items()})
    segments = doc.get("torus_segments", 24)
    if isinstance(segments, bool) or not isinstance(segments, int) or segments < 6:
        raise ValueError(f"{where}: torus_segments must be an integer >= 6, got {segments!r}")
    armature = number(doc.get("armature_kgm2", 0.0), f"{where}: armature_kgm2")
    if armature < 0.0:
        raise ValueError(f"{where}: armature_kgm2 must be >= 0, got {armature}")
    return PhysicsConfig(
        path=path, timestep_s=dt, friction=positive(doc["friction"], f"{where}: friction"),
        impratio=positive(doc.get("impratio", 1.0), f"{where}: impratio"),
        sole_thickness_m=positive(doc.get("sole_thickness_m", 0.01), f"{where}: sole_thickness_m"),
        torus_segments=segments, armature_kgm2=armature,
        hand_sphere_radius_m=_non_negative(doc.get("hand_sphere_radius_m", 0.0), f"{where}: hand_sphere_radius_m"),
        gains={str(k): _gain(v, f"{where}: gains.{k}") for k, v in gains_raw.items()},
        joint_gains={str(k): _gain(v, f"{where}: joint_gains.{k}") for k, v in joint_raw.items()},
        fall=fall,
        stabilizer=_section(doc.get("stabilizer"), StabilizerConfig, _STABILIZER_KEYS, f"{where}: stabilizer"),
        force_guard=_section(doc.get("force_guard"), ForceGuardConfig, _GUARD_KEYS, f"{where}: force_guard"))


def load_physics_config(robot_dir: str | Path) -> PhysicsConfig:
    """``physics.yaml`` of the robot description directory ``robot_dir`` (beside robot.yaml), or a
    physics YAML file given directly; ValueError when missing or malformed."""
    p = Path(robot_dir)
    if p.is_dir():
        p = p / PHYSICS_FILE
    if not p.is_file():
        raise ValueError(f"no physics settings {p}: the mujoco plant needs config/robots/<name>/{PHYSICS_FILE} "
                         "(docs/physics.md)")
    with open(p) as f:
        try:
            doc = yaml.safe_load(f)
        except yaml.YAMLError as exc:
            raise ValueError(f"{p}: not YAML ({exc})") from None
    return physics_config_from_dict(doc, p)


__all__ = ["FallThresholds", "ForceGuardConfig", "Gain", "JOINT_GROUPS", "PHYSICS_FILE", "PhysicsConfig",
           "StabilizerConfig", "load_physics_config", "physics_config_from_dict"]
