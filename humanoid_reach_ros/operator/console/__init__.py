"""The operator's console in a browser (issue 34): the same flow as ``reach_operator``, another face.

``views`` makes the frames the page draws (voxel layers as changes, the robot from its collision
capsules, the plan's ghost, the camera image); ``control`` holds the controls (one operator at a
time) and runs each action through ``session.OperatorSession``; ``server`` is the aiohttp page
and WebSocket; ``static/`` the page (three.js from npm: ``make setup``). ROS-free:
``nodes/operator_console.py`` is the adapter.
"""
