"""``joint_driver``: the simulated HRP-2 joint driver.

Subscribes ``/joint_command`` (sensor_msgs/JointState, by joint name, any subset of
the 30 joints; from publishers on this host only, ``command_source`` host, the default: a
participant of its own with localhost discovery, ``io/host_local.py``) and every
``period_s`` (5 ms) steps ``JointSimulator`` and publishes

* ``/joint_states``  sensor_msgs/JointState, all 30 joints, position + velocity;
* ``/base_pose``     geometry_msgs/PoseStamped, waist pose in ``world`` by kinematic
  odometry (right foot fixed on the floor, see ``humanoid_reach_ros.sim.joint_sim``);
  with ``plant: mujoco`` the joints and the base are those a MuJoCo plant measures
  (``humanoid_reach_ros.sim.physics``: the kinematic simulator's joints are its servos'
  targets), ``/diagnostics`` carries a ``physics`` status (CoP, margin, slip, tilt, fall) and
  ``/physics/metrics`` (msg/PlantMetrics, every ``physics_metrics_period_s``) the same figures typed,
  with their worst since start;
* ``/robot_description`` std_msgs/String, the URDF (with the robot description's added frames as
  fixed links), once, transient local (depth 1);
* ``/diagnostics``   diagnostic_msgs/DiagnosticArray every ``diagnostics_period_s``:
  command rejections (with the last reason), stale commands, target clipping,
  loop timing (achieved rate, overruns), left-foot slip.

Bad commands (unknown names, NaN/inf, mismatched array lengths, empty, duplicates)
are rejected with a throttled warning; the last good command is held. When no
command arrives for ``command_timeout_s`` the joints stop where they are.

Run: ``python -m humanoid_reach_ros.nodes.joint_driver --ros-args --params-file
config/joint_driver.yaml`` (``ros2 run humanoid_reach_ros joint_driver`` on an install).
"""
from __future__ import annotations

import sys
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from humanoid_reach_ros.execution.periodic import PeriodicLoop
from humanoid_reach_ros.execution.realtime import (REALTIME_SWITCH_INTERVAL_S, make_feeder_thread_realtime,
                                                   make_thread_realtime)
from humanoid_reach_ros.io import msgs
from humanoid_reach_ros.io.gil_free import GilFreePublisher
from humanoid_reach_ros.io.host_local import HostLocalSubscription
from humanoid_reach_ros.io.endpoints import LATCHED
from humanoid_reach_ros.nodes.common import declare_parameters, run_node
from humanoid_reach_ros.params import ParamSpec
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.spec import DEFAULT_ROBOT
from humanoid_reach_ros.sim.driver import POSTURES, SimulatedDriver
from humanoid_reach_ros.sim.joint_sim import MAX_BUFFERED_COMMANDS
from humanoid_reach_ros.sim.physics import PLANTS, check_plant

NODE_NAME = "joint_driver"
COMMAND_SOURCES = ("host", "any")


# Defaults match config/joint_driver.yaml (checked by test_joint_driver_node).
PARAMETERS: dict[str, ParamSpec] = {
    "period_s": ParamSpec(0.005, "control loop period [s] (200 Hz)", (0.0005, 1.0)),
    "plant": ParamSpec("kinematic", "what the commands move: kinematic (joints placed where commanded, the waist "
                       "on the feet) or mujoco (a MuJoCo physics plant: servos, contacts, a measured floating base; "
                       "docs/physics.md)", constraints=f"one of {', '.join(PLANTS)}"),
    "physics_metrics_period_s": ParamSpec(0.02, "with plant mujoco: period of /physics/metrics (msg/PlantMetrics: "
                                          "CoP, margin, slip, tilt, hand forces, fall; its worst fields since start)",
                                          (0.005, 60.0)),
    "physics_scene": ParamSpec("", "scene the mujoco plant stands in (relative to config/ or absolute); empty: the "
                               "robot description's demo scene"),
    "initial_posture": ParamSpec("half_sitting", "posture at start", constraints=f"one of {', '.join(POSTURES)}"),
    "robot_config": ParamSpec(DEFAULT_ROBOT, "robot: a name (config/robots/<name>/robot.yaml) or the path of "
                                          "a robot description (relative to config/, or absolute)"),
    "velocity_scale": ParamSpec(1.0, "fraction of each joint's velocity limit used as the hard bound",
                                (0.01, 1.0), read_only=False),
    "tracking_time_constant_s": ParamSpec(0.01, "first-order position tracking time constant [s]; "
                                          "0 = rate limit only", (0.0, 10.0), read_only=False),
    "command_timeout_s": ParamSpec(0.5, "no command for this long [s] -> stale: hold the current position",
                                   (0.001, 3600.0), read_only=False),
    "stopped_short_warn_rad": ParamSpec(1e-4, "diagnostics WARN when a stale command leaves a joint this far "
                                        "from its target [rad]", (0.0, 10.0)),
    "warn_throttle_s": ParamSpec(1.0, "minimum interval between repeated warnings [s]", (0.0, 3600.0)),
    "diagnostics_period_s": ParamSpec(1.0, "period of /diagnostics [s]", (0.05, 60.0)),
    "overrun_factor": ParamSpec(1.5, "a loop period longer than this times period_s counts as an overrun",
                                (1.0, 100.0)),
    "min_rate_fraction": ParamSpec(0.9, "diagnostics WARN when the achieved rate is below this fraction of "
                                   "1/period_s", (0.0, 1.0)),
    "max_overrun_fraction": ParamSpec(0.02, "diagnostics WARN when more than this fraction of loop periods "
                                      "overran", (0.0, 1.0)),
    "left_foot_slip_warn_m": ParamSpec(0.005, "diagnostics WARN when the left sole is this far from its stance "
                                       "pose [m]", (0.0, 10.0)),
    "rt_priority": ParamSpec(70, "SCHED_FIFO priority of the 200 Hz loop thread where the OS allows it (the "
                             "simulated hardware loop); 0 = normal scheduling"),
    "world_frame_id": ParamSpec("world", "frame of /base_pose (the stance frame on the floor)"),
    "base_frame_id": ParamSpec("base_link", "frame whose pose /base_pose carries (the waist)"),
    "command_source": ParamSpec("host", "who may publish joint_command: host (publishers on this host only: a "
                                "participant of its own with localhost discovery, docs/deployment.md) or any",
                                constraints=f"one of {', '.join(COMMAND_SOURCES)}"),
}


class JointDriver(Node):
    """Thin node around ``SimulatedDriver`` (sim/driver.py): messages, parameters, the loop thread."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = declare_parameters(self, PARAMETERS)
        self.period_s: float = p["period_s"]
        self.warn_throttle_s: float = p["warn_throttle_s"]
        self.world_frame_id: str = p["world_frame_id"]
        self._p = p

        self.model = RobotModel(p["robot_config"])
        posture = p["initial_posture"]
        self.core = SimulatedDriver(
            self.model, posture, period_s=self.period_s, velocity_scale=p["velocity_scale"],
            time_constant_s=p["tracking_time_constant_s"], command_timeout_s=p["command_timeout_s"],
            stopped_short_warn_rad=p["stopped_short_warn_rad"], overrun_factor=p["overrun_factor"],
            min_rate_fraction=p["min_rate_fraction"], max_overrun_fraction=p["max_overrun_fraction"],
            left_foot_slip_warn_m=p["left_foot_slip_warn_m"])
        self.sim = self.core.sim
        self.hardware_id = self.model.name
        self.physics = None
        if check_plant(p["plant"]) == "mujoco":
            from humanoid_reach_ros.sim.physics.driver import PhysicsDriver   # imports mujoco only when used

            self.physics = PhysicsDriver(self.model, self.sim.q, p["physics_scene"] or None)

        reliable10 = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.joint_states_pub = self.create_publisher(JointState, "joint_states", reliable10)
        self.base_pose_pub = self.create_publisher(PoseStamped, "base_pose", reliable10)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", reliable10)
        self.description_pub = self.create_publisher(String, "robot_description", LATCHED)
        # the loop's two writes release the interpreter lock (io/gil_free.py): one that blocks in DDS
        # no longer stops the thread that takes /joint_command
        self._joint_states_out = GilFreePublisher(self.joint_states_pub)
        self._base_pose_out = GilFreePublisher(self.base_pose_pub)
        # a command history of a second: a loop that stood still (a DDS write held it 333 ms, and the
        # interpreter lock with it) finds every command since, and plays them through in order
        # (JointSimulator's burst) rather than cutting across the ones a 10-deep history lost
        # (bench/session: 0.96 mm between the soles)
        commands = QoSProfile(depth=MAX_BUFFERED_COMMANDS, reliability=ReliabilityPolicy.RELIABLE)
        # command_source host: only this host's publishers reach the subscription (across hosts, a stray
        # publisher on the operator's network must not move the robot); its thread takes the callbacks
        if p["command_source"] not in COMMAND_SOURCES:
            raise ValueError(f"command_source must be one of {', '.join(COMMAND_SOURCES)}, got "
                             f"{p['command_source']!r}")
        self._host_local: HostLocalSubscription | None = None
        if p["command_source"] == "host":
            rt = p["rt_priority"]
            self._host_local = HostLocalSubscription(
                self, JointState, "joint_command", self._on_command, commands,
                thread_setup=(lambda: make_feeder_thread_realtime(rt)) if rt > 0 else None)
            self.command_sub = self._host_local.subscription
        else:
            self.command_sub = self.create_subscription(JointState, "joint_command", self._on_command, commands)

        # Pre-built outgoing message: only arrays and stamp change per tick.
        self._joint_state = msgs.joint_state(self.sim.joint_names, self.sim.q, self.sim.dq)

        self._pose_msg: PoseStamped | None = None
        self._pose_key = b""

        self.description_pub.publish(String(data=self.model.description_xml))
        self.plant_metrics_pub = None
        self._fall_logged = False
        if self.physics is not None:
            from humanoid_reach_interfaces.msg import PlantMetrics

            self.plant_metrics_pub = self.create_publisher(PlantMetrics, "physics/metrics", reliable10)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        # the 200 Hz loop runs in a thread of its own at absolute deadlines: an executor wake-up per tick
        # (wait set, callback dispatch) cost more than the tick itself
        self._stop = threading.Event()
        self._periodic = PeriodicLoop(self.period_s, lambda _due: self._tick(), on_error=self._tick_failed,
                                      stop_event=self._stop, first_tick_now=False)
        self._loop = threading.Thread(target=self._run_loop, name="joint_driver_loop", daemon=True)
        self._loop.start()
        # the thread that spins (command callbacks) shares the interpreter lock with the loop: at
        # normal priority a busy machine could deschedule it while it holds the lock and stall the
        # 200 Hz loop behind it; it runs SCHED_FIFO well below the loop where allowed, and the lock
        # is handed over every 0.5 ms
        if self._p["rt_priority"] > 0:
            make_feeder_thread_realtime(self._p["rt_priority"])
            sys.setswitchinterval(REALTIME_SWITCH_INTERVAL_S)
        self.diagnostics_timer = self.create_timer(p["diagnostics_period_s"], self._publish_diagnostics, clock=steady)
        if self.plant_metrics_pub is not None:
            self.create_timer(p["physics_metrics_period_s"], self._publish_plant_metrics, clock=steady)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.get_logger().info(
            f"simulated {self.hardware_id}: {self.model.n_joints} joints at {1.0 / self.period_s:.0f} Hz "
            f"(period {self.period_s * 1e3:.1f} ms), {p['plant']} plant, initial posture {posture!r}, velocity scale "
            f"{self.sim.velocity_scale:g}, tracking tau {self.sim.time_constant_s * 1e3:.1f} ms, "
            f"command timeout {self.core.command_timeout_s:g} s; publishing joint_states, base_pose, "
            f"robot_description, /diagnostics (the loop's writes {self._joint_states_out.mode}); listening on "
            f"{self.command_sub.topic_name} ("
            + ("publishers on this host only" if self._host_local else "any publisher: command_source any") + ")"
        )

    # ------------------------------------------------------------ callbacks
    def _run_loop(self) -> None:
        # the simulated hardware loop: real-time priority where the OS allows (one warning otherwise)
        ok, text = make_thread_realtime(self._p["rt_priority"])
        if self._p["rt_priority"] > 0 and not ok:
            self.get_logger().warning(f"joint loop without real-time priority: {text}")
        self._periodic.run()

    def _tick_failed(self, exc: Exception) -> None:
        if not self.context.ok():       # publishing while Ctrl-C shuts the context down
            self._stop.set()
            return
        self.get_logger().error(f"tick failed: {type(exc).__name__}: {exc}", throttle_duration_sec=self.warn_throttle_s)

    def destroy_node(self) -> None:
        self._stop.set()
        if self._loop.is_alive():
            self._loop.join(2.0)
        if self._host_local is not None:
            self._host_local.close()
        super().destroy_node()

    def _on_command(self, msg: JointState) -> None:
        cmd = msgs.parse_joint_state(msg)
        result, resumed = self.core.command(cmd.names, cmd.positions, cmd.velocities)
        if not result.accepted:
            self.get_logger().warning(
                f"rejected joint_command ({self.sim.rejected_count} so far): {result.reason}; "
                "holding the last good command",
                throttle_duration_sec=self.warn_throttle_s,
            )
            return
        if resumed:
            self.get_logger().info("joint_command resumed")
        if result.clipped:
            self.get_logger().warning(
                f"clipped targets into position limits: {', '.join(result.clipped)}",
                throttle_duration_sec=self.warn_throttle_s,
            )

    def _tick(self) -> None:
        core = self.core
        t, dt, notice = core.begin_tick()
        if notice is not None:
            warn, text = notice
            (self.get_logger().warning if warn else self.get_logger().info)(text)
        if self.physics is not None:
            self._tick_physics(dt)
            core.end_tick(t)
            return
        with core.lock:
            self.sim.step(dt)
            stamp = self.get_clock().now().to_msg()
            js = msgs.fill_joint_state(self._joint_state, self.sim.q, self.sim.dq, stamp)
            odom = self.sim.odometry()
        self._joint_states_out.publish(js)
        if self._pose_msg is None or self._pose_key != odom.base.translation.tobytes() + odom.base.rotation.tobytes():
            self._pose_msg = msgs.pose_stamped(odom.base, self.world_frame_id, stamp)   # standing still: reused
            self._pose_key = odom.base.translation.tobytes() + odom.base.rotation.tobytes()
        self._pose_msg.header.stamp = stamp
        self._base_pose_out.publish(self._pose_msg)
        core.end_tick(t)

    def _tick_physics(self, dt: float) -> None:
        """One tick on the mujoco plant: the kinematic simulator's joints are the servos' targets."""
        with self.core.lock:
            self.sim.step(dt)
            targets = self.sim.q.copy()
        q, dq, base = self.physics.step(targets, dt)
        stamp = self.get_clock().now().to_msg()
        self._joint_states_out.publish(msgs.fill_joint_state(self._joint_state, q, dq, stamp))
        self._base_pose_out.publish(msgs.pose_stamped(base, self.world_frame_id, stamp))

    def _publish_plant_metrics(self) -> None:
        snap = self.physics.snapshot()
        if snap.fall_reason and not self._fall_logged:      # once: when, and why
            self._fall_logged = True
            self.get_logger().error(f"the robot fell at {snap.sim_time_s:.2f} s of simulated time: {snap.fall_reason}")
        self.plant_metrics_pub.publish(msgs.plant_metrics(snap, self.world_frame_id, self.get_clock().now().to_msg()))

    def _publish_diagnostics(self) -> None:
        now = time.monotonic()
        self.diagnostics_pub.publish(msgs.diagnostic_array(self.diagnostic_statuses(now),
                                                           self.get_clock().now().to_msg()))

    def diagnostic_statuses(self, now: float) -> list:
        """The statuses of one /diagnostics message (``SimulatedDriver.statuses``); resets the timing window."""
        name = self.get_name()
        statuses = self.core.statuses(now, self.world_frame_id, self._p["base_frame_id"])
        if self.physics is not None:
            statuses += self.physics.statuses()
        return [msgs.diagnostic_status(f"{name}: {suffix}", level, message, values, self.hardware_id)
                for suffix, level, message, values in statuses]

    # ------------------------------------------------------------ parameters
    def _apply_parameters(self, params: list[Parameter]) -> None:
        """Apply run-time changes of the writable parameters (ranges checked by their descriptors)."""
        for prm in params:
            if prm.name == "velocity_scale":
                self.sim.velocity_scale = prm.value
            elif prm.name == "tracking_time_constant_s":
                self.sim.time_constant_s = prm.value
            elif prm.name == "command_timeout_s":
                self.core.command_timeout_s = prm.value
            self._p[prm.name] = prm.value


def main(args: list[str] | None = None) -> int:
    """Run the node until Ctrl-C / SIGTERM (exit 0); a configuration error exits 2."""
    return run_node(JointDriver, NODE_NAME, args)


if __name__ == "__main__":
    sys.exit(main())
