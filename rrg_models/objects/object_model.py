"""An object of the catalogue: collision primitives, physical properties, goal region and WRTs."""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path

import numpy as np
import trimesh

from rrg_models.config import SETTLING_KERNEL_BANDWIDTH
from rrg_models.goal import GoalRegion, Settling, load_settling
from rrg_models.objects.composites import turn_about_z
from rrg_models.objects.primitives import Primitive, union_bounds
from rrg_models.objects.wrt_generation import goal_probe_wrt, info_wrts, sweep_wrt
from rrg_models.wrt import WRT, ReorientOutcome, table_touch_wrt

#: An object folder's planned table touch (rrg_sim.table_touch writes it).
TABLE_TOUCH_FILE = "table_touch.json"

#: An object folder's measured grasp-settling fit (rrg_sim.physics.settle writes it).
SETTLING_FILE = "settling.json"


def settling_file(profile: str = "nominal", goal: str = "goal") -> str:
    """The file of the settling study of goal grasp ``goal`` measured in world ``profile``:
    the goal grasp "goal"'s is SETTLING_FILE in the nominal world, settling.<profile>.json in
    another (e.g. settling.realistic.json); another goal grasp's is prefixed with its name
    (goal2.settling.json)."""
    name = SETTLING_FILE if profile == "nominal" else f"settling.{profile}.json"
    return name if goal == "goal" else f"{goal}.{name}"


#: An object folder's measured reorientation outcomes (rrg_sim.physics.reorient_study).
REORIENTATION_FILE = "reorientation.json"
#: Half-width [rad] of the θ range of start offsets the settling study samples, at most
#: (chosen: the low level's 3σ of 9° and then some).
SETTLING_THETA_BOX = 0.25


def measured_reorientation(wrts: tuple[WRT, ...], path: Path | None) -> tuple[WRT, ...]:
    """The reorientation WRTs with the outcomes measured in ``path`` for them
    (WRT.reorient_outcome); unmeasured ones unchanged."""
    fits = json.loads(path.read_text()) if path is not None and path.exists() else {}
    return tuple(
        replace(
            w,
            reorient_outcome=ReorientOutcome(
                *(np.array(fits[w.name][k]) for k in ("box", "shift", "sigma"))
            ),
        )
        if w.name in fits
        else w
        for w in wrts
    )


@dataclass(frozen=True)
class GoalGrasp:
    """One of an object's goal grasps: its WRT (kind "goal") and its goal region (the
    object's tolerances about the grasp's own centre)."""

    wrt: WRT
    region: GoalRegion

    @property
    def name(self) -> str:
        return self.wrt.name


@dataclass(frozen=True, eq=False)
class ObjectModel:
    """One object of the catalogue (object frame: origin at the centre of the part resting on
    the table, z up, resting on z = 0).

    parts: collision primitives (shared by the geometric and the MuJoCo simulators).
    mass [kg]; friction: sliding friction coefficient.
    dimensions: documented sizes [m]; ``size_x``, ``size_y``, ``size_z`` are the bounding-box
    extents, other keys name features (e.g. a handle's opening). source: where they come from.
    goal / goal_wrt: the goal region and the goal WRT of the goal grasp "goal".
    more_goals: the object's other goal grasps (``goal_grasps`` lists them all): the planner
    runs whichever has the highest P(goal) under its belief, and the judge judges the one
    that ran against its own region.
    reorient_wrts: reorientation WRTs (empty when the goal grasp stays feasible at any θ).
    designed_info_wrts: hand-designed information-gathering WRTs, added to the generated ones
    (the paper's WRTs were mostly demonstrated by hand).
    symmetric: the goal region ignores θ.
    placement_yaw: the parts are the object built in its canonical frame (where the
    documented sizes are the bounding box) turned by this yaw [rad] about z, so that its goal
    grasp is reachable at the nominal pose.
    folder: the object's folder (rrg_models.objects.object_file), where its measured studies
    live (SETTLING_FILE, REORIENTATION_FILE); None: an object built in code, never measured.
    """

    name: str
    parts: tuple[Primitive, ...]
    mass: float
    friction: float
    dimensions: dict[str, float]
    source: str
    goal: GoalRegion
    goal_wrt: WRT
    more_goals: tuple[GoalGrasp, ...] = ()
    reorient_wrts: tuple[WRT, ...] = ()
    designed_info_wrts: tuple[WRT, ...] = ()
    symmetric: bool = False
    placement_yaw: float = 0.0
    #: whether the belief applies the measured settling of the goal grasp (see ``settling``)
    track_settling: bool = True
    description: str = field(default="", repr=False)
    folder: Path | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self.symmetric != self.goal.ignores_theta:
            raise ValueError(f"{self.name}: symmetric must match a goal region that ignores θ")
        for grasp in self.goal_grasps:
            if grasp.wrt.kind != "goal":
                raise ValueError(f"{self.name}: goal grasp {grasp.name!r} is not of kind goal")
            if grasp.region.ignores_theta != self.goal.ignores_theta:
                raise ValueError(f"{self.name}: every goal region must ignore θ, or none")
            for rc in grasp.region.required_contacts:
                if max(rc.parts) >= len(self.parts) or min(rc.parts) < 0:
                    raise ValueError(
                        f"{self.name}: required contact {rc.name!r} names a missing part"
                    )

    @cached_property
    def goal_grasps(self) -> tuple[GoalGrasp, ...]:
        """Every goal grasp: "goal" first, then ``more_goals``."""
        return (GoalGrasp(self.goal_wrt, self.goal), *self.more_goals)

    def goal_region(self, goal: str = "goal") -> GoalRegion:
        """The goal region of the goal grasp called ``goal`` (KeyError if it has none)."""
        for grasp in self.goal_grasps:
            if grasp.name == goal:
                return grasp.region
        names = [g.name for g in self.goal_grasps]
        raise KeyError(f"{self.name} has no goal grasp {goal!r}; valid: {names}")

    def bounds(self) -> np.ndarray:
        """(2,3) axis-aligned bounds [m] of the parts in the object frame."""
        return union_bounds(self.parts)

    def canonical_bounds(self) -> np.ndarray:
        """(2,3) axis-aligned bounds [m] of the parts turned back by -placement_yaw."""
        return union_bounds(turn_about_z(self.parts, -self.placement_yaw))

    @cached_property
    def _mesh(self) -> trimesh.Trimesh:
        return trimesh.util.concatenate([part.mesh() for part in self.parts])

    def mesh(self) -> trimesh.Trimesh:
        """Visualization mesh: the concatenated primitive meshes (cached; do not modify)."""
        return self._mesh

    @cached_property
    def info_wrts(self) -> tuple[WRT, ...]:
        """Information-gathering WRTs: generated from the primitives (pinches, then the sweep),
        then the hand-designed ones, then for each side goal grasp its probe (goal_probe_wrt)."""
        probes = (goal_probe_wrt(g.wrt) for g in self.goal_grasps)
        return (
            info_wrts(self.parts)
            + (sweep_wrt(self.parts),)
            + self.designed_info_wrts
            + tuple(p for p in probes if p is not None)
        )

    @cached_property
    def _wrts(self) -> tuple[WRT, ...]:
        wrts = (
            tuple(g.wrt for g in self.goal_grasps)
            + self.info_wrts
            + measured_reorientation(self.reorient_wrts, self._artefact(REORIENTATION_FILE))
        )
        names = [w.name for w in wrts]
        if len(set(names)) != len(names):
            raise ValueError(f"{self.name}: WRT names are not unique: {names}")
        return wrts

    @property
    def grasp_settling(self) -> Settling | None:
        """How the firm goal grasp "goal" moves the object (measured), or None if not
        measured."""
        return self.settling_for("goal")

    def _load_settling(self, path: Path, goal: str) -> Settling | None:
        """A settling study of the goal grasp ``goal`` (load_settling, with its kernel
        bandwidth of SETTLING_KERNEL_BANDWIDTH of its region's tolerances)."""
        tol = np.asarray(self.goal_region(goal).tol, dtype=float)
        return load_settling(path, bandwidth=SETTLING_KERNEL_BANDWIDTH * tol)

    @cached_property
    def _settlings(self) -> dict[tuple[str, str], Settling | None]:
        """The settling studies loaded so far, by goal grasp and world profile."""
        return {}

    def settling_for(self, goal: str = "goal", profile: str = "nominal") -> Settling | None:
        """How the firm goal grasp ``goal`` moves the object and holds it in world
        ``profile`` (a profile spec's base name, config.world_profile): its own study where
        one was measured (settling_file), else the nominal world's; None if neither was."""
        base = profile.partition(":")[0]
        key = (goal, base)
        if key not in self._settlings:
            path = self._artefact(settling_file(base, goal))
            if path is None:  # an object built in code
                self._settlings[key] = None
            elif base != "nominal" and not path.exists():
                self._settlings[key] = self.settling_for(goal)
            else:
                self._settlings[key] = self._load_settling(path, goal)
        return self._settlings[key]

    def settling_in(self, profile: str) -> Settling | None:
        """How the firm goal grasp "goal" moves the object and holds it in world ``profile``
        (settling_for)."""
        return self.settling_for("goal", profile)

    def _artefact(self, filename: str) -> Path | None:
        """Where the object's measured ``filename`` lives (None: the object has no folder)."""
        return None if self.folder is None else self.folder / filename

    @property
    def settling(self) -> Settling | None:
        """The measured settling of the goal grasp "goal" if the belief tracks it after a
        retreat (``track_settling``), else None."""
        return self.tracked_settling("goal")

    def tracked_settling(self, goal: str, profile: str = "nominal") -> Settling | None:
        """The settling the belief applies after goal grasp ``goal`` retreats in world
        ``profile`` (settling_for), or None when the object's settling is not tracked."""
        return self.settling_for(goal, profile) if self.track_settling else None

    def wrts(self) -> tuple[WRT, ...]:
        """The goal WRT, the generated info WRTs, the sweep and the reorientation WRTs (cached)."""
        return self._wrts

    @cached_property
    def table_touch(self) -> WRT | None:
        """The planned table touch (rrg_sim.table_touch), a WRT of kind "touch" that is no
        action of the planner's; None where none was planned."""
        path = self._artefact(TABLE_TOUCH_FILE)
        if path is None or not path.exists():
            return None
        plan = json.loads(path.read_text())
        return table_touch_wrt(
            plan["poses"],
            plan["spread"],
            plan["preclose"],
            plan["finger"],
            plan["serves"],
            plan["clear"],
        )

    def wrt(self, name: str) -> WRT:
        """The WRT called ``name`` (an action's, or the table touch). A goal grasp's is found
        without generating the others (a settling study needs only its own)."""
        for grasp in self.goal_grasps:
            if grasp.wrt.name == name:
                return grasp.wrt
        wrts = self._wrts + (() if self.table_touch is None else (self.table_touch,))
        for w in wrts:
            if w.name == name:
                return w
        raise KeyError(f"{self.name} has no WRT {name!r}; valid: {[w.name for w in wrts]}")
