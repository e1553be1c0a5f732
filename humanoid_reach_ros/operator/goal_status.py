"""The goals' status as the action servers publish it, standing in for a lost response.

A service response can be lost when the server's response writer has not yet matched a fresh
client's reader (the server logs "failed to send response (timeout): client will not receive
response"; bench/session saw it once for /look's goal response: the scan ran to the end and the
CLI timed out). The goal's status (a topic, transient local) then tells: any status of our goal
id for ``LOST_RESPONSE_GRACE_S`` means accepted; a final one for as long means finished (the
result request is sent again: the server keeps results). ROS-free: ids are bytes, statuses
``action_msgs/GoalStatus`` numbers.
"""
from __future__ import annotations

import time

# action_msgs/GoalStatus: any status of our goal id means the server accepted it; these three end it
GOAL_KNOWN = frozenset(range(1, 7))        # ACCEPTED, EXECUTING, CANCELING, SUCCEEDED, CANCELED, ABORTED
GOAL_DONE = frozenset((4, 5, 6))           # SUCCEEDED, CANCELED, ABORTED
LOST_RESPONSE_GRACE_S = 1.0   # the status said so this long and the response did not come: taken as lost


class GoalStatuses:
    """Goal id -> (status, when first seen with that status)."""

    def __init__(self) -> None:
        self.seen: dict[bytes, tuple[int, float]] = {}

    def update(self, goal_id: bytes, status: int, now: float | None = None) -> None:
        now = time.monotonic() if now is None else now
        old = self.seen.get(goal_id)
        self.seen[goal_id] = (int(status), old[1] if old and old[0] == status else now)

    def says(self, goal_id: bytes, statuses: frozenset[int], now: float | None = None) -> bool:
        """The goal's status is one of ``statuses`` and has been for ``LOST_RESPONSE_GRACE_S``."""
        st = self.seen.get(goal_id)
        now = time.monotonic() if now is None else now
        return st is not None and st[0] in statuses and now - st[1] > LOST_RESPONSE_GRACE_S
