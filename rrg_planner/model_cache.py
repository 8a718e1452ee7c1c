"""The planning models a planner serves, loaded on first use and kept (ROS-free)."""

from __future__ import annotations

import threading
import time

from rrg_estimator.config import LikelihoodParams
from rrg_sim.config import WorldProfile

from .planning_model import PlanningModel


class ModelCache:
    """One planning model per object, at the given levels, loaded on first use."""

    def __init__(self, levels, world: WorldProfile, likelihood: LikelihoodParams, log):
        self.levels = tuple(levels)
        self.world = world
        self.likelihood = likelihood
        self.log = log  # info(message)
        self.models: dict[str, PlanningModel] = {}
        self._lock = threading.Lock()
        self.loading = ""  # the object whose planning model is being loaded

    def get(self, object_name: str) -> PlanningModel:
        """The object's planning model, loaded on first use (a first build takes ~1 min)."""
        with self._lock:
            if object_name not in self.models:
                self.models[object_name] = self._load(object_name)
            return self.models[object_name]

    def _load(self, object_name: str) -> PlanningModel:
        self.loading = object_name
        self.log.info(
            f"loading the planning model of {object_name} at levels "
            f"{list(self.levels)} (building missing tables takes ~1 min per object)"
        )
        t0 = time.monotonic()
        # workers=1: forking a table-building pool from a process running DDS threads can
        # deadlock; rrg-launch builds missing tables in parallel before it starts the nodes.
        try:
            model = PlanningModel(
                object_name,
                levels=self.levels,
                workers=1,
                progress=False,
                world=self.world,
                likelihood=self.likelihood,
            )
        finally:
            self.loading = ""
        self.log.info(
            f"model of {object_name} loaded in {time.monotonic() - t0:.1f} s: WRTs {model.names}"
        )
        return model
