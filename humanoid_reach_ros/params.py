"""A declared parameter, without ROS: what ``nodes/common.declare_parameters`` declares with a
ROS parameter descriptor, and what the core's configurations (``execution/config.py``) take
their defaults from."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class ParamSpec:
    """A declared parameter: default (its type is the parameter's type), description,
    optional inclusive range, read-only (fixed after start-up) or not, constraints in words."""

    default: Any
    description: str
    range: tuple[float, float] | None = None
    read_only: bool = True
    constraints: str = ""


__all__ = ["ParamSpec"]
