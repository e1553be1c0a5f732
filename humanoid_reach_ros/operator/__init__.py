"""The operator's command line without ROS (issue 25: thin nodes).

``cli`` parses and checks the arguments and gives the plan request's inputs as plain values;
``report`` holds the code texts, exit classes, progress bar, summaries and reports; ``session``
is the flow (scan -> marker -> plan with automatic looks -> execute) written against a small
client protocol. ``nodes/reach_operator.py`` implements that client with rclpy, so the flow is
tested with a fake client (test/test_operator_core.py) and run by the real CLI unchanged.
"""
