"""Result codes shared by the core and the nodes, one numbering, mapped 1:1 to the interfaces.

``ExecuteCode`` mirrors ``humanoid_reach_interfaces/action/ExecuteReach`` ``Result`` constants
(``test_codes.py`` checks that every value equals the interface's). The core (``execution/``)
uses these so it never imports a message package.
"""
from __future__ import annotations

from enum import IntEnum


class ExecuteCode(IntEnum):
    """Outcome of an execution (``ExecuteReach.Result.error_code``)."""

    SUCCESS = 0
    INVALID_GOAL = 1        # bad trajectory or targets; the message says why
    NO_JOINT_STATES = 2     # /joint_states missing or stale
    PREEMPTED = 3           # replaced by a newer motion (blended, never a jump)
    CANCELED = 4
    ABORTED = 5             # e.g. joint states went stale while executing, an executor error
    TARGET_NOT_REACHED = 6  # the reference ended, the hand stayed off its end (a damper or a limit held it)




ARM_AUTO, ARM_RIGHT, ARM_LEFT = 0, 1, 2        # PlanReach.Request ARM_* (ExecuteReach.arm uses them)
ARM_NAMES = {ARM_RIGHT: "right", ARM_LEFT: "left"}


class RequestError(ValueError):
    """An input that cannot be executed; ``code`` is an :class:`ExecuteCode`."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = int(code)


__all__ = ["ExecuteCode", "RequestError", "ARM_AUTO", "ARM_RIGHT", "ARM_LEFT", "ARM_NAMES"]
