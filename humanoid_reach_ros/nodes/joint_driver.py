"""``joint_driver``: the simulated HRP-2 joint driver.

Subscribes ``/joint_command`` (sensor_msgs/JointState, by joint name, any subset of
the 30 joints; from publishers on this host only, ``command_source`` host, the default: a
participant of its own with localhost discovery, ``io/host_local.py``) and every
``period_s`` (5 ms) steps ``JointSimulator`` and publishes

* ``/joint_states``  sensor_msgs/JointState, all 30 joints, position + velocity;
* ``/base_pose``     geometry_msgs/PoseStamped, waist pose in ``world`` by kinematic
  odometry (right foot fixed on the floor, see ``humanoid_reach_ros.sim.joint_sim``);
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

import math
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
from humanoid_reach_ros.nodes.common import LATCHED, ParamSpec, declare_parameters, run_node
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.spec import DEFAULT_ROBOT
from humanoid_reach_ros.sim.joint_sim import MAX_BUFFERED_COMMANDS, JointSimulator

NODE_NAME = "joint_driver"
POSTURES = ("half_sitting", "zero")
COMMAND_SOURCES = ("host", "any")


# Defaults match config/joint_driver.yaml (checked by test_joint_driver_node).
PARAMETERS: dict[str, ParamSpec] = {
    "period_s": ParamSpec(0.005, "control loop period [s] (200 Hz)", (0.0005, 1.0)),
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
    """Thin node around ``JointSimulator``: conversions, timing and diagnostics only."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = declare_parameters(self, PARAMETERS)
        self.period_s: float = p["period_s"]
        self.command_timeout_s: float = p["command_timeout_s"]
        self.warn_throttle_s: float = p["warn_throttle_s"]
        self.world_frame_id: str = p["world_frame_id"]
        self.overrun_factor: float = p["overrun_factor"]
        self._p = p

        self.model = RobotModel(p["robot_config"])
        posture = p["initial_posture"]
        if posture == "half_sitting":
            initial = self.model.half_sitting_joints
        elif posture == "zero":
            initial = [0.0] * self.model.n_joints
        else:
            raise ValueError(f"initial_posture must be one of {POSTURES}, got {posture!r}")
        self.sim = JointSimulator(self.model, initial, p["velocity_scale"], p["tracking_time_constant_s"])
        self.hardware_id = self.model.name

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

        # loop statistics: totals and the current diagnostics window
        self._last_tick: float | None = None
        self.ticks = 0
        self.overruns = 0
        self._window = self._new_window()
        self._stale = False
        self._stopped_short_rad = 0.0  # how far from its target the joint furthest off was when going stale
        self._rejected_reported = 0
        self._clip_events_reported = 0
        self._pose_msg: PoseStamped | None = None
        self._pose_key = b""

        self.description_pub.publish(String(data=self.model.description_xml))
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        # the 200 Hz loop runs in a thread of its own at absolute deadlines: an executor wake-up per tick
        # (wait set, callback dispatch) cost more than the tick itself
        self._lock = threading.Lock()        # the simulator: command callback vs loop thread
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
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.get_logger().info(
            f"simulated {self.hardware_id}: {self.model.n_joints} joints at {1.0 / self.period_s:.0f} Hz "
            f"(period {self.period_s * 1e3:.1f} ms), initial posture {posture!r}, velocity scale "
            f"{self.sim.velocity_scale:g}, tracking tau {self.sim.time_constant_s * 1e3:.1f} ms, "
            f"command timeout {self.command_timeout_s:g} s; publishing joint_states, base_pose, "
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
        with self._lock:
            result = self.sim.set_command(cmd.names, cmd.positions, cmd.velocities, now=time.monotonic())
        if not result.accepted:
            self.get_logger().warning(
                f"rejected joint_command ({self.sim.rejected_count} so far): {result.reason}; "
                "holding the last good command",
                throttle_duration_sec=self.warn_throttle_s,
            )
            return
        if self._stale:
            self.get_logger().info("joint_command resumed")
            self._stale = False
        if result.clipped:
            self.get_logger().warning(
                f"clipped targets into position limits: {', '.join(result.clipped)}",
                throttle_duration_sec=self.warn_throttle_s,
            )

    def _tick(self) -> None:
        t = time.monotonic()
        if self._last_tick is None:
            dt = self.period_s
        else:
            dt = t - self._last_tick
            w = self._window
            w["periods"] += 1
            w["max_period_s"] = max(w["max_period_s"], dt)
            if dt > self.overrun_factor * self.period_s:
                self.overruns += 1
                w["overruns"] += 1
        self._last_tick = t
        self.ticks += 1

        if not self._stale and math.isfinite(age := self.sim.command_age(t)) and age > self.command_timeout_s:
            self._stale = True
            self._stopped_short_rad = float(abs(self.sim.target - self.sim.q).max())
            self.sim.hold()
            if self._stopped_short_rad > self._p["stopped_short_warn_rad"]:
                self.get_logger().warning(
                    f"joint_command stale (nothing for {self.command_timeout_s:g} s) while moving: holding "
                    f"position {self._stopped_short_rad:.3f} rad short of the target")
            else:
                self.get_logger().info(f"joint_command idle for {self.command_timeout_s:g} s: holding position")

        with self._lock:
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
        self._window["max_tick_s"] = max(self._window["max_tick_s"], time.monotonic() - t)

    def _new_window(self) -> dict[str, float]:
        """Statistics of one diagnostics period (the loop's totals live on the node)."""
        return {"start": time.monotonic(), "ticks_at_start": self.ticks, "periods": 0, "overruns": 0,
                "max_period_s": 0.0, "max_tick_s": 0.0}

    def _publish_diagnostics(self) -> None:
        now = time.monotonic()
        self.diagnostics_pub.publish(msgs.diagnostic_array(self.diagnostic_statuses(now),
                                                           self.get_clock().now().to_msg()))

    def diagnostic_statuses(self, now: float) -> list:
        """The statuses of one /diagnostics message; resets the timing window."""
        p, sim, name = self._p, self.sim, self.get_name()
        w, self._window = self._window, self._new_window()
        statuses = []

        # commands
        rejected_recent = sim.rejected_count - self._rejected_reported
        self._rejected_reported = sim.rejected_count
        age = sim.command_age(now)
        values = {
            "accepted_total": sim.accepted_count,
            "rejected_total": sim.rejected_count,
            "rejected_recent": rejected_recent,
            "last_rejection_reason": sim.last_rejection,
            "command_age_s": age if math.isfinite(age) else "never",
            "command_timeout_s": self.command_timeout_s,
            "stale": self._stale,
            "stopped_short_rad": self._stopped_short_rad if self._stale else 0.0,
        }
        level, message = msgs.LEVEL_OK, "tracking joint_command"
        if sim.last_command_time is None:
            message = "no joint_command yet: holding the initial posture"
        if self._stale:
            message = f"joint_command idle ({age:.1f} s): holding position"
            if self._stopped_short_rad > self._p["stopped_short_warn_rad"]:
                level = msgs.LEVEL_WARN
                message = (f"joint_command stale ({age:.1f} s > {self.command_timeout_s:g} s) while moving: "
                           f"held position {self._stopped_short_rad:.3f} rad short of the target")
        if rejected_recent:
            level = msgs.LEVEL_WARN
            message = f"rejected {rejected_recent} joint_command(s), last: {sim.last_rejection}"
        statuses.append(msgs.diagnostic_status(f"{name}: commands", level, message, values, self.hardware_id))

        # limits
        clip_recent = sim.clip_events - self._clip_events_reported
        self._clip_events_reported = sim.clip_events
        per_joint = {f"clipped_targets.{j}": int(c) for j, c in zip(sim.joint_names, sim.clip_count) if c}
        values = {"clip_events_total": sim.clip_events, "clip_events_recent": clip_recent,
                  "clipped_targets_total": int(sim.clip_count.sum()),
                  "velocity_scale": sim.velocity_scale, **per_joint}
        level, message = msgs.LEVEL_OK, "targets within position limits"
        if clip_recent:
            level = msgs.LEVEL_WARN
            message = f"{clip_recent} command(s) had targets clipped into position limits"
        statuses.append(msgs.diagnostic_status(f"{name}: limits", level, message, values, self.hardware_id))

        # loop timing
        elapsed = max(now - w["start"], 1e-9)
        ticks = self.ticks - w["ticks_at_start"]
        rate = ticks / elapsed
        nominal = 1.0 / self.period_s
        overrun_frac = w["overruns"] / w["periods"] if w["periods"] else 0.0
        values = {"nominal_rate_hz": nominal, "achieved_rate_hz": rate, "overruns_total": self.overruns,
                  "overruns_recent": w["overruns"], "overrun_threshold_ms": self.overrun_factor * self.period_s * 1e3,
                  "max_period_ms": w["max_period_s"] * 1e3, "max_tick_ms": w["max_tick_s"] * 1e3,
                  "ticks_total": self.ticks}
        level, message = msgs.LEVEL_OK, f"{rate:.1f} Hz"
        if rate < p["min_rate_fraction"] * nominal or overrun_frac > p["max_overrun_fraction"]:
            level = msgs.LEVEL_WARN
            message = f"{rate:.1f} Hz of {nominal:.0f} Hz, {w['overruns']} overrun(s) in {w['periods']} periods"
        statuses.append(msgs.diagnostic_status(f"{name}: loop", level, message, values, self.hardware_id))

        # odometry
        with self._lock:
            odom = sim.odometry()
        x, y, z = (float(v) for v in odom.base.translation)
        values = {"base_x_m": x, "base_y_m": y, "base_z_m": z, "left_foot_slip_m": odom.left_foot_slip_m,
                  "frame_id": self.world_frame_id, "child_frame_id": p["base_frame_id"]}
        level, message = msgs.LEVEL_OK, "right foot fixed, left foot on its stance pose"
        if odom.left_foot_slip_m > p["left_foot_slip_warn_m"]:
            level = msgs.LEVEL_WARN
            message = f"left foot {odom.left_foot_slip_m * 1e3:.1f} mm from its stance pose (feet-fixed odometry)"
        statuses.append(msgs.diagnostic_status(f"{name}: odometry", level, message, values, self.hardware_id))
        return statuses

    # ------------------------------------------------------------ parameters
    def _apply_parameters(self, params: list[Parameter]) -> None:
        """Apply run-time changes of the writable parameters (ranges checked by their descriptors)."""
        for prm in params:
            if prm.name == "velocity_scale":
                self.sim.velocity_scale = prm.value
            elif prm.name == "tracking_time_constant_s":
                self.sim.time_constant_s = prm.value
            elif prm.name == "command_timeout_s":
                self.command_timeout_s = prm.value
            self._p[prm.name] = prm.value


def main(args: list[str] | None = None) -> int:
    """Run the node until Ctrl-C / SIGTERM (exit 0); a configuration error exits 2."""
    return run_node(JointDriver, NODE_NAME, args)


if __name__ == "__main__":
    sys.exit(main())
