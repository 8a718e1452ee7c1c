"""WRT construction from an object's primitives (algorithm §4; paper, "Generating WRTs").

* Goal WRTs are hand-designed by a hand orientation and a line the hand's approach axis
  follows through the object (``line_grasp_wrt``); the final pose is where the hand first
  comes within a margin of the object or the table.
* Information-gathering WRTs are generated: the pinches of ``surface_pairs`` (fingers on
  nearly parallel, opposing, roughly vertical surfaces), approached from above; two or three
  diverse, collision-free ones are kept, deterministically. An object may add hand-designed
  pinches (``designed_pinch_wrt``) where the generated ones miss what matters (a handle).
* The sweep moves the hand low over the table across the object's whole uncertainty region.
* Reorientation WRTs grasp from above at the pinch nearest the object's centre and turn it.

Every first pose keeps ``APPROACH_CLEARANCE`` from the object's bounding box.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from functools import lru_cache

import numpy as np
from scipy.spatial.transform import Rotation

from rrg_models.objects.clearance import (
    backoff_until_clear,
    free_travel,
    hand_points,
    scene,
    translate,
)
from rrg_models.objects.primitives import Primitive, union_bounds
from rrg_models.objects.surface_pairs import DIVERSE_DISTANCE, Pinch, pinch_candidates
from rrg_models.poses import make_pose
from rrg_models.wrt import WRT

#: Hand clearance from the object's bounding box at every WRT's first pose [m] (brief: ≥ 10 cm).
APPROACH_CLEARANCE = 0.10
#: Final-pose margins [m]: to the object (palm ~5 mm off) and to the table (fingertips).
OBJECT_MARGIN = 0.005
TABLE_MARGIN = 0.01
#: Info pinches: how many, and how deep [m] the fingertips must reach below the top of the
#: surfaces' shared height for a pinch to count.
N_INFO = 3
FINGER_DEPTH = 0.015
DIVERSE_ANGLE = np.radians(30.0)  # pinch axes this far apart (mod π) count as different
#: Sweep (paper: "sweeps horizontally across the entire workspace"): fingertip height [m],
#: spread [rad] (fingers 1, 2 lead the palm by ~1 cm and widen the swept band), and the
#: object offset [m] along the sweep it must still hit (3σ of the high uncertainty, 15 cm).
SWEEP_TIP_HEIGHT = 0.03
SWEEP_SPREAD = 0.6
SWEEP_REACH = 0.15
#: Commanded rotation of the reorientation WRTs [rad] (chosen: ~ 2σ of the high θ uncertainty).
REORIENT_ANGLE = 0.6


def top_down_rotation(yaw: float) -> Rotation:
    """Hand pointing straight down (hand z = object -z), hand x at ``yaw`` [rad] about z,
    so hand y = (sin yaw, -cos yaw, 0): finger 3 on its -y side, fingers 1, 2 on +y."""
    return Rotation.from_euler("ZX", [yaw, np.pi])


def side_rotation(pitch: float = 0.0, roll: float = 0.0, yaw: float = 0.0) -> Rotation:
    """Hand approaching horizontally along the object's +x (turned by ``yaw`` about z),
    tilted down by ``pitch`` [rad], rolled by ``roll`` about its approach axis. At roll 0,
    hand x points up and hand y = object -y (finger 3 on the +y side); roll π/2 puts finger 3
    on top."""
    base = Rotation.from_matrix(np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]]))
    return Rotation.from_euler("ZY", [yaw, pitch]) * base * Rotation.from_euler("z", roll)


def line_grasp_poses(
    parts: Sequence[Primitive],
    rotation: Rotation,
    through,
    spread: float = 0.0,
    preclose: float = 0.0,
    standoff: float = 0.0,
) -> np.ndarray:
    """(2,4,4) approach and final hand poses for a grasp along a straight line.

    The hand keeps ``rotation`` and moves along its approach axis (hand z) on the line through
    ``through`` (3,) [m]. It starts where it is ``APPROACH_CLEARANCE`` from the object's
    bounding box and stops ``standoff`` [m] before it would first come within OBJECT_MARGIN of
    the object or TABLE_MARGIN of the table.
    """
    points = hand_points(spread, preclose)
    R = rotation.as_matrix()
    approach = R[:, 2]
    bounds = union_bounds(parts)
    on_line = make_pose(np.asarray(through, dtype=float), rotation)
    start = backoff_until_clear(bounds, on_line, -approach, points, APPROACH_CLEARANCE)
    reach = float(np.linalg.norm(start[:3, 3] - on_line[:3, 3])) + 0.3
    checker = scene(tuple(parts), float(spread), float(preclose), OBJECT_MARGIN, TABLE_MARGIN)
    travel = free_travel(checker, start, approach, reach)
    final = translate(start, (travel - standoff) * approach)
    return np.stack([start, final])


def line_grasp_wrt(
    parts: Sequence[Primitive],
    rotation: Rotation,
    through,
    spread: float = 0.0,
    preclose: float = 0.0,
    standoff: float = 0.0,
    description: str = "",
    name: str = "goal",
) -> WRT:
    """The goal WRT ``name`` of a hand-designed grasp along a line (see ``line_grasp_poses``).

    Its closure angles are not informative (WRT.closure_informative False): a firm grasp
    closing on a light object pulls it to where the fingers balance, so physics reads nearly
    the same closures wherever the object was. MuJoCo, Δx = -8, 0, +8 mm: the pitcher's
    fingers 1, 2 close to 0.95, 0.94, 0.91 rad where the geometric model (nothing moves)
    predicts 0.84, 0.70, 0.54; the cooler's to 0.33, 0.30, 0.31 for 0.30, 0.24, 0.18; the tea
    box's to 0.18, 0.16, 0.16 for 0.15, 0.09, 0.03 (likewise the other objects). Read as
    geometry, every closure votes for one offset and biases the belief (pitcher: x by ~8 mm,
    which its settling map turns into θ). Per-WRT physics vs geometric closure RMS
    (rrg_sim.physics.agreement --offsets 12 --json): 0.06-0.24 rad for the goal grasps,
    ≤ 0.015 rad for every info grasp.
    """
    poses = line_grasp_poses(parts, rotation, through, spread, preclose, standoff)
    meta = {"through": tuple(float(v) for v in through), "standoff": standoff}
    return WRT(
        name,
        "goal",
        poses,
        spread=spread,
        preclose=preclose,
        description=description,
        closure_informative=False,
        meta=meta,
    )


def top_down_poses(
    parts: Sequence[Primitive], pinch: Pinch, preclose: float = 0.0
) -> np.ndarray | None:
    """(2,4,4) approach and final poses of a pinch from above, or None when the descent
    collides before the fingertips reach FINGER_DEPTH below the top of the shared height."""
    points = hand_points(pinch.spread, preclose)
    top = union_bounds(parts)[1, 2]
    reach = points[
        :, 2
    ].max()  # hand z = object -z: the lowest hand point is this far below the origin
    start = make_pose(
        [pinch.centre[0], pinch.centre[1], top + APPROACH_CLEARANCE + reach], pinch.rotation()
    )
    down = np.array([0.0, 0.0, -1.0])
    checker = scene(tuple(parts), float(pinch.spread), float(preclose), OBJECT_MARGIN, TABLE_MARGIN)
    travel = free_travel(checker, start, down, start[2, 3])
    final = translate(start, travel * down)
    if final[2, 3] - reach > pinch.centre[2] - FINGER_DEPTH:
        return None
    return np.stack([start, final])


def _axis_angle(a: Pinch, b: Pinch) -> float:
    """Angle [rad] between two pinch axes, ignoring their sense."""
    return float(np.arccos(np.clip(abs(a.axis @ b.axis), 0.0, 1.0)))


def _similar(a: Pinch, b: Pinch) -> bool:
    return (
        _axis_angle(a, b) < DIVERSE_ANGLE
        and np.linalg.norm(a.centre[:2] - b.centre[:2]) < DIVERSE_DISTANCE
    )


@lru_cache(maxsize=64)
def _info_pinches(parts: tuple[Primitive, ...]) -> tuple[tuple[Pinch, np.ndarray], ...]:
    """Greedy diverse choice: first pinches across new directions, then at new places."""
    candidates = pinch_candidates(parts)
    chosen: list[tuple[Pinch, np.ndarray]] = []

    def new_direction(pinch: Pinch) -> bool:
        return all(_axis_angle(pinch, c) >= DIVERSE_ANGLE for c, _ in chosen)

    def new_place(pinch: Pinch) -> bool:
        return not any(_similar(pinch, c) for c, _ in chosen)

    for accept in (new_direction, new_place):
        for pinch in candidates:
            if len(chosen) == N_INFO:
                return tuple(chosen)
            if accept(pinch):
                poses = top_down_poses(parts, pinch)
                if poses is not None:
                    chosen.append((pinch, poses))
    return tuple(chosen)


def _describe(pinch: Pinch) -> str:
    fingers = "finger 3 against fingers 1+2" if pinch.spread == 0.0 else "finger 2 against finger 1"
    return (
        f"top-down pinch, {fingers}, across {100 * pinch.separation:.1f} cm along "
        f"({pinch.axis[0]:+.2f}, {pinch.axis[1]:+.2f}) at ({100 * pinch.centre[0]:+.1f}, "
        f"{100 * pinch.centre[1]:+.1f}) cm"
    )


def _pinch_meta(pinch: Pinch) -> dict:
    return {
        "pinch_axis": tuple(pinch.axis[:2]),
        "pinch_centre": tuple(pinch.centre),
        "separation": pinch.separation,
    }


def info_wrts(parts: Sequence[Primitive]) -> tuple[WRT, ...]:
    """Up to N_INFO diverse top-down pinch WRTs ("info1", …) generated from the primitives."""
    return tuple(
        WRT(
            f"info{k + 1}",
            "info",
            poses,
            spread=pinch.spread,
            description=_describe(pinch),
            meta=_pinch_meta(pinch),
        )
        for k, (pinch, poses) in enumerate(_info_pinches(tuple(parts)))
    )


def designed_pinch_wrt(parts: Sequence[Primitive], name: str, pinch: Pinch, what: str) -> WRT:
    """A hand-designed top-down pinch info WRT (``what`` names what it pinches); ValueError
    when its descent collides (``top_down_poses``)."""
    poses = top_down_poses(parts, pinch)
    if poses is None:
        raise ValueError(f"{name}: the top-down pinch of {what} collides on the way down")
    return WRT(
        name,
        "info",
        poses,
        spread=pinch.spread,
        description=f"{_describe(pinch)}: {what}",
        meta=_pinch_meta(pinch),
    )


def reorient_wrts(
    parts: Sequence[Primitive], angle: float = REORIENT_ANGLE, away_from: np.ndarray | None = None
) -> tuple[WRT, ...]:
    """Two reorientation WRTs ("reorient_ccw" +angle, "reorient_cw" -angle): the collision-free
    top-down pinch nearest the object's centre, then a turn about the object's vertical axis.
    ``away_from``: a horizontal direction (x, y) in the object frame, e.g. towards a handle;
    the pinch is then the one whose centre lies most opposite it, finger 3 on its inner side
    (on a ring every wall pinch is equally central)."""
    if away_from is None:

        def key(p: Pinch) -> float:
            return round(float(np.hypot(*p.centre[:2])), 4)
    else:
        away = np.asarray(away_from, dtype=float)[:2] / np.linalg.norm(away_from[:2])

        def key(p: Pinch) -> float:
            outward = p.axis[:2] @ p.centre[:2] > 0.0
            return round(float(p.centre[:2] @ away / np.hypot(*p.centre[:2])), 4) + (
                0.0 if outward else 10.0
            )

    candidates = sorted(pinch_candidates(parts), key=key)
    for pinch in candidates:
        poses = top_down_poses(parts, pinch)
        if poses is not None:
            return tuple(
                WRT(
                    name,
                    "reorient",
                    poses,
                    spread=pinch.spread,
                    reorient_angle=sign * angle,
                    description=f"{_describe(pinch)}, then turn {sign * angle:+.2f} rad",
                    meta=_pinch_meta(pinch),
                )
                for name, sign in (("reorient_ccw", 1.0), ("reorient_cw", -1.0))
            )
    raise ValueError("no collision-free top-down pinch for a reorientation grasp")


def sweep_wrt(parts: Sequence[Primitive]) -> WRT:
    """ "sweep": the hand, fingers down and spread, fingertips SWEEP_TIP_HEIGHT over the table,
    crosses the object's region along the object's -y, from where an object SWEEP_REACH
    toward the start would still be ahead to where one SWEEP_REACH the other way is passed."""
    bounds = union_bounds(parts)
    rotation = top_down_rotation(0.0)  # hand y = object -y: fingers 1, 2 lead
    points = hand_points(SWEEP_SPREAD) @ rotation.as_matrix().T
    reach = -points[:, 2].min()
    lead, trail = -points[:, 1].min(), points[:, 1].max()
    x = bounds[:, 0].mean()
    y_start = bounds[1, 1] + SWEEP_REACH + lead + OBJECT_MARGIN
    y_end = bounds[0, 1] - SWEEP_REACH - trail - OBJECT_MARGIN
    z_low = SWEEP_TIP_HEIGHT + reach
    z_high = bounds[1, 2] + APPROACH_CLEARANCE + reach
    positions = np.array([[x, y_start, z_high], [x, y_start, z_low], [x, y_end, z_low]])
    poses = make_pose(positions, Rotation.concatenate([rotation] * 3))
    return WRT(
        "sweep",
        "info",
        poses,
        spread=SWEEP_SPREAD,
        description=f"horizontal sweep along -y, fingertips {100 * SWEEP_TIP_HEIGHT:.0f} cm "
        f"over the table, from y = {100 * y_start:+.0f} to {100 * y_end:+.0f} cm",
        meta={"sweep_reach": SWEEP_REACH},
    )


#: A goal grasp whose approach axis (hand z) points down by less than this cosine is a side
#: grasp (chosen: 45°; the paper objects' side grasps are tilted 0.15 rad, their top-down
#: grasps point straight down).
SIDE_GRASP_COS = np.cos(np.pi / 4)


def probe_name(goal_name: str) -> str:
    """The name of a goal grasp's probe: goal_probe for the goal grasp "goal", <name>_probe
    for another of the object's goal grasps."""
    return "goal_probe" if goal_name == "goal" else f"{goal_name}_probe"


def goal_probe_wrt(goal: WRT) -> WRT | None:
    """For a side goal grasp, an information-gathering WRT in its own posture: the goal grasp's
    path, closing carefully (each finger stops at its first touch) instead of firmly. Its
    readings see the object from the posture the goal grasp will have, so the robot's
    calibration error, which differs between a top-down posture and a side one, cancels
    between them (rrg_sim.posture_calibration). None for a top-down goal grasp, whose
    posture the top-down information grasps already share."""
    approach = goal.poses[-1][:3, 2]
    if -approach[2] >= SIDE_GRASP_COS:
        return None
    return replace(
        goal,
        name=probe_name(goal.name),
        kind="info",
        closure_informative=True,
        description="the goal grasp's path, closing carefully: a reading in its posture",
        meta={"probe_of": goal.name},
    )
