"""A MuJoCo physics plant (issue 32): the robot's own files made into a MuJoCo model
(:mod:`.model_builder`), a fixed-timestep stepper with wall-clock pacing (:mod:`.stepper`),
and the balance metrics read from its contacts (:mod:`.metrics`); ``config/robots/<name>/physics.yaml``
is read by :mod:`.config`. No ROS here; ``nodes/joint_driver.py`` adapts it (``plant: mujoco``)."""
