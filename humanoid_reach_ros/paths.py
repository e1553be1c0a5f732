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
