"""The planning model of one object: its WRTs with their offline tables, observation
clusters, goal indicators and feasibility maps, at one or more grid resolutions.

This is the "models" part of the pomdp_py split: everything the search needs, computed
offline (or loaded from the on-disk cache) once per object.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace

import numpy as np

from rrg_estimator.config import LEVELS, LIKELIHOOD, LikelihoodParams, UncertaintyLevel
from rrg_estimator.grid import Grid
from rrg_estimator.obs_model import likelihood_params
from rrg_estimator.obs_tables import ObservationTable, load_or_build
from rrg_models.config import REORIENT_MIN_FINGERS
from rrg_models.goal import Settling, goal_weights, holds_object
from rrg_models.objects import ObjectModel, get_object
from rrg_models.wam_feasibility import FeasibilityMap
from rrg_models.wrt import WRT
from rrg_planner.clustering import ObservationClusters, cluster_table
from rrg_planner.config import GOAL_AIM_FRACTION
from rrg_sim.config import NOMINAL, WorldProfile, world_profile
from rrg_sim.executor.wrt_executor import executed_poses
from rrg_sim.posture_calibration import PostureCalibration

log = logging.getLogger(__name__)


def goal_indicator(
    obj: ObjectModel,
    table: ObservationTable,
    start_sigma: np.ndarray | None = None,
    settling: Settling | None = None,
    goal: str = "goal",
) -> np.ndarray:
    """P(G | Δ) over goal grasp ``goal``'s table offsets (the static evaluation's precomputed
    weights), for a belief held ``start_sigma`` away from the goal's frame (goal_weights; None:
    in it), with its region and its settling (default: measured in the nominal world). The
    table's outermost entries stand for every offset beyond them (indices are clamped), so
    they get 0, except along a θ the goal ignores."""
    p = goal_weights(
        obj.goal_region(goal),
        table.grid.points(),
        table.contact,
        table.sensors,
        cell=table.grid.spacing,
        start_sigma=start_sigma,
        settling=obj.settling_for(goal) if settling is None else settling,
    )
    shape = table.grid.shape
    edge = np.zeros(shape, dtype=bool)
    edge[[0, -1], :, :] = edge[:, [0, -1], :] = True
    if not obj.goal.ignores_theta:
        edge[:, :, [0, -1]] = True
    p[edge.ravel()] = 0.0
    return p


def goal_aim(obj: ObjectModel, table: ObservationTable, weights: np.ndarray) -> np.ndarray:
    """Δ_aim (3,): the offset of the object from the estimate that a goal grasp best meets,
    the mean of the table offsets with P(G | Δ) ≥ GOAL_AIM_FRACTION of the best (θ 0 for a goal
    that ignores it). Without settling this is about 0: the goal region is centred."""
    offsets = table.grid.points()
    top = weights >= GOAL_AIM_FRACTION * weights.max()
    aim = offsets[top].mean(axis=0) if weights.max() > 0 else np.zeros(3)
    if obj.goal.ignores_theta:
        aim[2] = 0.0
    return aim


@dataclass(eq=False)
class ActionModel:
    """One WRT with its per-level offline models (keyed by level name)."""

    wrt: WRT
    feasibility: FeasibilityMap
    tables: dict[str, ObservationTable] = field(default_factory=dict)
    clusters: dict[str, ObservationClusters] = field(default_factory=dict)
    #: P(G | Δ) over the table offsets, per level (goal WRTs only), for a belief in the goal's
    #: own frame (rrg_sim.posture_calibration)
    goal: dict[str, np.ndarray] = field(default_factory=dict)
    #: the same for a belief in another frame, by frame and level (a world with calibration
    #: error only): the calibration's offset between the frames blurs it
    goal_from: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    #: per level, the offset Δ_aim the grasp best meets (goal WRTs only; goal_aim on the finest
    #: level's table for all: on the 0.1 rad grid the teacup's fell on a half step, -0.05 rad,
    #: where the table index of every offset from it is a tie)
    aim: dict[str, np.ndarray] = field(default_factory=dict)
    #: per level, (C,) whether each observation cluster's grasp holds the object, so that
    #: the reorientation turns it (reorient WRTs only; goal.holds_object)
    turns: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return self.wrt.name

    @property
    def kind(self) -> str:
        return self.wrt.kind


class PlanningModel:
    """All offline models of one object for the given uncertainty levels."""

    def __init__(
        self,
        object_name: str,
        levels: tuple[str | UncertaintyLevel, ...] = tuple(LEVELS),
        workers: int = 2,
        progress: bool = True,
        wrt_names: tuple[str, ...] | None = None,
        closures_as_predicted: bool = False,
        world: WorldProfile | str = NOMINAL,
        likelihood: LikelihoodParams = LIKELIHOOD,
    ):
        """levels: level names from config.LEVELS, or UncertaintyLevel objects (e.g. small test
        grids).
        wrt_names: restrict the actions to these WRTs (default: all of the object's WRTs).
        closures_as_predicted: the world reads every WRT's closures exactly as the geometric
        model predicts (the GeometricEnvironment, where nothing moves), so even the goal
        grasp's are used (WRT.closure_informative); physics and the robot drag the object.
        world: the world profile (or its spec, config.world_profile) the robot acts in: its
        calibration error puts the WRTs' readings in frames (rrg_sim.posture_calibration), and
        a goal grasp from a belief in another frame than its own is valued with that error.
        likelihood: the robot's likelihood parameters, as its estimator's (e.g. the sensors it
        has no reading of)."""
        self.obj = get_object(object_name)
        self.world = world_profile(world)
        self.calibration = PostureCalibration.for_object(self.obj, self.world)
        frames = sorted(set(self.calibration.frames.values()) | {""})
        resolved = [LEVELS[n] if isinstance(n, str) else n for n in levels]
        self.levels: dict[str, UncertaintyLevel] = {lv.name: lv for lv in resolved}
        wrts = [
            replace(w, closure_informative=True) if closures_as_predicted else w
            for w in self.obj.wrts()
            if wrt_names is None or w.name in wrt_names
        ]
        self.actions: list[ActionModel] = []
        for wrt in wrts:
            act = ActionModel(wrt=wrt, feasibility=FeasibilityMap(executed_poses(wrt)))
            for name, level in self.levels.items():
                table = load_or_build(
                    self.obj, wrt, Grid.for_level(level), workers=workers, progress=progress
                )
                act.tables[name] = table
                act.clusters[name] = cluster_table(
                    table, level, params=likelihood_params(wrt, likelihood)
                )
                if wrt.kind == "goal":
                    # the grasp's settling and hold as measured in this world (the nominal
                    # world's where its own study is missing)
                    settling = self.obj.settling_for(wrt.name, self.world.name)
                    act.goal[name] = goal_indicator(
                        self.obj, table, settling=settling, goal=wrt.name
                    )
                    own = self.calibration.frame_of(wrt.name)
                    for frame in frames:
                        if self.calibration.distinct(frame, own):
                            sigma = self.calibration.sigma(frame, own)
                            act.goal_from.setdefault(frame, {})[name] = goal_indicator(
                                self.obj, table, sigma, settling, goal=wrt.name
                            )
                if wrt.kind == "reorient":
                    rep = act.clusters[name].representatives
                    act.turns[name] = holds_object(
                        table.contact[rep], table.sensors[rep], REORIENT_MIN_FINGERS
                    )
            if wrt.kind == "goal":  # a physical offset: from the finest table, for every level
                finest = min(self.levels, key=lambda n: np.prod(act.tables[n].grid.spacing))
                aim = goal_aim(self.obj, act.tables[finest], act.goal[finest])
                act.aim = {name: aim for name in self.levels}
            self.actions.append(act)
            log.info(
                "%s/%s: %s clusters",
                object_name,
                wrt.name,
                {n: c.count for n, c in act.clusters.items()},
            )
        self.goal_actions = [i for i, a in enumerate(self.actions) if a.kind == "goal"]
        if not self.goal_actions:
            raise ValueError(f"object {object_name!r} has no goal WRT")
        #: per level, (3,) the largest |Δ| [m, m, rad] with P(G | Δ) > 0 for some goal WRT,
        #: from a belief in any frame
        self.goal_reach: dict[str, np.ndarray] = {}
        for name in self.levels:
            offsets = np.concatenate(
                [
                    self.actions[g].tables[name].grid.points()[p > 0]
                    for g in self.goal_actions
                    for p in [self.actions[g].goal[name]]
                    + [t[name] for t in self.actions[g].goal_from.values()]
                ]
            )
            self.goal_reach[name] = np.abs(offsets).max(axis=0) if len(offsets) else np.zeros(3)

    @property
    def names(self) -> list[str]:
        return [a.name for a in self.actions]

    def index(self, wrt_name: str) -> int:
        """Action index of a WRT by name (KeyError with the valid names otherwise)."""
        for i, a in enumerate(self.actions):
            if a.name == wrt_name:
                return i
        raise KeyError(f"unknown WRT {wrt_name!r} for {self.obj.name}; valid: {self.names}")

    def reading_frame(self, action: int, current: str) -> str:
        """The frame a reading of ``action`` puts a belief held in ``current`` in
        (rrg_sim.posture_calibration.PostureCalibration.reading_frame)."""
        return self.calibration.reading_frame(self.actions[action].name, current)

    def goal_table(self, action: int, level: str, frame: str) -> np.ndarray:
        """P(G | Δ) over goal WRT ``action``'s table offsets at ``level``, for a belief held in
        ``frame``: its own frame's, or the one blurred by the calibration between the two."""
        act = self.actions[action]
        return act.goal_from.get(frame, act.goal)[level]

    def level_of(self, grid: Grid) -> str:
        """The level whose table spacing matches a belief grid's spacing."""
        for name, level in self.levels.items():
            if np.allclose(grid.spacing, level.spacing):
                return name
        raise ValueError(
            f"no tables for grid spacing {grid.spacing}; loaded levels: {list(self.levels)}"
        )

    def wrt(self, name: str) -> WRT:
        """The WRT called ``name`` as this model plans with it (KeyError with the valid names)."""
        return self.actions[self.index(name)].wrt

    def table(self, wrt_name: str, grid: Grid) -> ObservationTable:
        """The WRT's observation table at the level whose spacing ``grid`` has (ValueError if
        none)."""
        return self.actions[self.index(wrt_name)].tables[self.level_of(grid)]

    def feasible(self, action: int, e) -> bool:
        """F_τ(e): IK within joint limits and the arm clear of the table at every sample of the
        path an executor follows (execution.executed_poses)."""
        return bool(self.actions[action].feasibility.lookup(np.asarray(e, dtype=float)))
