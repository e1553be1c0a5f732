"""The ``reach_executor`` control process's ROS side: a publish-only rclpy node (``<node>_loop``)
that publishes ``/joint_command`` and ``/executor/metrics`` from the loop's tick thread, and the
child's entry point (``python -m humanoid_reach_ros.nodes.reach_executor_loop <fd>``: the
process itself is ``execution/process.py``'s, without ROS)."""
from __future__ import annotations

import sys
import time
from multiprocessing.connection import Connection
from typing import Callable

from humanoid_reach_ros.execution.process import LoopConfig, LoopOutput, child_main

SLOW_PUBLISH_LOGS = 3          # blocked publishes logged one by one, then one line every 10 s


def ros_output(config: LoopConfig, joint_names: list[str], log: Callable[[str, str], None]) -> LoopOutput:
    """The loop's :class:`LoopOutput`: a publish-only node whose writes release the interpreter
    lock (``io/gil_free.py``: a DDS write that blocks holds up the tick thread only, never the
    solver); blocked writes are counted and logged (the first few, then one line every 10 s)."""
    import numpy as np
    import rclpy
    from humanoid_reach_interfaces.msg import ExecutorMetrics
    from rclpy.signals import SignalHandlerOptions
    from sensor_msgs.msg import JointState

    from humanoid_reach_ros.io import exec_msgs, msgs
    from humanoid_reach_ros.io.gil_free import GilFreePublisher

    rclpy.init(args=["--ros-args", *config.ros_args] if config.ros_args else None,
               signal_handler_options=SignalHandlerOptions.NO,
               **({"domain_id": config.domain_id} if config.domain_id is not None else {}))
    node = rclpy.create_node(config.node_name, namespace=config.namespace, start_parameter_services=False,
                             use_global_arguments=False)
    command_pub = GilFreePublisher(node.create_publisher(JointState, config.command_topic, 10))
    metrics_pub = GilFreePublisher(node.create_publisher(ExecutorMetrics, config.metrics_topic, 10))
    command = msgs.joint_state(joint_names, np.zeros(len(joint_names)))
    clock = node.get_clock()
    counter = [0]
    slow = {"count": 0, "max_s": 0.0, "logged_at": -float("inf")}

    def sink(joints, metrics, overruns) -> None:   # the tick thread
        t0 = time.perf_counter()
        stamp = clock.now().to_msg()
        command_pub.publish(msgs.fill_joint_state(command, joints, stamp=stamp))
        if metrics is not None:
            counter[0] += 1
            if counter[0] % config.metrics_decimation == 0:
                metrics_pub.publish(exec_msgs.executor_metrics(metrics, overruns, stamp, config.map_frame))
        took = time.perf_counter() - t0
        if took > config.supervisor.period_s:
            # a DDS write that blocked (the tick thread waited; the solver went on)
            slow["count"] += 1
            slow["max_s"] = max(slow["max_s"], took)
            now = time.monotonic()
            if slow["count"] <= SLOW_PUBLISH_LOGS or now - slow["logged_at"] > 10.0:
                slow["logged_at"] = now
                log("warning", f"publishing one command took {took * 1e3:.1f} ms: the DDS write blocked the tick "
                               f"thread (deadlines missed meanwhile; the solver went on); {slow['count']} so far")

    def close() -> None:
        try:
            node.destroy_node()
        finally:
            rclpy.try_shutdown()

    return LoopOutput(sink, command_pub.mode, slow, close)


if __name__ == "__main__":
    _conn = Connection(int(sys.argv[1]))
    child_main(_conn, _conn.recv(), ros_output)
