"""``rrg-object``: the installed objects.

    rrg-object list              # every installed object: built-in or user, and what it has
    rrg-object remove NAME       # delete a user object and its cached observation tables

User objects live in ``$RRG_OBJECTS_DIR`` (default ``~/.local/share/rrg/objects``); the
paper's ten ship with the package and cannot be removed. Every CLI and node takes an
installed object by its name.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

from rrg_estimator.obs_tables import DEFAULT_CACHE_DIR
from rrg_sim.objects import (
    PAPER_OBJECTS,
    ObjectFileError,
    get_object,
    object_folders,
    unknown_object_message,
    user_objects_dir,
)
from rrg_sim.objects.object_model import REORIENTATION_FILE, SETTLING_FILE


def cached_tables(name: str, cache_dir: Path = DEFAULT_CACHE_DIR) -> list[Path]:
    """The object's observation tables in the cache (rrg_estimator.obs_tables file names)."""
    return sorted(Path(cache_dir).glob(f"{name}__*.npz"))


def describe(name: str, folder: Path) -> str:
    """One line about an installed object: origin, parts, mass, studies, tables, goal."""
    origin = "built-in" if name in PAPER_OBJECTS else "user"
    studies = [f for f in (SETTLING_FILE, REORIENTATION_FILE) if (folder / f).exists()]
    try:
        obj = get_object(name)
    except ObjectFileError as exc:
        return f"{name:14s} {origin:8s} INVALID: {exc}"
    return (
        f"{name:14s} {origin:8s} {len(obj.parts):3d} parts {obj.mass:6.3f} kg  "
        f"studies: {', '.join(s.removesuffix('.json') for s in studies) or 'none':24s} "
        f"tables: {len(cached_tables(name)):2d}  {obj.description}"
    )


def cmd_list(args: argparse.Namespace) -> int:
    folders = object_folders()
    for name, folder in folders.items():
        print(describe(name, folder))
    print(f"{len(folders)} objects; user objects in {user_objects_dir()}")
    return 0


def remove_object(name: str, cache_dir: Path = DEFAULT_CACHE_DIR) -> Path:
    """Delete the user object ``name`` and its tables cached in ``cache_dir``; returns its
    folder. KeyError if it is not installed, ValueError for a built-in one."""
    folders = object_folders()
    if name not in folders:
        raise KeyError(unknown_object_message(name))
    if name in PAPER_OBJECTS:
        raise ValueError(f"{name!r} is built in (one of the paper's objects): not removed")
    for table in cached_tables(name, cache_dir):
        table.unlink()
    shutil.rmtree(folders[name])
    return folders[name]


def cmd_remove(args: argparse.Namespace) -> int:
    try:
        folder = remove_object(args.name)
    except (KeyError, ValueError) as exc:
        print(f"rrg-object remove: {exc.args[0]}", file=sys.stderr)
        return 2
    print(f"removed {args.name} ({folder}) and its cached tables")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="rrg-object", description=__doc__.split("\n\n")[0].strip("`: ")
    )
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("list", help="every installed object").set_defaults(run=cmd_list)
    remove = sub.add_parser("remove", help="delete a user object and its cached tables")
    remove.add_argument("name")
    remove.set_defaults(run=cmd_remove)
    args = parser.parse_args(argv)
    return args.run(args)


if __name__ == "__main__":
    sys.exit(main())
