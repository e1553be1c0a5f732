"""``make demo``: run what the graph has end to end and report.

Until the planner, executor and perception nodes land (issues #3-#6), the demo runs the
foundation for real: it starts ``joint_driver`` as its own process in an isolated ROS
graph, waits for ``/joint_states``, solves the right arm in closed form for a reach
toward the valve side of the plant (trunk held in half-sitting), streams the motion on
``/joint_command`` as a clamped cubic in time, and measures from what comes back:
the ``/joint_states`` rate, the hand error at the end (forward kinematics of the
measured joints), the largest joint speed against its limit, joint-limit violations and
the feet (``/base_pose`` against the stance). It writes a plot of commanded vs measured
joint angles and shuts every process down cleanly, also on Ctrl-C.

Options: ``--arm left``, ``--target X Y Z`` (hand target in the world frame [m]),
``--duration S``, ``--out DIR``.
"""
from __future__ import annotations

import argparse
import json
import signal
import sys
import time
from pathlib import Path

import numpy as np
import pinocchio as pin

from humanoid_reach_ros.graph import NodeProcess, allocate_domain, graph_env, wait_for
from humanoid_reach_ros.paths import config_path
from humanoid_reach_ros.robot.limb_ik import LimbIKSet
from humanoid_reach_ros.robot.model import RobotModel

COMMAND_RATE_HZ = 100.0


def reach_target(robot: RobotModel, ik: LimbIKSet, arm: str, target_p: np.ndarray, q0: np.ndarray) -> np.ndarray:
    """Joint angles with the ``arm`` hand at ``target_p``, pointing forward and down (45 deg),
    trunk and legs as in ``q0``; closed-form arm IK. Raises ValueError if out of reach."""
    limb = robot.limbs[f"{arm}_arm"]
    root = robot.frame_pose(q0, limb.root)
    # hand frame z axis = from the grasp point back to the wrist: up and backward (45 deg)
    R = pin.rpy.rpyToMatrix(0.0, -np.pi / 4, 0.0)
    joints = q0[7:].copy()
    res = ik[limb.name].solve(root.translation, root.rotation, target_p, R, q_ref=joints[list(limb.joint_index)])
    if not res.ok[0]:
        raise ValueError(f"hand target {target_p} is not reachable with the {arm} arm "
                         f"({res.failure_counts()})")
    joints[list(limb.joint_index)] = res.q[0]
    return joints


def joint_arrays(robot: RobotModel, msg) -> tuple[np.ndarray, np.ndarray]:
    """Positions and velocities of a sensor_msgs/JointState as 30-vectors in model order."""
    from humanoid_reach_ros.io import msgs

    js = msgs.parse_joint_state(msg)
    idx = [robot.joint_index[n] for n in js.names]
    pos, vel = np.zeros(robot.n_joints), np.zeros(robot.n_joints)
    pos[idx] = js.positions
    if js.velocities is not None:
        vel[idx] = js.velocities
    return pos, vel


def clamped_cubic(s: np.ndarray) -> np.ndarray:
    """Clamped cubic time scaling 3 s^2 - 2 s^3 (zero velocity at both ends)."""
    return 3 * s**2 - 2 * s**3


def run(args: argparse.Namespace) -> dict:
    import rclpy
    from geometry_msgs.msg import PoseStamped
    from sensor_msgs.msg import JointState

    from humanoid_reach_ros.io import msgs

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    robot = RobotModel()
    ik = LimbIKSet(robot)
    lease = allocate_domain()
    env = graph_env(lease.domain_id)
    print(f"[demo] isolated ROS graph: ROS_DOMAIN_ID={lease.domain_id}, discovery LOCALHOST; logs in {out}/")
    driver = NodeProcess.start("joint_driver", out, env, config_path("joint_driver.yaml"))
    context = rclpy.Context()
    try:
        driver.wait_for_log("joint_driver", timeout=60)
        rclpy.init(context=context, domain_id=lease.domain_id)
        node = rclpy.create_node("demo_operator", context=context)
        states: list[tuple[float, JointState]] = []
        poses: list[PoseStamped] = []
        node.create_subscription(JointState, "/joint_states", lambda m: states.append((time.monotonic(), m)), 50)
        node.create_subscription(PoseStamped, "/base_pose", poses.append, 10)
        pub = node.create_publisher(JointState, "/joint_command", 10)
        from rclpy.executors import SingleThreadedExecutor

        ex = SingleThreadedExecutor(context=context)
        ex.add_node(node)

        def spin_until(cond, timeout, what):
            return wait_for(cond, timeout, what, on_timeout=driver.log_tail, step=lambda: ex.spin_once(0.005))

        spin_until(lambda: len(states) > 20 and poses, 30, "/joint_states and /base_pose from joint_driver")
        t_rate = time.monotonic()
        n0 = len(states)
        while time.monotonic() - t_rate < 2.0:
            ex.spin_once(0.005)
        rate_hz = (len(states) - n0) / (time.monotonic() - t_rate)
        print(f"[demo] /joint_states at {rate_hz:.1f} Hz")

        names = list(robot.joint_names)
        start, _ = joint_arrays(robot, states[-1][1])
        q_start = robot.config(start, robot.base_on_feet(start))
        target_p = np.asarray(args.target, dtype=float)
        goal = reach_target(robot, ik, args.arm, target_p, q_start)
        print(f"[demo] {args.arm} hand -> {target_p.round(3).tolist()} m (closed-form arm IK), "
              f"{args.duration:.1f} s clamped cubic, commands at {COMMAND_RATE_HZ:.0f} Hz")

        log_t, log_cmd, log_meas = [], [], []
        t0 = time.monotonic()
        next_cmd = t0
        settle = 1.0
        while True:
            now = time.monotonic()
            t = now - t0
            if now >= next_cmd and t <= args.duration + settle:
                s = clamped_cubic(np.clip(t / args.duration, 0.0, 1.0))
                cmd = start + s * (goal - start)
                pub.publish(msgs.joint_state(names, cmd, stamp=node.get_clock().now().to_msg()))
                next_cmd += 1.0 / COMMAND_RATE_HZ
                log_t.append(t)
                log_cmd.append(cmd)
                log_meas.append(joint_arrays(robot, states[-1][1])[0])
            if t > args.duration + settle:
                break
            ex.spin_once(0.002)

        final = np.array(log_meas[-1])
        q_final = robot.config(final, robot.base_on_feet(final))
        hand = robot.frame_pose(q_final, robot.limbs[f"{args.arm}_arm"].tip).translation
        meas = np.array(log_meas)
        dt = np.diff(np.array([s[0] for s in states]))
        pos, vel = map(np.array, zip(*(joint_arrays(robot, s[1]) for s in states)))
        soles = robot.stance_soles
        feet_err = max(np.linalg.norm(robot.frame_pose(q_final, f).translation - s.translation)
                       for f, s in zip(("r_sole", "l_sole"), soles))
        report = {
            "joint_states_rate_hz": round(rate_hz, 1),
            "joint_states_max_gap_ms": round(float(dt.max()) * 1e3, 2),
            "arm": args.arm,
            "target_m": target_p.tolist(),
            "final_hand_error_m": float(np.linalg.norm(hand - target_p)),
            "max_speed_over_limit": float(np.max(np.abs(vel) / robot.velocity_limit)),
            "limit_violations": int(np.sum((pos < robot.lower - 1e-9) | (pos > robot.upper + 1e-9))),
            "feet_drift_m": float(feet_err),
            "waist_from_base_pose_m": msgs.se3_from_pose(poses[-1].pose).translation.round(4).tolist(),
            "duration_s": args.duration,
        }
        plot(out / "demo_joints.png", np.array(log_t), np.array(log_cmd), meas, robot, args.arm)
        (out / "demo_report.json").write_text(json.dumps(report, indent=2))
        node.destroy_node()
        return report
    finally:
        code = driver.stop()
        rclpy.try_shutdown(context=context)
        lease.release()
        print(f"[demo] joint_driver stopped (exit code {code})")


def plot(path: Path, t: np.ndarray, cmd: np.ndarray, meas: np.ndarray, robot: RobotModel, arm: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    idx = list(robot.limbs[f"{arm}_arm"].joint_index)
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for k, j in enumerate(idx):
        line, = ax.plot(t, np.degrees(cmd[:, j]), "--", lw=1)
        ax.plot(t, np.degrees(meas[:, j]), color=line.get_color(), lw=1.8, label=robot.joint_names[j])
    ax.set(xlabel="time [s]", ylabel="joint angle [deg]",
           title=f"{arm} arm: commanded (dashed) vs measured /joint_states (solid)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--arm", choices=("right", "left"), default="right")
    ap.add_argument("--target", type=float, nargs=3, metavar=("X", "Y", "Z"), default=None,
                    help="hand target in the world frame [m] (default: in front of the chosen shoulder)")
    ap.add_argument("--duration", type=float, default=2.0, help="motion duration [s]")
    ap.add_argument("--out", default="out/demo", help="directory for logs, report and plot")
    args = ap.parse_args(argv)
    if args.target is None:
        args.target = [0.45, -0.22 if args.arm == "right" else 0.22, 0.95]
    if not np.all(np.isfinite(args.target)) or not (0.2 <= args.duration <= 60.0):
        ap.error("--target must be finite and --duration within [0.2, 60] s")
    def on_sigterm(*_) -> None:
        raise KeyboardInterrupt  # stop like Ctrl-C: every child process is shut down

    signal.signal(signal.SIGTERM, on_sigterm)
    try:
        report = run(args)
    except KeyboardInterrupt:
        print("[demo] interrupted; every process stopped")
        return 130
    except ValueError as exc:
        print(f"[demo] error: {exc}", file=sys.stderr)
        return 1
    ok = (report["final_hand_error_m"] <= 0.002 and report["limit_violations"] == 0
          and report["max_speed_over_limit"] <= 1.0 + 1e-6 and report["feet_drift_m"] <= 1e-6)
    print("[demo] report:")
    for k, v in report.items():
        print(f"  {k:28s} {v}")
    print(f"[demo] plot: {Path(args.out) / 'demo_joints.png'}")
    print("[demo] " + ("OK" if ok else "FAILED: see the report above"))
    print("[demo] the full reaching graph (planner, executor, perception) arrives with issues #3-#6")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
