"""A rigid object from a mesh file: load, check, stand on the table, decompose into convex parts.

``import_mesh(path, units, up)`` reads an STL, OBJ or PLY file with trimesh, scales it to
metres and turns its declared up axis to +z; ``check_mesh`` repairs what a lab's mesh needs
(merged vertices, consistent normals, small holes filled, several closed shells, overlapping
or touching as CAD assemblies and merged parts are, united into one with manifold3d, and a
closed surface that is still not a manifold rebuilt from CoACD's manifold pre-processing) and
says what it repaired, and refuses a mesh that is empty, open, without volume, of an
implausible size, or whose rebuild changed its volume by more than
MAX_REBUILD_VOLUME_CHANGE; ``stand_on_table`` puts its lowest face on z = 0 with
the origin at the centre of its footprint, and refuses a mesh whose centre of mass falls
outside that footprint; ``convex_parts`` decomposes it with CoACD so that MuJoCo, which
collides every mesh as its convex hull, keeps its concavities. Every refusal is a
``MeshError`` that says what is wrong and what to pass instead.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import ConvexHull, QhullError
from scipy.spatial.transform import Rotation

log = logging.getLogger(__name__)

#: Length units a mesh file may be declared in, in metres.
UNITS_M = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}
#: The turn that brings a mesh's declared up axis to +z, by the axis's name.
UP_AXES = {
    "z": Rotation.identity(),
    "-z": Rotation.from_euler("x", 180.0, degrees=True),
    "y": Rotation.from_euler("x", 90.0, degrees=True),
    "-y": Rotation.from_euler("x", -90.0, degrees=True),
    "x": Rotation.from_euler("y", -90.0, degrees=True),
    "-x": Rotation.from_euler("y", 90.0, degrees=True),
}
#: Plausible sizes [m] of an object the WAM grasps on a table (chosen: a 2 cm die to a
#: 60 cm box; outside them a mesh is most likely in other units than declared).
MIN_SIZE_M, MAX_SIZE_M = 0.02, 0.6
#: Vertices of the convex hull this close [m] above the lowest one make the footprint
#: (chosen: half a millimetre, the unevenness of a scanned flat base).
FOOTPRINT_TOLERANCE_M = 0.0005
#: The object must tilt at least this far [rad] about an edge of its footprint before its
#: centre of mass passes over it (chosen: 10°; the paper objects need 16°, the drill on its
#: battery, or more; a 4 cm ball resting on its tessellation, 9°).
MIN_TIP_ANGLE = np.radians(10.0)
#: CoACD's concavity threshold (its default, 0.05) and the most parts to keep (chosen: the
#: paper objects have 1-24 primitives; each part is a MuJoCo collision geom).
COACD_THRESHOLD = 0.05
MAX_PARTS = 24
#: The finer decomposition tried when the first one's parts enclose more than
#: MAX_HULL_EXCESS beyond the mesh's volume: concavity threshold and most parts (chosen: a
#: 3 mm-walled bowl 17 cm across then keeps 56 parts enclosing 25 % more, from 75 % more with
#: 24 parts, whose hulls bridged its curved wall and filled the wedge under its rim).
FINE_COACD_THRESHOLD = 0.03
FINE_MAX_PARTS = 64
#: The most the convex parts may enclose beyond the mesh's volume, as a share of it, before
#: the finer decomposition is tried (chosen: above the generated mug's 19 % and pitcher's
#: 16 %, whose first decompositions are kept; the other generated objects' are within 1 %).
MAX_HULL_EXCESS = 0.30
#: The most vertices a convex part keeps (CoACD's decimation, its max_ch_vertex). The parts of
#: a dense mesh keep hundreds (a 51k-triangle pitcher: up to 824), and MuJoCo's convex
#: collisions cost per vertex. Chosen: the largest part of the generated objects (the coarse
#: pitcher's, 160), whose decompositions it leaves bit for bit; the dense pitcher's parts then
#: move by at most 0.26 mm and lose 0.18 % of their volume (docs/objects.md).
MAX_PART_VERTICES = 160
#: The most a rebuild from CoACD's manifold pre-processing may change the volume the mesh
#: encloses, as a share of it (chosen: 10 %; the pre-processing's voxel remesh thickens a
#: surface by about one voxel, +5.5 % on a 4 x 4 x 8 cm block at its default resolution).
MAX_REBUILD_VOLUME_CHANGE = 0.10
#: Voxels across a mesh's largest extent when measuring the volume a non-manifold surface
#: encloses (chosen: within 1 % of the exact volume of the generated mug and a sphere).
ENCLOSED_VOXELS = 100


class MeshError(ValueError):
    """A mesh that cannot become an object: what is wrong, and what to do."""


@dataclass(frozen=True)
class MeshRepair:
    """What check_mesh repaired: faces added to close holes, closed shells united into one
    (0: none), convex parts the surface was rebuilt from (0: not rebuilt), and the volume
    [m³] before (the shells' volumes summed, overlaps counted as often as they overlap; for
    a rebuilt surface, what it enclosed, measured on voxels) and after."""

    holes_filled: int
    shells_united: int
    volume_before_m3: float
    volume_after_m3: float
    rebuilt_parts: int = 0

    def describe(self) -> str:
        """One line for people."""
        done = []
        if self.shells_united:
            done.append(f"{self.shells_united} closed shells united into one")
        if self.holes_filled:
            done.append(f"{self.holes_filled} faces added to close holes")
        if self.rebuilt_parts:
            done.append(
                "not a manifold (edges shared by more than two faces): rebuilt as one closed "
                "surface from CoACD's manifold pre-processing, its convex parts united "
                f"({self.rebuilt_parts})"
            )
        if not done:
            return "no repair needed"
        cm3 = lambda v: f"{v * 1e6:.1f} cm³"
        volumes = f"{cm3(self.volume_before_m3)} → {cm3(self.volume_after_m3)}"
        return f"repaired: {'; '.join(done)} (volume {volumes})"


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
    turn = np.eye(4)
    turn[:3, :3] = UP_AXES[up].as_matrix()
    mesh.apply_transform(turn)
    return mesh


def check_mesh(
    mesh: trimesh.Trimesh, allow_size: bool = False
) -> tuple[trimesh.Trimesh, MeshRepair]:
    """A repaired copy of ``mesh`` and what was repaired: merged vertices, consistent outward
    normals, small holes filled, its closed shells (bodies that overlap or touch, as in a CAD
    assembly or at a shared edge) united into one, and a closed surface that is still not a
    manifold (bodies glued by a face kept once, a scan's merged parts) rebuilt from CoACD's
    manifold pre-processing. MeshError if it is open (an open sheet), encloses no volume, was
    rebuilt with a volume more than MAX_REBUILD_VOLUME_CHANGE off what it enclosed, or (unless
    ``allow_size``) if its largest extent is outside [MIN_SIZE_M, MAX_SIZE_M]."""
    mesh = mesh.copy()
    mesh.merge_vertices()
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.update_faces(mesh.unique_faces())
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) == 0:
        raise MeshError("the mesh is empty (no faces left after removing degenerate ones)")
    trimesh.repair.fix_normals(mesh)
    faces = len(mesh.faces)
    trimesh.repair.fill_holes(mesh)
    holes_filled = len(mesh.faces) - faces
    open_edges = len(trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1))
    if open_edges:
        raise MeshError(
            f"the mesh is open: {open_edges} edges bound a single face, and its holes are too "
            "large to fill (an open sheet, or a surface with a missing side): a rigid object "
            "needs a closed surface (close it, e.g. in MeshLab, and export it again)"
        )
    shells = mesh.split(only_watertight=False)
    for shell in shells:
        trimesh.repair.fix_normals(shell)
    volume_before = float(sum(shell.volume for shell in shells))
    united = rebuilt = 0
    if all(s.is_watertight for s in shells) and (len(shells) > 1 or not mesh.is_watertight):
        try:
            mesh, united = _united(shells), len(shells)
        except MeshError as exc:
            log.info("%s; rebuilding it", exc)
    if not mesh.is_watertight:
        volume_before = enclosed_volume(mesh)
        if volume_before <= 0.0:
            raise MeshError("the mesh encloses no volume (a flat or inside-out surface)")
        mesh, rebuilt = _rebuilt(mesh)
        change = mesh.volume / volume_before - 1.0
        if abs(change) > MAX_REBUILD_VOLUME_CHANGE:
            raise MeshError(
                "the mesh is not a manifold, and rebuilding it as one closed surface changed "
                f"its volume by {change:+.0%} ({volume_before * 1e6:.1f} → "
                f"{mesh.volume * 1e6:.1f} cm³; at most {MAX_REBUILD_VOLUME_CHANGE:.0%}): repair "
                "it (e.g. in MeshLab) and export it again"
            )
    if not mesh.is_volume or mesh.volume <= 0.0:
        raise MeshError("the mesh encloses no volume (a flat or inside-out surface)")
    size = float(mesh.extents.max())
    if not allow_size and not MIN_SIZE_M <= size <= MAX_SIZE_M:
        hint = "mm or cm" if size > MAX_SIZE_M else "m"
        raise MeshError(
            f"the mesh is {size:.4g} m across, outside the {MIN_SIZE_M}-{MAX_SIZE_M} m an "
            f"object on a table has: are its units really as declared? (try --units {hint}, "
            "or --allow-size if it really is that size)"
        )
    repair = MeshRepair(holes_filled, united, volume_before, float(mesh.volume), rebuilt)
    return mesh, repair


def _united(shells: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    """The union of closed shells (manifold3d through trimesh): one closed surface."""
    try:
        return trimesh.boolean.union(shells, engine="manifold")
    except Exception as exc:  # manifold3d raises its own types for inputs it cannot use
        raise MeshError(
            f"the mesh's {len(shells)} closed shells could not be united ({exc}): repair it "
            "(e.g. in MeshLab) and export it again"
        ) from exc


def enclosed_volume(mesh: trimesh.Trimesh, cells: int = ENCLOSED_VOXELS) -> float:
    """The volume [m³] a closed surface encloses, manifold or not: its voxels (``cells``
    across its largest extent) inside it, those it passes through counted half."""
    pitch = float(mesh.extents.max()) / cells
    grid = mesh.voxelized(pitch)
    surface = int(grid.matrix.sum())
    return (int(grid.fill().matrix.sum()) - surface / 2) * pitch**3


def _rebuilt(mesh: trimesh.Trimesh) -> tuple[trimesh.Trimesh, int]:
    """A closed surface that is not a manifold, rebuilt as one: CoACD's manifold
    pre-processing (a voxel remesh) decomposed into convex parts, which manifold3d unites →
    (the mesh, its parts)."""
    import coacd

    coacd.set_log_level("error")
    try:
        parts = coacd.run_coacd(
            coacd.Mesh(np.asarray(mesh.vertices), np.asarray(mesh.faces)),
            threshold=COACD_THRESHOLD,
            max_convex_hull=MAX_PARTS,
            preprocess_mode="on",
            seed=0,
        )
    except Exception as exc:  # CoACD raises RuntimeError and its own types
        raise MeshError(
            f"the mesh is not a manifold, and CoACD could not rebuild it ({exc}): repair it "
            "(e.g. in MeshLab) and export it again"
        ) from exc
    hulls = [trimesh.convex.convex_hull(vertices) for vertices, _ in parts]
    rebuilt = _united(hulls) if len(hulls) > 1 else hulls[0] if hulls else None
    if rebuilt is None or not rebuilt.is_watertight:
        raise MeshError(
            "the mesh is not a manifold, and its rebuild is not one closed surface either: "
            "repair it (e.g. in MeshLab) and export it again"
        )
    return rebuilt, len(hulls)


def stand_on_table(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """A copy of ``mesh`` resting on z = 0 with the origin at its footprint's centre, the
    footprint being its convex hull's vertices within FOOTPRINT_TOLERANCE_M of the lowest.
    MeshError if it would tip over at less than MIN_TIP_ANGLE (uniform density)."""
    mesh = mesh.copy()
    hull = mesh.convex_hull.vertices
    z = hull[:, 2]
    foot = hull[z <= z.min() + FOOTPRINT_TOLERANCE_M, :2]
    try:
        footprint = ConvexHull(foot)
    except (QhullError, ValueError):
        raise MeshError(
            "the mesh cannot stand on the table in the declared orientation: it touches it at "
            "a point or along a line only (try another --up)"
        ) from None
    polygon = foot[footprint.vertices]
    centre = _polygon_centroid(polygon)
    mesh.apply_translation((-centre[0], -centre[1], -z.min()))
    com = mesh.center_mass
    inside = -np.max(footprint.equations[:, :2] @ (com[:2] + centre) + footprint.equations[:, 2])
    tip = np.arctan2(inside, com[2])
    if tip < MIN_TIP_ANGLE:
        where = "outside" if inside < 0 else "inside"
        raise MeshError(
            f"the mesh cannot stand on the table in the declared orientation: its centre of "
            f"mass is {abs(inside) * 1000:.1f} mm {where} its footprint, {com[2] * 1000:.0f} mm "
            f"up, so it tips over at {np.degrees(tip):.0f}° (needs "
            f"{np.degrees(MIN_TIP_ANGLE):.0f}°; try another --up)"
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


def convex_parts(mesh: trimesh.Trimesh, seed: int = 0) -> list[np.ndarray]:
    """The vertices (N_k,3) [m] of each convex part of ``mesh``: CoACD's decomposition at
    COACD_THRESHOLD into at most MAX_PARTS parts, or, if those enclose more than
    MAX_HULL_EXCESS beyond the mesh (a thin curved wall bridged), its finer one at
    FINE_COACD_THRESHOLD into at most FINE_MAX_PARTS (seeded, so repeatable)."""
    parts = coacd_parts(mesh, COACD_THRESHOLD, MAX_PARTS, seed)
    excess = hull_excess(mesh, parts)
    if excess > MAX_HULL_EXCESS:
        log.info(
            "%d convex parts enclose %.0f%% more than the mesh; decomposing it finer",
            len(parts),
            excess * 100,
        )
        parts = coacd_parts(mesh, FINE_COACD_THRESHOLD, FINE_MAX_PARTS, seed)
    return parts


def hull_excess(mesh: trimesh.Trimesh, parts: list[np.ndarray]) -> float:
    """How much more the convex hulls of ``parts`` enclose, summed, than ``mesh``, as a share
    of its volume (0 for a decomposition that fits it exactly)."""
    return sum(ConvexHull(p).volume for p in parts) / mesh.volume - 1.0


def coacd_parts(
    mesh: trimesh.Trimesh, threshold: float, max_parts: int, seed: int = 0
) -> list[np.ndarray]:
    """The vertices (N_k,3) [m] of each convex part of CoACD's decomposition of ``mesh``
    (concavity ``threshold``, at most ``max_parts`` parts, each decimated to at most
    MAX_PART_VERTICES; seeded). The mesh is a closed manifold (check_mesh), so CoACD's
    pre-processing is off: its self-intersection test flags meshes that manifold3d united,
    and its voxel remesh (3.4 mm voxels across a 17 cm bowl) doubled a 3 mm wall."""
    import coacd

    coacd.set_log_level("error")
    parts = coacd.run_coacd(
        coacd.Mesh(np.asarray(mesh.vertices), np.asarray(mesh.faces)),
        threshold=threshold,
        max_convex_hull=max_parts,
        preprocess_mode="off",
        decimate=True,
        max_ch_vertex=MAX_PART_VERTICES,
        seed=seed,
    )
    log.info("CoACD: %d convex parts (threshold %.3g)", len(parts), threshold)
    return [np.asarray(vertices, dtype=float) for vertices, _ in parts]
