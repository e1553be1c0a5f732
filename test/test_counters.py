"""The one counters helper (issue 25, part 4): counts from several threads add up, values()
is a consistent copy for diagnostics, an unknown counter is refused."""
from __future__ import annotations

import dataclasses
import threading

import pytest

from humanoid_reach_ros.counters import Counters


@dataclasses.dataclass
class Example(Counters):
    goals: int = 0
    maps_received: int = 0
    map_source: str = "none"
    problems: dict = dataclasses.field(default_factory=dict)


def test_counts_from_threads_add_up_and_values_copy() -> None:
    c = Example()
    threads = [threading.Thread(target=lambda: [c.count("goals") for _ in range(2000)]) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert c.goals == 8000 and c.count("maps_received", 3) == 3
    c.set(map_source="/voxel_map")
    c.problems["stale"] = 1
    assert c.values(prefix="map") == {"maps_received": 3, "map_source": "/voxel_map"}
    assert set(c.values(exclude="map")) == {"goals", "problems"}
    copy = c.values()["problems"]
    copy["stale"] = 99
    snap = c.snapshot()
    c.problems["stale"] = 2
    assert c.problems["stale"] == 2 and snap.problems["stale"] == 1 and isinstance(snap, Example)
    with pytest.raises(AttributeError, match="no counter 'nope'"):
        c.set(nope=1)
