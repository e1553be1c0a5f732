"""Validation of values read from the package's YAML files (robot, scenes, markers).

Every checker raises ``ValueError`` whose text starts with ``where`` (file and entry),
so a bad file is reported as "scene plant.yaml: primitive #3 radius: must be > 0, got -1".
"""
from __future__ import annotations

import math
from typing import Any, Iterable

import numpy as np

Vec3 = tuple[float, float, float]


def top_level(doc: Any, keys: Iterable[str], where: str) -> dict:
    """``doc`` must be a mapping whose keys are among ``keys``."""
    if not isinstance(doc, dict):
        raise ValueError(f"{where}: expected a mapping at the top level")
    allowed = set(keys)
    unknown = set(doc) - allowed
    if unknown:
        raise ValueError(f"{where}: unknown top-level key(s) {sorted(unknown)}; expected {sorted(allowed)}")
    return doc


def number(x: Any, where: str) -> float:
    """A finite int or float (bools are refused)."""
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
        raise ValueError(f"{where}: expected a finite number, got {x!r}")
    return float(x)


def positive(x: Any, where: str) -> float:
    v = number(x, where)
    if not v > 0.0:
        raise ValueError(f"{where}: must be > 0, got {v}")
    return v


def vec3(x: Any, where: str) -> Vec3:
    """A list of three finite numbers."""
    if not isinstance(x, (list, tuple)) or len(x) != 3:
        raise ValueError(f"{where}: expected [x, y, z], got {x!r}")
    return tuple(number(v, where) for v in x)  # type: ignore[return-value]


def unit(x: Any, where: str) -> Vec3:
    """A non-zero 3-vector, normalised."""
    v = np.asarray(vec3(x, where))
    n = float(np.linalg.norm(v))
    if n < 1e-9:
        raise ValueError(f"{where}: must be a non-zero vector, got {tuple(v)}")
    return tuple(float(c) for c in v / n)  # type: ignore[return-value]


def named_entry(entry: Any, where: str, expected: str) -> tuple[str, str]:
    """A mapping with a non-empty ``name``; returns the name and ``where`` extended by it.
    ``expected`` says what else the mapping must hold (for the error text)."""
    if not isinstance(entry, dict):
        raise ValueError(f"{where}: expected a mapping with 'name' and {expected}")
    name = entry.get("name")
    if not isinstance(name, str) or not name:
        raise ValueError(f"{where}: missing or empty 'name'")
    return name, f"{where} ({name!r})"
