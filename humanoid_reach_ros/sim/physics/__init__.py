"""A MuJoCo physics plant (issue 32): the robot's own files made into a MuJoCo model
(:mod:`.model_builder`), a fixed-timestep stepper with wall-clock pacing (:mod:`.stepper`),
and the balance metrics read from its contacts (:mod:`.metrics`); ``config/robots/<name>/physics.yaml``
is read by :mod:`.config`. No ROS here; ``nodes/joint_driver.py`` adapts it (``plant: mujoco``)."""

PLANTS = ("kinematic", "mujoco")


def check_plant(name: str) -> str:
    """``name`` if it names a plant (:data:`PLANTS`), else ValueError. (Here, not in driver.py: the
    kinematic joint driver checks its parameter without importing mujoco.)"""
    if name not in PLANTS:
        raise ValueError(f"plant must be one of {', '.join(PLANTS)}, got {name!r}")
    return name


__all__ = ["PLANTS", "check_plant"]
