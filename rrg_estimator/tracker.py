"""The estimator as a ROS-free core: one object's belief, reset to a Gaussian, updated with each
WRT's observation and carried through each retreat (algorithm §3). The estimator node and the
in-process closed loop (rrg_planner.closed_loop) both keep their belief here, so the sequence of
updates exists once.

An update is SE(b, τ(e), o): first, where the WRT's posture sees the object from another frame
than the belief's (rrg_sim.posture_calibration: the robot's calibration error differs between
postures), the belief moves to the WRT's frame (transition.change_frame); then the Bayes update
with the WRT's table at the belief's grid level,
then, for a reorientation WRT whose grasp held the object, the commanded rotation about e. The
belief after an update is the one the agent's stopping rule reads. When the hand retreats,
``retreated`` applies the retreat's transition: the belief is re-gridded finer once it has
concentrated (variable resolution), then a goal grasp that arrived moves the object as its
measured settling says (it closed firmly and the object followed the fingers). An update that
comes before the last retreat was reported applies that retreat first.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from typing import Protocol

import numpy as np

from rrg_estimator.config import LEVELS, LIKELIHOOD, LikelihoodParams, UncertaintyLevel
from rrg_estimator.grid import Grid
from rrg_models.config import REORIENT_MIN_FINGERS
from rrg_models.goal import holds_object
from rrg_models.objects import ObjectModel, get_object
from rrg_models.observation import Observation
from rrg_models.wrt import WRT
from rrg_sim.posture_calibration import PostureCalibration

from .belief import Belief
from .obs_model import TableLike, likelihood_params
from .obs_tables import ObservationTable, load_or_build
from .transition import change_frame, reorient, settle
from .update import update
from .varres import maybe_refine

log = logging.getLogger(__name__)


def level_of_grid(grid: Grid) -> UncertaintyLevel:
    """The uncertainty level whose grid spacing a belief grid has (tables exist only for those)."""
    for level in LEVELS.values():
        if np.allclose(grid.spacing, level.spacing):
            return level
    raise ValueError(
        f"no observation tables for grid spacing {tuple(grid.spacing)}; "
        f"levels: { {n: lv.spacing for n, lv in LEVELS.items()} }"
    )


def closest_level(sigma) -> UncertaintyLevel:
    """The level whose σ is closest to ``sigma`` (x [m], y [m], θ [rad]) in log scale."""
    s = np.log(np.asarray(sigma, dtype=float))
    return min(LEVELS.values(), key=lambda lv: float(np.sum((s - np.log(lv.sigma)) ** 2)))


def wrt_posterior(
    belief: Belief,
    table: TableLike,
    wrt: WRT,
    e,
    obs: Observation,
    params: LikelihoodParams = LIKELIHOOD,
) -> Belief:
    """The belief after executing ``wrt`` at estimate e and observing ``obs``: the Bayes update
    with the WRT's table (``params``: the robot's likelihood parameters, adjusted per WRT by
    likelihood_params), then the reorientation's rotation about e for a reorient WRT whose
    grasp held the object (goal.holds_object; otherwise nothing was turned)."""
    post = update(belief, table, e, obs, params=likelihood_params(wrt, params))
    if wrt.kind == "reorient" and holds_object(obs.contact, obs.sensors, REORIENT_MIN_FINGERS):
        e = np.asarray(e, dtype=float)
        post = reorient(
            post, wrt.reorient_angle, center_xy=e[:2], outcome=wrt.reorient_outcome, e=e
        )
    return post


def settle_after_grasp(
    belief: Belief, obj: ObjectModel, wrt: WRT, e, contact: bool, world: str = "nominal"
) -> Belief:
    """The belief after retreating from ``wrt`` run at e: a goal grasp that arrived (no early
    contact, so it closed firmly) moved the object as that goal grasp's settling measured in
    world profile ``world`` says (the planner's, PlanningModel); anything else leaves it (the
    bump of an early contact is part of the update)."""
    settling = obj.tracked_settling(wrt.name, world) if wrt.kind == "goal" else None
    if settling is None or contact:
        return belief
    return settle(belief, settling, e)


class WrtTables(Protocol):
    """Where a tracker finds an object's WRTs and their observation tables."""

    def wrt(self, name: str) -> WRT:
        """The WRT called ``name`` (KeyError if the object has none)."""

    def table(self, wrt_name: str, grid: Grid) -> TableLike:
        """The WRT's table at the level whose spacing a belief grid has (ValueError if none)."""


class CachedTables:
    """An object's own WRTs, with their tables from the on-disk cache (built when missing).

    workers: processes used when a table has to be built (it is normally cached on disk).
    """

    def __init__(self, obj: ObjectModel, workers: int = 2):
        self.obj = obj
        self.workers = workers
        self._tables: dict[tuple[str, str], ObservationTable] = {}

    def wrt(self, name: str) -> WRT:
        return self.obj.wrt(name)

    def table(self, wrt_name: str, grid: Grid) -> ObservationTable:
        """The WRT's table at the grid's level (from memory, the disk cache, or built: ~1 min,
        logged)."""
        level = level_of_grid(grid)
        key = (wrt_name, level.name)
        if key not in self._tables:
            log.info(
                "loading observation table %s/%s at level %s", self.obj.name, wrt_name, level.name
            )
            self._tables[key] = load_or_build(
                self.obj, self.wrt(wrt_name), level, workers=self.workers, progress=False
            )
        return self._tables[key]

    def loaded(self) -> dict[str, list[str]]:
        """The WRTs whose tables are in memory, by level name."""
        out: dict[str, list[str]] = {}
        for wrt_name, level in list(self._tables):
            out.setdefault(level, []).append(wrt_name)
        return out


class BeliefTracker:
    """The belief over one object's pose, and the sequence that changes it.

    tables: the WRTs and their tables (default: the object's own, from the disk cache).
    levels: the uncertainty levels a concentrated belief may be re-gridded to (variable resolution).
    calibration: the frames of the object's WRTs (default: none, the nominal world's robot).
    likelihood: the robot's likelihood parameters (e.g. the sensors it has no reading of).
    """

    def __init__(
        self,
        obj: ObjectModel,
        belief: Belief,
        tables: WrtTables | None = None,
        levels: Iterable[UncertaintyLevel] = LEVELS.values(),
        variable_resolution: bool = True,
        calibration: PostureCalibration | None = None,
        likelihood: LikelihoodParams = LIKELIHOOD,
        world: str = "nominal",
    ):
        self.obj = obj
        self.likelihood = likelihood
        #: the world profile whose settling studies a goal grasp's retreat applies
        self.world = world
        self.calibration = calibration or PostureCalibration.none()
        self.belief = belief
        self.tables = tables if tables is not None else CachedTables(obj)
        self.levels = tuple(levels)
        self.variable_resolution = variable_resolution
        #: the last WRT, its estimate and whether it stopped early, until the hand retreats from it
        self.pending: tuple[WRT, np.ndarray, bool] | None = None

    @classmethod
    def gaussian(
        cls, obj: ObjectModel | str, mean, sigma, level: UncertaintyLevel | None = None, **kwargs
    ) -> BeliefTracker:
        """A tracker whose belief is N(mean, diag(σ²)) on the level's grid centred at the mean
        (level None: the one whose σ is closest). Raises KeyError for an unknown object and
        ValueError for a non-finite mean or a non-positive σ."""
        mean, sigma = (
            np.asarray(mean, dtype=float).reshape(3),
            np.asarray(sigma, dtype=float).reshape(3),
        )
        if not np.all(np.isfinite(mean)):
            raise ValueError(f"mean must be finite, got {mean.tolist()}")
        if not (np.all(np.isfinite(sigma)) and np.all(sigma > 0.0)):
            raise ValueError(f"sigma must be finite and > 0, got {sigma.tolist()}")
        obj = get_object(obj) if isinstance(obj, str) else obj
        level = level or closest_level(sigma)
        return cls(obj, Belief.gaussian(Grid.for_level(level, center=mean), mean, sigma), **kwargs)

    def preload(self) -> None:
        """Load every WRT's table at the belief's level, so the first update does not wait."""
        for wrt in self.obj.wrts():
            self.tables.table(wrt.name, self.belief.grid)

    def update(self, wrt_name: str, e, obs: Observation) -> Belief:
        """The belief after WRT ``wrt_name`` ran at estimate e and observed ``obs``. Raises
        KeyError for a WRT the object does not have and ValueError for an observation the belief
        cannot explain; the belief (and a pending retreat) is kept then."""
        wrt = self.tables.wrt(wrt_name)
        prior = self.in_frame_of(self._after_retreat(), wrt_name)
        table = self.tables.table(wrt_name, prior.grid)
        post = wrt_posterior(prior, table, wrt, e, obs, self.likelihood)
        self.belief, self.pending = post, (wrt, np.asarray(e, dtype=float), bool(obs.contact))
        return post

    def in_frame_of(self, belief: Belief, wrt_name: str) -> Belief:
        """``belief`` in the frame WRT ``wrt_name`` reads in (itself when it is already)."""
        frame = self.calibration.reading_frame(wrt_name, belief.frame)
        if belief.frame == frame:
            return belief
        log.info("belief moves from frame %r to %r", belief.frame, frame)
        return change_frame(belief, self.calibration.sigma(belief.frame, frame), frame)

    def retreated(self) -> Belief:
        """The belief once the hand retreated from the last WRT: re-gridded finer if it has
        concentrated, then moved as a goal grasp that arrived settles the object. Nothing
        changes when no update is pending."""
        self.belief, self.pending = self._after_retreat(), None
        return self.belief

    def _after_retreat(self) -> Belief:
        """The pending retreat's transition applied to the belief (the belief itself if none)."""
        if self.pending is None:
            return self.belief
        belief = self.belief
        if self.variable_resolution:
            belief = maybe_refine(belief, self.levels) or belief
        return settle_after_grasp(belief, self.obj, *self.pending, world=self.world)
