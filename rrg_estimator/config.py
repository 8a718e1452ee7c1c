"""The estimator's parameters: uncertainty levels and belief grids, the variable-resolution
grid, the observation likelihood and the transition model, each with its source.

Units are SI (m, rad) unless a name says otherwise. Sources: the paper (Hsiao, Lozano-Pérez,
Kaelbling, "Relatively Robust Grasping"), docs/algorithm.md, MuJoCo measurements
(docs/world.md), or "chosen" with the reason where none gives a number.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, replace

from rrg_models.config import SENSOR_NAMES


# ------------------------------------------------------------------- belief grid
@dataclass(frozen=True)
class UncertaintyLevel:
    """One initial-uncertainty level: its Gaussian σ and its belief grid."""

    name: str
    sigma: tuple[float, float, float]  # (m, m, rad)
    spacing: tuple[float, float, float]  # grid spacing (m, m, rad)
    shape: tuple[int, int, int] = (31, 31, 25)


#: Paper: σ = 5 cm, 5 cm, 30°, grid 1 cm and 0.1 rad. A true pose off the grid can never be
#: found. The paper's 25 θ points span only ±1.2 rad = ±2.3σ, so about 2 % of true poses
#: drawn from the prior lie off the grid (MuJoCo: 26 of 1,000 high-uncertainty RRG-Info
#: trials, 12 of them failures); 33 span ±1.6 rad = ±3σ. x and y span ±20 cm = ±4σ (41
#: points; the paper's 31 span ±3σ): with ±3σ, 0.54 % of drawn poses lie off the grid in x or
#: y, and 5 of the 6 such poses in 1,000 high-uncertainty RRG-Info trials failed; ±4σ leaves
#: 0.013 % (docs/algorithm.md §3).
HIGH = UncertaintyLevel("high", (0.05, 0.05, math.radians(30.0)), (0.01, 0.01, 0.1), (41, 41, 33))
#: Paper: σ = 1 cm, 1 cm, 3°; algorithm §3: about 2 mm and 0.013 rad.
LOW = UncertaintyLevel("low", (0.01, 0.01, math.radians(3.0)), (0.002, 0.002, 0.013))
#: Chosen: the variable-resolution grid's middle step, ±3σ like LOW (±7.5 cm, ±0.6 rad at
#: 5 mm and 0.05 rad). With HIGH and LOW alone a belief stays on HIGH's 0.1 rad until 99 %
#: of it fits LOW's ±0.156 rad, and 0.1 rad is coarse against the goal tolerances it must
#: resolve (the teacup's ±0.14 rad). Measured in MuJoCo with HIGH and LOW alone: 41 of 100
#: pitcher and half the teacup trials at high uncertainty used all 10 actions, and in one
#: pitcher trial HIGH's belief settled 0.15 rad off the truth, then refined to a LOW grid the
#: truth lay 0.065 rad beyond (docs/algorithm.md §3).
MID = UncertaintyLevel("mid", (0.025, 0.025, 0.2), (0.005, 0.005, 0.05))
LEVELS = {"high": HIGH, "mid": MID, "low": LOW}

#: Variable-resolution grid (algorithm §3): re-grid to the finest of the finer levels (MID, LOW)
#: whose box holds at least 1 - VARRES_EPS of the mass.
VARRES_EPS = 0.01
#: A fine belief is re-centred on its mean once the mean is off the grid centre by more
#: than this fraction of the half extent on some axis (chosen: a firm grasp turns the
#: pitcher ~0.1 rad per goal grasp, against LOW's ±0.156 rad; re-centring at a quarter
#: keeps such a move on the grid).
VARRES_RECENTER = 0.25


# ------------------------------------------------------------- observation model
@dataclass(frozen=True)
class LikelihoodParams:
    """P(o | w, τ(e)) (algorithm §5). Chosen to cover the physics simulator's spread of
    outcomes around the geometric prediction (measured by
    tests/rrg_sim/test_physics_vs_geometric)."""

    p_contact_mismatch: float = 0.05  # P(early contact differs from prediction)
    sigma_progress: float = 0.012  # m, where along the path the hand stopped
    p_detect: float = 0.90  # P(sensor fires | predicted contact on it)
    p_false_alarm: float = 0.04  # P(sensor fires | no predicted contact on it)
    #: rad, per-finger proximal closure angle at the entry's exact offset; each table entry adds
    #: its nearest-entry discretization (obs_model.closure_sigma)
    sigma_closure: float = 0.05
    sigma_tip: float = 0.012  # m, Nano17 contact point
    #: Per-term outlier floors on the Gaussian terms (likelihood ratio of an outlier): a finger
    #: that slides off or pushes a light object on, or a stop point shifted by a bump, costs
    #: one bounded factor instead of ruling the state out. Chosen from the physics-vs-geometric
    #: agreement (rrg_sim.physics.agreement): ~10 % of closures/tip points are such outliers.
    outlier_progress: float = 0.02
    outlier_closure: float = 0.05
    outlier_tip: float = 0.05
    floor: float = 1e-3  # ε: no single observation rules a state out
    #: Sensors (rrg_models.config.SENSOR_NAMES indices) the robot has no reading of, e.g. the
    #: proximal pads of a real BarrettHand, whose tactile pucks sit on the fingertips and the
    #: palm only: their terms are left out of the likelihood (marginalized), so a silence they
    #: cannot break is not taken for a missed contact. Empty: every sensor reads.
    unsensed: tuple[int, ...] = ()


LIKELIHOOD = LikelihoodParams()


def likelihood_without(
    sensor_names: Iterable[str], params: LikelihoodParams = LIKELIHOOD
) -> LikelihoodParams:
    """``params`` with the named sensors (rrg_models.config.SENSOR_NAMES) unsensed; ValueError
    for a name that is not a sensor."""
    names = [n for n in sensor_names if n]
    unknown = [n for n in names if n not in SENSOR_NAMES]
    if unknown:
        raise ValueError(f"unknown sensors {unknown}; sensors: {', '.join(SENSOR_NAMES)}")
    return replace(params, unsensed=tuple(sorted({SENSOR_NAMES.index(n) for n in names})))


@dataclass(frozen=True)
class TransitionParams:
    """Transition model (algorithm §3; paper: a mixture 'stays' / 'bumped')."""

    p_stay: float = 0.7  # P(object does not move | contact)
    bump_mean: float = 0.01  # m, mean displacement along the hand's motion at contact
    bump_sigma_xy: float = 0.008  # m
    bump_sigma_theta: float = 0.05  # rad
    p_reorient_success: float = 0.8  # P(rotation fully achieved)
    p_reorient_partial: float = 0.1  # P(stops half way); the rest: no rotation
    #: rad, spread of the turn actually made about the commanded one (MuJoCo, 0.6 rad
    #: reorientations of the giant teacup from 8 seeded starts each: 0.8-1.06 of the angle,
    #: σ ≈ 0.04 rad; the drill: σ ≈ 0.015 rad; the larger is used). A full turn of a WRT with a
    #: measured outcome (its object's reorientation.json, WRT.reorient_outcome) adds that one's σ.
    reorient_sigma_theta: float = 0.04


TRANSITION = TransitionParams()
