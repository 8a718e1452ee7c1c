"""Touching the table in the goal grasp's calibration: the height that a planar belief cannot
hold, measured where its error cancels (docs/algorithm.md §4, "The table touch").

The WAM's joint zero offsets (WorldProfile.joint_offset_sigma) move a goal grasp's hand up or
down by σ 5.6-6.6 mm at 10 mrad, and the table's height draw adds 2.3 mm. The vertical error at
a point of the hand is linear in the offsets, with a row J_z(q) that depends on the arm's shape
(J2-J6) and not on its heading about the base (J1). ``plan`` finds a posture whose fingertip
rests on the table, clear of the object, with J_z as close as it can to the goal grasp's: the
goal's posture turned about the base, the fingers curled so that one tip is lowest. Each
candidate must read the table within CHECK_TOLERANCE in the nominal MuJoCo world with the
object off the estimate by CHECK_OFFSETS; of those, the one that leaves the least over
estimates drawn from the high prior is kept.

The touch is a WRT of kind "touch" in the object's frame, no action of the planner's: a
guarded descent from TOUCH_START above the table, which the executor
(rrg_sim.executor.wrt_executor.WrtExecutor.touch_table) runs before the WRTs it serves (the
goal grasp and its probe, SERVES) and raises them by the table height it read.

``python -m rrg_sim.table_touch [objects…]`` plans each object's touch and writes
``table_touch.json`` into its folder (TABLE_TOUCH_FILE), with what it leaves of the goal's
vertical error at the nominal pose and over the prior.
"""

from __future__ import annotations

import itertools
import logging

import numpy as np
from scipy.optimize import minimize

from rrg_models import wam
from rrg_models.config import WORLD
from rrg_models.hand import fingertip_points, hand_geoms_world
from rrg_models.objects import ObjectModel, get_object
from rrg_models.objects.object_model import TABLE_TOUCH_FILE
from rrg_models.poses import planar_pose
from rrg_models.trajectory import InfeasiblePath
from rrg_models.wrt import WRT, table_touch_wrt
from rrg_sim.executor.wrt_executor import wrt_path
from rrg_sim.posture_calibration import GRASP_CENTRE_Z, JACOBIAN_STEP, reading_posture

log = logging.getLogger(__name__)

#: Height [m] above the modelled table at which the guarded descent starts (chosen: 20 σ of
#: the vertical error at a side goal grasp, so it never starts in contact).
TOUCH_START = 0.05
#: Depth [m] below the modelled table at which the descent would end if nothing stopped it
#: (chosen: beyond any table the profile draws, σ 2.3 mm, with the arm's error on top).
TOUCH_OVERTRAVEL = 0.02
#: The touching tip and the palm stay this far [m] beyond the object's footprint radius from
#: its estimated centre (chosen: 2.4 σ of the high uncertainty prior's 5 cm).
TOUCH_CLEARANCE = 0.12
#: The arm passes this far [m] above the object's top where it passes over it (chosen).
ABOVE_CLEARANCE = 0.03
#: Offsets (x [m], y [m], θ [rad]) of the true object from the estimate at which a touch must
#: read the table in the nominal MuJoCo world, untouched by the object (chosen: the high
#: prior's σ each way).
CHECK_OFFSETS = ((0, 0, 0), (0.05, 0, 0), (-0.05, 0, 0), (0, 0.05, 0), (0, -0.05, 0))
#: A checked touch reads the table within this [m] (MuJoCo's contact depth is about 0.1 mm).
CHECK_TOLERANCE = 0.001
#: Every other part of the hand stays this far [m] above the touching tip (chosen).
TIP_LOWEST_MARGIN = 0.01
#: The table edge margin [m] the touching tip keeps (chosen).
TABLE_MARGIN = 0.05
#: Preshapes tried: spread [rad] × proximal [rad] × touching finger (chosen: curled fingers
#: point a tip down while the hand keeps the goal's orientation nearly).
SPREADS = (0.0, np.pi / 2)
PROXIMALS = (0.8, 1.1)
#: σ of the high uncertainty prior (x [m], y [m], θ [rad]) over which a touch's residual is
#: measured (rrg_estimator's "high" level).
PRIOR_SIGMA = np.array([0.05, 0.05, np.radians(30.0)])
#: Turns [rad] of the goal posture about the base from which the search starts (chosen).
TURNS = (-0.8, -0.4, 0.4, 0.8)
#: Candidates, best at the nominal pose, whose residual is also measured over the prior.
PRIOR_CANDIDATES = 4
#: The WRTs a touch raises by the height it reads: those in the goal grasp's posture.
SERVES = ("goal", "goal_probe")


def vertical_jacobian(q: np.ndarray, point: np.ndarray) -> np.ndarray:
    """(7,) d(height [m] of the hand-frame ``point`` (3,))/d(joint angles [rad]) at q (7,);
    the true height under joint offsets off is height(q − off)."""
    J = np.zeros(7)
    p = np.r_[point, 1.0]
    for k in range(7):
        d = np.zeros(7)
        d[k] = JACOBIAN_STEP
        J[k] = ((wam.fk(q + d) @ p)[2] - (wam.fk(q - d) @ p)[2]) / (2 * JACOBIAN_STEP)
    return J


def _hand_points(spread: float, proximal: float, finger: int) -> tuple[np.ndarray, np.ndarray]:
    """The hand's outline apart from finger ``finger``'s tip, in the hand frame: points (P,3)
    [m] and the radius (P,) [m] each stands for (box corners 0, capsule and cylinder axis
    ends their radius, sphere centres theirs)."""
    points, radii = [], []
    corners = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
    for g, P in hand_geoms_world(np.eye(4), spread, np.full(3, proximal)):
        if g.name == f"f{finger}_tip":
            continue
        if g.kind == "box":
            local = corners * np.asarray(g.size)
            radius = 0.0
        elif g.kind in ("capsule", "cylinder"):
            local = np.array([[0.0, 0.0, -g.size[1]], [0.0, 0.0, g.size[1]]])
            radius = g.size[0]
        else:
            local, radius = np.zeros((1, 3)), g.size[0]
        points.append((P[:3, :3] @ local.T).T + P[:3, 3])
        radii += [radius] * len(local)
    return np.vstack(points), np.array(radii)


def goal_posture(obj: ObjectModel, e: np.ndarray) -> np.ndarray:
    """(7,) the goal grasp's posture at estimate e (reading_posture). Raises InfeasiblePath."""
    return reading_posture(obj, obj.goal_wrt, e)


def _solve(
    obj: ObjectModel,
    e: np.ndarray,
    J_goal: np.ndarray,
    q_goal: np.ndarray,
    spread: float,
    proximal: float,
    finger: int,
) -> list[np.ndarray]:
    """Postures (7,) whose tip ``finger`` rests on the modelled table, clear of the object,
    with their vertical Jacobian nearest J_goal, one from each start (the goal posture turned
    about the base by TURNS)."""
    tip = fingertip_points(spread, np.full(3, proximal))[finger - 1]
    others, others_radii = _hand_points(spread, proximal, finger)
    radius, height = clear_cylinder(obj)

    def constraints(q: np.ndarray) -> np.ndarray:
        T = wam.fk(q)
        t = (T @ np.r_[tip, 1.0])[:3]
        return np.r_[
            1e-4 - abs(t[2] - WORLD.table_top_z),
            np.min((T[:3, :3] @ others.T)[2] + T[2, 3] - others_radii) - t[2] - TIP_LOWEST_MARGIN,
            np.linalg.norm(t[:2] - e[:2]) - radius,
            np.linalg.norm(T[:2, 3] - e[:2]) - radius,
            float(wam.links_clearance(q, e[:2], radius, WORLD.table_top_z + height)),
            wam.arm_points(q)[:, 2] - wam.CLEARANCE_Z,  # the arm stays clear of the table
            t[0] - WORLD.table_x[0] - TABLE_MARGIN,
            WORLD.table_x[1] - TABLE_MARGIN - t[0],
            WORLD.table_y[1] - TABLE_MARGIN - abs(t[1]),
        ]

    def cost(q: np.ndarray) -> float:
        return float(np.sum((vertical_jacobian(q, tip) - J_goal) ** 2))

    found = []
    for turn in TURNS:
        q0 = np.clip(q_goal + np.r_[turn, np.zeros(6)], wam.LOWER, wam.UPPER)
        r = minimize(
            cost,
            q0,
            method="SLSQP",
            bounds=list(zip(wam.LOWER, wam.UPPER)),
            constraints=[{"type": "ineq", "fun": constraints}],
            options=dict(maxiter=200, ftol=1e-12),
        )
        if r.success and np.all(constraints(r.x) > -1e-4):
            found.append(r.x)
    return found


def clear_cylinder(obj: ObjectModel) -> tuple[float, float]:
    """(radius, height) [m] of the cylinder about the object's estimated centre that the touch
    keeps its tip, palm and links out of (TOUCH_CLEARANCE, ABOVE_CLEARANCE)."""
    radius = float(np.max(np.linalg.norm(obj.bounds()[:, :2], axis=1))) + TOUCH_CLEARANCE
    return radius, float(obj.bounds()[1, 2]) + ABOVE_CLEARANCE


def touch_wrt(
    obj: ObjectModel, e: np.ndarray, q: np.ndarray, spread: float, proximal: float, finger: int
) -> WRT:
    """The touch as a WRT in the object's frame from the contact posture q at estimate e: the
    hand TOUCH_START above it, then TOUCH_OVERTRAVEL below it. Its meta holds the touching
    finger, the WRTs it serves and the cylinder its links keep out of (``clear_cylinder``)."""
    T = np.linalg.inv(planar_pose(e)) @ wam.fk(q)
    poses = np.stack([T.copy(), T.copy()])
    poses[0, 2, 3] += TOUCH_START
    poses[1, 2, 3] -= TOUCH_OVERTRAVEL
    return table_touch_wrt(poses, spread, proximal, finger, SERVES, clear_cylinder(obj))


def executed_posture(wrt: WRT, e: np.ndarray) -> np.ndarray:
    """(7,) the posture the executor's IK chain reaches at the modelled table on ``wrt``'s path
    at estimate e. Raises InfeasiblePath."""
    path = wrt_path(wrt, e, wam.HOME_Q)
    target = (wrt.world_poses(e)[0])[2, 3] - TOUCH_START
    on_descent = np.nonzero(path.segment == 1)[0]
    k = on_descent[np.argmin(np.abs(path.poses[on_descent, 2, 3] - target))]
    return path.q[k]


def residual(obj: ObjectModel, wrt: WRT, e: np.ndarray, sigma: float) -> tuple[float, float]:
    """(σ of the goal grasp's vertical error, σ of what the touch leaves of it) [m] at estimate
    e for joint offsets of σ ``sigma`` [rad], along the executed paths; where the touch cannot
    be made, it leaves all of it. Raises InfeasiblePath when the goal grasp cannot be made."""
    J_goal = vertical_jacobian(goal_posture(obj, e), np.array([0.0, 0.0, GRASP_CENTRE_Z]))
    goal_sigma = sigma * float(np.linalg.norm(J_goal))
    tip = fingertip_points(wrt.spread, np.full(3, wrt.preclose))[wrt.meta["finger"] - 1]
    try:
        J_tip = vertical_jacobian(executed_posture(wrt, e), tip)
    except InfeasiblePath:
        return goal_sigma, goal_sigma
    return goal_sigma, sigma * float(np.linalg.norm(J_tip - J_goal))


def _prior_residuals(obj: ObjectModel, wrt: WRT, sigma: float, offsets: np.ndarray) -> np.ndarray:
    """(n,2) ``residual`` at the nominal pose moved by each of ``offsets`` (…,3) where the
    goal grasp can be made."""
    e = np.asarray(WORLD.nominal_pose, dtype=float)
    rows = []
    for d in offsets:
        try:
            rows.append(residual(obj, wrt, e + d, sigma))
        except InfeasiblePath:
            continue
    return np.array(rows).reshape(-1, 2)


def reads_the_table(obj: ObjectModel, wrt: WRT) -> bool:
    """Whether the touch, run in the nominal MuJoCo world at the nominal pose with the object
    off it by each of CHECK_OFFSETS, reads the table within CHECK_TOLERANCE each time (no
    link or finger meets the object first)."""
    from rrg_sim.physics.world import PhysicsWorld

    world = PhysicsWorld(obj.name, seed=0, touch_table=True)
    e = np.asarray(WORLD.nominal_pose, dtype=float)
    for d in CHECK_OFFSETS:
        world.reset(e + np.asarray(d, dtype=float))
        try:
            height = world.executor.touch_table(wrt, e)
        except InfeasiblePath:
            return False
        if height is None or abs(height - WORLD.table_top_z) > CHECK_TOLERANCE:
            return False
    return True


def plan(obj: ObjectModel, sigma: float = 0.010, draws: int = 20, seed: int = 0) -> dict:
    """The object's table touch (see the module doc) and its residuals: at the nominal pose and
    over ``draws`` estimates from the high uncertainty prior (σ 5 cm, 5 cm, 30°); the touch
    and the goal grasp are made at the same estimate."""
    e = np.asarray(WORLD.nominal_pose, dtype=float)
    q_goal = goal_posture(obj, e)
    J_goal = vertical_jacobian(q_goal, np.array([0.0, 0.0, GRASP_CENTRE_Z]))
    goal_sigma = sigma * float(np.linalg.norm(J_goal))  # as ``residual`` finds it at e
    found = []
    for spread in SPREADS:
        for proximal in PROXIMALS:
            for finger in (1, 2, 3):
                for q in _solve(obj, e, J_goal, q_goal, spread, proximal, finger):
                    wrt = touch_wrt(obj, e, q, spread, proximal, finger)
                    _, left = residual(obj, wrt, e, sigma)
                    if left < goal_sigma:
                        found.append((left, wrt))
    if not found:
        raise InfeasiblePath(f"{obj.name}: no table touch found")
    offsets = np.random.default_rng(seed).normal(0.0, 1.0, (draws, 3)) * PRIOR_SIGMA
    scored = []
    checked = (f for f in sorted(found, key=lambda f: f[0]) if reads_the_table(obj, f[1]))
    for left, wrt in itertools.islice(checked, PRIOR_CANDIDATES):
        prior = _prior_residuals(obj, wrt, sigma, offsets)
        scored.append((float(np.sqrt(np.mean(prior[:, 1] ** 2))), left, wrt, prior))
    if not scored:
        raise InfeasiblePath(f"{obj.name}: no table touch reads the table clear of the object")
    _, left, wrt, prior = min(scored, key=lambda s: s[0])
    return dict(
        spread=wrt.spread,
        preclose=wrt.preclose,
        finger=wrt.meta["finger"],
        serves=list(SERVES),
        clear=[round(v, 6) for v in clear_cylinder(obj)],
        poses=np.round(wrt.poses, 6).tolist(),
        sigma_rad=sigma,
        goal_vertical_sigma=round(goal_sigma, 6),
        residual_sigma=round(left, 6),
        prior_draws=len(prior),
        prior_goal_vertical_rms=round(float(np.sqrt(np.mean(prior[:, 0] ** 2))), 6),
        prior_residual_rms=round(float(np.sqrt(np.mean(prior[:, 1] ** 2))), 6),
    )


def _plan_job(args: tuple) -> tuple[str, dict]:
    name, draws, seed = args
    return name, plan(get_object(name), draws=draws, seed=seed)


def _report(name: str, fit: dict, _records) -> str:
    return (
        f"{name}: finger {fit['finger']} at spread {fit['spread']:.2f}, proximal "
        f"{fit['preclose']:.2f}: the goal's vertical error σ {fit['goal_vertical_sigma'] * 1e3:.1f}"
        f" mm, left {fit['residual_sigma'] * 1e3:.2f} mm (over the prior: "
        f"{fit['prior_goal_vertical_rms'] * 1e3:.1f} → {fit['prior_residual_rms'] * 1e3:.2f} mm)"
    )


def main(argv: list[str] | None = None) -> None:
    from rrg_models.objects import PAPER_OBJECTS
    from rrg_sim.physics.settle import run_study, study_args

    args = study_args(argv, __doc__, list(PAPER_OBJECTS), "draws", 20, "prior estimates")
    run_study(
        args.objects,
        args.draws,
        args.seed,
        args.workers,
        TABLE_TOUCH_FILE,
        _plan_job,
        lambda name, fit: fit,
        _report,
        "table touch",
        f"python -m rrg_sim.table_touch --draws {args.draws} --seed {args.seed}"
        " (MuJoCo's WAM kinematics, joint offsets σ 10 mrad)",
        args.out_dir,
    )


if __name__ == "__main__":
    logging.basicConfig(level=logging.WARNING)
    main()
