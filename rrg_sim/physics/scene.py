"""MJCF scenes: the table in front of the robot, lights, and one object as a free body.

``scene_xml(obj)`` includes the robot file (``mjcf_robot.ROBOT_FILE``) as mujoco_menagerie's
scene files do; ``build_model(obj)`` compiles it from memory. ``write_assets()`` writes the
robot, the bare scene and one scene per object to ``rrg_sim/assets/`` for MuJoCo's viewer
(``python -m mujoco.viewer --mjcf rrg_sim/assets/scene_powerdrill.xml``); a test keeps them
identical to what the code builds.
"""

from __future__ import annotations

import argparse
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco

from rrg_models.config import WORLD
from rrg_models.description.mjcf import sub, to_xml
from rrg_models.description.mjcf_robot import ROBOT_FILE, robot_xml
from rrg_models.objects import PAPER_OBJECTS, ObjectModel, get_object
from rrg_models.objects.primitives import mjcf_mesh_asset

ASSETS_DIR = Path(__file__).resolve().parent.parent / "assets"
OBJECT_BODY = "object"
OBJECT_JOINT = "object/free"
#: Collision bits (robot: contype 1, conaffinity 2). The table top collides with the robot and
#: with the object's convex hull; the object's primitives collide with the robot only.
#: Against a flat table only an object's convex hull matters, so resting and tipping are
#: exact while the hull keeps object-table contacts few (a cup's 16 wall boxes would make
#: 64); the primitives keep the concavities the hand can reach into.
TABLE_CONTYPE, TABLE_CONAFFINITY = 4, 1
PARTS_CONTYPE, PARTS_CONAFFINITY = 2, 0
HULL_CONTYPE, HULL_CONAFFINITY = 0, 4
#: Height of the table top above the (visual) floor [m] (chosen: a standard 75 cm table).
TABLE_HEIGHT = 0.75
OBJECT_RGBA = "0.85 0.45 0.15 1"
#: Offscreen framebuffer for renders [px].
OFFSCREEN = (1280, 960)


def _visual_assets(root: ET.Element) -> None:
    visual = sub(root, "visual")
    sub(visual, "headlight", diffuse="0.5 0.5 0.5", ambient="0.3 0.3 0.3", specular="0 0 0")
    sub(visual, "global", azimuth=150, elevation=-25, offwidth=OFFSCREEN[0], offheight=OFFSCREEN[1])
    sub(visual, "quality", shadowsize=4096)
    sub(root, "statistic", center="0.6 0 0.2", extent=1.0)
    asset = sub(root, "asset")
    sub(
        asset,
        "texture",
        type="skybox",
        builtin="gradient",
        rgb1="0.3 0.5 0.7",
        rgb2="0 0 0",
        width=512,
        height=3072,
    )
    sub(
        asset,
        "texture",
        type="2d",
        name="groundplane",
        builtin="checker",
        mark="edge",
        rgb1="0.2 0.3 0.4",
        rgb2="0.1 0.2 0.3",
        markrgb="0.8 0.8 0.8",
        width=300,
        height=300,
    )
    sub(
        asset,
        "material",
        name="groundplane",
        texture="groundplane",
        texuniform="true",
        texrepeat="5 5",
        reflectance=0.2,
    )
    sub(asset, "material", name="table", rgba="0.62 0.5 0.38 1")


def _environment(worldbody: ET.Element) -> None:
    """Light, the table top (a collision plane at WORLD.table_top_z, drawn over the table's
    extent; the object stays far from its edges), the table slab, floor and pedestal (visual)."""
    w = WORLD
    sub(worldbody, "light", pos="0.6 0 2.5", dir="0 0 -1", directional="true")
    hx, hy = (w.table_x[1] - w.table_x[0]) / 2, (w.table_y[1] - w.table_y[0]) / 2
    cx, cy = (w.table_x[0] + w.table_x[1]) / 2, (w.table_y[0] + w.table_y[1]) / 2
    sub(
        worldbody,
        "geom",
        name="table",
        type="plane",
        material="table",
        size=(hx, hy, 0.05),
        pos=(cx, cy, w.table_top_z),
        friction=f"{w.table_friction} 0.005 0.0001",
        contype=TABLE_CONTYPE,
        conaffinity=TABLE_CONAFFINITY,
    )
    visual = dict(contype=0, conaffinity=0)
    sub(
        worldbody,
        "geom",
        name="table_slab",
        type="box",
        material="table",
        size=(hx, hy, w.table_thickness / 2),
        pos=(cx, cy, w.table_top_z - w.table_thickness / 2 - 1e-4),
        **visual,
    )
    sub(
        worldbody,
        "geom",
        name="floor",
        type="plane",
        size="0 0 0.05",
        pos=(0, 0, w.table_top_z - TABLE_HEIGHT),
        material="groundplane",
        **visual,
    )
    sub(
        worldbody,
        "geom",
        name="pedestal",
        type="box",
        size=(0.15, 0.15, TABLE_HEIGHT / 2),
        pos=(-0.04, 0, w.table_top_z - TABLE_HEIGHT / 2),
        rgba="0.3 0.3 0.32 1",
        **visual,
    )


def _object(worldbody: ET.Element, obj: ObjectModel) -> None:
    """The object as a free body at the table origin (placed later through its free joint):
    the catalogue's primitives with one density giving the catalogue mass, plus its massless
    convex hull for the table contact (see the collision bits above)."""
    body = sub(worldbody, "body", name=OBJECT_BODY, pos=(0, 0, WORLD.table_top_z))
    sub(body, "freejoint", name=OBJECT_JOINT)
    volume = sum(p.volume for p in obj.parts)
    friction = f"{obj.friction} 0.005 0.0001"
    for k, p in enumerate(obj.parts):
        shape = {"mesh": f"object_part_{k}"} if p.kind == "mesh" else {"size": p.size}
        sub(
            body,
            "geom",
            name=f"object/{k}",
            type=p.kind,
            **shape,
            pos=p.pos,
            quat=p.quat,
            density=obj.mass / volume,
            friction=friction,
            condim=4,
            rgba=OBJECT_RGBA,
            contype=PARTS_CONTYPE,
            conaffinity=PARTS_CONAFFINITY,
        )
    sub(
        body,
        "geom",
        name="object/hull",
        type="mesh",
        mesh="object_hull",
        density=0,
        friction=friction,
        condim=4,
        group=3,
        rgba="0 0 0 0",
        contype=HULL_CONTYPE,
        conaffinity=HULL_CONAFFINITY,
    )


def _hull_asset(root: ET.Element, obj: ObjectModel) -> None:
    asset = root.find("asset")
    sub(asset, "mesh", name="object_hull", vertex=obj.mesh().convex_hull.vertices.ravel())
    for k, p in enumerate(obj.parts):
        if p.kind == "mesh":
            sub(asset, "mesh", **mjcf_mesh_asset(p, f"object_part_{k}"))


def scene_xml(obj: ObjectModel | None) -> str:
    """Scene MJCF: includes the robot, adds the table, lights and (optionally) the object."""
    root = ET.Element("mujoco", model=f"rrg_{obj.name}" if obj else "rrg_scene")
    sub(root, "include", file=ROBOT_FILE)
    _visual_assets(root)
    worldbody = sub(root, "worldbody")
    _environment(worldbody)
    if obj is not None:
        _hull_asset(root, obj)
        _object(worldbody, obj)
    return to_xml(root)


def build_model(object_name: str | None) -> mujoco.MjModel:
    """Compile the scene with one catalogue object (or none) from memory."""
    obj = get_object(object_name) if object_name else None
    return mujoco.MjModel.from_xml_string(scene_xml(obj), assets={ROBOT_FILE: robot_xml().encode()})


def asset_files() -> dict[str, str]:
    """File name → MJCF text of every generated asset."""
    files = {ROBOT_FILE: robot_xml(), "scene.xml": scene_xml(None)}
    files |= {f"scene_{name}.xml": scene_xml(get_object(name)) for name in PAPER_OBJECTS}
    return files


def write_assets(directory: Path = ASSETS_DIR) -> list[Path]:
    """Write every generated MJCF file to ``directory``; returns the paths."""
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, text in asset_files().items():
        path = directory / name
        path.write_text(text)
        paths.append(path)
    return paths


def main(argv: list[str] | None = None) -> int:
    """``python -m rrg_sim.physics.scene [--dir DIR]``: regenerate the MJCF assets."""
    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("--dir", type=Path, default=ASSETS_DIR)
    for path in write_assets(parser.parse_args(argv).dir):
        print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
