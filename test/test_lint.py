"""The repository is clean under its linter: ``ruff check .`` (config: ruff.toml) finds nothing.

``make test`` runs the same check before pytest; this test keeps it part of any pytest run.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_ruff_check_finds_nothing() -> None:
    proc = subprocess.run([sys.executable, "-m", "ruff", "check", "."], cwd=REPO, capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, f"ruff check . failed ({proc.returncode}):\n{proc.stdout}{proc.stderr}"


def test_no_class_is_defined_twice() -> None:
    """One name, one class across the package, bench/ and tools/ (issue 25): two ``RequestError``s,
    ``StepResult``s or ``Counters`` made a reader ask which one a module meant."""
    import ast
    from collections import defaultdict

    where: dict[str, list[str]] = defaultdict(list)
    for root in ("humanoid_reach_ros", "bench", "tools"):
        for path in sorted((REPO / root).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.ClassDef):
                    where[node.name].append(f"{path.relative_to(REPO)}:{node.lineno}")
    twice = {name: files for name, files in where.items() if len(files) > 1}
    assert not twice, twice
