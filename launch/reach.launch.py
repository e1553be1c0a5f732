r"""The whole reaching graph: simulated robot and head sensors, mapping, marker localization,
planning and execution, each node with its parameter file from share/humanoid_reach_ros/config.

    ros2 launch humanoid_reach_ros reach.launch.py
    ros2 launch humanoid_reach_ros reach.launch.py scene:=/path/to/scene.yaml use_sim_sensors:=false

Arguments:
    scene              scene file of scene_sim (and of the planner's/executor's map until /voxel_map
                       arrives); default: the plant of the Kanehiro paper (config/scenes/plant.yaml)
    use_sim_sensors    start joint_driver and scene_sim (true) or use the real robot's drivers (false)
    enclave            SROS2 enclave of every node (e.g. /humanoid/robot), given to rcl as
                       ROS_SECURITY_ENCLAVE_OVERRIDE; empty (default): none. The ROS_SECURITY_*
                       variables of the shell (ENABLE, STRATEGY, KEYSTORE) pass through untouched
                       (docs/deployment.md)
    robot              the robot of every node (robot_config: a name of config/robots, e.g. talos or
                       g1, or a robot.yaml path); empty (default): the parameter files' (hrp2). A
                       robot too small for the plant names its own scene (robot.yaml demo_scene):
                       give it as scene:=, e.g. robot:=g1 scene:=<share>/config/robots/g1/plant.yaml
                       (hr_graph --robot g1 picks it by itself)
    plant              what joint_driver simulates: kinematic (default: joints where commanded, the
                       waist on the feet) or mujoco (a MuJoCo physics plant standing in the scene:=
                       file; servos, contacts, a measured floating base, /physics/metrics;
                       docs/physics.md)
    console            true: also start operator_console, the operator's console in a browser on
                       http://127.0.0.1:<console_port>/ (default 8765; docs/operator.md, docs/deployment.md)
    host               all (default), robot (driver, sensors, mapper, localizer, executor) or compute
                       (the planner): the graph across hosts (docs/deployment.md), e.g.
                       ros2 launch humanoid_reach_ros reach.launch.py host:=robot   # on the robot
                       ros2 launch humanoid_reach_ros reach.launch.py host:=compute # on the workstation

Then, from another shell, reach the valve the marker shows (see README):

    ros2 service call /plan_reach humanoid_reach_interfaces/srv/PlanReach \
        "{use_marker_target: true, execute: true, ...}"
    ros2 run humanoid_reach_ros reach_operator --marker --execute

(For ROS 2 installs that have `launch`; without it, `hr_graph` (`make up`) starts the same
processes with the same options: --scene FILE, --no-sim-sensors.)
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, SetEnvironmentVariable
from launch.conditions import IfCondition
from launch.substitutions import EnvironmentVariable, LaunchConfiguration, PythonExpression
from launch_ros.actions import Node

PACKAGE = "humanoid_reach_ros"
FASTDDS_PROFILES_ENV = "FASTRTPS_DEFAULT_PROFILES_FILE"
ENCLAVE_ENV = "ROS_SECURITY_ENCLAVE_OVERRIDE"   # rcl: the enclave of every node of the process
# (executable, started only with simulated sensors, the hosts that run it besides "all")
NODES = [
    ("joint_driver", True, ("robot",)),
    ("scene_sim", True, ("robot",)),
    ("voxel_mapper", False, ("robot",)),
    ("marker_localizer", False, ("robot",)),
    ("reach_planner", False, ("compute",)),
    ("reach_executor", False, ("robot",)),
]
HOSTS = ("all", "robot", "compute")


def generate_launch_description() -> LaunchDescription:
    config = os.path.join(get_package_share_directory(PACKAGE), "config")
    scene = LaunchConfiguration("scene")
    sim = LaunchConfiguration("use_sim_sensors")
    actions = [
        DeclareLaunchArgument("scene", default_value=os.path.join(config, "scenes", "plant.yaml"),
                              description="scene file (primitives, valve, marker)"),
        DeclareLaunchArgument("use_sim_sensors", default_value="true",
                              description="start the simulated joint driver and head sensors"),
        DeclareLaunchArgument("robot", default_value="",
                              description="robot_config of every node (a name of config/robots or a robot.yaml "
                                          "path); empty: the parameter files'"),
        DeclareLaunchArgument("plant", default_value="kinematic", choices=["kinematic", "mujoco"],
                              description="joint_driver's plant: kinematic or mujoco (physics, docs/physics.md)"),
        DeclareLaunchArgument("host", default_value="all", choices=list(HOSTS),
                              description="the nodes of one host: robot, compute (the planner) or all"),
        DeclareLaunchArgument("console", default_value="false", choices=["true", "false"],
                              description="also start operator_console, the operator's console in a browser"),
        DeclareLaunchArgument("console_port", default_value="8765",
                              description="operator_console's port (http://127.0.0.1:<port>/)"),
        DeclareLaunchArgument("enclave", default_value="",
                              description="SROS2 enclave of every node (ROS_SECURITY_ENCLAVE_OVERRIDE); empty: none"),
        SetEnvironmentVariable(ENCLAVE_ENV, LaunchConfiguration("enclave"), condition=IfCondition(
            PythonExpression(["'", LaunchConfiguration("enclave"), "' != ''"]))),
        # Fast DDS: an 8 MB shared-memory segment for the point clouds (config/fastdds.xml);
        # a profile the user already set is kept
        SetEnvironmentVariable(FASTDDS_PROFILES_ENV, EnvironmentVariable(
            FASTDDS_PROFILES_ENV, default_value=os.path.join(config, "fastdds.xml"))),
    ]
    host = LaunchConfiguration("host")
    robot = LaunchConfiguration("robot")
    for exe, sim_only, hosts in NODES:
        # started when host:= names one of its hosts (or all), and, for a simulated node, with use_sim_sensors
        here = ["'", host, f"' in {('all', *hosts)!r}"]
        started = here + [" and '", sim, "'.lower() in ('true', '1')"] if sim_only else here
        params = [os.path.join(config, f"{exe}.yaml")]
        if exe in ("scene_sim", "reach_planner", "reach_executor"):
            params.append({"scene_file": scene})
        if exe == "joint_driver":   # the physics plant stands in the scene the sensors render
            params.append({"plant": LaunchConfiguration("plant"), "physics_scene": scene})
        # one of two: with robot:= its robot_config overrides the parameter file's, without it the file's holds
        for named in (False, True):
            actions.append(Node(
                package=PACKAGE,
                executable=exe,
                name=exe,
                parameters=params + [{"robot_config": robot}] if named else params,
                output="screen",
                condition=IfCondition(PythonExpression(
                    started + [" and '", robot, "' " + ("!=" if named else "==") + " ''"])),
            ))
    # the operator's console (console:=true), on any host: it reaches the others through /plan_reach,
    # /execute_reach, /look and the topics, as reach_operator does (docs/operator.md)
    for named in (False, True):
        params = [os.path.join(config, "operator_console.yaml"), {"port": LaunchConfiguration("console_port")}]
        actions.append(Node(
            package=PACKAGE, executable="operator_console", name="operator_console",
            parameters=params + [{"robot_config": robot}] if named else params, output="screen",
            condition=IfCondition(PythonExpression(["'", LaunchConfiguration("console"), "' == 'true' and '", robot,
                                                    "' " + ("!=" if named else "==") + " ''"]))))
    return LaunchDescription(actions)
