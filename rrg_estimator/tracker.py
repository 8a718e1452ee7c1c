"""The estimator as a ROS-free core: one object's belief, reset to a Gaussian and updated with
each WRT's observation (DESIGN §3), with the offline tables loaded on demand.

One update is SE(b, τ(e), o) with the WRT's table at the belief's grid level, then, for a
reorientation WRT, the commanded rotation about e; afterwards the belief is re-gridded finer
when it has concentrated (variable resolution). A goal grasp that arrived moves the object
as it closes and retreats (``settle_after_grasp``); the tracker applies that at the next
update, since the belief that declares the grasp is the one before it.
"""
from __future__ import annotations

import logging

import numpy as np

from rrg_estimator.config import LEVELS, UncertaintyLevel
from rrg_sim.config import REORIENT_MIN_FINGERS
from rrg_estimator.grid import Grid
from rrg_sim.objects import ObjectModel, get_object
from rrg_sim.observation import Observation, holds_object
from rrg_sim.wrt import WRT

from .belief import Belief
from .obs_model import TableLike, likelihood_params
from .obs_tables import ObservationTable, load_or_build
from .transition import reorient, settle
from .update import update
from .varres import maybe_refine

log = logging.getLogger(__name__)


def level_of_grid(grid: Grid) -> UncertaintyLevel:
    """The uncertainty level whose grid spacing a belief grid has (tables exist only for those)."""
    for level in LEVELS.values():
        if np.allclose(grid.spacing, level.spacing):
            return level
    raise ValueError(f"no observation tables for grid spacing {tuple(grid.spacing)}; "
                     f"levels: { {n: lv.spacing for n, lv in LEVELS.items()} }")


def closest_level(sigma) -> UncertaintyLevel:
    """The level whose σ is closest to ``sigma`` (x [m], y [m], θ [rad]) in log scale."""
    s = np.log(np.asarray(sigma, dtype=float))
    return min(LEVELS.values(), key=lambda lv: float(np.sum((s - np.log(lv.sigma)) ** 2)))


def wrt_posterior(belief: Belief, table: TableLike, wrt: WRT, e, obs: Observation) -> Belief:
    """The belief after executing ``wrt`` at estimate e and observing ``obs``: the Bayes update
    with the WRT's table, then the reorientation's rotation about e for a reorient WRT whose
    grasp held the object (observation.holds_object; otherwise nothing was turned)."""
    post = update(belief, table, e, obs, params=likelihood_params(wrt))
    if wrt.kind == "reorient" and holds_object(obs.contact, obs.sensors, REORIENT_MIN_FINGERS):
        e = np.asarray(e, dtype=float)
        post = reorient(post, wrt.reorient_angle, center_xy=e[:2], outcome=wrt.reorient_outcome, e=e)
    return post


def settle_after_grasp(belief: Belief, obj: ObjectModel, wrt: WRT, e, contact: bool) -> Belief:
    """The belief after retreating from ``wrt`` run at e: a goal grasp that arrived (no early
    contact, so it closed firmly) moved the object as the object's measured settling says;
    anything else leaves it (the bump of an early contact is part of the update)."""
    if wrt.kind != "goal" or contact or obj.settling is None:
        return belief
    return settle(belief, obj.settling, e)


class BeliefTracker:
    """The belief over one object's pose and the tables that update it.

    workers: processes used when a table has to be built (it is normally cached on disk).
    """

    def __init__(self, obj: ObjectModel, belief: Belief, variable_resolution: bool = True, workers: int = 2):
        self.obj = obj
        self.belief = belief
        self.variable_resolution = variable_resolution
        self.workers = workers
        self._tables: dict[tuple[str, str], ObservationTable] = {}
        #: the last WRT, its estimate and whether it stopped early, until the next update
        self._last: tuple[WRT, np.ndarray, bool] | None = None

    @classmethod
    def gaussian(cls, object_name: str, mean, sigma, level: UncertaintyLevel | None = None,
                 **kwargs) -> "BeliefTracker":
        """A tracker whose belief is N(mean, diag(σ²)) on the level's grid centred at the mean
        (level None: the one whose σ is closest). Raises KeyError for an unknown object and
        ValueError for a non-finite mean or a non-positive σ."""
        mean, sigma = np.asarray(mean, dtype=float).reshape(3), np.asarray(sigma, dtype=float).reshape(3)
        if not np.all(np.isfinite(mean)):
            raise ValueError(f"mean must be finite, got {mean.tolist()}")
        if not (np.all(np.isfinite(sigma)) and np.all(sigma > 0.0)):
            raise ValueError(f"sigma must be finite and > 0, got {sigma.tolist()}")
        obj = get_object(object_name)
        level = level or closest_level(sigma)
        return cls(obj, Belief.gaussian(Grid.for_level(level, center=mean), mean, sigma), **kwargs)

    def table(self, wrt: WRT, level: UncertaintyLevel) -> ObservationTable:
        """The WRT's table at a level (from memory, the disk cache, or built: ~1 min, logged)."""
        key = (wrt.name, level.name)
        if key not in self._tables:
            log.info("loading observation table %s/%s at level %s", self.obj.name, wrt.name, level.name)
            self._tables[key] = load_or_build(self.obj, wrt, level, workers=self.workers, progress=False)
        return self._tables[key]

    def preload(self) -> None:
        """Load every WRT's table at the belief's level, so the first update does not wait."""
        level = level_of_grid(self.belief.grid)
        for wrt in self.obj.wrts():
            self.table(wrt, level)

    def observe(self, wrt_name: str, e, obs: Observation) -> Belief:
        """Update the belief with the observation of WRT ``wrt_name`` run at estimate e, then
        re-grid it finer if it has concentrated. Raises KeyError for a WRT the object does not
        have and ValueError for an observation the belief cannot explain; the belief is kept then."""
        wrt = self.obj.wrt(wrt_name)
        prior = self.belief if self._last is None else settle_after_grasp(self.belief, self.obj, *self._last)
        post = wrt_posterior(prior, self.table(wrt, level_of_grid(prior.grid)), wrt, e, obs)
        if self.variable_resolution:
            post = maybe_refine(post) or post
        self.belief, self._last = post, (wrt, np.asarray(e, dtype=float), bool(obs.contact))
        return post
