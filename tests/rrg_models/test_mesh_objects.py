"""Mesh parts and mesh import: a convex mesh part is what its hull is to every simulator,
and a mesh file that cannot become an object is refused with a clear error."""

from __future__ import annotations

import itertools
from dataclasses import replace

import mujoco
import numpy as np
import pytest
import trimesh

from rrg_models.description.mjcf_robot import ROBOT_FILE, robot_xml
from rrg_models.objects import Primitive, get_object
from rrg_models.objects.mesh_import import (
    MeshError,
    check_mesh,
    convex_parts,
    import_mesh,
    stand_on_table,
)
from rrg_models.objects.wrt_generation import info_wrts
from rrg_sim.geometric_sim import GeometricSimulator
from rrg_sim.physics.scene import scene_xml


def as_mesh_part(p: Primitive) -> Primitive:
    """A box primitive as a mesh part: the convex hull of its eight corners."""
    corners = [tuple(np.array(s) * p.size) for s in itertools.product((-1, 1), repeat=3)]
    return Primitive("mesh", (), p.pos, p.quat, vertices=corners)


@pytest.fixture(scope="module")
def boxes():
    """The catalogue box, and the same box whose part is a mesh."""
    box = get_object("box")
    return box, replace(box, parts=(as_mesh_part(box.parts[0]),))


def test_a_mesh_part_has_its_hulls_distance_bounds_and_volume(boxes):
    box, mesh_box = boxes
    p, m = box.parts[0], mesh_box.parts[0]
    points = np.random.default_rng(0).uniform(-0.15, 0.15, (2000, 3)) + (0.0, 0.0, 0.05)
    exact, planes = p.signed_distance(points), m.signed_distance(points)
    inside = exact < 0
    assert inside.sum() > 50
    np.testing.assert_allclose(planes[inside], exact[inside], atol=1e-12)
    assert np.all(planes[~inside] <= exact[~inside] + 1e-12)  # a lower bound outside
    front = np.abs(points[:, 1]) < 0.09  # in front of the ±x faces, nearest a face
    on_x = ~inside & front & (np.abs(points[:, 2] - 0.05) < 0.04)
    np.testing.assert_allclose(planes[on_x], exact[on_x], atol=1e-12)
    np.testing.assert_allclose(m.bounds(), p.bounds(), atol=1e-15)
    assert m.volume == pytest.approx(p.volume, rel=1e-12)
    np.testing.assert_allclose(m.local_half_extents(), p.size)
    assert m.mesh().is_watertight and m.mesh().volume == pytest.approx(p.volume, rel=1e-9)


def test_a_mesh_part_needs_vertices_that_span_a_volume():
    with pytest.raises(ValueError, match="span no volume"):
        Primitive("mesh", (), vertices=[(0, 0, 0), (1, 0, 0), (0, 1, 0), (1, 1, 0)])
    with pytest.raises(ValueError, match="needs its vertices"):
        Primitive("mesh", ())
    with pytest.raises(ValueError, match="only a mesh part"):
        Primitive("sphere", (0.1,), vertices=[(0, 0, 0)])


def test_info_grasps_of_a_mesh_part_are_those_of_its_primitive(boxes):
    box, mesh_box = boxes
    for a, b in zip(info_wrts(box.parts), info_wrts(mesh_box.parts), strict=True):
        np.testing.assert_allclose(a.poses, b.poses, atol=1e-9)


def test_the_geometric_simulator_sees_a_mesh_part_as_its_primitive(boxes):
    box, mesh_box = boxes
    deltas = np.random.default_rng(1).normal(0.0, (0.02, 0.02, 0.2), (120, 3))
    for wrt in box.wrts()[:2]:
        a = GeometricSimulator(box, wrt).simulate_batch(deltas)
        b = GeometricSimulator(mesh_box, wrt).simulate_batch(deltas)
        np.testing.assert_array_equal(a.contact, b.contact)
        np.testing.assert_allclose(a.progress, b.progress, atol=5e-4)
        # MuJoCo's box-box and mesh-box collisions differ only at grazing finger contacts.
        assert np.mean(np.abs(a.closure - b.closure) < 0.02) > 0.97


def test_the_physics_scene_holds_a_mesh_part_with_the_objects_mass(boxes):
    _, mesh_box = boxes
    model = mujoco.MjModel.from_xml_string(
        scene_xml(mesh_box), assets={ROBOT_FILE: robot_xml().encode()}
    )
    assert model.body("object").mass[0] == pytest.approx(mesh_box.mass, rel=1e-6)
    assert model.geom("object/0").type == mujoco.mjtGeom.mjGEOM_MESH


# ------------------------------------------------------------------ mesh files
def write(mesh: trimesh.Trimesh, path) -> str:
    mesh.export(path)
    return str(path)


def test_import_scales_declared_units_and_turns_the_up_axis(tmp_path):
    tall_in_y = trimesh.creation.box(extents=(40.0, 100.0, 20.0))  # millimetres, y up
    mesh = import_mesh(write(tall_in_y, tmp_path / "b.stl"), units="mm", up="y")
    np.testing.assert_allclose(mesh.extents, (0.04, 0.02, 0.1), atol=1e-9)
    x_up = import_mesh(tmp_path / "b.stl", units="mm", up="x")
    np.testing.assert_allclose(x_up.extents, (0.02, 0.1, 0.04), atol=1e-9)
    with pytest.raises(MeshError, match="unknown units"):
        import_mesh(tmp_path / "b.stl", units="furlong")


def test_an_empty_or_unreadable_file_is_refused(tmp_path):
    (tmp_path / "empty.stl").write_text("solid empty\nendsolid empty\n")
    with pytest.raises(MeshError, match="empty"):
        import_mesh(tmp_path / "empty.stl")
    (tmp_path / "junk.ply").write_bytes(b"\x00not a mesh")
    with pytest.raises(MeshError, match="cannot read a mesh|empty"):
        import_mesh(tmp_path / "junk.ply")


def box_at(extents, centre) -> trimesh.Trimesh:
    """A closed box of ``extents`` [m] centred at ``centre`` [m]."""
    return trimesh.creation.box(extents=extents).apply_translation(centre)


def test_a_small_hole_is_filled_and_said():
    box = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    pierced = trimesh.Trimesh(box.vertices, box.faces[1:], process=False)  # one triangle gone
    assert not pierced.is_watertight
    mesh, repair = check_mesh(pierced)
    assert mesh.volume == pytest.approx(box.volume)
    assert (repair.holes_filled, repair.shells_united) == (1, 0)
    assert "1 faces added to close holes" in repair.describe()
    assert check_mesh(box)[1].describe() == "no repair needed"


@pytest.mark.parametrize(
    "case, shells, volume_m3",
    [
        # a bracket exported as two overlapping boxes: the overlap counts once
        (
            "overlapping boxes",
            [
                box_at((0.06, 0.04, 0.04), (0, 0, 0.02)),
                box_at((0.04, 0.06, 0.04), (0.01, 0.01, 0.03)),
            ],
            0.06 * 0.04 * 0.04 + 0.04 * 0.06 * 0.04 - 0.04 * 0.04 * 0.03,
        ),
        # a vessel whose handle is a box touching its body
        (
            "body and touching handle",
            [box_at((0.08, 0.08, 0.1), (0, 0, 0.05)), box_at((0.01, 0.02, 0.06), (0.045, 0, 0.05))],
            0.08 * 0.08 * 0.1 + 0.01 * 0.02 * 0.06,
        ),
        # two cubes that share one edge: after merging vertices, that edge bounds four faces
        (
            "a non-manifold edge",
            [box_at((0.05,) * 3, (0, 0, 0)), box_at((0.05,) * 3, (0.05, 0.05, 0))],
            2 * 0.05**3,
        ),
    ],
)
def test_closed_shells_are_united_into_one_closed_surface(case, shells, volume_m3):
    mesh, repair = check_mesh(trimesh.util.concatenate(shells))
    assert mesh.is_watertight and mesh.is_volume
    assert mesh.volume == pytest.approx(volume_m3, rel=1e-6)
    assert repair.shells_united == len(shells)
    assert repair.volume_before_m3 == pytest.approx(sum(s.volume for s in shells))
    assert repair.volume_after_m3 == pytest.approx(volume_m3, rel=1e-6)
    assert f"{len(shells)} closed shells united into one" in repair.describe()


def test_bodies_glued_by_a_face_are_rebuilt_from_coacds_manifold_preprocessing():
    """Two blocks stacked in CAD, each exported closed: the face they share is there twice,
    with other diagonals, and its edges bound four faces in one tangle that manifold3d cannot
    take. CoACD's pre-processing rebuilds one closed surface, within a voxel of the blocks."""
    from rrg_models.objects.mesh_import import MAX_REBUILD_VOLUME_CHANGE, enclosed_volume

    lower = trimesh.creation.box(bounds=[[0, 0, 0], [0.04, 0.04, 0.04]])
    upper = trimesh.creation.box(bounds=[[0, 0, 0.04], [0.04, 0.04, 0.08]])
    glued = trimesh.util.concatenate([lower, upper])
    merged = glued.copy()
    merged.merge_vertices()
    pieces = merged.split(only_watertight=False)  # the shared face splits off, open
    assert not all(piece.is_watertight for piece in pieces)
    mesh, repair = check_mesh(glued)
    assert mesh.is_watertight and mesh.is_volume
    assert repair.rebuilt_parts >= 1 and repair.shells_united == 0
    assert repair.volume_before_m3 == pytest.approx(0.04 * 0.04 * 0.08, rel=0.01)
    assert repair.volume_after_m3 == pytest.approx(mesh.volume)
    assert abs(mesh.volume / repair.volume_before_m3 - 1) <= MAX_REBUILD_VOLUME_CHANGE
    np.testing.assert_allclose(mesh.bounds, [[0, 0, 0], [0.04, 0.04, 0.08]], atol=0.001)
    assert "rebuilt as one closed surface from CoACD's manifold" in repair.describe()
    assert enclosed_volume(box_at((0.05, 0.03, 0.02), (0, 0, 0))) == pytest.approx(
        0.05 * 0.03 * 0.02, rel=0.02
    )


def test_a_rebuild_that_changes_the_volume_beyond_the_bound_is_refused():
    """Thin glued plates (1.5 mm) thicken by about a voxel of the pre-processing: more than
    MAX_REBUILD_VOLUME_CHANGE, refused with the volumes."""
    lower = trimesh.creation.box(bounds=[[0, 0, 0], [0.05, 0.0015, 0.04]])
    upper = trimesh.creation.box(bounds=[[0, 0, 0.04], [0.05, 0.0015, 0.08]])
    with pytest.raises(MeshError, match=r"rebuilding it as one closed surface changed its volume"):
        check_mesh(trimesh.util.concatenate([lower, upper]))


def test_an_open_sheet_or_a_flat_mesh_is_refused_with_its_reason():
    sphere = trimesh.creation.icosphere(radius=0.03)
    cut = sphere.faces[sphere.triangles_center[:, 2] < 0.02]  # its cap above 2 cm gone
    with pytest.raises(MeshError, match=r"the mesh is open: \d+ edges bound a single face"):
        check_mesh(trimesh.Trimesh(sphere.vertices, cut, process=False))
    sheet = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    top = sheet.faces[sheet.triangles_center[:, 2] > 0.02]  # one square face: a flat sheet
    with pytest.raises(MeshError, match="the mesh is open"):
        check_mesh(trimesh.Trimesh(sheet.vertices, top, process=False))
    flat = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    flat.vertices[:, 2] = 0.0  # a closed surface squashed flat: no volume
    with pytest.raises(MeshError, match="empty|no volume"):
        check_mesh(flat)


def test_a_mesh_in_millimetres_declared_as_metres_is_refused_unless_told(tmp_path):
    mug_mm = trimesh.creation.cylinder(radius=45.0, height=95.0)
    mesh = import_mesh(write(mug_mm, tmp_path / "mug.stl"), units="m")
    with pytest.raises(MeshError, match=r"95 m across.*--units mm"):
        check_mesh(mesh)
    assert check_mesh(mesh, allow_size=True)[0].extents.max() == pytest.approx(95.0)


def test_stand_on_table_centres_the_footprint_and_refuses_what_would_fall():
    box = trimesh.creation.box(extents=(0.04, 0.06, 0.1))
    box.apply_translation((0.3, -0.2, 0.5))
    placed = stand_on_table(box)
    np.testing.assert_allclose(placed.bounds, [[-0.02, -0.03, 0.0], [0.02, 0.03, 0.1]], atol=1e-12)
    cone = trimesh.creation.cone(radius=0.03, height=0.08)
    cone.apply_transform(trimesh.transformations.rotation_matrix(np.pi, (1, 0, 0)))  # on its tip
    with pytest.raises(MeshError, match="at a point or along a line"):
        stand_on_table(cone)
    with pytest.raises(MeshError, match="cannot stand"):
        stand_on_table(trimesh.creation.icosphere(radius=0.04))
    # An L standing on a short, narrow foot with its long arm overhanging.
    foot = trimesh.creation.box(extents=(0.02, 0.03, 0.02)).apply_translation((0, 0, 0.01))
    arm = trimesh.creation.box(extents=(0.15, 0.03, 0.02)).apply_translation((0.065, 0, 0.03))
    with pytest.raises(MeshError, match="outside its footprint"):
        stand_on_table(foot.union(arm))
    tall = trimesh.creation.box(extents=(0.02, 0.02, 0.2))  # tips over at 5.7°
    with pytest.raises(MeshError, match="inside its footprint.* tips over at 6°"):
        stand_on_table(tall)


def test_convex_parts_keep_a_concavity():
    u = trimesh.creation.box(extents=(0.08, 0.03, 0.06)).difference(
        trimesh.creation.box(extents=(0.05, 0.04, 0.05)).apply_translation((0, 0, 0.015))
    )
    parts = [Primitive("mesh", (), vertices=v) for v in convex_parts(u)]
    assert 2 <= len(parts) <= 6
    from rrg_models.objects import signed_distance

    assert signed_distance(parts, [(0.0, 0.0, 0.02)]) > 0.005  # the notch stays open
    assert signed_distance(parts, [(0.03, 0.0, 0.0)]) < 0.0  # the walls stay solid
    assert sum(p.volume for p in parts) == pytest.approx(u.volume, rel=0.15)


@pytest.mark.slow
def test_a_thin_curved_wall_is_decomposed_finer_until_its_parts_fit_it():
    """The flared bowl's 3 mm wall: 24 parts enclose far more than it (they bridge the curve
    and fill the wedge under the rim), so it gets the finer decomposition, whose parts leave
    the cavity and the space under the rim open and still hold the wall."""
    from generated_meshes import flared_bowl

    from rrg_models.objects import signed_distance
    from rrg_models.objects.mesh_import import (
        COACD_THRESHOLD,
        FINE_MAX_PARTS,
        MAX_HULL_EXCESS,
        MAX_PARTS,
        check_mesh,
        coacd_parts,
        hull_excess,
    )

    bowl = stand_on_table(check_mesh(flared_bowl(24))[0])
    assert hull_excess(bowl, coacd_parts(bowl, COACD_THRESHOLD, MAX_PARTS)) > MAX_HULL_EXCESS
    parts = convex_parts(bowl)
    assert MAX_PARTS < len(parts) <= FINE_MAX_PARTS
    assert hull_excess(bowl, parts) <= MAX_HULL_EXCESS
    under_rim, cavity, wall = (0.075, 0.0, 0.045), (0.05, 0.0, 0.05), (0.0616, 0.0, 0.045)
    distance = signed_distance(
        [Primitive("mesh", (), vertices=v) for v in parts], [under_rim, cavity, wall]
    )
    assert distance[0] > 0.005 and distance[1] > 0.005 and distance[2] < 0.0


def test_an_object_file_takes_mesh_parts_from_its_folder(tmp_path, boxes):
    import shutil

    from rrg_models.objects import ObjectFileError, load_object_folder
    from rrg_models.objects.catalogue import BUILTIN_DIR

    box, mesh_box = boxes
    folder = tmp_path / "box"
    shutil.copytree(BUILTIN_DIR / "box", folder)
    (folder / "collision").mkdir()
    mesh_box.parts[0].mesh().export(folder / "collision" / "body.stl")
    path = folder / "object.toml"
    text = path.read_text()
    head, part = text.split("[[parts]]")
    path.write_text(head + '[[parts]]\nname = "body"\nkind = "mesh"\nfile = "collision/body.stl"\n')
    loaded = load_object_folder(folder)
    assert loaded.parts[0].kind == "mesh"
    np.testing.assert_allclose(loaded.parts[0].bounds(), box.parts[0].bounds(), atol=1e-6)
    np.testing.assert_allclose(loaded.goal_wrt.poses, box.goal_wrt.poses, atol=1e-6)
    (folder / "collision" / "body.stl").unlink()
    with pytest.raises(ObjectFileError, match=r"file: .*body.stl"):
        load_object_folder(folder)
