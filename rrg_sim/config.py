"""Every model constant of RRG in one place, each with its source.

Units are SI (m, rad, N, kg, s) unless a name says otherwise. Frames:

* ``world``: the WAM base at the origin, z up, x forward, the table in front.
* object frame: origin at the centre of the object's footprint on the table
  surface, z up; an object pose on the table is w = (x, y, θ) in ``world``.
* hand frame: the BarrettHand base at the wrist flange, +z out of the palm
  (the approach direction), finger 3 on the -y side, fingers 1 and 2 on +y
  at spread 0.

Sources are cited per block: the paper (Hsiao, Lozano-Pérez, Kaelbling,
"Relatively Robust Grasping"), ``shared/notes/mujoco-world.md`` (published
WAM and BarrettHand dimensions), ``shared/DESIGN.md``, or "chosen" with the
reason where neither gives a number.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

MODEL_VERSION = "1"
"""Bump when any geometric constant below changes: observation tables on disk
are keyed by it and rebuilt when stale."""


# --------------------------------------------------------------------------- WAM
@dataclass(frozen=True)
class WamParams:
    """Barrett WAM 7-DOF. Source: Barrett's published DH table (shared/notes/mujoco-world.md)."""

    #: (alpha [rad], a [m], d [m]) per joint, standard (distal) DH convention.
    dh: tuple[tuple[float, float, float], ...] = (
        (-math.pi / 2, 0.0, 0.0),
        (math.pi / 2, 0.0, 0.0),
        (-math.pi / 2, 0.045, 0.55),
        (math.pi / 2, -0.045, 0.0),
        (-math.pi / 2, 0.0, 0.30),
        (math.pi / 2, 0.0, 0.0),
        (-math.pi / 2, 0.0, 0.0609),
    )
    #: J1 axis height above the base (the common WAM model).
    base_height: float = 0.346
    #: joint limits [rad] (Barrett).
    lower: tuple[float, ...] = (-2.6, -1.985, -2.8, -0.9, -4.55, -1.5707, -3.0)
    upper: tuple[float, ...] = (2.6, 1.985, 2.8, math.pi, 1.25, 1.5707, 3.0)
    #: hand base frame lies this far beyond the J7 frame along its z (notes: "about 0.06 m").
    hand_mount: float = 0.06
    #: link radii used for the table-clearance check [m] (chosen: WAM outer link radius ~ 0.05).
    link_radius: float = 0.06
    #: minimum clearance of the wrist and elbow above the table surface [m] (chosen).
    table_clearance: float = 0.02


WAM = WamParams()


# ------------------------------------------------------------------ BarrettHand
@dataclass(frozen=True)
class HandParams:
    """BarrettHand BH8-282 in the hand frame. Source: public URDFs (shared/notes/mujoco-world.md);
    link cross-sections chosen from the BH8-282 data sheet drawings (25 mm wide fingers)."""

    spread_axis_x: float = 0.025  # fingers 1 and 2 spread axes at (±0.025, 0, ·)
    spread_axis_z: float = 0.0415
    knuckle_radius: float = 0.05  # proximal knuckle, radially out from the spread axis
    knuckle_z: float = 0.0754
    finger3_xy: tuple[float, float] = (0.0, -0.05)
    spread_range: tuple[float, float] = (0.0, math.pi)
    proximal_length: float = 0.07
    proximal_range: tuple[float, float] = (0.0, 2.44)
    distal_length: float = 0.057  # knuckle of the distal joint to the fingertip's end
    distal_range: tuple[float, float] = (0.0, 0.84)
    #: distal angle = coupling * proximal angle (notes: "about 1/3", an estimate).
    distal_coupling: float = 1.0 / 3.0
    finger_width: float = 0.025  # link width across the finger [m]
    finger_thickness: float = 0.018  # link thickness, inner pad to back [m]
    #: Nano17 fingertip: a cylinder of this radius capped by a hemisphere (notes).
    tip_radius: float = 0.011
    tip_length: float = 0.022  # fingertip sensor part of the distal link, incl. the cap
    palm_surface_z: float = 0.08
    palm_half_extent: tuple[float, float] = (0.045, 0.045)  # palm box half sizes in x, y
    palm_mass: float = 0.5
    finger_link_mass: float = 0.07  # per link (chosen: BH8 total 1.2 kg)
    #: Torque limit at the proximal joint when closing [N m] (chosen: stalls at ~ 15 N at the tip).
    close_torque: float = 1.0
    #: Proximal closing speed [rad/s] (BH8-282 data sheet: 1.0 s open to close).
    close_speed: float = 2.4


HAND = HandParams()

#: Sensor ids (index into every sensor array): 7 binary pads and 3 Nano17 fingertips.
SENSOR_NAMES: tuple[str, ...] = (
    "palm",
    "prox1", "prox2", "prox3",
    "dist1", "dist2", "dist3",
    "tip1", "tip2", "tip3",
)
N_SENSORS = len(SENSOR_NAMES)
PAD_SENSORS = tuple(range(7))
TIP_SENSORS = (7, 8, 9)


# -------------------------------------------------------------------- the world
@dataclass(frozen=True)
class WorldParams:
    """Table and nominal placement (chosen to put objects in the WAM's dexterous workspace)."""

    table_top_z: float = 0.0
    table_x: tuple[float, float] = (0.20, 1.20)
    table_y: tuple[float, float] = (-0.70, 0.70)
    table_thickness: float = 0.05
    table_friction: float = 0.5
    #: nominal object pose (x, y, θ) - the centre of the initial belief.
    nominal_pose: tuple[float, float, float] = (0.62, 0.0, 0.0)
    #: home pose of the hand: palm above the table, pointing down (hand z = world -z).
    home_position: tuple[float, float, float] = (0.45, 0.0, 0.45)


WORLD = WorldParams()

#: Rotation (rotation vector, rad) of the home hand frame in world: π about x, so the
#: hand approaches straight down (hand z = world -z) with hand x = world x.
HOME_ROTVEC = (math.pi, 0.0, 0.0)


# ------------------------------------------------------------------- belief grid
@dataclass(frozen=True)
class UncertaintyLevel:
    """One initial-uncertainty level: its Gaussian σ and its belief grid."""

    name: str
    sigma: tuple[float, float, float]  # (m, m, rad)
    spacing: tuple[float, float, float]  # grid spacing (m, m, rad)
    shape: tuple[int, int, int] = (31, 31, 25)


#: Paper: σ = 5 cm, 5 cm, 30°, grid 1 cm and 0.1 rad.
HIGH = UncertaintyLevel("high", (0.05, 0.05, math.radians(30.0)), (0.01, 0.01, 0.1))
#: Paper: σ = 1 cm, 1 cm, 3°; DESIGN §3: about 2 mm and 0.013 rad.
LOW = UncertaintyLevel("low", (0.01, 0.01, math.radians(3.0)), (0.002, 0.002, 0.013))
LEVELS = {"high": HIGH, "low": LOW}

#: Variable-resolution grid (DESIGN §3): re-grid to LOW's spacing once at least
#: 1 - VARRES_EPS of the mass lies inside a LOW-sized box.
VARRES_EPS = 0.01


# ------------------------------------------------------------- observation model
@dataclass(frozen=True)
class LikelihoodParams:
    """P(o | w, τ(e)) (DESIGN §5). Chosen to cover the physics simulator's spread of
    outcomes around the geometric prediction (measured by tests/test_physics_vs_geometric)."""

    p_contact_mismatch: float = 0.05  # P(early contact differs from prediction)
    sigma_progress: float = 0.012  # m, where along the path the hand stopped
    p_detect: float = 0.90  # P(sensor fires | predicted contact on it)
    p_false_alarm: float = 0.04  # P(sensor fires | no predicted contact on it)
    sigma_closure: float = 0.15  # rad, per-finger proximal closure angle
    sigma_tip: float = 0.012  # m, Nano17 contact point
    floor: float = 1e-3  # ε: no single observation rules a state out


LIKELIHOOD = LikelihoodParams()


@dataclass(frozen=True)
class TransitionParams:
    """Transition model (DESIGN §3; paper: a mixture 'stays' / 'bumped')."""

    p_stay: float = 0.7  # P(object does not move | contact)
    bump_mean: float = 0.01  # m, mean displacement along the hand's motion at contact
    bump_sigma_xy: float = 0.008  # m
    bump_sigma_theta: float = 0.05  # rad
    p_reorient_success: float = 0.8  # P(rotation fully achieved)
    p_reorient_partial: float = 0.1  # P(stops half way); the rest: no rotation


TRANSITION = TransitionParams()


# ------------------------------------------------------------------ search
@dataclass(frozen=True)
class SearchParams:
    """Forward search and strategies (paper: δ = 0.1, ≤ 10 actions, prune 0.01, keep 50 %)."""

    horizon: int = 2
    delta: float = 0.1
    action_cost: float = 0.01
    max_actions: int = 10
    offline_prune: float = 0.01
    online_keep_mass: float = 0.5
    merge_entropy_tol: float = 0.15  # nats
    merge_cov_tol: float = 0.25  # relative Frobenius difference
    support_rel: float = 1e-5  # drop belief points below this fraction of the max in search


SEARCH = SearchParams()


# ----------------------------------------------------------- geometric simulator
@dataclass(frozen=True)
class GeometricSimParams:
    """Resolution of the geometric sweep (chosen: well below the 2 mm fine grid after refinement)."""

    path_step: float = 0.005  # m between swept hand copies
    refine_iters: int = 5  # bisection steps inside the first colliding step (0.16 mm)
    close_step: float = 0.04  # rad between finger closing samples
    close_max: float = HAND.proximal_range[1]


GEOMSIM = GeometricSimParams()


# ------------------------------------------------------------------ sensing
@dataclass(frozen=True)
class SensingParams:
    """Guarded-move thresholds and sensor noise (chosen; Nano17 resolution ~ 3 mN, pads ~ 0.1 N)."""

    tip_force_threshold: float = 0.5  # N on a Nano17 stops a guarded move
    pad_force_threshold: float = 0.3  # N on a touch pad counts as contact
    nano17_force_noise: float = 0.01  # N, σ
    # Observation-level noise used by the geometric closed loop:
    progress_noise: float = 0.003  # m
    closure_noise: float = 0.03  # rad
    tip_point_noise: float = 0.002  # m
    sensor_flip: float = 0.02  # P(a binary sensor reading flips)


SENSING = SensingParams()


def as_array(t: tuple[float, ...]) -> np.ndarray:
    """Tuple constant → float array (helper for the frozen dataclasses above)."""
    return np.asarray(t, dtype=float)


__all__ = [name for name in dir() if name.isupper() or name.endswith("Params")] + [
    "UncertaintyLevel", "as_array", "field",
]
