"""Tooling of the tests, benches and tools, not of the product: the figures of a running graph
(:mod:`.graph_metrics`: CPU of a process tree, gaps between messages, the feet drift and COG
drift measured from ``/joint_states``) and the machine a figure was measured on
(:mod:`.machine`). Nothing else in the package imports it (``test/test_layering.py`` checks);
the orchestration of a graph here (``humanoid_reach_ros.graph``) stays in the product: ``demo``
and ``hr_graph`` start the graph with it where ``ros2 launch`` is missing.
"""
