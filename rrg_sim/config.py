"""The simulated worlds: how far each departs from the robot's models (rrg_models.config), with
the source of every number. The planner knows a profile's distributions, never a trial's draw."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from rrg_models.config import WAM_DRIVE_RATIOS, WAM_ENCODER_COUNTS, WAM_TORQUE_LIMIT


# ------------------------------------------------------------------ world profiles
@dataclass(frozen=True)
class WorldProfile:
    """How far the simulated world departs from the planner's models (rrg_sim.physics.realism).

    Per-trial draws are fixed for a whole trial; the planner knows these distributions, never
    a trial's draw. Every default is "off": the nominal world, whose robot is its own model.
    """

    name: str = "nominal"
    #: σ of each WAM joint's zero offset (calibration error) [rad], drawn per trial: the
    #: encoders read q_true + offset, so the servos and the forward kinematics are off by it.
    joint_offset_sigma: float = 0.0
    #: Resolution of each WAM joint reading [rad] (0: exact).
    joint_resolution: tuple[float, ...] = (0.0,) * 7
    #: Torque limit of each WAM joint servo's output [N m], gravity compensation apart (None:
    #: unlimited).
    arm_torque_limit: tuple[float, ...] | None = None
    #: Sample period of the touch pads [s] (0: every control period); a sample is held until
    #: the next one.
    pad_period: float = 0.0
    #: P(a touched pad stays silent for a whole guarded move and its closing).
    pad_miss: float = 0.0
    #: P(a pad fires falsely during a guarded move), for one sample at a uniform instant.
    pad_false_alarm: float = 0.0
    #: Nano17 noise σ per axis [N] and [N m]; None: the config's SENSING / PHYSICS values.
    nano17_force_noise: float | None = None
    nano17_torque_noise: float | None = None
    #: Range of the object's sliding friction coefficient against the table, uniform per trial
    #: (None: the catalogue's value against the table's).
    friction_range: tuple[float, float] | None = None
    #: Range of the distance [m] of the object's centre of mass from its modelled one, uniform
    #: per trial, in a uniformly drawn horizontal direction.
    com_offset_range: tuple[float, float] = (0.0, 0.0)
    #: σ of the table top's height about its modelled height [m], per trial.
    table_height_sigma: float = 0.0

    @property
    def uncertain_height(self) -> bool:
        """Whether the hand's height over the table is uncertain (calibration error or a table
        height draw): the robot then touches the table before a goal grasp
        (rrg_sim.table_touch)."""
        return self.joint_offset_sigma > 0 or self.table_height_sigma > 0


NOMINAL = WorldProfile()


#: The realistic world: a real WAM, BarrettHand and Nano17s as their makers and the literature
#: describe them. Sources per field; where no source gives a number, the nearest one is named.
#: Not modelled, for want of any published figure: cable-drive compliance, the gravity model's
#: residual, unit-to-unit object mass, Nano17 bias drift (the sensors are tared before every
#: guarded move), and sensing latency beyond the sample period (the Net F/T's 288 µs, ATI,
#: is below one control period).
REALISTIC = WorldProfile(
    name="realistic",
    # A WAM's offsets are a fixed bias of its zero calibration, not a per-start error: its
    # quasi-absolute motor encoders restore the calibrated zero at every start-up within half
    # a motor turn (Barrett, "WAM Calibration" wiki; libbarrett low_level_wam-inl.h), and the
    # zero itself is set by eye against scribe marks (libbarrett config/calibration.conf,
    # programs/zerocal.cpp). A trial's draw stands for one calibrated robot. No study gives
    # the residual; it is sized to the nearest published figure, a 6-DOF arm's 9 mm mean
    # position error before kinematic calibration (Joubair, Zhao, Bigras, Bonev, "Use of a
    # Force-Torque Sensor for Self-Calibration of a 6-DOF Medical Robot", Sensors 16(6) 798,
    # 2016), below the "nearly six centimeters" at the hand reported for DARPA ARM-S's cable-
    # driven Barrett arms with cable stretch and gravity included (M. Klingensmith's account of
    # the ARM-S arms, matthewklingensmith.com/?p=87; an informal source).
    # On the WAM, 1 mrad on every joint moves the palm 0.88 mm on average over home and the ten
    # goal grasps (forward kinematics, 2000 draws each), so 9 mm needs 10 mrad.
    joint_offset_sigma=0.010,
    joint_resolution=tuple(2 * math.pi / (WAM_ENCODER_COUNTS * n) for n in WAM_DRIVE_RATIOS),
    arm_torque_limit=WAM_TORQUE_LIMIT,
    # Barrett's ROS 2 driver publishes the tactile states at 50 Hz (docs/sources.md
    # §6); Barrett recommends ≥ 50 Hz for the hand (wiki,
    # Hand/282/ControlModes).
    pad_period=0.02,
    # No published miss or false-alarm rate for binary contact pads was found (nor BarrettHand
    # tactile cell noise); the rates the estimator's likelihood assumes are used
    # (rrg_estimator.config.LIKELIHOOD: p_detect 0.90, p_false_alarm 0.04).
    pad_miss=0.10,
    pad_false_alarm=0.04,
    # ATI Nano17 SI-12-0.12 resolution: 1/320 N, 1/64 N mm (ATI, "F/T Sensor: Nano17").
    nano17_force_noise=1.0 / 320.0,
    nano17_torque_noise=1.0 / 64.0 * 1e-3,
    # Static friction measured for seven household objects, 0.23 (a can) to 1.1 (an eraser)
    # (thesis "Development of Grasps", Table 4.1, object characteristics; the nearest source:
    # the counter-surface is not stated).
    friction_range=(0.23, 1.1),
    # Same table: centre-of-mass offsets from the geometric centre of 2 to 11.5 mm.
    com_offset_range=(0.002, 0.0115),
    # Kinect depth noise grows with the square of range to about 4 cm at 5 m (Khoshelham and
    # Oude Elberink, "Accuracy and Resolution of Kinect Depth Data for Indoor Mapping
    # Applications", Sensors 12(2) 1437, 2012): 2.3 mm at the 1.2 m from a head camera to
    # the table.
    table_height_sigma=0.0023,
)


#: The world profiles by name (``--world``).
WORLD_PROFILES: dict[str, WorldProfile] = {p.name: p for p in (NOMINAL, REALISTIC)}

#: The WorldProfile fields a profile spec may set (world_profile): the numbers whose
#: sensitivity the results show.
PROFILE_KNOBS = ("joint_offset_sigma", "pad_miss", "pad_false_alarm", "table_height_sigma")


def world_profile(spec: str | WorldProfile) -> WorldProfile:
    """The profile a spec names: a WORLD_PROFILES name, or one with some PROFILE_KNOBS set,
    e.g. ``realistic:joint_offset_sigma=0.0025,pad_false_alarm=0.01`` (named by the spec).
    ValueError, naming what is valid, for anything else."""
    if isinstance(spec, WorldProfile):
        return spec
    base, _, knobs = spec.partition(":")
    if base not in WORLD_PROFILES:
        raise ValueError(f"unknown world profile {base!r}; valid: {sorted(WORLD_PROFILES)}")
    values = {}
    for item in filter(None, knobs.split(",")):
        key, _, value = item.partition("=")
        if key not in PROFILE_KNOBS:
            raise ValueError(f"world profile {spec!r}: {key!r} is not one of {PROFILE_KNOBS}")
        try:
            values[key] = float(value)
        except ValueError:
            raise ValueError(
                f"world profile {spec!r}: {key} needs a number, got {value!r}"
            ) from None
        if values[key] < 0:
            raise ValueError(f"world profile {spec!r}: {key} must be >= 0")
    return replace(WORLD_PROFILES[base], name=spec, **values) if values else WORLD_PROFILES[base]


def world_spec(spec: str) -> str:
    """``spec`` itself if it names a world profile (world_profile), for argparse's ``type``;
    argparse.ArgumentTypeError with world_profile's reason otherwise."""
    import argparse

    try:
        world_profile(spec)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return spec
