"""codes.py is the one definition of result and arm codes: every value equals the generated
interface constant of the same name, and every interface constant has its code."""
from __future__ import annotations

from humanoid_reach_interfaces.action import ExecuteReach, Look
from humanoid_reach_interfaces.srv import PlanReach

from humanoid_reach_ros import codes


def _constants(cls, prefix: str = "") -> dict[str, int]:
    return {n: getattr(cls, n) for n in dir(cls) if n.isupper() and n.startswith(prefix)
            and isinstance(getattr(cls, n), int)}


def test_plan_codes_are_the_interface_codes():
    assert {e.name: e.value for e in codes.PlanError} == _constants(PlanReach.Response)


def test_execute_codes_are_the_interface_codes():
    assert {e.name: e.value for e in codes.ExecuteCode} == _constants(ExecuteReach.Result)
    # the Look action shares the first six
    assert _constants(Look.Result) == {e.name: e.value for e in codes.ExecuteCode if e.value <= 5}


def test_arm_codes_are_the_interface_codes():
    arms = _constants(PlanReach.Request, "ARM_")
    assert arms == {"ARM_AUTO": codes.ARM_AUTO, "ARM_RIGHT": codes.ARM_RIGHT, "ARM_LEFT": codes.ARM_LEFT}
    assert _constants(ExecuteReach.Goal, "ARM_") in ({}, arms)
    assert codes.ARM_REQUESTS == {"auto": 0, "right": 1, "left": 2}
    assert {codes.ARM_CODES[a] for a in codes.ARMS} == set(codes.ARM_NAMES) and codes.ARM_NONE not in codes.ARM_NAMES
