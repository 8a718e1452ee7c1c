"""Small helpers to write MJCF with ElementTree: number formatting and sub-elements."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Iterable

import numpy as np
from scipy.spatial.transform import Rotation


def fmt(v) -> str:
    """Scalar or vector → MJCF attribute text (9 significant digits, space separated)."""
    if isinstance(v, str):
        return v
    a = np.atleast_1d(np.asarray(v, dtype=float))
    return " ".join(f"{x:.9g}" for x in a)


def sub(parent: ET.Element, tag: str, **attrs) -> ET.Element:
    """Append a child element; attribute values go through ``fmt`` (None values are dropped)."""
    return ET.SubElement(parent, tag, {k: fmt(v) for k, v in attrs.items() if v is not None})


def pose_attrs(T: np.ndarray) -> dict[str, str]:
    """(4,4) transform → MJCF ``pos`` and ``quat`` (w x y z) attributes."""
    q = Rotation.from_matrix(T[:3, :3]).as_quat(scalar_first=True)
    return {"pos": fmt(T[:3, 3]), "quat": fmt(q)}


def full_inertia_in(T: np.ndarray, inertia6: Iterable[float]) -> str:
    """Rotate a (Ixx, Iyy, Izz, Ixy, Ixz, Iyz) inertia given in frame T's axes into the parent's."""
    ixx, iyy, izz, ixy, ixz, iyz = inertia6
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    R = T[:3, :3]
    Ip = R @ inertia @ R.T
    return fmt([Ip[0, 0], Ip[1, 1], Ip[2, 2], Ip[0, 1], Ip[0, 2], Ip[1, 2]])


def to_xml(root: ET.Element) -> str:
    """Pretty-printed XML text of an element tree."""
    ET.indent(root, space="  ")
    return ET.tostring(root, encoding="unicode") + "\n"
