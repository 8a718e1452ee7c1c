"""Builders of primitives (a box, a cylinder) and the turn of a set of them about z."""

from __future__ import annotations

from scipy.spatial.transform import Rotation

from rrg_models.objects.primitives import Primitive


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


def turn_about_z(parts: tuple[Primitive, ...], yaw: float) -> tuple[Primitive, ...]:
    """The primitives turned by ``yaw`` [rad] about the object's vertical axis."""
    turn = Rotation.from_euler("z", yaw)
    return tuple(
        Primitive(
            p.kind,
            p.size,
            tuple(turn.apply(p.pos)),
            _quat(turn * Rotation.from_quat(p.quat, scalar_first=True)),
            vertices=p.vertices,
        )
        for p in parts
    )
