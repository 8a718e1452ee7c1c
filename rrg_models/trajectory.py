"""Hand paths for the physics arm: Cartesian densification, IK to joint via-points, timing.

A ``DensePath`` samples straight Cartesian segments between hand poses about every
``PHYSICS.path_step`` (the geometric simulator assumes straight lines, so the arm must follow
them closely) and solves them with the core's IK. ``wam.ik_path`` picks, pose after pose, the
solution nearest the previous one, which flips the wrist (J5, J7 by π) where a path passes
near the wrist singularity; here every dense pose is solved over all of ``wam.ik_solutions``'s
branches and J3 samples, and a dynamic programme picks the continuous chain (neighbouring
samples less than MAX_JOINT_STEP apart) with the least joint motion. J3 is held along a
WRT's own segments, whose straightness the geometric simulator relies on, and may walk
between neighbouring samples (an elbow swivel on the way) on free-space moves. When the
chain starts in another configuration than the arm's, the arm first swivels its elbow in
place (same hand pose) or, from home, rises and reconfigures in joint space. Chains keep
LIMIT_MARGIN inside the joint limits where they can, and a grasp's chain is chosen through
the lift that follows it (``plan_path``'s ``then``), so that the arm can lift what it grasped.
``sample_times`` times a dense path with a trapezoidal speed profile per segment (rest at
every waypoint): these are the joint via-points' times of a guarded move. ``servo_targets``
turns timed via-points into servo targets for every control period.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rrg_models import wam
from rrg_models.config import GEOMSIM, PHYSICS
from rrg_models.poses import interpolate_poses, raised
from rrg_models.wrt import InfeasibleWRT

#: Time to reach cruise speed on a segment [s] (chosen: 2 m/s² at 0.2 m/s, a smooth WAM move).
ACCEL_TIME = 0.1
#: Joint-space metric of the IK chain: joint j counts 1/joint_speed_j (scaled so J1-J4 count
#: in rad), so the least-motion chain is about the fastest one.
JOINT_METRIC = min(PHYSICS.joint_speed) / np.asarray(PHYSICS.joint_speed)
#: Largest step (Euclidean norm in that metric) between neighbouring dense poses of one IK
#: chain [rad] (chosen: 1 cm Cartesian steps need < 0.1 rad away from singularities; a wrist
#: flip needs ~ π; between 0.3 and 0.45 paths near the wrist singularity break up).
MAX_JOINT_STEP = 0.45
#: Weight of the distance from the current configuration in the chain's cost (chosen: moving
#: there costs as much as moving along the path).
START_WEIGHT = 1.0
#: A chain ``from_prev`` starts at the IK solution this close to q_prev [rad] (round-off).
START_TOLERANCE = 1e-6
#: Height the hand rises at home before changing IK branch by a joint-space move [m] (chosen:
#: the fingertips then clear the tallest object, the 28 cm cooler, by ~ 10 cm).
RECONFIGURE_LIFT = 0.15
#: Planned paths keep this far inside every joint limit where they can [rad] (chosen: the
#: smoothed servo targets overshoot a via-point by up to ~ 0.01 rad, and a joint pressed on
#: its limit stop trips the arm's collision detection like a contact) ...
LIMIT_MARGIN = 0.03
#: ... each sample inside that margin costs this much in the chain's cost [rad²] (chosen: as
#: much as 5 of the largest steps, so a chain detours around the margin but still passes
#: through it where nothing else reaches the path: some top-down grasps touch J6's limit).
LIMIT_PENALTY = 5 * MAX_JOINT_STEP**2
#: Joint-space sampling of a free move [rad].
JOINT_STEP = 0.05
#: Width of the moving average smoothing the joint targets [control periods] (chosen: 20 ms,
#: so a speed change between dense samples takes ≥ 40 ms, not one 2 ms period).
SMOOTH_STEPS = 11
#: Time holding the final target at the end of a move so the servos settle [s] (chosen: the
#: velocity feed-forward leaves a lag of a few ms).
SETTLE_TIME = 0.04


class InfeasiblePath(InfeasibleWRT):
    """No continuous joint path follows the requested hand poses (IK or joint limits)."""


def rotation_angles(T0: np.ndarray, T1: np.ndarray) -> np.ndarray:
    """Angles [rad] of the relative rotations between (…,4,4) transforms T0 and T1."""
    cos = (np.einsum("...ij,...ij->...", T0[..., :3, :3], T1[..., :3, :3]) - 1.0) / 2.0
    return np.arccos(np.clip(cos, -1.0, 1.0))


@dataclass(frozen=True)
class DensePath:
    """Hand poses (M,4,4) in world, joint angles (M,7), and segment index (M,) of each sample
    (sample 0 is the start; segment k ≥ 0 leads to waypoint k; negative: lead-in moves)."""

    poses: np.ndarray
    q: np.ndarray
    segment: np.ndarray
    #: The chain ``plan_path`` chose through its ``then`` waypoints, continuing from the last
    #: sample (not part of the path; segment k leads to then[k]); None without them.
    after: DensePath | None = None

    @property
    def arc(self) -> np.ndarray:
        """(M,) cumulative palm (hand-frame origin) path length [m]."""
        steps = np.linalg.norm(np.diff(self.poses[:, :3, 3], axis=0), axis=1)
        return np.r_[0.0, np.cumsum(steps)]

    def upto(self, index: int) -> DensePath:
        """The samples 0..index."""
        return DensePath(self.poses[: index + 1], self.q[: index + 1], self.segment[: index + 1])

    def then_path(self) -> DensePath | None:
        """The path's last sample followed by ``after`` (segment 0); None without it."""
        if self.after is None:
            return None
        return DensePath(
            np.concatenate([self.poses[-1:], self.after.poses]),
            np.vstack([self.q[-1:], self.after.q]),
            np.zeros(len(self.after.q) + 1, int),
        )

    def reversed(self) -> DensePath:
        """The same samples backwards, segment k renumbered max - k (a lead-in becomes last)."""
        seg = self.segment[::-1]
        return DensePath(self.poses[::-1], self.q[::-1], seg.max() - seg)


def densify(
    waypoints: np.ndarray, step: float = PHYSICS.path_step
) -> tuple[np.ndarray, np.ndarray]:
    """Straight-line samples (M,4,4) between hand waypoints (K,4,4), about ``step`` [m] apart
    (rotations counted at GEOMSIM.rotation_sample_radius), and their segment index (M,)."""
    poses, segment = [waypoints[:1]], [np.zeros(1, int)]
    for k, (T0, T1) in enumerate(zip(waypoints[:-1], waypoints[1:])):
        length = max(
            np.linalg.norm(T1[:3, 3] - T0[:3, 3]),
            rotation_angles(T0, T1) * GEOMSIM.rotation_sample_radius,
        )
        n = max(1, int(np.ceil(length / step)))
        poses.append(interpolate_poses(T0, T1, n + 1)[1:])
        segment.append(np.full(n, k))
    return np.concatenate(poses), np.concatenate(segment)


def chain_ik(
    poses: np.ndarray, q_prev: np.ndarray, free: np.ndarray | None = None, from_prev: bool = False
) -> np.ndarray:
    """Joint angles (M,7) for dense hand poses (M,4,4): the continuous IK chain (see the module
    doc) of least joint motion, counting START_WEIGHT × the distance of its start from q_prev
    (7,); with ``from_prev``, the least-motion chain that starts at q_prev itself (poses[0]
    must be fk(q_prev)). J3 is held except on the steps into samples where ``free`` (M,) is
    True, where it may move to a neighbouring sample. Raises InfeasiblePath when no chain
    exists."""
    M = len(poses)
    free = np.zeros(M, bool) if free is None else np.asarray(free, bool)
    sol = wam.ik_solutions(poses, q_prev)
    order = np.argsort(sol.q3[:, 0])  # J3 samples in ascending order (q_prev's own among them)
    q = sol.angles().reshape(wam.N_JOINTS, 8, -1, M)[:, :, order]  # (7, branch, J3 sample, pose)
    usable = sol.usable().reshape(8, -1, M)[:, order]
    inside = np.all(
        (q >= wam.LOWER[:, None, None, None] + LIMIT_MARGIN)
        & (q <= wam.UPPER[:, None, None, None] - LIMIT_MARGIN),
        axis=0,
    )
    penalty = np.where(inside, 0.0, LIMIT_PENALTY)  # (branch, J3 sample, pose)
    S = q.shape[2]
    q = np.where(usable, q, np.nan)
    shifts = (-1, 0, 1)
    # Step costs (shift, from branch, to branch, to J3 sample, to pose): squared distance in
    # time-scaled joint space (|a|² + |b|² - 2 a·b of JOINT_METRIC q), inf beyond MAX_JOINT_STEP
    # or where unusable (NaN); J3 shifts only into free samples.
    qs = q * JOINT_METRIC[:, None, None, None]
    n2 = np.einsum("jbsm,jbsm->bsm", qs, qs)
    steps = np.full((3, 8, 8, S, M), np.inf)
    for k, sh in enumerate(shifts):
        lo, hi = max(0, sh), S + min(0, sh)  # target samples s with s - sh in range
        cross = np.einsum("jfsm,jtsm->ftsm", qs[:, :, lo - sh : hi - sh, :-1], qs[:, :, lo:hi, 1:])
        d2 = n2[:, None, lo - sh : hi - sh, :-1] + n2[None, :, lo:hi, 1:] - 2 * cross
        if sh:
            d2[..., ~free[1:]] = np.inf
        with np.errstate(invalid="ignore"):
            steps[k, :, :, lo:hi, 1:] = np.where(
                d2 <= MAX_JOINT_STEP**2, np.maximum(d2, 0.0), np.inf
            )
    steps = steps.reshape(24, 8, S, M) + penalty[None]
    start = (q[..., 0] - q_prev[:, None, None]) * JOINT_METRIC[:, None, None]
    start2 = np.sum(start**2, axis=0)
    if from_prev:
        usable_start = usable[..., 0] & (start2 <= START_TOLERANCE**2)
    else:
        usable_start = usable[..., 0]
    cost = np.where(usable_start, START_WEIGHT * start2 + penalty[..., 0], np.inf)
    back = np.zeros((M, 8, S), dtype=int)  # (J3 shift + 1) * 8 + branch of the previous sample
    prev = np.full((3, 8, S), np.inf)
    for m in range(1, M):
        prev[0, :, :-1], prev[1], prev[2, :, 1:] = (
            cost[:, 1:],
            cost,
            cost[:, :-1],
        )  # cost at s - shift
        total = (prev[:, :, None, :] + steps[..., m].reshape(3, 8, 8, S)).reshape(24, 8, S)
        back[m] = np.argmin(total, axis=0)
        cost = np.take_along_axis(total, back[m][None], axis=0)[0]
    if not np.isfinite(cost).any():
        raise InfeasiblePath("no continuous IK chain along the path")
    b, s = np.unravel_index(np.argmin(cost), cost.shape)
    branch, sample = np.empty(M, int), np.empty(M, int)
    branch[-1], sample[-1] = b, s
    for m in range(M - 1, 0, -1):
        k, b_prev = divmod(back[m, branch[m], sample[m]], 8)
        branch[m - 1], sample[m - 1] = b_prev, sample[m] - shifts[k]
    chain = q[:, branch, sample, np.arange(M)].T
    if np.abs(wam.fk(chain) - poses).max() > 1e-6:
        raise InfeasiblePath("IK chain misses its poses")
    return chain


def self_motion(T: np.ndarray, q_from: np.ndarray, q_to: np.ndarray) -> np.ndarray:
    """(n,7) configurations from q_from to q_to, two IK solutions of the same hand pose T,
    keeping the hand at T (the WAM's elbow swivel), about JOINT_STEP apart."""
    n = int(np.ceil(np.abs(q_to - q_from).max() / JOINT_STEP))
    if n == 0:
        return q_from[None]
    prefs = q_from + np.linspace(0.0, 1.0, n + 1)[:, None] * (q_to - q_from)
    q, ok = wam.ik_batch(np.repeat(T[None], n - 1, axis=0), prefs[1:-1])
    q = np.vstack([q_from, q, q_to])
    if not ok.all() or _largest_step(q) > MAX_JOINT_STEP:
        raise InfeasiblePath("no continuous elbow swivel to the path's start")
    return q


def _largest_step(q: np.ndarray) -> float:
    """Largest step between consecutive configurations (M,7) in the JOINT_METRIC norm."""
    return float(np.linalg.norm(np.diff(q, axis=0) * JOINT_METRIC, axis=1).max(initial=0.0))


def _densify_via(
    start: np.ndarray, waypoints: np.ndarray, via: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    """densify from start through waypoints; with a via pose, segment 0 runs start → via →
    waypoints[0] (both legs labelled 0)."""
    if via is None:
        return densify(np.concatenate([start[None], waypoints]))
    poses, segment = densify(np.concatenate([start[None], via[None], waypoints]))
    return poses, np.maximum(segment - 1, 0)


def plan_path(
    waypoints: np.ndarray,
    q_start: np.ndarray,
    rigid_from: int = 0,
    reconfigure: bool = False,
    via: np.ndarray | None = None,
    then: np.ndarray | None = None,
) -> DensePath:
    """Dense joint path from the arm's configuration q_start along straight Cartesian segments
    from the current hand pose through hand waypoints (K,4,4); segment 0 passes through the
    ``via`` pose (4,4) when one is given. ``then`` (L,4,4): hand waypoints the arm must be
    able to go on to from the last one (e.g. the lift after a grasp, J3 free along them);
    the IK chain is chosen through them too, and they are not part of the returned path
    (its ``after`` holds their chain).

    The joints follow the ``chain_ik`` chain; segments before ``rigid_from`` (segment 0 leads
    to waypoints[0]) may swivel the elbow on the way. When the chain starts in another
    configuration than q_start, the arm first swivels its elbow in place (``self_motion``)
    or, where none exists and ``reconfigure`` allows it (from home), rises RECONFIGURE_LIFT
    and changes IK branch there by a joint-space move (the hand leaves its pose), and the
    chain starts from the raised pose. Lead-in samples have segment index -1 (the rise: -2).
    """
    waypoints = np.asarray(waypoints, dtype=float)
    # A contact can press a joint a few mrad past its limit (MuJoCo's limits are soft), where no
    # IK solution, so no chain, starts: plan from the nearest configuration within the limits.
    q_start = np.clip(q_start, wam.LOWER, wam.UPPER)
    K = len(waypoints)
    if then is not None:
        waypoints = np.concatenate([waypoints, np.asarray(then, dtype=float)])

    def chain(
        start: np.ndarray, q0: np.ndarray, from_prev: bool = False
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, DensePath | None]:
        poses, segment = _densify_via(start, waypoints, via)
        q = chain_ik(poses, q0, (segment < rigid_from) | (segment >= K), from_prev)
        keep = segment < K
        after = None if then is None else DensePath(poses[~keep], q[~keep], segment[~keep] - K)
        return poses[keep], segment[keep], q[keep], after

    here = wam.fk(q_start)
    poses, segment, q, after = chain(here, q_start)
    try:
        lead = self_motion(here, q_start, q[0])[:-1]
        return DensePath(
            np.concatenate([np.repeat(here[None], len(lead), axis=0), poses]),
            np.vstack([lead, q]),
            np.r_[np.full(len(lead), -1), segment],
            after,
        )
    except InfeasiblePath:
        pass
    # No elbow swivel reaches the least-motion chain: take the least-motion one that starts
    # where the arm is (a grasp near J2's limit lifts the can only from its own configuration).
    try:
        poses, segment, q, after = chain(here, q_start, from_prev=True)
        return DensePath(poses, q, segment, after)
    except InfeasiblePath:
        if not reconfigure:
            raise
    up = raised(here, RECONFIGURE_LIFT)
    rise_poses, _ = densify(np.stack([here, up]))
    rise, ok = wam.ik_batch(rise_poses, q_start)
    if not ok.all() or _largest_step(rise) > MAX_JOINT_STEP:
        raise InfeasiblePath("cannot rise to reconfigure the arm")
    poses, segment, q, after = chain(up, rise[-1])
    move = joint_path(rise[-1], q[0])
    lead_poses = np.concatenate([rise_poses, move.poses[1:-1]])
    return DensePath(
        np.concatenate([lead_poses, poses]),
        np.vstack([rise, move.q[1:-1], q]),
        np.r_[np.full(len(rise_poses), -2), np.full(len(move.q) - 2, -1), segment],
        after,
    )


def solve_path(poses: np.ndarray, q_start: np.ndarray) -> DensePath:
    """One-segment joint path through dense hand poses (M,4,4) (the first at q_start), J3
    free to move along it, with an elbow swivel first where the chain starts elsewhere."""
    q = chain_ik(poses, q_start, np.ones(len(poses), bool))
    lead = self_motion(poses[0], q_start, q[0])[:-1]
    return DensePath(
        np.concatenate([np.repeat(poses[:1], len(lead), axis=0), poses]),
        np.vstack([lead, q]),
        np.r_[np.full(len(lead), -1), np.zeros(len(poses), int)],
    )


def joint_path(q_from: np.ndarray, q_to: np.ndarray) -> DensePath:
    """A joint-space straight line (one segment), sampled about JOINT_STEP apart."""
    n = max(1, int(np.ceil(np.abs(q_to - q_from).max() / JOINT_STEP)))
    q = q_from + np.linspace(0.0, 1.0, n + 1)[:, None] * (q_to - q_from)
    return DensePath(wam.fk(q), q, np.zeros(n + 1, int))


def _trapezoid_time(length: float, u: np.ndarray) -> np.ndarray:
    """Time [s] at which a trapezoidal profile along a segment of ``length`` cruise-seconds,
    accelerating over ACCEL_TIME (a triangle when too short to reach cruise speed), reaches
    progress u (in cruise-seconds, 0 ≤ u ≤ length)."""
    ta, u = ACCEL_TIME, np.clip(u, 0.0, length)
    total = _duration(length)
    ramp = min(ta / 2, length / 2)  # progress at the end of the acceleration
    return np.where(
        u <= ramp,
        np.sqrt(2 * ta * u),
        np.where(u > length - ramp, total - np.sqrt(2 * ta * (length - u)), u + ta / 2),
    )


def _smooth(q: np.ndarray) -> np.ndarray:
    """Joint targets (N,7) filtered twice by a centred SMOOTH_STEPS-wide moving average (ends
    held), which bounds the accelerations where the per-sample speed limits change."""
    w = SMOOTH_STEPS // 2
    kernel = np.full(2 * w + 1, 1.0 / (2 * w + 1))
    for _ in range(2):
        padded = np.pad(q, ((w, w), (0, 0)), mode="edge")
        q = np.stack(
            [np.convolve(padded[:, j], kernel, mode="valid") for j in range(q.shape[1])], axis=1
        )
    return q


def _duration(length: float) -> float:
    ta = ACCEL_TIME
    return length + ta if length >= ta else 2 * np.sqrt(length * ta)


@dataclass(frozen=True)
class TimedPath:
    """Arm servo targets per control period along a dense path.

    ctrl: (N,7) position-servo targets (with velocity feed-forward folded in: q + kv/kp q̇);
    index: (N,) fractional dense-sample index commanded at each period.
    """

    path: DensePath
    ctrl: np.ndarray
    index: np.ndarray

    def __len__(self) -> int:
        return len(self.ctrl)


def sample_times(
    path: DensePath, speeds: dict[int, tuple[float, float]] | None = None
) -> np.ndarray:
    """Time [s] from the start at which the arm passes each dense sample (M,): a trapezoidal
    profile per segment at (palm speed [m/s], turn speed [rad/s]) (``speeds`` by segment
    index; default PHYSICS.move_speed, PHYSICS.turn_speed), no joint faster than
    PHYSICS.joint_speed, at rest at every waypoint. These are the via-point times of a
    guarded move."""
    speeds = speeds or {}
    default = (PHYSICS.move_speed, PHYSICS.turn_speed)
    v = np.array([speeds.get(int(k), default) for k in path.segment[1:]]).reshape(-1, 2)  # per step
    a, b = path.poses[:-1], path.poses[1:]
    steps = np.stack(
        [np.linalg.norm(b[:, :3, 3] - a[:, :3, 3], axis=1), rotation_angles(a, b)], axis=1
    )
    joint = (np.abs(np.diff(path.q, axis=0)) / np.asarray(PHYSICS.joint_speed)).max(
        axis=1, initial=0.0
    )
    cost = np.r_[0.0, np.cumsum(np.maximum((steps / v).max(axis=1, initial=0.0), joint))]
    t = np.zeros(len(cost))
    start = 0.0
    for k in np.unique(path.segment[1:]):
        idx = np.nonzero(path.segment[1:] == k)[0] + 1
        u0, u1 = cost[idx[0] - 1], cost[idx[-1]]
        t[idx] = start + _trapezoid_time(u1 - u0, cost[idx] - u0)
        start += _duration(u1 - u0)
    return t


def servo_targets(q: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Servo targets for every control period of a move through joint via-points q (M,7)
    reached at times t (M,) [s] (t[0] = 0 at q[0]), then SETTLE_TIME holding the last one:
    (ctrl (N,7), with velocity feed-forward folded in: q + kv/kp q̇; index (N,), the
    fractional via-point index commanded at each period)."""
    dt = PHYSICS.timestep
    n = int(np.ceil(t[-1] / dt)) if len(t) > 1 else 0
    periods = np.arange(n + 1) * dt
    index = np.r_[
        np.interp(periods, t, np.arange(len(t))),
        np.full(int(round(SETTLE_TIME / dt)), len(t) - 1.0),
    ]
    lo = np.minimum(np.floor(index).astype(int), max(len(t) - 2, 0))
    hi = np.minimum(lo + 1, len(t) - 1)
    qp = _smooth(q[lo] + (index - lo)[:, None] * (q[hi] - q[lo]))
    qd = np.gradient(qp, dt, axis=0)
    return qp + qd * (np.asarray(PHYSICS.arm_kv) / np.asarray(PHYSICS.arm_kp)), index


def timed_controls(
    path: DensePath, speeds: dict[int, tuple[float, float]] | None = None
) -> TimedPath:
    """Servo targets for every control period along a dense path timed by ``sample_times``."""
    ctrl, index = servo_targets(path.q, sample_times(path, speeds))
    return TimedPath(path, ctrl, index)


class GoalError(ValueError):
    """A guarded-move goal the arm/hand interface refuses (in the simulator or the bridge):
    ``message`` and the GuardedMove result ``code``."""

    def __init__(self, message: str, code: int):
        super().__init__(message)
        self.code = code


#: Largest distance [rad] between the arm and a guarded move's first via-point at time 0 (the
#: arm/hand interface's check of a goal, in the simulator and in the bridge).
GOAL_START_TOLERANCE = 0.05


def client_fraction(index: float, n: int) -> float:
    """Fraction [0, 1] of a client's n via-points done at fractional index ``index`` of the
    followed points (the arm's configuration prepended to the client's)."""
    return float(np.clip(index if n == 1 else (index - 1.0) / (n - 1), 0.0, 1.0))
