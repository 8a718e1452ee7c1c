"""The geometric world as an Environment: the object at a hidden true pose, observations
from the geometric simulator with seeded sensor noise (the pomdp_py 'environment').

The object does not move when touched, except that a reorientation grasp that closes on
it turns it about the hand's axis (fully, to where the WRT's measured outcome puts it).
Physics trials (rrg_sim.physics) are the honest test of bumps; this environment tests the
estimator and planner against their own geometry.
"""

from __future__ import annotations

import numpy as np

from rrg_models.config import N_SENSORS, REORIENT_MIN_FINGERS, SENSING, SensingParams
from rrg_models.goal import goal_holds, holds_object
from rrg_models.objects import ObjectModel
from rrg_models.observation import Observation
from rrg_models.poses import relative_planar
from rrg_models.wrt import WRT
from rrg_sim.geometric_sim import GeometricSimulator

from .search import full_turn


def add_sensor_noise(
    obs: Observation, rng: np.random.Generator, noise: SensingParams = SENSING
) -> Observation:
    """A noisy copy of an observation: Gaussian on the continuous parts, random flips of binary
    sensors."""
    flips = rng.random(N_SENSORS) < noise.sensor_flip
    tips = obs.tip_points + rng.normal(0.0, noise.tip_point_noise, (3, 3))
    return Observation(
        contact=obs.contact,
        progress=obs.progress + (rng.normal(0.0, noise.progress_noise) if obs.contact else 0.0),
        hand_pose=obs.hand_pose,
        sensors=obs.sensors ^ flips,
        closure=obs.closure + rng.normal(0.0, noise.closure_noise, 3),
        tip_points=tips,
        tip_normals=obs.tip_normals,
        motion_dir=obs.motion_dir,
    )


class GeometricEnvironment:
    """Executes WRTs in the geometric simulator against a hidden true pose."""

    def __init__(self, obj: ObjectModel, true_pose, seed: int = 0, noise: SensingParams = SENSING):
        self.obj = obj
        self.true_pose = np.asarray(true_pose, dtype=float)
        self.rng = np.random.default_rng(seed)
        self.noise = noise
        self._sims: dict[str, GeometricSimulator] = {}

    def _sim(self, wrt: WRT) -> GeometricSimulator:
        if wrt.name not in self._sims:
            self._sims[wrt.name] = GeometricSimulator(self.obj, wrt)
        return self._sims[wrt.name]

    def execute(self, wrt: WRT, e: np.ndarray) -> Observation:
        obs = self._sim(wrt).simulate(self.true_pose, e)
        if wrt.kind == "reorient" and holds_object(obs.contact, obs.sensors, REORIENT_MIN_FINGERS):
            self.true_pose = full_turn(
                self.true_pose[None], e, wrt.reorient_angle, wrt.reorient_outcome
            )[0]
        return add_sensor_noise(obs, self.rng, self.noise)

    def retreat(self) -> None:
        """Nothing moves in the geometric world when the hand retreats."""

    def judge(self, wrt: WRT, e: np.ndarray) -> bool:
        """Goal grasp ``wrt``'s region holds the true pose (noise-free geometric outcome)."""
        obs = self._sim(wrt).simulate(self.true_pose, e)
        delta = relative_planar(e, self.true_pose)
        region = self.obj.goal_region(wrt.name)
        return bool(goal_holds(region, delta[None], np.array([obs.contact]), obs.sensors[None])[0])
