"""A stray ``/joint_command`` publisher (test_hosts.py runs it on one of the three hosts).

Waits for ``/joint_states``, then for ``--seconds`` publishes a command that moves one joint
``--delta`` rad from where it stands, towards zero (a joint the looks left at a limit, the chest's
yaw at 45 deg, would be clipped where it stands and not move), at 50 Hz, while it watches
``/joint_states`` (after waiting ``--match-timeout`` for the publisher to match a
subscription). Prints one JSON line: the joint, where it started, whether the publisher
matched a subscription, and how far the joint moved. Not a test module (no ``test_``
prefix): a program run inside a network namespace.
"""
from __future__ import annotations

import argparse
import json
import time

import rclpy
from sensor_msgs.msg import JointState


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--seconds", type=float, default=3.0)
    p.add_argument("--joint", default="")
    p.add_argument("--delta", type=float, default=0.05)
    p.add_argument("--match-timeout", type=float, default=20.0,
                   help="wait this long for the publisher to match a subscription before the --seconds start "
                        "(discovery on a loaded host took longer than the 3 s of publishing)")
    a = p.parse_args()
    rclpy.init()
    node = rclpy.create_node("stray_command")
    states: list[JointState] = []
    node.create_subscription(JointState, "/joint_states", states.append, 50)
    pub = node.create_publisher(JointState, "/joint_command", 10)
    deadline = time.monotonic() + 60.0
    while not states and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    if not states:
        print(json.dumps({"error": "no /joint_states within 60 s"}))
        return
    names = list(states[-1].name)
    joint = a.joint or names[0]
    i = names.index(joint)
    start = states[-1].position[i]
    delta = -a.delta if start > 0.0 else a.delta
    cmd = JointState(name=[joint], position=[start + delta])
    match_deadline = time.monotonic() + a.match_timeout
    while pub.get_subscription_count() == 0 and time.monotonic() < match_deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    matched, moved = 0, 0.0
    t_end = time.monotonic() + a.seconds
    while time.monotonic() < t_end:
        pub.publish(cmd)
        matched = max(matched, pub.get_subscription_count())
        t_next = time.monotonic() + 0.02
        while time.monotonic() < t_next:
            rclpy.spin_once(node, timeout_sec=0.005)
        moved = max(moved, abs(states[-1].position[i] - start))
    print(json.dumps({"joint": joint, "start_rad": start, "matched_subscriptions": matched, "moved_rad": moved}))
    node.destroy_node()
    rclpy.try_shutdown()


if __name__ == "__main__":
    main()
