"""``operator_console``: the operator's console in a browser, on ``http://<host>:<port>/``.

An adapter: topics in (``/joint_states`` and ``/head_camera/image_raw`` taken on demand when a
frame is due, ``LatestOnDemand``: no wake-up per message; ``/voxel_map``, ``/voxel_map/unobserved``, ``/target_pose``,
``/diagnostics``), the actions out through ``reach_operator``'s own client (:class:`Operator`:
``/plan_reach``, ``/execute_reach``, ``/look``). The console itself (server, controls, frames) is
``operator/console``; docs/operator.md, "The browser console".
"""
from __future__ import annotations

import sys
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.qos import qos_profile_sensor_data as sensor
from sensor_msgs.msg import Image, JointState, PointCloud2

from humanoid_reach_ros.io import msgs
from humanoid_reach_ros.io.endpoints import LATCHED, LatestOnDemand
from humanoid_reach_ros.nodes.common import declare_parameters, run_node
from humanoid_reach_ros.nodes.reach_operator import Operator, plan_request
from humanoid_reach_ros.operator.console.control import ConsoleControl
from humanoid_reach_ros.operator.console.server import (
    ConsoleConfig, ConsoleFeed, ConsoleServer, marker_detector)
from humanoid_reach_ros.operator.console.views import RobotView, VoxelLayer
from humanoid_reach_ros.params import ParamSpec
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.shapes import load_collision_model
from humanoid_reach_ros.robot.spec import DEFAULT_ROBOT

PARAMETERS = {
    "host": ParamSpec("127.0.0.1", "address to serve on: 127.0.0.1 (default) keeps the console on this machine "
                      "(docs/deployment.md: an SSH tunnel from the workstation)"),
    "port": ParamSpec(8765, "TCP port of the page and its WebSocket", (1, 65535)),
    "robot_config": ParamSpec(DEFAULT_ROBOT, "robot: a name (config/robots/<name>/robot.yaml) or a robot.yaml path"),
    "update_period_s": ParamSpec(0.1, "period of the updates to the pages [s]: the robot when a capsule moved, "
                                 "the status when it changed", (0.02, 5.0)),
    "map_period_s": ParamSpec(1.0, "the voxel layers' changes go out at most this often [s]", (0.1, 60.0)),
    "image_period_s": ParamSpec(0.5, "a new camera image goes out at most this often [s]", (0.05, 60.0)),
    "image_quality": ParamSpec(60, "JPEG quality of the camera image", (10, 95)),
    "image_max_width": ParamSpec(480, "the camera image is scaled down to this width [px]", (64, 4096)),
    "robot_move_threshold_m": ParamSpec(0.002, "the robot goes out when a capsule end moved this far [m]",
                                        (0.0, 0.1)),
    "voxel_resolution_m": ParamSpec(0.02, "voxel size of the layers as drawn [m] (the voxel mapper's "
                                    "resolution_m)", (0.001, 1.0)),
    "target_map_distance_m": ParamSpec(0.06, "a clicked target or look point must lie this close to an occupied "
                                       "voxel [m]", (0.0, 1.0)),
    "scan_dwell_s": ParamSpec(0.0, "Scan: hold each head pose this long [s] (reach_operator --dwell); 0.0: the "
                              "executor's", (0.0, 10.0)),
    "plan_budget_s": ParamSpec(0.0, "Plan and Home: the planning time budget [s] (reach_operator --budget); 0.0: "
                               "the planner's", (0.0, 600.0)),
    "ghost_frames": ParamSpec(40, "postures of the plan's preview (ghost)", (2, 400)),
    "marker_dictionary": ParamSpec("DICT_4X4_50", "ArUco dictionary of the markers outlined in the image (the "
                                   "marker localizer's)"),
    "timeout_s": ParamSpec(60.0, "wait at most this long for each server (reach_operator --timeout) [s]",
                           (1.0, 600.0)),
    "three_js_dir": ParamSpec("", "three.js (its build/ and examples/jsm/); empty: node_modules/three of the "
                              "checkout (make setup)"),
}


class _ErrLog:
    """The client's stderr lines (waiting for a server ...) as the node's warnings."""

    def __init__(self, node: Node) -> None:
        self.node = node

    def write(self, s: str) -> int:
        if s.strip():
            self.node.get_logger().warning(s.strip())
        return len(s)

    def flush(self) -> None:
        pass


class OperatorConsole(Node):
    def __init__(self, **kwargs: Any) -> None:
        super().__init__("operator_console", **kwargs)
        p = declare_parameters(self, PARAMETERS)
        model = RobotModel(p["robot_config"])
        self.model = model
        robot = RobotView(model, load_collision_model(None, model), p["robot_move_threshold_m"])
        self.detector = marker_detector(p["marker_dictionary"])
        self.feed = ConsoleFeed(VoxelLayer("occupied", p["voxel_resolution_m"]),
                                VoxelLayer("unobserved", p["voxel_resolution_m"]))
        self.client = Operator(p["timeout_s"], _ErrLog(self), init=False)
        config = ConsoleConfig(p["host"], p["port"], p["update_period_s"], p["map_period_s"], p["image_period_s"],
                               p["image_quality"], p["image_max_width"], p["three_js_dir"])
        log = self.get_logger().info
        self.server: ConsoleServer | None = None
        control = ConsoleControl(
            self.client, plan_request, self.feed.current_joints, self.feed.map_distance,
            lambda traj, start: robot.ghost(traj, start, p["ghost_frames"]),
            lambda m, to: self.server.emit(m, to), lambda f: self.server.emit_frame(f),
            p["target_map_distance_m"], log, p["scan_dwell_s"], p["plan_budget_s"])
        self.server = ConsoleServer(config, self.feed, robot, control, log, detector=self.detector)
        latest = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)
        self.joint_states = LatestOnDemand(self, JointState, "joint_states", latest)
        self.images = LatestOnDemand(self, Image, "head_camera/image_raw", latest)
        self._joints: tuple[Any, Any] = (None, None)    # (message, its joints): converted once
        self._image_msg: Any = None
        self.feed.joints, self.feed.image = self._latest_joints, self._latest_image
        for topic, layer in (("voxel_map", "occupied"), ("voxel_map/unobserved", "unobserved")):
            self.create_subscription(PointCloud2, topic, lambda m, a=layer: self._on_layer(a, m), LATCHED)
        self.create_subscription(PoseStamped, "target_pose", self._on_target, sensor)
        self.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 20)
        url = self.server.start()
        log(f"operator console ready: open {url} (robot {model.name}; docs/operator.md: the browser console)")

    def _latest_joints(self):
        msg = self.joint_states.latest()
        if msg is not None and msg is not self._joints[0]:
            j, why = msgs.model_joints(msg, self.model)
            if j is None:
                self.get_logger().warning(f"/joint_states refused: {why}", throttle_duration_sec=10.0)
            self._joints = (msg, j)
        return self._joints[1]

    def _latest_image(self):
        msg = self.images.latest()
        if msg is None or msg is self._image_msg:
            return None
        self._image_msg = msg
        try:
            return msgs.gray_from_image(msg)
        except ValueError as exc:
            self.get_logger().warning(f"camera image refused: {exc}", throttle_duration_sec=10.0)
            return None

    def _on_layer(self, layer: str, msg: PointCloud2) -> None:
        try:
            self.feed.set_layer(layer, msgs.points_from_cloud(msg).points)
        except ValueError as exc:
            self.get_logger().warning(f"{layer} voxels refused: {exc}", throttle_duration_sec=10.0)

    def _on_target(self, msg: PoseStamped) -> None:
        p = msg.pose.position
        self.feed.set_status(marker_target=[round(p.x, 3), round(p.y, 3), round(p.z, 3)],
                             marker_stamp_s=msgs.seconds_from_time(msg.header.stamp))

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for st in msg.status:
            v = msgs.diagnostic_values(st)
            if st.name.endswith(": execution"):
                self.feed.set_status(executor=v.get("state", "?"), executor_message=st.message)
            elif st.name.endswith(": loop") and "overruns_total" in v:
                self.feed.set_status(overruns_total=_int(v["overruns_total"]))

    def destroy_node(self) -> None:
        if self.server is not None:
            self.server.stop()
        self.client.interrupted = True
        self.client.close()
        self.joint_states.destroy()
        self.images.destroy()
        super().destroy_node()


def _int(text: str) -> int | None:
    try:
        return int(float(text))
    except ValueError:
        return None


def main(args: list[str] | None = None) -> int:
    return run_node(OperatorConsole, "operator_console", args)


if __name__ == "__main__":
    sys.exit(main())
