"""The generality suite (``config/scenes/suite.yaml``): scenes beyond the plant, the
targets an operator would point at in them, and what the planner must answer for each
arm. Used by ``bench/generality.py`` and ``test/test_scene_suite.py``.

A case: ``name``, ``scene`` (a scene YAML, relative to ``config/``), an optional
``target`` ``{position, rpy}`` (default: the scene's), ``region`` (``hemisphere``: the
paper's eq. 3 -- hand at the target, roll and pitch within +-90 deg, yaw free -- or
``cone``: roll and pitch within +-``cone_deg``), ``exclude_groups`` (default
``[target]``: the reached object is not an obstacle) and ``expect`` per arm:
``reachable`` (SUCCESS), ``out_of_reach`` (TARGET_OUT_OF_REACH, proven by the geometric
bound), ``no_goal`` (NO_GOAL_FOUND: not ruled out by a reach bound, yet no goal posture; at once
where the collision proof at the target decides it, planning/enclosure.py) or
``marginal`` (SUCCESS, NO_GOAL_FOUND or NO_PATH: the hand fits the model with zero
clearance, so a path exists only at the collision margin's edge; whether the planner finds
one within its budget depends on the samples: any of the three is a right answer, an error
or TARGET_OUT_OF_REACH is not).
``expect`` holds for every robot; ``expect_by_robot`` ``{robot: {arm: ...}}`` replaces it
for one robot of ``config/robots`` and the arms it names (robots differ: a longer arm reaches
across to a valve the other robot's cannot, a bigger hand does not pass where a smaller one
does).

No ROS here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from humanoid_reach_ros.codes import ARMS
from humanoid_reach_ros.paths import config_path
from humanoid_reach_ros.robot.spec import robots
from humanoid_reach_ros.planning.wgr import WorkspaceGoalRegion
from humanoid_reach_ros.sim.scene import Scene, load_scene, pose_matrix
from humanoid_reach_ros.yaml_checks import vec3

SUITE_FILE = "scenes/suite.yaml"
#: expectation -> the PlanReach error code names that answer it correctly
EXPECTATIONS = {"reachable": ("SUCCESS",), "out_of_reach": ("TARGET_OUT_OF_REACH",), "no_goal": ("NO_GOAL_FOUND",),
                "marginal": ("SUCCESS", "NO_GOAL_FOUND", "NO_PATH")}
REGIONS = ("hemisphere", "cone")
_CASE_KEYS = {"name", "scene", "target", "region", "cone_deg", "exclude_groups", "expect", "expect_by_robot"}


@dataclass(frozen=True, eq=False)
class SuiteCase:
    """One target in one scene and the answer expected per arm (module doc)."""

    name: str
    scene_path: Path
    target_pose: np.ndarray          # 4x4, world
    region_kind: str
    cone_deg: float
    exclude_groups: tuple[str, ...]
    expect: dict                     # arm -> key of EXPECTATIONS (every robot)
    expect_by_robot: dict = field(default_factory=dict)   # robot -> {arm -> key}: replaces ``expect``

    def region(self) -> WorkspaceGoalRegion:
        a = math.pi / 2 if self.region_kind == "hemisphere" else math.radians(self.cone_deg)
        lo = np.array([0.0, 0.0, 0.0, -a, -a, -math.pi])
        return WorkspaceGoalRegion(self.target_pose[:3, 3], self.target_pose[:3, :3], lo, -lo)

    def scene(self) -> Scene:
        return load_scene(self.scene_path)

    def voxels(self, resolution_m: float) -> np.ndarray:
        """The scene's occupied voxel centres without the reached object."""
        return self.scene().voxelize(resolution_m, exclude_groups=self.exclude_groups)

    def expect_for(self, robot: str | None = None) -> dict:
        """arm -> expectation for ``robot`` (``None``: the common ``expect``)."""
        return {**self.expect, **self.expect_by_robot.get(robot, {})}

    def expected_codes(self, arm: str, robot: str | None = None) -> tuple[str, ...]:
        """PlanReach error code names that answer ``arm`` of ``robot`` correctly."""
        return EXPECTATIONS[self.expect_for(robot)[arm]]

    def scene_class(self, robot: str | None = None) -> str:
        """What kind of case it is for ``robot``: the expectation of its best arm."""
        kinds = set(self.expect_for(robot).values())
        return "reachable" if "reachable" in kinds else sorted(kinds)[0]


def load_suite(path: str | Path = SUITE_FILE) -> list[SuiteCase]:
    """Load and validate the suite; ValueError naming the entry on bad input."""
    p = Path(path)
    if not p.is_absolute() and not p.exists():
        p = config_path(str(path))
    with open(p) as f:
        doc = yaml.safe_load(f)
    if not isinstance(doc, dict) or not isinstance(doc.get("cases"), list) or not doc["cases"]:
        raise ValueError(f"suite {p}: expected a mapping with a non-empty list 'cases'")
    cases, seen = [], set()
    for k, entry in enumerate(doc["cases"]):
        where = f"suite {p}: case #{k}"
        if not isinstance(entry, dict):
            raise ValueError(f"{where}: expected a mapping")
        extra = set(entry) - _CASE_KEYS
        if extra:
            raise ValueError(f"{where}: unknown key(s) {sorted(extra)}; expected some of {sorted(_CASE_KEYS)}")
        name = entry.get("name")
        if not isinstance(name, str) or not name or name in seen:
            raise ValueError(f"{where}: 'name' must be a unique non-empty string, got {name!r}")
        seen.add(name)
        where = f"suite {p}: case {name!r}"
        scene_file = entry.get("scene")
        if not isinstance(scene_file, str):
            raise ValueError(f"{where}: 'scene' must be a scene YAML path")
        scene_path = Path(scene_file) if Path(scene_file).is_absolute() else config_path(scene_file)
        if not scene_path.exists():
            raise ValueError(f"{where}: scene {scene_path} does not exist")
        scene = load_scene(scene_path)
        if "target" in entry:
            t = entry["target"]
            if not isinstance(t, dict) or set(t) - {"position", "rpy"} or "position" not in t:
                raise ValueError(f"{where}: 'target' must be {{position: [x, y, z], rpy: [r, p, y]}}")
            pose = pose_matrix(vec3(t["position"], f"{where}: target.position"),
                               vec3(t.get("rpy", [0.0, 0.0, 0.0]), f"{where}: target.rpy"))
        elif scene.target is not None:
            pose = scene.target.pose
        else:
            raise ValueError(f"{where}: no 'target' and the scene has none")
        region = entry.get("region", "hemisphere")
        if region not in REGIONS:
            raise ValueError(f"{where}: region must be one of {REGIONS}, got {region!r}")
        cone = entry.get("cone_deg", 90.0)
        if not isinstance(cone, (int, float)) or not 0 < cone <= 90:
            raise ValueError(f"{where}: cone_deg must be in (0, 90], got {cone!r}")
        groups = entry.get("exclude_groups", ["target"])
        if not isinstance(groups, list) or not all(isinstance(g, str) for g in groups):
            raise ValueError(f"{where}: exclude_groups must be a list of group names")
        expect = entry.get("expect")
        if not isinstance(expect, dict) or set(expect) != set(ARMS) or not all(
                v in EXPECTATIONS for v in expect.values()):
            raise ValueError(f"{where}: expect must give each of {ARMS} one of {sorted(EXPECTATIONS)}, got {expect!r}")
        by_robot = entry.get("expect_by_robot", {})
        known = robots()
        if not isinstance(by_robot, dict) or not all(
                r in known and isinstance(e, dict) and e and set(e) <= set(ARMS)
                and all(v in EXPECTATIONS for v in e.values())
                for r, e in by_robot.items()):
            raise ValueError(f"{where}: expect_by_robot must map robots of config/robots ({', '.join(known)}) to "
                             f"{{arm: one of {sorted(EXPECTATIONS)}}} for some of {ARMS}, got {by_robot!r}")
        cases.append(SuiteCase(name, scene_path, pose, region, float(cone), tuple(groups), dict(expect),
                               {r: dict(e) for r, e in by_robot.items()}))
    return cases


__all__ = ["SuiteCase", "load_suite", "EXPECTATIONS", "SUITE_FILE"]
