"""Execution of reaching motions: what runs the 5 ms loop, without ROS.

* :mod:`engines`: the two solvers behind one interface (the whole-body executor of
  Kanehiro et al. and the dissertation's dual-arm controller);
* :mod:`supervisor`: accept / execute / cancel / preempt / hold the last safe command,
  with an injected clock and command sink;
* :mod:`loop`: the tick and solver threads at absolute deadlines (real-time priority
  where the OS allows, :mod:`realtime`);
* the loop runs in a process of its own (``nodes/reach_executor_loop.py``: it publishes
  through rclpy, so it lives with the nodes), so the 5 ms deadlines never wait on the ROS
  callbacks of the node (one interpreter lock per process).
"""
