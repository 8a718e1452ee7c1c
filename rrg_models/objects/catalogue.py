"""The installed objects: the paper's ten, shipped with the package, and the user's own.

Each object is a folder (rrg_models.objects.object_file). The built-in ones live in
``builtin/`` next to this module; user objects in ``user_objects_dirs()``: the folders named
by the ``RRG_OBJECTS_DIR`` environment variable (a list, like ``PATH``; the first is where
``rrg-object add`` installs), else ``$XDG_DATA_HOME/rrg/objects``
(``~/.local/share/rrg/objects``). A user object never shadows a built-in one, and an earlier
folder's object shadows a later one's.
"""

from __future__ import annotations

import logging
import os
from functools import cache
from pathlib import Path

from rrg_models.objects.object_file import OBJECT_FILE, load_object_folder
from rrg_models.objects.object_model import ObjectModel

log = logging.getLogger(__name__)

#: The paper's objects (Fig. 5 and 6), in the paper's order: the built-in catalogue.
PAPER_OBJECTS: tuple[str, ...] = (
    "powerdrill",
    "brita_pitcher",
    "cooler",
    "taperoll",
    "can",
    "wooden_bowl",
    "cup",
    "teabox",
    "box",
    "giant_teacup",
)
#: Where the built-in object folders live (inside the package: read-only at run time).
BUILTIN_DIR = Path(__file__).with_name("builtin")
#: The environment variable naming the folder of user objects.
USER_DIR_ENV = "RRG_OBJECTS_DIR"


def user_objects_dirs() -> list[Path]:
    """The folders of user objects: $RRG_OBJECTS_DIR's, else $XDG_DATA_HOME/rrg/objects."""
    listed = [p for p in os.environ.get(USER_DIR_ENV, "").split(os.pathsep) if p]
    if listed:
        return [Path(p).expanduser() for p in listed]
    data_home = os.environ.get("XDG_DATA_HOME") or Path.home() / ".local" / "share"
    return [Path(data_home) / "rrg" / "objects"]


def user_objects_dir() -> Path:
    """The folder user objects are installed into: the first of user_objects_dirs()."""
    return user_objects_dirs()[0]


def object_folders() -> dict[str, Path]:
    """Every installed object's folder by name: the built-ins in the paper's order, then the
    user's objects by name."""
    folders = {name: BUILTIN_DIR / name for name in PAPER_OBJECTS}
    for user in user_objects_dirs():
        if not user.is_dir():
            continue
        for folder in sorted(user.iterdir()):
            if not (folder / OBJECT_FILE).is_file():
                continue
            if folder.name in folders:
                log.warning("ignoring %s: %s has its name", folder, folders[folder.name])
                continue
            folders[folder.name] = folder
    return folders


def object_names() -> tuple[str, ...]:
    """The names of every installed object (see object_folders)."""
    return tuple(object_folders())


def unknown_object_message(name: str) -> str:
    """The error text for an object that is not installed: what is."""
    return f"unknown object {name!r}; installed: {', '.join(object_names())}"


def get_object(name: str) -> ObjectModel:
    """The installed object called ``name`` (loaded once per version of its object file)."""
    folders = object_folders()
    if name not in folders:
        raise KeyError(unknown_object_message(name))
    path = folders[name] / OBJECT_FILE
    return _load(folders[name], path.stat().st_mtime_ns)


@cache
def _load(folder: Path, mtime_ns: int) -> ObjectModel:
    """The object in ``folder`` (``mtime_ns`` keys the cache: an edited file is reloaded)."""
    return load_object_folder(folder)
