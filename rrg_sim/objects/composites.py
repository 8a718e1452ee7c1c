"""Builders of primitives and of the concave composites (rings, handles) the objects are made of."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from .primitives import Primitive

#: Tangential overlap factor of adjacent ring segments (chosen: closes the seams with margin).
RING_OVERLAP = 1.15


def _quat(rotation: Rotation | None) -> tuple[float, float, float, float]:
    if rotation is None:
        return (1.0, 0.0, 0.0, 0.0)
    return tuple(rotation.as_quat(scalar_first=True))


def box(half, pos, rotation: Rotation | None = None) -> Primitive:
    """Box with half-extents ``half`` (3,) [m] centred at ``pos`` in the object frame."""
    return Primitive("box", tuple(half), tuple(pos), _quat(rotation))


def cylinder(radius: float, half_height: float, pos, rotation: Rotation | None = None) -> Primitive:
    """Cylinder along its local z (vertical unless rotated)."""
    return Primitive("cylinder", (radius, half_height), tuple(pos), _quat(rotation))


def _segment(kind: str, p0, p1, radius: float) -> Primitive:
    p0, p1 = np.asarray(p0, dtype=float), np.asarray(p1, dtype=float)
    axis = p1 - p0
    length = float(np.linalg.norm(axis))
    rotation, _ = Rotation.align_vectors(axis[None] / length, [[0.0, 0.0, 1.0]])
    return Primitive(kind, (radius, length / 2), tuple((p0 + p1) / 2), _quat(rotation))


def capsule_between(p0, p1, radius: float) -> Primitive:
    """Capsule whose cap centres sit at p0 and p1 [m]."""
    return _segment("capsule", p0, p1, radius)


def cylinder_between(p0, p1, radius: float) -> Primitive:
    """Cylinder whose flat ends are centred at p0 and p1 [m]."""
    return _segment("cylinder", p0, p1, radius)


def ring_wall(
    n: int, r_bottom: float, r_top: float, z_bottom: float, z_top: float, thickness: float
) -> tuple[Primitive, ...]:
    """A thin wall of revolution about the object's z axis made of n overlapping boxes.

    r_bottom, r_top: radius [m] of the wall's mid-surface at z_bottom and z_top (different
    radii give a flared wall of tilted boxes, as in a bowl). Segment k faces the direction
    2πk/n, so with n divisible by 4 a segment's face is centred on each of ±x and ±y.
    """
    tilt = np.arctan2(r_top - r_bottom, z_top - z_bottom)
    slant_half = np.hypot(r_top - r_bottom, z_top - z_bottom) / 2
    r_outer = max(r_bottom, r_top) + thickness / 2
    half = (thickness / 2, RING_OVERLAP * r_outer * np.tan(np.pi / n), slant_half)
    r_mid, z_mid = (r_bottom + r_top) / 2, (z_bottom + z_top) / 2
    parts = []
    for phi in 2 * np.pi * np.arange(n) / n:
        rotation = Rotation.from_euler(
            "ZY", [phi, tilt]
        )  # Rz(φ) Ry(tilt): face the segment, lean out
        parts.append(box(half, (r_mid * np.cos(phi), r_mid * np.sin(phi), z_mid), rotation))
    return tuple(parts)


def loop_handle(
    y_root: float,
    y_bar: float,
    z_low: float,
    z_high: float,
    radius: float,
    x: float = 0.0,
    y_root_high: float | None = None,
) -> tuple[Primitive, ...]:
    """A round "C" handle in the plane x = const: two arms from the body at y_root out to a
    vertical bar at y_bar, at heights z_low and z_high (capsule centre lines) [m].
    y_root_high: where the upper arm leaves the body, if not at y_root (a flared body)."""
    top_root = (x, y_root if y_root_high is None else y_root_high, z_high)
    top_out = (x, y_bar, z_high)
    low_root, low_out = (x, y_root, z_low), (x, y_bar, z_low)
    return (
        capsule_between(top_root, top_out, radius),
        capsule_between(top_out, low_out, radius),
        capsule_between(low_out, low_root, radius),
    )


def turn_about_z(parts: tuple[Primitive, ...], yaw: float) -> tuple[Primitive, ...]:
    """The primitives turned by ``yaw`` [rad] about the object's vertical axis."""
    turn = Rotation.from_euler("z", yaw)
    return tuple(
        Primitive(
            p.kind,
            p.size,
            tuple(turn.apply(p.pos)),
            _quat(turn * Rotation.from_quat(p.quat, scalar_first=True)),
        )
        for p in parts
    )
