"""rrg_models.objects.symmetry: an object's rotational symmetry about its vertical axis, found
from its mesh, as the goal region's θ needs it (ignored, or taken modulo 2π/n)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from rrg_models.objects.mesh_import import stand_on_table
from rrg_models.objects.symmetry import SYMMETRY_TOLERANCE_M, rotational_symmetry


def prism(radius_m: float, sides: int, height_m: float = 0.08) -> trimesh.Trimesh:
    return stand_on_table(trimesh.creation.cylinder(radius_m, height_m, sections=sides))


@pytest.mark.parametrize(
    ("mesh", "folds"),
    [
        (prism(0.04, 32, 0.12), 0),  # a tessellated can: the same at every turn
        (prism(0.05, 12), 0),  # 12 sides deviate 1.7 mm at most from the circle
        (prism(0.04, 8), 8),  # fits 12-fold within 2 mm too, 8-fold exactly
        (prism(0.04, 6), 6),  # and not 7-fold, which its first turn nearly fits
        (prism(0.04, 3), 3),
        (stand_on_table(trimesh.creation.box(extents=(0.05, 0.05, 0.09))), 4),
        (stand_on_table(trimesh.creation.box(extents=(0.05, 0.07, 0.09))), 2),
    ],
)
def test_symmetric_meshes_are_found_with_their_turns(mesh, folds):
    symmetry = rotational_symmetry(mesh)
    assert symmetry.folds == folds
    assert symmetry.deviation_m <= SYMMETRY_TOLERANCE_M
    expected = np.inf if folds == 0 else 2 * np.pi / folds
    assert symmetry.theta_period_rad == expected


def test_a_handle_or_a_small_spout_breaks_the_symmetry():
    from generated_meshes import mug

    symmetry = rotational_symmetry(stand_on_table(mug()))
    assert symmetry.folds == 1 and symmetry.deviation_m > 0.02  # the handle, 5.5 cm out
    assert "not symmetric" in symmetry.describe()
    body = trimesh.creation.cylinder(0.04, 0.10, sections=48)
    spout = trimesh.creation.box(extents=(0.01, 0.01, 0.01)).apply_translation((0.044, 0, 0.045))
    spouted = stand_on_table(trimesh.boolean.union([body, spout], engine="manifold"))
    assert rotational_symmetry(spouted).folds == 1


def test_the_axis_is_the_vertical_through_the_origin():
    """A cylinder standing beside the origin is not symmetric about it (stand_on_table puts
    the origin on the footprint's centre, which is on the axis of a symmetric object)."""
    off = trimesh.creation.cylinder(0.04, 0.12, sections=32).apply_translation((0.01, 0, 0.06))
    assert rotational_symmetry(off).folds == 1
    assert rotational_symmetry(stand_on_table(off)).folds == 0
