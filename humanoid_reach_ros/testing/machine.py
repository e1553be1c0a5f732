"""What the benchmarks ran on (their JSON states it, as the figures depend on it)."""
from __future__ import annotations

import os
import platform


def describe() -> str:
    """CPU model, CPU count, OS and Python version in one line."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cpus, {platform.system()} {platform.release()}, Python {platform.python_version()}"
