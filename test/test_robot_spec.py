"""The robot description (robot/spec.py): one file per robot, validated, and the only place
robot-specific names live: no string in the package's code names a joint or frame of a
robot description (or a robot), outside the loader."""
from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest
import yaml

from humanoid_reach_ros.paths import config_path
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.spec import load_robot_spec, robot_config_path, robots

PKG_DIR = Path(__file__).resolve().parents[1] / "humanoid_reach_ros"
LOADER = {PKG_DIR / "robot" / "spec.py", PKG_DIR / "robot" / "model.py"}
ROBOTS = robots()


def _code_strings(path: Path):
    """(line, text) of every string constant of a module that is not a docstring."""
    tree = ast.parse(path.read_text())
    docstrings = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                docstrings.add(id(first.value))
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings:
            yield node.lineno, node.value


def test_every_robot_loads_and_matches_its_urdf():
    assert "hrp2" in ROBOTS
    for name in ROBOTS:
        robot = RobotModel(name)
        assert robot.name and set(robot.hand_frames) == {"right", "left"} and len(robot.sole_frames) == 2
        for frame in (*robot.hand_frames.values(), *robot.sole_frames, robot.camera_frame, robot.base_link):
            robot.frame_id(frame)
        assert robot.spec.chest_link == robot.limbs["right_arm"].root
    assert RobotModel("robots/hrp2/robot.yaml").spec == RobotModel().spec


def test_no_robot_specific_name_outside_the_description_and_its_loader():
    names = set()
    for name in ROBOTS:
        names |= load_robot_spec(name)[0].names() | {name}
    hits = []
    for path in sorted(PKG_DIR.rglob("*.py")):
        if path in LOADER:
            continue
        for line, text in _code_strings(path):
            for n in names:
                if n in text:
                    hits.append(f"{path.relative_to(PKG_DIR.parent)}:{line}: {n!r} in {text[:60]!r}")
    assert not hits, "robot-specific names in code (take them from RobotModel / RobotSpec):\n" + "\n".join(hits)


def _write(tmp_path, edit) -> Path:
    doc = yaml.safe_load(robot_config_path("hrp2").read_text())
    edit(doc)
    d = tmp_path / "bot"
    d.mkdir(exist_ok=True)
    for f in robot_config_path("hrp2").parent.iterdir():   # the robot's files: URDF, collision, dual-arm data
        (d / f.name).write_bytes(f.read_bytes())
    (d / "robot.yaml").write_text(yaml.safe_dump(doc))
    return d / "robot.yaml"


@pytest.mark.parametrize("edit, text", [
    (lambda d: d.pop("head"), "missing key"),
    (lambda d: d.update(colour="red"), "unknown key"),
    (lambda d: d["limbs"].pop("left_arm"), "limbs must be exactly"),
    (lambda d: d["limbs"]["right_arm"]["joints"].pop(), "six|6 joint"),
    (lambda d: d["limbs"]["left_arm"].update(root="base_link"), "same \\(chest\\) link"),
    (lambda d: d.update(chest={"yaw": "CHEST_JOINT0"}), "chest must be"),
    (lambda d: d["chest"].update(tilt="CHEST_JOINT0"), "chest must be"),
    (lambda d: d["head"].pop("pitch"), "head names a neck yaw joint but no pitch joint"),
    (lambda d: d["head"].pop("yaw"), "head names a neck pitch joint but no yaw joint"),
    (lambda d: d["head"].pop("camera_frame"), "head must be \\{camera_frame\\}"),
    (lambda d: d["chest"].update(roll=d["chest"]["yaw"]), "named twice: \\['CHEST_JOINT0'\\]"),
    (lambda d: d["chest"].update(roll="RARM_JOINT6"), "\\['RARM_JOINT6'\\] are also limb or gripper joints"),
    (lambda d: d.update(sole_rectangle_m=[0.1, -0.1, -0.07, 0.07]), "sole_rectangle_m"),
    (lambda d: d["half_sitting"].update(RLEG_JOINT2=float("nan")), "half_sitting"),
    (lambda d: d.update(dual_arm_workspace=3), "dual_arm_workspace must be a YAML file"),
    (lambda d: d.update(dual_arm_workspace="torso_svr"), "dual_arm_workspace must be a YAML"),
    (lambda d: d.update(dual_arm_workspace="nope.yaml"), "dual_arm_workspace .*no such file"),
    (lambda d: d.update(dual_arm_workspace="torso_svr.yaml"),
     "not a dual-arm workspace file"),
])
def test_bad_descriptions_are_refused(tmp_path, edit, text):
    with pytest.raises(ValueError, match=text):
        load_robot_spec(_write(tmp_path, edit))


@pytest.mark.parametrize("edit, text", [
    (lambda d: d["head"].update(yaw="NECK_YAW"), "NECK_YAW"),
    (lambda d: d["limbs"]["right_arm"].update(tip="r_gripper_tip"), "r_gripper_tip"),
    (lambda d: d["chest"].update(roll="WAIST_ROLL"), "WAIST_ROLL"),
])
def test_names_the_urdf_lacks_are_refused(tmp_path, edit, text):
    with pytest.raises(ValueError, match=text):
        RobotModel(_write(tmp_path, edit))


def test_unknown_robot_names_the_robots_there_are():
    with pytest.raises(ValueError, match="hrp2"):
        RobotModel("nao")


def test_dual_arm_workspace_defaults_to_the_first_robots_and_is_per_robot(tmp_path):
    """A description without the key reads as before the key existed (HRP-2's file); Talos
    names its own."""
    doc_path = _write(tmp_path, lambda d: d.pop("dual_arm_workspace"))
    assert load_robot_spec(doc_path)[0].dual_arm_workspace == load_robot_spec("hrp2")[0].dual_arm_workspace
    assert config_path(load_robot_spec("hrp2")[0].dual_arm_workspace).is_file()
    if "talos" in ROBOTS:
        assert load_robot_spec("talos")[0].dual_arm_workspace != load_robot_spec("hrp2")[0].dual_arm_workspace


def test_the_demo_scene_is_the_plant_unless_the_robot_names_its_own(tmp_path):
    """``demo_scene`` (issue 23: a robot too small for the plant's valve names a scene made for
    its size): without the key, the plant; a name is read beside robot.yaml; a missing file or
    a value that is no YAML file name is refused at load, naming the key."""
    plant = str(config_path("scenes/plant.yaml"))
    assert load_robot_spec("hrp2")[0].demo_scene == plant
    doc_path = _write(tmp_path, lambda d: d.update(demo_scene="small_plant.yaml"))
    (doc_path.parent / "small_plant.yaml").write_bytes(Path(plant).read_bytes())
    assert load_robot_spec(doc_path)[0].demo_scene == str(doc_path.parent / "small_plant.yaml")
    for value, text in (("nowhere.yaml", "demo_scene 'nowhere.yaml': no such file"),
                        (3, "demo_scene must be a scene YAML file"), ("plant.txt", "demo_scene must be")):
        with pytest.raises(ValueError, match=text):
            load_robot_spec(_write(tmp_path, lambda d, v=value: d.update(demo_scene=v)))
    for name in ROBOTS:   # every shipped robot's demo scene exists
        assert Path(load_robot_spec(name)[0].demo_scene).is_file(), name


def test_dual_arm_files_are_read_beside_robot_yaml(tmp_path):
    """A robot's trained files live in its directory (issue 23 part 5): a copy of the directory
    elsewhere reads its own copies, not config/'s."""
    doc_path = _write(tmp_path, lambda d: None)
    spec = load_robot_spec(doc_path)[0]
    assert spec.dual_arm_workspace == str(doc_path.parent / "dual_arm_workspace.yaml")
    assert spec.torso_regression == str(doc_path.parent / "torso_svr")
    for name in ROBOTS:   # every shipped robot with a torso model keeps it beside its robot.yaml
        s = load_robot_spec(name)[0]
        assert s.torso_regression is None or s.torso_regression.startswith(str(s.path.parent) + "/"), name
        assert s.dual_arm_workspace.startswith(str(config_path("robots")) + "/"), name


def _neckless(doc) -> None:
    """HRP-2 without a neck: the head names the camera frame only (its joints stay in the URDF)."""
    doc["head"] = {"camera_frame": doc["head"]["camera_frame"]}


def test_a_robot_without_a_neck_loads_and_names_what_it_lacks(tmp_path):
    """Issue 23 (a neckless robot, e.g. Unitree G1): ``head: {camera_frame}`` is a description;
    the neck is empty, and what turns the head by its own angles says the robot has none."""
    from humanoid_reach_ros.robot.head_aim import aim_head_deg

    hrp2 = load_robot_spec("hrp2")[0]
    assert hrp2.has_neck and hrp2.neck_joints == hrp2.head_joints == (hrp2.head_yaw, hrp2.head_pitch)
    assert hrp2.torso_joints == hrp2.chest_joints and hrp2.chest_roll is None
    robot = RobotModel(_write(tmp_path, _neckless))
    spec = robot.spec
    assert not spec.has_neck and spec.neck_joints == () and spec.head_yaw is None and spec.head_pitch is None
    assert spec.camera_frame == hrp2.camera_frame and spec.chest_joints == hrp2.chest_joints
    assert spec.names() == hrp2.names() - set(hrp2.neck_joints)
    for call in (lambda: spec.head_joints, lambda: spec.require_neck("a look at head angles"),
                 lambda: aim_head_deg(robot, [1.0, 0.0, 1.0])):
        with pytest.raises(ValueError, match=re.escape(f"robot 'hrp2' has no neck: its description {spec.path} "
                                                       "names no head yaw and pitch joints")):
            call()
    with pytest.raises(ValueError, match="a look at head angles needs them"):
        spec.require_neck("a look at head angles")


def test_a_chest_roll_is_read_and_checked_against_the_urdf(tmp_path):
    """An optional ``chest.roll``: in ``torso_joints`` and the names, not in ``chest_joints``
    (yaw and pitch, what the reaching algorithms and the gaze move); checked against the URDF
    like every name (test_names_the_urdf_lacks_are_refused: a roll the URDF lacks). The joint
    freed by removing HRP-2's neck stands in for a roll (its axis is not checked)."""
    hrp2 = load_robot_spec("hrp2")[0]

    def edit(doc):
        _neckless(doc)
        doc["chest"]["roll"] = hrp2.head_yaw

    spec = RobotModel(_write(tmp_path, edit)).spec
    assert spec.chest_roll == hrp2.head_yaw
    assert spec.torso_joints == (*hrp2.chest_joints, hrp2.head_yaw) and spec.chest_joints == hrp2.chest_joints
    assert hrp2.head_yaw in spec.names()
