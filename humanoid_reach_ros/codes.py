"""Result and arm codes shared by the core and the nodes, one numbering, mapped 1:1 to the
interfaces: the only place they are defined.

``PlanError`` mirrors ``humanoid_reach_interfaces/srv/PlanReach`` ``Response`` constants,
``ExecuteCode`` ``action/ExecuteReach`` ``Result``'s (the ``Look`` action uses the same first
six), the arm codes ``PlanReach.Request.ARM_*`` (``ExecuteReach`` goals use them too); the
tests check every value against the generated interfaces. The core (``planning/``,
``execution/``) uses these so it never imports a message package; arrays of arms (the goal
postures' ``arm``) hold these codes too, ``ARM_NONE`` where no arm reached.
"""
from __future__ import annotations

from enum import IntEnum


class PlanError(IntEnum):
    """Outcome of a plan request (``PlanReach.Response.error_code``)."""

    SUCCESS = 0
    INVALID_REQUEST = 1
    INVALID_BOUNDS = 2
    UNKNOWN_FRAME = 3
    TARGET_OUT_OF_REACH = 4     # proven by the geometric reach bound (planning/trunk_region.py)
    START_IN_COLLISION = 5
    NO_MAP = 6
    TIMED_OUT = 7               # reserved: no longer returned (NO_GOAL_FOUND / NO_PATH say which part ran out)
    NO_PATH = 8                 # goal postures found, no path to any within the budget
    NO_TARGET = 9
    NO_JOINT_STATES = 10
    BUSY = 11
    UNOBSERVED_SPACE = 12
    NO_GOAL_FOUND = 13          # the budget ran out before a goal posture was found (not proven out of reach)
    UNOBSERVABLE_SPACE = 14     # as UNOBSERVED_SPACE, but no reachable gaze of the head camera sees that space
    INTERNAL_ERROR = 99


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
ARM_NONE = ARM_AUTO                            # in an outcome: no arm
ARMS = ("right", "left")
ARM_NAMES = {ARM_RIGHT: "right", ARM_LEFT: "left"}
ARM_CODES = {"right": ARM_RIGHT, "left": ARM_LEFT}
ARM_REQUESTS = {"auto": ARM_AUTO, **ARM_CODES}  # what a request may name


class RequestError(ValueError):
    """An input that cannot be served, with its code: a :class:`PlanError` for a
    ``/plan_reach`` request (``io/msgs.py``), an :class:`ExecuteCode` for an execution or a
    look (``execution/requests.py``). One class for both (issue 25)."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = int(code)


__all__ = ["PlanError", "ExecuteCode", "RequestError", "ARM_AUTO", "ARM_RIGHT", "ARM_LEFT", "ARM_NONE", "ARMS",
           "ARM_NAMES", "ARM_CODES", "ARM_REQUESTS"]
