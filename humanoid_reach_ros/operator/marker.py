"""What ``reach_operator --marker`` hears of the marker: the ``MarkerWatch`` the flow reads.

The planner takes the marker's ``/target_pose`` only while it is recent, and marker_localizer
publishes it only while the marker is in view; its diagnostics hold the marker's last known
position, and ``/joint_states`` the posture to aim the head from (``session.OperatorSession.
ensure_marker_target``). :class:`MarkerSightings` keeps these from the messages (read by
attribute: ROS-free); the client's ``watch_marker`` feeds its callbacks for a ``with`` block.
"""
from __future__ import annotations

import math
import time
from typing import Any, Callable, Protocol


class MarkerWatch(Protocol):
    """``pose_t``: monotonic time of the last ``/target_pose`` (-inf: none); ``position``: its x y z;
    ``last``: the marker's last known position from marker_localizer's diagnostics; ``diagnostics``:
    any heard; ``joints``: {name: angle} of the last /joint_states, or None; ``map_voxels``: the
    voxel mapper's occupied voxels from its last diagnostics, None before any (the scan's report)."""

    pose_t: float
    position: tuple[float, float, float] | None
    last: list[float] | None
    diagnostics: bool
    joints: dict[str, float] | None
    map_voxels: int | None

    def publishers(self) -> int:
        """``/target_pose`` publishers known now."""


class MarkerSightings:
    """A ``MarkerWatch`` fed by the callbacks below; ``publishers`` counts /target_pose publishers."""

    def __init__(self, publishers: Callable[[], int]) -> None:
        self.publishers = publishers
        self.pose_t, self.position, self.last, self.diagnostics = -math.inf, None, None, False
        self.joints: dict[str, float] | None = None
        self.map_voxels: int | None = None

    def on_pose(self, m: Any) -> None:
        """A ``geometry_msgs/PoseStamped`` on /target_pose."""
        p = m.pose.position
        self.pose_t, self.position = time.monotonic(), (p.x, p.y, p.z)

    def on_diagnostics(self, m: Any) -> None:
        """A ``diagnostic_msgs/DiagnosticArray``: marker_localizer's status, with the last position;
        the voxel mapper's map status (``occupied_voxels``)."""
        for st in m.status:
            if st.name.endswith(": map"):
                v = {kv.key: kv.value for kv in st.values}
                if "occupied_voxels" in v:
                    self.map_voxels = int(v["occupied_voxels"])
            if st.name.startswith("marker_localizer"):
                v = {kv.key: kv.value for kv in st.values}
                self.diagnostics = True
                if "target_x_m" in v:
                    self.last = [float(v["target_x_m"]), float(v["target_y_m"]), float(v["target_z_m"])]

    def on_joint_state(self, m: Any) -> None:
        """A ``sensor_msgs/JointState``."""
        self.joints = dict(zip(m.name, (float(q) for q in m.position)))
