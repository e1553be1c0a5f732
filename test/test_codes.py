"""codes.py is the one definition of error and arm codes: one error numbering serves every
interface (issue 25): ``msg/ErrorCode`` holds it, ``PlanReach``'s response and ``ExecuteReach``'s
and ``Look``'s results embed it and define no codes of their own, and every value equals
``codes.ErrorCode``'s of the same name."""
from __future__ import annotations

import pytest
from humanoid_reach_interfaces.action import ExecuteReach, Look
from humanoid_reach_interfaces.msg import ErrorCode
from humanoid_reach_interfaces.srv import PlanReach

from humanoid_reach_ros import codes


def _constants(cls, prefix: str = "") -> dict[str, int]:
    return {n: getattr(cls, n) for n in dir(cls) if n.isupper() and n.startswith(prefix)
            and isinstance(getattr(cls, n), int)}


def test_one_numbering_is_the_interface_error_code():
    assert {e.name: e.value for e in codes.ErrorCode} == _constants(ErrorCode)
    assert codes.PlanError is codes.ExecuteCode is codes.ErrorCode
    assert len(set(_constants(ErrorCode).values())) == len(_constants(ErrorCode))   # one name per code


@pytest.mark.parametrize("cls", [PlanReach.Response, ExecuteReach.Result, Look.Result])
def test_every_interface_embeds_it_and_defines_no_codes_of_its_own(cls):
    assert cls.get_fields_and_field_types()["error_code"] == "humanoid_reach_interfaces/ErrorCode"
    assert isinstance(cls().error_code, ErrorCode)
    assert _constants(cls, "") == {}, _constants(cls)


def test_the_error_type_carries_its_code_and_source():
    err = codes.RequestError(codes.ErrorCode.NO_MAP, "no map yet", unobserved_points=None)
    assert err.code is codes.ErrorCode.NO_MAP and str(err) == err.message == "no map yet"
    assert err.source == __name__ and err.extra == {"unobserved_points": None}
    assert codes.RequestError(1, "x", source="planner").source == "planner"
    assert codes.code_name(12) == "UNOBSERVED_SPACE" and codes.code_name(42) == "UNKNOWN_CODE_42"
    assert set(codes.CODE_INFO) == set(codes.ErrorCode)


def test_arm_codes_are_the_interface_codes():
    arms = _constants(PlanReach.Request, "ARM_")
    assert arms == {"ARM_AUTO": codes.ARM_AUTO, "ARM_RIGHT": codes.ARM_RIGHT, "ARM_LEFT": codes.ARM_LEFT}
    assert _constants(ExecuteReach.Goal, "ARM_") in ({}, arms)
    assert codes.ARM_REQUESTS == {"auto": 0, "right": 1, "left": 2}
    assert {codes.ARM_CODES[a] for a in codes.ARMS} == set(codes.ARM_NAMES) and codes.ARM_NONE not in codes.ARM_NAMES
