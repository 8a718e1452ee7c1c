"""Objects as data: an object folder's ``object.toml`` read into an ``ObjectModel``.

An object folder holds:

* ``object.toml``: name, mass, friction, sizes, source, the goal region with its required
  contacts, the goal grasp (and optionally further ones, ``[[goal_grasps]]``, each named and
  with its region's centre and, optionally, tolerances), optional hand-designed info grasps
  and reorientation, and the shape as named collision parts (``[[parts]]``: MuJoCo
  primitives, or convex mesh parts whose files the folder keeps, ``kind = "mesh"`` and
  ``file``);
* the artefacts measured or planned for it: ``settling.json`` and
  ``settling.realistic.json`` (rrg_sim.physics.settle; ``<goal>.settling.json`` for a
  further goal grasp), ``reorientation.json``
  (rrg_sim.physics.reorient_study) and ``table_touch.json`` (rrg_sim.table_touch), loaded
  when present.

Units are SI and named in the keys (``_m``, ``_rad``, ``_kg``). Every error names the file
and the key (``ObjectFileError``).
"""

from __future__ import annotations

import math
import re
import tomllib
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from rrg_models.goal import GoalRegion, RequiredContact
from rrg_models.objects.object_model import GoalGrasp, ObjectModel
from rrg_models.objects.primitives import SIZE_LENGTHS, Primitive
from rrg_models.objects.surface_pairs import Pinch
from rrg_models.objects.wrt_generation import (
    designed_pinch_wrt,
    line_grasp_wrt,
    reorient_wrts,
    side_rotation,
    top_down_rotation,
)

#: The object file's name inside an object folder.
OBJECT_FILE = "object.toml"
#: How a goal grasp approaches: name → its hand rotation from (yaw, pitch, roll) [rad].
APPROACHES = {
    "top_down": lambda yaw, pitch, roll: top_down_rotation(yaw),
    "side": lambda yaw, pitch, roll: side_rotation(pitch=pitch, roll=roll, yaw=yaw),
}


class ObjectFileError(ValueError):
    """An object file that cannot be read: names the file and what is wrong."""


class _Table:
    """A TOML table with typed, path-naming accessors (errors say file and key)."""

    def __init__(self, data: dict, where: str) -> None:
        self.data, self.where = data, where

    def error(self, key: str, what: str) -> ObjectFileError:
        return ObjectFileError(f"{self.where}: {key}: {what}")

    def get(self, key: str, default: Any = ...) -> Any:
        if key not in self.data:
            if default is ...:
                raise self.error(key, "missing")
            return default
        return self.data[key]

    def number(self, key: str, default: Any = ..., positive: bool = False) -> float:
        v = self.get(key, default)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or math.isnan(v):
            raise self.error(key, f"expected a number, got {v!r}")
        if positive and not v > 0:
            raise self.error(key, f"must be > 0, got {v!r}")
        return float(v)

    def vector(self, key: str, length: int, default: Any = ...) -> tuple[float, ...]:
        v = self.get(key, default)
        if (
            not isinstance(v, list)
            or len(v) != length
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
        ):
            raise self.error(key, f"expected {length} numbers, got {v!r}")
        return tuple(float(x) for x in v)

    def text(self, key: str, default: Any = ...) -> str:
        v = self.get(key, default)
        if not isinstance(v, str):
            raise self.error(key, f"expected a string, got {v!r}")
        return v

    def table(self, key: str, default: Any = ...) -> _Table:
        v = self.get(key, default)
        if not isinstance(v, dict):
            raise self.error(key, "expected a table")
        return _Table(v, f"{self.where} [{key}]")

    def tables(self, key: str) -> list[_Table]:
        v = self.get(key, [])
        if not isinstance(v, list) or not all(isinstance(t, dict) for t in v):
            raise self.error(key, "expected an array of tables")
        return [_Table(t, f"{self.where} [[{key}]] #{i + 1}") for i, t in enumerate(v)]


def _part(t: _Table, folder: Path) -> tuple[str, Primitive]:
    kind = t.text("kind")
    if kind not in SIZE_LENGTHS:
        raise t.error("kind", f"unknown kind {kind!r}; valid: {', '.join(sorted(SIZE_LENGTHS))}")
    pose = t.vector("pos_m", 3, [0.0, 0.0, 0.0]), t.vector("quat_wxyz", 4, [1.0, 0.0, 0.0, 0.0])
    if kind == "mesh":
        path = folder / t.text("file")
        try:
            vertices = trimesh.load_mesh(path, process=False).vertices
            return t.text("name"), Primitive("mesh", (), *pose, vertices=vertices)
        except (OSError, ValueError) as exc:
            raise t.error("file", f"{path}: {exc}") from exc
    try:
        return t.text("name"), Primitive(kind, t.vector("size_m", SIZE_LENGTHS[kind]), *pose)
    except ValueError as exc:
        raise t.error("size_m", str(exc)) from exc


def _tolerances(t: _Table, default: Any = ...) -> tuple[float, float, float]:
    """A goal region's ``tol`` (|dx| [m], |dy| [m], |dθ| [rad]), each > 0."""
    tol = t.vector("tol", 3, default)
    if not all(v > 0 for v in tol):
        raise t.error("tol", f"every tolerance must be > 0, got {tol}")
    return tol


def _goal_region(t: _Table, part_index: dict[str, int]) -> GoalRegion:
    contacts = []
    for c in t.tables("required_contacts"):
        names = c.get("parts")
        if not isinstance(names, list) or not names:
            raise c.error("parts", "expected a non-empty list of part names")
        unknown = [n for n in names if n not in part_index]
        if unknown:
            raise c.error("parts", f"no part called {unknown}; parts: {list(part_index)}")
        fingers = c.get("fingers", [1, 2, 3])
        try:
            contacts.append(
                RequiredContact(
                    c.text("name"),
                    tuple(part_index[n] for n in names),
                    tuple(int(f) for f in fingers),
                    int(c.number("min_fingers", 1)),
                )
            )
        except ValueError as exc:
            raise c.error("fingers", str(exc)) from exc
    tol = _tolerances(t)
    try:
        return GoalRegion(
            tol,
            min_fingers=int(t.number("min_fingers", 3)),
            required_contacts=tuple(contacts),
            theta_period=t.number("theta_period_rad", 2 * np.pi, positive=True),
            centre=t.vector("centre", 3, [0.0, 0.0, 0.0]),
        )
    except ValueError as exc:
        raise t.error("min_fingers", str(exc)) from exc


def goal_grasp_wrt(
    parts: tuple[Primitive, ...],
    approach: str,
    through_m,
    angles_rad: tuple[float, float, float] = (0.0, 0.0, 0.0),
    spread_rad: float = 0.0,
    preclose_rad: float = 0.0,
    standoff_m: float = 0.0,
    description: str = "",
    name: str = "goal",
):
    """The goal grasp WRT a ``[goal_grasp]`` table states: the hand turned as ``approach``
    by (yaw, pitch, roll) ``angles_rad``, along its approach through ``through_m`` [m]."""
    rotation = APPROACHES[approach](*angles_rad)
    return line_grasp_wrt(
        parts,
        rotation,
        through_m,
        spread=spread_rad,
        preclose=preclose_rad,
        standoff=standoff_m,
        description=description,
        name=name,
    )


def _goal_grasp(t: _Table, parts: tuple[Primitive, ...], name: str = "goal"):
    approach = t.text("approach")
    if approach not in APPROACHES:
        raise t.error("approach", f"unknown approach {approach!r}; valid: {', '.join(APPROACHES)}")
    angles = tuple(t.number(k, 0.0) for k in ("yaw_rad", "pitch_rad", "roll_rad"))
    return goal_grasp_wrt(
        parts,
        approach,
        t.vector("through_m", 3),
        angles,
        spread_rad=t.number("spread_rad", 0.0),
        preclose_rad=t.number("preclose_rad", 0.0),
        standoff_m=t.number("standoff_m", 0.0),
        description=t.text("description", ""),
        name=name,
    )


#: A further goal grasp's name: "goal" and a suffix (goal2, goal_rim, ...).
GOAL_NAME_PATTERN = re.compile(r"goal[a-z0-9_]+")


def _more_goals(
    top: _Table, parts: tuple[Primitive, ...], goal: GoalRegion
) -> tuple[GoalGrasp, ...]:
    """The object's further goal grasps, ``[[goal_grasps]]``: each a ``[goal_grasp]`` with
    its ``name``, the ``centre`` of its region and optionally its own ``tol`` (default:
    ``[goal_region]``'s)."""
    grasps = []
    for t in top.tables("goal_grasps"):
        name = t.text("name")
        if not GOAL_NAME_PATTERN.fullmatch(name) or name.endswith("_probe"):
            raise t.error("name", f"{name!r}: a goal grasp's name is goal and a suffix, as goal2")
        try:
            wrt = _goal_grasp(t, parts, name)
        except ValueError as exc:
            if isinstance(exc, ObjectFileError):
                raise
            raise t.error("through_m", str(exc)) from exc
        centre = tuple(t.vector("centre", 3, [0.0, 0.0, 0.0]))
        tol = _tolerances(t, list(goal.tol))
        grasps.append(GoalGrasp(wrt, replace(goal, centre=centre, tol=tol)))
    names = ["goal", *(g.name for g in grasps)]
    if len(set(names)) != len(names):
        raise top.error("goal_grasps", f"goal grasp names must be unique: {names}")
    return tuple(grasps)


def _info_grasp(t: _Table, parts: tuple[Primitive, ...]):
    axis = np.asarray(t.vector("axis", 3))
    if not np.isclose(np.linalg.norm(axis), 1.0, atol=1e-6) or abs(axis[2]) > 1e-9:
        raise t.error("axis", f"expected a horizontal unit vector, got {axis.tolist()}")
    pinch = Pinch(
        axis=axis,
        centre=np.asarray(t.vector("centre_m", 3)),
        separation=t.number("separation_m", positive=True),
        spread=t.number("spread_rad", 0.0),
        score=0.0,
    )
    try:
        return designed_pinch_wrt(parts, t.text("name"), pinch, t.text("what"))
    except ValueError as exc:
        raise t.error("centre_m", str(exc)) from exc


def read_object_file(path: Path) -> dict:
    """The parsed TOML of an object file (ObjectFileError if it is not valid TOML)."""
    try:
        return tomllib.loads(Path(path).read_text())
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ObjectFileError(f"{path}: {exc}") from exc


def load_object_folder(folder: Path | str) -> ObjectModel:
    """The ObjectModel described by ``folder``/object.toml (ObjectFileError if invalid)."""
    folder = Path(folder)
    path = folder / OBJECT_FILE
    top = _Table(read_object_file(path), str(path))
    named = [_part(t, folder) for t in top.tables("parts")]
    if not named:
        raise top.error("parts", "an object needs at least one part")
    part_index = {n: i for i, (n, _) in enumerate(named)}
    if len(part_index) != len(named):
        raise top.error("parts", "part names must be unique")
    parts = tuple(p for _, p in named)
    goal = _goal_region(top.table("goal_region"), part_index)
    grasp = top.table("goal_grasp")
    try:
        goal_wrt = _goal_grasp(grasp, parts)
    except ValueError as exc:
        if isinstance(exc, ObjectFileError):
            raise
        raise grasp.error("through_m", str(exc)) from exc
    reorient = top.get("reorientation", None)
    if reorient is not None:
        r = top.table("reorientation")
        away = r.vector("away_from", 3, None) if "away_from" in r.data else None
        try:
            reorient_grasps = reorient_wrts(
                parts, away_from=None if away is None else np.array(away)
            )
        except ValueError as exc:
            raise r.error("away_from", str(exc)) from exc
    else:
        reorient_grasps = ()
    dims = top.table("dimensions_m")
    name = top.text("name")
    if name != folder.name:
        raise top.error("name", f"{name!r} must match its folder's name {folder.name!r}")
    try:
        return ObjectModel(
            name,
            parts,
            mass=top.number("mass_kg", positive=True),
            friction=top.number("friction", positive=True),
            dimensions={k: dims.number(k) for k in dims.data},
            source=top.text("source"),
            goal=goal,
            goal_wrt=goal_wrt,
            more_goals=_more_goals(top, parts, goal),
            reorient_wrts=reorient_grasps,
            designed_info_wrts=tuple(_info_grasp(t, parts) for t in top.tables("info_grasps")),
            symmetric=goal.ignores_theta,
            placement_yaw=top.number("placement_yaw_rad", 0.0),
            track_settling=bool(top.get("track_settling", True)),
            description=top.text("description", ""),
            folder=folder,
        )
    except ValueError as exc:
        if isinstance(exc, ObjectFileError):
            raise
        raise ObjectFileError(f"{path}: {exc}") from exc
