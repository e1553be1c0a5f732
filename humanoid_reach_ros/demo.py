"""``make demo``: the whole node graph reaches the valve in the plant scene.

Every node runs as its own process in an isolated ROS graph (own ``ROS_DOMAIN_ID``, discovery
limited to this machine): ``joint_driver`` (the simulated HRP-2), ``scene_sim`` (head camera and
depth sensor), ``voxel_mapper``, ``marker_localizer``, ``reach_planner`` and ``reach_executor``,
plus the MCAP recorder. The demo then acts as the operator:

1. scans the plant with the head through the executor's ``/look`` action (its scan pattern,
   the ``reach_operator --scan`` of the operator), then waits until the voxel map stops growing;
2. looks at the valve (``/look``) until ``/target_pose`` (the ArUco marker on the valve, R_T_O) is steady;
3. calls ``/plan_reach`` with the marker target and the valve WGR of eq. 3 (planner's map = the
   measured ``/voxel_map``, not the scene file);
4. sends the trajectory to ``/execute_reach`` and follows its feedback;
5. prints a report (planning time split, trajectory, execution time, exact COG drift, minimum
   distance, final hand error), writes it as JSON with the Fig. 7/8-style plots of the executed
   motion and the MCAP recording of the run into ``--out``, and stops every process (also on Ctrl-C).

Options: ``--arm left``, ``--target X Y Z [--rpy R P Y]`` (a manual target in the world frame
instead of the marker), ``--scene FILE``, ``--out DIR``, ``--no-record``, ``--no-scan`` (no step 1:
the plan's automatic looks, ``--max-looks``, see what it needs). Each run writes into its own
directory ``DIR/<robot>/<YYYYmmdd-HHMMSS>/`` (default ``out/demo``), ``DIR/<robot>/latest`` links
to the last, and the newest ``--keep`` runs per robot are kept (default ``DEMO_RUNS_KEPT``).
"""
from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from humanoid_reach_ros.codes import ARM_REQUESTS, ErrorCode, code_name
from humanoid_reach_ros.graph import (  # noqa: F401  (Graph, GRAPH_NODES: also for benches and tools)
    GRAPH_NODES, STOP_DEADLINE_S, Graph, allocate_domain, graph_env, nodes_text, wait_for)
from humanoid_reach_ros.execution.config import PARAMETERS
from humanoid_reach_ros.paths import run_directory
from humanoid_reach_ros.operator.report import contact_line, execution_summary
from humanoid_reach_ros.robot.spec import DEFAULT_ROBOT, robots

# the topics the MCAP recording keeps (camera images are left out: 10 Hz of 640x480 RGB is 9 MB/s)
RECORDED_TOPICS = ("/joint_states", "/joint_command", "/base_pose", "/robot_description", "/target_pose",
                   "/markers", "/voxel_map", "/reach_trajectory", "/planning/markers", "/executor/metrics",
                   "/diagnostics", "/head_camera/camera_info", "/voxel_map/unobserved", "/voxel_map/unobserved_blocks",
                   "/physics/metrics")
# the executor's head scan (parameter scan_poses_deg of reach_executor): (yaw, pitch) [deg], pitch > 0 looks
# down; tools/record_bags.py and test_perception_graph command the same poses without the executor
_SCAN = PARAMETERS["scan_poses_deg"].default
HEAD_SCAN_DEG = tuple(zip(_SCAN[::2], _SCAN[1::2]))
SIM_JOINT_STATES_TIMEOUT_S = 2.0   # planner/executor staleness of /joint_states in the demo [s]
SIM_JOINT_STATES_ABORT_S = 5.0     # executor: abort a motion when /joint_states stop this long [s]

# the nodes are in the graph before their servers are: the executor warms its solver and its scan's gazes
# first (a few seconds quiet; under a load of 30 on two cores the demo's 30 s ran out waiting for /look)
SERVER_WAIT_S = 120.0
DEMO_RUNS_KEPT = 10    # --keep: runs kept per robot under --out (older ones removed)
# home on the physics plant: the servos hold each joint a little off its target under gravity (HRP-2 standing
# at half-sitting: 0.010 rad at most, docs/physics.md), so the measured joints end within this of half-sitting
PLANT_HOME_TOL_RAD = 0.02


def arm_code(arm: str) -> int:
    return ARM_REQUESTS[arm]


class DemoClient:
    """The operator's side in the demo process: topics to watch, the service and the action."""

    def __init__(self, domain_id: int, graph: Graph, plant: str = "kinematic") -> None:
        import rclpy
        from geometry_msgs.msg import PoseStamped
        from humanoid_reach_interfaces.action import ExecuteReach, Look
        from humanoid_reach_interfaces.msg import ExecutorMetrics
        from humanoid_reach_interfaces.srv import PlanReach
        from rclpy.action import ActionClient
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import qos_profile_sensor_data

        from humanoid_reach_ros.io.endpoints import LATCHED
        from sensor_msgs.msg import JointState, PointCloud2

        self.graph = graph
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node("demo_operator", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.joint_states: JointState | None = None
        self.recording = False                      # keep /joint_states while executing
        self.samples: list[JointState] = []
        self.maps: list[tuple[float, int]] = []
        self.targets: list[PoseStamped] = []
        self.metrics: list[Any] = []
        self.node.create_subscription(JointState, "/joint_states", self._on_joints, 10)
        self.node.create_subscription(PointCloud2, "/voxel_map",
                                      lambda m: self.maps.append((time.monotonic(), m.width * m.height)), LATCHED)
        self.node.create_subscription(PoseStamped, "/target_pose", self.targets.append, qos_profile_sensor_data)
        self.node.create_subscription(ExecutorMetrics, "/executor/metrics", self.metrics.append, 200)
        self.base_pose: PoseStamped | None = None
        self.base_samples: list[PoseStamped] = []   # /base_pose while recording (frames of the motion)
        self.node.create_subscription(PoseStamped, "/base_pose", self._on_base, 10)
        self.plant_metrics: list[Any] = []          # /physics/metrics (plant mujoco), every message
        if plant == "mujoco":
            from humanoid_reach_interfaces.msg import PlantMetrics
            self.node.create_subscription(PlantMetrics, "/physics/metrics", self.plant_metrics.append, 100)
        self.plan_client = self.node.create_client(PlanReach, "/plan_reach")
        self.action_client = ActionClient(self.node, ExecuteReach, "/execute_reach")
        self.look_client = ActionClient(self.node, Look, "/look")
        self.PlanReach, self.ExecuteReach, self.Look = PlanReach, ExecuteReach, Look

    def _on_base(self, msg) -> None:
        self.base_pose = msg
        if self.recording:
            self.base_samples.append(msg)

    def _on_joints(self, msg) -> None:
        self.joint_states = msg
        if self.recording:
            self.samples.append(msg)

    def spin_until(self, cond: Callable[[], Any], timeout: float, what: str):
        def step() -> None:
            self.executor.spin_once(0.01)
            self.graph.check_alive()
        return wait_for(cond, timeout, what, on_timeout=self.graph.log_tails, step=step)

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(0.01)

    def look(self, yaw_deg: list[float], pitch_deg: list[float], dwell_s: float, timeout: float = 120.0,
             gaze_points=None, come_back: bool = False):
        """The executor's ``/look`` action (the operator's ``reach_operator --scan`` / ``--look``):
        the head through the poses (empty: the executor's scan pattern), each held ``dwell_s``;
        ``gaze_points`` (K, 3) [m, world]: a whole-body gaze at each instead (the automatic look);
        ``come_back``: then back to the posture the look began in."""
        goal = self.Look.Goal(yaw_rad=np.radians(yaw_deg).tolist(), pitch_rad=np.radians(pitch_deg).tolist(),
                              dwell_s=dwell_s, come_back=come_back)
        if gaze_points is not None:
            from humanoid_reach_ros.io.msgs import points_list
            goal.gaze_points = points_list(gaze_points)
        self.spin_until(lambda: self.look_client.server_is_ready(), SERVER_WAIT_S, "/look")
        held = set()

        def feedback(m) -> None:
            f = m.feedback
            if f.holding and f.pose_index not in held:
                held.add(f.pose_index)
                n = self.maps[-1][1] if self.maps else 0
                print(f"[demo] head pose {f.pose_index + 1}/{f.pose_count}: yaw {math.degrees(f.yaw_rad):+5.1f} "
                      f"pitch {math.degrees(f.pitch_rad):+5.1f} deg (map {n} voxels)")
        deadline = time.monotonic() + 30.0
        while True:
            send = self.look_client.send_goal_async(goal, feedback_callback=feedback)
            self.spin_until(send.done, 30.0, "/look to accept the goal")
            result = send.result().get_result_async()
            self.spin_until(result.done, timeout, "the /look result")
            res = result.result().result
            # right after start-up the executor may not have taken a /joint_states yet: ask again
            if res.error_code.val != ErrorCode.NO_JOINT_STATES or time.monotonic() > deadline:
                break
            self.spin_for(0.5)
        if not res.success:
            raise RuntimeError(f"/look failed ({res.error_code.val}): {res.message}")
        return res

    def close(self) -> None:
        import rclpy

        self.action_client.destroy()
        self.look_client.destroy()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def scan_plant(op: DemoClient, settle_s: float) -> int:
    """The head scan through ``/look`` (the executor's scan pattern); then waits until the
    mapper has integrated it (no new /voxel_map for a second); returns the voxel count."""
    t0 = time.monotonic()
    res = op.look([], [], settle_s)
    print(f"[demo] head scan: {res.poses_done} poses in {res.duration_s:.1f} s, max COG drift "
          f"{res.max_com_error_m * 1e3:.3f} mm")
    op.spin_until(lambda: op.maps and op.maps[-1][0] > t0 and time.monotonic() - op.maps[-1][0] > 1.0, 30.0,
                  "the /voxel_map of the scan")
    return op.maps[-1][1]


def aim_head_deg(robot_name: str, point, step_deg: float = 1.0) -> tuple[float, float]:
    """Head yaw and pitch [deg] that point the camera closest to ``point`` [m, world] from
    half-sitting (``robot.head_aim``): where the operator turns the head to find a marker they
    know roughly where to look for. For the plant's valve on HRP-2 this is the executor's
    ``marker_look_deg`` (yaw 2, pitch 40), the look the README gives."""
    from humanoid_reach_ros.robot.head_aim import aim_head_deg as aim
    from humanoid_reach_ros.robot.model import RobotModel

    return aim(RobotModel(robot_name), point, step_deg=step_deg)


def wait_marker(op: DemoClient, look_at: tuple[float, float] | None, timeout: float = 30.0, gaze=None):
    """Looks at the valve (head angles ``look_at`` [deg], or a whole-body gaze at the point
    ``gaze`` [m, world]) and waits for five consistent /target_pose messages."""
    from humanoid_reach_ros.io import msgs

    if gaze is not None:
        op.look([], [], 0.1, gaze_points=np.asarray(gaze, float).reshape(1, 3))
    else:
        op.look([look_at[0]], [look_at[1]], 0.1)
    n0 = len(op.targets)

    def steady() -> bool:
        recent = op.targets[n0:][-5:]
        if len(recent) < 5:
            return False
        p = np.array([msgs.se3_from_pose(t.pose).translation for t in recent])
        return float(np.max(np.ptp(p, axis=0))) < 0.005
    op.spin_until(steady, timeout, "a steady /target_pose from marker_localizer (is the valve marker in view?)")
    return op.targets[-1]


def plan(op: DemoClient, args: argparse.Namespace, home: bool = False, relocate: Callable[[], Any] | None = None):
    """``/plan_reach`` as ``reach_operator`` asks it: while the answer is UNOBSERVED_SPACE with the
    points to look at, a whole-body gaze there (``/look``), then plan again (at most
    ``--max-looks``); ``relocate``: called after each such look (the marker target: the head turns
    back to the marker, whose /target_pose went stale while it looked away). ``(response, operator
    wait [s] without the looks, region, looks)``."""
    from humanoid_reach_ros.io import msgs
    from humanoid_reach_ros.planning.wgr import valve_region

    region = valve_region()
    if args.target is not None:
        import pinocchio as pin

        R = pin.rpy.rpyToMatrix(*np.radians(args.rpy)) if args.rpy is not None else region.target_R
        region = type(region)(np.asarray(args.target, dtype=float), R, region.lower, region.upper)
    req = msgs.plan_reach_request(region, "world", arm=arm_code(args.arm), planner=args.planner,
                                  use_marker_target=args.target is None and not home, time_budget_s=args.budget,
                                  seed=args.seed, home=home)
    op.spin_until(lambda: op.plan_client.service_is_ready(), SERVER_WAIT_S, "/plan_reach")
    wait_s, looks, max_looks = 0.0, 0, args.max_looks
    while True:
        t0 = time.monotonic()
        future = op.plan_client.call_async(req)
        op.spin_until(future.done, args.budget + 30.0, "the /plan_reach response")
        wait_s += time.monotonic() - t0
        resp = future.result()
        if resp.error_code.val != ErrorCode.UNOBSERVED_SPACE or not resp.unobserved_points \
                or looks >= max_looks:
            return resp, wait_s, region, looks
        looks += 1
        pts = msgs.points_array(resp.unobserved_points)
        print(f"[demo] the plan needs to see {np.round(pts, 2).tolist()} m (unobserved): looking there "
              f"(automatic look {looks}/{max_looks})")
        op.look([], [], args.settle, gaze_points=pts, come_back=True)
        if relocate is not None:
            relocate()


class ProgressBar:
    """The demo's execution bar from the ``/execute_reach`` feedback: in place on a terminal,
    else a line per 20 %. The feedback is the control loop's status (10 Hz), whose last message
    comes before the motion's end with a progress below 1: a log's bar stopped at its 80 % line
    (80.1 %). A successful result draws the bar at 100 % with the result's figures."""

    def __init__(self, out) -> None:
        self.out = out
        self.tty = bool(getattr(out, "isatty", lambda: False)())
        self.last = -1

    def line(self, progress: float, min_distance_m: float, com_error_m: float) -> str:
        pct = int(min(1.0, max(0.0, progress)) * 20)
        return (f"[demo] executing [{'#' * pct}{'.' * (20 - pct)}] {progress * 100:5.1f} %  "
                f"min distance {min_distance_m * 100:5.2f} cm  COG {com_error_m * 1e3:5.2f} mm")

    def _write(self, text: str) -> None:
        self.out.write(("\r" + text) if self.tty else (text + "\n"))
        self.out.flush()

    def update(self, f) -> None:
        pct = int(min(1.0, max(0.0, f.progress)) * 20)
        if pct != self.last and (self.tty or pct % 4 == 0):
            self.last = pct
            self._write(self.line(f.progress, f.min_distance_m, f.com_error_m))

    def finish(self, result) -> None:
        """The last line: 100 % on success (min distance and max COG drift of the whole motion)."""
        if result is not None and result.success and self.last < 20:
            self.last = 20
            self._write(self.line(1.0, result.min_distance_m, result.max_com_error_m))
        if self.tty:
            self.out.write("\n")
            self.out.flush()


def execute(op: DemoClient, trajectory, arm: int):
    goal = op.ExecuteReach.Goal(mode=op.ExecuteReach.Goal.MODE_TRAJECTORY, trajectory=trajectory, arm=arm)
    op.spin_until(lambda: op.action_client.server_is_ready(), SERVER_WAIT_S, "/execute_reach")
    bar = ProgressBar(sys.stdout)
    t0 = time.monotonic()
    op.samples.clear()
    op.base_samples.clear()
    op.recording = True
    send = op.action_client.send_goal_async(goal, feedback_callback=lambda fb: bar.update(fb.feedback))
    op.spin_until(send.done, 30.0, "/execute_reach to accept the goal")
    handle = send.result()
    if not handle.accepted:
        raise RuntimeError("/execute_reach rejected the goal")
    result = handle.get_result_async()
    duration = trajectory.points[-1].time_from_start.sec + trajectory.points[-1].time_from_start.nanosec * 1e-9
    op.spin_until(result.done, duration + 60.0, "the /execute_reach result")
    op.recording = False
    res = result.result().result
    bar.finish(res)
    return res, time.monotonic() - t0


def final_hand_in_region(op: DemoClient, region, arm: str, tol: float = 2e-3, robot_name: str | None = None) -> bool:
    """Is the measured hand pose (FK of /joint_states) inside the WGR (bounds grown by ``tol``, m / rad)?"""
    from humanoid_reach_ros.io import msgs
    from humanoid_reach_ros.robot.model import RobotModel

    robot = RobotModel(robot_name)
    js = msgs.parse_joint_state(op.joint_states)
    joints = robot.joints_from_dict(dict(zip(js.names, js.positions)))
    q = robot.config(joints, robot.base_on_feet(joints))
    hand = robot.frame_pose(q, robot.limbs[f"{arm}_arm"].tip)
    return bool(region.contains(hand.translation, hand.rotation, tol=tol))


def measured_balance(samples: list[Any], robot_name: str | None = None) -> dict[str, float]:
    """From the measured /joint_states while executing: drift of the left sole (the driver's odometry
    keeps the right sole at its stance pose, so a moving left sole is what a leg error would show) and
    of the exact COG's horizontal position from the first sample."""
    from humanoid_reach_ros.io import msgs
    from humanoid_reach_ros.robot.model import RobotModel

    robot = RobotModel(robot_name)
    left = robot.stance_soles[1]
    feet, com0, com = 0.0, None, 0.0
    for msg in samples[::5]:
        js = msgs.parse_joint_state(msg)
        joints = robot.joints_from_dict(dict(zip(js.names, js.positions)))
        q = robot.config(joints, robot.base_on_feet(joints))
        feet = max(feet, float(np.linalg.norm(robot.frame_pose(q, robot.sole_frames[1]).translation
                                              - left.translation)))
        c = np.asarray(robot.com(q))[:2]
        com0 = c if com0 is None else com0
        com = max(com, float(np.linalg.norm(c - com0)))
    return {"feet_drift_m": feet, "com_drift_measured_m": com, "joint_state_samples": len(samples[::5])}


def plot_metrics(path: Path, metrics: list[Any], arm: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.array([m.time_from_start_s for m in metrics])
    fig, ax = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
    ax[0].plot(t, [m.com_error_m * 1e3 for m in metrics])
    ax[0].set(ylabel="exact COG drift [mm]", title=f"{arm}-arm reach of the valve, as executed (Fig. 7/8 style)")
    ax[1].plot(t, [m.min_distance_m * 1e2 for m in metrics])
    ax[1].axhline(0.0, color="k", lw=0.8)
    ax[1].set(ylabel="min robot-environment\ndistance [cm]")
    ax[2].plot(t, [m.step_time_s * 1e3 for m in metrics], lw=0.8, label="step")
    ax[2].plot(t, [m.distance_query_time_s * 1e3 for m in metrics], lw=0.8, label="distance query")
    ax[2].axhline(5.0, color="r", lw=0.8, label="period")
    ax[2].set(xlabel="trajectory time [s]", ylabel="step time [ms]")
    ax[2].legend(fontsize=8)
    for a in ax:
        a.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plant_state(robot, joint_state, base_pose):
    """(model joints, base SE3) of a /joint_states and a /base_pose message; None if unusable."""
    from humanoid_reach_ros.io import msgs

    if joint_state is None or base_pose is None:
        return None
    joints, _ = msgs.model_joints(joint_state, robot)
    return None if joints is None else (joints, msgs.se3_from_pose(base_pose))


def write_demo_frames(out: Path, robot_name: str, scene: str, states: list[tuple[str, Any]]) -> list[str]:
    """Pictures of the robot in the scene at the measured ``states`` ((label, (joints, base))), by
    MuJoCo's offscreen renderer (sim/physics/render.py; MUJOCO_GL=egl unless set): ``frame_<k>.png``
    and ``frames.png`` side by side. Without an OpenGL context it says why and writes none."""
    from humanoid_reach_ros.sim.physics.render import (  # first: it sets MUJOCO_GL before mujoco loads
        default_view, gl_problem, render_states, write_frames)
    from humanoid_reach_ros.robot.model import RobotModel
    from humanoid_reach_ros.sim.physics.model_builder import build_for_robot
    from humanoid_reach_ros.sim.scene import load_scene

    problem = gl_problem()
    if problem is not None:
        print(f"[demo] no frames: {problem}")
        return []
    states = [(label, st) for label, st in states if st is not None]
    try:
        pm = build_for_robot(RobotModel(robot_name), scene)
    except ValueError as exc:       # a robot without physics.yaml: nothing to render with
        print(f"[demo] no frames: {exc}")
        return []
    target = load_scene(scene).target
    images = render_states(pm, [st for _, st in states],
                           default_view(pm, target.pose[:3, 3] if target is not None else None))
    return [str(p) for p in write_frames(images, [label for label, _ in states], out, "frame")]


def run(args: argparse.Namespace) -> dict:
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    lease = allocate_domain()
    env = graph_env(lease.domain_id)
    print(f"[demo] isolated ROS graph: ROS_DOMAIN_ID={lease.domain_id}, discovery LOCALHOST; logs in {out}/")
    graph = Graph(out, env)
    op = None
    t_start = time.monotonic()
    try:
        scene = str(Path(args.scene).resolve())
        for name in GRAPH_NODES:
            params: dict[str, Any] = {"robot_config": args.robot}
            if name == "scene_sim":
                params["scene_file"] = scene
            elif name == "joint_driver":
                params["plant"] = args.plant
                params["physics_scene"] = scene     # the physics plant stands in the scene the sensors render
            elif name in ("reach_planner", "reach_executor"):
                params["scene_file"] = ""  # the measured /voxel_map is the map
                # simulation on a shared 2-core machine: a node can be starved of /joint_states for a
                # second or two, which on a robot would rightly stop a motion (defaults 0.5 s / 2 s)
                params["joint_states_timeout_s"] = SIM_JOINT_STATES_TIMEOUT_S
                if name == "reach_executor":
                    params["joint_states_abort_s"] = SIM_JOINT_STATES_ABORT_S
            graph.start(name, params)
        if not args.no_record:
            bag = out / "demo.mcap"
            bag.unlink(missing_ok=True)
            graph.start_command("bag_record", [sys.executable, "-m", "humanoid_reach_ros.nodes.bag_record",
                                               "-o", str(bag), *RECORDED_TOPICS])
        op = DemoClient(lease.domain_id, graph, args.plant)
        names = set(GRAPH_NODES)
        op.spin_until(lambda: names <= set(op.node.get_node_names()) and op.joint_states is not None, 90.0,
                      f"the nodes {sorted(names)} in the graph")
        print(f"[demo] {nodes_text(len(names))} up in {time.monotonic() - t_start:.1f} s")
        from humanoid_reach_ros.robot.model import RobotModel
        robot_model = RobotModel(args.robot)
        op.spin_until(lambda: op.base_pose is not None, 30.0, "/base_pose")
        frames = [("start", plant_state(robot_model, op.joint_states, op.base_pose))]
        if args.no_scan:
            print("[demo] no head scan (--no-scan): the planner's UNOBSERVED_SPACE answers are looked at instead")
        else:
            scan_plant(op, args.settle)
        target = None
        if args.target is None:
            look, gaze = args.look, None
            if look is None:
                from humanoid_reach_ros.robot.spec import load_robot_spec
                from humanoid_reach_ros.sim.scene import load_scene

                valve = load_scene(scene).target.pose[:3, 3]
                if load_robot_spec(args.robot)[0].has_neck:
                    look = aim_head_deg(args.robot, valve)
                    print(f"[demo] looking for the marker at yaw {look[0]:.0f}, pitch {look[1]:.0f} deg (the head "
                          "aimed at the scene's valve)")
                else:   # the camera turns with the body only: a balanced whole-body gaze at the valve
                    gaze = valve
                    print(f"[demo] looking for the marker: a whole-body gaze at the scene's valve "
                          f"{np.round(valve, 3).tolist()} (the robot has no neck)")
            target = wait_marker(op, look, gaze=gaze)
            from humanoid_reach_ros.io import msgs

            p = msgs.se3_from_pose(target.pose).translation
            print(f"[demo] marker target (valve centre) at {np.round(p, 4).tolist()} m in world")
        relocate = None
        if args.target is None:
            def relocate() -> None:
                print("[demo] looking back at the marker (its /target_pose went stale during the look)")
                wait_marker(op, look, gaze=gaze)
        resp, wait_s, region, looks = plan(op, args, relocate=relocate)
        if not resp.success:
            raise RuntimeError(f"/plan_reach failed: {code_name(resp.error_code.val)}: "
                               f"{resp.message}")
        if args.target is None:
            from humanoid_reach_ros.io import msgs

            region = type(region)(msgs.se3_from_pose(target.pose).translation,
                                  msgs.se3_from_pose(target.pose).rotation, region.lower, region.upper)
        s = resp.statistics
        arm = {1: "right", 2: "left"}[resp.arm]
        traj = resp.trajectory
        t_end = traj.points[-1].time_from_start
        traj_s = t_end.sec + t_end.nanosec * 1e-9
        print(f"[demo] planned in {wait_s * 1e3:.0f} ms ({arm} arm): {resp.message}")
        op.metrics.clear()
        result, exec_s = execute(op, traj, resp.arm)
        reach_js, reach_base = list(op.samples), list(op.base_samples)
        for frac in (0.33, 0.66):     # two frames of the motion: the measured state a third and two thirds in
            if reach_js and reach_base:
                frames.append((f"reaching {frac:.0%}", plant_state(
                    robot_model, reach_js[int(frac * (len(reach_js) - 1))],
                    reach_base[int(frac * (len(reach_base) - 1))])))
        if not result.success:
            raise RuntimeError(f"/execute_reach failed ({result.error_code.val}): {result.message}")
        contact = execution_summary("done", result)   # where the hand ended (issue 33): as reach_operator says it
        print(f"[demo] {contact_line(contact)}")
        op.spin_for(0.5)
        frames.append(("at the valve", plant_state(robot_model, op.joint_states, op.base_pose)))
        in_region = final_hand_in_region(op, region, arm, robot_name=args.robot)
        measured = measured_balance(op.samples, args.robot)
        report = {
            "arm": arm,
            "map_voxels": int(op.maps[-1][1]) if op.maps else 0,
            "operator_wait_s": round(wait_s, 3),
            "goal_sampling_s": round(s.goal_sampling_time_s, 3),
            "path_planning_s": round(s.path_planning_time_s, 3),
            "goals_found": int(s.goals_found),
            "path_waypoints": int(s.path_waypoints),
            "trajectory_points": len(traj.points),
            "trajectory_duration_s": round(traj_s, 3),
            "execution_wall_s": round(exec_s, 3),
            "execution_steps": int(result.steps),
            "overruns": int(result.overruns),
            "max_com_drift_m": float(result.max_com_error_m),
            "min_distance_m": float(result.min_distance_m),
            "final_hand_error_m": float(result.final_hand_error_m),
            "final_hand_error_rad": float(result.final_hand_error_rad),
            "final_hand_in_wgr": in_region,
            **{k: contact[k] for k in ("hand_in_contact", "contact_distance_m", "contact_with")},
            **measured,
            "target_from_marker": args.target is None,
        }
        if op.metrics:
            plot_metrics(out / "demo_execution.png", op.metrics, arm)
            report["metrics_messages"] = len(op.metrics)
        report["automatic_looks"] = looks
        # the session ends where it began: the arm home (a retreat from the valve first)
        home, home_wait_s, _, _ = plan(op, args, home=True)
        if not home.success:
            raise RuntimeError(f"/plan_reach home failed: {code_name(home.error_code.val)}: "
                               f"{home.message}")
        print(f"[demo] planned the way home in {home_wait_s * 1e3:.0f} ms: {home.message}")
        home_result, home_exec_s = execute(op, home.trajectory, home.arm)
        if not home_result.success:
            raise RuntimeError(f"/execute_reach (home) failed ({home_result.error_code.val}): {home_result.message}")
        op.spin_for(0.5)
        frames.append(("home", plant_state(robot_model, op.joint_states, op.base_pose)))
        robot = robot_model
        js = op.joint_states
        at_rest = (float(np.max(np.abs(robot.joints_from_dict(dict(zip(js.name, js.position)))
                                       - robot.half_sitting_joints))) if js is not None else math.inf)
        report.update(home_wait_s=round(home_wait_s, 3), home_retreat=home.retreat, home_execution_wall_s=round(
            home_exec_s, 3), home_overruns=int(home_result.overruns), home_max_joint_error_rad=at_rest)
        report["plant"] = args.plant
        if args.plant == "mujoco":    # what the physics plant measured over the whole run (/physics/metrics)
            from humanoid_reach_ros.sim.physics.summary import plant_figures
            op.spin_for(0.1)
            report["physics"] = plant_figures(op.plant_metrics)
        if not args.no_frames:
            report["frames"] = write_demo_frames(out, args.robot, scene, frames)
        return report
    finally:
        if op is not None:
            op.close()
        codes = graph.stop()
        lease.release()
        slow = {p.name: round(p.stop_s, 2) for p in graph.procs if (p.stop_s or 0.0) > STOP_DEADLINE_S}
        bad = {k: v for k, v in codes.items() if v != 0}
        print(f"[demo] stopped {len(codes)} processes" + (f"; unclean exits: {bad}" if bad else " cleanly")
              + (f"; slower than {STOP_DEADLINE_S:g} s to stop: {slow}" if slow else ""))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False,  # it moves a robot
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--arm", choices=("auto", "right", "left"), default="auto")
    ap.add_argument("--target", type=float, nargs=3, metavar=("X", "Y", "Z"), default=None,
                    help="manual target position in the world frame [m] instead of the marker on the valve")
    ap.add_argument("--rpy", type=float, nargs=3, metavar=("R", "P", "Y"), default=None,
                    help="manual target orientation [deg] (with --target; default: the valve's)")
    ap.add_argument("--scene", default=None, help="scene file for scene_sim (default: the robot's demo_scene, "
                    "the plant unless its robot.yaml names one made for its size)")
    ap.add_argument("--planner", default="", help="rrt_connect | prm | modified_prm (default: the node's)")
    ap.add_argument("--budget", type=float, default=5.0, help="planning time budget [s]")
    ap.add_argument("--seed", type=int, default=-1, help="planner seed (negative: the node's)")
    ap.add_argument("--look", type=float, nargs=2, metavar=("YAW", "PITCH"), default=None,
                    help="head yaw/pitch [deg] while localizing the marker (default: aimed at the scene's valve)")
    ap.add_argument("--settle", type=float, default=1.0, help="seconds each head pose of the scan is held")
    ap.add_argument("--robot", default=DEFAULT_ROBOT, choices=robots(),
                    help=f"robot of config/robots (default {DEFAULT_ROBOT})")
    ap.add_argument("--out", default="out/demo", help="base directory: each run writes its node logs, report, plots "
                    "and MCAP file into OUT/<robot>/<date-time>/, OUT/<robot>/latest links to the last run")
    ap.add_argument("--keep", type=int, default=DEMO_RUNS_KEPT, help="runs kept per robot under --out, the oldest "
                    f"removed first (0: keep all; default {DEMO_RUNS_KEPT})")
    ap.add_argument("--no-record", action="store_true", help="do not record an MCAP file")
    ap.add_argument("--no-scan", action="store_true",
                    help="skip the head scan: plan on what the head has seen and look where the planner answers "
                         "UNOBSERVED_SPACE (up to --max-looks times)")
    ap.add_argument("--plant", choices=("kinematic", "mujoco"), default="kinematic",
                    help="joint_driver's plant: kinematic (joints where commanded, the waist on the feet; default) or "
                         "mujoco (a MuJoCo physics plant in the same scene: servos, contacts, a measured base; "
                         "docs/physics.md); the report then has the plant's figures under 'physics'")
    ap.add_argument("--no-frames", action="store_true", help="write no pictures of the robot in the scene "
                    "(default: frame_*.png and frames.png, MuJoCo's offscreen renderer)")
    ap.add_argument("--max-looks", type=int, default=3, help="automatic looks per plan request (0: none)")
    args = ap.parse_args(argv)
    if args.target is not None and not all(math.isfinite(v) for v in args.target):
        ap.error("--target must be finite")
    if args.rpy is not None and (args.target is None or not all(math.isfinite(v) for v in args.rpy)):
        ap.error("--rpy needs --target and finite angles")
    if args.scene is None:
        from humanoid_reach_ros.robot.spec import load_robot_spec
        try:
            args.scene = load_robot_spec(args.robot)[0].demo_scene
        except ValueError as exc:
            ap.error(f"--robot {args.robot}: {exc}")
    if not Path(args.scene).is_file():
        ap.error(f"--scene {args.scene}: no such file")
    if not 0.1 <= args.budget <= 60.0:
        ap.error("--budget must be within [0.1, 60] s")
    if not 0 <= args.max_looks <= 20:
        ap.error("--max-looks must be within [0, 20]")
    if args.keep < 0:
        ap.error("--keep must be >= 0 (0: keep every run)")
    base = Path(args.out)
    args.out = str(run_directory(base / args.robot, args.keep))   # this run's own directory

    def on_sigterm(*_) -> None:
        raise KeyboardInterrupt  # stop like Ctrl-C: every child process is shut down

    signal.signal(signal.SIGTERM, on_sigterm)
    try:
        report = run(args)
    except KeyboardInterrupt:
        print("[demo] interrupted; every process stopped")
        return 130
    except (RuntimeError, TimeoutError, AssertionError) as exc:
        print(f"[demo] error: {exc}", file=sys.stderr)
        return 1
    out = Path(args.out)
    (out / "demo_report.json").write_text(json.dumps(report, indent=2))
    ok = (report["min_distance_m"] >= 0.0 and report["final_hand_in_wgr"] and report["max_com_drift_m"] <= 1e-3
          and report["home_max_joint_error_rad"] <= (PLANT_HOME_TOL_RAD if args.plant == "mujoco" else 0.01))
    if args.plant == "mujoco":   # the soles' drift is measured by the plant, not from the joints' kinematics
        ph = report["physics"]
        ok = ok and ph["falls"] == 0 and ph["foot_slip_mm_max"] is not None and ph["foot_slip_mm_max"] <= 1.0 \
            and ph["cop_margin_mm_min"] is not None and ph["cop_margin_mm_min"] >= 20.0
    else:
        ok = ok and report["feet_drift_m"] <= 1e-4
    print("[demo] report:")
    for k, v in report.items():
        print(f"  {k:24s} {v}")
    if report.get("frames"):
        print(f"[demo] frames of the robot in the scene: {out / 'frames.png'} ({len(report['frames']) - 1} frames)")
    print(f"[demo] files: {out / 'demo_report.json'}, {out / 'demo_execution.png'}"
          + ("" if args.no_record else f", {out / 'demo.mcap'}") + f", the node logs (also {out.parent / 'latest'}/)")
    print("[demo] " + ("OK" if ok else "FAILED: see the report above"))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
