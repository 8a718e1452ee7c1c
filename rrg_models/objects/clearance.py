"""Clearance between the BarrettHand (rrg_models.hand) and an object's primitives plus the table.

Used to design and check WRTs. Exact proximity tests use MuJoCo's collision detection on a
small scene (the table, the object's primitives with a contact margin, and the hand's geoms
at a fixed preshape on a free body): a hand pose is *clear* when MuJoCo reports no contact
within the margins. Straight motions are sampled every ``STEP`` and refined by bisection.
Bounding-box distances use surface samples of the hand's geoms.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Sequence
from functools import lru_cache

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from rrg_models import hand
from rrg_models.objects.primitives import Primitive, box_distance, mjcf_mesh_asset, surface_samples

#: Spacing of the hand's surface samples [m] (bounding-box distances only).
SAMPLE_SPACING = 0.004
#: Path sampling step [m] (below the thinnest object wall) and bisection steps inside the
#: first failing step (to 0.03 mm).
STEP = 0.002
REFINE_ITERS = 6
_TABLE_HALF = (2.0, 2.0, 0.05)  # m: a table slab with its top at z = 0


def _fmt(values) -> str:
    return " ".join(f"{v:.9g}" for v in np.atleast_1d(values))


def _geom(
    parent: ET.Element, kind: str, size, pos, quat, margin: float, mesh: str | None = None
) -> None:
    """A geom: a primitive of ``size``, or (``mesh``) the named mesh asset."""
    shape = {"size": _fmt(size)} if mesh is None else {"mesh": mesh}
    ET.SubElement(
        parent,
        "geom",
        type=kind,
        **shape,
        pos=_fmt(pos),
        quat=_fmt(quat),
        margin=_fmt(margin),
        gap="0",
    )


class HandObjectScene:
    """MuJoCo scene to test hand poses against one object and the table.

    parts: the object's primitives (object frame = MuJoCo world; table top at z = 0);
    spread, preclose: the hand's preshape [rad]; object_margin, table_margin [m].
    """

    def __init__(
        self,
        parts: Sequence[Primitive],
        spread: float,
        preclose: float,
        object_margin: float,
        table_margin: float,
    ) -> None:
        root = ET.Element("mujoco", model="hand_object_clearance")
        asset = ET.SubElement(root, "asset")
        world = ET.SubElement(root, "worldbody")
        _geom(world, "box", _TABLE_HALF, (0.0, 0.0, -_TABLE_HALF[2]), (1, 0, 0, 0), table_margin)
        for k, part in enumerate(parts):
            mesh = f"part_{k}" if part.kind == "mesh" else None
            if mesh is not None:
                ET.SubElement(asset, "mesh", mjcf_mesh_asset(part, mesh))
            _geom(world, part.kind, part.size, part.pos, part.quat, object_margin, mesh)
        body = ET.SubElement(world, "body", name="hand")
        ET.SubElement(body, "freejoint")
        for geom, T in hand.hand_geoms_world(np.eye(4), spread, np.full(3, preclose)):
            quat = Rotation.from_matrix(T[:3, :3]).as_quat(scalar_first=True)
            _geom(body, geom.kind, geom.size, T[:3, 3], quat, 0.0)
        self.model = mujoco.MjModel.from_xml_string(ET.tostring(root, encoding="unicode"))
        self.data = mujoco.MjData(self.model)

    def clear(self, poses: np.ndarray) -> np.ndarray:
        """(…) True where the hand at poses (…,4,4) (object frame) is outside every margin."""
        poses = np.asarray(poses, dtype=float)
        flat = poses.reshape(-1, 4, 4)
        quats = Rotation.from_matrix(flat[:, :3, :3]).as_quat(scalar_first=True)
        out = np.empty(len(flat), dtype=bool)
        m, d = self.model, self.data
        for k in range(len(flat)):
            d.qpos[:3] = flat[k, :3, 3]
            d.qpos[3:7] = quats[k]
            mujoco.mj_kinematics(m, d)
            mujoco.mj_collision(m, d)
            out[k] = d.ncon == 0
        return out.reshape(poses.shape[:-2])


@lru_cache(maxsize=64)
def scene(
    parts: tuple[Primitive, ...],
    spread: float,
    preclose: float,
    object_margin: float,
    table_margin: float,
) -> HandObjectScene:
    """Cached ``HandObjectScene``."""
    return HandObjectScene(parts, spread, preclose, object_margin, table_margin)


@lru_cache(maxsize=32)
def _hand_points(spread: float, preclose: float) -> np.ndarray:
    points = [
        surface_samples(g.kind, g.size, SAMPLE_SPACING) @ T[:3, :3].T + T[:3, 3]
        for g, T in hand.hand_geoms_world(np.eye(4), spread, np.full(3, preclose))
    ]
    out = np.concatenate(points)
    out.setflags(write=False)
    return out


def hand_points(spread: float, preclose: float = 0.0) -> np.ndarray:
    """(N,3) surface points of every hand geom in the hand frame for a preshape [rad]."""
    return _hand_points(float(spread), float(preclose))


def transform_points(poses: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Hand poses (…,4,4) in the object frame and hand-frame points (N,3) → (…,N,3)."""
    return np.einsum("...ij,nj->...ni", poses[..., :3, :3], points) + poses[..., None, :3, 3]


def translate(pose: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(4,4) pose moved by (…,3) translations → (…,4,4)."""
    offsets = np.asarray(offsets, dtype=float)
    out = np.broadcast_to(pose, offsets.shape[:-1] + (4, 4)).copy()
    out[..., :3, 3] += offsets
    return out


def free_travel(checker: HandObjectScene, start: np.ndarray, direction, max_travel: float) -> float:
    """How far [m] the hand can move in a straight line from ``start`` along ``direction``
    (object frame) before it first comes within a margin of the object or the table.

    Returns ``max_travel`` if it never does; raises ValueError if ``start`` itself is not clear.
    """
    direction = np.asarray(direction, dtype=float) / np.linalg.norm(direction)
    t = np.append(np.arange(0.0, max_travel, STEP), max_travel)
    ok = checker.clear(translate(start, t[:, None] * direction))
    if not ok[0]:
        raise ValueError("the start pose is not clear of the object and the table")
    if ok.all():
        return float(max_travel)
    first_bad = int(np.argmin(ok))
    lo, hi = t[first_bad - 1], t[first_bad]
    for _ in range(REFINE_ITERS):
        mid = (lo + hi) / 2
        if checker.clear(translate(start, mid * direction)):
            lo = mid
        else:
            hi = mid
    return float(lo)


def bounds_clearance(bounds: np.ndarray, poses: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(…) min distance [m] of the hand points at poses (…,4,4) to the box ``bounds`` (2,3)."""
    return box_distance(bounds, transform_points(poses, points)).min(axis=-1)


def backoff_until_clear(
    bounds: np.ndarray,
    pose: np.ndarray,
    direction,
    points: np.ndarray,
    clearance: float,
    max_travel: float = 2.0,
) -> np.ndarray:
    """Move ``pose`` along ``direction`` until every hand point is at least ``clearance`` [m]
    from the axis-aligned box ``bounds`` (2,3); returns the new (4,4) pose.

    Each step moves by the missing clearance: the distance grows at most as fast as the hand
    moves, so this never overshoots the first clear pose by more than a step's rounding.
    """
    direction = np.asarray(direction, dtype=float) / np.linalg.norm(direction)
    t = 0.0
    while t <= max_travel:
        moved = translate(pose, t * direction)
        missing = clearance - float(bounds_clearance(bounds, moved, points))
        if missing <= 0.0:
            return moved
        t += max(missing, 1e-4)
    raise ValueError(f"no pose along the back-off direction within {max_travel} m is clear")
