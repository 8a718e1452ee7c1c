"""The geometric simulator: predicted observations of a WRT, kinematically (design §2, §5).

The hand sweeps along the WRT's path until it first touches the object or the table, then
each finger closes until it touches something or reaches its limit. Only positions are
computed (no dynamics): the object never moves. Collisions come from MuJoCo on a small
*probe* model per object and WRT:

* the table top as the plane z = 0 (static, in ``world``);
* the object as a free body holding its collision primitives (its qpos sets the pose w);
* the hand from ``rrg_sim.hand.hand_tree()`` as one articulated free body (palm pose and
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

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from .config import GEOMSIM, N_SENSORS
from .hand import FINGERS, LINKS, BodySpec, GeomSpec, body_poses, hand_tree, joint_angles
from .objects.primitives import Primitive, mjcf_mesh_asset, rotated_half_extents, union_bounds
from .observation import Observation, grasp_arrived
from .poses import planar_pose
from .wrt import WRT

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

    Fields as in rrg_sim.observation.Observation; stop_pose is the hand pose at the stop.
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


# ------------------------------------------------------------------ the simulator
@dataclass(frozen=True)
class _FramedPath:
    """The swept path placed in one path frame: what a sweep needs, precomputed."""

    poses: np.ndarray  # (S,4,4) fine hand poses
    palm_qpos: np.ndarray  # (S,7)
    centres: np.ndarray  # (S_coarse·G, 3) hand sphere centres at the coarse samples
    table_hit: int  # first coarse sample touching the table (n_coarse if none)


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
        self._part_rot = np.stack(
            [
                Rotation.from_quat(np.asarray(p.quat, float), scalar_first=True).as_matrix()
                for p in obj.parts
            ]
        )
        self._part_centre = np.array([p.pos for p in obj.parts], float)
        self._part_half = np.array([p.local_half_extents() for p in obj.parts])
        self.path = SweptPath.from_wrt(wrt)
        self._init_sweep_spheres()
        self._init_closing()
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

    def _frame(self, F: np.ndarray) -> _FramedPath:
        """The path placed in path frame F, with its table-contact sample found by a sweep."""
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
        return _FramedPath(poses, palm_qpos, centres, table_hit)

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
        local = np.matmul(X[None] - self._part_centre[:, None], self._part_rot)  # (P, K, 3)
        gap = np.maximum(np.abs(local) - self._part_half[:, None], 0.0)
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
        if per_part and len(self._part_half) > 1:
            idx = np.nonzero(near)
            X = np.stack([np.broadcast_to(v, near.shape)[idx] for v in (x, y, z)], axis=1)
            near[idx] = self._near_parts(X, np.broadcast_to(r, near.shape)[idx])
        return near

    # ------------------------------------------------------------ culling
    def _sweep_candidates(self, framed: _FramedPath, w: np.ndarray) -> np.ndarray:
        """(N, S_coarse) bool: coarse samples where the hand may touch the object at w[n] or the
        table.

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

    def _closing_candidates(self, T_stop: np.ndarray, w: np.ndarray) -> np.ndarray:
        """(N, A_coarse, 3) bool: coarse closing angles where each finger may touch the object or
        the table, for hands stopped at T_stop (N,4,4) with the objects at w (N,3).

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

    # ------------------------------------------------------------ one execution
    def _sweep(self, framed: _FramedPath, candidates: np.ndarray) -> int | None:
        """Fine index of the first touching sample (bisected), or None if the path is free.

        On a hit, the last collision query was at the returned sample (its contacts are current).
        """
        q, m, d, a = framed.palm_qpos, self.model, self.data, self._palm_adr
        qpos, kinematics, collision = self._qpos, mujoco.mj_kinematics, mujoco.mj_collision

        def touch(k: int) -> int:
            qpos[a : a + 7] = q[k]
            kinematics(m, d)
            collision(m, d)
            return d.ncon

        for c in np.flatnonzero(candidates).tolist():
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

    def _close(self, candidates: np.ndarray) -> tuple[list[int], bool]:
        """Fine closing-angle index per finger where it stops (touching, or its limit), and
        whether any finger touched.

        candidates: (A_coarse, 3). Fingers step together through their candidate coarse
        angles (the others are free); one that touches is bisected back to its first touching
        fine angle.
        """
        last = len(self._angles) - 1
        fingers, coarse = np.nonzero(candidates.T)
        todo = [(coarse[fingers == f] * FINE_CLOSE).tolist() for f in range(3)]
        final, ptr = [last] * 3, [0] * 3
        active = [f for f in range(3) if todo[f]]
        touched = False
        while active:
            cur = final[:]
            for f in active:
                cur[f] = todo[f][ptr[f]]
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
                ptr[f] += 1
                if ptr[f] == len(todo[f]):
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
            sel = np.flatnonzero(on_tip == f)
            n_sum = signed[sel].sum(axis=0)
            norm = np.linalg.norm(n_sum)
            if norm < 1e-6:
                n_sum, norm = signed[sel[np.argmin(dist[sel])]], 1.0
            points[f] = (pos[sel].mean(axis=0) - t) @ R
            normals[f] = n_sum @ R / norm
        return points, normals

    def _execute(
        self, framed: _FramedPath, w: np.ndarray, sweep_candidates: np.ndarray
    ) -> ObservationArrays:
        """Sweep, then close, for objects at w (N,3); everything in the path frame of ``framed``."""
        n = len(w)
        out = ObservationArrays.empty(n)
        stops = np.empty(n, int)
        contact_points = np.full((n, 3), np.nan)
        for i in range(n):
            self._set_object(w[i])
            self._set_fingers(PRESHAPE)
            hit = self._sweep(framed, sweep_candidates[i])
            stops[i] = len(framed.poses) - 1 if hit is None else hit
            if hit is not None:
                geoms, pos, _, _ = self._contact_arrays()
                out.sensors[i], contact_points[i] = self._sensors(geoms), pos.mean(axis=0)
                out.contact[i] = not grasp_arrived(
                    self.wrt.kind, self.path.length - self.path.progress[hit]
                )
        T_stop = framed.poses[stops]
        close_candidates = self._closing_candidates(T_stop, w)
        for i in range(n):
            self._set_object(w[i])
            self._qpos[self._palm_adr : self._palm_adr + 7] = framed.palm_qpos[stops[i]]
            final, touched = self._close(close_candidates[i])
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
        out.stop_pose[:] = T_stop
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
        framed = self._frame(planar_pose(e))
        return self._execute(framed, w, self._sweep_candidates(framed, w)).observation(0)

    def simulate_batch(self, deltas: np.ndarray, chunk: int = 256) -> ObservationArrays:
        """simulate_relative for each of the (N,3) offsets, as arrays."""
        deltas = np.asarray(deltas, dtype=float).reshape(-1, 3)
        return ObservationArrays.concatenate(
            [
                self._execute(self._relative, block, self._sweep_candidates(self._relative, block))
                for block in (deltas[s : s + chunk] for s in range(0, len(deltas), chunk))
            ]
        )
