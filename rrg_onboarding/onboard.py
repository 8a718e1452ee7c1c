"""``rrg-object add``: a mesh file onboarded as an installed object, stage by stage.

1. *mesh*: read in its declared units and up axis, repaired and checked, stood on the table
   (rrg_models.objects.mesh_import);
2. *decompose*: CoACD's convex parts, one collision file each;
3. *goal grasp*: the one given, or proposed: among the top-down pinches the info-grasp
   generator finds on the parts (rrg_models.objects.surface_pairs), narrower than the hand opens,
   whose descent is free and which the WAM reaches at the nominal pose, side envelopes of
   the pinched faces and side grasps of a thin rim (the object placed turned so that the WAM
   reaches them), a few distinct ones are each run from starts across twice the goal region
   in physics, and the one whose grasps held most often wins (an object with no pinch and no
   rim is too big for the hand);
4. *object file*: ``object.toml``, read back as every object is;
5. *studies*: the grasp-settling study, whose intercept centres the goal region, the same
   study in the realistic world (``settling.realistic.json``: the planner's hold prediction
   there), and the reorientation study when the goal grasp cannot run at every heading
   (dropped if its WRTs rarely turn the object; rrg_sim.physics.settle, reorient_study);
6. *tables*: the observation tables and feasibility maps of every WRT at every level
   (rrg_planner.planning_model);
7. *picture*: the goal grasp closed on the object, ``goal.png``.

Everything is built in a staging folder beside the user objects folder and moved into it in
one rename at the end, so a refused or failed onboarding leaves nothing installed.
"""

from __future__ import annotations

import itertools
import logging
import os
import re
import shutil
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from rrg_common.parallel import fork_map
from rrg_models import wam
from rrg_models.config import WORLD
from rrg_models.goal import GoalRegion, Settling
from rrg_models.objects import (
    ObjectFileError,
    Primitive,
    load_object_folder,
    object_folders,
    signed_distance,
    user_objects_dir,
)
from rrg_models.objects.catalogue import USER_DIR_ENV
from rrg_models.objects.composites import turn_about_z
from rrg_models.objects.mesh_import import (
    MeshError,
    MeshRepair,
    check_mesh,
    convex_parts,
    hull_excess,
    import_mesh,
    stand_on_table,
)
from rrg_models.objects.object_file import OBJECT_FILE, goal_grasp_wrt
from rrg_models.objects.surface_pairs import (
    MIN_FINGER_CLEARANCE,
    Pinch,
    finger_gap,
    pinch_candidates,
)
from rrg_models.objects.symmetry import Symmetry, rotational_symmetry
from rrg_models.objects.wrt_generation import (
    line_grasp_wrt,
    reorient_wrts,
    side_rotation,
    top_down_poses,
    top_down_rotation,
)
from rrg_models.poses import wrap_angle

log = logging.getLogger(__name__)

#: An object's name: a lower-case identifier, as the paper's objects have.
NAME_PATTERN = re.compile(r"[a-z][a-z0-9_]{0,39}")
#: Density [kg/m³] that gives a mass when none is declared (chosen: water's, about that of
#: the plastics and filled containers a lab grasps; pass --mass for anything else).
DEFAULT_DENSITY = 1000.0
#: Friction of an object whose friction is not declared (chosen: 0.5, the paper objects'
#: most common value, docs/world.md).
DEFAULT_FRICTION = 0.5
#: Goal region of a proposed goal grasp: |dx|, |dy| [m], |dθ| [rad] (chosen: the paper
#: objects' most common region, 1 cm and 10°).
DEFAULT_TOL = (0.01, 0.01, float(np.radians(10.0)))
#: A proposed goal region's tolerances, unless given (--goal-tol), are measured: the widest of
#: these multiples of DEFAULT_TOL (θ too, unless ignored) about the grasp's intercept within
#: which at least FUNNEL_MIN_HELD of the grasps that closed there held (the paper's regions
#: were "hand-chosen to guarantee that being within the goal region ensures a stable grasp",
#: its can's 2.5 × 1.5 cm, its cup's ignoring θ). The grasps are a settling study's,
#: FUNNEL_GRASPS_FACTOR × --settle-grasps of them across twice the widest region; a multiple
#: is judged once at least FUNNEL_MIN_SAMPLES closed in it (chosen: a failure in 20 grasps is
#: allowed).
FUNNEL_SCALES = (1.0, 1.5, 2.0, 2.5)
FUNNEL_MIN_HELD = 0.95
FUNNEL_MIN_SAMPLES = 10
FUNNEL_GRASPS_FACTOR = 2
#: Goal grasps of the settling study, and runs per WRT of the reorientation study (the paper
#: objects' studies used 300 and 40; chosen smaller to keep onboarding within minutes).
SETTLE_GRASPS = 60
REORIENT_RUNS = 20
#: Goal candidates measured in physics, grasps each from starts across twice the goal
#: region (the settling study's box: the funnel the planner's estimate needs), and how far
#: apart [m] the centres of two with the same preshape must be (chosen: about 2 minutes on
#: two cores; a mug's rim and handle give distinct candidates, and a plate is tried with both
#: preshapes). With 30 grasps a share's standard error is at most 9 points; with 12 it was
#: 14, and a tin can's 1 cm-deep envelope ranked first at 12 of 12 though it holds from 22 of
#: 30 starts within 8 mm, its 3 cm-deep one from all 30 (docs/objects.md).
RANKED_CANDIDATES = 8
RANKED_ENVELOPES = 6
RANKING_GRASPS = 30
CANDIDATE_SPACING_M = 0.02
#: The goal grasp set: with the candidate that held most, the others that held at least
#: SET_MIN_HELD of their ranking grasps and within SET_MARGIN of it, in its placement (a
#: top-down pinch is the same grasp of the object turned with it; an envelope is placed for
#: its own face), at most MAX_GOAL_GRASPS (chosen: 3 of 4 ranking grasps, within 5 of 30 of
#: the best; the planner weighs each of them at every step).
SET_MIN_HELD = 0.75
SET_MARGIN = 0.17
MAX_GOAL_GRASPS = 4
#: The least share of its ranking grasps the best candidate must have held, or onboarding
#: asks for a goal grasp (chosen: half; a generated flared bowl's best rim pinch held 1 of 30,
#: and installed so it succeeded in none of 400 trials).
MIN_BEST_HELD = 0.5
#: Side envelope grasps: the hand comes level with the object's top, palm against a face,
#: finger 3 over the top and fingers 1 and 2 (spread π/2) closing round the face's width, as
#: the can's goal grasp (builtin/can/object.toml). Every paper side grasp approaches at world
#: heading 1.0 rad, where the WAM reaches them; the object is placed turned so that the
#: chosen face meets the hand there. Tilt down [rad]: the can's (a level side grasp of a low
#: object is out of reach). The hand's axis passes one of these depths [m] below the top of
#: the face (each a candidate of its own, while it stays in the object's upper half), and
#: fingers 1 and 2 close round what lies within ENVELOPE_BAND_M [m] below the top (chosen).
SIDE_APPROACH_YAW = 1.0
SIDE_PITCH = 0.15
ENVELOPE_DEPTHS_M = (0.01, 0.03)
ENVELOPE_BAND_M = 0.04
#: Two envelopes whose approaches differ by less than this [rad] come at the same face.
SAME_FACE_RAD = 0.1
#: Rim grasps from the side, as a hand holds a plate: the hand comes level, tilted down
#: SIDE_PITCH, at a thin rim that stands out over free space (a flange, a lip, a plate's
#: edge), finger 3 over it and fingers 1 and 2 (spread 0) under it. A rim is the object's
#: outermost band RIM_EDGE_BAND_M deep at a heading, at most RIM_MAX_THICKNESS_M thick, with
#: RIM_CLEARANCE_M free above and below it RIM_DEPTH_M in from its edge; the hand's axis
#: passes RIM_AXIS_ABOVE_M above its top at the edge. Chosen: a flared bowl's 2.5 mm rim held
#: in 2, 23 and 15 of 30 grasps from starts within 2 cm with the axis 0.5, 1 and 1.5 cm above
#: it (docs/objects.md); fingers 1 and 2 need about a finger's width under it. Tried at
#: RIM_HEADINGS headings round the object (one for an object the same at every heading), at
#: most RANKED_RIMS of them.
RIM_EDGE_BAND_M = 0.002
RIM_MAX_THICKNESS_M = 0.015
RIM_DEPTH_M = 0.01
RIM_CLEARANCE_M = 0.02
RIM_AXIS_ABOVE_M = 0.01
RIM_HEADINGS = 8
RANKED_RIMS = 4
#: The pinch generator's preshapes by spread [rad] (rrg_models.objects.surface_pairs).
PRESHAPES = {0.0: "finger 3 against fingers 1 and 2", float(np.pi / 2): "finger 1 against 2"}
#: Headings [rad] about the nominal at which the goal grasp must run, or the object gets
#: reorientation WRTs (as in tests of the paper objects).
HEADINGS = np.linspace(-1.2, 1.2, 9)


class OnboardError(ValueError):
    """Onboarding refused: what is wrong, and what to pass instead. Nothing was installed."""


@dataclass(frozen=True)
class GoalSpec:
    """A goal grasp as an object file holds it (rrg_models.objects.object_file)."""

    through_m: tuple[float, float, float]
    approach: str = "top_down"
    yaw_rad: float = 0.0
    pitch_rad: float = 0.0
    roll_rad: float = 0.0
    standoff_m: float = 0.0
    spread_rad: float = 0.0
    tol: tuple[float, float, float] = DEFAULT_TOL
    description: str = "given on the command line"
    #: the turn [rad] about z from the mesh as given to the object as placed on the table
    #: (the goal grasp is in the placed frame)
    placement_yaw_rad: float = 0.0
    #: the goal region's centre (Δx [m], Δy [m], Δθ [rad]; rrg_models.objects.GoalRegion)
    centre: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: the object's rotational symmetry [rad]: its goal region takes θ modulo it
    theta_period_rad: float = 2 * np.pi
    #: its name in the object file: "goal", or goal2, goal3, … for the set's others
    name: str = "goal"

    def with_symmetry(self, symmetry: Symmetry) -> GoalSpec:
        """This grasp's goal region for an object of that symmetry: θ ignored for a
        continuous one, taken modulo 2π/n for an n-fold one."""
        if symmetry.continuous:
            return replace(self, tol=(self.tol[0], self.tol[1], float("inf")))
        return replace(self, theta_period_rad=symmetry.theta_period_rad)

    def placed(self, yaw: float) -> GoalSpec | None:
        """This grasp of the object placed turned by ``yaw`` [rad] instead: a top-down pinch
        turns with the object; None for a side envelope placed otherwise (its approach
        heading is fixed, SIDE_APPROACH_YAW)."""
        turn = float(wrap_angle(yaw - self.placement_yaw_rad))
        if abs(turn) < 1e-9:
            return self
        if self.approach != "top_down":
            return None
        through = Rotation.from_euler("z", turn).apply(self.through_m)
        return replace(
            self,
            through_m=tuple(float(v) for v in through),
            yaw_rad=float(wrap_angle(self.yaw_rad + turn)),
            placement_yaw_rad=yaw,
        )


@dataclass
class AddOptions:
    """What ``rrg-object add`` was asked for."""

    mesh: Path
    name: str
    units: str = "m"
    up: str = "z"
    mass_kg: float | None = None
    friction: float = DEFAULT_FRICTION
    goal: GoalSpec | None = None
    #: the goal region of a proposed goal grasp (a given GoalSpec has its own); None: its
    #: tolerances are measured (FUNNEL_SCALES), for a given GoalSpec's too
    goal_tol: tuple[float, float, float] | None = None
    allow_size: bool = False
    settle_grasps: int = SETTLE_GRASPS
    ranking_grasps: int = RANKING_GRASPS
    reorient_runs: int = REORIENT_RUNS
    workers: int = 2
    seed: int = 0


@dataclass
class AddReport:
    """What onboarding chose and how long each stage took [s]."""

    folder: Path
    stage_s: dict[str, float] = field(default_factory=dict)
    choices: list[str] = field(default_factory=list)
    repair: MeshRepair | None = None  # what the mesh check repaired


def check_name(name: str) -> None:
    """OnboardError unless ``name`` is a valid name no installed object has."""
    if not NAME_PATTERN.fullmatch(name):
        raise OnboardError(
            f"invalid name {name!r}: use lower-case letters, digits and _, starting with a letter"
        )
    folders = object_folders()
    if name in folders:
        raise OnboardError(
            f"an object called {name!r} is already installed ({folders[name]}); choose another "
            "name, or remove it first (rrg-object remove)"
        )


def _yaw_of(pinch: Pinch) -> float:
    """The top_down_rotation yaw [rad] whose hand orientation is the pinch's."""
    x = pinch.rotation().as_matrix()[:, 0]
    return float(np.arctan2(x[1], x[0]))


def goal_candidates(
    parts: tuple[Primitive, ...],
    tol: tuple[float, float, float] = DEFAULT_TOL,
    symmetry: Symmetry | None = None,
) -> list[GoalSpec]:
    """The goal grasps to measure: up to RANKED_CANDIDATES top-down pinches,
    RANKED_ENVELOPES side envelopes (envelope_candidates) and RANKED_RIMS rim grasps
    (rim_candidates; headings as ``symmetry`` leaves distinct). The pinches are those the
    generator finds (largest faces first), with a free descent, reachable at the nominal
    pose, and distinct: centres CANDIDATE_SPACING_M apart, or another preshape (finger 3
    against fingers 1 and 2, or finger 1 against 2). OnboardError if there is none."""
    pinches = pinch_candidates(parts)
    rims = rim_candidates(parts, tol, symmetry)
    if not pinches and not rims:
        raise OnboardError(
            "too big for the hand: no two opposing, roughly vertical faces are close enough "
            "for the BarrettHand to pinch them, and no thin rim stands out to hold from the "
            "side; give a goal grasp (--goal-through ...)"
        )
    nominal = np.asarray(WORLD.nominal_pose)
    chosen: list[GoalSpec] = []
    for pinch in pinches:
        if len(chosen) == RANKED_CANDIDATES:
            break
        if any(
            g.spread_rad == pinch.spread
            and np.linalg.norm(np.subtract(g.through_m, pinch.centre)) < CANDIDATE_SPACING_M
            for g in chosen
        ):
            continue
        if top_down_poses(parts, pinch) is None:
            continue
        yaw = _yaw_of(pinch)
        wrt = line_grasp_wrt(parts, top_down_rotation(yaw), pinch.centre, spread=pinch.spread)
        if not wam.feasible_path(wrt.with_home(nominal)):
            continue
        c = pinch.centre
        chosen.append(
            GoalSpec(
                through_m=tuple(float(v) for v in c),
                yaw_rad=yaw,
                spread_rad=float(pinch.spread),
                tol=tol,
                description=f"from above, {PRESHAPES[float(pinch.spread)]} pinching "
                f"{pinch.separation * 100:.1f} cm across at ({c[0]:+.3f}, {c[1]:+.3f}, "
                f"{c[2]:.3f}) m",
            )
        )
    chosen += envelope_candidates(parts, pinches, tol)
    chosen += rims
    if not chosen:
        raise OnboardError(
            f"none of the {len(pinches)} top-down pinches and side envelopes is free and "
            "reachable by the WAM at the nominal pose; give a goal grasp (--goal-through ...)"
        )
    return chosen


def envelope_candidates(
    parts: tuple[Primitive, ...], pinches: list[Pinch], tol: tuple[float, float, float]
) -> list[GoalSpec]:
    """Up to RANKED_ENVELOPES side envelopes (see SIDE_APPROACH_YAW): the palm comes against
    one of a pinch's faces, along the pinch axis, at each of ENVELOPE_DEPTHS_M below its top
    that stays in the object's upper half, and fingers 1 and 2 close round what lies within
    ENVELOPE_BAND_M of the face's top, if it fits between them. Each places the object turned
    so that the face meets the hand at SIDE_APPROACH_YAW; reachable, with a free start, and
    distinct: another face direction, another depth, or centres CANDIDATE_SPACING_M apart."""
    gap = finger_gap(np.pi / 2) - 2 * MIN_FINGER_CLEARANCE
    vertices = np.vstack([p.mesh().vertices for p in parts])
    bottom = float(vertices[:, 2].min())
    chosen: list[GoalSpec] = []
    for pinch in pinches:
        for approach, depth in itertools.product((pinch.axis, -pinch.axis), ENVELOPE_DEPTHS_M):
            if len(chosen) == RANKED_ENVELOPES:
                return chosen
            top = pinch.centre[2]
            if top - depth < (top + bottom) / 2:
                continue
            across = np.array([-approach[1], approach[0], 0.0])
            band = vertices[
                (vertices[:, 2] >= top - ENVELOPE_BAND_M)
                & (np.abs((vertices - pinch.centre) @ approach) <= ENVELOPE_BAND_M)
            ]
            lateral = band @ across
            width = float(np.ptp(lateral)) if len(band) else np.inf
            if width > gap:
                continue
            shift = (lateral.max() + lateral.min()) / 2 - pinch.centre @ across
            through = pinch.centre + shift * across
            through[2] = top - depth
            placement = float(wrap_angle(SIDE_APPROACH_YAW - np.arctan2(approach[1], approach[0])))
            placed = Rotation.from_euler("z", placement).apply(through)
            if any(
                np.cos(g.placement_yaw_rad - placement) > np.cos(SAME_FACE_RAD)
                and abs(g.through_m[2] - placed[2]) < 1e-6
                and np.linalg.norm(np.subtract(g.through_m, placed)) < CANDIDATE_SPACING_M
                for g in chosen
            ):
                continue
            spec = _side_grasp(
                parts,
                placement,
                placed,
                float(np.pi / 2),
                tol,
                f"from the side along ({approach[0]:+.2f}, {approach[1]:+.2f}) of the mesh, "
                f"{depth * 100:.0f} cm below the top, through ({through[0]:+.3f}, "
                f"{through[1]:+.3f}, {through[2]:.3f}) m, finger 3 over the top, fingers 1 "
                f"and 2 round {width * 100:.1f} cm",
            )
            if spec is not None:
                chosen.append(spec)
    return chosen


def _side_grasp(
    parts: tuple[Primitive, ...],
    placement: float,
    through: np.ndarray,
    spread: float,
    tol: tuple[float, float, float],
    description: str,
) -> GoalSpec | None:
    """A grasp from the side (SIDE_APPROACH_YAW, tilted down SIDE_PITCH, finger 3 up) through
    ``through`` [m] of the object placed turned by ``placement`` [rad]; None unless its start
    is clear and the WAM reaches it at the nominal pose."""
    rotation = side_rotation(pitch=SIDE_PITCH, roll=np.pi / 2, yaw=SIDE_APPROACH_YAW)
    try:
        wrt = line_grasp_wrt(turn_about_z(parts, placement), rotation, through, spread=spread)
    except ValueError:  # the start is not clear of the object or the table
        return None
    if not wam.feasible_path(wrt.with_home(np.asarray(WORLD.nominal_pose))):
        return None
    return GoalSpec(
        through_m=tuple(float(v) for v in through),
        approach="side",
        yaw_rad=SIDE_APPROACH_YAW,
        pitch_rad=SIDE_PITCH,
        roll_rad=float(np.pi / 2),
        spread_rad=spread,
        tol=tol,
        placement_yaw_rad=placement,
        description=description,
    )


def rim_candidates(
    parts: tuple[Primitive, ...],
    tol: tuple[float, float, float],
    symmetry: Symmetry | None = None,
) -> list[GoalSpec]:
    """Up to RANKED_RIMS rim grasps from the side (see RIM_EDGE_BAND_M): at each of
    RIM_HEADINGS headings round the object (within one turn of its symmetry; one heading when
    it is the same at every heading), where its outermost band is a thin rim over free space.
    Each places the object turned so that the rim meets the hand at SIDE_APPROACH_YAW;
    reachable, with a free start."""
    if symmetry is not None and symmetry.continuous:
        headings = np.zeros(1)
    else:
        turn = 2 * np.pi if symmetry is None else symmetry.theta_period_rad
        headings = np.arange(RIM_HEADINGS) * 2 * np.pi / RIM_HEADINGS
        headings = headings[headings < turn - 1e-9]
    vertices = np.vstack([p.mesh().vertices for p in parts])
    chosen: list[GoalSpec] = []
    for heading in headings:
        if len(chosen) == RANKED_RIMS:
            break
        out = np.array([np.cos(heading), np.sin(heading), 0.0])
        reach = vertices @ out
        edge = reach.max()
        band = vertices[reach >= edge - RIM_EDGE_BAND_M]
        top, bottom = float(band[:, 2].max()), float(band[:, 2].min())
        if top - bottom > RIM_MAX_THICKNESS_M:
            continue
        left = np.array([-out[1], out[0], 0.0])
        foot = edge * out + float(np.mean(band @ left)) * left  # the rim's edge, at z = 0
        inside = foot - RIM_DEPTH_M * out
        probes = [inside + (0, 0, top + RIM_CLEARANCE_M), inside + (0, 0, bottom - RIM_CLEARANCE_M)]
        if bottom - RIM_CLEARANCE_M < vertices[:, 2].min() or np.any(
            signed_distance(parts, probes) <= 0.0
        ):
            continue
        through = foot + (0.0, 0.0, top + RIM_AXIS_ABOVE_M)
        placement = float(wrap_angle(SIDE_APPROACH_YAW - (heading + np.pi)))
        placed = Rotation.from_euler("z", placement).apply(through)
        spec = _side_grasp(
            parts,
            placement,
            placed,
            0.0,
            tol,
            f"from the side at the rim along ({-out[0]:+.2f}, {-out[1]:+.2f}) of the mesh, "
            f"{(top - bottom) * 1000:.1f} mm thick at {top * 100:.1f} cm, finger 3 over it and "
            "fingers 1 and 2 under it",
        )
        if spec is not None:
            chosen.append(spec)
    return chosen


def _score_job(args: tuple[str, int, int]) -> float:
    """The share of a candidate's goal grasps that made their fingers and held (physics)."""
    from rrg_sim.physics import settle

    name, grasps, seed = args
    records = settle.measure(name, grasps, seed)
    return sum(r["held"] for r in records) / grasps


def _toml(value) -> str:
    """A TOML value (floats round-trip exactly)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float, np.floating)):
        v = float(value)
        return "inf" if v == np.inf else repr(v)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    return "[" + ", ".join(_toml(v) for v in value) + "]"


def object_file_text(
    name: str,
    mesh: trimesh.Trimesh,
    part_files: list[str],
    mass_kg: float,
    friction: float,
    goal: GoalSpec,
    source: str,
    reorientation: bool,
    more_goals: tuple[GoalSpec, ...] = (),
) -> str:
    """The ``object.toml`` of an onboarded mesh object: its goal grasp ``goal`` and, as
    ``[[goal_grasps]]``, the others of its set."""
    lines = [
        f"# Onboarded by rrg-object add from {source}.",
        "",
        f"name = {_toml(name)}",
        f"description = {_toml(f'{name}; goal: {goal.description}')}",
        f"source = {_toml(source)}",
        f"mass_kg = {_toml(mass_kg)}",
        f"friction = {_toml(friction)}",
        f"placement_yaw_rad = {_toml(goal.placement_yaw_rad)}",
        "track_settling = true",
        "",
        "[dimensions_m]",
        *(f"size_{axis} = {_toml(v)}" for axis, v in zip("xyz", mesh.extents)),
        "",
        "[goal_region]",
        f"tol = {_toml(goal.tol)}  # |dx| [m], |dy| [m], |dθ| [rad] (inf: θ ignored)",
        f"centre = {_toml(goal.centre)}  # where the grasp leaves it: Δx, Δy [m], Δθ [rad]",
        "min_fingers = 3",
        *(
            [f"theta_period_rad = {_toml(goal.theta_period_rad)}  # its rotational symmetry"]
            if goal.theta_period_rad != 2 * np.pi
            else []
        ),
        "",
        "[goal_grasp]",
        *_grasp_lines(goal),
    ]
    for more in more_goals:
        lines += [
            "",
            "[[goal_grasps]]",
            f"name = {_toml(more.name)}",
            *_grasp_lines(more),
            f"centre = {_toml(more.centre)}  # where the grasp leaves it: Δx, Δy [m], Δθ [rad]",
            *([f"tol = {_toml(more.tol)}  # its own region"] if more.tol != goal.tol else []),
        ]
    if reorientation:
        lines += ["", "[reorientation]  # no goal grasp can run at every heading"]
    for k, path in enumerate(part_files):
        lines += [
            "",
            "[[parts]]",
            f'name = "part {k + 1}"',
            'kind = "mesh"',
            f"file = {_toml(path)}",
        ]
    return "\n".join(lines) + "\n"


def _grasp_lines(goal: GoalSpec) -> list[str]:
    """A goal grasp's keys in an object file."""
    return [
        f"approach = {_toml(goal.approach)}",
        f"yaw_rad = {_toml(goal.yaw_rad)}",
        f"pitch_rad = {_toml(goal.pitch_rad)}",
        f"roll_rad = {_toml(goal.roll_rad)}",
        f"through_m = {_toml(goal.through_m)}",
        f"standoff_m = {_toml(goal.standoff_m)}",
        f"spread_rad = {_toml(goal.spread_rad)}",
        f"description = {_toml(goal.description)}",
    ]


@contextmanager
def _searched_first(folder: Path) -> Iterator[None]:
    """Every object lookup (here and in forked workers) sees ``folder``'s objects first."""
    old = os.environ.get(USER_DIR_ENV)
    rest = old if old else str(user_objects_dir())
    os.environ[USER_DIR_ENV] = os.pathsep.join([str(folder), rest])
    try:
        yield
    finally:
        if old is None:
            del os.environ[USER_DIR_ENV]
        else:
            os.environ[USER_DIR_ENV] = old


def add_object(opts: AddOptions, say: Callable[[str], None] = print) -> AddReport:
    """Onboard ``opts.mesh`` as the user object ``opts.name`` (see the module doc)."""
    check_name(opts.name)
    counts = ("settle_grasps", "ranking_grasps", "reorient_runs", "workers")
    for count in counts:
        if getattr(opts, count) < 1:
            flag = count.replace("_", "-")
            raise OnboardError(f"--{flag} must be at least 1, got {getattr(opts, count)}")
    user = user_objects_dir()
    user.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".rrg-staging-{opts.name}-", dir=user.parent))
    folder = staging / opts.name
    (folder / "collision").mkdir(parents=True)
    report = AddReport(user / opts.name)

    @contextmanager
    def stage(name: str) -> Iterator[None]:
        say(f"[{name}]")
        t0 = time.perf_counter()
        yield
        report.stage_s[name] = time.perf_counter() - t0
        say(f"[{name}] done in {report.stage_s[name]:.1f} s")

    def choose(text: str) -> None:
        report.choices.append(text)
        say(f"  {text}")

    try:
        with stage("mesh"):
            raw = import_mesh(opts.mesh, opts.units, opts.up)
            checked, repair = check_mesh(raw, allow_size=opts.allow_size)
            report.repair = repair
            choose(f"mesh {repair.describe()}")
            mesh = stand_on_table(checked)
            mesh.export(folder / "mesh.stl")
            choose(
                f"{len(mesh.faces)} faces, {mesh.extents[0] * 100:.1f} x "
                f"{mesh.extents[1] * 100:.1f} x {mesh.extents[2] * 100:.1f} cm, "
                f"{mesh.volume * 1e6:.0f} cm³, standing on its footprint"
            )
            symmetry = rotational_symmetry(mesh, seed=opts.seed)
            choose(symmetry.describe())
        with stage("decompose"):
            part_files = []
            convex = convex_parts(mesh, seed=opts.seed)
            for k, vertices in enumerate(convex):
                path = f"collision/part_{k + 1:02d}.stl"
                trimesh.convex.convex_hull(vertices).export(folder / path)
                part_files.append(path)
            choose(
                f"{len(part_files)} convex parts (CoACD), enclosing "
                f"{max(hull_excess(mesh, convex), 0.0):.0%} more than the mesh"
            )
        parts = tuple(
            Primitive("mesh", (), vertices=trimesh.load_mesh(folder / p).vertices)
            for p in part_files
        )
        mass = opts.mass_kg if opts.mass_kg is not None else DEFAULT_DENSITY * mesh.volume
        if opts.mass_kg is None:
            choose(f"mass {mass:.3f} kg: its volume at {DEFAULT_DENSITY:.0f} kg/m³ (--mass)")
        source = f"mesh {Path(opts.mesh).name} ({opts.units}, {opts.up} up)"
        with stage("goal grasp"):
            if opts.goal is None:
                args = (staging, folder, opts, mesh, part_files, mass, source)
                goals = _goal_set(parts, symmetry, args, choose)
            else:
                goals = (opts.goal.with_symmetry(symmetry),)
                choose(f"the given goal grasp through {goals[0].through_m}")
        with stage("object file"):
            args = (folder, opts, mesh, part_files, mass, goals, source)
            reorient = _write_object(*args, symmetry, choose)

        def rewrite(goals: tuple[GoalSpec, ...], reorientation: bool) -> None:
            first, *more = goals
            args = (folder, opts, mesh, part_files, mass, first, source)
            _write_and_load(*args, reorientation, tuple(more))

        with _searched_first(staging):
            _measure_and_build(opts, goals, reorient, rewrite, stage, choose)
        os.replace(folder, report.folder)
        say(f"installed {opts.name} in {report.folder}")
        return report
    except (MeshError, ObjectFileError) as exc:
        raise OnboardError(str(exc)) from exc
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def _goal_set(
    parts, symmetry: Symmetry, rank_args: tuple, choose: Callable[[str], None]
) -> tuple[GoalSpec, ...]:
    """The proposed goal grasps (_rank's arguments but the candidates: ``rank_args``), their
    regions as the object's symmetry allows: the one that held the object most often in
    physics from starts across its funnel, of those within one ranking grasp of it the one
    the WAM reaches at the most of the prior's headings (_reach), named "goal", and the
    others of its set (_set_members); OnboardError when the best held in less than
    MIN_BEST_HELD of its ranking grasps."""
    opts = rank_args[2]
    tol = DEFAULT_TOL if opts.goal_tol is None else opts.goal_tol
    candidates = [g.with_symmetry(symmetry) for g in goal_candidates(parts, tol, symmetry)]
    scores = _rank(*rank_args, candidates)
    headings = _prior_headings(symmetry)
    reach = [_reach(g, parts, headings) for g in candidates]
    for goal, score, r in zip(candidates, scores, reach):
        choose(
            f"{score:4.0%} held of {opts.ranking_grasps}, reached at {r} of {len(headings)} "
            f"headings: {goal.description}"
        )
    if max(scores) < MIN_BEST_HELD:
        raise OnboardError(
            f"none of the {len(candidates)} proposed goal grasps held the object in "
            f"physics in {MIN_BEST_HELD:.0%} of its {opts.ranking_grasps} grasps (the best: "
            f"{max(scores):.0%}); give a goal grasp (--goal-through ...)"
        )
    near_best = [k for k, v in enumerate(scores) if v >= max(scores) - 1 / opts.ranking_grasps]
    best = max(near_best, key=lambda k: (reach[k], scores[k], -k))
    goal = candidates[best]
    choose(f"chose the goal grasp that held most and reaches widest: {goal.description}")
    if symmetry.continuous:
        choose("one goal grasp: the object is the same at every heading, so every other is it")
        return (goal,)
    members = _set_members(goal, scores[best], candidates, scores, parts)
    if not members:
        choose(
            f"one goal grasp: no other held in {SET_MIN_HELD:.0%} of its grasps and within "
            f"{SET_MARGIN:.0%} of it in its placement"
        )
    for more in members:
        choose(f"with {more.name}: {more.description}")
    return (goal, *members)


def _prior_headings(symmetry: Symmetry) -> np.ndarray:
    """The HEADINGS [rad] about the nominal that the object's symmetry leaves distinct
    (within half its turn); only the nominal for an object the same at every heading."""
    if symmetry.continuous:
        return np.zeros(1)
    return HEADINGS[np.abs(HEADINGS) <= symmetry.theta_period_rad / 2 + 1e-9]


def _reached(wrt, headings: np.ndarray) -> np.ndarray:
    """(len(headings),) bool: whether the WAM reaches ``wrt`` with the object at the nominal
    pose turned by each of ``headings`` [rad]."""
    nominal = np.asarray(WORLD.nominal_pose)
    return np.array([bool(wam.feasible_path(wrt.with_home(nominal + (0, 0, t)))) for t in headings])


def _reach(spec: GoalSpec, parts, headings: np.ndarray) -> int:
    """At how many of ``headings`` [rad] about the nominal the WAM reaches ``spec``."""
    return int(_reached(_spec_wrt(spec, parts), headings).sum())


def _set_members(
    goal: GoalSpec, held: float, candidates: list[GoalSpec], scores: list[float], parts
) -> list[GoalSpec]:
    """The other goal grasps of ``goal``'s set (see SET_MIN_HELD): in its placement, reachable
    there at the nominal pose, best held first, named goal2, goal3, …"""
    floor = max(SET_MIN_HELD, held - SET_MARGIN)
    nominal = np.asarray(WORLD.nominal_pose)
    members: list[GoalSpec] = []
    for k in sorted(range(len(scores)), key=lambda k: -scores[k]):  # ties: the candidates' order
        other = candidates[k].placed(goal.placement_yaw_rad)
        if other is None or other == goal or scores[k] < floor:
            continue
        if len(members) == MAX_GOAL_GRASPS - 1:
            break
        if other is not candidates[k]:  # turned with the object: is it still reachable?
            if not wam.feasible_path(_spec_wrt(other, parts).with_home(nominal)):
                continue
        members.append(replace(other, name=f"goal{len(members) + 2}"))
    return members


def _spec_wrt(spec: GoalSpec, parts):
    """The goal WRT of ``spec`` on ``parts`` (in the mesh's frame), placed as it says."""
    return goal_grasp_wrt(
        turn_about_z(parts, spec.placement_yaw_rad),
        spec.approach,
        spec.through_m,
        (spec.yaw_rad, spec.pitch_rad, spec.roll_rad),
        spread_rad=spec.spread_rad,
        standoff_m=spec.standoff_m,
    )


def _write_object(
    folder, opts, mesh, part_files, mass, goals, source, symmetry: Symmetry, choose
) -> bool:
    """Place the object for its goal grasps and write its object file, with reorientation
    WRTs when no goal grasp can run at every heading its symmetry leaves distinct and a
    top-down pinch can turn it (returned); OnboardError when the WAM cannot reach the goal
    grasp at the nominal pose."""
    goal, *more = goals
    place(folder, ["mesh.stl", *part_files], goal.placement_yaw_rad)
    if goal.placement_yaw_rad:
        choose(f"placed turned by {goal.placement_yaw_rad:+.2f} rad for the goal grasp")
    args = (folder, opts, mesh, part_files, mass, goal, source)
    obj = _write_and_load(*args, False, tuple(more))
    nominal = np.asarray(WORLD.nominal_pose)
    if not wam.feasible_path(obj.goal_wrt.with_home(nominal)):
        raise OnboardError(
            "the WAM cannot reach the goal grasp at the nominal pose "
            f"{WORLD.nominal_pose}; give another (--goal-through, --goal-yaw, ...)"
        )
    reorient = _needs_reorientation(obj, symmetry, choose)
    if reorient:
        obj = _write_and_load(*args, True, tuple(more))
    choose(f"{len(obj.wrts())} WRTs: " + ", ".join(w.name for w in obj.wrts()))
    return reorient


def _needs_reorientation(obj, symmetry: Symmetry, choose: Callable[[str], None]) -> bool:
    """Whether the object gets reorientation WRTs, with the reason said either way: not for
    an object the same at every heading, nor when no top-down pinch is free to turn it; yes
    when at some of HEADINGS (within half the symmetry's turn) no goal grasp can run."""
    if symmetry.continuous:
        choose(
            "no reorientation WRTs: turned about its vertical axis the object is the same "
            "object, so the goal grasp runs at the heading the WAM reaches"
        )
        return False
    headings = _prior_headings(symmetry)
    reached = np.any([_reached(g.wrt, headings) for g in obj.goal_grasps], axis=0)
    grasp = "the goal grasp" if len(obj.goal_grasps) == 1 else "one of the goal grasps"
    if all(reached):
        choose(
            f"no reorientation WRTs: the WAM reaches {grasp} at every heading from "
            f"{headings[0]:+.1f} to {headings[-1]:+.1f} rad"
        )
        return False
    where = ", ".join(f"{t:+.1f}" for t, ok in zip(headings, reached) if ok)
    try:
        reorient_wrts(obj.parts)
    except ValueError:
        choose(
            "no reorientation WRTs: the goal grasp cannot run at every heading, but no "
            "top-down pinch of the object is free of collisions to turn it with; the goal "
            f"grasp runs only at the headings the WAM reaches ({where} rad)"
        )
        return False
    choose(
        f"reorientation WRTs: the WAM reaches {grasp} only at headings {where} rad of "
        f"{', '.join(f'{t:+.1f}' for t in headings)}"
    )
    return True


def _rank(staging, folder, opts, mesh, part_files, mass, source, candidates) -> list[float]:
    """Each candidate's share of held grasps in physics: each staged as an object of its own
    (the object's collision files, that goal grasp), measured in parallel."""
    names = []
    for k, goal in enumerate(candidates):
        name = f"{opts.name}_candidate{k + 1}"
        shutil.copytree(folder / "collision", staging / name / "collision")
        place(staging / name, part_files, goal.placement_yaw_rad)
        _write_and_load(
            staging / name, replace(opts, name=name), mesh, part_files, mass, goal, source, False
        )
        names.append(name)
    jobs = [(name, opts.ranking_grasps, opts.seed) for name in names]
    try:
        with _searched_first(staging):
            return list(fork_map(_score_job, jobs, opts.workers))
    finally:
        for name in names:
            shutil.rmtree(staging / name, ignore_errors=True)


def funnel_scale(region: GoalRegion, settling: Settling) -> float:
    """The largest of FUNNEL_SCALES by which ``region``'s tolerances (about the study's
    intercept) may grow while at least FUNNEL_MIN_HELD of the study's grasps that closed in it
    held, scanned outwards: a multiple with fewer than FUNNEL_MIN_SAMPLES grasps in it is
    passed over, and the first that falls short ends the scan; 1 when none qualifies."""
    b = settling.closed.b
    centre = (float(b[0]), float(b[1]), 0.0 if region.ignores_theta else float(b[2]))
    closed, held = settling.samples["closed"], settling.held
    best = FUNNEL_SCALES[0]
    for scale in FUNNEL_SCALES:
        inside = replace(region, tol=_scaled_tol(region.tol, scale), centre=centre).contains(closed)
        if inside.sum() < FUNNEL_MIN_SAMPLES:
            continue
        if held[inside].mean() < FUNNEL_MIN_HELD:
            break
        best = scale
    return best


def _scaled_tol(tol: tuple[float, float, float], scale: float) -> tuple[float, float, float]:
    """``tol`` × ``scale`` (an ignored θ stays ignored)."""
    return (tol[0] * scale, tol[1] * scale, tol[2] * scale)


def _scaled(goal: GoalSpec, scale: float) -> GoalSpec:
    """``goal`` with its region's tolerances ``scale`` × DEFAULT_TOL (θ still ignored if it
    was)."""
    theta = goal.tol[2] if np.isinf(goal.tol[2]) else DEFAULT_TOL[2]
    return replace(goal, tol=_scaled_tol((DEFAULT_TOL[0], DEFAULT_TOL[1], theta), scale))


def _measured_region(
    opts: AddOptions,
    goals: tuple[GoalSpec, ...],
    rewrite: Callable[[tuple[GoalSpec, ...]], None],
    choose: Callable[[str], None],
) -> tuple[tuple[GoalSpec, ...], set[str]]:
    """``goals`` with each goal region's tolerances measured (FUNNEL_SCALES) in its grasp's
    settling study across twice the widest region, and the names of those whose region is
    the widest: that study is their settling study."""
    from rrg_models.objects import get_object
    from rrg_sim.physics import settle

    rewrite(tuple(_scaled(g, FUNNEL_SCALES[-1]) for g in goals))
    grasps = FUNNEL_GRASPS_FACTOR * opts.settle_grasps
    measured, widest = [], set()
    names = tuple(goal.name for goal in goals)
    unfitted = settle.goal_studies(opts.name, names, grasps, opts.seed, opts.workers)
    obj = get_object(opts.name)
    for goal in goals:
        if goal.name in unfitted:  # too few of its grasps arrived to fit
            measured.append(_scaled(goal, 1.0))
            choose(f"{goal.name} region: the default, not measured ({unfitted[goal.name]})")
            continue
        region = replace(obj.goal_region(goal.name), tol=_scaled(goal, 1.0).tol)
        scale = funnel_scale(region, obj.settling_for(goal.name))
        measured.append(_scaled(goal, scale))
        if scale == FUNNEL_SCALES[-1]:
            widest.add(goal.name)
        tol = measured[-1].tol
        theta = "" if np.isinf(tol[2]) else f" and {np.degrees(tol[2]):.0f}°"
        choose(
            f"{goal.name} region ±{tol[0] * 100:.1f} cm{theta}: {scale:g} × the default, the "
            f"widest of {', '.join(f'{s:g}' for s in FUNNEL_SCALES)} × in which "
            f"{FUNNEL_MIN_HELD:.0%} of its {grasps} study grasps that closed there held "
            "(--goal-tol sets it)"
        )
    goals = tuple(measured)
    rewrite(goals)
    return goals, widest


def _held_share(obj, goal: str, profile: str) -> str:
    """How many of the settling study's arrived grasps of ``goal`` held, in ``profile``."""
    held = obj.settling_for(goal, profile).held
    return f"{int(held.sum())} of {held.size} grasps that arrived held"


def place(folder: Path, files: list[str], yaw: float) -> None:
    """Turn the mesh files in ``folder`` by ``yaw`` [rad] about z: the object as placed."""
    if yaw == 0.0:
        return
    turn = trimesh.transformations.rotation_matrix(yaw, (0.0, 0.0, 1.0))
    for path in files:
        trimesh.load_mesh(folder / path).apply_transform(turn).export(folder / path)


def _write_and_load(
    folder, opts, mesh, part_files, mass, goal, source, reorientation, more_goals=()
):
    (folder / OBJECT_FILE).write_text(
        object_file_text(
            opts.name,
            mesh,
            part_files,
            mass,
            opts.friction,
            goal,
            source,
            reorientation,
            more_goals,
        )
    )
    return load_object_folder(folder)


def _measure_and_build(
    opts: AddOptions,
    goals: tuple[GoalSpec, ...],
    reorient: bool,
    rewrite: Callable[[tuple[GoalSpec, ...], bool], None],
    stage,
    choose: Callable[[str], None],
) -> None:
    """The physics studies, the tables and the picture of the staged object.

    Each goal grasp's region is centred where it leaves the object from a perfect start (its
    settling study's intercept): a grasp that pulls the object into the hand meets its
    region about there, not where the estimate put the object. Reorientation WRTs that turn
    the object fully too rarely to fit are dropped: the goal grasp then runs only at the
    headings the WAM reaches."""
    from rrg_models.objects import get_object
    from rrg_planner.planning_model import PlanningModel
    from rrg_sim.physics import reorient_study, settle
    from rrg_sim.physics.render import render_goal_grasps

    with stage("settling study"):
        studied: set[str] = set()  # the goal grasps whose region's study is already made
        if opts.goal_tol is None:
            goals, studied = _measured_region(opts, goals, lambda g: rewrite(g, reorient), choose)
        todo = tuple(goal.name for goal in goals if goal.name not in studied)
        unfitted = settle.goal_studies(opts.name, todo, opts.settle_grasps, opts.seed, opts.workers)
        if unfitted:
            raise OnboardError("; ".join(unfitted.values()))
        centred = []
        for goal in goals:
            b = get_object(opts.name).settling_for(goal.name).closed.b
            theta = 0.0 if np.isinf(goal.tol[2]) else round(float(b[2]), 4)
            centre = (round(float(b[0]), 4), round(float(b[1]), 4), theta)
            centred.append(replace(goal, centre=centre))
            choose(
                f"{goal.name} region centred where the grasp leaves the object from a perfect "
                f"start: Δ = ({centre[0] * 100:+.1f} cm, {centre[1] * 100:+.1f} cm, "
                f"{np.degrees(centre[2]):+.1f}°)"
            )
        goals = tuple(centred)
        rewrite(goals, reorient)
    with stage("realistic settling study"):
        names = tuple(goal.name for goal in goals)
        unfitted = settle.goal_studies(
            opts.name, names, opts.settle_grasps, opts.seed, opts.workers, "realistic"
        )
        obj = get_object(opts.name)
        for goal in names:
            if goal in unfitted:
                choose(f"no realistic study of {goal} ({unfitted[goal]}): the nominal one serves")
                continue
            choose(
                f"{goal} in the realistic world: {_held_share(obj, goal, 'realistic')} "
                f"(nominal: {_held_share(obj, goal, 'nominal')}); the planner predicts "
                "holds from it there"
            )
    if reorient:
        with stage("reorientation study"):
            try:
                reorient_study.study([opts.name], opts.reorient_runs, opts.seed, opts.workers)
            except reorient_study.TooFewTurns as exc:
                rewrite(goals, False)
                choose(
                    f"no reorientation WRTs: {exc}; the goal grasp runs only at headings "
                    "the WAM reaches"
                )
    with stage("tables"):
        PlanningModel(opts.name, workers=opts.workers, progress=True)
    with stage("picture"):
        folder = object_folders()[opts.name]
        render_goal_grasps(folder, (opts.name,))
        (folder / f"goal_{opts.name}.png").rename(folder / "goal.png")
