"""One counters helper: what a component counts for its diagnostics.

A component's counters are a dataclass deriving from :class:`Counters` (named, typed fields,
defaults 0 / ""). :meth:`Counters.count` adds to one (thread-safe: nodes count from several
callback threads), :meth:`Counters.set` records values, and :meth:`Counters.values` is the
consistent copy that becomes the ``/diagnostics`` key/values (``io/msgs.diagnostic_status``).
"""
from __future__ import annotations

import dataclasses
import threading
from typing import Any


@dataclasses.dataclass
class Counters:
    """Base of a component's counters (module doc); subclasses add the fields."""

    def __post_init__(self) -> None:
        self._lock = threading.Lock()

    def count(self, name: str, amount: int | float = 1) -> int | float:
        """Add ``amount`` to the field ``name``; its new value."""
        with self._lock:
            value = getattr(self, name) + amount
            setattr(self, name, value)
            return value

    def set(self, **values: Any) -> None:
        """Record values (field = value) at once."""
        with self._lock:
            for name, value in values.items():
                if not hasattr(self, name):
                    raise AttributeError(f"{type(self).__name__} has no counter {name!r}")
                setattr(self, name, value)

    def values(self, prefix: str = "", exclude: str = "") -> dict[str, Any]:
        """The fields (those starting with ``prefix``, none starting with ``exclude``) as a dict
        for diagnostics: one consistent copy (dicts copied too)."""
        with self._lock:
            out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                   if f.name.startswith(prefix) and not (exclude and f.name.startswith(exclude))}
        return {k: dict(v) if isinstance(v, dict) else v for k, v in out.items()}

    def snapshot(self):
        """A copy of the same type (for a status read off another thread)."""
        with self._lock:
            return dataclasses.replace(self, **{f.name: dict(v) if isinstance(v := getattr(self, f.name), dict) else v
                                                for f in dataclasses.fields(self)})


__all__ = ["Counters"]
