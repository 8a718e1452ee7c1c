"""The planning model of one object: its WRTs with their offline tables, observation
clusters, goal indicators and feasibility maps, at one or more grid resolutions.

This is the "models" part of the pomdp_py split: everything the search needs, computed
offline (or loaded from the on-disk cache) once per object.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from rrg_estimator.obs_tables import ObservationTable, load_or_build
from rrg_sim.config import LEVELS, SENSOR_NAMES, UncertaintyLevel
from rrg_sim.observation import fingers_in_contact
from rrg_sim.grid import Grid
from rrg_sim.objects import ObjectModel, get_object
from rrg_sim.wam import FeasibilityMap
from rrg_sim.wrt import WRT

from .clustering import ObservationClusters, cluster_table

log = logging.getLogger(__name__)



def goal_holds(obj: ObjectModel, delta: np.ndarray, contact: np.ndarray, sensors: np.ndarray) -> np.ndarray:
    """G for a goal grasp executed relative to an estimate, with the object really at offset
    delta (N,3): delta inside the goal region, the hand reached the grasp pose without an
    early contact (contact (N,)), and the required contacts are made (sensors (N,10))."""
    ok = obj.goal.contains(delta) & ~np.asarray(contact, dtype=bool)
    ok &= fingers_in_contact(sensors) >= obj.goal.min_fingers
    for name in obj.goal.required_sensors:
        ok &= sensors[:, SENSOR_NAMES.index(name)]
    return ok


def goal_indicator(obj: ObjectModel, table: ObservationTable) -> np.ndarray:
    """G(Δ) over the goal WRT's table (the static evaluation's precomputed indicator)."""
    return goal_holds(obj, table.grid.points(), table.contact, table.sensors)


@dataclass(eq=False)
class ActionModel:
    """One WRT with its per-level offline models (keyed by level name)."""

    wrt: WRT
    feasibility: FeasibilityMap
    tables: dict[str, ObservationTable] = field(default_factory=dict)
    clusters: dict[str, ObservationClusters] = field(default_factory=dict)
    goal: dict[str, np.ndarray] = field(default_factory=dict)
    #: the goal indicators as float64, for fast dot products with belief weights
    goal_weight: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return self.wrt.name

    @property
    def kind(self) -> str:
        return self.wrt.kind


class PlanningModel:
    """All offline models of one object for the given uncertainty levels."""

    def __init__(self, object_name: str, levels: tuple[str | UncertaintyLevel, ...] = ("high", "low"),
                 workers: int = 2, progress: bool = True, wrt_names: tuple[str, ...] | None = None):
        """levels: level names from config.LEVELS, or UncertaintyLevel objects (e.g. small test grids).
        wrt_names: restrict the actions to these WRTs (default: all of the object's WRTs)."""
        self.obj = get_object(object_name)
        resolved = [LEVELS[n] if isinstance(n, str) else n for n in levels]
        self.levels: dict[str, UncertaintyLevel] = {lv.name: lv for lv in resolved}
        wrts = [w for w in self.obj.wrts() if wrt_names is None or w.name in wrt_names]
        self.actions: list[ActionModel] = []
        for wrt in wrts:
            act = ActionModel(wrt=wrt, feasibility=FeasibilityMap(wrt.poses))
            for name, level in self.levels.items():
                table = load_or_build(self.obj, wrt, Grid.for_level(level), workers=workers, progress=progress)
                act.tables[name] = table
                act.clusters[name] = cluster_table(table, level)
                if wrt.kind == "goal":
                    act.goal[name] = goal_indicator(self.obj, table)
                    act.goal_weight[name] = act.goal[name].astype(np.float64)
            self.actions.append(act)
            log.info("%s/%s: %s clusters", object_name, wrt.name,
                     {n: c.count for n, c in act.clusters.items()})
        self.goal_actions = [i for i, a in enumerate(self.actions) if a.kind == "goal"]
        if not self.goal_actions:
            raise ValueError(f"object {object_name!r} has no goal WRT")

    @property
    def names(self) -> list[str]:
        return [a.name for a in self.actions]

    def index(self, wrt_name: str) -> int:
        """Action index of a WRT by name (KeyError with the valid names otherwise)."""
        for i, a in enumerate(self.actions):
            if a.name == wrt_name:
                return i
        raise KeyError(f"unknown WRT {wrt_name!r} for {self.obj.name}; valid: {self.names}")

    def level_of(self, grid: Grid) -> str:
        """The level whose table spacing matches a belief grid's spacing."""
        for name, level in self.levels.items():
            if np.allclose(grid.spacing, level.spacing):
                return name
        raise ValueError(f"no tables for grid spacing {grid.spacing}; loaded levels: {list(self.levels)}")

    def feasible(self, action: int, e) -> bool:
        """F_τ(e): IK within joint limits at every waypoint and the arm clear of the table."""
        return bool(self.actions[action].feasibility.lookup(np.asarray(e, dtype=float)))
