"""World-relative trajectories (WRTs): hand poses in the object frame, a preshape and a kind."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from .poses import home_pose, planar_pose

WrtKind = Literal["goal", "info", "reorient"]


class InfeasibleWRT(RuntimeError):
    """τ(e) cannot be executed (e.g. no continuous IK chain along the path); an executor
    raises it before the robot moves, so the agent can rule the action out at e and replan."""


@dataclass(frozen=True, eq=False)
class WRT:
    """A world-relative trajectory.

    poses: (K,4,4) hand-frame poses in the object frame. The first is an approach pose
    well clear of the object (the move from home to it is never expected to touch), the
    last is where the fingers close if nothing was touched before.
    spread: the preshape spread angle [rad] (fingers 1 and 2; 0 = opposing finger 3).
    preclose: proximal angle [rad] the fingers hold while moving (preshape).
    reorient_angle: for kind "reorient", the commanded rotation of the object about its
    vertical axis after the grasp [rad].
    closure_informative: False when the fingers drag the object as they close, so that the
    closure angles physics reads are not the geometric (object stays put) prediction; the
    belief update then ignores them (rrg_estimator.obs_model.likelihood_params). Set from
    rrg_sim.physics.agreement's per-WRT closure differences.
    """

    name: str
    kind: WrtKind
    poses: np.ndarray
    spread: float = 0.0
    preclose: float = 0.0
    reorient_angle: float = 0.0
    description: str = ""
    closure_informative: bool = True
    meta: dict = field(default_factory=dict)

    def world_poses(self, e) -> np.ndarray:
        """τ(e): the hand poses (K,4,4) in ``world`` for the object estimated at e = (x, y, θ)."""
        return planar_pose(e) @ self.poses

    def with_home(self, e) -> np.ndarray:
        """Home, τ(e), as one (K+1,4,4) sequence (the executor retraces it back to home)."""
        return np.concatenate([home_pose()[None], self.world_poses(e)], axis=0)
