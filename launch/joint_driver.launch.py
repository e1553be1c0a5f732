"""Start the simulated HRP-2 joint driver with its parameter file.

    ros2 launch humanoid_reach_ros joint_driver.launch.py

(For ROS 2 installs that have `launch`; here use `make demo` or the executables.)
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch_ros.actions import Node


def generate_launch_description() -> LaunchDescription:
    share = get_package_share_directory("humanoid_reach_ros")
    return LaunchDescription([
        Node(
            package="humanoid_reach_ros",
            executable="joint_driver",
            name="joint_driver",
            parameters=[os.path.join(share, "config", "joint_driver.yaml")],
            output="screen",
        ),
    ])
