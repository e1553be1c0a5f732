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
