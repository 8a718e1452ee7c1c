"""A node's restart state on disk: written atomically, read back whole or refused.

``write_atomically`` writes a temporary file beside the target, flushes it to the disk and
renames it over the target, so the file is always one whole state, the old or the new,
whatever moment the process is killed at. ``read_state`` turns any failure to read one into a
StateError that says which file and why.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

T = TypeVar("T")


class StateError(ValueError):
    """A stored state that cannot be restored (another format, a torn or foreign file)."""


def write_atomically(path: Path, data: bytes) -> None:
    """Write ``data`` to a temporary file beside ``path``, flush it to the disk and rename it over
    ``path``: the file is the old one or the new one, whenever the process dies. OSError (the
    old file kept, no temporary left) when it cannot be written."""
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError:
        tmp.unlink(missing_ok=True)
        raise
    dir_fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)


def check_format(path: Path | str, kind: str, found, expected: int, reader: str) -> None:
    """StateError unless the stored format ``found`` is ``expected``."""
    if found != expected:
        raise StateError(f"{path}: {kind} format {found}, this {reader} reads {expected}")


def read_state(
    path: Path | str,
    parse: Callable[[Path], T],
    kind: str,
    errors: tuple[type[Exception], ...],
) -> T:
    """``parse(path)``: FileNotFoundError when there is no file; StateError when it is not a
    whole ``kind`` of this format (``parse`` raised StateError or one of ``errors``)."""
    try:
        return parse(Path(path))
    except (FileNotFoundError, StateError):
        raise
    except errors as exc:
        raise StateError(f"{path}: not a whole {kind} ({type(exc).__name__}: {exc})") from exc
