"""The launch files name real executables and parameter files (``launch`` itself is not installable
here, so they are checked statically: what ``ros2 launch`` would resolve must exist)."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest
import yaml

from nodetools import REPO_ROOT

LAUNCH_FILES = sorted((REPO_ROOT / "launch").glob("*.launch.py"))


def executables() -> dict[str, str]:
    tree = ast.parse((REPO_ROOT / "setup.py").read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "EXECUTABLES" for t in node.targets):
            return ast.literal_eval(node.value)
    raise AssertionError("setup.py has no EXECUTABLES dict")


def launched(path: Path) -> list[str]:
    """Executables a launch file starts: Node(executable="...") literals and the NODES table."""
    tree = ast.parse(path.read_text())
    names = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "Node":
            for kw in node.keywords:
                if kw.arg == "executable" and isinstance(kw.value, ast.Constant):
                    names.append(kw.value.value)
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "NODES" for t in node.targets):
            names += [row[0] for row in ast.literal_eval(node.value)]
    return names


def test_there_are_launch_files() -> None:
    assert {p.name for p in LAUNCH_FILES} >= {"reach.launch.py", "joint_driver.launch.py"}


@pytest.mark.parametrize("path", LAUNCH_FILES, ids=lambda p: p.name)
def test_launch_file_names_installed_executables_and_params(path: Path) -> None:
    compile(path.read_text(), str(path), "exec")
    exes = executables()
    names = launched(path)
    assert names, f"{path.name} starts nothing"
    for exe in names:
        assert exe in exes, f"{path.name}: {exe} is not an executable in setup.py"
        module = exes[exe].split(":")[0]
        assert (REPO_ROOT / (module.replace(".", "/") + ".py")).is_file(), module
        params = REPO_ROOT / "config" / f"{exe}.yaml"
        assert params.is_file(), f"{path.name}: {params} missing"
        doc = yaml.safe_load(params.read_text())
        assert "ros__parameters" in doc["/**"], params


def test_full_graph_launch_starts_the_design_nodes() -> None:
    names = launched(REPO_ROOT / "launch" / "reach.launch.py")
    assert set(names) == {"joint_driver", "scene_sim", "voxel_mapper", "marker_localizer", "reach_planner",
                          "operator_console",   # with console:=true only (test_the_launch_file_starts_the_console)
                          "reach_executor"}


def test_fastdds_profile_gives_large_messages_a_shared_memory_segment() -> None:
    """config/fastdds.xml parses and gives shared memory a segment larger than a point cloud;
    the graphs started here (graph_env) and reach.launch.py use it unless a profile is set."""
    import xml.etree.ElementTree as ET

    from humanoid_reach_ros.graph import FASTDDS_PROFILES, FASTDDS_PROFILES_ENV, graph_env

    ns = {"f": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}
    root = ET.parse(FASTDDS_PROFILES).getroot()
    shm = [d for d in root.iterfind("f:transport_descriptors/f:transport_descriptor", ns)
           if d.findtext("f:type", namespaces=ns) == "SHM"]
    assert len(shm) == 1 and int(shm[0].findtext("f:segment_size", namespaces=ns)) >= 4 * 2**20
    used = {t.text for t in root.iterfind("f:participant/f:rtps/f:userTransports/f:transport_id", ns)}
    declared = {d.findtext("f:transport_id", namespaces=ns)
                for d in root.iterfind("f:transport_descriptors/f:transport_descriptor", ns)}
    assert used == declared and len(used) == 2   # shared memory and UDPv4: the network still works
    assert graph_env(5, base={})[FASTDDS_PROFILES_ENV] == str(FASTDDS_PROFILES)
    assert graph_env(5, base={FASTDDS_PROFILES_ENV: "/mine.xml"})[FASTDDS_PROFILES_ENV] == "/mine.xml"
    launch = (REPO_ROOT / "launch" / "reach.launch.py").read_text()
    assert f'"{FASTDDS_PROFILES_ENV}"' in launch and '"fastdds.xml"' in launch



def test_the_launch_file_places_nodes_on_hosts_as_hr_graph_does() -> None:
    """reach.launch.py's host:= and hr_graph --host start the same nodes (graph.HOST_NODES);
    use_sim_sensors:=false leaves out the same ones (graph.SIM_NODES)."""
    from humanoid_reach_ros.graph import GRAPH_NODES, HOST_NODES, SIM_NODES, host_nodes

    tree = ast.parse((REPO_ROOT / "launch" / "reach.launch.py").read_text())
    table = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) in ("NODES", "HOSTS") for t in node.targets):
            table[node.targets[0].id] = ast.literal_eval(node.value)
    assert set(table["HOSTS"]) == set(HOST_NODES)
    for host in HOST_NODES:
        in_launch = tuple(exe for exe, _, hosts in table["NODES"] if host == "all" or host in hosts)
        assert in_launch == host_nodes(host), host
    assert {exe for exe, sim_only, _ in table["NODES"] if sim_only} == set(SIM_NODES)
    # every node on exactly one host; no host runs the simulated robot without its driver's host
    assert sorted(n for h, names in HOST_NODES.items() if h != "all" for n in names) == sorted(GRAPH_NODES)
    assert host_nodes("robot", sim_sensors=False) == ("voxel_mapper", "marker_localizer", "reach_executor")
    with pytest.raises(ValueError, match="host must be one of"):
        host_nodes("laptop")


def test_the_launch_file_takes_an_enclave_as_hr_graph_does() -> None:
    """reach.launch.py's enclave:= sets the variable hr_graph --enclave sets (graph.ENCLAVE_ENV),
    only when given; the ROS_SECURITY_* variables are never set by it (they pass through)."""
    from humanoid_reach_ros.graph import ENCLAVE_ENV

    text = (REPO_ROOT / "launch" / "reach.launch.py").read_text()
    tree = ast.parse(text)
    consts = {node.targets[0].id: ast.literal_eval(node.value) for node in ast.walk(tree)
              if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name)
              and isinstance(node.value, ast.Constant)}
    assert consts["ENCLAVE_ENV"] == ENCLAVE_ENV == "ROS_SECURITY_ENCLAVE_OVERRIDE"
    assert 'DeclareLaunchArgument("enclave", default_value=""' in text
    assert "SetEnvironmentVariable(ENCLAVE_ENV" in text and "' != ''\"" in text
    assert "ROS_SECURITY_ENABLE" not in text.split('"""', 2)[2]   # not set anywhere below the docstring


def _evaluate_reach_launch(args: dict[str, str]) -> list[tuple[str, list]]:
    """reach.launch.py run against a minimal stand-in of ``launch`` / ``launch_ros`` (not
    installable here): the (executable, parameters) of every Node whose condition holds for
    the launch arguments ``args`` (the declared defaults for the others), substitutions
    resolved. What ``ros2 launch`` would start, short of starting it."""
    import importlib.util
    import sys
    import types

    declared: dict[str, str] = {}

    class LaunchConfiguration:
        def __init__(self, name):
            self.name = name

    class EnvironmentVariable:
        def __init__(self, name, default_value=""):
            self.name, self.default_value = name, default_value

    def resolve(v):
        if isinstance(v, LaunchConfiguration):
            return args.get(v.name, declared.get(v.name, ""))
        if isinstance(v, PythonExpression):
            return str(eval("".join(str(resolve(x)) for x in v.parts)))   # noqa: S307 (our own launch file)
        if isinstance(v, dict):
            return {k: resolve(x) for k, x in v.items()}
        return v

    class PythonExpression:
        def __init__(self, parts):
            self.parts = parts

    class IfCondition:
        def __init__(self, expr):
            self.expr = expr

        def holds(self) -> bool:
            return str(resolve(self.expr)).lower() in ("true", "1")

    class DeclareLaunchArgument:
        def __init__(self, name, default_value="", **_kw):
            declared[name] = default_value

    class SetEnvironmentVariable:
        def __init__(self, *a, **kw):
            pass

    class Node:
        def __init__(self, executable, parameters, condition=None, **_kw):
            self.executable, self.parameters, self.condition = executable, parameters, condition

    class LaunchDescription(list):
        pass

    fakes = {
        "launch": types.SimpleNamespace(LaunchDescription=LaunchDescription),
        "launch.actions": types.SimpleNamespace(DeclareLaunchArgument=DeclareLaunchArgument,
                                                SetEnvironmentVariable=SetEnvironmentVariable),
        "launch.conditions": types.SimpleNamespace(IfCondition=IfCondition),
        "launch.substitutions": types.SimpleNamespace(EnvironmentVariable=EnvironmentVariable,
                                                      LaunchConfiguration=LaunchConfiguration,
                                                      PythonExpression=PythonExpression),
        "launch_ros": types.SimpleNamespace(),
        "launch_ros.actions": types.SimpleNamespace(Node=Node),
        "ament_index_python": types.SimpleNamespace(),
        "ament_index_python.packages": types.SimpleNamespace(
            get_package_share_directory=lambda _p: str(REPO_ROOT)),
    }
    saved = {k: sys.modules.get(k) for k in fakes}
    sys.modules.update(fakes)
    try:
        spec = importlib.util.spec_from_file_location("reach_launch", REPO_ROOT / "launch" / "reach.launch.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        actions = mod.generate_launch_description()
    finally:
        for k, v in saved.items():
            if v is None:
                sys.modules.pop(k, None)
            else:
                sys.modules[k] = v
    return [(a.executable, [resolve(p) for p in a.parameters]) for a in actions
            if isinstance(a, Node) and (a.condition is None or a.condition.holds())]


@pytest.mark.parametrize("robot", ["", "g1"])
@pytest.mark.parametrize("host, sim", [("all", "true"), ("robot", "true"), ("compute", "true"), ("all", "false")])
def test_the_launch_file_starts_each_node_once_with_the_robot_asked_for(robot, host, sim) -> None:
    """reach.launch.py evaluated (a stand-in for ``launch``): each node of the host once; with
    ``robot:=`` every node gets that ``robot_config`` on top of its parameter file, without it
    the file's holds (as hr_graph --robot); the scene reaches the nodes that take one."""
    from humanoid_reach_ros.graph import host_nodes

    started = _evaluate_reach_launch({"robot": robot, "host": host, "use_sim_sensors": sim})
    names = [exe for exe, _ in started]
    assert sorted(names) == sorted(host_nodes(host, sim_sensors=sim == "true")), (host, sim, names)
    for exe, params in started:
        files = [p for p in params if isinstance(p, str)]
        assert files == [str(REPO_ROOT / "config" / f"{exe}.yaml")] and Path(files[0]).is_file(), exe
        overrides = {k: v for p in params if isinstance(p, dict) for k, v in p.items()}
        assert overrides.get("robot_config") == (robot or None), (exe, overrides)
        if exe in ("scene_sim", "reach_planner", "reach_executor"):
            assert overrides["scene_file"].endswith("plant.yaml"), overrides


@pytest.mark.parametrize("plant", ["kinematic", "mujoco"])
def test_the_launch_file_gives_the_plant_to_the_joint_driver(plant) -> None:
    """reach.launch.py's plant:= reaches joint_driver alone, with the scene the sensors render as the
    physics plant's scene (as hr_graph --plant: graph.launch_params)."""
    from humanoid_reach_ros.graph import launch_params

    started = dict(_evaluate_reach_launch({"plant": plant}))
    overrides = {exe: {k: v for p in params if isinstance(p, dict) for k, v in p.items()}
                 for exe, params in started.items()}
    assert overrides["joint_driver"]["plant"] == plant
    assert overrides["joint_driver"]["physics_scene"] == overrides["scene_sim"]["scene_file"]
    assert all("plant" not in o for exe, o in overrides.items() if exe != "joint_driver")
    scene = overrides["scene_sim"]["scene_file"]
    assert launch_params("joint_driver", scene, None, plant) == {"plant": plant, "physics_scene": scene}
    assert "plant" not in launch_params("scene_sim", scene, None, plant)


@pytest.mark.parametrize("robot", ["", "talos"])
def test_the_launch_file_starts_the_console_when_asked(robot) -> None:
    """console:=true adds operator_console (once, its port and the robot asked for), as hr_graph --console."""
    assert "operator_console" not in dict(_evaluate_reach_launch({"robot": robot}))
    started = [(exe, p) for exe, p in _evaluate_reach_launch({"console": "true", "console_port": "9001",
                                                             "robot": robot}) if exe == "operator_console"]
    assert len(started) == 1, started
    overrides = {k: v for p in started[0][1] if isinstance(p, dict) for k, v in p.items()}
    assert overrides["port"] == "9001" and overrides.get("robot_config") == (robot or None), overrides
