"""The geometric simulator: predicted observations of a WRT, kinematically (algorithm §2, §5).

The hand sweeps along the WRT's path until it first touches the object or the table, then
each finger closes until it touches something or reaches its limit. Only positions are
computed (no dynamics): the object never moves. Collisions come from MuJoCo on a small
*probe* model per object and WRT:

* the table top as the plane z = 0 (static, in ``world``);
* the object as a free body holding its collision primitives (its qpos sets the pose w);
* the hand from ``rrg_models.hand.hand_tree()`` as one articulated free body (palm pose and
  finger angles all set through qpos, distal joints coupled by hand).

Only hand–object and hand–table pairs collide (contype/conaffinity). Unsensed hand parts
stop the sweep too. (An articulated free hand rather than mocap bodies: one qpos write poses
everything, and unlike mocap bodies it collides with the static table.) Costs are kept low
by culling: sphere covers of the hand, tested against the object's bounding box in its own
frame and the table, certify most path samples and closing angles free without a MuJoCo
call; the first touching step is bisected on precomputed fine lattices.

Frames: the *path frame* is the frame in which the WRT's object-frame poses are placed,
planar_pose(e) for an estimate e. ``simulate_relative(Δ)`` uses e = identity (the path frame
is ``world`` itself and the object sits at Δ), which is what the observation tables store;
``simulate(w, e)`` runs the same computation genuinely in ``world``.
Tip normals point from the object into the fingertip (the object's outward surface normal,
the direction of the force on the Nano17).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from itertools import chain
from typing import Protocol

import mujoco
import numpy as np
from numba import njit
from scipy.spatial.transform import Rotation, Slerp

from rrg_models.config import GEOMSIM, N_SENSORS
from rrg_models.hand import (
    FINGERS,
    LINKS,
    BodySpec,
    GeomSpec,
    body_poses,
    finger_link_poses,
    geom_local_pose,
    hand_tree,
    joint_angles,
)
from rrg_models.objects.primitives import (
    Primitive,
    mjcf_mesh_asset,
    rotated_half_extents,
    union_bounds,
)
from rrg_models.observation import Observation, grasp_arrived
from rrg_models.poses import planar_pose
from rrg_models.wrt import WRT

FINE_PATH = 2**GEOMSIM.refine_iters  # fine path samples per coarse step
FINE_CLOSE = 2**GEOMSIM.close_refine_iters  # fine closing angles per coarse step
FAR_AWAY_Z = 100.0  # m: object parked here when only the table matters
PRESHAPE = [0, 0, 0]  # closing-lattice indices of the preshape
SIM_VERSION = "1"  # bump when the simulator's results change (observation tables are keyed by it)


class ObjectLike(Protocol):
    name: str
    parts: Sequence[Primitive]


@dataclass
class ObservationArrays:
    """Predicted observations for N object offsets, in the path frame (see module doc).

    Fields as in rrg_models.observation.Observation; stop_pose is the hand pose at the stop.
    """

    contact: np.ndarray  # (N,) bool
    progress: np.ndarray  # (N,) float32 [m]
    sensors: np.ndarray  # (N,10) bool
    closure: np.ndarray  # (N,3) float32 [rad]
    tip_points: np.ndarray  # (N,3,3) float32 [m], hand frame, NaN = no contact
    tip_normals: np.ndarray  # (N,3,3) float32, hand frame, NaN = no contact
    motion_dir: np.ndarray  # (N,3) float32, path frame
    stop_pose: np.ndarray  # (N,4,4) float32, path frame

    @classmethod
    def empty(cls, n: int) -> ObservationArrays:
        return cls(
            np.zeros(n, bool),
            np.zeros(n, np.float32),
            np.zeros((n, N_SENSORS), bool),
            np.zeros((n, 3), np.float32),
            np.full((n, 3, 3), np.nan, np.float32),
            np.full((n, 3, 3), np.nan, np.float32),
            np.zeros((n, 3), np.float32),
            np.zeros((n, 4, 4), np.float32),
        )

    @classmethod
    def concatenate(cls, parts: Sequence[ObservationArrays]) -> ObservationArrays:
        return cls(
            *(np.concatenate([getattr(p, f) for p in parts]) for f in cls.__dataclass_fields__)
        )

    def observation(self, i: int) -> Observation:
        return Observation(
            bool(self.contact[i]),
            float(self.progress[i]),
            self.stop_pose[i],
            self.sensors[i],
            self.closure[i],
            self.tip_points[i],
            self.tip_normals[i],
            self.motion_dir[i],
        )


# ------------------------------------------------------------------ the probe model
def _fmt(v) -> str:
    return " ".join(f"{float(x):.9g}" for x in v)


def _hand_body_xml(body: BodySpec, children: dict[str, list[BodySpec]]) -> str:
    joint = (
        "<freejoint/>"
        if body.parent is None
        else (
            ""
            if body.joint is None
            else f'<joint name="{body.joint.name}" axis="{_fmt(body.joint.axis)}"/>'
        )
    )
    inertial = (
        "" if body.geoms else '<inertial pos="0 0 0" mass="0.01" diaginertia="1e-6 1e-6 1e-6"/>'
    )
    geoms = "".join(
        f'<geom name="{g.name}" type="{g.kind}" size="{_fmt(g.size)}" pos="{_fmt(g.pos)}" '
        f'quat="{_fmt(g.quat)}" contype="1" conaffinity="0"/>'
        for g in body.geoms
    )
    inner = "".join(_hand_body_xml(c, children) for c in children.get(body.name, []))
    return (
        f'<body name="{body.name}" pos="{_fmt(body.pos)}" quat="{_fmt(body.quat)}">'
        f"{joint}{inertial}{geoms}{inner}</body>"
    )


def _object_geom_xml(k: int, p: Primitive) -> str:
    shape = f'mesh="object_{k}"' if p.kind == "mesh" else f'size="{_fmt(p.size)}"'
    return (
        f'<geom name="object_{k}" type="{p.kind}" {shape} pos="{_fmt(p.pos)}" '
        f'quat="{_fmt(p.quat)}" contype="0" conaffinity="1"/>'
    )


def probe_mjcf(parts: Sequence[Primitive]) -> str:
    """MJCF of the probe: table plane, the object (free body ``object``) and the free hand."""
    children: dict[str, list[BodySpec]] = {}
    for b in hand_tree():
        children.setdefault(b.parent, []).append(b)
    obj = "".join(_object_geom_xml(k, p) for k, p in enumerate(parts))
    meshes = "".join(
        '<mesh name="{name}" vertex="{vertex}"/>'.format(**mjcf_mesh_asset(p, f"object_{k}"))
        for k, p in enumerate(parts)
        if p.kind == "mesh"
    )
    return (
        f'<mujoco model="geometric_probe"><asset>{meshes}</asset><worldbody>'
        '<geom name="table" type="plane" size="0 0 1" contype="0" conaffinity="1"/>'
        f'<body name="object"><freejoint/>{obj}</body>'
        f"{_hand_body_xml(children[None][0], children)}"
        "</worldbody></mujoco>"
    )


# ------------------------------------------------------------------ the swept path
@dataclass(frozen=True)
class SweptPath:
    """The WRT's path sampled on a fine lattice (FINE_PATH samples per coarse path_step).

    poses: (S,4,4) hand poses in the object frame; progress: (S,) palm path length [m].
    Coarse samples are every FINE_PATH-th fine sample.
    """

    poses: np.ndarray
    progress: np.ndarray

    @classmethod
    def from_wrt(cls, wrt: WRT) -> SweptPath:
        poses, progress = [wrt.poses[:1]], [np.zeros(1)]
        for T0, T1 in zip(wrt.poses[:-1], wrt.poses[1:]):
            dist = float(np.linalg.norm(T1[:3, 3] - T0[:3, 3]))
            rots = Rotation.from_matrix(np.stack([T0[:3, :3], T1[:3, :3]]))
            angle = float((rots[0].inv() * rots[1]).magnitude())
            n = max(
                1,
                int(np.ceil(max(dist, angle * GEOMSIM.rotation_sample_radius) / GEOMSIM.path_step)),
            )
            t = np.linspace(0.0, 1.0, n * FINE_PATH + 1)[1:]
            seg = np.zeros((t.size, 4, 4))
            seg[:, :3, :3] = Slerp([0.0, 1.0], rots)(t).as_matrix()
            seg[:, :3, 3] = T0[:3, 3] * (1 - t[:, None]) + T1[:3, 3] * t[:, None]
            seg[:, 3, 3] = 1.0
            poses.append(seg)
            progress.append(progress[-1][-1] + dist * t)
        return cls(np.concatenate(poses), np.concatenate(progress))

    @property
    def length(self) -> float:
        return float(self.progress[-1])

    @property
    def n_coarse(self) -> int:
        return (len(self.poses) - 1) // FINE_PATH + 1


def _pose_to_qpos(T: np.ndarray) -> np.ndarray:
    """(…,4,4) → (…,7) free-joint qpos (position, quaternion wxyz)."""
    flat = T.reshape(-1, 4, 4)
    q = Rotation.from_matrix(flat[:, :3, :3]).as_quat(scalar_first=True)
    return np.concatenate([flat[:, :3, 3], q], axis=1).reshape(T.shape[:-2] + (7,))


def _planar_qpos(w) -> np.ndarray:
    """Free-joint qpos of an object at planar pose w = (x, y, θ) on the table."""
    x, y, th = (float(v) for v in w)
    return np.array([x, y, 0.0, np.cos(th / 2), 0.0, 0.0, np.sin(th / 2)])


# ------------------------------------------------------------------ conservative culling
def primitive_aabb(p: GeomSpec) -> tuple[np.ndarray, np.ndarray]:
    """Exact axis-aligned bounds (lo, hi) of a hand geom in its body frame."""
    R = Rotation.from_quat(np.asarray(p.quat, float), scalar_first=True).as_matrix()
    half = rotated_half_extents(p.kind, p.size, R)
    c = np.asarray(p.pos, float)
    return c - half, c + half


def box_sphere_cover(lo: np.ndarray, hi: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """Spheres (centres (k,3), radii (k,)) covering the box [lo, hi], cells of half
    extent ≤ cell."""
    half = (hi - lo) / 2
    n = np.maximum(1, np.ceil(half / cell - 1e-9)).astype(int)
    axes = [lo[i] + (np.arange(n[i]) + 0.5) * (2 * half[i] / n[i]) for i in range(3)]
    centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    return centres, np.full(len(centres), float(np.linalg.norm(half / n)))


def _body_aabb(body: BodySpec) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of all geoms of a hand body in the body frame."""
    boxes = [primitive_aabb(g) for g in body.geoms]
    return np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0)


def _body_spheres(cell: float) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Sphere covers (in the body frame) of every hand body that has geoms."""
    return {b.name: box_sphere_cover(*_body_aabb(b), cell) for b in hand_tree() if b.geoms}


SWEEP_CELL = 0.05  # m: sphere cover of the hand for culling the sweep (chosen: one sphere per body)
CLOSE_CELL = (
    0.02  # m: cover of the finger links for culling the closing (chosen: 4 spheres per finger)
)


# ------------------------------------------------------------------ box culling (compiled)
#: A hand box and an object box (or the table) closer than this [m] count as touching. Chosen:
#: far above MuJoCo's collision tolerances (its convex solver's 1e-6), far below the sweep's
#: 5 mm and the closing's 0.04 rad steps, so culling stays conservative and still tight.
BOX_SLACK = 1e-4
#: The compiled scans stop at this many candidates per sample (per finger when closing): the
#: first is nearly always a touch, and what lies past it is deep in the object and costly to
#: scan. The loops scan the rest only when all of these were free (chosen: fastest of 1-4).
SCAN_LIMIT = 2
ANGLE_GROUP = 8  # closing angles under one bounding sphere in the compiled scan (chosen)


def _geom_half_extents(g: GeomSpec) -> np.ndarray:
    """(3,) half extents [m] of the box, in the geom's frame, that holds a hand geom."""
    return Primitive(g.kind, g.size).local_half_extents()


@dataclass(frozen=True)
class _Boxes:
    """Oriented boxes that hold a set of primitives: rotations (…,3,3) whose columns are the
    box axes, centres (…,3) [m], half extents (…,3) [m] and bounding radii (…) [m]."""

    rot: np.ndarray
    centre: np.ndarray
    half: np.ndarray
    radius: np.ndarray

    @classmethod
    def of_parts(cls, parts: Sequence[Primitive]) -> _Boxes:
        half = np.array([p.local_half_extents() for p in parts])
        return cls(
            np.stack([p.rotation for p in parts]),
            np.array([p.pos for p in parts], float),
            half,
            np.linalg.norm(half, axis=1),
        )


@njit(cache=True)
def _boxes_touch(Ra, ca, ha, Rb, cb, hb, slack, scratch):  # pragma: no cover - compiled
    """Whether boxes a and b (axes as columns of R, centre c, half extents h) may come within
    ``slack`` of each other: False only if one of the 15 separating axes separates them by more
    (Gottschalk's OBB test; a cross axis's own length ≤ 1 only makes the test more lenient).
    scratch: (7,3) work space."""
    R, A, t = scratch[0:3], scratch[3:6], scratch[6]
    d0, d1, d2 = cb[0] - ca[0], cb[1] - ca[1], cb[2] - ca[2]
    for i in range(3):
        t[i] = Ra[0, i] * d0 + Ra[1, i] * d1 + Ra[2, i] * d2
        for j in range(3):
            R[i, j] = Ra[0, i] * Rb[0, j] + Ra[1, i] * Rb[1, j] + Ra[2, i] * Rb[2, j]
            A[i, j] = abs(R[i, j])
    for i in range(3):
        rb = hb[0] * A[i, 0] + hb[1] * A[i, 1] + hb[2] * A[i, 2]
        if abs(t[i]) > ha[i] + rb + slack:
            return False
    for j in range(3):
        ra = ha[0] * A[0, j] + ha[1] * A[1, j] + ha[2] * A[2, j]
        if abs(t[0] * R[0, j] + t[1] * R[1, j] + t[2] * R[2, j]) > ra + hb[j] + slack:
            return False
    for i in range(3):
        i1, i2 = (i + 1) % 3, (i + 2) % 3
        for j in range(3):
            j1, j2 = (j + 1) % 3, (j + 2) % 3
            ra = ha[i1] * A[i2, j] + ha[i2] * A[i1, j]
            rb = hb[j1] * A[i, j2] + hb[j2] * A[i, j1]
            if abs(t[i2] * R[i1, j] - t[i1] * R[i2, j]) > ra + rb + slack:
                return False
    return True


@njit(cache=True)
def _dot3(a, b):  # pragma: no cover - compiled
    """a · b of two 3-vectors (no BLAS call)."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True)
def _sphere_near_box(x, y, z, r, centre, half):  # pragma: no cover - compiled
    """Whether the sphere at (x, y, z) of radius r meets the axis-aligned box (centre, half)."""
    gx = max(abs(x - centre[0]) - half[0], 0.0)
    gy = max(abs(y - centre[1]) - half[1], 0.0)
    gz = max(abs(z - centre[2]) - half[2], 0.0)
    return gx * gx + gy * gy + gz * gz < r * r


@njit(cache=True)
def _box_touches_object(
    Rb, cb, hb, rb, part_rot, part_centre, part_half, part_radius, slack, scratch
):  # pragma: no cover - compiled
    """Whether a box (object frame, bounding radius rb) may touch some part's box."""
    for p in range(part_rot.shape[0]):
        dx = cb[0] - part_centre[p, 0]
        dy = cb[1] - part_centre[p, 1]
        dz = cb[2] - part_centre[p, 2]
        reach = rb + part_radius[p] + slack
        if dx * dx + dy * dy + dz * dz >= reach * reach:
            continue
        if _boxes_touch(part_rot[p], part_centre[p], part_half[p], Rb, cb, hb, slack, scratch):
            return True
    return False


@njit(cache=True)
def _sweep_box_candidates(
    w,
    start,
    limit,
    hand_centre,
    hand_radius,
    geom_rot,
    geom_centre,
    geom_half,
    geom_radius,
    part_rot,
    part_centre,
    part_half,
    part_radius,
    union_centre,
    union_half,
    table_hit,
    slack,
):  # pragma: no cover - compiled
    """Coarse path samples where the hand's geom boxes (path frame, (S,G,…)) may touch the
    object at w (N,3) (or the table, from sample ``table_hit`` on): (N, S) bool, scanned from
    sample start[n] until ``limit`` are found, and (N,) the sample each scan stopped before
    (S: scanned to the end)."""
    n_w, n_s, n_g = w.shape[0], geom_rot.shape[0], geom_rot.shape[1]
    out = np.zeros((n_w, n_s), np.bool_)
    resume = np.full(n_w, n_s)
    Rb = np.empty((3, 3))
    cb = np.empty(3)
    scratch = np.empty((7, 3))
    for n in range(n_w):
        c, s = np.cos(w[n, 2]), np.sin(w[n, 2])
        found = 0
        for k in range(start[n], n_s):
            if k >= table_hit:  # the table: every later sample (no need to count them)
                out[n, k:] = True
                break
            hit = False
            dx, dy = hand_centre[k, 0] - w[n, 0], hand_centre[k, 1] - w[n, 1]
            if not _sphere_near_box(
                c * dx + s * dy,
                c * dy - s * dx,
                hand_centre[k, 2],
                hand_radius + slack,
                union_centre,
                union_half,
            ):
                continue
            for g in range(n_g):
                dx, dy = geom_centre[k, g, 0] - w[n, 0], geom_centre[k, g, 1] - w[n, 1]
                cb[0], cb[1], cb[2] = c * dx + s * dy, c * dy - s * dx, geom_centre[k, g, 2]
                if not _sphere_near_box(
                    cb[0], cb[1], cb[2], geom_radius[g] + slack, union_centre, union_half
                ):
                    continue
                for j in range(3):
                    Rb[0, j] = c * geom_rot[k, g, 0, j] + s * geom_rot[k, g, 1, j]
                    Rb[1, j] = c * geom_rot[k, g, 1, j] - s * geom_rot[k, g, 0, j]
                    Rb[2, j] = geom_rot[k, g, 2, j]
                if _box_touches_object(
                    Rb,
                    cb,
                    geom_half[g],
                    geom_radius[g],
                    part_rot,
                    part_centre,
                    part_half,
                    part_radius,
                    slack,
                    scratch,
                ):
                    hit = True
                    break
            if hit:
                out[n, k] = True
                found += 1
                if found == limit:
                    resume[n] = k + 1
                    break
    return out, resume


@njit(cache=True)
def _finger_links_hit(M, b, links, parts, union, slack, cb, Rb, scratch):  # pragma: no cover
    """Whether a link box of one finger at one angle (``links``: its links' rotations,
    centres, half sizes and radii in the hand frame) touches the table or the object's parts
    (``parts``: rotations, centres, half sizes, radii; ``union``: their bounding box's centre
    and half size), the hand frame mapped to the object's by M (3,3) and b (3,). cb, Rb and
    scratch are work arrays."""
    link_rot, link_centre, link_half, link_radius = links
    union_centre, union_half = union
    for link in range(link_rot.shape[0]):
        for i in range(3):
            cb[i] = _dot3(M[i], link_centre[link]) + b[i]
        r = link_radius[link] + slack
        near_object = _sphere_near_box(cb[0], cb[1], cb[2], r, union_centre, union_half)
        if cb[2] >= r and not near_object:
            continue
        R = link_rot[link]
        h = link_half[link]
        for i in range(3):
            for j in range(3):
                Rb[i, j] = M[i, 0] * R[0, j] + M[i, 1] * R[1, j] + M[i, 2] * R[2, j]
        lowest = cb[2] - (abs(Rb[2, 0]) * h[0] + abs(Rb[2, 1]) * h[1])
        lowest -= abs(Rb[2, 2]) * h[2]
        if lowest < slack or (
            near_object
            and _box_touches_object(
                Rb, cb, h, link_radius[link], parts[0], parts[1], parts[2], parts[3], slack, scratch
            )
        ):
            return True
    return False


@njit(cache=True)
def _closing_box_candidates(
    T_stop,
    w,
    start,
    limit,
    reach_centre,
    reach_radius,
    group_centre,
    group_radius,
    finger_centre,
    finger_radius,
    link_rot,
    link_centre,
    link_half,
    link_radius,
    part_rot,
    part_centre,
    part_half,
    part_radius,
    union_centre,
    union_half,
    slack,
):  # pragma: no cover - compiled
    """Coarse closing angles where each finger's link boxes (hand frame, (A,3,3,…)) may touch
    the object at w (N,3) or the table, the hand stopped at T_stop (N,4,4): (N, A, 3) bool,
    each finger scanned from angle start[n, f] until ``limit`` are found, and (N, 3) the angle
    each scan stopped before (A: scanned to the end).

    Bounding spheres first: of a finger over all its angles (reach_*), over each ANGLE_GROUP of
    them (group_*), at one angle (finger_*), of one link (link_radius); then each link's box
    against the table plane and the parts' boxes."""
    n_w, n_a = w.shape[0], link_rot.shape[0]
    out = np.zeros((n_w, n_a, 3), np.bool_)
    resume = np.full((n_w, 3), n_a)
    scratch = np.empty((7, 3))
    M = np.empty((3, 3))
    b = np.empty(3)
    Rb = np.empty((3, 3))
    cb = np.empty(3)
    for n in range(n_w):
        c, s = np.cos(w[n, 2]), np.sin(w[n, 2])
        for j in range(3):  # hand → object frame
            M[0, j] = c * T_stop[n, 0, j] + s * T_stop[n, 1, j]
            M[1, j] = c * T_stop[n, 1, j] - s * T_stop[n, 0, j]
            M[2, j] = T_stop[n, 2, j]
        dx, dy = T_stop[n, 0, 3] - w[n, 0], T_stop[n, 1, 3] - w[n, 1]
        b[0], b[1], b[2] = c * dx + s * dy, c * dy - s * dx, T_stop[n, 2, 3]
        for f in range(3):
            if start[n, f] >= n_a:
                continue
            x = _dot3(M[0], reach_centre[f]) + b[0]
            y = _dot3(M[1], reach_centre[f]) + b[1]
            z = _dot3(M[2], reach_centre[f]) + b[2]
            r = reach_radius[f] + slack
            if z >= r and not _sphere_near_box(x, y, z, r, union_centre, union_half):
                continue
            found = 0
            for a in range(start[n, f], n_a):
                if a == start[n, f] or a % ANGLE_GROUP == 0:  # entering a group of angles
                    group = a // ANGLE_GROUP
                    x = _dot3(M[0], group_centre[group, f]) + b[0]
                    y = _dot3(M[1], group_centre[group, f]) + b[1]
                    z = _dot3(M[2], group_centre[group, f]) + b[2]
                    r = group_radius[group, f] + slack
                    group_free = z >= r and not _sphere_near_box(
                        x, y, z, r, union_centre, union_half
                    )
                if group_free:
                    continue
                x = _dot3(M[0], finger_centre[a, f]) + b[0]
                y = _dot3(M[1], finger_centre[a, f]) + b[1]
                z = _dot3(M[2], finger_centre[a, f]) + b[2]
                r = finger_radius[a, f] + slack
                if z >= r and not _sphere_near_box(x, y, z, r, union_centre, union_half):
                    continue
                links = (link_rot[a, f], link_centre[a, f], link_half[f], link_radius[f])
                parts = (part_rot, part_centre, part_half, part_radius)
                union = (union_centre, union_half)
                if _finger_links_hit(M, b, links, parts, union, slack, cb, Rb, scratch):
                    out[n, a, f] = True
                    found += 1
                    if found == limit:
                        resume[n, f] = a + 1
                        break
    return out, resume


def _flagged_in_order(flagged: np.ndarray) -> list[list[list[int]]]:
    """Per sample m and column f of flagged (M, K, F) bool, the flagged k in increasing order."""
    m_idx, f_idx, k_idx = np.nonzero(flagged.transpose(0, 2, 1))
    n_f = flagged.shape[2]
    ends = np.cumsum(np.bincount(m_idx * n_f + f_idx, minlength=flagged.shape[0] * n_f)).tolist()
    ks = k_idx.tolist()
    starts = [0] + ends[:-1]
    return [
        [ks[starts[m * n_f + f] : ends[m * n_f + f]] for f in range(n_f)]
        for m in range(flagged.shape[0])
    ]


def _enclosing_spheres(centre: np.ndarray, radius: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A sphere (centre (…,3), radius (…)) holding the spheres centre (K,…,3), radius (K,…)."""
    c = centre.mean(axis=0)
    return c, (np.linalg.norm(centre - c, axis=-1) + radius).max(axis=0)


# ------------------------------------------------------------------ the simulator
@dataclass(frozen=True)
class _FramedPath:
    """The swept path placed in one path frame: what a sweep needs, precomputed."""

    poses: np.ndarray  # (S,4,4) fine hand poses
    palm_qpos: np.ndarray  # (S,7)
    centres: np.ndarray  # (S_coarse·G, 3) hand sphere centres at the coarse samples
    table_hit: int  # first coarse sample touching the table (n_coarse if none)
    geom_rot: np.ndarray  # (S_coarse, G, 3, 3) hand geom boxes' axes at the coarse samples
    geom_centre: np.ndarray  # (S_coarse, G, 3) [m] their centres
    hand_centre: np.ndarray  # (S_coarse, 3) [m] centre of the hand's bounding sphere
    #: (S,4,4) the fine hand poses as the robot measures them (its forward kinematics): the
    #: stop poses reported; ``poses`` itself unless the hand is truly off (simulate_offset).
    measured_poses: np.ndarray


class GeometricSimulator:
    """Kinematic execution of one WRT against one object (see the module doc)."""

    def __init__(self, obj: ObjectLike, wrt: WRT):
        self.obj, self.wrt = obj, wrt
        self.model = mujoco.MjModel.from_xml_string(probe_mjcf(obj.parts))
        self.data = mujoco.MjData(self.model)
        self._qpos = self.data.qpos
        m = self.model
        jadr = lambda name: int(m.jnt_qposadr[m.joint(name).id])
        self._obj_adr = int(m.jnt_qposadr[m.body("object").jntadr[0]])
        self._palm_adr = int(m.jnt_qposadr[m.body("palm").jntadr[0]])
        self._prox_qadr = [jadr(f"f{i}_prox") for i in FINGERS]
        self._dist_qadr = [jadr(f"f{i}_dist") for i in FINGERS]
        for i in (1, 2):
            self._qpos[jadr(f"f{i}_spread")] = wrt.spread
        self._init_geom_maps()
        lo, hi = union_bounds(obj.parts)
        self._obj_centre, self._obj_half = (lo + hi) / 2, (hi - lo) / 2
        self._parts = _Boxes.of_parts(obj.parts)
        self.path = SweptPath.from_wrt(wrt)
        self._init_sweep_spheres()
        self._init_sweep_boxes()
        self._init_closing()
        self._init_closing_boxes()
        self._relative = self._frame(np.eye(4))

    # ------------------------------------------------------------ setup
    def _init_geom_maps(self) -> None:
        ng = self.model.ngeom
        self._sensor_of_geom = np.full(ng, -1)
        self._finger_of_geom = np.full(ng, -1)
        self._tip_of_geom = np.full(ng, -1)
        for body in hand_tree():
            for g in body.geoms:
                gid = self.model.geom(g.name).id
                self._sensor_of_geom[gid] = g.sensor
                if body.name[0] == "f":
                    f = int(body.name[1]) - 1
                    self._finger_of_geom[gid] = f
                    if body.name.endswith("_tip"):
                        self._tip_of_geom[gid] = f

    def _init_sweep_spheres(self) -> None:
        """Sphere cover of the whole hand at the preshape, in the hand frame."""
        poses = body_poses(self.wrt.spread, np.full(3, self.wrt.preclose))
        covers = _body_spheres(SWEEP_CELL)
        self._sweep_centres = np.concatenate(
            [c @ poses[b][:3, :3].T + poses[b][:3, 3] for b, (c, _) in covers.items()]
        )
        self._sweep_radii = np.concatenate([r for _, r in covers.values()])

    def _init_sweep_boxes(self) -> None:
        """Boxes holding the hand's geoms at the preshape (hand frame) and a sphere holding
        them all."""
        poses = body_poses(self.wrt.spread, np.full(3, self.wrt.preclose))
        geoms = [(b.name, g) for b in hand_tree() for g in b.geoms]
        T = np.stack([poses[b] @ geom_local_pose(g) for b, g in geoms])
        half = np.array([_geom_half_extents(g) for _, g in geoms])
        radius = np.linalg.norm(half, axis=1)
        self._hand_boxes = _Boxes(T[:, :3, :3], T[:, :3, 3], half, radius)
        self._hand_sphere_centre = T[:, :3, 3].mean(axis=0)
        self._hand_sphere_radius = float(
            (np.linalg.norm(T[:, :3, 3] - self._hand_sphere_centre, axis=1) + radius).max()
        )

    def _init_closing(self) -> None:
        """Fine lattice of closing angles and the finger link spheres at its coarse angles."""
        a0 = self.wrt.preclose
        n_coarse = max(1, int(np.ceil((GEOMSIM.close_max - a0) / GEOMSIM.close_step - 1e-9)))
        self._angles = np.minimum(
            a0 + np.arange(n_coarse * FINE_CLOSE + 1) * GEOMSIM.close_step / FINE_CLOSE,
            GEOMSIM.close_max,
        )
        distal = joint_angles(0.0, np.repeat(self._angles[:, None], 3, axis=1))["f1_dist"]
        self._prox_list, self._distal_list = (
            self._angles.tolist(),
            distal.tolist(),
        )  # fast scalar access
        coarse = self._angles[::FINE_CLOSE]
        poses = body_poses(self.wrt.spread, np.repeat(coarse[:, None], 3, axis=1))
        covers = _body_spheres(CLOSE_CELL)
        centres, radii = [], []
        for i in FINGERS:
            links = [f"f{i}_{link}" for link in LINKS]
            centres.append(
                np.concatenate(
                    [
                        covers[b][0] @ np.swapaxes(poses[b][:, :3, :3], 1, 2)
                        + poses[b][:, None, :3, 3]
                        for b in links
                    ],
                    axis=1,
                )
            )
            radii.append(np.concatenate([covers[b][1] for b in links]))
        centres = np.stack(centres, axis=1)  # (A_coarse, 3 fingers, K, 3), hand frame
        self._link_shape = centres.shape[:3]
        self._link_coords = np.ascontiguousarray(
            centres.reshape(-1, 3).T
        )  # (3, L) coordinate-major
        self._link_r = np.broadcast_to(np.stack(radii), self._link_shape).ravel()  # (L,)

    def _init_closing_boxes(self) -> None:
        """Boxes holding each finger link's geom at the coarse closing angles (hand frame), and
        spheres holding a finger at one angle and over all of them."""
        coarse = self._angles[::FINE_CLOSE]
        links = finger_link_poses(self.wrt.spread, np.repeat(coarse[:, None], 3, axis=1))
        geoms = {b.name: b.geoms[0] for b in hand_tree() if b.name[0] == "f" and b.geoms}
        local = np.stack(
            [np.stack([geom_local_pose(geoms[f"f{i}_{k}"]) for k in LINKS]) for i in FINGERS]
        )
        T = links @ local  # (A, 3 fingers, 3 links, 4, 4)
        half = np.array([[_geom_half_extents(geoms[f"f{i}_{k}"]) for k in LINKS] for i in FINGERS])
        radius = np.linalg.norm(half, axis=2)  # (3, 3)
        self._link_boxes = _Boxes(
            np.ascontiguousarray(T[..., :3, :3]), np.ascontiguousarray(T[..., :3, 3]), half, radius
        )
        centre = T[..., :3, 3].mean(axis=2)  # (A, 3)
        self._finger_centre = centre
        self._finger_radius = (
            np.linalg.norm(T[..., :3, 3] - centre[:, :, None], axis=3) + radius
        ).max(axis=2)
        self._reach_centre, self._reach_radius = _enclosing_spheres(centre, self._finger_radius)
        groups = [
            _enclosing_spheres(
                centre[a : a + ANGLE_GROUP], self._finger_radius[a : a + ANGLE_GROUP]
            )
            for a in range(0, len(centre), ANGLE_GROUP)
        ]
        self._group_centre = np.stack([c for c, _ in groups])  # (groups, 3 fingers, 3)
        self._group_radius = np.stack([r for _, r in groups])  # (groups, 3 fingers)

    def _frame(self, F: np.ndarray, measured: np.ndarray | None = None) -> _FramedPath:
        """The path placed in path frame F, with its table-contact sample found by a sweep.

        measured: the frame the robot believes the path is in (default F; see _FramedPath).
        """
        poses = F @ self.path.poses
        coarse = poses[::FINE_PATH]
        centres = (
            np.einsum("sij,gj->sgi", coarse[:, :3, :3], self._sweep_centres)
            + coarse[:, None, :3, 3]
        ).reshape(-1, 3)
        palm_qpos = _pose_to_qpos(poses)
        self._set_object((0.0, 0.0, 0.0), z=FAR_AWAY_Z)
        self._set_fingers(PRESHAPE)
        table_hit = self.path.n_coarse
        for c in range(self.path.n_coarse):
            self._qpos[self._palm_adr : self._palm_adr + 7] = palm_qpos[c * FINE_PATH]
            if self._collide():
                table_hit = c
                break
        hb = self._hand_boxes
        return _FramedPath(
            poses,
            palm_qpos,
            centres,
            table_hit,
            geom_rot=np.ascontiguousarray(coarse[:, None, :3, :3] @ hb.rot),
            geom_centre=np.ascontiguousarray(
                np.einsum("sij,gj->sgi", coarse[:, :3, :3], hb.centre) + coarse[:, None, :3, 3]
            ),
            hand_centre=coarse[:, :3, :3] @ self._hand_sphere_centre + coarse[:, :3, 3],
            measured_poses=poses if measured is None else measured @ self.path.poses,
        )

    # ------------------------------------------------------------ collision queries
    def _set_object(self, w, z: float = 0.0) -> None:
        q = _planar_qpos(w)
        q[2] = z
        self._qpos[self._obj_adr : self._obj_adr + 7] = q

    def _set_fingers(self, idx: list[int]) -> None:
        """Pose the fingers at fine closing-lattice indices idx (3,) (0 = the preshape)."""
        q, prox, dist = self._qpos, self._prox_list, self._distal_list
        for f, k in enumerate(idx):
            q[self._prox_qadr[f]] = prox[k]
            q[self._dist_qadr[f]] = dist[k]

    def _collide(self) -> int:
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_collision(self.model, self.data)
        return self.data.ncon

    def _touching_fingers(self) -> set[int]:
        """Fingers with a contact now (after a _collide)."""
        n = self.data.ncon
        if not n:
            return set()
        return set(self._finger_of_geom[self.data.contact.geom[:n]].ravel().tolist()) - {-1}

    def _near_parts(self, X: np.ndarray, r: np.ndarray) -> np.ndarray:
        """(K,) bool: sphere k (object-frame centre X[k], radius r[k]) touches some part's box."""
        parts = self._parts
        local = np.matmul(X[None] - parts.centre[:, None], parts.rot)  # (P, K, 3)
        gap = np.maximum(np.abs(local) - parts.half[:, None], 0.0)
        return ((gap * gap).sum(axis=2) < r * r).any(axis=0)

    def _near_object(
        self, x: np.ndarray, y: np.ndarray, z: np.ndarray, r: np.ndarray, per_part: bool
    ) -> np.ndarray:
        """(…) bool: spheres with object-frame centres (x, y, z) and radii r (all broadcastable)
        that may touch the object. Exact sphere tests against the union box, then (per_part)
        against each part's box in its own frame (conservative: a part lies inside its box)."""
        o, h = self._obj_centre, self._obj_half
        gx = np.maximum(np.abs(x - o[0]) - h[0], 0.0)
        gy = np.maximum(np.abs(y - o[1]) - h[1], 0.0)
        gz = np.maximum(np.abs(z - o[2]) - h[2], 0.0)
        near = gx * gx + gy * gy + gz * gz < r * r
        if per_part and len(self._parts.half) > 1:
            idx = np.nonzero(near)
            X = np.stack([np.broadcast_to(v, near.shape)[idx] for v in (x, y, z)], axis=1)
            near[idx] = self._near_parts(X, np.broadcast_to(r, near.shape)[idx])
        return near

    # ------------------------------------------------------------ culling
    def _sweep_candidates(
        self, framed: _FramedPath, w: np.ndarray, start: np.ndarray | None = None, limit=SCAN_LIMIT
    ) -> tuple[np.ndarray, np.ndarray]:
        """Coarse samples where the hand may touch the object at w[n] or the table (the hand's
        geom boxes against the parts' boxes; compiled): (N, S_coarse) bool scanned from start[n]
        (default 0) until ``limit`` are found, and (N,) where each scan stopped (S_coarse: done).

        Samples scanned and not flagged are certainly free: the sweep tests only flagged ones.
        """
        hb, parts = self._hand_boxes, self._parts
        return _sweep_box_candidates(
            np.ascontiguousarray(w, dtype=float),
            np.zeros(len(w), np.int64) if start is None else start,
            limit,
            framed.hand_centre,
            self._hand_sphere_radius,
            framed.geom_rot,
            framed.geom_centre,
            hb.half,
            hb.radius,
            parts.rot,
            parts.centre,
            parts.half,
            parts.radius,
            self._obj_centre,
            self._obj_half,
            framed.table_hit,
            BOX_SLACK,
        )

    def _closing_candidates(
        self, T_stop: np.ndarray, w: np.ndarray, start: np.ndarray | None = None, limit=SCAN_LIMIT
    ) -> tuple[np.ndarray, np.ndarray]:
        """Coarse closing angles where each finger may touch the object or the table, for hands
        stopped at T_stop (N,4,4) with the objects at w (N,3) (the finger links' boxes against
        the table and the parts' boxes; compiled): (N, A_coarse, 3) bool, each finger scanned
        from start[n, f] (default 0) until ``limit`` are found, and (N, 3) where each scan
        stopped (A_coarse: done). Angles scanned and not flagged are certainly free."""
        lb, parts = self._link_boxes, self._parts
        return _closing_box_candidates(
            np.ascontiguousarray(T_stop, dtype=float),
            np.ascontiguousarray(w, dtype=float),
            np.zeros((len(w), 3), np.int64) if start is None else start,
            limit,
            self._reach_centre,
            self._reach_radius,
            self._group_centre,
            self._group_radius,
            self._finger_centre,
            self._finger_radius,
            lb.rot,
            lb.centre,
            lb.half,
            lb.radius,
            parts.rot,
            parts.centre,
            parts.half,
            parts.radius,
            self._obj_centre,
            self._obj_half,
            BOX_SLACK,
        )

    def _sweep_candidates_spheres(self, framed: _FramedPath, w: np.ndarray) -> np.ndarray:
        """(N, S_coarse) bool: coarse samples where the hand may touch the object at w[n] or the
        table: the reference path's culling (sphere covers, looser than _sweep_candidates).

        Samples not flagged are certainly free, so the sweep only tests flagged ones. The union
        box suffices here: the sweep stops at its first touching sample anyway.
        """
        n_c, C = self.path.n_coarse, framed.centres
        c, s = np.cos(w[:, 2:3]), np.sin(w[:, 2:3])
        dx, dy = C[None, :, 0] - w[:, 0:1], C[None, :, 1] - w[:, 1:2]
        near = self._near_object(
            c * dx + s * dy,
            c * dy - s * dx,
            C[None, :, 2],
            np.tile(self._sweep_radii, n_c)[None],
            per_part=False,
        )
        near = near.reshape(len(w), n_c, -1).any(axis=2)
        near[:, framed.table_hit :] = True
        return near

    def _closing_candidates_spheres(self, T_stop: np.ndarray, w: np.ndarray) -> np.ndarray:
        """(N, A_coarse, 3) bool: coarse closing angles where each finger may touch the object or
        the table, for hands stopped at T_stop (N,4,4) with the objects at w (N,3): the reference
        path's culling (looser than _closing_candidates).

        Link spheres (hand frame) are tested against the object's parts and the table plane.
        Angles not flagged are certainly free.
        """
        R, t = T_stop[:, :3, :3], T_stop[:, :3, 3]
        c, s = np.cos(w[:, 2:3]), np.sin(w[:, 2:3])
        M = np.stack(
            [c * R[:, 0] + s * R[:, 1], c * R[:, 1] - s * R[:, 0], R[:, 2]], axis=1
        )  # hand → object
        dx, dy = t[:, 0] - w[:, 0], t[:, 1] - w[:, 1]
        b = np.stack([c[:, 0] * dx + s[:, 0] * dy, c[:, 0] * dy - s[:, 0] * dx, t[:, 2]], axis=1)
        X = M @ self._link_coords + b[:, :, None]  # (N, 3, L) object frame
        near = self._near_object(X[:, 0], X[:, 1], X[:, 2], self._link_r, per_part=True)
        near |= X[:, 2] < self._link_r  # the table: object-frame z is height above it
        return near.reshape((len(w),) + self._link_shape).any(axis=3)

    # ------------------------------------------------------------ candidates in order
    def _sweep_rest(self, framed: _FramedPath, w: np.ndarray, resume: int) -> Iterator[int]:
        """The coarse samples a sweep with the object at w (3,) tests past ``resume``, where the
        first scan stopped: scanned only if the sweep gets there."""
        if resume < self.path.n_coarse:
            rest, _ = self._sweep_candidates(
                framed, w[None], np.array([resume]), limit=self.path.n_coarse
            )
            yield from np.flatnonzero(rest[0]).tolist()

    def _closing_rest(
        self, T_stop: np.ndarray, w: np.ndarray, resume: int, f: int
    ) -> Iterator[int]:
        """Finger f's coarse closing angles to test past ``resume``, where its first scan
        stopped, for the hand stopped at T_stop (4,4) and the object at w (3,): scanned only if
        the closing gets there."""
        n_a = self._link_shape[0]
        if resume < n_a:
            start = np.full((1, 3), n_a)
            start[0, f] = resume
            rest, _ = self._closing_candidates(T_stop[None], w[None], start, limit=n_a)
            yield from np.flatnonzero(rest[0, :, f]).tolist()

    # ------------------------------------------------------------ one execution
    def _sweep(self, framed: _FramedPath, candidates: Iterable[int]) -> int | None:
        """Fine index of the first touching sample (bisected), or None if the path is free.

        candidates: the coarse samples that may touch, in order (the others are free).

        On a hit, the last collision query was at the returned sample (its contacts are current).
        """
        q, m, d, a = framed.palm_qpos, self.model, self.data, self._palm_adr
        qpos, kinematics, collision = self._qpos, mujoco.mj_kinematics, mujoco.mj_collision

        def touch(k: int) -> int:
            qpos[a : a + 7] = q[k]
            kinematics(m, d)
            collision(m, d)
            return d.ncon

        for c in candidates:
            if touch(c * FINE_PATH):
                break
        else:
            return None
        hi = c * FINE_PATH
        lo = hi - FINE_PATH  # free: tested, or not a candidate
        if lo < 0:
            return hi
        last_touched = True
        while hi - lo > 1:
            mid = (lo + hi) // 2
            last_touched = touch(mid) > 0
            if last_touched:
                hi = mid
            else:
                lo = mid
        if not last_touched:
            touch(hi)
        return hi

    def _close(self, candidates: Sequence[Iterable[int]]) -> tuple[list[int], bool]:
        """Fine closing-angle index per finger where it stops (touching, or its limit), and
        whether any finger touched.

        candidates: per finger, its coarse angles that may touch, in order. Fingers step
        together through their candidates (the other angles are free); one that touches is
        bisected back to its first touching fine angle.
        """
        last = len(self._angles) - 1
        todo = [iter(c) for c in candidates]
        upcoming = [next(t, None) for t in todo]
        final = [last] * 3
        active = [f for f in range(3) if upcoming[f] is not None]
        touched = False
        while active:
            cur = final[:]
            for f in active:
                cur[f] = upcoming[f] * FINE_CLOSE
            self._set_fingers(cur)
            self._collide()
            touching = self._touching_fingers()
            hit = [f for f in active if f in touching]
            if hit:
                lo = {f: cur[f] - FINE_CLOSE for f in hit}
                hi = {f: cur[f] for f in hit}
                refine = [f for f in hit if lo[f] >= 0]
                while refine:
                    mid = cur[:]
                    for f in refine:
                        mid[f] = (lo[f] + hi[f]) // 2
                    self._set_fingers(mid)
                    self._collide()
                    touching = self._touching_fingers()
                    for f in refine:
                        if f in touching:
                            hi[f] = mid[f]
                        else:
                            lo[f] = mid[f]
                    refine = [f for f in refine if hi[f] - lo[f] > 1]
                for f in hit:
                    final[f] = hi[f]
                    active.remove(f)
                touched = True
            for f in active[:]:
                upcoming[f] = next(todo[f], None)
                if upcoming[f] is None:
                    active.remove(f)
        return final, touched

    def _contact_arrays(self):
        """Current contacts (after a _collide): geoms (n,2), positions (n,3), normals (n,3),
        depths (n,)."""
        n, con = self.data.ncon, self.data.contact
        return con.geom[:n], con.pos[:n], con.frame[:n, :3], con.dist[:n]

    def _sensors(self, geoms: np.ndarray) -> np.ndarray:
        sensors = np.zeros(N_SENSORS, bool)
        s = self._sensor_of_geom[geoms].max(axis=1)
        sensors[s[s >= 0]] = True
        return sensors

    def _tip_contacts(self, geoms, pos, normal, dist, T_stop: np.ndarray):
        """Per-fingertip mean contact point and unit normal (into the tip) in the hand frame.

        The normal is the mean over the tip's contacts, or the deepest contact's where they
        cancel (a tip wedged between two faces).
        """
        points, normals = np.full((3, 3), np.nan), np.full((3, 3), np.nan)
        tip = self._tip_of_geom[geoms]  # (n, 2)
        on_tip = tip.max(axis=1)
        fingers = set(on_tip.tolist()) - {-1}
        if not fingers:
            return points, normals
        # MuJoCo's normal points from geom1 to geom2; flip it where the tip is geom1.
        signed = normal * np.where(tip[:, 0] >= 0, -1.0, 1.0)[:, None]
        R, t = T_stop[:3, :3], T_stop[:3, 3]
        for f in fingers:
            sel = on_tip == f
            n_sum = signed[sel].sum(axis=0)
            norm = math.sqrt(n_sum.dot(n_sum))  # np.linalg.norm's own arithmetic
            if norm < 1e-6:
                on_f = np.flatnonzero(sel)
                n_sum, norm = signed[on_f[np.argmin(dist[on_f])]], 1.0
            points[f] = (pos[sel].sum(axis=0) / np.count_nonzero(sel) - t) @ R  # the mean
            normals[f] = n_sum @ R / norm
        return points, normals

    def _execute(
        self, framed: _FramedPath, w: np.ndarray, reference: bool = False
    ) -> ObservationArrays:
        """Sweep, then close, for objects at w (N,3); everything in the path frame of ``framed``.

        Only objects whose culling leaves something to test go through the per-sample MuJoCo
        loops; the others get the free result (no contact, full path, fingers closed to their
        limit) as arrays, which is what the loops would give them. ``reference``: the loose
        sphere culling and every sample through the loops (the path the fast one is tested
        against).
        """
        n = len(w)
        out = ObservationArrays.empty(n)
        last = len(framed.poses) - 1
        stops = np.full(n, last)
        contact_points = np.full((n, 3), np.nan)
        if reference:
            flagged = self._sweep_candidates_spheres(framed, w)
            to_sweep = range(n)
        else:
            flagged, resume = self._sweep_candidates(framed, w)
            to_sweep = np.flatnonzero(flagged.any(axis=1)).tolist()
        orders = _flagged_in_order(flagged[to_sweep, :, None])
        for k, i in enumerate(to_sweep):
            self._set_object(w[i])
            self._set_fingers(PRESHAPE)
            order = orders[k][0]
            if not reference and resume[i] < self.path.n_coarse:
                order = chain(order, self._sweep_rest(framed, w[i], resume[i]))
            hit = self._sweep(framed, order)
            if hit is not None:
                stops[i] = hit
                geoms, pos, _, _ = self._contact_arrays()
                out.sensors[i], contact_points[i] = self._sensors(geoms), pos.mean(axis=0)
                out.contact[i] = not grasp_arrived(
                    self.wrt.kind, self.path.length - self.path.progress[hit]
                )
        T_stop = framed.poses[stops]
        out.closure[:] = self._angles[-1]
        if reference:
            flagged = self._closing_candidates_spheres(T_stop, w)
            to_close = range(n)
        else:
            flagged, resume = self._closing_candidates(T_stop, w)
            to_close = np.flatnonzero(flagged.any(axis=(1, 2)) | out.contact).tolist()
        orders = _flagged_in_order(flagged[to_close])
        n_a = self._link_shape[0]
        for k, i in enumerate(to_close):
            self._set_object(w[i])
            self._qpos[self._palm_adr : self._palm_adr + 7] = framed.palm_qpos[stops[i]]
            order = orders[k]
            if not reference:
                order = [
                    chain(order[f], self._closing_rest(T_stop[i], w[i], int(resume[i, f]), f))
                    if resume[i, f] < n_a
                    else order[f]
                    for f in range(3)
                ]
            final, touched = self._close(order)
            out.closure[i] = self._angles[final]
            if not (touched or out.contact[i]):
                continue  # nothing touched: the final pose is certified free
            self._set_fingers(final)
            if self._collide():
                geoms, pos, normal, dist = self._contact_arrays()
                out.sensors[i] |= self._sensors(geoms)
                out.tip_points[i], out.tip_normals[i] = self._tip_contacts(
                    geoms, pos, normal, dist, T_stop[i]
                )
        out.progress[:] = self.path.progress[stops]
        out.stop_pose[:] = framed.measured_poses[stops]
        out.motion_dir[:] = self._motion_dirs(framed.poses, stops, contact_points)
        return out

    @staticmethod
    def _motion_dirs(poses: np.ndarray, stops: np.ndarray, points: np.ndarray) -> np.ndarray:
        """(N,3) unit direction the contact point (else the palm origin) moved in the last fine
        step."""
        a = np.where(stops > 0, stops - 1, 0)
        b = np.where(stops > 0, stops, min(1, len(poses) - 1))
        Ta, Tb = poses[a], poses[b]
        p = np.where(np.isnan(points), Tb[:, :3, 3], points)
        local = np.einsum("nji,nj->ni", Tb[:, :3, :3], p - Tb[:, :3, 3])
        d = p - (np.einsum("nij,nj->ni", Ta[:, :3, :3], local) + Ta[:, :3, 3])
        return d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)

    # ------------------------------------------------------------ public API
    def simulate_relative(self, delta) -> Observation:
        """Ω_τ(Δ): execute τ(e) for e = identity with the object at Δ = e⁻¹ ⊕ w.

        hand_pose and motion_dir are in the estimate's frame (``world`` if e were the
        origin); tip points and normals are in the hand frame.
        """
        return self.simulate_batch(np.asarray(delta, dtype=float).reshape(1, 3)).observation(0)

    def simulate(self, w, e) -> Observation:
        """Execute τ(e) = planar_pose(e) @ wrt.poses in ``world`` with the object actually at w.

        The home → first-pose segment is assumed free. hand_pose, motion_dir in ``world``.
        """
        w = np.asarray(w, dtype=float).reshape(1, 3)
        return self._execute(self._frame(planar_pose(e)), w).observation(0)

    def simulate_batch(self, deltas: np.ndarray, chunk: int = 256) -> ObservationArrays:
        """simulate_relative for each of the (N,3) offsets, as arrays."""
        return self._run_batch(self._relative, deltas, chunk, reference=False)

    def simulate_batch_reference(self, deltas: np.ndarray, chunk: int = 256) -> ObservationArrays:
        """simulate_batch the slow way: the sphere culling, every offset through the per-sample
        MuJoCo loops. The reference the fast batch must equal bit for bit (tests)."""
        return self._run_batch(self._relative, deltas, chunk, reference=True)

    def simulate_batch_offset(
        self, deltas: np.ndarray, hand_offset, chunk: int = 256
    ) -> ObservationArrays:
        """simulate_batch with the hand truly displaced by hand_offset (3,) [m] (estimate frame)
        from where the robot measures it, relative to the table and the object (a calibration
        error, the table's height error). Stop poses are reported as measured (undisplaced);
        a zero offset gives simulate_batch's arrays exactly."""
        offset = np.asarray(hand_offset, dtype=float).reshape(3)
        if not offset.any():
            return self.simulate_batch(deltas, chunk)
        F = np.eye(4)
        F[:3, 3] = offset
        return self._run_batch(self._frame(F, measured=np.eye(4)), deltas, chunk, reference=False)

    def _run_batch(
        self, framed: _FramedPath, deltas: np.ndarray, chunk: int, reference: bool
    ) -> ObservationArrays:
        """_execute over (N,3) offsets in blocks of ``chunk``."""
        deltas = np.asarray(deltas, dtype=float).reshape(-1, 3)
        return ObservationArrays.concatenate(
            [
                self._execute(framed, deltas[s : s + chunk], reference)
                for s in range(0, len(deltas), chunk)
            ]
        )
