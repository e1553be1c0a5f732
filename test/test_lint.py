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
