"""The data shipped with the package: the hands (``robots/``) and the grasp library (``grasps/``).

The repository keeps both folders at its top level; ``pyproject.toml`` maps them to the
resource packages ``planner.robots`` and ``planner.grasps`` (``package-dir``), so an editable
install, an installed wheel and a source checkout without install all find them here,
through `importlib.resources`, whatever the working directory.

A bundled hand is a folder ``robots/<name>/`` holding ``hand.yaml`` (and its URDF); a bundled
grasp is named by its path under ``grasps/``, e.g. ``icub/box_ir2m.yaml``.
"""

from __future__ import annotations

import importlib.resources
import os
from pathlib import Path

from planner.errors import UnknownNameError

HANDS_PACKAGE = "planner.robots"
GRASPS_PACKAGE = "planner.grasps"
HAND_SPEC = "hand.yaml"


def _package_dir(package: str, folder: str) -> Path:
    """The folder of a resource package as a real directory (pinocchio and pybullet need paths).

    A source checkout that was never installed has no ``package-dir`` mapping: its top-level
    folder is used."""
    try:
        return Path(str(importlib.resources.files(package)))
    except ModuleNotFoundError:
        return Path(__file__).resolve().parents[1] / folder


def robots_dir() -> Path:
    """The directory of the bundled hands (``robots/``)."""
    return _package_dir(HANDS_PACKAGE, "robots")


def grasps_dir() -> Path:
    """The directory of the bundled grasp library (``grasps/``)."""
    return _package_dir(GRASPS_PACKAGE, "grasps")


def bundled_hands() -> list[str]:
    """Names of the bundled hands, sorted."""
    return sorted(d.name for d in robots_dir().iterdir() if (d / HAND_SPEC).is_file())


def is_hand_path(ref: str) -> bool:
    """A hand reference is a path when it contains a path separator or ends in .yaml/.yml;
    otherwise it is a name (a bare name is the bundled hand of that name)."""
    return "/" in ref or "\\" in ref or ref.endswith((".yaml", ".yml"))


def bundled_hand_name(path: str | os.PathLike) -> str | None:
    """The name of the bundled hand whose folder `path` is (or whose ``hand.yaml`` it is),
    else None: a plan records a bundled hand by name, not by this machine's path."""
    try:
        rel = Path(path).resolve().relative_to(robots_dir().resolve())
    except ValueError:
        return None
    if len(rel.parts) == 1 or rel.parts[1:] == (HAND_SPEC,):
        return rel.parts[0] if rel.parts[0] in bundled_hands() else None
    return None


def hand_dir(name: str) -> Path:
    """The folder of the bundled hand `name` (it holds ``hand.yaml``).

    Raises:
        UnknownNameError: no bundled hand has that name (the message lists them).
    """
    names = bundled_hands()
    if name not in names:
        raise UnknownNameError("hand", name, names)
    return robots_dir() / name


def bundled_grasps() -> list[str]:
    """Names (paths under ``grasps/``, with ``/``) of the bundled grasp files, sorted."""
    root = grasps_dir()
    return sorted(p.relative_to(root).as_posix() for p in root.rglob("*.yaml"))


def bundled_grasp(rel: str) -> Path:
    """The bundled grasp file named `rel` (its path under ``grasps/``, e.g. ``icub/box_ir2m.yaml``).

    Raises:
        UnknownNameError: no bundled grasp has that name (the message lists them).
    """
    path = grasps_dir() / rel
    if ".." in Path(rel).parts or Path(rel).is_absolute() or not path.is_file():
        raise UnknownNameError("bundled grasp", rel, bundled_grasps())
    return path


def bundled_grasp_name(path: str | os.PathLike) -> str | None:
    """The name of `path` (``icub/box_ir2m.yaml``) when it is a file of the bundled grasp
    library, else None: a plan can record a bundled input by name, not by this machine's path."""
    try:
        return Path(path).resolve().relative_to(grasps_dir().resolve()).as_posix()
    except ValueError:
        return None
