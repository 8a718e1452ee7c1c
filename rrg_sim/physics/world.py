"""PhysicsWorld: the MuJoCo stand-in for the real robot (algorithm §2, §4).

One scene (WAM + BarrettHand + table + one catalogue object as a free body). The API mirrors
what the robot offers the executor: place the object (simulation only), run a WRT τ(e) as
guarded moves through IK via-points, close the fingers until each stops, read an
``Observation`` (the planning core's type), retreat along the path, and judge a grasp by
lifting it. The object really moves when it is bumped; ``true_object_pose`` is for
evaluation only. The WRT sequence itself is ``rrg_sim.executor.wrt_executor.WrtExecutor``, which the
executor node also runs over ROS: this world is its ``Robot`` (``follow``, ``move_hand``,
``close_hand``, ``reading``, ``arm_q``, ``hand_angles``, ``hand_pose``).

Control: the WAM's position servos run every 2 ms control period; a guarded move checks the
pads and Nano17s after every period and stops (holds the current joint angles) as soon as
one crosses its threshold.
"""

from __future__ import annotations

from collections.abc import Callable

import mujoco
import numpy as np

from rrg_models import wam
from rrg_models.config import HAND, PHYSICS, WORLD
from rrg_models.description.mjcf_robot import (
    ARM_ACTUATORS,
    ARM_JOINTS,
    FINGER_ACTUATORS,
    FINGER_JOINTS,
    PALM_BODY,
    ROBOT_CONAFFINITY,
    ROBOT_CONTYPE,
    SPREAD_ACTUATOR,
    SPREAD_JOINT,
)
from rrg_models.hand_sensing import CLOSE_START_TIME, FingerClosing, Reading, StopConfirmation
from rrg_models.objects import ObjectModel, get_object
from rrg_models.observation import Observation
from rrg_models.poses import planar_map
from rrg_models.trajectory import (
    DensePath,
    InfeasiblePath,
    TimedPath,
    plan_path,
    servo_targets,
    timed_controls,
)
from rrg_models.wrt import WRT
from rrg_sim.config import NOMINAL, WorldProfile, world_profile
from rrg_sim.executor.wrt_executor import WrtExecutor
from rrg_sim.physics.realism import ModelConditions, draw_conditions, quantize
from rrg_sim.physics.scene import OBJECT_BODY, OBJECT_JOINT, build_model
from rrg_sim.physics.sensing import HandSensors

__all__ = ["PhysicsWorld", "InfeasiblePath", "WorldsByObject"]


class PhysicsWorld:
    """The simulated robot and one object (see the module doc).

    object_name: a catalogue name (rrg_models.objects). seed: seeds the sensor noise and the
    world profile's draws. sensor_noise: scale of every sensor's noise σ (1 = the profile's
    values, 0 = noiseless). profile: a config.WorldProfile or its spec (config.world_profile).
    confirm_stops: a guarded move stops on a lone pad only once the next pad sample agrees
    (hand_sensing.StopConfirmation); off only to measure what the confirmation gains.
    touch_table: the goal grasp and its probe begin with the object's table touch
    (rrg_sim.table_touch) and are raised by the height it reads; None: where the profile
    has calibration error or a table height draw (not in the nominal world, whose robot is
    its own model).
    """

    def __init__(
        self,
        object_name: str,
        seed: int = 0,
        sensor_noise: float = 1.0,
        profile: WorldProfile | str = NOMINAL,
        confirm_stops: bool = True,
        touch_table: bool | None = None,
    ):
        self.obj: ObjectModel = get_object(object_name)
        self.confirm_stops = confirm_stops
        #: lone pad trips that the next pad sample did not confirm, since the world was made
        #: (the executor's Robot.unconfirmed_stops)
        self.unconfirmed_stops = 0
        self.profile = world_profile(profile)
        self.touch_table = self.profile.uncertain_height if touch_table is None else touch_table
        self.model = build_model(object_name)
        self.data = mujoco.MjData(self.model)
        self.rng = np.random.default_rng(seed)
        self.sensors = HandSensors(
            self.model, self.data, self.rng, sensor_noise, profile=self.profile
        )
        m = self.model
        qadr = lambda j: int(m.jnt_qposadr[m.joint(j).id])
        vadr = lambda j: int(m.jnt_dofadr[m.joint(j).id])
        self._arm_q = np.array([qadr(j) for j in ARM_JOINTS])
        self._finger_q = np.array([qadr(j) for j in FINGER_JOINTS])
        self._finger_v = np.array([vadr(j) for j in FINGER_JOINTS])
        self._arm_v = np.array([vadr(j) for j in ARM_JOINTS])
        self._spread_q = qadr(SPREAD_JOINT)
        self._obj_q = qadr(OBJECT_JOINT)
        self._obj_v = vadr(OBJECT_JOINT)
        act = [m.actuator(a).id for a in ARM_ACTUATORS + (SPREAD_ACTUATOR,) + FINGER_ACTUATORS]
        if act != list(range(11)):
            raise RuntimeError("actuator order must be: 7 arm, spread, 3 fingers")
        self._palm = m.body(PALM_BODY).id
        self._obj_body = m.body(OBJECT_BODY).id
        self._robot_geom = (m.geom_contype == ROBOT_CONTYPE) & (
            m.geom_conaffinity == ROBOT_CONAFFINITY
        )
        self._obj_geom = m.geom_bodyid == self._obj_body
        # Which finger (1-3; 0: the palm) each hand geom belongs to, and which object part each
        # object geom is (-1: neither).
        self._geom_finger = np.full(m.ngeom, -1)
        self._geom_part = np.full(m.ngeom, -1)
        for g in range(m.ngeom):
            name = m.geom(g).name
            if name.startswith("bh/f") and name[4:5].isdigit():
                self._geom_finger[g] = int(name[4])
            elif name.startswith("bh/"):
                self._geom_finger[g] = 0
            elif name.startswith("object/") and name[7:].isdigit():
                self._geom_part[g] = int(name[7:])
        #: The object's true pose when a finger first touched it in the last closing (None
        #: before any closing).
        self.first_touch_pose: np.ndarray | None = None
        self._placed = np.asarray(WORLD.nominal_pose, dtype=float)
        table = np.array([m.geom("table").id, m.geom("table_slab").id])
        self._conditions = ModelConditions(
            m,
            self.profile,
            np.arange(7),
            m.body("wam/base").id,
            table,
            self._obj_body,
            np.flatnonzero(self._obj_geom),
        )
        self._resolution = np.asarray(self.profile.joint_resolution, dtype=float)
        self.executor = WrtExecutor(self)
        self._draw_conditions(seed)
        self.reset()

    # ------------------------------------------------------------------ state
    def reseed(self, seed: int) -> None:
        """Restart the sensor noise from ``seed`` and draw the profile's trial conditions
        from it (e.g. per trial); ``reset`` next."""
        self.rng = self.sensors.rng = np.random.default_rng(seed)
        self._draw_conditions(seed)

    def _draw_conditions(self, seed: int) -> None:
        """Set ``conditions``, this trial's (realism.draw_conditions), from their own stream of
        seed, and write them into the model."""
        self.conditions = draw_conditions(self.profile, np.random.default_rng((seed, 1)))
        self._conditions.apply(self.conditions)

    def reset(self, w=None) -> None:
        """Arm at home, hand open, object at w (default: where it was last placed), settled."""
        mujoco.mj_resetData(self.model, self.data)
        self.sensors.restart()
        self.release_fingers()
        self.data.qpos[self._arm_q] = wam.HOME_Q - self.conditions.joint_offset  # reads HOME_Q
        self.data.ctrl[:] = 0.0
        self.data.ctrl[:7] = wam.HOME_Q
        self.executor.forget()
        self.place_object(self._placed if w is None else w)

    def place_object(self, w) -> None:
        """Put the object at the true planar pose w = (x [m], y [m], θ [rad]) at rest, and let it
        settle."""
        self._placed = np.asarray(w, dtype=float)
        x, y, th = self._placed
        d = self.data
        d.qpos[self._obj_q : self._obj_q + 7] = [
            x,
            y,
            WORLD.table_top_z,
            np.cos(th / 2),
            0.0,
            0.0,
            np.sin(th / 2),
        ]
        d.qvel[self._obj_v : self._obj_v + 6] = 0.0
        mujoco.mj_forward(self.model, d)
        mujoco.mj_step(self.model, d, nstep=int(round(PHYSICS.settle_time / PHYSICS.timestep)))

    def true_object_pose(self) -> np.ndarray:
        """The object's planar pose (x, y, θ) in world: ground truth, for evaluation only."""
        R = self.data.xmat[self._obj_body].reshape(3, 3)
        p = self.data.xpos[self._obj_body]
        return np.array([p[0], p[1], np.arctan2(R[1, 0], R[0, 0])])

    def _body_pose(self, body: int) -> np.ndarray:
        """(4,4) pose of a body in world."""
        T = np.eye(4)
        T[:3, :3] = self.data.xmat[body].reshape(3, 3)
        T[:3, 3] = self.data.xpos[body]
        return T

    def object_pose(self) -> np.ndarray:
        """(4,4) object frame in world (ground truth)."""
        return self._body_pose(self._obj_body)

    def object_height(self) -> float:
        """z of the object's frame origin [m] (0 when it rests on the table)."""
        return float(self.data.xpos[self._obj_body][2])

    def arm_q(self) -> np.ndarray:
        """(7,) WAM joint angles as the encoders read them [rad] (the profile's zero offsets
        and resolution)."""
        return quantize(
            self.data.qpos[self._arm_q] + self.conditions.joint_offset, self._resolution
        )

    def finger_angles(self) -> np.ndarray:
        """(3,) proximal joint angles [rad]."""
        return self.data.qpos[self._finger_q].copy()

    def hand_angles(self) -> tuple[float, np.ndarray]:
        """Spread [rad] and (3,) proximal joint angles [rad]."""
        return float(self.data.qpos[self._spread_q]), self.finger_angles()

    def reading(self) -> Reading:
        """The hand's sensors now (noisy, see sensing.HandSensors)."""
        return self.sensors.reading()

    def hand_pose(self) -> np.ndarray:
        """(4,4) hand-frame pose in world as the robot measures it: forward kinematics of the
        joint readings (off the true pose by the profile's calibration error)."""
        return wam.fk(self.arm_q())

    def true_hand_pose(self) -> np.ndarray:
        """(4,4) hand-frame pose in world (ground truth, for evaluation only)."""
        return self._body_pose(self._palm)

    def hand_pose_error(self) -> np.ndarray:
        """(3,) the planar map (x [m], y [m], θ [rad], applied as compose_planar) that takes
        where the robot measures its hand to where the hand truly is: identity unless the
        profile's calibration error moves the hand (ground truth, for evaluation only)."""
        return planar_map(self.hand_pose(), self.true_hand_pose())

    def touching(self) -> dict[int, set[int]]:
        """The object parts (indices into obj.parts) each finger (1-3; 0: the palm) touches
        now (ground truth, for evaluation only)."""
        out: dict[int, set[int]] = {}
        for g1, g2 in self.data.contact.geom[: self.data.ncon]:
            for hand, obj in ((g1, g2), (g2, g1)):
                finger, part = self._geom_finger[hand], self._geom_part[obj]
                if finger >= 0 and part >= 0:
                    out.setdefault(int(finger), set()).add(int(part))
        return out

    def touching_while_held(self, seconds: float) -> dict[int, set[int]]:
        """``touching`` gathered over ``seconds`` of simulated time with every servo target
        kept: a finger closed on the object touches it in most periods, but its contact comes
        and goes between them (MuJoCo: a box pinched by three fingertips showed one, two or
        three fingers in contact from one period to the next)."""
        out: dict[int, set[int]] = {}
        for _ in range(max(1, int(round(seconds / PHYSICS.timestep)))):
            mujoco.mj_step(self.model, self.data)
            for finger, parts in self.touching().items():
                out.setdefault(finger, set()).update(parts)
        return out

    def object_in_hand(self) -> bool:
        """True while any hand or arm geom touches the object."""
        n = self.data.ncon
        g = self.data.contact.geom[:n]
        return bool(
            np.any(
                (self._robot_geom[g[:, 0]] & self._obj_geom[g[:, 1]])
                | (self._robot_geom[g[:, 1]] & self._obj_geom[g[:, 0]])
            )
        )

    @property
    def sim_time(self) -> float:
        """Simulated time since the last reset [s]."""
        return float(self.data.time)

    # ------------------------------------------------------------------ motion primitives
    def _hand_ramp(self, n: int, spread: float, proximal) -> np.ndarray:
        """(n,4) spread + proximal servo targets moving from the current targets to the given
        ones (proximal: one angle for every finger, or (3,)) at the hand's speeds (config),
        then holding."""
        dt = PHYSICS.timestep
        start = self.data.ctrl[7:].copy()
        goal = np.r_[spread, np.broadcast_to(proximal, 3)]
        speed = np.array([PHYSICS.spread_speed] + [HAND.close_speed] * 3)
        t = np.arange(1, n + 1)[:, None] * dt
        return start + np.clip(goal - start, -speed * t, speed * t)

    def _hand_ramp_steps(self, spread: float, proximal) -> int:
        start = self.data.ctrl[7:]
        travel = np.abs(np.r_[spread, np.broadcast_to(proximal, 3)] - start)
        speed = np.array([PHYSICS.spread_speed] + [HAND.close_speed] * 3)
        return max(1, int(np.ceil(np.max(travel / speed) / PHYSICS.timestep)))

    def _run(
        self,
        arm: np.ndarray,
        hand: np.ndarray | None = None,
        guard: bool = False,
        monitor: Callable[[], bool] | None = None,
    ) -> int | None:
        """Step through arm servo targets (N,7) and hand targets (N',4), each held past its end.
        With ``guard``, stop at the first period a sensed contact is confirmed (a Nano17 or the
        arm's collision detection, HandSensors.arm_collision, at once; a lone pad when the
        next pad sample agrees: hand_sensing.StopConfirmation, unless ``confirm_stops`` is
        off): hold the arm where it is and return that period's index; None when the motion
        completed. ``monitor`` is called after every period; when it returns True the motion
        stops the same way (e.g. a cancel)."""
        m, d = self.model, self.data
        n = len(arm) if hand is None else max(len(arm), len(hand))
        ctrl = np.repeat(d.ctrl[None], n, axis=0)
        ctrl[:, :7] = arm[np.minimum(np.arange(n), len(arm) - 1)]
        if hand is not None:
            ctrl[:, 7:] = hand[np.minimum(np.arange(n), len(hand) - 1)]

        trip = StopConfirmation(self.confirm_stops)

        def tripped() -> bool:  # a hand sensor, or the arm's collision detection (unsensed parts)
            s = self.sensors
            return trip.update(s.fired_now(), s.arm_collision(self._arm_v), s.pad_sample())

        if guard:
            self.sensors.schedule_false_alarms(n)

        try:
            for k in range(n):
                d.ctrl[:] = ctrl[k]
                mujoco.mj_step(m, d)
                if (guard and tripped()) or (monitor is not None and monitor()):
                    self.hold_arm()
                    return k
            return None
        finally:
            self.unconfirmed_stops += trip.rejected

    def hold(self, seconds: float) -> None:
        """Keep every servo target for ``seconds`` of simulated time."""
        mujoco.mj_step(self.model, self.data, nstep=int(round(seconds / PHYSICS.timestep)))

    def hold_arm(self) -> None:
        """Servo the arm to where it is now (a stop)."""
        self.data.ctrl[:7] = self.data.qpos[self._arm_q] + self.conditions.joint_offset

    def move_through(
        self,
        waypoints: np.ndarray,
        guard: bool = False,
        speeds: dict | None = None,
        rigid_from: int = 0,
        reconfigure: bool = False,
    ) -> tuple[DensePath, TimedPath, int | None]:
        """Move the hand from where it is along straight lines through hand waypoints (K,4,4)
        (trajectory.plan_path; segments before ``rigid_from`` may swivel the elbow, and with
        ``reconfigure`` the arm may first change IK branch by a joint-space move), optionally
        guarded. ``speeds``: (m/s, rad/s) per segment (segment 0 leads to waypoints[0]), see
        trajectory.sample_times. Returns the dense path, its timing and the period a guard
        stopped it (or None)."""
        path = plan_path(waypoints, self.arm_q(), rigid_from, reconfigure)
        timed = timed_controls(path, speeds)
        if guard:
            self.sensors.tare()
        return path, timed, self._run(timed.ctrl, guard=guard)

    def follow(
        self,
        q: np.ndarray,
        t: np.ndarray,
        guard: bool = False,
        monitor: Callable[[], bool] | None = None,
    ) -> float | None:
        """Track joint via-points q (M,7) (q[0]: the current configuration) reached at times t
        (M,) [s], optionally guarded (the Nano17s are tared first); ``monitor`` as in ``_run``.
        Returns the fractional via-point index commanded when the move stopped early, or None."""
        ctrl, index = servo_targets(np.asarray(q, dtype=float), np.asarray(t, dtype=float))
        if guard:
            self.sensors.tare()
        stop = self._run(ctrl, guard=guard, monitor=monitor)
        return None if stop is None else float(index[stop])

    def _finger_servo(self, finger: int, kp: float, torque: float) -> None:
        """Set proximal servo ``finger``'s stiffness [N m/rad] and torque limit [N m]."""
        a = 8 + finger
        self.model.actuator_gainprm[a, 0] = kp
        self.model.actuator_biasprm[a, 1] = -kp
        self.model.actuator_forcerange[a] = (-torque, torque)

    def close_hand(
        self, monitor: Callable[[], bool] | None = None, guarded: bool = False
    ) -> np.ndarray:
        """Close every finger at the hand's speed until it stops: stalled (closing slower than
        PHYSICS.stall_speed for PHYSICS.stall_time, e.g. at the torque limit on the object,
        or pushed back) or at its joint limit. A stopped finger keeps its stall torque and
        cannot be pushed back (the non-backdrivable worm drive, see config.PHYSICS.brake_kp).
        ``guarded`` (the paper's "carefully closing the fingers" after an early contact): the
        fingers close at HAND.careful_close_speed, and a finger also stops in the period any
        of its own sensors (proximal or distal pad, Nano17) fires, so it touches the object
        without pushing it on.
        ``monitor`` is called after every period (its answer is ignored: closing completes).
        Records the object's true pose when a finger first touches it (``first_touch_pose``;
        at the end when none does).

        Returns (10,) bool: the sensors that fired at any time during the closing (a careful
        touch often eases off once the finger has stopped, so the reading after it misses it)."""
        m, d = self.model, self.data
        dt = PHYSICS.timestep
        target = d.ctrl[8:11].copy()
        closing = FingerClosing(guarded)
        self.first_touch_pose = None
        for _ in range(int(round(closing.timeout / dt))):
            if self.first_touch_pose is None and any(f > 0 for f in self.touching()):
                self.first_touch_pose = self.true_object_pose()
            target = np.where(
                closing.stopped,
                target,
                np.minimum(target + closing.speed * dt, HAND.proximal_range[1]),
            )
            d.ctrl[8:11] = target
            mujoco.mj_step(m, d)
            if monitor is not None:
                monitor()
            fired = self.sensors.fired_now()
            for i in np.nonzero(closing.update(dt, d.qvel[self._finger_v], fired))[0]:
                self.brake_finger(i)
                target[i] = d.ctrl[8 + i]
            if closing.done:
                break
        if self.first_touch_pose is None:
            self.first_touch_pose = self.true_object_pose()
        return closing.touched

    def brake_finger(self, finger: int) -> None:
        """Hold finger where it is with the torque it pushes with now (worm-drive brake)."""
        a, q = 8 + finger, self.data.qpos[self._finger_q[finger]]
        torque = float(
            np.clip(
                PHYSICS.finger_kp * (self.data.ctrl[a] - q), -HAND.close_torque, HAND.close_torque
            )
        )
        self._finger_servo(finger, PHYSICS.brake_kp, PHYSICS.brake_torque)
        self.data.ctrl[a] = q + torque / PHYSICS.brake_kp

    def move_hand(self, spread: float, proximal, monitor: Callable[[], bool] | None = None) -> None:
        """Servo the spread and the proximal joints (one angle for all, or (3,)) to the given
        angles [rad] at the hand's speeds (releasing the brakes of stopped fingers), holding
        the arm; ``monitor`` as in ``_run``."""
        self.release_fingers()
        n = self._hand_ramp_steps(spread, proximal) + int(
            round(CLOSE_START_TIME / PHYSICS.timestep)
        )
        self._run(
            self.data.ctrl[None, :7].copy(), self._hand_ramp(n, spread, proximal), monitor=monitor
        )

    # ------------------------------------------------------------------ driver emulation
    # Real-time stepping for emulated hardware drivers (rrg_fake_hw): one control period
    # at a time with servo targets set from outside.
    def servo_targets(self) -> np.ndarray:
        """(11,) current servo targets: arm (7) [rad], spread, proximal 1-3 [rad]."""
        return self.data.ctrl.copy()

    def step(self, arm: np.ndarray | None = None, hand: np.ndarray | None = None) -> None:
        """One control period with arm servo targets (7,) and spread + proximal targets (4,)
        (None: keep the current ones)."""
        if arm is not None:
            self.data.ctrl[:7] = arm
        if hand is not None:
            self.data.ctrl[7:] = hand
        mujoco.mj_step(self.model, self.data)

    def release_fingers(self) -> None:
        """Give every finger its closing servo back (a braked finger can move again)."""
        for i in range(3):
            self.release_finger(i)

    def release_finger(self, finger: int) -> None:
        """Give one finger its closing servo back (its brake off)."""
        self._finger_servo(finger, PHYSICS.finger_kp, HAND.close_torque)

    def arm_velocity(self) -> np.ndarray:
        """(7,) arm joint velocities [rad/s]."""
        return self.data.qvel[self._arm_v].copy()

    def finger_velocities(self) -> np.ndarray:
        """(3,) proximal joint velocities [rad/s]."""
        return self.data.qvel[self._finger_v].copy()

    def arm_external_torque(self) -> np.ndarray:
        """(7,) contact torque on the arm joints [N m] (what the arm's collision detection
        estimates, see sensing.HandSensors.arm_collision)."""
        return self.data.qfrc_constraint[self._arm_v].copy()

    # ------------------------------------------------------------------ WRTs
    def execute_wrt(self, wrt: WRT, e) -> Observation:
        """Run τ(e) as guarded moves from the current (home) pose, close the fingers, and
        return the observation (rrg_sim.executor.wrt_executor.WrtExecutor.execute). The hand is left
        closed at the stop; call ``retreat`` next (for a goal WRT, ``physics.judge.judge_grasp``
        may come first). A "reorient" WRT also lifts the grasped object slightly, turns it by
        wrt.reorient_angle about the vertical through e, puts it down and opens the hand.
        Raises InfeasiblePath when IK fails. The goal grasp and its probe begin with the
        object's table touch when ``touch_table``."""
        touch = self.obj.table_touch if self.touch_table else None
        return self.executor.execute(wrt, e, touch=touch)

    def retreat(self) -> None:
        """Open the hand and retrace the executed path back to home (WrtExecutor.retreat)."""
        self.executor.retreat()

    @property
    def last_observation(self) -> Observation | None:
        last = self.executor.last
        return None if last is None else last.observation


class WorldsByObject:
    """One PhysicsWorld per object, made the first time it is asked for and kept, for a
    process that switches objects again and again (the simulator node, the emulated drivers).

    A world is about 20 MB of MuJoCo model and data. Making a new one at every switch left the
    freed ones resident: over hundreds of grasps the simulator's RSS grew by about 1 MB a grasp
    while malloc's bytes in use stayed flat. A kept world's noise goes on from one grasp to the
    next. ``world_args``: PhysicsWorld's keyword arguments, the same for every object.
    """

    def __init__(self, **world_args):
        self.world_args = world_args
        self._worlds: dict[str, PhysicsWorld] = {}

    def __call__(self, object_name: str) -> PhysicsWorld:
        if object_name not in self._worlds:
            self._worlds[object_name] = PhysicsWorld(object_name, **self.world_args)
        return self._worlds[object_name]
