"""The WAM, the BarrettHand and the fingertip loads emulated by a PhysicsWorld stepped in real time
(no ROS): the core behind rrg_fake_hw.fake_hw_node.

A thread steps the world one control period (PHYSICS.timestep) at a time against
``time.monotonic()`` deadlines, under one lock. Before every step it sets the servo targets of

* a joint trajectory controller: via-points tracked with rrg_models.trajectory's
  ``servo_targets``, exactly as PhysicsWorld.follow does; a new goal preempts the running one, a
  cancel holds the arm where it is measured;
* the BarrettHand: spread and finger position moves ramped at the hand's speeds (as
  PhysicsWorld.move_hand does), finger velocity moves, and the worm-drive brake of a finger that
  is stopped (velocity 0 or idle), which a later move of that finger releases.

Readings for the driver emulations (``snapshot``) carry seeded noise where the real drivers'
readings are noisy (the arm's joint torques, pads). The joint torques are the motors', gravity
and motion included, as a real controller reports them. The fingertip loads are noise-free and
never tared, since the emulated Net F/T boxes add their own noise and the bias is the client's job.
Faults: a stuck finger, a joint-4 encoder glitch past its limit, and a synthetic force on
fingertip 1.

The same arm also answers as Barrett's own ROS 2 wam_node does (its own section below): a
real-time joint position stream that sets the servo targets and holds the arm after 0.5 s of
silence, holdJointPosition, and moveToJointPosition as a trapezoidal move.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from enum import Enum

import mujoco
import numpy as np

from rrg_models import wam
from rrg_models.config import HAND, PHYSICS
from rrg_models.description.mjcf_robot import (
    ARM_ACTUATORS,
    ARM_JOINTS,
    HAND_JOINTS,
    PALM_BODY,
    TIP_FORCE,
    TIP_TORQUE,
)
from rrg_models.trajectory import servo_targets
from rrg_sim.physics.sensing import HandSensors
from rrg_sim.physics.world import PhysicsWorld, WorldsByObject

#: Most control periods the stepping thread runs back to back after a late wake-up (chosen: 5
#: periods = 10 ms); periods missed beyond that are dropped and counted as overruns.
MAX_CATCH_UP = 5
#: How far past joint 4's upper limit [rad] the joint-limit fault reports it (chosen: far beyond
#: any tolerance a limit check allows, as an encoder glitch would be).
JOINT_LIMIT_GLITCH = 0.2
#: Control periods of joint readings kept for the driver emulation (chosen: 0.2 s at 500 Hz).
PERIOD_STATE_BACKLOG = 100
#: Joint 4 (index 3) is the one the joint-limit fault corrupts.
GLITCH_JOINT = 3
#: Largest lead [rad] of a finger's target over its measured angle in a velocity move: the lead at
#: which the proximal servo pushes with the hand's stall torque (HAND.close_torque /
#: PHYSICS.finger_kp), as a velocity-controlled motor at its current limit does.
VELOCITY_LEAD = HAND.close_torque / PHYSICS.finger_kp
#: Ramp speeds [rad/s] of the hand's channels: spread, proximal 1-3 (PhysicsWorld._hand_ramp).
HAND_SPEEDS = np.array([PHYSICS.spread_speed] + [HAND.close_speed] * 3)
#: JTC's message for a goal preempted by a new one (ros2_controllers jazzy,
#: joint_trajectory_controller.cpp, goal_accepted_callback).
PREEMPTED_MESSAGE = "Current goal cancelled due to new incoming action."
#: MuJoCo joints of the hand readings: spread (fingers 1, 2), proximal 1-3, distal 1-3.
SPREAD_JOINTS, PROXIMAL_JOINTS, DISTAL_JOINTS = HAND_JOINTS[:2], HAND_JOINTS[2:5], HAND_JOINTS[5:]

# Hand channel modes.
_HOLD, _POSITION, _VELOCITY = 0, 1, 2

# wam_node's arm interface (Barrett's barrett-ros2-pkg; its wam_node/src at e9056c2 of the copy
# github.com/gaolongsen/WAM-ROS2: wam_subscribers.h and wam_services.h).
#: wam_node holds the arm when no real-time command arrived for this long [s] (kRtMsgTimeout).
WAM_RT_TIMEOUT = 0.5
#: libbarrett's Wam::moveTo defaults, used by wam_node's moveToJointPosition: 0.5 rad/s and
#: 0.5 rad/s² along the straight joint-space line (systems/wam.h).
MOVE_TO_VELOCITY = 0.5
MOVE_TO_ACCELERATION = 0.5
#: Spacing [s] of the via-points an emulated moveTo samples its trapezoid at (chosen).
MOVE_TO_SAMPLE = 0.02
#: A streamed command's velocity feed-forward applies while it is this fresh [s] (chosen: 5
#: periods; a stream that stops leaves the arm at its last position, not ahead of it).
RT_FEED_FORWARD_AGE = 0.01
#: Messages of the goals that wam_node's commands end (emulation's own).
RT_PREEMPTED_MESSAGE = "replaced by wam_node's real-time joint position stream"
RT_TIMEOUT_MESSAGE = "wam_node: RT Control timed-out (holding)"
HOLD_MESSAGE = "replaced by wam_node's holdJointPosition"


class GoalState(Enum):
    """States of a trajectory goal (the JTC's outcomes)."""

    ACTIVE = "active"
    SUCCEEDED = "succeeded"
    CANCELED = "canceled"  # by a cancel request: the arm holds where it was
    PREEMPTED = "preempted"  # by a newer goal
    ABORTED = "aborted"  # by a reset or a simulation-only evaluation


@dataclass
class GoalStatus:
    """Where a trajectory goal stands."""

    goal_id: int
    state: GoalState
    #: Fractional via-point index commanded now (0 … M-1 of the followed points, the measured
    #: configuration prepended when the client's first point is later than t = 0).
    index: float
    #: Desired joint positions (7,) [rad] on the via-point polyline at ``index``.
    desired: np.ndarray
    message: str = ""


@dataclass
class Event:
    """One entry of the event log: what happened, when (time.monotonic() [s]), details."""

    name: str
    time_s: float
    details: dict = field(default_factory=dict)


@dataclass
class Snapshot:
    """The readings the drivers publish, all taken at one instant."""

    time_s: float  # time.monotonic() [s]
    #: time.monotonic() [s] of the control period that produced this state on the
    #: controller's clock, which runs with the simulated time (its joint states' stamp)
    stepped_s: float
    sim_time: float  # [s] since the last reset
    arm_q: np.ndarray  # (7,) [rad], as the encoders report (the joint-limit fault shows here)
    arm_qd: np.ndarray  # (7,) [rad/s]
    #: (7,) the motors' joint torques [N m], gravity and motion included, noisy: what
    #: ros2_control's effort state interface reports
    arm_effort: np.ndarray
    spread: np.ndarray  # (2,) spread joints of fingers 1, 2 [rad]
    proximal: np.ndarray  # (3,) [rad]
    distal: np.ndarray  # (3,) [rad]
    spread_velocity: np.ndarray  # (2,) [rad/s]
    proximal_velocity: np.ndarray  # (3,) [rad/s]
    distal_velocity: np.ndarray  # (3,) [rad/s]
    pads: np.ndarray  # (7,) pad forces [N], noisy
    tip_loads: np.ndarray  # (3,6) load on each fingertip [N, N m], sensor frame, noise-free
    #: (7,) the same torques as commanded, noise-free: wam_node's effort (libbarrett's
    #: getJointTorques)
    arm_torque: np.ndarray | None = None


@dataclass
class _Goal:
    goal_id: int
    q: np.ndarray  # (M,7) followed via-points
    ctrl: np.ndarray  # (N,7) servo targets
    index: np.ndarray  # (N,) fractional via-point index per period
    k: int = 0  # next period
    state: GoalState = GoalState.ACTIVE
    message: str = ""


@dataclass
class Timing:
    """Real-time statistics of the stepping thread."""

    steps: int = 0
    overruns: int = 0  # periods dropped because the thread fell more than MAX_CATCH_UP behind
    late_steps: int = 0  # periods stepped more than one period after their deadline
    max_lateness_s: float = 0.0


class EmulatedRobot:
    """The emulated arm controller, BarrettHand and fingertip loads (see the module doc).

    object_name: a catalogue object (rrg_models.objects). seed: seeds the world's sensor noise and
    the readings' noise. sensor_noise: scale of every noise σ (1: config values, 0: noiseless).
    """

    def __init__(self, object_name: str = "powerdrill", seed: int = 0, sensor_noise: float = 1.0):
        self.seed, self.sensor_noise = seed, sensor_noise
        self._worlds = WorldsByObject(seed=seed, sensor_noise=sensor_noise)
        self._lock = threading.RLock()
        self._rng = np.random.default_rng(seed)
        self._goal: _Goal | None = None
        self._goals: dict[int, _Goal] = {}
        self._next_goal_id = 1
        self._stuck: int | None = None
        self._joint_limit_fault = False
        self._extra_force = 0.0
        self._palm_push = 0.0  # [N]
        #: time.monotonic() [s] at sim time 0: the controller's clock (re-anchored when the
        #: real-time stepping restarts)
        self._epoch_s = time.monotonic()
        self._stepped_s = self._epoch_s
        #: each control period's joint readings, for a driver that publishes every period
        self._period_states: deque[Snapshot] = deque(maxlen=PERIOD_STATE_BACKLOG)
        self.record_periods = False
        self._events: list[Event] = []
        self._pending: deque[Event] = deque()
        self._listeners: list[Callable[[Event], None]] = []
        self._dispatch_lock = threading.Lock()
        self._deliver_lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._rebase = False
        self.timing = Timing()
        self._select_world(object_name)

    # ------------------------------------------------------------------ world
    def _select_world(self, object_name: str) -> None:
        self.world = self._worlds(object_name)
        m = self.world.model
        qadr = lambda names: np.array([m.jnt_qposadr[m.joint(n).id] for n in names])
        vadr = lambda names: np.array([m.jnt_dofadr[m.joint(n).id] for n in names])
        self._hand_q = {k: qadr(v) for k, v in self._hand_joint_groups().items()}
        self._hand_v = {k: vadr(v) for k, v in self._hand_joint_groups().items()}
        self._clean = HandSensors(m, self.world.data, np.random.default_rng(0), noise=0.0)
        adr = lambda names: np.array([m.sensor_adr[m.sensor(n).id] for n in names])[:, None]
        self._load_adr = np.hstack([adr(TIP_FORCE) + np.arange(3), adr(TIP_TORQUE) + np.arange(3)])
        self._sync_controllers()

    @staticmethod
    def _hand_joint_groups() -> dict[str, tuple[str, ...]]:
        return {"spread": SPREAD_JOINTS, "proximal": PROXIMAL_JOINTS, "distal": DISTAL_JOINTS}

    def _sync_controllers(self) -> None:
        """Controllers idle, holding the world's current servo targets (call under the lock)."""
        self._hand_target = self.world.servo_targets()[7:].copy()
        self._hand_goal = self._hand_target.copy()
        self._hand_mode = np.full(4, _HOLD)
        self._finger_speed = np.zeros(3)
        self._braked = np.zeros(3, bool)
        self._loads = self._read_loads()
        self._apply_palm_push()
        self._epoch_s = time.monotonic() - self.world.sim_time  # the clock goes on from now
        self._wam_reset()

    def _read_loads(self) -> np.ndarray:
        """(3,6) raw fingertip loads (HandSensors.read's wrench, noise-free, bias zero) with the
        extra force."""
        loads = -self.world.data.sensordata[self._load_adr]
        loads[0, 2] += self._extra_force
        return loads

    @contextmanager
    def exclusive(self) -> Iterator[PhysicsWorld]:
        """The world for a simulation-only operation that steps it by itself (e.g. judging a
        grasp): motions are aborted first, the controllers then hold whatever the world's servo
        targets are, and the real-time clock restarts (the pause counts as no overrun)."""
        with self._lock:
            self._abort("interrupted by a simulation-only operation")
            try:
                yield self.world
            finally:
                self._sync_controllers()
                self._rebase = True
        self._dispatch()

    def reset(self, object_name: str | None = None, pose=None) -> None:
        """Abort every motion; arm home, hand open, the object (a new one if ``object_name``
        differs) at the planar pose (x [m], y [m], θ [rad]) (default: where it was placed)."""
        with self._lock:
            self._abort("reset")
            if object_name is not None and object_name != self.world.obj.name:
                self._select_world(object_name)
            self.world.reset(pose)
            self._sync_controllers()
            self._rebase = True
        self._dispatch()

    # ------------------------------------------------------------------ stepping
    def advance(self, seconds: float) -> None:
        """Step ``seconds`` of simulated time at once (no pacing; not while the thread runs)."""
        if self.running:
            raise RuntimeError("advance() while the real-time thread runs")
        for _ in range(int(round(seconds / PHYSICS.timestep))):
            with self._lock:
                self._step()
            self._dispatch()

    def start(self) -> None:
        """Start stepping in real time in a daemon thread."""
        if self.running:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._loop, name="emulated_robot", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        if self._thread is not None:
            self._stop.set()
            self._thread.join()
            self._thread = None

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def __enter__(self) -> EmulatedRobot:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def _loop(self) -> None:
        dt = PHYSICS.timestep
        t0, done = time.monotonic(), 0  # deadline of period k: t0 + k dt
        while not self._stop.is_set():
            now = time.monotonic()
            if self._rebase:
                self._rebase = False
                t0, done = now, 0
                with self._lock:
                    self._epoch_s = now - self.world.sim_time
            due = int((now - t0) / dt) + 1 - done  # periods whose deadline has passed
            if due <= 0:
                time.sleep(t0 + done * dt - now)
                continue
            if due > MAX_CATCH_UP:
                self.timing.overruns += due - MAX_CATCH_UP
                done += due - MAX_CATCH_UP
                due = MAX_CATCH_UP
            lateness = now - (t0 + done * dt)
            if lateness > dt:
                self.timing.late_steps += 1
            self.timing.max_lateness_s = max(self.timing.max_lateness_s, lateness)
            with self._lock:
                if not self._rebase:
                    self._step()
            done += 1
            self.timing.steps += 1
            self._dispatch()

    def _step(self) -> None:
        """One control period (call under the lock)."""
        w = self.world
        arm = None
        self._rt_watch()
        goal = self._goal
        if goal is not None:
            arm = goal.ctrl[goal.k]
            goal.k += 1
            if goal.k >= len(goal.ctrl):
                self._finish(goal, GoalState.SUCCEEDED, "", time.monotonic())
        elif self._rt_tracking:
            arm = self._rt_target()
        self._hand_step()
        v0 = w.data.qvel[self._arm_dof].copy()
        w.step(arm, self._hand_target)
        self._applied = self._joint_torques_now(w.data.qvel[self._arm_dof] - v0)
        self._stepped_s = self._epoch_s + w.sim_time
        self._loads = self._read_loads()
        if self.record_periods:
            self._period_states.append(self.snapshot(pads=False))

    def period_states(self) -> list[Snapshot]:
        """The joint readings of every control period since the last call (oldest first; at
        most PERIOD_STATE_BACKLOG), when ``record_periods`` is set."""
        with self._lock:
            states = list(self._period_states)
            self._period_states.clear()
        return states

    def _hand_step(self) -> None:
        tgt, mode = self._hand_target, self._hand_mode
        if not mode.any():  # every channel holds
            return
        dt = PHYSICS.timestep
        pos = mode == _POSITION
        step = np.clip(self._hand_goal - tgt, -HAND_SPEEDS * dt, HAND_SPEEDS * dt)
        tgt[pos] += step[pos]
        mode[pos & (tgt == self._hand_goal)] = _HOLD  # arrived: hold
        vel = mode[1:] == _VELOCITY
        if vel.any():
            q = self.world.finger_angles()
            moved = np.clip(tgt[1:] + self._finger_speed * dt, q - VELOCITY_LEAD, q + VELOCITY_LEAD)
            moved = np.clip(moved, *HAND.proximal_range)
            tgt[1:][vel] = moved[vel]

    # ------------------------------------------------------------------ events
    def add_listener(self, listener: Callable[[Event], None]) -> None:
        """Call ``listener(event)`` for every new event (from the thread that caused it, outside
        the lock)."""
        self._listeners.append(listener)

    def events(self, name: str | None = None) -> list[Event]:
        """The event log so far (only ``name``'s events when given)."""
        with self._dispatch_lock:
            return [e for e in self._events if name is None or e.name == name]

    def _emit(self, name: str, time_s: float, **details) -> None:
        event = Event(name, time_s, details)
        with self._dispatch_lock:
            self._events.append(event)
            self._pending.append(event)

    def _dispatch(self) -> None:
        """Hand the pending events to the listeners, in the order they happened (one thread
        delivers at a time; call outside the lock)."""
        with self._deliver_lock:
            while True:
                with self._dispatch_lock:
                    if not self._pending:
                        return
                    event = self._pending.popleft()
                for listener in self._listeners:
                    listener(event)

    # ------------------------------------------------------------------ arm controller
    def follow(self, q, t) -> int:
        """Accept a trajectory goal: via-points q (M,7) [rad] at times t (M,) [s] from now (when
        t[0] > 0 the measured configuration is prepended at t = 0); it preempts a running goal.
        Returns the goal id; ValueError for an invalid trajectory."""
        received = time.monotonic()
        q, t = np.asarray(q, dtype=float), np.asarray(t, dtype=float)
        if q.ndim != 2 or q.shape[1] != 7 or len(q) == 0 or t.shape != (len(q),):
            raise ValueError(f"need q (M,7) and t (M,), got {q.shape} and {t.shape}")
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(t))):
            raise ValueError("non-finite via-points or times")
        if t[0] < 0.0 or np.any(np.diff(t) <= 0.0):
            raise ValueError("times must start at or after 0 and increase strictly")
        with self._lock:
            if t[0] > 0.0:
                q, t = np.vstack([self.world.arm_q(), q]), np.r_[0.0, t]
            ctrl, index = servo_targets(q, t)
            self._rt_tracking = False  # the goal replaces wam_node's stream
            if self._goal is not None:
                self._finish(self._goal, GoalState.PREEMPTED, PREEMPTED_MESSAGE, received)
            goal = _Goal(self._next_goal_id, q, ctrl, index)
            self._next_goal_id += 1
            self._goals[goal.goal_id] = goal
            self._goal = goal
            self._emit("goal_accepted", received, goal_id=goal.goal_id, points=len(q))
        self._dispatch()
        return goal.goal_id

    def cancel(self, goal_id: int | None = None) -> bool:
        """Cancel goal ``goal_id`` (default: the running one) and hold the arm at its measured
        configuration; False when that goal is not running."""
        received = time.monotonic()
        with self._lock:
            goal = self._goal
            # the truth at the cancel (evaluation only): the arm's largest contact torque [N m]
            contact = float(np.abs(self.world.arm_external_torque()).max())
            self._emit("cancel_received", received, goal_id=goal_id, contact_torque=contact)
            ok = goal is not None and goal_id in (None, goal.goal_id)
            if ok:
                self.world.hold_arm()
                self._finish(goal, GoalState.CANCELED, "canceled", received)
        self._dispatch()
        return ok

    def _finish(self, goal: _Goal, state: GoalState, message: str, time_s: float) -> None:
        goal.state, goal.message = state, message
        if self._goal is goal:
            self._goal = None
        self._emit("goal_finished", time_s, goal_id=goal.goal_id, state=state.value)

    def _abort(self, why: str) -> None:
        if self._goal is not None:
            self.world.hold_arm()
            self._finish(self._goal, GoalState.ABORTED, why, time.monotonic())

    def goal_status(self, goal_id: int) -> GoalStatus:
        """The state of goal ``goal_id`` (KeyError for an unknown id)."""
        with self._lock:
            g = self._goals[goal_id]
            index = float(g.index[min(g.k, len(g.index)) - 1]) if g.k else 0.0
            lo = min(int(np.floor(index)), max(len(g.q) - 2, 0))
            hi = min(lo + 1, len(g.q) - 1)
            desired = g.q[lo] + (index - lo) * (g.q[hi] - g.q[lo])
            return GoalStatus(goal_id, g.state, index, desired, g.message)

    # ------------------------------------------------------------------ wam_node's arm interface
    # Barrett's ROS 2 wam_node on the same arm: the real-time joint position stream and its
    # timeout (wam_subscribers.h: rtJointPositionCb, updateRT), holdJointPosition and
    # moveToJointPosition (wam_services.h). One arm: a stream, a hold, a move and a trajectory
    # goal each replace what the arm tracked before.

    def _wam_reset(self) -> None:
        """wam_node's real-time mode off (call under the lock)."""
        self._rt_active = False  # wam_node's rt_joint_position_status_
        self._rt_tracking = False  # the arm tracks the streamed reference (jp_track_)
        self._rt_last = -np.inf  # sim time [s] of the newest streamed command
        self._rt_q = self.world.arm_q()  # the streamed reference [rad]
        self._rt_ff = np.zeros(7)  # its velocity feed-forward [rad]
        self._rt_prev: tuple[float, np.ndarray] | None = None  # (stamp [s], q) of the last one
        self._rt_ignored = False  # a command the arm does not track arrived (reported once)
        m = self.world.model
        self._arm_dof = np.array([m.jnt_dofadr[m.joint(n).id] for n in ARM_JOINTS])
        #: the arm servos' velocity gains [N m s/rad] (their bias -kv q̇)
        self._arm_kv = -m.actuator_biasprm[[m.actuator(n).id for n in ARM_ACTUATORS], 2]
        self._applied = self._joint_torques_now(np.zeros(7))

    def rt_joint_positions(self, q, stamp_s: float = 0.0) -> None:
        """One command of wam_node's real-time joint position stream (/wam/RTJointPositionCMD):
        joint positions (7,) [rad] stamped ``stamp_s`` [s] (its header's; 0: unknown). As
        wam_node: the first command of a stream starts tracking at the measured configuration
        (its positions are ignored) and replaces any move; later ones set the reference the arm
        tracks, unless a hold or a move replaced the stream since it started: then they only
        keep it alive (event rt_command_ignored, once). Stream silence for WAM_RT_TIMEOUT holds
        the arm (event rt_timeout). The model's servo damping would lag the reference by
        kv/kp q̇, which the real arm's stiff, lightly damped PD does not: the velocity between
        two stamped commands is fed forward as servo_targets does. ValueError for a command of
        the wrong size (wam_node drops it) or non-finite positions (wam_node would send them
        to the arm)."""
        received = time.monotonic()
        q = np.asarray(q, dtype=float)
        if q.shape != (7,):
            raise ValueError(f"need 7 joint positions, got {q.size}")
        if not np.all(np.isfinite(q)):
            raise ValueError(f"non-finite joint positions {q.tolist()}")
        with self._lock:
            if not self._rt_active:
                self._rt_active = self._rt_tracking = True
                self._rt_ignored = False
                if self._goal is not None:
                    self._finish(self._goal, GoalState.PREEMPTED, RT_PREEMPTED_MESSAGE, received)
                self._rt_q, self._rt_ff = self.world.arm_q(), np.zeros(7)
                self._emit("rt_stream_started", received)
            else:
                self._rt_q, self._rt_ff = q, np.zeros(7)
                if self._rt_prev is not None and 0.0 < stamp_s - self._rt_prev[0] <= 0.1:
                    velocity = (q - self._rt_prev[1]) / (stamp_s - self._rt_prev[0])
                    self._rt_ff = velocity * (np.asarray(PHYSICS.arm_kv) / PHYSICS.arm_kp)
                if not self._rt_tracking and not self._rt_ignored:
                    self._rt_ignored = True
                    self._emit("rt_command_ignored", received)
            self._rt_prev = (stamp_s, q) if stamp_s > 0.0 else None
            self._rt_last = self.world.sim_time
        self._dispatch()

    def _rt_target(self) -> np.ndarray:
        """The arm's servo target while it tracks the stream (call under the lock)."""
        if self.world.sim_time - self._rt_last <= RT_FEED_FORWARD_AGE:
            return self._rt_q + self._rt_ff
        return self._rt_q

    def _rt_watch(self) -> None:
        """wam_node's updateRT: a stream silent for WAM_RT_TIMEOUT ends the real-time mode and
        holds the arm where it is, whatever it was doing (call under the lock)."""
        if self._rt_active and self.world.sim_time - self._rt_last > WAM_RT_TIMEOUT:
            now = time.monotonic()
            self._rt_active = self._rt_tracking = False
            if self._goal is not None:
                self._finish(self._goal, GoalState.ABORTED, RT_TIMEOUT_MESSAGE, now)
            self.world.hold_arm()
            self._emit("rt_timeout", now)

    def hold_joint_position(self, hold: bool = True) -> None:
        """wam_node's /wam/holdJointPosition: true holds the arm where it is measured
        (libbarrett's moveTo(getJointPositions(), false)), replacing any stream, move or goal; a
        stream's real-time mode goes on until its timeout, and its commands meanwhile do not
        reach the arm. false (wam_node: idle, the arm floats in gravity compensation) is
        emulated as a hold, the model having no idle mode (event release_received)."""
        received = time.monotonic()
        with self._lock:
            self._rt_tracking = False
            if self._goal is not None:
                self._finish(self._goal, GoalState.PREEMPTED, HOLD_MESSAGE, received)
            self.world.hold_arm()
            self._emit("hold_received" if hold else "release_received", received)
        self._dispatch()

    def move_to_joint_position(self, q) -> int:
        """wam_node's /wam/moveToJointPosition: a straight joint-space move from the measured
        configuration to q (7,) [rad] with a trapezoidal speed profile (MOVE_TO_VELOCITY,
        MOVE_TO_ACCELERATION, from rest), a trajectory goal of its own (goal_status); returns
        its goal id. ValueError for a wrong size or non-finite positions."""
        q = np.asarray(q, dtype=float)
        if q.shape != (7,) or not np.all(np.isfinite(q)):
            raise ValueError(f"need 7 finite joint positions, got {q.tolist()}")
        with self._lock:
            q0 = self.world.arm_q()
        length = float(np.linalg.norm(q - q0))
        v, a = MOVE_TO_VELOCITY, MOVE_TO_ACCELERATION
        ramp = min(v / a, np.sqrt(length / a))  # [s] accelerating (and decelerating)
        peak = a * ramp
        cruise = (length - peak * ramp) / peak if peak > 0.0 else 0.0
        total = max(2.0 * ramp + cruise, PHYSICS.timestep)
        t = np.r_[np.arange(MOVE_TO_SAMPLE, total, MOVE_TO_SAMPLE), total]
        up, flat = np.minimum(t, ramp), np.clip(t - ramp, 0.0, cruise)
        down = np.clip(t - ramp - cruise, 0.0, ramp)
        s = a * up**2 / 2 + peak * flat + peak * down - a * down**2 / 2
        fraction = np.clip(s / length, 0.0, 1.0) if length > 0.0 else np.ones_like(t)
        return self.follow(q0 + fraction[:, None] * (q - q0), t)

    def _joint_torques_now(self, dv: np.ndarray) -> np.ndarray:
        """(7,) the torques [N m] the arm's motors applied in the last step, whose velocity
        change was dv (7,) [rad/s]: the servo's and the gravity compensation's. The implicit
        integrator applies the servo's damping at the step's end velocity, -kv dv more than
        qfrc_actuator (evaluated at its start) says (call under the lock)."""
        d = self.world.data
        return d.qfrc_actuator[self._arm_dof] + d.qfrc_gravcomp[self._arm_dof] - self._arm_kv * dv

    # ------------------------------------------------------------------ hand
    def _commandable(self, fingers) -> np.ndarray:
        """The fingers (indices 0-2) of ``fingers`` that are not stuck."""
        return np.array([i for i in fingers if i != self._stuck], dtype=int)

    def _release(self, fingers: np.ndarray) -> None:
        """Give braked fingers their closing servo back (PhysicsWorld.release_fingers, one
        finger at a time so that other stopped fingers stay braked)."""
        for i in fingers:
            if self._braked[i]:
                self.world.release_finger(int(i))
                self._braked[i] = False

    def _brake(self, fingers: np.ndarray) -> None:
        """Stop fingers where they are, held by the worm drive (PhysicsWorld.brake_finger)."""
        for i in fingers:
            if not self._braked[i]:
                self.world.brake_finger(int(i))
                self._braked[i] = True
            self._hand_target[1 + i] = self.world.data.ctrl[8 + i]
            self._hand_mode[1 + i] = _HOLD

    def move_fingers(self, proximal) -> None:
        """Move the proximal joints to (3,) (or one angle for all) [rad] at HAND.close_speed;
        ValueError outside HAND.proximal_range."""
        goal = _in_range(np.broadcast_to(np.asarray(proximal, dtype=float), 3), "proximal")
        with self._lock:
            f = self._commandable(range(3))
            self._release(f)
            self._hand_goal[1 + f] = goal[f]
            self._hand_mode[1 + f] = _POSITION

    def move_spread(self, spread: float) -> None:
        """Move the spread to ``spread`` [rad] at PHYSICS.spread_speed; ValueError outside
        HAND.spread_range."""
        goal = float(_in_range(np.array([spread], dtype=float), "spread")[0])
        with self._lock:
            self._hand_goal[0] = goal
            self._hand_mode[0] = _POSITION

    def finger_velocities(self, velocity) -> None:
        """Move the proximal joints at (3,) [rad/s] (clipped to ±HAND.close_speed) until their
        joint limits; a finger at velocity 0 stops and is braked where it is."""
        v = np.asarray(velocity, dtype=float).reshape(3)
        if not np.all(np.isfinite(v)):
            raise ValueError(f"non-finite finger velocities {v.tolist()}")
        v = np.clip(v, -HAND.close_speed, HAND.close_speed)
        with self._lock:
            f = self._commandable(range(3))
            stop, move = f[v[f] == 0.0], f[v[f] != 0.0]
            self._brake(stop)
            self._release(move)
            self._finger_speed[move] = v[move]
            self._hand_mode[1 + move] = _VELOCITY

    def open_grasp(self) -> None:
        """Open every finger (proximal 0)."""
        self.move_fingers(HAND.proximal_range[0])

    def close_grasp(self) -> None:
        """Close every finger towards its joint limit (each stalls on whatever it meets)."""
        self.move_fingers(HAND.proximal_range[1])

    def idle(self) -> None:
        """Stop every hand motion: the spread holds where it is and the fingers are braked."""
        with self._lock:
            self._hand_target[0] = self._hand_goal[0] = self.world.hand_angles()[0]
            self._hand_mode[0] = _HOLD
            self._brake(self._commandable(range(3)))

    @property
    def braked(self) -> np.ndarray:
        """(3,) bool: fingers held by the worm-drive brake."""
        return self._braked.copy()

    # ------------------------------------------------------------------ faults
    def set_stuck_finger(self, finger: int | None) -> None:
        """Finger ``finger`` (0-2) stops where it is and ignores every command; None: none."""
        if finger is not None and finger not in (0, 1, 2):
            raise ValueError(f"stuck finger must be 0-2 or None, got {finger}")
        with self._lock:
            if finger is not None and finger != self._stuck:
                self._brake(np.array([finger]))
            self._stuck = finger

    def set_joint_limit_fault(self, on: bool) -> None:
        """Report joint 4 JOINT_LIMIT_GLITCH past its upper limit (an encoder glitch)."""
        self._joint_limit_fault = bool(on)

    def set_palm_push(self, force_n: float) -> None:
        """Push the palm with ``force_n`` [N] along the world's +z at its origin (a contact on
        the arm: its servos answer it, the fingertips feel nothing); 0: none."""
        if not np.isfinite(force_n):
            raise ValueError("palm push must be finite")
        with self._lock:
            self._palm_push = float(force_n)
            self._apply_palm_push()

    def _apply_palm_push(self) -> None:
        """The palm push into the world (after a reset too; call under the lock)."""
        palm = self.world.model.body(PALM_BODY).id
        self.world.data.xfrc_applied[palm] = [0.0, 0.0, self._palm_push, 0.0, 0.0, 0.0]

    def palm_push_torque(self) -> np.ndarray:
        """(7,) the joint torques [N m] of the palm push (the truth an observer estimates)."""
        with self._lock:
            m, d = self.world.model, self.world.data
            palm = m.body(PALM_BODY).id
            torque = np.zeros(m.nv)
            mujoco.mj_applyFT(
                m, d, d.xfrc_applied[palm, :3], d.xfrc_applied[palm, 3:], d.xpos[palm], palm, torque
            )
            return torque[self._arm_dof]

    def set_extra_force(self, force_n: float) -> None:
        """Add ``force_n`` [N] to fingertip 1's load along its z (a synthetic contact)."""
        if not np.isfinite(force_n):
            raise ValueError("extra force must be finite")
        with self._lock:
            self._extra_force = float(force_n)
            self._loads = self._read_loads()

    @property
    def stuck_finger(self) -> int | None:
        return self._stuck

    # ------------------------------------------------------------------ readings
    def object_pose(self) -> np.ndarray:
        """(4,4) true object pose in world (evaluation only)."""
        with self._lock:
            return self.world.object_pose()

    def tip_load(self, finger: int) -> np.ndarray:
        """(6,) load on fingertip ``finger`` (0-2) after the latest step: force [N], torque
        [N m] the object applies, in the Nano17's frame, noise-free, never tared, with the
        extra-force fault added (lock-free: safe from any thread at any rate)."""
        return self._loads[finger].copy()

    def snapshot(self, pads: bool = True) -> Snapshot:
        """Every reading the drivers publish, at one instant (``pads`` False: pad forces NaN,
        saving their noise draw)."""
        with self._lock:
            w, d = self.world, self.world.data
            arm_q = w.arm_q()
            if self._joint_limit_fault:
                arm_q[GLITCH_JOINT] = wam.UPPER[GLITCH_JOINT] + JOINT_LIMIT_GLITCH
            noise = self.sensor_noise
            effort = self._applied.copy()
            if noise > 0.0:
                effort = effort + self._rng.normal(0.0, PHYSICS.arm_torque_noise * noise, 7)
            pad_forces = np.full(7, np.nan)
            if pads:
                pad_forces = self._clean.read()[0]
                if noise > 0.0:
                    pad_forces += self._rng.normal(0.0, PHYSICS.pad_force_noise * noise, 7)
            return Snapshot(
                time_s=time.monotonic(),
                stepped_s=self._stepped_s,
                sim_time=w.sim_time,
                arm_q=arm_q,
                arm_qd=w.arm_velocity(),
                arm_effort=effort,
                spread=d.qpos[self._hand_q["spread"]].copy(),
                proximal=d.qpos[self._hand_q["proximal"]].copy(),
                distal=d.qpos[self._hand_q["distal"]].copy(),
                spread_velocity=d.qvel[self._hand_v["spread"]].copy(),
                proximal_velocity=d.qvel[self._hand_v["proximal"]].copy(),
                distal_velocity=d.qvel[self._hand_v["distal"]].copy(),
                pads=pad_forces,
                tip_loads=self._loads.copy(),
                arm_torque=self._applied.copy(),
            )


#: Slack [rad] on the hand's joint ranges: bhand_srvs' float32 fields round a limit such as
#: 2.44 rad up by ~ 6e-8 rad.
RANGE_TOLERANCE = 1e-6


def _in_range(values: np.ndarray, what: str) -> np.ndarray:
    """The values clipped to the joint's range; ValueError when they lie outside it."""
    lo, hi = HAND.spread_range if what == "spread" else HAND.proximal_range
    inside = (values >= lo - RANGE_TOLERANCE) & (values <= hi + RANGE_TOLERANCE)
    if not (np.all(np.isfinite(values)) and np.all(inside)):
        raise ValueError(f"{what} {values.tolist()} outside [{lo}, {hi}] rad")
    return np.clip(values, lo, hi)
