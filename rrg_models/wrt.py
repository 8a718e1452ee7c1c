"""World-relative trajectories (WRTs): hand poses in the object frame, a preshape and a kind."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from rrg_models.poses import home_pose, planar_pose, wrap_angle

WrtKind = Literal["goal", "info", "reorient", "touch"]


class InfeasibleWRT(RuntimeError):
    """τ(e) cannot be executed (e.g. no continuous IK chain along the path); an executor
    raises it before the robot moves, so the agent can rule the action out at e and replan."""


@dataclass(frozen=True, eq=False)
class ReorientOutcome:
    """Where a reorientation's full turn leaves the object, measured in MuJoCo
    (rrg_sim.physics.reorient_study): for a start offset Δ = relative_planar(e, w) inside
    ``box`` (3,) half-widths, the offset from the turned estimate e' = (e_x, e_y, e_θ + angle)
    after the turn is Δ' ~ N(Δ + shift, diag σ²) [m, m, rad] (a rigid turn: Δ' = Δ). Outside
    the box the object is taken to turn rigidly (the study did not sample there)."""

    box: np.ndarray
    shift: np.ndarray
    sigma: np.ndarray

    def inside(self, delta: np.ndarray) -> np.ndarray:
        """(…) bool: Δ (…,3) lies in the studied box."""
        d = np.asarray(delta, dtype=float).copy()
        d[..., 2] = wrap_angle(d[..., 2])
        return np.all(np.abs(d) <= self.box, axis=-1)

    def mean(self, delta: np.ndarray) -> np.ndarray:
        """(…,3) the mean Δ' for starts Δ (…,3)."""
        return np.asarray(delta, dtype=float) + self.shift


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
    reorient_outcome: for kind "reorient", where a full turn measurably leaves the object
    (``ReorientOutcome``, from rrg_sim.physics.reorient_study); None: turned rigidly.
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
    reorient_outcome: ReorientOutcome | None = None
    description: str = ""
    closure_informative: bool = True
    meta: dict = field(default_factory=dict)

    def world_poses(self, e) -> np.ndarray:
        """τ(e): the hand poses (K,4,4) in ``world`` for the object estimated at e = (x, y, θ)."""
        return planar_pose(e) @ self.poses

    def with_home(self, e) -> np.ndarray:
        """Home, τ(e), as one (K+1,4,4) sequence (the executor retraces it back to home)."""
        return np.concatenate([home_pose()[None], self.world_poses(e)], axis=0)


def table_touch_wrt(
    poses: np.ndarray, spread: float, preclose: float, finger: int, serves, clear
) -> WRT:
    """The table touch (rrg_sim.table_touch) as a WRT of kind "touch", no action of the
    planner's: poses (2,4,4) in the object's frame (above the contact, then below it), the hand's
    spread and proximal angles [rad], the touching finger (1-3), the WRTs it serves and the
    cylinder about the estimate (radius, height [m]) its hand and links keep out of."""
    return WRT(
        name="table_touch",
        kind="touch",
        poses=np.asarray(poses, dtype=float),
        spread=float(spread),
        preclose=float(preclose),
        description=f"finger {int(finger)}'s tip lowered to the table in the goal's calibration",
        meta={
            "finger": int(finger),
            "serves": list(serves),
            "clear": [float(v) for v in clear],
        },
    )
