"""A rigid object from a mesh file: load, check, stand on the table, decompose into convex parts.

``import_mesh(path, units, up)`` reads an STL, OBJ or PLY file with trimesh, scales it to
metres and turns its declared up axis to +z; ``check_mesh`` repairs what trimesh can (merged
vertices, consistent normals, small holes) and refuses a mesh that is empty, not a closed
manifold, or of an implausible size; ``stand_on_table`` puts its lowest face on z = 0 with
the origin at the centre of its footprint, and refuses a mesh whose centre of mass falls
outside that footprint; ``convex_parts`` decomposes it with CoACD so that MuJoCo, which
collides every mesh as its convex hull, keeps its concavities. Every refusal is a
``MeshError`` that says what is wrong and what to pass instead.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import ConvexHull, QhullError

log = logging.getLogger(__name__)

#: Length units a mesh file may be declared in, in metres.
UNITS_M = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}
#: Axis names a mesh may be declared to have up.
UP_AXES = {"x": (1, 0, 0), "y": (0, 1, 0), "z": (0, 0, 1), "-x": (-1, 0, 0), "-y": (0, -1, 0)}
#: Plausible sizes [m] of an object the WAM grasps on a table (chosen: a 2 cm die to a
#: 60 cm box; outside them a mesh is most likely in other units than declared).
MIN_SIZE_M, MAX_SIZE_M = 0.02, 0.6
#: Vertices this close [m] above the lowest one make the footprint (chosen: 1 mm).
FOOTPRINT_TOLERANCE_M = 0.001
#: The centre of mass must lie this far [m] inside the footprint (chosen: 2 mm, so that a
#: table-height draw or a bump does not tip it).
STABILITY_MARGIN_M = 0.002
#: CoACD's concavity threshold (its default, 0.05) and the most parts to keep (chosen: the
#: paper objects have 1-24 primitives; each part is a MuJoCo collision geom).
COACD_THRESHOLD = 0.05
MAX_PARTS = 24


class MeshError(ValueError):
    """A mesh that cannot become an object: what is wrong, and what to do."""


def import_mesh(path: Path | str, units: str = "m", up: str = "z") -> trimesh.Trimesh:
    """The mesh in ``path`` in metres with its ``up`` axis turned to +z (MeshError if it
    cannot be read or has no faces)."""
    if units not in UNITS_M:
        raise MeshError(f"unknown units {units!r}; valid: {', '.join(UNITS_M)}")
    if up not in UP_AXES:
        raise MeshError(f"unknown up axis {up!r}; valid: {', '.join(UP_AXES)}")
    try:
        mesh = trimesh.load_mesh(Path(path), process=True)
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise MeshError(f"{path}: cannot read a mesh: {exc}") from exc
    if isinstance(mesh, trimesh.Scene):
        mesh = mesh.to_mesh() if mesh.geometry else trimesh.Trimesh()
    if len(mesh.faces) == 0:
        raise MeshError(f"{path}: the mesh is empty (no faces)")
    mesh.apply_scale(UNITS_M[units])
    turn = trimesh.geometry.align_vectors(UP_AXES[up], (0.0, 0.0, 1.0))
    mesh.apply_transform(turn)
    return mesh


def check_mesh(mesh: trimesh.Trimesh, allow_size: bool = False) -> trimesh.Trimesh:
    """A repaired copy of ``mesh``: merged vertices, consistent outward normals, small holes
    filled. MeshError if it is not then a closed manifold with a volume, or (unless
    ``allow_size``) if its largest extent is outside [MIN_SIZE_M, MAX_SIZE_M]."""
    mesh = mesh.copy()
    mesh.merge_vertices()
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.update_faces(mesh.unique_faces())
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) == 0:
        raise MeshError("the mesh is empty (no faces left after removing degenerate ones)")
    trimesh.repair.fix_normals(mesh)
    trimesh.repair.fill_holes(mesh)
    if not mesh.is_watertight:
        edges = trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1)
        raise MeshError(
            f"the mesh is not a closed manifold ({len(edges)} edges bound a single face, "
            "or some edge bounds more than two): a rigid object needs a closed surface "
            "(repair it, e.g. in MeshLab, and export it again)"
        )
    if not mesh.is_volume or mesh.volume <= 0.0:
        raise MeshError("the mesh encloses no volume (inconsistent or inward faces)")
    size = float(mesh.extents.max())
    if not allow_size and not MIN_SIZE_M <= size <= MAX_SIZE_M:
        hint = "mm or cm" if size > MAX_SIZE_M else "m"
        raise MeshError(
            f"the mesh is {size:.4g} m across, outside the {MIN_SIZE_M}-{MAX_SIZE_M} m an "
            f"object on a table has: are its units really as declared? (try --units {hint}, "
            "or --allow-size if it really is that size)"
        )
    return mesh


def stand_on_table(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """A copy of ``mesh`` resting on z = 0 with the origin at its footprint's centre, the
    footprint being its vertices within FOOTPRINT_TOLERANCE_M of the lowest. MeshError if
    the centre of mass (uniform density) is not STABILITY_MARGIN_M inside the footprint."""
    mesh = mesh.copy()
    z = mesh.vertices[:, 2]
    foot = mesh.vertices[z <= z.min() + FOOTPRINT_TOLERANCE_M, :2]
    try:
        hull = ConvexHull(foot)
    except (QhullError, ValueError):
        raise MeshError(
            "the mesh touches the table at a point or along a line only, so it cannot stand "
            "in the declared orientation (try another --up)"
        ) from None
    polygon = foot[hull.vertices]
    centre = _polygon_centroid(polygon)
    mesh.apply_translation((-centre[0], -centre[1], -z.min()))
    com = mesh.center_mass[:2]
    inside = -np.max(hull.equations[:, :2] @ (com + centre) + hull.equations[:, 2])
    if inside < STABILITY_MARGIN_M:
        raise MeshError(
            f"the mesh cannot stand on the table: its centre of mass is "
            f"{-inside * 1000:+.1f} mm outside its footprint (needs {STABILITY_MARGIN_M * 1000:.0f}"
            " mm inside; try another --up)"
        )
    return mesh


def _polygon_centroid(polygon: np.ndarray) -> np.ndarray:
    """(2,) area centroid of a convex polygon given by its (N,2) vertices in order."""
    x, y = polygon[:, 0], polygon[:, 1]
    cross = x * np.roll(y, -1) - np.roll(x, -1) * y
    area = cross.sum() / 2.0
    return np.array(
        [
            ((x + np.roll(x, -1)) * cross).sum() / (6 * area),
            ((y + np.roll(y, -1)) * cross).sum() / (6 * area),
        ]
    )


def convex_parts(
    mesh: trimesh.Trimesh,
    threshold: float = COACD_THRESHOLD,
    max_parts: int = MAX_PARTS,
    seed: int = 0,
) -> list[np.ndarray]:
    """The vertices (N_k,3) [m] of each convex part of CoACD's decomposition of ``mesh``
    (concavity ``threshold``, at most ``max_parts`` parts; seeded, so repeatable)."""
    import coacd

    coacd.set_log_level("error")
    parts = coacd.run_coacd(
        coacd.Mesh(np.asarray(mesh.vertices), np.asarray(mesh.faces)),
        threshold=threshold,
        max_convex_hull=max_parts,
        seed=seed,
    )
    log.info("CoACD: %d convex parts (threshold %.3g)", len(parts), threshold)
    return [np.asarray(vertices, dtype=float) for vertices, _ in parts]
