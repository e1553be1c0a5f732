"""ament_python package humanoid_reach_ros (see package.xml)."""
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = "humanoid_reach_ros"


def tree(src: str) -> list[tuple[str, list[str]]]:
    """data_files entries installing every file under ``src`` into share/<pkg>/<src>/..."""
    out: dict[str, list[str]] = {}
    for f in sorted(Path(src).rglob("*")):
        if f.is_file():
            out.setdefault(f"share/{PACKAGE}/{f.parent.as_posix()}", []).append(f.as_posix())
    return sorted(out.items())


# One executable per node / tool: `ros2 run humanoid_reach_ros <name>`.
EXECUTABLES = {
    "joint_driver": "humanoid_reach_ros.nodes.joint_driver:main",
    "reach_planner": "humanoid_reach_ros.nodes.reach_planner:main",
    "reach_executor": "humanoid_reach_ros.nodes.reach_executor:main",
    "scene_sim": "humanoid_reach_ros.nodes.scene_sim:main",
    "voxel_mapper": "humanoid_reach_ros.nodes.voxel_mapper:main",
    "marker_localizer": "humanoid_reach_ros.nodes.marker_localizer:main",
    "reach_operator": "humanoid_reach_ros.nodes.reach_operator:main",
    "operator_console": "humanoid_reach_ros.nodes.operator_console:main",   # the console in a browser
    "hr_record": "humanoid_reach_ros.nodes.bag_record:main",
    "hr_play": "humanoid_reach_ros.nodes.bag_play:main",
    "hr_demo": "humanoid_reach_ros.demo:main",
    "hr_graph": "humanoid_reach_ros.graph_up:main",   # the whole graph until Ctrl-C (where `ros2 launch` is absent)
}

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*"]),
    package_data={PACKAGE: ["operator/console/static/*"]},   # the console's page (three.js: npm, make setup)
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", glob("launch/*.py")),
        *tree("config"),
    ],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="humanoid_reach_ros developers",
    maintainer_email="humanoid-reach@example.com",
    description="Reaching-motion planning and execution for an HRP-2-class humanoid (ROS 2 Jazzy).",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={"console_scripts": [f"{k} = {v}" for k, v in EXECUTABLES.items()]},
)
