"""Where the package's data files are: the source tree or the ament share directory."""
from __future__ import annotations

import os
from pathlib import Path

PACKAGE_NAME = "humanoid_reach_ros"


def share_dir() -> Path:
    """Directory holding ``config/`` (and ``launch/``).

    Order: ``$HUMANOID_REACH_SHARE`` if set; the source checkout this module lives in
    (``<repo>/config`` exists next to the package); the ament share directory of an
    installed package (``<prefix>/share/humanoid_reach_ros``).
    """
    env = os.environ.get("HUMANOID_REACH_SHARE")
    if env:
        return Path(env)
    here = Path(__file__).resolve().parent
    if (here.parent / "config" / "robots").is_dir():
        return here.parent
    try:
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory(PACKAGE_NAME))
    except Exception as exc:  # pragma: no cover - only on a broken install
        raise FileNotFoundError(
            f"cannot find the {PACKAGE_NAME} share directory (config/); set HUMANOID_REACH_SHARE"
        ) from exc


def config_path(*parts: str) -> Path:
    """Absolute path of a file under ``config/``; relative names resolve there, absolute stay."""
    p = Path(*parts)
    return p if p.is_absolute() else share_dir() / "config" / p


def unique_stamp(directory: Path, suffix: str = "", prefix: str = "") -> str:
    """``<prefix>YYYYmmdd-HHMMSS<suffix>`` (local time); when ``directory`` already holds names of that
    second, ``-2``, ``-3`` ... before the suffix, above the highest there (a removed name is not reused)."""
    import re
    import time

    stamp = prefix + time.strftime("%Y%m%d-%H%M%S")
    same = re.compile(re.escape(stamp) + r"(?:-(\d+))?" + re.escape(suffix))
    taken = [int(m.group(1) or 1) for p in Path(directory).glob(f"{stamp}*") if (m := same.fullmatch(p.name))]
    return stamp + suffix if not taken else f"{stamp}-{max(taken) + 1}{suffix}"


def run_directory(base: str | Path, keep: int) -> Path:
    """A new directory ``base/<YYYYmmdd-HHMMSS>/`` for one run's outputs, ``base/latest`` a link to
    it, and of the run directories in ``base`` the newest ``keep`` kept (older ones removed with
    everything in them; ``keep`` <= 0 keeps all). Only names of the stamp's form are ever removed."""
    import re
    import shutil

    base = Path(base)
    base.mkdir(parents=True, exist_ok=True)
    run = base / unique_stamp(base)
    run.mkdir()
    latest = base / "latest"
    if latest.is_symlink() or latest.exists():
        latest.unlink()
    latest.symlink_to(run.name)
    runs = sorted((p for p in base.iterdir() if p.is_dir() and not p.is_symlink()
                   and re.fullmatch(r"\d{8}-\d{6}(-\d+)?", p.name)), key=lambda p: (p.stat().st_mtime, p.name))
    for old in runs[:-keep] if keep > 0 else []:
        shutil.rmtree(old, ignore_errors=True)
    return run
