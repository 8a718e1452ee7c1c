"""Pinch candidates: pairs of nearly parallel, opposing, roughly vertical surfaces of an
object's primitives that the BarrettHand's straight fingers can close on from above
(paper, "Generating WRTs": "hand positions that place the fingers on nearly parallel pairs
of object surfaces").

A pinch puts finger 3 against fingers 1+2 (spread 0) or finger 2 against finger 1 (spread
π/2) across the pair; long shared surfaces give several pinch positions along them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from rrg_models import hand
from rrg_models.config import HAND
from rrg_models.objects.primitives import Primitive, signed_distance, surface_samples

#: Surface pairing (paper: "nearly parallel pairs of object surfaces"; angles chosen).
MAX_FACE_TILT = np.radians(35.0)  # a face counts as roughly vertical (a bowl's wall leans 30°)
MAX_PAIR_ANGLE = np.radians(15.0)  # normals within this of antiparallel
PATCH_SPACING = 0.004  # m between surface samples
ROUND_BINS = 16  # angular patches around a vertical cylinder, capsule or sphere
PROBE_RADIUS = 0.008  # m: a fingertip-sized ball must fit against an exposed sample
MIN_PATCH_SAMPLES = 6
MIN_LATERAL_OVERLAP = 0.008  # m the two patches must share across the pinch axis
MIN_VERTICAL_OVERLAP = 0.01  # m the two patches must share in height
MIN_FINGER_CLEARANCE = 0.006  # m between each fingertip and its surface before closing
DIVERSE_DISTANCE = 0.04  # m between pinch positions along a long pair of surfaces


@dataclass(frozen=True, eq=False)
class SurfacePatch:
    """Exposed samples (M,3) [m] of one roughly vertical face, with its horizontal outward
    normal."""

    points: np.ndarray
    normal: np.ndarray


@dataclass(frozen=True, eq=False)
class Pinch:
    """A top-down pinch across two opposing patches.

    axis: horizontal unit vector from the finger-3 (spread 0) or finger-2 (spread π/2) side
    to the other side; centre: (3,) the hand's axis point (x, y) and the top of the shared
    height (z) [m]; separation: mean horizontal distance [m] between the surfaces; score: the
    smaller patch area [m²].
    """

    axis: np.ndarray
    centre: np.ndarray
    separation: float
    spread: float
    score: float

    def rotation(self) -> Rotation:
        """Hand orientation: pointing down, the opposing fingers closing along ``axis``."""
        z = np.array([0.0, 0.0, -1.0])
        if self.spread == 0.0:
            y = self.axis
            x = np.cross(y, z)
        else:
            x = self.axis
            y = np.cross(z, x)
        return Rotation.from_matrix(np.stack([x, y, z], axis=1))


def _horizontal(v: np.ndarray) -> np.ndarray:
    h = np.array([v[0], v[1], 0.0])
    return h / np.linalg.norm(h)


def _face_patches(part: Primitive) -> list[tuple[np.ndarray, np.ndarray]]:
    """(object-frame samples, outward unit normal) of each roughly vertical face of one
    primitive."""
    R, s = part.rotation, part.size
    out = []
    if part.kind == "mesh":
        return _hull_face_patches(part)
    if part.kind == "box":
        samples = surface_samples("box", s, PATCH_SPACING)
        for k in range(3):
            for sign in (-1.0, 1.0):
                normal = sign * R[:, k]
                if abs(normal[2]) > np.sin(MAX_FACE_TILT):
                    continue
                on_face = np.isclose(samples[:, k], sign * s[k])
                out.append((samples[on_face] @ R.T + part.pos, normal))
        return out
    r = s[0]
    axis = R[:, 2]
    if part.kind == "sphere" or abs(axis[2]) >= np.cos(MAX_FACE_TILT):
        centres = 2 * np.pi * np.arange(ROUND_BINS) / ROUND_BINS
        half_bin = np.pi / ROUND_BINS
    elif abs(axis[2]) <= np.sin(MAX_FACE_TILT):
        phi0 = np.arctan2(-R[2, 0], R[2, 1])  # local angle whose radial direction is horizontal
        centres = np.array([phi0, phi0 + np.pi])
        half_bin = MAX_FACE_TILT
    else:
        return out
    along = np.array([0.0]) if part.kind == "sphere" else _samples(-s[1], s[1])
    for phi_c in centres:
        phi = phi_c + np.linspace(-half_bin, half_bin, 4, endpoint=False) + half_bin / 4
        if part.kind == "sphere":
            lat = np.linspace(-MAX_FACE_TILT, MAX_FACE_TILT, 5)
            p, t = np.meshgrid(phi, lat, indexing="ij")
            local = r * np.stack([np.cos(p) * np.cos(t), np.sin(p) * np.cos(t), np.sin(t)], axis=-1)
        else:
            p, z = np.meshgrid(phi, along, indexing="ij")
            local = np.stack([r * np.cos(p), r * np.sin(p), z], axis=-1)
        normal = R @ np.array([np.cos(phi_c), np.sin(phi_c), 0.0])
        if abs(normal[2]) <= np.sin(MAX_FACE_TILT):
            out.append((local.reshape(-1, 3) @ R.T + part.pos, normal))
    return out


def _hull_face_patches(part: Primitive) -> list[tuple[np.ndarray, np.ndarray]]:
    """(object-frame samples, outward unit normal) of a mesh part's convex hull: its roughly
    vertical faces gathered by the direction they face into ROUND_BINS bins, as a round
    primitive's side is (a tessellated curved wall is many narrow faces, none wide enough to
    pinch alone); the normal is the bin's area-weighted mean, and samples are PATCH_SPACING
    apart."""
    hull = part.mesh()
    normals = hull.face_normals
    vertical = np.abs(normals[:, 2]) <= np.sin(MAX_FACE_TILT)
    azimuth = np.arctan2(normals[:, 1], normals[:, 0])
    bins = np.round(azimuth / (2 * np.pi / ROUND_BINS)).astype(int) % ROUND_BINS
    out = []
    for b in range(ROUND_BINS):
        faces = np.flatnonzero(vertical & (bins == b))
        if len(faces) == 0:
            continue
        normal = (hull.area_faces[faces, None] * normals[faces]).sum(axis=0)
        normal /= np.linalg.norm(normal)
        points = np.concatenate([_triangle_samples(t) for t in hull.triangles[faces]])
        out.append((np.unique(np.round(points, 9), axis=0), normal))
    return out


def _triangle_samples(triangle: np.ndarray) -> np.ndarray:
    """(N,3) points on a triangle (3,3), a lattice about PATCH_SPACING apart."""
    a, b, c = triangle
    n = max(1, int(np.ceil(max(np.linalg.norm(b - a), np.linalg.norm(c - a)) / PATCH_SPACING)))
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    keep = i + j <= n
    return a + np.outer(i[keep] / n, b - a) + np.outer(j[keep] / n, c - a)


def _samples(lo: float, hi: float) -> np.ndarray:
    return np.linspace(lo, hi, max(2, int(np.ceil((hi - lo) / PATCH_SPACING)) + 1))


def surface_patches(parts: Sequence[Primitive]) -> list[SurfacePatch]:
    """Roughly vertical faces of the union whose samples a fingertip-sized ball can touch."""
    patches = []
    for part in parts:
        for points, normal in _face_patches(part):
            on_boundary = signed_distance(parts, points) >= -1e-4
            probe = points + (PROBE_RADIUS + 0.001) * normal
            reachable = signed_distance(parts, probe) >= PROBE_RADIUS
            exposed = points[on_boundary & reachable]
            if len(exposed) >= MIN_PATCH_SAMPLES:
                patches.append(SurfacePatch(exposed, _horizontal(normal)))
    return patches


def finger_gap(spread: float) -> float:
    """Free distance [m] between the opposing straight fingertips (finger 3 vs 1 at spread 0,
    finger 2 vs 1 at spread π/2) along the pinch axis."""
    tips = hand.fingertip_points(spread, np.zeros(3))
    across = abs(tips[0, 1] - tips[2, 1]) if spread == 0.0 else abs(tips[0, 0] - tips[1, 0])
    return float(across - 2 * HAND.tip_radius)


def _lateral_span(spread: float) -> float:
    """Half-extent [m] of the fingers across the pinch axis (fingers 1, 2 side by
    side at spread 0)."""
    if spread == 0.0:
        return HAND.spread_axis_x + HAND.finger_width / 2
    return HAND.finger_width / 2


def _lateral_positions(lo: float, hi: float, half_span: float) -> np.ndarray:
    """Pinch positions across the axis: the middle of the shared interval [lo, hi], then
    every DIVERSE_DISTANCE outward and the two ends, keeping the fingers on the interval."""
    mid = (lo + hi) / 2
    room = (hi - lo) / 2 - half_span
    if room <= 0.0:
        return np.array([mid])
    steps = DIVERSE_DISTANCE * np.arange(1, int(room / DIVERSE_DISTANCE) + 1)
    return mid + np.concatenate([[0.0], steps, -steps, [room, -room]])


def pinch_candidates(parts: Sequence[Primitive]) -> list[Pinch]:
    """Every pinch across a pair of opposing patches that fits a preshape: best score first,
    then the central positions first."""
    patches = surface_patches(parts)
    gaps = {spread: finger_gap(spread) - 2 * MIN_FINGER_CLEARANCE for spread in (0.0, np.pi / 2)}
    keyed = []
    for i, a in enumerate(patches):
        for j, b in enumerate(patches):
            if i == j or a.normal @ b.normal > -np.cos(MAX_PAIR_ANGLE):
                continue
            u = -a.normal
            v = np.array([-u[1], u[0], 0.0])
            a_u, b_u, a_v, b_v = a.points @ u, b.points @ u, a.points @ v, b.points @ v
            sep = float(b_u.mean() - a_u.mean())
            lat_lo, lat_hi = max(a_v.min(), b_v.min()), min(a_v.max(), b_v.max())
            z_lo = max(a.points[:, 2].min(), b.points[:, 2].min())
            z_hi = min(a.points[:, 2].max(), b.points[:, 2].max())
            if (
                sep <= 0.001
                or lat_hi - lat_lo < MIN_LATERAL_OVERLAP
                or z_hi - z_lo < MIN_VERTICAL_OVERLAP
            ):
                continue
            mid_u = (a_u.mean() + b_u.mean()) / 2
            score = min(len(a.points), len(b.points)) * PATCH_SPACING**2
            for spread, gap in gaps.items():
                if sep > gap:
                    continue
                for lateral in _lateral_positions(lat_lo, lat_hi, _lateral_span(spread)):
                    centre = mid_u * u + lateral * v
                    centre[2] = z_hi
                    offset = abs(lateral - (lat_lo + lat_hi) / 2)
                    key = (
                        -round(score, 8),
                        spread,
                        round(offset, 6),
                        round(sep, 6),
                        *np.round(centre, 6),
                        *np.round(u, 6),
                    )
                    keyed.append((key, Pinch(u, centre, sep, spread, score)))
    keyed.sort(key=lambda kp: kp[0])
    return [p for _, p in keyed]
