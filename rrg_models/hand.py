"""BarrettHand BH8-282 geometry: one kinematic tree shared by the geometric and physics simulators.

All dimensions come from ``config.HAND``. Frames (see config): the tree root ``palm`` is the
hand frame, +z out of the palm. Each finger has a *base* frame whose local +y points radially
out from the palm centre and +z along the hand's approach axis; its proximal and distal
hinges turn about local +x, 0 = finger straight along +z, positive closes the finger inward
(its tip moves toward -y of the base frame, i.e. toward the palm axis).

Bodies (parent → child): palm → f{1,2}_base (spread hinge about z at (±0.025, 0, 0.0415))
→ f{i}_prox (knuckle hinge 0.05 m out radially at z = 0.0754) → f{i}_dist (hinge at the
proximal link's end, coupled: distal = HAND.distal_coupling × proximal) → f{i}_tip (welded:
the Nano17 fingertip). Finger 3's base is welded to the palm at its knuckle (0, -0.05, 0.0754).
Finger 1's spread hinge turns about -z and finger 2's about +z, so one spread angle s moves
them symmetrically: at s = 0 both sit on +y closing toward -y; at s = π/2 finger 1 is on +x
and finger 2 on -x, closing toward each other.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.spatial.transform import Rotation

from rrg_models.config import HAND, SENSOR_NAMES

FINGERS = (1, 2, 3)
LINKS = ("prox", "dist", "tip")
IDENTITY_QUAT = (1.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class GeomSpec:
    """One collision/visual geom in its body frame (MuJoCo semantics for ``size``).

    kind: box (half sizes x,y,z) | capsule / cylinder (radius, half length along z) |
    sphere (radius,).
    sensor: index into config.SENSOR_NAMES, or -1 for an unsensed part.
    """

    name: str
    kind: str
    size: tuple[float, ...]
    pos: tuple[float, float, float]
    quat: tuple[float, float, float, float] = IDENTITY_QUAT
    sensor: int = -1


@dataclass(frozen=True)
class JointSpec:
    """A hinge joint of a body (about ``axis`` in the body frame, through its origin).

    coupled_to: (driving joint name, ratio) when this joint follows another one
    (the distal joints: angle = ratio × proximal angle).
    """

    name: str
    axis: tuple[float, float, float]
    range: tuple[float, float]
    coupled_to: tuple[str, float] | None = None


@dataclass(frozen=True)
class BodySpec:
    """A body of the hand tree: pose relative to its parent at zero joint angles (quat wxyz)."""

    name: str
    parent: str | None
    pos: tuple[float, float, float]
    quat: tuple[float, float, float, float]
    joint: JointSpec | None
    geoms: tuple[GeomSpec, ...]


def sensor_id(name: str) -> int:
    """Index of a sensor name in config.SENSOR_NAMES."""
    return SENSOR_NAMES.index(name)


def _palm_body() -> BodySpec:
    h = HAND
    hx, hy = h.palm_half_extent
    pad_z = h.palm_surface_z - h.palm_pad_thickness / 2
    box_top = h.palm_surface_z - h.palm_pad_thickness
    box_bottom = h.palm_surface_z - h.palm_depth
    geoms = (
        GeomSpec(
            "palm",
            "box",
            (hx, hy, (box_top - box_bottom) / 2),
            (0.0, 0.0, (box_top + box_bottom) / 2),
        ),
        GeomSpec(
            "palm_pad",
            "box",
            (hx, hy, h.palm_pad_thickness / 2),
            (0.0, 0.0, pad_z),
            sensor=sensor_id("palm"),
        ),
        GeomSpec(
            "housing", "cylinder", (h.housing_radius, box_bottom / 2), (0.0, 0.0, box_bottom / 2)
        ),
    )
    return BodySpec("palm", None, (0.0, 0.0, 0.0), IDENTITY_QUAT, None, geoms)


def _finger_bodies(i: int) -> list[BodySpec]:
    """Base, proximal, distal and tip bodies of finger i (1, 2, 3)."""
    h = HAND
    f = f"f{i}"
    if i == 3:
        x3, y3 = h.finger3_xy
        # Welded at the knuckle, rotated π about z so its +y points radially out (hand -y).
        base = BodySpec(f"{f}_base", "palm", (x3, y3, h.knuckle_z), (0.0, 0.0, 0.0, 1.0), None, ())
        knuckle = (0.0, 0.0, 0.0)
    else:
        x = h.spread_axis_x if i == 1 else -h.spread_axis_x
        axis_z = -1.0 if i == 1 else 1.0
        spread = JointSpec(f"{f}_spread", (0.0, 0.0, axis_z), h.spread_range)
        base = BodySpec(f"{f}_base", "palm", (x, 0.0, h.spread_axis_z), IDENTITY_QUAT, spread, ())
        knuckle = (0.0, h.knuckle_radius, h.knuckle_z - h.spread_axis_z)
    w, t = h.finger_width / 2, h.finger_thickness / 2
    dist_box = h.distal_length - h.tip_length
    tip_half = (
        h.tip_length - h.tip_radius
    ) / 2  # half the cylinder part (the near cap sits inside the link)
    prox = BodySpec(
        f"{f}_prox",
        f"{f}_base",
        knuckle,
        IDENTITY_QUAT,
        JointSpec(f"{f}_prox", (1.0, 0.0, 0.0), h.proximal_range),
        (
            GeomSpec(
                f"{f}_prox",
                "box",
                (w, t, h.proximal_length / 2),
                (0.0, 0.0, h.proximal_length / 2),
                sensor=sensor_id(f"prox{i}"),
            ),
        ),
    )
    dist = BodySpec(
        f"{f}_dist",
        f"{f}_prox",
        (0.0, 0.0, h.proximal_length),
        IDENTITY_QUAT,
        JointSpec(
            f"{f}_dist",
            (1.0, 0.0, 0.0),
            h.distal_range,
            coupled_to=(f"{f}_prox", h.distal_coupling),
        ),
        (
            GeomSpec(
                f"{f}_dist",
                "box",
                (w, t, dist_box / 2),
                (0.0, 0.0, dist_box / 2),
                sensor=sensor_id(f"dist{i}"),
            ),
        ),
    )
    # The Nano17 tip: a capsule whose far cap ends exactly at the distal link's length.
    tip = BodySpec(
        f"{f}_tip",
        f"{f}_dist",
        (0.0, 0.0, dist_box),
        IDENTITY_QUAT,
        None,
        (
            GeomSpec(
                f"{f}_tip",
                "capsule",
                (h.tip_radius, tip_half),
                (0.0, 0.0, h.tip_length - h.tip_radius - tip_half),
                sensor=sensor_id(f"tip{i}"),
            ),
        ),
    )
    return [base, prox, dist, tip]


@lru_cache(maxsize=1)
def hand_tree() -> tuple[BodySpec, ...]:
    """All hand bodies, parents before children: palm, then per finger base/prox/dist/tip."""
    bodies = [_palm_body()]
    for i in FINGERS:
        bodies += _finger_bodies(i)
    return tuple(bodies)


def hand_geoms() -> list[tuple[str, GeomSpec]]:
    """(body name, geom) for every hand geom, in tree order."""
    return [(b.name, g) for b in hand_tree() for g in b.geoms]


def _axis_rotation(axis, angle: np.ndarray) -> np.ndarray:
    """(…,4,4) rotations by angle (…) about a unit axis through the origin."""
    angle = np.asarray(angle, dtype=float)
    rotvec = np.asarray(axis, dtype=float) * angle.reshape(-1, 1)
    T = np.zeros((angle.size, 4, 4))
    T[:, :3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:, 3, 3] = 1.0
    return T.reshape(angle.shape + (4, 4))


def _offset(body: BodySpec) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(body.quat, scalar_first=True).as_matrix()
    T[:3, 3] = body.pos
    return T


def joint_angles(spread, proximal) -> dict[str, np.ndarray]:
    """Every joint's angle (…) for a spread (…) and proximal angles (…,3); distal coupled."""
    proximal = np.asarray(proximal, dtype=float)
    batch = proximal.shape[:-1]
    spread = np.broadcast_to(np.asarray(spread, dtype=float), batch)
    q = {"f1_spread": spread, "f2_spread": spread}
    for k, i in enumerate(FINGERS):
        q[f"f{i}_prox"] = proximal[..., k]
        q[f"f{i}_dist"] = np.clip(HAND.distal_coupling * proximal[..., k], *HAND.distal_range)
    return q


def body_poses(spread, proximal) -> dict[str, np.ndarray]:
    """Hand-frame poses (…,4,4) of every body for spread (…) and proximal angles (…,3)."""
    return body_poses_at(joint_angles(spread, proximal))


def body_poses_at(q: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Hand-frame poses (…,4,4) of every body at every joint's angle (…) [rad] (joint_angles'
    keys: a measured distal angle, say, instead of its coupling)."""
    batch = np.shape(q["f1_spread"])
    poses: dict[str, np.ndarray] = {}
    for body in hand_tree():
        parent = (
            np.broadcast_to(np.eye(4), batch + (4, 4))
            if body.parent is None
            else poses[body.parent]
        )
        T = parent @ _offset(body)
        if body.joint is not None:
            T = T @ _axis_rotation(body.joint.axis, q[body.joint.name])
        poses[body.name] = T
    return poses


def finger_link_poses(spread, proximal) -> np.ndarray:
    """Hand-frame poses (…, 3 fingers, 3 links [prox, dist, tip], 4, 4) of the finger link bodies.

    spread: (…) or scalar [rad]; proximal: (…,3) proximal angles [rad] (distal coupled).
    """
    poses = body_poses(spread, proximal)
    return np.stack(
        [np.stack([poses[f"f{i}_{link}"] for link in LINKS], axis=-3) for i in FINGERS], axis=-4
    )


def geom_local_pose(g: GeomSpec) -> np.ndarray:
    """(4,4) pose of a geom in its body frame."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(g.quat, scalar_first=True).as_matrix()
    T[:3, 3] = g.pos
    return T


def hand_geoms_world(T_hand: np.ndarray, spread, proximal) -> list[tuple[GeomSpec, np.ndarray]]:
    """Every hand geom with its (…,4,4) pose in the frame of T_hand (…,4,4) (e.g. ``world``)."""
    poses = body_poses(spread, proximal)
    return [(g, T_hand @ poses[body] @ geom_local_pose(g)) for body, g in hand_geoms()]


def fingertip_points(spread, proximal) -> np.ndarray:
    """(…,3,3) hand-frame position of each fingertip's far end (the cap's apex)."""
    tips = finger_link_poses(spread, proximal)[..., 2, :, :]
    apex = np.array([0.0, 0.0, HAND.tip_length, 1.0])
    return (tips @ apex)[..., :3]


def geom_mjcf(g: GeomSpec, extra: str = "") -> str:
    """A MuJoCo ``<geom>`` element for g (``extra``: more attributes, e.g. contype/rgba)."""
    f = lambda v: " ".join(f"{x:.6g}" for x in v)
    return (
        f'<geom name="{g.name}" type="{g.kind}" size="{f(g.size)}" pos="{f(g.pos)}" '
        f'quat="{f(g.quat)}" {extra}/>'
    )


def fingertip_lowest_z(T_hand: np.ndarray, spread: float, proximal, finger: int) -> float:
    """Height [m] in the frame of T_hand (4,4) (e.g. ``world``) of the lowest point of finger
    ``finger``'s (1-3) Nano17 tip capsule, the hand at (spread, proximal (3,))."""
    name = f"f{finger}_tip"
    for g, T in hand_geoms_world(T_hand, spread, np.asarray(proximal, dtype=float)):
        if g.name == name:
            radius, half = g.size
            ends = T[:3, 3] + np.outer([-half, half], T[:3, 2])
            return float(ends[:, 2].min() - radius)
    raise ValueError(f"no fingertip {name}")
