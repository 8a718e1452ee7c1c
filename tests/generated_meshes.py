"""Meshes of everyday objects, generated with trimesh, for onboarding tests and the
onboarding benchmark (docs/objects.md, "Measured"). The pitcher, the flared bowl and the
spatula are their raw parts, overlapping and not united, as CAD assemblies export them.

    python tests/generated_meshes.py OUT_DIR   # writes <name>.stl; prints "name path mass_kg"
    python tests/generated_meshes.py OUT_DIR --dense   # only pitcher_50k.stl (dense_pitcher)

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


def tin_can(sections: int = 64) -> trimesh.Trimesh:
    """A closed cylinder 8 cm across and 12 cm tall."""
    return trimesh.creation.cylinder(radius=0.04, height=0.12, sections=sections)


def pitcher(sections: int = 64) -> trimesh.Trimesh:
    """A 10 cm pitcher 15 cm tall with a 5 mm wall and a 6 mm floor, and a handle built from
    three 1.5 cm bars that overlap the wall and each other: its raw parts, not united (as a
    CAD assembly exports them)."""
    body = trimesh.creation.cylinder(radius=0.05, height=0.15, sections=sections)
    cavity = trimesh.creation.cylinder(radius=0.045, height=0.15, sections=sections)
    shell = body.difference(cavity.apply_translation((0, 0, 0.006))).apply_translation(
        (0, 0, 0.075)
    )
    bars = [
        trimesh.creation.box(extents=extents).apply_translation(centre)
        for extents, centre in [
            ((0.05, 0.015, 0.015), (0.07, 0.0, 0.13)),  # from the wall, near the top
            ((0.015, 0.015, 0.105), (0.09, 0.0, 0.085)),  # down, clear of the wall
            ((0.05, 0.015, 0.015), (0.07, 0.0, 0.04)),  # back into the wall
        ]
    ]
    return trimesh.util.concatenate([shell, *bars])


def dense_pitcher() -> trimesh.Trimesh:
    """The pitcher's raw, overlapping parts at 51,344 triangles (1,600 sections, each
    triangle then split in four): the onboarding timing's 50k-triangle mesh."""
    return pitcher(1600).subdivide()


def flared_bowl(sections: int = 64) -> trimesh.Trimesh:
    """A bowl 14 cm across and 6 cm tall with a 3 mm wall and a 4 mm floor, and a thin rim
    flaring out to 17 cm: its raw parts, the rim a ring that overlaps the wall's top."""
    wall = np.array(
        [[0.0, 0.0], [0.04, 0.0], [0.07, 0.058], [0.067, 0.058], [0.0375, 0.004], [0.0, 0.004]]
    )
    rim = np.array(  # closed: it does not reach the axis
        [[0.066, 0.054], [0.085, 0.062], [0.085, 0.0645], [0.066, 0.057], [0.066, 0.054]]
    )
    return trimesh.util.concatenate(
        [trimesh.creation.revolve(profile, sections=sections) for profile in (wall, rim)]
    )


def spatula() -> trimesh.Trimesh:
    """A spatula lying on the table: a 6 x 9 cm blade 3 mm thick and a chunky 14 cm handle,
    2.2 cm wide and 2.8 cm tall, that overlaps the blade's end: its raw parts, not united."""
    blade = trimesh.creation.box(extents=(0.09, 0.06, 0.003)).apply_translation((-0.06, 0, 0.0015))
    handle = trimesh.creation.box(extents=(0.14, 0.022, 0.028)).apply_translation((0.075, 0, 0.014))
    return trimesh.util.concatenate([blade, handle])


#: The generated objects by name, with the mass [kg] they are onboarded with (chosen: about
#: a ceramic mug's and a half-full bottle's; the bracket's 48 cm³ of aluminium, 2.7 g/cm³; a
#: full 400 g tin; the pitcher's 300 cm³ and the bowl's 110 cm³ of material at 1.2 g/cm³
#: (plastic) and 2.4 g/cm³ (ceramic); the spatula's 102 cm³ at 0.8 g/cm³, wood and nylon).
GENERATED = {
    "mug": (mug, 0.3),
    "spray_bottle": (spray_bottle, 0.25),
    "l_bracket": (l_bracket, 0.13),
    "tin_can": (tin_can, 0.4),
    "pitcher": (pitcher, 0.36),
    "flared_bowl": (flared_bowl, 0.26),
    "spatula": (spatula, 0.08),
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
    if sys.argv[2:] == ["--dense"]:
        Path(sys.argv[1]).mkdir(parents=True, exist_ok=True)
        dense_pitcher().export(Path(sys.argv[1]) / "pitcher_50k.stl")
        print("pitcher_50k", Path(sys.argv[1]) / "pitcher_50k.stl", GENERATED["pitcher"][1])
    else:
        for name, path in write_all(Path(sys.argv[1])).items():
            print(name, path, GENERATED[name][1])
