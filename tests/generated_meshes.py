"""Meshes of three everyday objects, generated with trimesh, for onboarding tests and the
onboarding benchmark (docs/objects.md, "Measured").

    python tests/generated_meshes.py OUT_DIR   # writes <name>.stl; prints "name path mass_kg"

Sizes (m) are those of common household items (chosen, not measured from one item).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import trimesh


def mug(sections: int = 64) -> trimesh.Trimesh:
    """A 9 cm mug, 9.5 cm tall, with a 5 mm wall, a 6 mm floor and a torus handle."""
    body = trimesh.creation.cylinder(radius=0.045, height=0.095, sections=sections)
    cavity = trimesh.creation.cylinder(radius=0.040, height=0.095, sections=sections)
    handle = trimesh.creation.torus(0.03, 0.006, major_sections=sections, minor_sections=16)
    handle.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (0, 1, 0)))
    shell = body.difference(cavity.apply_translation((0, 0, 0.006)))
    return shell.union(handle.apply_translation((0, 0.055, 0.0)))


def spray_bottle() -> trimesh.Trimesh:
    """A 6.5 x 4 cm body 16 cm tall, a neck and a trigger head."""
    body = trimesh.creation.box(extents=(0.065, 0.04, 0.16)).apply_translation((0, 0, 0.08))
    neck = trimesh.creation.cylinder(radius=0.013, height=0.03, sections=32)
    head = trimesh.creation.box(extents=(0.07, 0.025, 0.035))
    return body.union(neck.apply_translation((0, 0, 0.175))).union(
        head.apply_translation((0.015, 0, 0.2075))
    )


def l_bracket() -> trimesh.Trimesh:
    """An L-shaped bracket of 6 mm plate, 4 cm wide: a 12 cm foot and an 8 cm upright."""
    foot = trimesh.creation.box(extents=(0.12, 0.04, 0.006)).apply_translation((0, 0, 0.003))
    upright = trimesh.creation.box(extents=(0.006, 0.04, 0.08)).apply_translation((-0.057, 0, 0.04))
    return foot.union(upright)


#: The generated objects by name, with the mass [kg] they are onboarded with (chosen: about
#: a ceramic mug's and a half-full bottle's; the bracket's 48 cm³ of aluminium, 2.7 g/cm³).
GENERATED = {
    "mug": (mug, 0.3),
    "spray_bottle": (spray_bottle, 0.25),
    "l_bracket": (l_bracket, 0.13),
}


def write_all(out_dir: Path) -> dict[str, Path]:
    """Each generated mesh as ``<name>.stl`` in ``out_dir``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {}
    for name, (make, _) in GENERATED.items():
        paths[name] = out_dir / f"{name}.stl"
        make().export(paths[name])
    return paths


if __name__ == "__main__":
    for name, path in write_all(Path(sys.argv[1])).items():
        print(name, path, GENERATED[name][1])
