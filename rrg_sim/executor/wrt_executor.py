"""Executing a world-relative trajectory on a robot (algorithm §4): the one sequence that the
physics world runs in-process and the executor node runs over ROS against the arm/hand interface.

τ(e) → straight Cartesian segments, densified and solved to one continuous IK chain
(physics.trajectory.plan_path) → joint via-points timed per segment → a guarded move that
stops at the first sensed contact → close the fingers until each stops (carefully, each at its
first touch, unless a grasp arrived) → the Observation. The
hand is left closed where it stopped; ``retreat`` opens it and retraces the path back home. A
reorientation WRT also lifts the grasped object, turns it about the vertical through e, puts
it down and opens the hand.

The robot is anything with the small ``Robot`` interface: ``PhysicsWorld`` implements it
directly, the executor node with action and service clients of the sim (or hardware) node.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Protocol

import numpy as np
from scipy.spatial.transform import Rotation

from rrg_models import wam
from rrg_models.config import GEOMSIM, N_SENSORS, PHYSICS, REORIENT_MIN_FINGERS, WORLD
from rrg_models.goal import holds_object
from rrg_models.hand import fingertip_lowest_z, hand_geoms_world, sensor_id
from rrg_models.hand_sensing import Reading
from rrg_models.observation import Observation, grasp_arrived
from rrg_models.poses import planar_pose, raised
from rrg_models.trajectory import (
    DensePath,
    InfeasiblePath,
    densify,
    joint_path,
    plan_path,
    sample_times,
    solve_path,
)
from rrg_models.wrt import WRT
from rrg_sim.executor.robot_errors import ExecutionStopped, ForceCeilingStop, StaleDataStop

log = logging.getLogger(__name__)

#: (m/s, rad/s) through free space: from home to a WRT's first pose, and back.
FREE_SPEEDS = (PHYSICS.free_speed, PHYSICS.free_turn_speed)
#: A retreat retraces the path only if the arm is still where the WRT left it, within this
#: joint distance [rad] (chosen: far above servo error, far below any real move).
RETREAT_TOLERANCE = 0.05
#: (m/s, rad/s) of the lift after a goal grasp.
LIFT_SPEEDS = (PHYSICS.lift_speed, PHYSICS.turn_speed)
#: A lift follows the lift planned with its grasp only when the hand stands this close [m] to
#: the planned path's end (chosen: an arrived grasp's servo lag leaves < 1 mm; the planned
#: lift's first step, 1 cm up from the planned end, would first carry a hand that stopped a
#: centimetre short towards the object).
LIFT_START_TOLERANCE = 0.003

#: Execution phases reported to a progress callback, with the fraction done when each starts.
PHASES = {
    "planning": 0.0,
    "touch": 0.05,
    "approach": 0.1,
    "closing": 0.6,
    "reorient": 0.7,
    "retreat": 0.8,
}
#: Speed [m/s] of a table touch's guarded descent (rrg_sim.table_touch; chosen: a tenth of a
#: guarded move's PHYSICS.move_speed, 0.4 mm between two 50 Hz pad samples).
TOUCH_SPEED = 0.02
#: A table touch that reads the table further than this [m] from its modelled height touched
#: something else, and corrects nothing (chosen: 3 σ of the vertical error at a touch, 6-7 mm
#: at 10 mrad with the table's 2.3 mm).
TOUCH_VALID = 0.02
#: Tries at bringing the hand home after a stale-data stop, and the pause [s] before each
#: (chosen: the bridge's watchdog allows 150 ms of silence; a stream that stalls for a loaded
#: host's moment is fresh again within a few of its cycles).
WITHDRAW_TRIES, WITHDRAW_PAUSE_S = 3, 0.5


class Robot(Protocol):
    """The arm and hand as the executor drives them."""

    def arm_q(self) -> np.ndarray:
        """(7,) measured WAM joint angles [rad]."""

    def hand_angles(self) -> tuple[float, np.ndarray]:
        """Measured spread [rad] and (3,) proximal angles [rad]."""

    def hand_pose(self) -> np.ndarray:
        """(4,4) hand (wrist flange) pose in ``world``."""

    def follow(self, q: np.ndarray, t: np.ndarray, guard: bool) -> float | None:
        """Track joint via-points q (M,7) (q[0]: where the arm is) reached at times t (M,) [s].
        Guarded: stop and hold at the first control period any sensor fires. Returns the
        fractional via-point index commanded at the stop, or None when the move completed."""

    def move_hand(self, spread: float, proximal: float | np.ndarray) -> None:
        """Servo the spread and the proximal joints (one angle for all, or (3,)) to the given
        angles [rad], arm held."""

    def close_hand(self, guarded: bool = False) -> np.ndarray:
        """Close every finger until it stops (stalls on the object or reaches its limit);
        guarded: also stop each finger as soon as one of its own sensors fires. Returns
        (10,) bool: the sensors that fired at any time during the closing."""

    def reading(self) -> Reading:
        """The hand's sensors now."""

    @property
    def unconfirmed_stops(self) -> int:
        """Lone pad trips of the guarded moves so far that the next pad sample did not
        confirm (a running count)."""


@dataclass
class Execution:
    """What the last WRT execution left behind for ``retreat`` (and a grasp judge)."""

    wrt: WRT
    e: np.ndarray
    path: DensePath  # the hand path actually commanded, from its start to the stop
    observation: Observation
    q_end: np.ndarray  # (7,) where the arm was when the execution ended
    #: Rigid motion (4,4) the object was given (a reorientation), applied to the way back.
    moved: np.ndarray = field(default_factory=lambda: np.eye(4))
    #: The lift the plan chose through a goal grasp, from the planned path's end
    #: (DensePath.then_path); None for other WRTs.
    lift: DensePath | None = None

    def turned_approach(self) -> np.ndarray:
        """(P,4,4) the way back after the object was moved: the WRT poses the hand passed,
        in reverse, moved with the object."""
        passed = max(0, int(self.path.segment[-1]))  # WRT poses 0 … passed-1 were passed
        return self.moved @ self.wrt.world_poses(self.e)[:passed][::-1]


def _translation_z(dz: float) -> np.ndarray:
    """(4,4) a translation by dz [m] along z."""
    T = np.eye(4)
    T[2, 3] = dz
    return T


def rotation_about_z(centre_xy, angle: float) -> np.ndarray:
    """(4,4) world rotation by ``angle`` about the vertical axis through centre_xy."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.0, 0.0, angle]).as_matrix()
    c = np.array([centre_xy[0], centre_xy[1], 0.0])
    T[:3, 3] = c - T[:3, :3] @ c
    return T


def sensor_points(spread: float, proximal: np.ndarray) -> np.ndarray:
    """(10,3) centre of each sensor's geom in the hand frame for the given hand angles."""
    points = np.zeros((N_SENSORS, 3))
    for g, T in hand_geoms_world(np.eye(4), spread, np.asarray(proximal, dtype=float)):
        if g.sensor >= 0:
            points[g.sensor] = T[:3, 3]
    return points


def transit_via(first: np.ndarray) -> np.ndarray | None:
    """The pose (4,4) the hand passes on its way from home to a WRT's first pose: that pose
    raised to PHYSICS.transit_height, so that the hand turns to it above every object and
    comes down to it from above; None when the first pose is that high already."""
    if first[2, 3] >= PHYSICS.transit_height:
        return None
    via = first.copy()
    via[2, 3] = PHYSICS.transit_height
    return via


def wrt_path(wrt: WRT, e: np.ndarray, q_start: np.ndarray) -> DensePath:
    """τ(e)'s dense joint path from the arm at q_start: through the transit above the object
    when the WRT starts low (``transit_via``), and with an IK chain that can go on to the lift
    or turn that follows its grasp (``lift_after``). Raises InfeasiblePath."""
    poses = wrt.world_poses(e)
    return plan_path(
        poses,
        q_start,
        rigid_from=1,
        reconfigure=True,
        via=transit_via(poses[0]),
        then=lift_after(wrt, poses[-1]),
    )


def executed_poses(wrt: WRT) -> np.ndarray:
    """The hand poses (N,4,4) in the object's frame along the path ``wrt_path`` follows from
    the transit on: the ``transit_via`` pose, τ's waypoints and the ``lift_after`` its grasp,
    about PHYSICS.feasibility_step apart. A feasibility map over these checks the path an
    executor must follow, not only τ's waypoints (a side grasp that starts near the WAM's
    base is reachable at its waypoints but not on the descent to them)."""
    origin = planar_pose(np.zeros(3))  # the object frame in world for e = 0
    poses = wrt.world_poses(np.zeros(3))
    via, lift = transit_via(poses[0]), lift_after(wrt, poses[-1])
    path = np.concatenate(
        [p for p in (None if via is None else via[None], poses, lift) if p is not None]
    )
    dense, _ = densify(path, PHYSICS.feasibility_step)
    return np.linalg.inv(origin) @ dense


def lift_after(wrt: WRT, last: np.ndarray) -> np.ndarray | None:
    """(1,4,4) the lift a WRT's grasp must be able to go on to from its last pose ``last``:
    a goal grasp is lifted PHYSICS.lift_height to be judged, a reorientation
    PHYSICS.reorient_lift to turn; None for other WRTs (they retrace their path)."""
    height = {"goal": PHYSICS.lift_height, "reorient": PHYSICS.reorient_lift}.get(wrt.kind)
    return None if height is None else raised(last, height)[None]


class WrtExecutor:
    """Runs WRTs on a robot and retreats from them (see the module doc)."""

    def __init__(self, robot: Robot):
        self.robot = robot
        self.last: Execution | None = None
        #: the table height [m] the last table touch read (None: none, or nothing valid)
        self.touched_height: float | None = None

    def forget(self) -> None:
        """Drop the pending retreat and the last table touch (the robot was reset elsewhere)."""
        self.last = None
        self.touched_height = None

    # ------------------------------------------------------------------ motion
    def _follow(
        self, path: DensePath, guard: bool = False, speeds: dict | None = None
    ) -> float | None:
        return self.robot.follow(path.q, sample_times(path, speeds), guard)

    def _move(self, waypoints: np.ndarray, rigid_from: int = 0) -> None:
        """An unguarded straight-line move from the current hand pose through hand waypoints."""
        self._follow(plan_path(waypoints, self.robot.arm_q(), rigid_from))

    def _rise(self) -> None:
        """Raise the open hand straight up to PHYSICS.transit_height, clear of the object, or as
        far as the arm can."""
        here = self.robot.hand_pose()
        self._move_as_far_as_feasible(
            lambda d: raised(here, d), PHYSICS.transit_height - here[2, 3]
        )

    def _back_out(self) -> None:
        """Withdraw the open hand along its approach axis (hand −z) by PHYSICS.back_out_distance,
        or as far as the arm can: the way out of a grasp whose fingers wrap a part (rising
        with them around the pitcher's handle dragged it 8 cm and turned it 1.3 rad)."""
        here = self.robot.hand_pose()
        self._move_as_far_as_feasible(
            lambda d: here @ _translation_z(-d), PHYSICS.back_out_distance
        )

    def _withdraw(self) -> None:
        """Open the hand fully, back out along its approach axis and rise clear of the objects:
        the way out when the WRT's path cannot be retraced."""
        self._open(0.0)
        self._back_out()
        self._rise()

    def _move_as_far_as_feasible(
        self, pose_at: Callable[[float], np.ndarray], distance: float
    ) -> None:
        """Move straight to pose_at(distance) [m], halving the distance until the move is
        feasible; none below 1 cm."""
        while distance >= 0.01:
            try:
                self._move(pose_at(distance)[None], rigid_from=1)
                return
            except InfeasiblePath:
                distance /= 2

    def _open(self, proximal: float) -> None:
        """Open every finger to ``proximal`` [rad], or leave it where it is if it is already
        more open: an opening never closes a finger (a finger that stopped short of the
        preshape would otherwise close on the object as the hand withdraws)."""
        spread, angles = self.robot.hand_angles()
        self.robot.move_hand(spread, np.minimum(angles, proximal))

    # ------------------------------------------------------------------ WRTs
    def execute(
        self,
        wrt: WRT,
        e,
        progress: Callable[[str, float], None] | None = None,
        touch: WRT | None = None,
    ) -> Observation:
        """Run τ(e) from home as a guarded move, close the fingers, and return the observation;
        the hand is left closed at the stop (call ``retreat`` next, or judge the grasp first).
        A pending retreat of the previous WRT runs first. ``touch``: the object's table touch
        (rrg_sim.table_touch); when it serves ``wrt``, it runs first at e and τ(e) is raised by
        the table height it read (``touch_table``). Raises physics.trajectory's InfeasiblePath
        when no continuous IK path follows τ(e) (for a reorientation: or its lift, turn and
        put-down from τ(e)'s end); the robot has not moved then, or only to touch the table
        and back home. A move the safety layer stops for stale data ends it: the hand is
        brought home (withdrawn, then home in joint space) and ExecutionStopped raised."""
        try:
            return self._execute(wrt, e, progress, touch)
        except StaleDataStop as exc:
            self.last = None
            log.warning(
                "%s stopped by the safety layer (%s): bringing the hand home; nothing was observed",
                wrt.name,
                exc,
            )
            self._withdraw_home_when_fresh()
            raise ExecutionStopped(f"{wrt.name} stopped by the safety layer: {exc}") from exc

    def _withdraw_home_when_fresh(self) -> None:
        """_withdraw_home, tried WITHDRAW_TRIES times while the data is still stale."""
        for attempt in range(1, WITHDRAW_TRIES + 1):
            if np.abs(self.robot.arm_q() - wam.HOME_Q).max() <= RETREAT_TOLERANCE:
                return  # stopped on its way out of home: it is home
            time.sleep(WITHDRAW_PAUSE_S)
            try:
                self._withdraw_home()
                return
            except StaleDataStop:
                if attempt == WITHDRAW_TRIES:
                    raise

    def _execute(
        self, wrt: WRT, e, progress: Callable[[str, float], None] | None, touch: WRT | None
    ) -> Observation:
        """execute, but a stale-data stop is the caller's."""
        report = progress or (lambda phase, fraction: None)
        if self.last is not None:
            self.retreat(report)
        e = np.asarray(e, dtype=float)
        report("planning", PHASES["planning"])
        path = wrt_path(wrt, e, self.robot.arm_q())
        height = None
        if touch is not None and wrt.name in touch.meta.get("serves", ()):
            report("touch", PHASES["touch"])
            try:
                height = self.touch_table(touch, e)
            except InfeasiblePath as exc:  # nothing moved: the WRT runs as it is
                log.info("table touch skipped: %s", exc)
            if height is not None:
                wrt, path = self._raised(wrt, e, height - WORLD.table_top_z, path)
        if wrt.kind == "reorient":
            self._check_reorient(wrt, e, path)
        report("approach", PHASES["approach"])
        self.robot.move_hand(wrt.spread, wrt.preclose)  # preshape at home, clear of everything
        unconfirmed = self.robot.unconfirmed_stops
        stop = self._follow(path, guard=True, speeds={k: FREE_SPEEDS for k in (0, -1, -2)})
        unconfirmed = self.robot.unconfirmed_stops - unconfirmed
        if unconfirmed:
            log.info(
                "%s: %d lone pad trip%s not confirmed by the next sample; the move went on",
                wrt.name,
                unconfirmed,
                "s" * (unconfirmed != 1),
            )
        index = stop if stop is not None else float(len(path.poses) - 1)
        at_stop = self.robot.reading()
        motion_dir = self._motion_dir(path, index, at_stop)
        stop_pose = self.robot.hand_pose()
        report("closing", PHASES["closing"])
        first = int(np.nonzero(path.segment == 0)[0][-1])  # the WRT's first pose
        arc = path.arc
        travelled = float(np.interp(index, np.arange(len(arc)), arc))
        progress_m = max(0.0, travelled - arc[first])
        # The fingers close carefully (paper: "carefully closing the fingers when a collision
        # is sensed"), each stopping at its first touch, measuring where the object is instead
        # of pushing it on (light objects slid 1-3 cm per firm closing in MuJoCo): always for
        # an information-gathering WRT, and for a grasp stopped well short of its end. A goal
        # or reorientation grasp that arrived closes firmly: it must hold, and a tight grasp
        # (a handle) often touches in its last centimetre.
        arrived = grasp_arrived(wrt.kind, arc[-1] - travelled)
        contact = stop is not None and not arrived
        touched = self.robot.close_hand(guarded=not arrived)
        closed = self.robot.reading()
        obs = Observation(
            contact=contact,
            progress=progress_m,
            hand_pose=stop_pose,
            sensors=at_stop.fired | touched | closed.fired,
            closure=self.robot.hand_angles()[1],
            tip_points=closed.tip_points,
            tip_normals=closed.tip_normals,
            motion_dir=motion_dir,
            unconfirmed_stops=unconfirmed,
            table_height=float("nan") if height is None else height,
        )
        self.last = Execution(
            wrt,
            e,
            path.upto(int(np.floor(index))),
            obs,
            self.robot.arm_q(),
            lift=path.then_path() if wrt.kind == "goal" else None,
        )
        if wrt.kind == "reorient" and holds_object(obs.contact, obs.sensors, REORIENT_MIN_FINGERS):
            report("reorient", PHASES["reorient"])
            self._reorient(wrt, e)
        return obs

    def _raised(self, wrt: WRT, e: np.ndarray, dz: float, path: DensePath) -> tuple[WRT, DensePath]:
        """``wrt`` raised by dz [m] with its path, or by as large a part of dz (halved down to
        a millimetre) as the arm can reach: a side grasp at the edge of the WAM's workspace
        cannot go lower."""
        part = dz
        while abs(part) >= 1e-3:
            raised_wrt = replace(wrt, poses=raised(wrt.poses, part))
            try:
                raised_path = wrt_path(raised_wrt, e, self.robot.arm_q())
            except InfeasiblePath:
                part /= 2
                continue
            if part != dz:
                log.info(
                    "%s raised %+.1f mm of the %+.1f mm the table touch asked: the arm "
                    "reaches no further",
                    wrt.name,
                    1e3 * part,
                    1e3 * dz,
                )
            return raised_wrt, raised_path
        if abs(dz) >= 1e-3:
            log.info("%s not raised by %+.1f mm: the arm cannot reach it", wrt.name, 1e3 * dz)
        return wrt, path

    def touch_table(self, touch: WRT, e: np.ndarray) -> float | None:
        """Run the table touch at estimate e and back home: a guarded descent of a fingertip
        (touch.meta["finger"]) at TOUCH_SPEED that stops at the first sensed contact, the hand
        held in its preshape. Returns the table's height [m] as the robot reads it (the tip's
        lowest point, from its measured hand pose), or None when it read nothing: the move
        ended without a stop, the touching tip's Nano17 was silent at the stop (something
        else was touched), or the height is further than TOUCH_VALID from the modelled
        table. Sets ``touched_height``. Raises InfeasiblePath, before anything moves, when no
        continuous IK path reaches the table or the arm's links would pass into the cylinder
        about e that the touch keeps out of (touch.meta["clear"]: radius, height [m]); the
        WRT it serves then runs unraised."""
        path = wrt_path(touch, e, self.robot.arm_q())
        radius, top = touch.meta["clear"]
        clearance = wam.links_clearance(path.q, e[:2], radius, WORLD.table_top_z + top).min()
        if clearance < 0:
            raise InfeasiblePath(
                f"the arm would pass {1e3 * -clearance:.0f} mm into the object's estimated "
                "space on the way to the table"
            )
        self.robot.move_hand(touch.spread, touch.preclose)
        free = {k: FREE_SPEEDS for k in (0, -1, -2)}
        stop = self._follow(path, guard=True, speeds={**free, 1: (TOUCH_SPEED, PHYSICS.turn_speed)})
        spread, proximal = self.robot.hand_angles()
        hand = self.robot.hand_pose()
        height = fingertip_lowest_z(hand, spread, proximal, touch.meta["finger"])
        index = stop if stop is not None else float(len(path.poses) - 1)
        reading = self.robot.reading()
        obs = Observation(
            contact=stop is not None,
            progress=0.0,
            hand_pose=hand,
            sensors=reading.fired,
            closure=proximal,
            tip_points=reading.tip_points,
            tip_normals=reading.tip_normals,
        )
        self.last = Execution(touch, e, path.upto(int(np.floor(index))), obs, self.robot.arm_q())
        self.retreat()
        tip_fired = bool(reading.fired[sensor_id(f"tip{touch.meta['finger']}")])
        valid = stop is not None and tip_fired and abs(height - WORLD.table_top_z) <= TOUCH_VALID
        self.touched_height = height if valid else None
        log.info(
            "table touch: finger %d %s",
            touch.meta["finger"],
            f"read the table at {1e3 * (height - WORLD.table_top_z):+.1f} mm"
            if valid
            else "read no table"
            + (
                ""
                if stop is None
                else f" (stopped at {1e3 * (height - WORLD.table_top_z):+.1f} mm, its Nano17 "
                + ("fired)" if tip_fired else "silent)")
            ),
        )
        return self.touched_height

    def _motion_dir(self, path: DensePath, index: float, reading: Reading) -> np.ndarray:
        """Unit direction the sensed contact (a fired Nano17's contact point, else a fired pad,
        else the palm) moved in world over the last dense step before ``index``."""
        b = max(1, int(np.ceil(index)))
        tips = reading.fired[7:] & np.isfinite(reading.tip_points).all(axis=1)
        if tips.any():
            local = reading.tip_points[np.argmax(tips)]
        elif reading.fired.any():
            local = sensor_points(*self.robot.hand_angles())[np.argmax(reading.fired)]
        else:
            local = np.zeros(3)
        a_pose, b_pose = path.poses[b - 1], path.poses[b]
        v = (b_pose[:3, :3] @ local + b_pose[:3, 3]) - (a_pose[:3, :3] @ local + a_pose[:3, 3])
        return v / max(np.linalg.norm(v), 1e-12)

    @staticmethod
    def _reorient_poses(
        wrt: WRT, e: np.ndarray, T: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """From the grasp's hand pose T (4,4): the lifted pose, the dense arc (n,4,4) turning it
        about the vertical through e, and the rigid motion G (4,4) of the whole turn."""
        lifted = raised(T, PHYSICS.reorient_lift)
        n = max(
            2,
            int(
                np.ceil(
                    abs(wrt.reorient_angle) * GEOMSIM.rotation_sample_radius / PHYSICS.path_step
                )
            )
            + 1,
        )
        arc = np.stack(
            [rotation_about_z(e[:2], a) @ lifted for a in np.linspace(0.0, wrt.reorient_angle, n)]
        )
        return lifted, arc, rotation_about_z(e[:2], wrt.reorient_angle)

    def _check_reorient(self, wrt: WRT, e: np.ndarray, path: DensePath) -> None:
        """Raise InfeasiblePath, before anything moves, when the arm could not lift, turn and
        put down the object from the end of the WRT's path (the object would be left turned
        part way while the agent is told nothing moved)."""
        lifted, arc, G = self._reorient_poses(wrt, e, path.poses[-1])
        q = plan_path(lifted[None], path.q[-1], rigid_from=1).q[-1]
        q = solve_path(arc, q).q[-1]
        plan_path((G @ path.poses[-1])[None], q, rigid_from=1)

    def _reorient(self, wrt: WRT, e: np.ndarray) -> None:
        """Lift, turn about the vertical through e, put down, open (after closing on the object)."""
        T = self.robot.hand_pose()
        lifted, arc, G = self._reorient_poses(wrt, e, T)
        self._move(lifted[None], rigid_from=1)
        self._follow(solve_path(arc, self.robot.arm_q()))
        self._move((G @ T)[None], rigid_from=1)
        self._open(wrt.preclose)
        self.last.moved, self.last.q_end = G, self.robot.arm_q()

    def lift(self) -> None:
        """Lift the closed hand PHYSICS.lift_height straight up at LIFT_SPEEDS. When the last
        WRT was a goal grasp and the hand stands where its planned path ends (within
        LIFT_START_TOLERANCE, the joints within RETREAT_TOLERANCE), the lift follows the chain
        that plan chose through the grasp (``wrt_path``'s ``lift_after``), so the lift that
        made the grasp feasible is the one that runs; otherwise the lift is planned from
        where the arm stands. A fresh plan can miss a lift the grasp's plan found: near the wrist
        singularity a few mrad of servo error decide whether a straight lift needs a wrist
        flip. Raises InfeasiblePath when no lift is planned (nothing moved); a retreat after a
        lift is dropped (the arm has left the WRT's path)."""
        hand, q = self.robot.hand_pose(), self.robot.arm_q()
        planned = None if self.last is None else self.last.lift
        if (
            planned is not None
            and np.abs(q - planned.q[0]).max() <= RETREAT_TOLERANCE
            and np.linalg.norm(hand[:3, 3] - planned.poses[0][:3, 3]) <= LIFT_START_TOLERANCE
        ):
            path = DensePath(
                np.concatenate([hand[None], planned.poses[1:]]),
                np.vstack([q, planned.q[1:]]),
                planned.segment,
            )
        else:
            path = plan_path(raised(hand, PHYSICS.lift_height)[None], q, rigid_from=1)
        self._follow(path, speeds={0: LIFT_SPEEDS})

    def recover(self, progress: Callable[[str, float], None] | None = None) -> None:
        """Bring the arm home with no record of how it got where it is (an executor restarted
        in the middle of a WRT): open the hand, back out along its approach axis, rise above
        the objects, then move home in joint space. Nothing moves when the arm is home."""
        if np.abs(self.robot.arm_q() - wam.HOME_Q).max() <= RETREAT_TOLERANCE:
            return
        log.warning(
            "the arm is away from home with no WRT to retrace: opening the hand, backing out "
            "along its approach axis and rising, then moving home"
        )
        if progress is not None:
            progress("retreat", PHASES["retreat"])
        self._withdraw_home()

    def _withdraw_home(self) -> None:
        """Withdraw (open fully, back out, rise), then move home in joint space."""
        self._withdraw()
        self._follow(joint_path(self.robot.arm_q(), wam.HOME_Q), speeds={0: FREE_SPEEDS})

    def retreat(self, progress: Callable[[str, float], None] | None = None) -> None:
        """Open the hand and retrace the executed path back to home. After a reorientation the
        WRT's part of the path is retraced turned with the object (where that is out of reach,
        the open hand backs out along its approach axis and rises instead), then the arm moves
        home in joint space. A retrace the safety layer stops at the force ceiling (an opened
        finger catching on the object) or for stale data gives way to the same withdrawal,
        then home (for stale data, tried again while the data is still stale). If the arm
        is no longer where the WRT left it (e.g. the simulator was reset), the retreat is
        dropped. With no WRT to retreat from (this executor was restarted while the arm was
        out), the arm is brought home by ``recover``."""
        if self.last is None:
            self.recover(progress)
            return
        last, self.last = self.last, None
        if np.abs(self.robot.arm_q() - last.q_end).max() > RETREAT_TOLERANCE:
            log.warning(
                "retreat from %s dropped: the arm has moved since the WRT ended", last.wrt.name
            )
            return
        if progress is not None:
            progress("retreat", PHASES["retreat"])
        self._open(last.wrt.preclose)
        try:
            self._retrace(last)
        except ForceCeilingStop as exc:
            log.warning(
                "retreat from %s stopped at the force ceiling (%s): opening the hand, backing "
                "out along its approach axis and rising, then moving home",
                last.wrt.name,
                exc,
            )
            self._withdraw_home()
        except StaleDataStop as exc:
            log.warning(
                "retreat from %s stopped by the safety layer (%s): bringing the hand home",
                last.wrt.name,
                exc,
            )
            self._withdraw_home_when_fresh()
        self._open(0.0)

    def _retrace(self, last: Execution) -> None:
        """Retrace the executed path from where the arm stands to its start (after a
        reorientation: the approach turned with the object, then joint space to its start)."""
        q0 = self.robot.arm_q()
        if np.allclose(last.moved, np.eye(4)):
            back = last.path.reversed()
            path = DensePath(
                np.concatenate([wam.fk(q0)[None], back.poses]),
                np.vstack([q0, back.q]),
                np.r_[back.segment[0], back.segment],
            )
            top = int(last.path.segment.max())  # segments 0 and the lead-ins are free space
            self._follow(path, speeds={top - k: FREE_SPEEDS for k in (0, -1, -2)})
        else:
            back = last.turned_approach()
            if len(back):
                try:
                    self._move(back, rigid_from=len(back))
                except InfeasiblePath as exc:  # the turned approach leaves the arm's reach
                    log.warning(
                        "retreat from %s: the turned approach is infeasible (%s); opening the "
                        "hand and backing out along its approach axis instead",
                        last.wrt.name,
                        exc,
                    )
                    self._withdraw()
            self._follow(joint_path(self.robot.arm_q(), last.path.q[0]), speeds={0: FREE_SPEEDS})
