"""tools/setup.sh and the package layout that `ros2 run` relies on."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from xml.etree import ElementTree

REPO = Path(__file__).resolve().parents[1]


def path_without(tmp_path: Path, missing: str) -> str:
    """A PATH holding every executable of the current PATH except ``missing``."""
    bindir = tmp_path / "bin"
    bindir.mkdir()
    for d in os.environ["PATH"].split(os.pathsep):
        if not os.path.isdir(d):
            continue
        for name in os.listdir(d):
            src = os.path.join(d, name)
            if name != missing and not (bindir / name).exists() and os.access(src, os.X_OK):
                (bindir / name).symlink_to(src)
    return str(bindir)


def test_setup_stops_with_one_line_reason_when_cmake_is_missing(tmp_path):
    env = dict(os.environ, PATH=path_without(tmp_path, "cmake"), PYTHON=sys._base_executable)
    proc = subprocess.run(["bash", str(REPO / "tools/setup.sh")], env=env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "cmake" in lines[0], proc.stderr


def test_setup_rejects_a_python_that_is_not_3_11(tmp_path):
    fake = tmp_path / "python3.9"
    fake.write_text("#!/bin/sh\nexit 1\n")
    fake.chmod(0o755)
    env = dict(os.environ, PYTHON=str(fake))
    proc = subprocess.run(["bash", str(REPO / "tools/setup.sh")], env=env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1 and "Python 3.11 is required" in proc.stderr, proc.stderr


def test_ament_layout_installed():
    """What `ros2 run humanoid_reach_ros joint_driver` needs on a real Jazzy install."""
    prefix = REPO / "install" / "humanoid_reach_ros"
    assert (prefix / "share/ament_index/resource_index/packages/humanoid_reach_ros").is_file()
    assert (prefix / "share/humanoid_reach_ros/package.xml").is_file()
    assert (prefix / "share/humanoid_reach_ros/config/robots/hrp2/hrp2.urdf").exists()
    exe = prefix / "lib/humanoid_reach_ros/joint_driver"
    assert exe.is_file() and os.access(exe, os.X_OK)
    iface = REPO / "install/humanoid_reach_interfaces/share/humanoid_reach_interfaces/srv/PlanReach.srv"
    assert iface.exists()


def test_package_xml_is_format_3_with_real_dependencies():
    root = ElementTree.parse(REPO / "package.xml").getroot()
    assert root.get("format") == "3"
    assert root.findtext("export/build_type") == "ament_python"
    deps = {e.text for e in root.iter("exec_depend")}
    assert {"rclpy", "humanoid_reach_interfaces", "sensor_msgs", "pinocchio"} <= deps
    email = root.find("maintainer").get("email")
    assert "@" in email and "." in email.split("@")[1]
