"""Barrett WAM 7-DOF kinematics: forward kinematics, analytic IK with redundancy resolution,
and the feasibility F_τ(e) of hand paths (joint limits and table clearance, algorithm §4).

Model: Barrett's DH table for the WAM (standard/distal DH: libbarrett's config/wam7w.conf,
docs/sources.md §1, as ``config.WAM``),
T_i = Rz(θ_i) Tz(d_i) Tx(a_i) Rx(α_i). The chain is

    world ─ Tz(base_height) ─ frame 0 ─ J1 … J7 ─ frame 7 ─ TOOL_TRANSFORM ─ hand frame

where frame i-1's z is joint i's axis and TOOL_TRANSFORM = Rx(-α_7) Tz(hand_mount)
Rz(hand_mount_yaw) (the tool plate's α = π/2 of the notes, then the hand mount along J7's
axis). Hence the hand frame is frame 6 ⊕ Rz(q7) ⊕ HAND_MOUNT with HAND_MOUNT =
Tz(d_7 + hand_mount) Rz(hand_mount_yaw): its +z (the approach) is J7's axis.

IK: J1-J3 intersect at the shoulder and J5-J7 at the wrist centre, so for a fixed J3 the
solution is closed-form: J4 from the shoulder-wrist distance (two elbow branches, with the
±0.045 m offsets), J1/J2 from the wrist-centre direction (two branches), J5-J7 as ZYZ Euler
angles of the remaining rotation (two wrist branches). The redundancy is sampled over J3
(``IK_REDUNDANCY_SAMPLES`` values across its range plus the preferred posture's own J3), and
resolved by choosing, among the solutions within joint limits with the arm clear of the
table, the one nearest the preferred posture in unweighted joint space (Σ (q - q_pref)²).
Including q_pref's J3 makes paths from ``ik_path`` keep J3 constant wherever possible.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rrg_models.config import WAM, WORLD
from rrg_models.poses import home_pose, wrap_angle

DH = np.asarray(WAM.dh, dtype=float)  # (7, 3): alpha [rad], a [m], d [m]
LOWER = np.asarray(WAM.lower, dtype=float)
UPPER = np.asarray(WAM.upper, dtype=float)
N_JOINTS = 7

#: J3 samples across its range for the redundancy (chosen: 0.18 rad apart; a side-grasp
#: feasibility map then misses 0.2 % of the cells a 96-sample one finds, a top-down one none).
IK_REDUNDANCY_SAMPLES = 32

_LIMIT_TOL = 1e-9  # rad, slack on the joint limits for round-off
_RESIDUAL_TOL = (
    1e-6  # m and rad: an analytic solution farther than this from its target is rejected
)
_UPPER_ARM = DH[2, 2]  # d3 [m], shoulder to elbow along the upper arm
_FOREARM = DH[4, 2]  # d5 [m], elbow to wrist centre
_A3, _A4 = DH[2, 1], DH[3, 1]  # elbow offsets [m] (+0.045, -0.045)
SHOULDER = np.array([0.0, 0.0, WAM.base_height])  # where J1-J3 intersect, in world [m]
#: Arm points (elbow, wrist centre) must stay above this height over the table [m].
CLEARANCE_Z = WORLD.table_top_z + WAM.link_radius + WAM.table_clearance


def dh_transform(alpha, a, d, theta) -> np.ndarray:
    """Standard DH link transform Rz(θ) Tz(d) Tx(a) Rx(α), broadcast over all
    arguments → (…,4,4)."""
    alpha, a, d, theta = np.broadcast_arrays(
        *(np.asarray(v, dtype=float) for v in (alpha, a, d, theta))
    )
    ca, sa, ct, st = np.cos(alpha), np.sin(alpha), np.cos(theta), np.sin(theta)
    T = np.zeros(theta.shape + (4, 4))
    T[..., 0, 0], T[..., 0, 1], T[..., 0, 2], T[..., 0, 3] = ct, -st * ca, st * sa, a * ct
    T[..., 1, 0], T[..., 1, 1], T[..., 1, 2], T[..., 1, 3] = st, ct * ca, -ct * sa, a * st
    T[..., 2, 1], T[..., 2, 2], T[..., 2, 3] = sa, ca, d
    T[..., 3, 3] = 1.0
    return T


#: world → frame 0 (J1's axis is frame 0's z).
BASE_TRANSFORM = dh_transform(0.0, 0.0, WAM.base_height, 0.0)
#: frame 7 → hand frame: undo J7's α (the tool plate), then the hand mount along J7's axis.
TOOL_TRANSFORM = dh_transform(-DH[6, 0], 0.0, 0.0, 0.0) @ dh_transform(
    0.0, 0.0, WAM.hand_mount, WAM.hand_mount_yaw
)
#: J7's rotating body (frame 6 ⊕ Rz(q7), origin at the wrist centre) → hand frame.
HAND_MOUNT = dh_transform(DH[6, 0], 0.0, DH[6, 2], 0.0) @ TOOL_TRANSFORM
_HAND_TO_J7 = np.linalg.inv(HAND_MOUNT)


def fk_frames(q) -> np.ndarray:
    """Joint angles (…,7) → (…,9,4,4) frames in world: frame 0 (at the base height), frames
    1…7 (after each joint; frame i-1's z is joint i's axis, through its origin), the hand frame."""
    q = np.asarray(q, dtype=float)
    links = dh_transform(DH[:, 0], DH[:, 1], DH[:, 2], q)  # (…,7,4,4)
    frames = np.empty(q.shape[:-1] + (9, 4, 4))
    frames[..., 0, :, :] = BASE_TRANSFORM
    for i in range(N_JOINTS):
        frames[..., i + 1, :, :] = frames[..., i, :, :] @ links[..., i, :, :]
    frames[..., 8, :, :] = frames[..., 7, :, :] @ TOOL_TRANSFORM
    return frames


def fk(q) -> np.ndarray:
    """Joint angles (…,7) → hand-frame pose(s) (…,4,4) in world."""
    return fk_frames(q)[..., 8, :, :]


def arm_points(q) -> np.ndarray:
    """(…,7) → (…,3,3): the elbow (frames 3 and 4 origins, either side of J4's 0.045 m offset)
    and the wrist centre (frame 5 origin), the points kept clear of the table."""
    return fk_frames(q)[..., 3:6, :3, 3]


def point_clear_of_table(x, y, z) -> np.ndarray:
    """Arm point coordinates [m] (broadcast) → True unless the point lies over the table's
    x/y extent lower than ``CLEARANCE_Z`` (points beside the table are unconstrained)."""
    over = (
        (x >= WORLD.table_x[0])
        & (x <= WORLD.table_x[1])
        & (y >= WORLD.table_y[0])
        & (y <= WORLD.table_y[1])
    )
    return ~(over & (z < CLEARANCE_Z))


def points_clear_of_table(points: np.ndarray) -> np.ndarray:
    """(…,P,3) arm points → (…,) True when every point clears the table."""
    return np.all(point_clear_of_table(points[..., 0], points[..., 1], points[..., 2]), axis=-1)


def arm_clear_of_table(q) -> np.ndarray:
    """(…,7) joint angles → (…,) True when the elbow and wrist centre clear the table."""
    return points_clear_of_table(arm_points(q))


def links_clearance(q, centre_xy, radius: float, top: float) -> np.ndarray:
    """(…,7) → (…,) least clearance [m] of the arm's links (frames 3-8 and the midpoints
    between them, each a WAM.link_radius ball) from the vertical cylinder of ``radius`` [m]
    about ``centre_xy`` (2,) up to height ``top`` [m]: beside it or above it."""
    origins = fk_frames(q)[..., 3:9, :3, 3]
    points = np.concatenate([origins, 0.5 * (origins[..., 1:, :] + origins[..., :-1, :])], -2)
    beside = np.linalg.norm(points[..., :2] - np.asarray(centre_xy), axis=-1) - radius
    above = points[..., 2] - top
    return np.maximum(beside, above).min(axis=-1) - WAM.link_radius


def within_limits(q) -> np.ndarray:
    """(…,7) → (…,) True when every joint lies within its limits."""
    q = np.asarray(q, dtype=float)
    return np.all((q >= LOWER - _LIMIT_TOL) & (q <= UPPER + _LIMIT_TOL), axis=-1)


def _into_limits(q: np.ndarray, joint: int) -> np.ndarray:
    """Angle(s) of one joint → the 2π-equivalent inside its range where one exists (J5 spans
    more than π on one side), else the wrapped angle (then rejected by the limit check)."""
    q = wrap_angle(q)
    q = np.where(q > UPPER[joint] + _LIMIT_TOL, q - 2 * np.pi, q)
    return np.where(q < LOWER[joint] - _LIMIT_TOL, q + 2 * np.pi, q)


def _in_range(
    c: np.ndarray, s: np.ndarray, joint: int, norm: float | np.ndarray = 1.0
) -> np.ndarray:
    """Joint angle given as (c, s) = norm·(cos, sin) within its limits: cos(q - mid) ≥
    cos(half range) (every WAM range spans less than 2π)."""
    mid, half = (UPPER[joint] + LOWER[joint]) / 2, (UPPER[joint] - LOWER[joint]) / 2
    return c * np.cos(mid) + s * np.sin(mid) >= np.cos(half + _LIMIT_TOL) * norm


def _j3_samples(n_poses: int, q_pref: np.ndarray | None) -> np.ndarray:
    """(M,S) J3 values to try per pose: a uniform sweep of J3's range, plus q_pref's own J3."""
    sweep = np.linspace(LOWER[2], UPPER[2], IK_REDUNDANCY_SAMPLES)
    if q_pref is None:
        return np.broadcast_to(sweep, (n_poses, sweep.size))
    own = np.clip(np.broadcast_to(q_pref[..., 2], (n_poses,)), LOWER[2], UPPER[2])
    return np.concatenate([own[:, None], np.broadcast_to(sweep, (n_poses, sweep.size))], axis=1)


_BRANCH = np.array([1.0, -1.0])
#: Axes of the dense solution arrays (pose innermost, so numpy's inner loops run over poses).
SOLUTION_AXES = ("wrist branch", "shoulder branch", "elbow branch", "J3 sample", "pose")


@dataclass(frozen=True)
class IkSolutions:
    """Closed-form IK solutions of M hand poses, dense over ``SOLUTION_AXES`` (2, 2, 2, S, M).
    Validity is decided from cosines and sines; joint angles are computed on request (``angles``).

    valid (2,2,2,S,M): the solution exists, J2-J7 lie within their limits, and so does J1 if
    solved with ``check_j1``; wrist singularities (J5 ∥ J7) are left out.
    elbows (2,3,2,2,S,M): origins of frames 3 and 4 (axis 0), x/y/z (axis 1), in world [m].
    wrist (3,M): the wrist centre in world [m]. The rest are the terms the angles come from.
    """

    valid: np.ndarray
    elbows: np.ndarray
    wrist: np.ndarray
    q3: np.ndarray  # (S,M)
    q4: np.ndarray  # (2,M)
    cs12: np.ndarray  # (4,2,2,S,M): cos q1, sin q1, cos q2, sin q2
    w: np.ndarray  # (5,2,2,S,M): W02, W12, W22, W20, W21 of W = Rz(q5) Ry(q6) Rz(q7)

    def clear_of_table(self) -> np.ndarray:
        """(2,2,S,M): the elbow points and the wrist centre clear the table."""
        e3, e4 = self.elbows
        return (
            point_clear_of_table(*e3)
            & point_clear_of_table(*e4)
            & point_clear_of_table(*self.wrist)
        )

    def usable(self) -> np.ndarray:
        """(2,2,2,S,M): within the joint limits and clear of the table."""
        return self.valid & self.clear_of_table()

    def angles(self) -> np.ndarray:
        """(7,2,2,2,S,M) joint angles [rad] of every solution (meaningful where ``valid``)."""
        c1, s1, c2, s2 = self.cs12
        W02, W12, W22, W20, W21 = self.w
        flip = np.array([0.0, np.pi])[
            :, None, None, None, None
        ]  # 2nd wrist branch: q5 + π, -q6, q7 + π
        q = np.empty((N_JOINTS,) + self.valid.shape)
        q[0], q[1] = np.arctan2(s1, c1), np.arctan2(s2, c2)
        q[2], q[3] = self.q3, self.q4[:, None, :]
        q[4] = _into_limits(np.arctan2(W12, W02) + flip, 4)
        q[5] = np.arctan2(np.sqrt(W02 * W02 + W12 * W12), W22) * _BRANCH[:, None, None, None, None]
        q[6] = _into_limits(np.arctan2(W21, -W20) + flip, 6)
        return q


def ik_solutions(T, q_pref=None, check_j1: bool = True) -> IkSolutions:
    """Every closed-form solution of hand poses T (M,4,4) over the sampled J3 values.

    Uses R02 = Rz(q1) Ry(q2), R24 = Rz(q3) Ry(q4) and R46 = Rz(q5) Ry(q6) (the α = ∓π/2 pairs of
    the DH table). Arrays broadcast over ``SOLUTION_AXES``. q_pref (7,) or (M,7), if given,
    adds its J3 to the samples.
    """
    T = np.asarray(T, dtype=float)
    M = T.shape[0]
    T_j7 = (
        T @ _HAND_TO_J7
    )  # J7's body: origin at the wrist centre, rotation R04 Rz(q5) Ry(q6) Rz(q7)
    wrist = np.ascontiguousarray(T_j7[:, :3, 3].T)  # (3,M)
    px, py, pz = wrist - SHOULDER[:, None]
    X7, Y7, Z7 = (np.ascontiguousarray(T_j7[:, :3, j].T) for j in range(3))  # hand axes (3,M)
    # J4 from |wrist|² = k0 + B cos q4 + A sin q4 (elbow branches ±).
    A = 2 * (_A3 * _FOREARM - _UPPER_ARM * _A4)
    B = 2 * (_A3 * _A4 + _UPPER_ARM * _FOREARM)
    k0 = _A3**2 + _A4**2 + _UPPER_ARM**2 + _FOREARM**2
    ratio = (px**2 + py**2 + pz**2 - k0) / np.hypot(A, B)
    spread = np.arccos(np.clip(ratio, -1.0, 1.0))
    q4 = _into_limits(np.arctan2(A, B) + spread * _BRANCH[:, None], 3)  # (2,M)
    c4, s4 = np.cos(q4)[:, None], np.sin(q4)[:, None]  # (2,1,M)
    q3 = np.ascontiguousarray(_j3_samples(M, q_pref).T)  # (S,M)
    c3, s3 = np.cos(q3), np.sin(q3)
    # Wrist centre in frame 2: Rz(q3) (x4, 0, z4).
    x4 = _A3 + _A4 * c4 + _FOREARM * s4
    z4 = _UPPER_ARM - _A4 * s4 + _FOREARM * c4
    x, y = x4 * c3, x4 * s3  # (2,S,M)
    # J1, J2: wrist = Rz(q1) (P, y, pz) with P = c2 x + s2 z = ±sqrt(r² - y²), pz = c2 z - s2 x.
    r2 = px**2 + py**2
    p_sq = r2 - y**2
    P = np.sqrt(np.maximum(p_sq, 0.0)) * _BRANCH[:, None, None, None]  # (2,2,S,M)
    r2_safe = np.maximum(r2, 1e-12)
    c1, s1 = (px * P + py * y) / r2_safe, (py * P - px * y) / r2_safe
    d2 = x**2 + z4**2
    c2, s2 = (x * P + z4 * pz) / d2, (z4 * P - x * pz) / d2
    ok = (
        (np.abs(ratio) <= 1.0)
        & (p_sq >= 0.0)
        & (r2 > 1e-12)
        & _in_range(c2, s2, 1)
        & _in_range(c4, s4, 3)
    )
    if check_j1:
        ok = ok & _in_range(c1, s1, 0)

    def from_frame2(v):  # R02 v for a frame-2 vector v = (vx, vy, vz)
        g = c2 * v[0] + s2 * v[2]
        return c1 * g - s1 * v[1], s1 * g + c1 * v[1], c2 * v[2] - s2 * v[0]

    elbow3_2 = (_A3 * c3, _A3 * s3, _UPPER_ARM)
    elbow4_2 = tuple(e + _A4 * v for e, v in zip(elbow3_2, (c3 * c4, s3 * c4, -s4)))
    elbows = np.empty((2, 3) + P.shape)
    for i, e in enumerate((elbow3_2, elbow4_2)):
        for j, comp in enumerate(from_frame2(e)):
            np.add(comp, SHOULDER[j], out=elbows[i, j])
    # J5-J7: W = R24ᵀ R02ᵀ R_j7 = Rz(q5) Ry(q6) Rz(q7) (ZYZ Euler angles).
    h = c1 * Z7[0] + s1 * Z7[1]
    ux, uy, uz = c2 * h - s2 * Z7[2], c1 * Z7[1] - s1 * Z7[0], s2 * h + c2 * Z7[2]  # R02ᵀ z7
    m = c3 * ux + s3 * uy
    W02, W12, W22 = c4 * m - s4 * uz, c3 * uy - s3 * ux, s4 * m + c4 * uz
    f = [(wrist[j] - elbows[1, j]) / _FOREARM for j in range(3)]  # R04 z: J5's axis
    W20 = f[0] * X7[0] + f[1] * X7[1] + f[2] * X7[2]
    W21 = f[0] * Y7[0] + f[1] * Y7[1] + f[2] * Y7[2]
    s6 = np.sqrt(W02 * W02 + W12 * W12)  # |sin q6|
    ok &= s6 > 1e-9
    # Wrist branches ±: (q5, q6, q7) = (atan2(W12, W02), atan2(s6, W22), atan2(W21, -W20)),
    # or (q5 + π, -q6, q7 + π).
    valid = np.stack(
        [
            ok
            & _in_range(W22, sign * s6, 5)
            & _in_range(sign * W02, sign * W12, 4, s6)
            & _in_range(-sign * W20, sign * W21, 6, s6)
            for sign in _BRANCH
        ]
    )
    return IkSolutions(
        valid,
        elbows,
        wrist,
        q3,
        q4,
        np.stack([c1, s1, c2, s2]),
        np.stack([W02, W12, W22, W20, W21]),
    )


#: Poses per ik_solutions call (chosen: keeps the ~ 40 temporaries cache-sized;
#: 3x faster than 2048).
BATCH_CHUNK = 128


def _pose_error(T_a: np.ndarray, T_b: np.ndarray) -> np.ndarray:
    """(…,4,4) pairs → max of position error [m] and rotation-matrix error (≈ rad)."""
    dp = np.linalg.norm(T_a[..., :3, 3] - T_b[..., :3, 3], axis=-1)
    dR = np.abs(T_a[..., :3, :3] - T_b[..., :3, :3]).max(axis=(-1, -2))
    return np.maximum(dp, dR)


def _nearest_usable(sol: IkSolutions, q_pref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per pose, the usable solution nearest q_pref (M,7) in joint space → (q (M,7), found (M,))."""
    q = sol.angles().reshape(N_JOINTS, -1, q_pref.shape[0])
    cost = np.where(
        sol.usable().reshape(q.shape[1:]), np.sum((q - q_pref.T[:, None, :]) ** 2, axis=0), np.inf
    )
    best = np.argmin(cost, axis=0)
    poses = np.arange(q_pref.shape[0])
    return q[:, best, poses].T, np.isfinite(cost[best, poses])


def ik_batch(T, q_pref=None) -> tuple[np.ndarray, np.ndarray]:
    """IK of hand poses T (M,4,4) → (q (M,7), ok (M,)).

    Each solution lies within the joint limits with the elbow and wrist centre clear of the
    table, and is the sampled solution nearest q_pref ((7,) or (M,7); default HOME_Q) in
    joint space. Rows without a solution have ok False and q NaN.
    """
    T = np.asarray(T, dtype=float)
    M = T.shape[0]
    q_pref = np.broadcast_to(
        HOME_Q if q_pref is None else np.asarray(q_pref, dtype=float), (M, N_JOINTS)
    )
    q = np.empty((M, N_JOINTS))
    ok = np.empty(M, dtype=bool)
    for lo in range(0, M, BATCH_CHUNK):
        part = slice(lo, lo + BATCH_CHUNK)
        q[part], ok[part] = _nearest_usable(ik_solutions(T[part], q_pref[part]), q_pref[part])
    ok[ok] = _pose_error(fk(q[ok]), T[ok]) < _RESIDUAL_TOL
    q[~ok] = np.nan
    return q, ok


def ik(T, q_seed=None) -> tuple[np.ndarray, bool]:
    """IK of one hand pose (4,4) → (q (7,), ok); the solution nearest q_seed (default HOME_Q)."""
    q, ok = ik_batch(np.asarray(T, dtype=float)[None], q_seed)
    return q[0], bool(ok[0])


def ik_path(Ts, q_start=None) -> tuple[np.ndarray, np.ndarray]:
    """Joint via-points (K,7) for hand poses Ts (K,4,4), each the solution nearest the previous
    one (the first nearest q_start, default HOME_Q), and ok (K,). After a failed waypoint the
    next one continues from the last solved posture."""
    Ts = np.asarray(Ts, dtype=float)
    qs = np.full((Ts.shape[0], N_JOINTS), np.nan)
    ok = np.zeros(Ts.shape[0], dtype=bool)
    q_prev = HOME_Q if q_start is None else np.asarray(q_start, dtype=float)
    for k, T in enumerate(Ts):
        qs[k], ok[k] = ik(T, q_prev)
        if ok[k]:
            q_prev = qs[k]
    return qs, ok


def reachable(T) -> np.ndarray:
    """(…,4,4) hand poses → (…,) True where some sampled IK solution respects the joint
    limits and keeps the elbow and wrist centre clear of the table."""
    T = np.asarray(T, dtype=float)
    flat = T.reshape(-1, 4, 4)
    ok = np.zeros(flat.shape[0], dtype=bool)
    for lo in range(0, flat.shape[0], BATCH_CHUNK):
        usable = ik_solutions(flat[lo : lo + BATCH_CHUNK]).usable()
        ok[lo : lo + BATCH_CHUNK] = usable.reshape(-1, usable.shape[-1]).any(axis=0)
    return ok.reshape(T.shape[:-2])


def feasible_paths(Ts) -> np.ndarray:
    """(…,K,4,4) hand paths → (…,) F_τ: every waypoint reachable (``reachable``)."""
    return np.all(reachable(Ts), axis=-1)


def feasible_path(Ts) -> bool:
    """F_τ(e) for one hand path τ(e) (K,4,4) in world (algorithm §4)."""
    return bool(feasible_paths(Ts))


def _home_q() -> np.ndarray:
    """HOME_Q: home_pose() solved nearest the upright arm (all zeros): J1 = J3 = 0, elbow up."""
    q, ok = ik_batch(home_pose()[None], np.zeros(N_JOINTS))
    if not ok[0]:
        raise RuntimeError("home_pose() is unreachable for the WAM model in config")
    return q[0]


HOME_Q = _home_q()
"""Joint angles [rad] of rrg_models.poses.home_pose()."""
