"""Collision primitives of the object models and their vectorized signed distance.

A ``Primitive`` uses MuJoCo's geom semantics, so the same tuple of primitives is the
collision geometry of the geometric simulator and of the MuJoCo physics model:

* box: ``size`` = 3 half-extents (x, y, z) [m];
* cylinder: (radius, half-height along local z) [m];
* capsule: (radius, half-length of the local-z segment between the cap centres) [m];
* sphere: (radius,) [m];
* mesh: no size; ``vertices`` (N,3) [m] in its own frame, whose convex hull it is (MuJoCo
  collides every mesh as its convex hull): a part of a convex decomposition.

``pos`` (3,) [m] and ``quat`` (4,) w x y z place the primitive in the object frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Literal

import numpy as np
import trimesh
from scipy.spatial import ConvexHull, QhullError
from scipy.spatial.transform import Rotation

PrimitiveKind = Literal["box", "cylinder", "capsule", "sphere", "mesh"]
SIZE_LENGTHS: dict[str, int] = {"box": 3, "cylinder": 2, "capsule": 2, "sphere": 1, "mesh": 0}
IDENTITY_QUAT = (1.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Primitive:
    """One convex collision primitive in the object frame (MuJoCo semantics, see module doc)."""

    kind: PrimitiveKind
    size: tuple[float, ...]
    pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    quat: tuple[float, float, float, float] = IDENTITY_QUAT
    #: mesh only: the vertices (N,3) [m] in the primitive's frame (their convex hull is the part)
    vertices: tuple[tuple[float, float, float], ...] = ()

    def __post_init__(self) -> None:
        if self.kind not in SIZE_LENGTHS:
            raise ValueError(f"unknown primitive kind {self.kind!r}; valid: {sorted(SIZE_LENGTHS)}")
        size = tuple(float(s) for s in self.size)
        if len(size) != SIZE_LENGTHS[self.kind] or min(size, default=0.0) < 0.0:
            raise ValueError(
                f"{self.kind} needs {SIZE_LENGTHS[self.kind]} non-negative sizes, got {size}"
            )
        quat = np.asarray(self.quat, dtype=float)
        norm = float(np.linalg.norm(quat))
        if abs(norm - 1.0) > 1e-12:  # a unit quaternion is kept bit for bit (renormalizing
            quat = quat / norm  # one can change its last digit: object files store them)
        object.__setattr__(self, "size", size)
        object.__setattr__(self, "pos", tuple(float(p) for p in self.pos))
        object.__setattr__(self, "quat", tuple(float(q) for q in quat))
        vertices = tuple(tuple(float(x) for x in v) for v in self.vertices)
        if (self.kind == "mesh") != bool(vertices):
            raise ValueError("a mesh part needs its vertices, and only a mesh part has them")
        object.__setattr__(self, "vertices", vertices)
        if vertices:
            try:
                self._hull  # noqa: B018  (a flat or degenerate set of vertices has no hull)
            except (QhullError, ValueError) as exc:
                raise ValueError(f"mesh vertices span no volume: {exc}") from exc

    @cached_property
    def _hull(self) -> ConvexHull:
        """The convex hull of a mesh part's vertices (its own frame)."""
        hull = ConvexHull(np.asarray(self.vertices, dtype=float))
        if not hull.volume > 0.0:
            raise ValueError("zero volume")
        return hull

    @property
    def volume(self) -> float:
        """Volume [m³] (a mesh part: its hull's)."""
        if self.kind == "mesh":
            return float(self._hull.volume)
        return primitive_volume(self.kind, self.size)

    def local_half_extents(self) -> np.ndarray:
        """(3,) half extents [m] of a box about the primitive's origin, in its own frame,
        that holds it."""
        s = np.asarray(self.size, dtype=float)
        if self.kind == "box":
            return s
        if self.kind == "mesh":
            return np.abs(np.asarray(self.vertices)).max(axis=0)
        r = s[0]
        return np.array([r, r, {"sphere": r, "cylinder": s[-1], "capsule": s[-1] + r}[self.kind]])

    @cached_property
    def rotation(self) -> np.ndarray:
        """(3,3) rotation of the primitive's local frame in the object frame."""
        return Rotation.from_quat(self.quat, scalar_first=True).as_matrix()

    @cached_property
    def transform(self) -> np.ndarray:
        """(4,4) pose of the primitive's local frame in the object frame."""
        T = np.eye(4)
        T[:3, :3] = self.rotation
        T[:3, 3] = self.pos
        return T

    def to_local(self, points: np.ndarray) -> np.ndarray:
        """Object-frame points (…,3) → the primitive's local frame."""
        return (np.asarray(points, dtype=float) - self.pos) @ self.rotation

    def signed_distance(self, points) -> np.ndarray:
        """Signed distance (…) [m] of object-frame points (…,3): < 0 inside. Exact, but for a
        mesh part outside: there, the largest distance past one of its face planes, exact
        in front of a face and smaller (closer) near its edges and corners."""
        local = self.to_local(points)
        if self.kind == "mesh":
            planes = self._hull.equations  # (F,4): unit outward normal n, offset d; n·x + d
            return np.max(local @ planes[:, :3].T + planes[:, 3], axis=-1)
        return local_signed_distance(self.kind, self.size, local)

    def bounds(self) -> np.ndarray:
        """(2,3) axis-aligned bounds [m] in the object frame (exact)."""
        if self.kind == "mesh":
            world = np.asarray(self.vertices) @ self.rotation.T + self.pos
            return np.stack([world.min(axis=0), world.max(axis=0)])
        half = rotated_half_extents(self.kind, self.size, self.rotation)
        return np.stack([np.asarray(self.pos) - half, np.asarray(self.pos) + half])

    def mesh(self) -> trimesh.Trimesh:
        """Triangle mesh of the primitive in the object frame (for visualization)."""
        s = self.size
        if self.kind == "mesh":
            hull = trimesh.convex.convex_hull(np.asarray(self.vertices))
            return hull.apply_transform(self.transform)
        if self.kind == "box":
            return trimesh.creation.box(extents=2 * np.asarray(s), transform=self.transform)
        if self.kind == "cylinder":
            return trimesh.creation.cylinder(
                radius=s[0], height=2 * s[1], sections=32, transform=self.transform
            )
        if self.kind == "capsule":
            return trimesh.creation.capsule(
                height=2 * s[1], radius=s[0], count=[24, 12], transform=self.transform
            )
        sphere = trimesh.creation.icosphere(subdivisions=2, radius=s[0])
        return sphere.apply_transform(self.transform)


def local_signed_distance(kind: str, size: Sequence[float], p: np.ndarray) -> np.ndarray:
    """Signed distance (…) of points p (…,3) given in a primitive's own frame."""
    if kind == "box":
        q = np.abs(p) - np.asarray(size)
        return np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(axis=-1), 0.0)
    if kind == "cylinder":
        q = np.stack(
            [np.hypot(p[..., 0], p[..., 1]) - size[0], np.abs(p[..., 2]) - size[1]], axis=-1
        )
        return np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(axis=-1), 0.0)
    if kind == "capsule":
        nearest = np.zeros_like(p)
        nearest[..., 2] = np.clip(p[..., 2], -size[1], size[1])
        return np.linalg.norm(p - nearest, axis=-1) - size[0]
    if kind == "sphere":
        return np.linalg.norm(p, axis=-1) - size[0]
    raise ValueError(f"unknown primitive kind {kind!r}")


def rotated_half_extents(kind: str, size: Sequence[float], R: np.ndarray) -> np.ndarray:
    """(3,) half extents [m] of the axis-aligned box that holds a MuJoCo box / sphere /
    capsule / cylinder / ellipsoid of MJCF ``size`` turned by R (3,3) (exact)."""
    s = np.asarray(size, dtype=float)
    if kind == "box":
        return np.abs(R) @ s
    if kind == "sphere":
        return np.full(3, s[0])
    if kind == "ellipsoid":
        return np.sqrt(((R * s) ** 2).sum(axis=1))
    if kind in ("capsule", "cylinder"):
        axis = np.abs(R[:, 2])
        across = s[0] if kind == "capsule" else s[0] * np.sqrt(np.clip(1.0 - axis**2, 0.0, 1.0))
        return s[1] * axis + across
    raise ValueError(f"unsupported primitive kind {kind!r}")


def primitive_volume(kind: str, size) -> float:
    """Volume [m³] of a MuJoCo box / cylinder / capsule / sphere / ellipsoid with MJCF ``size``."""
    s = size
    if kind == "box":
        return 8 * s[0] * s[1] * s[2]
    if kind == "cylinder":
        return np.pi * s[0] ** 2 * 2 * s[1]
    if kind == "capsule":
        return np.pi * s[0] ** 2 * 2 * s[1] + 4 / 3 * np.pi * s[0] ** 3
    if kind == "ellipsoid":
        return 4 / 3 * np.pi * s[0] * s[1] * s[2]
    if kind == "sphere":
        return 4 / 3 * np.pi * s[0] ** 3
    raise ValueError(f"no volume for geom type {kind!r}")


def mjcf_mesh_asset(part: Primitive, name: str) -> dict[str, str]:
    """The attributes of the MJCF ``<mesh>`` asset ``name`` of a mesh part (its vertices)."""
    return {"name": name, "vertex": " ".join(f"{x:.9g}" for v in part.vertices for x in v)}


def signed_distance(parts: Sequence[Primitive], points) -> np.ndarray:
    """Signed distance (…) [m] of object-frame points (…,3) to the union of
    ``parts`` (< 0 inside)."""
    points = np.asarray(points, dtype=float)
    return np.min([part.signed_distance(points) for part in parts], axis=0)


def union_bounds(parts: Sequence[Primitive]) -> np.ndarray:
    """(2,3) axis-aligned bounds [m] of a union of primitives."""
    b = np.stack([part.bounds() for part in parts])
    return np.stack([b[:, 0].min(axis=0), b[:, 1].max(axis=0)])


def box_distance(bounds: np.ndarray, points) -> np.ndarray:
    """Signed distance (…) of points (…,3) to an axis-aligned box given as (2,3) bounds."""
    bounds = np.asarray(bounds, dtype=float)
    centre, half = bounds.mean(axis=0), (bounds[1] - bounds[0]) / 2
    return local_signed_distance("box", half, np.asarray(points, dtype=float) - centre)


def _grid(lo: float, hi: float, spacing: float) -> np.ndarray:
    return np.linspace(lo, hi, max(2, int(np.ceil((hi - lo) / spacing)) + 1))


def _disk(radius: float, z: float, spacing: float) -> np.ndarray:
    """Points on concentric circles filling a disk of ``radius`` at height z."""
    rings = [np.zeros((1, 3)) + [0.0, 0.0, z]]
    for r in _grid(0.0, radius, spacing)[1:]:
        a = np.linspace(
            0.0, 2 * np.pi, max(6, int(np.ceil(2 * np.pi * r / spacing))), endpoint=False
        )
        rings.append(np.stack([r * np.cos(a), r * np.sin(a), np.full_like(a, z)], axis=-1))
    return np.concatenate(rings)


def surface_samples(kind: str, size: Sequence[float], spacing: float) -> np.ndarray:
    """(N,3) points on the surface of a primitive, in its own frame, about ``spacing`` [m] apart.

    Works for any geom with MuJoCo semantics (object primitives and the hand's geoms alike).
    """
    if kind == "box":
        axes = [_grid(-h, h, spacing) for h in size]
        faces = []
        for k in range(3):
            i, j = [a for a in range(3) if a != k]
            u, v = np.meshgrid(axes[i], axes[j], indexing="ij")
            for sign in (-1.0, 1.0):
                face = np.zeros(u.shape + (3,))
                face[..., i], face[..., j], face[..., k] = u, v, sign * size[k]
                faces.append(face.reshape(-1, 3))
        return np.concatenate(faces)
    r = size[0]
    if kind == "sphere":
        lat = _grid(-np.pi / 2, np.pi / 2, spacing / r)
        rings = [_circle(r * np.cos(t), r * np.sin(t), spacing) for t in lat]
        return np.concatenate(rings)
    hh = size[1]
    side = np.concatenate([_circle(r, z, spacing) for z in _grid(-hh, hh, spacing)])
    if kind == "cylinder":
        return np.concatenate([side, _disk(r, -hh, spacing), _disk(r, hh, spacing)])
    if kind == "capsule":
        lat = _grid(0.0, np.pi / 2, spacing / r)[1:]
        caps = [
            _circle(r * np.cos(t), s * (hh + r * np.sin(t)), spacing)
            for t in lat
            for s in (-1.0, 1.0)
        ]
        return np.concatenate([side] + caps)
    raise ValueError(f"unknown primitive kind {kind!r}")


def _circle(radius: float, z: float, spacing: float) -> np.ndarray:
    n = max(6, int(np.ceil(2 * np.pi * radius / spacing)))
    a = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return np.stack([radius * np.cos(a), radius * np.sin(a), np.full(n, z)], axis=-1)
