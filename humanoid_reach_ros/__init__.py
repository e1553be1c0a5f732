"""humanoid_reach_ros: reaching-motion planning and execution for an HRP-2-class humanoid.

Algorithm modules (robot, geometry, planning, control, perception, reach, sim, io)
never import rclpy; the thin ROS 2 nodes live in ``humanoid_reach_ros.nodes``.
"""

__version__ = "0.1.0"
