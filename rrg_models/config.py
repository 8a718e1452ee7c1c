"""The model constants of the robot, the hand, their sensing and the world they act in, each with
its source.

Units are SI (m, rad, N, kg, s) unless a name says otherwise. Frames:

* ``world``: the WAM base at the origin, z up, x forward, the table in front.
* object frame: origin at the centre of the object's footprint on the table
  surface, z up; an object pose on the table is w = (x, y, θ) in ``world``.
* hand frame: the BarrettHand base at the wrist flange, +z out of the palm
  (the approach direction), finger 3 on the -y side, fingers 1 and 2 on +y
  at spread 0.

Sources are cited per block: the paper (Hsiao, Lozano-Pérez, Kaelbling,
"Relatively Robust Grasping"), docs/sources.md (published WAM and BarrettHand dimensions,
object sizes, the drivers' figures), docs/algorithm.md, or "chosen" with the reason where
neither gives a number.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

MODEL_VERSION = "1"
"""Bump when any geometric constant below changes: observation tables on disk
are keyed by it and rebuilt when stale."""


# --------------------------------------------------------------------------- WAM
@dataclass(frozen=True)
class WamParams:
    """Barrett WAM 7-DOF. Source: Barrett's DH table (libbarrett config/wam7w.conf,
    docs/sources.md §1)."""

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
    #: rotation of the hand frame about J7's axis at J7 = 0 [rad] (chosen: π puts home_pose()
    #: at J7 ≈ 0 in the elbow-up posture, mid-range of J7's ±3.0; with 0 home needs |J7| ≈ π).
    hand_mount_yaw: float = math.pi
    #: link radii used for the table-clearance check [m] (chosen: WAM outer link radius ~ 0.05).
    link_radius: float = 0.06
    #: minimum clearance of the wrist and elbow above the table surface [m] (chosen).
    table_clearance: float = 0.02


WAM = WamParams()


# ------------------------------------------------------------------ BarrettHand
@dataclass(frozen=True)
class HandParams:
    """BarrettHand BH8-282 in the hand frame. Source: public URDFs (docs/sources.md §2);
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
    #: Palm box depth below the palm surface, pad thickness on its face, and the motor
    #: housing cylinder filling the rest down to the flange (chosen: BH8-282 drawings show
    #: a ~ 90 mm wide body from the flange to the palm face).
    palm_depth: float = 0.04
    palm_pad_thickness: float = 0.002
    housing_radius: float = 0.045
    palm_mass: float = 0.5
    finger_link_mass: float = 0.07  # per link (chosen: BH8 total 1.2 kg)
    #: Torque limit at the proximal joint when closing [N m] (chosen: stalls at ~ 15 N at the tip).
    close_torque: float = 1.0
    #: Proximal closing speed [rad/s] (BH8-282 data sheet: 1.0 s open to close).
    close_speed: float = 2.4
    #: Proximal speed [rad/s] of a careful closing, the one that stops each finger at its
    #: first touch (paper: "carefully closing the fingers"; chosen: a quarter of close_speed,
    #: the BH8's velocity mode; at full speed the worm drive's reflected inertia knocks an
    #: 80 g tea box 1-1.5 cm away before the Nano17 reading stops the finger).
    careful_close_speed: float = 0.6


HAND = HandParams()

#: Sensor ids (index into every sensor array): 7 binary pads and 3 Nano17 fingertips.
SENSOR_NAMES: tuple[str, ...] = (
    "palm",
    "prox1",
    "prox2",
    "prox3",
    "dist1",
    "dist2",
    "dist3",
    "tip1",
    "tip2",
    "tip3",
)
N_SENSORS = len(SENSOR_NAMES)
PAD_SENSORS = tuple(range(7))
TIP_SENSORS = (7, 8, 9)
#: Sensor ids of each finger's links (proximal pad, distal pad, Nano17 tip), fingers 1-3.
FINGER_SENSORS: tuple[tuple[int, int, int], ...] = tuple(
    tuple(SENSOR_NAMES.index(f"{link}{i}") for link in ("prox", "dist", "tip")) for i in (1, 2, 3)
)


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
    #: home pose of the hand: palm above the table, pointing down (hand z = world -z). Every
    #: WRT starts here, so the open hand must clear the tallest object (cooler, 28 cm) wherever
    #: it stands: at 45 cm the fingertips hung at 26 cm and 20 of 100 cooler poses drawn at
    #: high uncertainty stopped the first sweep in free space (MuJoCo); at 55 cm none does.
    home_position: tuple[float, float, float] = (0.45, 0.0, 0.55)


WORLD = WorldParams()

#: Rotation (rotation vector, rad) of the home hand frame in world: π about x, so the
#: hand approaches straight down (hand z = world -z) with hand x = world x.
HOME_ROTVEC = (math.pi, 0.0, 0.0)


# ------------------------------------------------------------------ goal model
#: Bandwidth of the kernel that corrects a settling map near an offset, in goal tolerances
#: per axis (objects.Settling.outcome; chosen on 300 measured grasps per object, half for
#: fitting and half held out: 0.5 predicts "ends inside the goal region" best of 0.5, 1, 1.5
#: and the affine map alone, Brier score 0.017 / 0.039 / 0.049 for drill / teacup / pitcher
#: against 0.037 / 0.067 / 0.085).
SETTLING_KERNEL_BANDWIDTH = 0.5

# ------------------------------------------------------------ grasp holding
#: A reorientation lifts and turns the object only when its grasp holds it: it arrived and
#: at least this many fingers touch (MuJoCo: a reorientation stopped early on one fingertip
#: turned the giant teacup by 0.03 rad where the belief turned it 0.6; the pitcher's
#: reorientation grasp holds its handle with two fingertips)
REORIENT_MIN_FINGERS = 2


# ----------------------------------------------------------- geometric simulator
@dataclass(frozen=True)
class GeometricSimParams:
    """Resolution of the geometric sweep (chosen: well below the 2 mm fine grid after
    refinement)."""

    path_step: float = 0.005  # m between swept hand copies
    refine_iters: int = 5  # bisection steps inside the first colliding step (0.16 mm)
    close_step: float = 0.04  # rad between finger closing samples
    close_max: float = HAND.proximal_range[1]
    close_refine_iters: int = 3  # bisection steps inside the first touching closing step (5 mrad)
    #: Rotation-only path parts are sampled as if a point this far from the palm moved [m]
    #: (chosen: about the fingertip reach, so the fingertips move ≤ path_step per sample).
    rotation_sample_radius: float = 0.2
    #: A grasp (goal or reorientation WRT) whose guarded move stopped within this distance [m]
    #: of its end has arrived: it closes firmly and its observation reports no early contact,
    #: in the tables and in execution alike (chosen: handle grasps touch in their last cm;
    #: without this margin a pitcher grasp stopped by its palm 5 mm short reads as a failed
    #: grasp).
    grasp_arrival_tolerance: float = 0.02


GEOMSIM = GeometricSimParams()


# ------------------------------------------------------------------ sensing
@dataclass(frozen=True)
class SensingParams:
    """Guarded-move thresholds and sensor noise (chosen; Nano17 resolution ~ 3 mN, pads ~ 0.1 N)."""

    tip_force_threshold: float = 0.5  # N on a Nano17 stops a guarded move
    pad_force_threshold: float = 0.3  # N on a touch pad counts as contact
    #: External torque [N m] on any WAM joint that stops a guarded move: the arm's own
    #: collision detection (motor current against the dynamics model), which catches contacts
    #: on the hand's unsensed parts; the geometric model stops on those too. Chosen: about 2 N
    #: at the hand, well above the 0.2 N m noise below.
    arm_torque_threshold: float = 1.2
    nano17_force_noise: float = 0.01  # N, σ
    # Observation-level noise used by the geometric closed loop:
    progress_noise: float = 0.003  # m
    closure_noise: float = 0.03  # rad
    tip_point_noise: float = 0.002  # m
    sensor_flip: float = 0.02  # P(a binary sensor reading flips)


SENSING = SensingParams()


# ------------------------------------------------------------------ physics world
@dataclass(frozen=True)
class LinkInertia:
    """Mass properties of one rigid link: mass [kg], centre of mass [m] and inertia
    (Ixx, Iyy, Izz, Ixy, Ixz, Iyz) [kg m²] about the centre of mass, in the link's frame."""

    mass: float
    com: tuple[float, float, float]
    inertia: tuple[float, float, float, float, float, float]


#: WAM links 1-7 in their DH frames i (7-DOF wrist). Source: Barrett Technology,
#: "WAM Arm Inertial Specifications" (AC-02) / WAM_MassParams_AA-00; link 7 without a tool,
#: in Barrett's tool-plate frame (α7 = 0: z along the roll axis, at d7).
WAM_LINKS: tuple[LinkInertia, ...] = (
    LinkInertia(
        10.76768767,
        (-0.00443422, 0.12189039, -0.00066489),
        (0.13488033, 0.11328369, 0.09046330, -0.00213041, -0.00012485, 0.00068555),
    ),
    LinkInertia(
        3.87493756,
        (-0.00236983, 0.03105614, 0.01542114),
        (0.02140958, 0.01377875, 0.01558906, 0.00027172, 0.00002461, -0.00181920),
    ),
    LinkInertia(
        1.80228141,
        (-0.03825858, 0.20750770, 0.00003309),
        (0.05911077, 0.00324550, 0.05927043, -0.00249612, 0.00000738, -0.00001767),
    ),
    LinkInertia(
        2.40016804,
        (0.00498512, -0.00022942, 0.13271662),
        (0.01491672, 0.01482922, 0.00294463, 0.00001741, -0.00150604, -0.00002109),
    ),
    LinkInertia(
        0.12376019,
        (0.00008921, 0.00511217, 0.00435824),
        (0.00005029, 0.00007582, 0.00006270, 0.00000020, -0.00000005, -0.00000359),
    ),
    LinkInertia(
        0.41797364,
        (-0.00012262, -0.01703194, 0.02468336),
        (0.00055516, 0.00024367, 0.00045358, 0.00000061, -0.00000074, -0.00004590),
    ),
    LinkInertia(
        0.06864753,
        (-0.00007974, 0.00016313, -0.00323552),
        (0.00003773, 0.00003806, 0.00007408, -0.00000019, 0.0, 0.0),
    ),
)
#: Reflected motor rotor inertia at each WAM joint [kg m²] (same source) → MuJoCo armature.
WAM_ARMATURE: tuple[float, ...] = (
    0.20518962,
    0.18885672,
    0.18885672,
    0.03462804,
    0.00322537,
    0.00322537,
    0.00031753,
)


@dataclass(frozen=True)
class PhysicsParams:
    """The MuJoCo world (algorithm §2): control, motion and judging parameters."""

    #: Integration step = the WAM's 500 Hz control period [s] (notes: 2 ms steps).
    timestep: float = 0.002
    #: WAM joint PD gains [N m/rad], [N m s/rad]: libbarrett's default stiffness; its default
    #: damping (10, 20, 5, 2, 0.5, 0.5, 0.05) relies on the real arm's cable-drive friction,
    #: which the model lacks (damping ratio 0.07-0.28), so kv is raised to critical damping
    #: at the home posture (2 √(kp I), I from the model's joint-space inertia with the hand).
    arm_kp: tuple[float, ...] = (900.0, 2500.0, 600.0, 500.0, 50.0, 50.0, 8.0)
    arm_kv: tuple[float, ...] = (63.0, 124.0, 35.0, 29.0, 1.8, 3.3, 0.29)
    #: Guarded-move speeds near the object, between a WRT's poses (chosen: a careful
    #: approach, ~ 1/10 of the WAM's top speed) ...
    move_speed: float = 0.2  # m/s, palm
    turn_speed: float = 1.5  # rad/s, hand orientation
    #: ... and through free space: home to a WRT's first pose (still guarded) and back.
    free_speed: float = 0.5  # m/s
    free_turn_speed: float = 3.0  # rad/s
    #: Height [m] above the table the hand passes over a WRT's first pose on its way from home
    #: (execution.transit_via; home is at 0.55 m). Chosen above the tallest object but the
    #: cooler (28 cm, approached from above anyway) plus a hand's reach: the straight line from
    #: home to a side grasp's approach pose hit the pitcher and the drill with a finger for
    #: about 3 in 10 poses drawn at high uncertainty (MuJoCo; the tables assume it is free).
    transit_height: float = 0.40
    #: [m] how far the open hand backs out along its approach axis after a reorientation
    #: whose retrace is infeasible, before rising (chosen: the open fingers' reach past the
    #: knuckles, proximal 0.07 m + distal 0.057 m + the fingertip, docs/sources.md §2)
    back_out_distance: float = 0.15
    #: Joint speed limits of every move [rad/s] (chosen: about half the WAM's top speeds; its
    #: wrist joints, with lower transmission ratios, run about twice as fast as J1-J4).
    joint_speed: tuple[float, ...] = (1.5, 1.5, 1.5, 1.5, 3.0, 3.0, 3.0)
    #: Cartesian densification of a WRT's straight segments before IK [m] (brief: ~ 1 cm).
    path_step: float = 0.01
    #: Spacing of the path samples a feasibility map checks [m] (execution.executed_poses;
    #: chosen: reachability changes over centimetres, and a map costs ~ 0.08 s per sample).
    feasibility_step: float = 0.02
    #: Reflected motor inertia of every hand joint [kg m²] (chosen: the BH8's worm-geared
    #: drives reflect a large rotor inertia; it also keeps MuJoCo's inertia-scaled soft
    #: equality constraints, the spread and distal couplings, within ~ 1 mrad at the stall torque).
    hand_armature: float = 0.01
    #: Spread-joint PD [N m/rad], [N m s/rad] and its speed (BH8-282: 180° in ~ 0.5 s).
    spread_kp: float = 5.0
    spread_kv: float = 0.4
    spread_speed: float = 6.0  # rad/s
    #: Proximal position-servo gain [N m/rad] (chosen: saturates HAND.close_torque at 0.1 rad
    #: error) and damping (damping ratio ~ 0.6 with hand_armature).
    finger_kp: float = 10.0
    finger_kv: float = 0.4
    #: A stopped finger is held by the BarrettHand's non-backdrivable worm drive: modelled as a
    #: stiff servo [N m/rad] preloaded with the stall torque, up to a back-drive torque [N m]
    #: (chosen: 30× the closing stiffness, 5× the stall torque).
    brake_kp: float = 30.0
    brake_torque: float = 5.0
    #: A closing finger has stopped when its proximal speed stays below this [rad/s] ...
    stall_speed: float = 0.05
    #: ... for this long [s] (chosen: 10 control periods).
    stall_time: float = 0.02
    #: Closing gives up after this long [s] (chosen: 1.5 × the 1 s open-to-close time).
    close_timeout: float = 1.5
    #: Nano17 mass [kg] (ATI Nano17 data sheet: 9.07 g).
    nano17_mass: float = 0.00907
    #: Nano17 torque noise σ [N m] (chosen: ~ 1/64 N mm resolution, ×5 for vibration).
    nano17_torque_noise: float = 1e-4
    #: Touch-pad force noise σ [N] (chosen: a tenth of the pad threshold).
    pad_force_noise: float = 0.03
    #: Noise σ [N m] of the WAM's external joint-torque estimate (chosen: ~ 2 % of the
    #: shoulder's rated torque, typical of current-based estimates).
    arm_torque_noise: float = 0.2
    #: Sliding friction of the hand's rubber-coated links (chosen: rubber on plastic/cardboard).
    hand_friction: float = 0.8
    #: Judging: lift height [m], lift speed [m/s] and hold time [s] (requirement: hold 2 s).
    lift_height: float = 0.10
    lift_speed: float = 0.25
    hold_time: float = 2.0
    #: Reorientation: lift before rotating [m] (chosen: clears the table by ~ 2 cm).
    reorient_lift: float = 0.02
    #: Objects settle this long after placement [s] (chosen).
    settle_time: float = 0.2


PHYSICS = PhysicsParams()


#: WAM drive ratios, motor turns per joint turn (libbarrett config/wam7w.conf, j2mp; J2/J3 and
#: J5/J6 are differentials, the magnitudes of their diagonal terms used: motor 3 turns 16.8155
#: times per turn of J3) and motor encoder counts per turn (Barrett WAM User's Manual D1001,
#: FAQ: CTS 40960 for the optical encoders).
WAM_DRIVE_RATIOS = (42.0, 28.25, 16.8155, 18.0, 9.7, 9.7, 14.93)
WAM_ENCODER_COUNTS = 40960
#: WAM joint servo output limits [N m], gravity compensation apart (libbarrett
#: config/wam7w.conf: control_signal_limit of the joint position PID).
WAM_TORQUE_LIMIT = (25.0, 20.0, 15.0, 15.0, 5.0, 5.0, 5.0)


__all__ = [name for name in dir() if name.isupper() or name.endswith("Params")] + ["LinkInertia"]
