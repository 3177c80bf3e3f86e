"""Where the package's shared files (config, tracks, trains, bags, launch) are.

From a source checkout (editable install, tests) they are read from the repository, so edits are
seen at once. In an installed package (colcon or a wheel) they are in ``share/train_calib``.
"""

from __future__ import annotations

import sys
from functools import lru_cache
from pathlib import Path

PACKAGE = "train_calib"


@lru_cache(maxsize=1)
def share_dir() -> Path:
    """The directory that holds ``config/``, ``bags/`` and ``launch/``."""
    source_root = Path(__file__).resolve().parent.parent
    if (source_root / "package.xml").is_file() and (source_root / "config").is_dir():
        return source_root
    try:  # a ROS install: ament index
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory(PACKAGE))
    except Exception:
        return Path(sys.prefix) / "share" / PACKAGE


def config_file(name: str) -> Path:
    """A file of ``config/``, e.g. ``config_file("train_calib.yaml")``."""
    return share_dir() / "config" / name


def track_file(name: str) -> Path:
    """A bundled track file by name (``intercity_32km`` or ``intercity_32km.yaml``)."""
    return _named(share_dir() / "config" / "tracks", name)


def train_file(name: str) -> Path:
    """A bundled train file by name (``virm6`` or ``virm6.yaml``)."""
    return _named(share_dir() / "config" / "trains", name)


def bags_dir() -> Path:
    """The bundled bags."""
    return share_dir() / "bags"


def msg_dir() -> Path:
    """The .msg files of train_calib_msgs (installed share dir, else the repository's msg_defs)."""
    candidates = []
    try:
        from ament_index_python.packages import get_package_share_directory

        candidates.append(Path(get_package_share_directory("train_calib_msgs")) / "msg")
    except Exception:
        pass
    candidates.append(Path(sys.prefix) / "share" / "train_calib_msgs" / "msg")
    candidates.append(Path(__file__).resolve().parent.parent / "msg_defs" / "msg")
    for folder in candidates:
        if folder.is_dir() and any(folder.glob("*.msg")):
            return folder
    raise FileNotFoundError("train_calib_msgs .msg files not found (looked in " + ", ".join(map(str, candidates)) + ")")


def _named(folder: Path, name: str) -> Path:
    path = Path(name)
    if path.suffix in (".yaml", ".yml") and path.exists():
        return path
    candidate = folder / (name if name.endswith((".yaml", ".yml")) else f"{name}.yaml")
    return candidate if candidate.exists() else path
