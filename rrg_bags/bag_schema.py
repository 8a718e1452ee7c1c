"""ros2msg schema text of a message type, as rosbag2 writes it into MCAP files.

The text is the type's own ``.msg`` file, then for each nested type, depth first and each
once, a line of 80 ``=``, a line ``MSG: pkg/Type`` and that type's ``.msg`` text. The ``MSG:``
line spells the type as a ``.msg`` field does (``std_msgs/Header``, not
``std_msgs/msg/Header``): Foxglove's reader rejects the long form. The ``.msg`` files are read
from ``<prefix>/share/<pkg>/msg/`` of each ament prefix (the venv itself for the pip wheels).
"""

from __future__ import annotations

import importlib
import os
import re
import sys
from functools import cache
from pathlib import Path

SCHEMA_ENCODING = "ros2msg"
SEPARATOR = "=" * 80

#: Built-in field types of the .msg format (ROS 2 design "Interface definition").
PRIMITIVE_TYPES = frozenset(
    {
        "bool",
        "byte",
        "char",
        "float32",
        "float64",
        "int8",
        "uint8",
        "int16",
        "uint16",
        "int32",
        "uint32",
        "int64",
        "uint64",
        "string",
        "wstring",
    }
)

_ARRAY_SUFFIX = re.compile(r"\[[^\]]*\]$")
_STRING_BOUND = re.compile(r"<=\d+$")


class UnknownMessageType(LookupError):
    """No ``.msg`` file exists for a type in any ament prefix."""


def ament_prefixes() -> list[Path]:
    """The ament prefixes to search: AMENT_PREFIX_PATH, else this interpreter's prefix."""
    env = os.environ.get("AMENT_PREFIX_PATH", "")
    prefixes = [Path(p) for p in env.split(os.pathsep) if p]
    return prefixes or [Path(sys.prefix)]


def split_type_name(type_name: str) -> tuple[str, str]:
    """``pkg/msg/Type`` or ``pkg/Type`` → (pkg, Type)."""
    parts = type_name.split("/")
    if len(parts) == 3 and parts[1] == "msg":
        return parts[0], parts[2]
    if len(parts) == 2:
        return parts[0], parts[1]
    raise ValueError(f"not a message type name: {type_name!r} (expected pkg/msg/Type)")


@cache
def msg_text(package: str, name: str) -> str:
    """The ``.msg`` definition of ``package/name``, without trailing whitespace."""
    for prefix in ament_prefixes():
        path = prefix / "share" / package / "msg" / f"{name}.msg"
        if path.is_file():
            return path.read_text(encoding="utf-8").rstrip()
    raise UnknownMessageType(
        f"no {package}/msg/{name}.msg under {[str(p) for p in ament_prefixes()]}"
    )


def field_types(package: str, text: str) -> list[tuple[str, str]]:
    """The non-primitive field types of a ``.msg`` text, in field order, as (pkg, Type)."""
    nested = []
    for line in text.splitlines():
        tokens = line.split("#", 1)[0].split()
        if len(tokens) < 2:
            continue
        base = _STRING_BOUND.sub("", _ARRAY_SUFFIX.sub("", tokens[0]))
        if base in PRIMITIVE_TYPES:
            continue
        nested.append(split_type_name(base) if "/" in base else (package, base))
    return nested


@cache
def full_definition(type_name: str) -> str:
    """The ros2msg schema data of ``type_name`` (``pkg/msg/Type``) with every nested type."""
    package, name = split_type_name(type_name)
    sections = [msg_text(package, name)]
    seen: set[tuple[str, str]] = set()

    def append_nested(pkg: str, text: str) -> None:
        for dep in field_types(pkg, text):
            if dep in seen:
                continue
            seen.add(dep)
            dep_text = msg_text(*dep)
            sections.append(f"{SEPARATOR}\nMSG: {dep[0]}/{dep[1]}\n{dep_text}")
            append_nested(dep[0], dep_text)

    append_nested(package, sections[0])
    return "\n".join(sections) + "\n"


def message_class(type_name: str) -> type:
    """The generated Python class of ``pkg/msg/Type``."""
    package, kind, name = type_name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), name)


def layout(text: str) -> list[str]:
    """What decoding a ros2msg schema text depends on: each nested type's ``MSG:`` line and the
    fields' types and names in order, without comments, constants and default values."""
    out = []
    for line in text.splitlines():
        tokens = line.split("#", 1)[0].split()
        if tokens[:1] == ["MSG:"]:
            out.append(" ".join(tokens))
        elif len(tokens) >= 2 and "=" not in tokens[1] and tokens[2:3] != ["="]:
            out.append(f"{tokens[0]} {tokens[1]}")
    return out


def same_layout(type_name: str, recorded: str) -> bool:
    """Whether a recorded schema text of ``type_name`` decodes as this version's type (the same
    fields in the same order, in every nested type)."""
    try:
        current = full_definition(type_name)
    except (UnknownMessageType, ValueError):
        return False
    return layout(recorded) == layout(current)
