"""The error codes and arm codes shared by the core, the nodes and the operator CLI: the only
place they are defined in Python.

``ErrorCode`` is ``humanoid_reach_interfaces/msg/ErrorCode``, the one numbering every interface
embeds (``PlanReach``'s response, ``ExecuteReach``'s and ``Look``'s results); ``PlanError`` and
``ExecuteCode`` are the same enum under the names the planner and the executor use.
``CODE_INFO`` holds each code's ``reach_operator`` exit class and hint. The arm codes are
``PlanReach.Request.ARM_*`` (``ExecuteReach`` goals use them too). The tests check every value
against the generated interfaces. The core (``planning/``, ``execution/``) uses these so it
never imports a message package; arrays of arms (the goal postures' ``arm``) hold these codes
too, ``ARM_NONE`` where no arm reached. :class:`RequestError` is the core's one error type.
"""
from __future__ import annotations

import sys
from enum import IntEnum


class ErrorCode(IntEnum):
    """The outcome of a request (``msg/ErrorCode``: every interface's ``error_code.val``)."""

    SUCCESS = 0
    INVALID_REQUEST = 1         # a malformed request, goal or target; the message says which
    INVALID_BOUNDS = 2
    UNKNOWN_FRAME = 3
    TARGET_OUT_OF_REACH = 4     # proven by the geometric reach bound (planning/trunk_region.py)
    START_IN_COLLISION = 5
    NO_MAP = 6
    TIMED_OUT = 7               # reserved: no longer returned (NO_GOAL_FOUND / NO_PATH say which part ran out)
    NO_PATH = 8                 # goal postures found, no path to any within the budget
    NO_TARGET = 9
    NO_JOINT_STATES = 10        # /joint_states missing or stale (a plan, a motion, a look)
    BUSY = 11
    UNOBSERVED_SPACE = 12
    NO_GOAL_FOUND = 13          # the budget ran out before a goal posture was found (not proven out of reach),
    #                             or at once when the target lies in a pocket the map closes (planning/enclosure.py)
    UNOBSERVABLE_SPACE = 14     # as UNOBSERVED_SPACE, but no reachable gaze of the head camera sees that space
    PREEMPTED = 20              # a motion replaced by a newer one (blended, never a jump)
    CANCELED = 21
    ABORTED = 22                # e.g. joint states went stale while executing, the control process exited
    TARGET_NOT_REACHED = 23     # the reference ended, the hand stayed off its end (a damper or a limit held it)
    INTERNAL_ERROR = 99


#: the planner's and the executor's names of the one enum
PlanError = ExecuteCode = ErrorCode

#: reach_operator's exit codes by failure class (docs/operator.md)
EXIT = {"success": 0, "internal": 1, "usage": 2, "unavailable": 3, "invalid": 4, "no_motion": 5,
        "no_input": 6, "execution": 7, "canceled": 130}

#: each code's exit class (``EXIT``) and the hint reach_operator prints after the server's message
#: ("" where that message already says what to do)
CODE_INFO: dict[ErrorCode, tuple[str, str]] = {
    ErrorCode.SUCCESS: ("success", "done"),
    ErrorCode.INVALID_REQUEST: ("invalid", "the request was refused as invalid: check the arguments"),
    ErrorCode.INVALID_BOUNDS: ("invalid", "WGR lower > upper, or a rotation bound outside [-pi, pi] (+-180 deg): "
                               "check --wgr-deg / --wgr"),
    ErrorCode.UNKNOWN_FRAME: ("invalid", "the target frame is not known: use --frame world or base_link"),
    # the planner's message gives the proof (arm, shoulder, what was searched) and the remedy
    ErrorCode.TARGET_OUT_OF_REACH: ("no_motion", ""),
    # the planner's message names the links, the nearest voxels and the retreats it tried
    ErrorCode.START_IN_COLLISION: ("no_motion", ""),
    ErrorCode.NO_MAP: ("no_input", "the planner has no environment model: start voxel_mapper (or give reach_planner "
                       "a scene_file)"),
    ErrorCode.TIMED_OUT: ("no_motion", "the time budget ran out: raise --budget"),
    ErrorCode.NO_PATH: ("no_motion", "goal postures were found but no path to them: raise --budget or --goals"),
    ErrorCode.NO_TARGET: ("no_input", "no recent /target_pose from the marker: is marker_localizer running and the "
                          "marker in view? Or give --target"),
    ErrorCode.NO_JOINT_STATES: ("no_input", "no recent /joint_states: is joint_driver running?"),
    ErrorCode.BUSY: ("no_input", "another request is being planned: try again"),
    # the planner's message names the place and the remedies (the automatic look ran out, or was off)
    ErrorCode.UNOBSERVED_SPACE: ("no_input", ""),
    ErrorCode.UNOBSERVABLE_SPACE: ("no_motion", ""),
    # the planner's message says which arms were tried and what to change
    ErrorCode.NO_GOAL_FOUND: ("no_motion", ""),
    ErrorCode.PREEMPTED: ("execution", "replaced by a newer goal or /reach_trajectory"),
    ErrorCode.CANCELED: ("canceled", ""),   # the executor's message says it holds the last command
    ErrorCode.ABORTED: ("execution", "the executor stopped the motion and holds the robot (e.g. stale joint states)"),
    ErrorCode.TARGET_NOT_REACHED: ("execution", "the hand was held off the trajectory's end (a collision damper or a "
                                   "joint limit); the robot holds there: plan again from here"),
    ErrorCode.INTERNAL_ERROR: ("internal", "the node failed internally: see its log"),
}


def code_name(code: int) -> str:
    """``UNOBSERVED_SPACE``; ``UNKNOWN_CODE_<n>`` for a number this package does not define."""
    try:
        return ErrorCode(int(code)).name
    except ValueError:
        return f"UNKNOWN_CODE_{int(code)}"


ARM_AUTO, ARM_RIGHT, ARM_LEFT = 0, 1, 2        # PlanReach.Request ARM_* (ExecuteReach.arm uses them)
ARM_NONE = ARM_AUTO                            # in an outcome: no arm
ARMS = ("right", "left")
ARM_NAMES = {ARM_RIGHT: "right", ARM_LEFT: "left"}
ARM_CODES = {"right": ARM_RIGHT, "left": ARM_LEFT}
ARM_REQUESTS = {"auto": ARM_AUTO, **ARM_CODES}  # what a request may name


class RequestError(ValueError):
    """The core's one error type: a request, goal or input that cannot be served, with its
    ``code`` (an :class:`ErrorCode`), the ``message``, its ``source`` (the module that raised it,
    unless given) and ``extra`` details for the answer (e.g. the planner's ``unobserved_points``)."""

    def __init__(self, code: int, message: str, source: str = "", **extra) -> None:
        super().__init__(message)
        self.code = ErrorCode(int(code))
        self.message = message
        self.source = source or sys._getframe(1).f_globals.get("__name__", "")
        self.extra = extra


__all__ = ["ErrorCode", "PlanError", "ExecuteCode", "CODE_INFO", "EXIT", "code_name", "RequestError", "ARM_AUTO",
           "ARM_RIGHT", "ARM_LEFT", "ARM_NONE", "ARMS", "ARM_NAMES", "ARM_CODES", "ARM_REQUESTS"]
