"""The bridge's safety state, without ROS (design §9): what the drivers last measured, the
E-stop, the watchdog, the force ceiling, the joint-limit fault and the contact guard of the
running move, and the stops they order. ``rrg_hw_bridge.ros.bridge_node`` feeds it the
drivers' streams and turns its answers into messages; ``arm_motion`` and ``hand_control``
run the arm's guarded moves and the hand's commands on it, as ``WrtExecutor`` serves the
simulator.

Every stream callback may run on its own thread (the I/O executor, the Net F/T receive
threads); the state they share is guarded by one lock.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from rrg_models.config import SENSOR_NAMES

from .arm_limits import ArmLimits
from .config import BRIDGE
from .contact_guard import ContactGuard, HandState, StopSensing, Trip, VelocityEstimate
from .driver_api import ArmDriver, FingertipSensors, HandDriver
from .external_torque import ExternalTorqueObserver
from .safety import EStop, ForceCeiling, Refusal, SafetyCode, Watchdog, limit_excess

#: arm_on_start arms the bridge this long [s] after its start, so that an E-stop a
#: transient-local publisher holds reaches it first (chosen: DDS discovery on one host takes
#: 0.1-0.5 s, measured by the bridge tests' startup; the message follows the match at once).
ARM_ON_START_DELAY_S = 1.0
#: What the driver's arm efforts are (parameter effort_kind).
EFFORT_KINDS = ("joint_torque", "external_torque")
#: A guarded move's effort baseline is the mean of the arm's last this many joint efforts (50 ms
#: of a 500 Hz driver). With one noisy sample as the baseline, the change between two samples
#: (σ√2 with the simulator's 0.2 N m effort noise) crosses the 1.2 N m threshold at 4.2σ: one
#: 3 s guarded move in free air in ten stopped on nothing (Monte Carlo, 500 Hz, 7 joints), where
#: the simulator, which compares one sample with 0, crosses it at 6σ. The mean brings it back to
#: 5.9σ.
EFFORT_BASELINE_SAMPLES = 25
#: A watchdog tick later than this fraction of watchdog_timeout after the previous one means the
#: bridge itself did not run meanwhile (its process descheduled, its threads starved): what the
#: drivers sent meanwhile waits unread in the Net F/T sockets and the joint-state subscription,
#: and rclpy's executor runs a ready timer before it takes a ready subscription. Such a tick
#: only looks (never two in a row); the next, a watchdog period later, judges. Measured on this
#: 2-core machine under load during a grasp: the bridge's receive threads saw records 0.14 s
#: apart whose boxes had sent them 1 ms apart.
WATCHDOG_SELF_STALL = 0.5
#: After a bias request the bridge tares on records that arrived this long [s] after it (chosen:
#: ten records at the boxes' 1 kHz, far beyond a LAN's sub-millisecond latency; a box applies
#: the bias to the samples after the request, so the records before it still carry the offset).
BIAS_SETTLE_S = 0.01
#: Longest wait [s] for those records before the bias is reported as failed.
BIAS_TIMEOUT_S = 1.0
#: A recovery move is stopped when a joint gets this much farther outside its limits than at
#: its start [rad] (chosen: above the WAM's encoder noise, well below a visible motion).
RECOVERY_SLACK = 0.01


class Log(Protocol):
    """Where the core logs: rclpy's node logger, or any with its keyword arguments."""

    def info(self, message: str, **kwargs) -> None: ...

    def warning(self, message: str, **kwargs) -> None: ...

    def error(self, message: str, **kwargs) -> None: ...


#: report(code, check, message, refused): a refusal or a safety stop, for people and
#: bridge/safety.
Report = Callable[[int, str, str, bool], None]


@dataclass(frozen=True)
class BridgeOptions:
    """The bridge's settings (its node's read-only parameters)."""

    limits: ArmLimits
    arm_driver_joints: tuple[str, ...]
    hand_driver_joints: tuple[str, ...]
    dry_run: bool = False
    #: sign of the driver's finger-1 spread reading (-1 where it is flipped)
    spread_sign: float = 1.0
    watchdog_timeout: float = BRIDGE.watchdog_timeout  # s
    #: pads derived from the fingertips (no pad stream to watch)
    derive_pads: bool = False
    force_ceiling: float = BRIDGE.force_ceiling  # N
    torque_ceiling: float = BRIDGE.torque_ceiling  # N m
    estop_heartbeat_timeout: float = 0.0  # s, 0: off
    estop_latch_file: str | None = None
    arm_on_start: bool = False
    effort_kind: str = EFFORT_KINDS[0]
    effort_threshold: float = 0.0  # N m, 0: off
    confirm_stops: bool = True
    retime: bool = True
    max_slowdown: float = BRIDGE.max_slowdown


@dataclass
class Measured:
    """The newest driver joint state, in RRG's joint order."""

    arm_q: np.ndarray = field(default_factory=lambda: np.full(7, np.nan))
    arm_v: np.ndarray = field(default_factory=lambda: np.zeros(7))
    arm_effort: np.ndarray | None = None
    hand_q: np.ndarray = field(default_factory=lambda: np.full(8, np.nan))  # HAND_JOINT_NAMES
    hand_v: np.ndarray = field(default_factory=lambda: np.zeros(8))
    received_s: float = -np.inf  # monotonic time of arrival
    hand_count: int = 0  # driver joint states with hand joints received so far
    hand_stamp_s: float = -np.inf  # the newest one's driver stamp [s] (arrival when unstamped)

    def copy(self) -> Measured:
        """A copy whose arrays are the caller's."""
        return Measured(
            self.arm_q.copy(),
            self.arm_v.copy(),
            self.arm_effort,
            self.hand_q.copy(),
            self.hand_v.copy(),
            self.received_s,
            self.hand_count,
            self.hand_stamp_s,
        )


@dataclass
class HandMotion:
    """A hand command being executed, and why the safety layer stopped it (set once). While
    the hand closes, the force ceiling limits each finger's squeeze instead: a finger whose
    fingertip crosses it stops (``squeezed``) and the others close on."""

    closing: bool = False
    code: int | None = None
    message: str = ""
    squeezed: np.ndarray = field(default_factory=lambda: np.zeros(3, bool))


class HandStopped(RuntimeError):
    """The safety layer stopped a hand motion (its code and message)."""

    def __init__(self, code: int, message: str):
        super().__init__(message)
        self.code = code


@dataclass
class ActiveMove:
    """The guarded move being executed, and why it stops (set once)."""

    guard: ContactGuard | None
    handle: object | None = None  # the controller's goal handle
    code: int | None = None
    message: str = ""
    trip: Trip | None = None
    stopped_s: float = np.nan
    #: what fired from the stop until the arm was at rest (the trip's sensors among it); the
    #: result reports it with the reading at the hold
    stop_sensing: StopSensing = field(default_factory=StopSensing)
    #: a recovery move (joints outside their limits, brought back): how far outside they were
    #: at its start [rad]; None for any other move
    recovery_excess: float | None = None


@dataclass(frozen=True)
class JointState:
    """A driver joint state as plain arrays (names, positions [rad], velocities [rad/s] and
    efforts [N m], each possibly empty or NaN, and its stamp [s] on the driver's clock)."""

    name: tuple[str, ...]
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray
    stamp_s: float


class BridgeCore:
    """The bridge's safety state and the stops it orders, fed by the drivers' streams."""

    def __init__(self, options: BridgeOptions, log: Log, report: Report) -> None:
        self.options = options
        self.limits = options.limits
        self.log = log
        self.report = report
        self.speed_scale = 1.0  # the node sets it; run-time changes may only lower it
        self.hand = HandState(derive_pads=options.derive_pads)
        self.ceiling = ForceCeiling(options.force_ceiling, options.torque_ceiling)
        now = time.monotonic()
        self.estop = EStop(options.estop_heartbeat_timeout, options.estop_latch_file, now)
        #: when arm_on_start arms the bridge: after a transient-local E-stop could have arrived
        self._arm_at = now + ARM_ON_START_DELAY_S if options.arm_on_start else None
        # a silent pad topic is a fault, not a hand that never touches anything
        streams = ("joint_states", "fingertip1", "fingertip2", "fingertip3")
        pads = () if options.derive_pads else ("pads",)
        self.watchdog = Watchdog(options.watchdog_timeout, streams + pads)
        self.pad_count = 0
        self.joint_count = 0
        self.lock = threading.Lock()
        self._measured = Measured()
        self._joint_event = threading.Condition()
        self._efforts: deque[np.ndarray] = deque(maxlen=EFFORT_BASELINE_SAMPLES)
        #: the arm's external torques from its joint torques (effort_kind joint_torque)
        joint_torques = options.effort_kind == EFFORT_KINDS[0]
        self.observer = ExternalTorqueObserver() if joint_torques else None
        #: per joint-name list, for drivers whose joint states carry no velocities
        self._velocity: dict[tuple[str, ...], VelocityEstimate] = {}
        self.move: ActiveMove | None = None
        self.hand_motion: HandMotion | None = None
        self.hand_command_lock = threading.RLock()  # the closing loop's commands vs a stop
        #: which interfaces the driver's joint states carry (finite values); what is missing is
        #: derived (velocities) or disables its guard (efforts)
        self.interfaces = {"arm_velocity": False, "arm_effort": False, "hand_velocity": False}
        self._interfaces_logged: dict = {}
        self._sensor_fault_s = -np.inf
        self._latch_reset_s = np.full(3, -np.inf)  # per box: the last RESET_THRESHOLD_LATCH
        self._sensor_fault = ""
        self._stale: list[str] = []
        self._watchdog_tick_s = now
        self._watchdog_skipped = False
        self._status_last = (now, 0, 0)  # (time [s], joint states, pad samples)
        self.limit_fault = ""
        self.arm: ArmDriver | None = None
        self.arm_text = ""
        self.hand_driver: HandDriver | None = None
        self.sensors: FingertipSensors | None = None

    def attach(
        self, arm: ArmDriver, arm_text: str, hand: HandDriver, sensors: FingertipSensors
    ) -> None:
        """The drivers (created after the core: they call back into it)."""
        self.arm, self.arm_text, self.hand_driver, self.sensors = arm, arm_text, hand, sensors

    @property
    def arm_on_start_pending(self) -> bool:
        """Whether arm_on_start will still arm the bridge."""
        return self._arm_at is not None

    # ------------------------------------------------------------------ state
    def measured(self) -> Measured:
        """A copy of the newest driver joint state."""
        with self.lock:
            return self._measured.copy()

    def effort_baseline(self) -> np.ndarray | None:
        """(7,) mean of the arm's recent joint efforts [N m] (EFFORT_BASELINE_SAMPLES), or None
        when the driver reports none."""
        with self.lock:
            if self._measured.arm_effort is None or not self._efforts:
                return None
            return np.mean(self._efforts, axis=0)

    def wait_joint_state(self, timeout: float) -> None:
        """Wait at most ``timeout`` [s] for the next driver joint state."""
        with self._joint_event:
            self._joint_event.wait(timeout)

    def gate(self) -> Refusal | None:
        """Why no command may start now (the E-stop or a robot fault, the arm's driver missing,
        a sensor fault, stale data, a joint-limit fault). A recent sensor fault comes before
        stale data: a box reporting a status error also goes stale (its records are not used),
        and the status error is the cause."""
        reason = self.estop.reason
        if reason.startswith(EStop.ROBOT_FAULT):
            return Refusal(SafetyCode.CONTROLLER_FAILED, "controller", f"{reason}; reset first")
        if reason:
            return Refusal(SafetyCode.ESTOP, "estop", f"the E-stop is latched ({reason})")
        if not self.options.dry_run and not self.arm.ready():
            return Refusal(
                SafetyCode.CONTROLLER_FAILED,
                "controller",
                f"the arm's driver ({self.arm_text}) is not available (yet)",
            )
        if time.monotonic() - self._sensor_fault_s < BRIDGE.sensor_fault_hold:
            return Refusal(SafetyCode.SENSOR_FAULT, "sensor", self._sensor_fault)
        stale = self.watchdog.stale(time.monotonic())
        if stale:
            return Refusal(SafetyCode.STALE_DATA, "watchdog", self.stale_message(stale))
        if self.limit_fault:
            return Refusal(SafetyCode.JOINT_LIMITS, "joint_limits", self.limit_fault)
        return None

    def describe_interfaces(self) -> str:
        """What the driver's joint states carry, and what the missing interfaces disable."""
        i, effort = self.interfaces, self.options.effort_threshold
        parts = [
            "arm velocities " + ("measured" if i["arm_velocity"] else "derived from positions"),
            "hand velocities "
            + ("measured" if i["hand_velocity"] else "derived from positions (stall detection)"),
        ]
        if i["arm_effort"]:
            parts.append(
                "arm efforts measured ("
                + (
                    f"joint torques: the external torque from a momentum observer, gain "
                    f"{self.observer.gain_per_s:.0f}/s"
                    if self.observer is not None
                    else "external torques"
                )
                + ")"
            )
        elif effort > 0.0:
            parts.append(
                f"NO arm efforts (missing or NaN): the effort guard ({effort} N m) cannot run, "
                "and guarded moves are refused until effort_threshold:=0.0"
            )
        else:
            parts.append("no arm efforts (the effort guard is off)")
        return "; ".join(parts)

    def stale_message(self, stale: list[str]) -> str:
        """Which streams are stale, and why the sensors say they are unread."""
        unread = self.sensors.unread()
        why = "".join(f" ({name}: {unread[name]})" for name in stale if name in unread)
        timeout_ms = self.options.watchdog_timeout * 1e3
        return f"no fresh data from {', '.join(stale)} within {timeout_ms:.0f} ms" + why

    def status_values(self, now: float) -> dict[str, str]:
        """The streams' rates since the last call and the safety state, for bridge/status."""
        count, pads = self.joint_count, self.pad_count
        then, before, pads_before = self._status_last
        self._status_last = (now, count, pads)
        return {
            "joint_states": f"{(count - before) / (now - then):.0f} Hz",
            "pads": "derived from the fingertips"
            if self.hand.derive_pads
            else f"{(pads - pads_before) / (now - then):.0f} Hz",
            **self.sensors.status(),
            "estop": self.estop.reason or "armed",
            "stale": ", ".join(self.watchdog.stale(now)) or "none",
            "dry_run": str(self.options.dry_run),
            "speed_scale": f"{self.speed_scale:g}",
            "interfaces": self.describe_interfaces(),
        }

    # ------------------------------------------------------------------ stops
    def stop_move(
        self,
        code: int,
        check: str,
        message: str,
        trip: Trip | None = None,
        only: ActiveMove | None = None,
        spare=None,
    ) -> None:
        """Stop the running move (once): cancel the controller's goal, which holds the arm.
        The move is the one running when the lock is taken: with ``only``, only if it is that
        move; with ``spare`` (a predicate on it), not if it spares it."""
        with self.lock:
            move = self.move
            if move is None or move.code is not None:
                return
            if (only is not None and move is not only) or (spare is not None and spare(move)):
                return
            move.code, move.message, move.trip = code, message, trip
            move.stopped_s = time.monotonic()
            if trip is not None:
                move.stop_sensing.add(trip.sensors, self.hand.tips())
            handle = move.handle
        if handle is not None:
            handle.cancel_goal_async()
        if code not in (SafetyCode.NONE, SafetyCode.CANCELED):  # a contact's trip: no event
            self.report(code, check, message, False)

    def stop_hand(self, code: int, check: str, message: str) -> bool:
        """Stop the running hand command (once): every hand motor stops at once. False when
        no hand command was running (or it had been stopped already)."""
        with self.lock:
            motion = self.hand_motion
            if motion is None or motion.code is not None:
                return False
            motion.code, motion.message = code, message
        with self.hand_command_lock:  # no finger command of the closing loop follows it
            self.hand_driver.stop(self.measured().hand_q[0])
        self.report(code, check, f"hand command: {message}", False)
        return True

    def stop_all(self, code: int, check: str, message: str) -> None:
        """Stop the arm's move and the hand's motion."""
        self.stop_move(code, check, message)
        self.stop_hand(code, check, message)

    def contact(self, trip: Trip | None, move: ActiveMove) -> None:
        """A guarded move's contact: the move stops (no safety event)."""
        if trip is not None:
            self.stop_move(SafetyCode.NONE, "contact", trip.describe(SENSOR_NAMES), trip, move)

    def emergency_stop(self, why: str, latched: bool) -> None:
        """The E-stop latched (``latched``: just now): the arm holds and every hand motor
        stops, whether or not a command runs."""
        self.stop_move(SafetyCode.ESTOP, "estop", why)
        if latched:
            if not self.stop_hand(SafetyCode.ESTOP, "estop", why):  # no command ran: stop anyway
                self.hand_driver.stop(self.measured().hand_q[0])
            self.report(SafetyCode.ESTOP, "estop", f"{why}: holding", False)

    def sensor_fault(self, message: str) -> None:
        """A sensor stream's fault: the arm holds, the hand stops, and commands are refused
        until the stream has been clean for BRIDGE.sensor_fault_hold."""
        self._sensor_fault_s = time.monotonic()
        self._sensor_fault = message
        self.log.warning(message, throttle_duration_sec=1.0)
        self.stop_all(SafetyCode.SENSOR_FAULT, "sensor", message)

    # ------------------------------------------------------------------ driver streams
    def on_joint_state(self, js: JointState) -> None:
        """A driver joint state: the measured state, the watchdog, the joint-limit fault and
        the running move's effort guard."""
        now = time.monotonic()
        arm, hand, pos, vel, eff = self._read_joint_state(js)
        with self.lock:
            self._store(arm, hand, pos, vel, eff, js.stamp_s, now)
            move = self.move
            m = self._measured
            arm_q, effort, hand_q = m.arm_q.copy(), m.arm_effort, m.hand_q.copy()
        if arm is not None:
            self._check_arm(arm_q, effort, hand_q, move, now)
        with self._joint_event:
            self._joint_event.notify_all()

    def _read_joint_state(self, js: JointState):
        """(arm indices or None, hand indices (None where absent), positions, velocities,
        efforts): velocities a driver lacks (or sends as NaN) are differentiated from the
        positions, and which interfaces the state carries is noted."""
        index = {n: i for i, n in enumerate(js.name)}
        try:
            arm = [index[n] for n in self.options.arm_driver_joints]
        except KeyError:
            arm = None
        hand = [index.get(n) for n in self.options.hand_driver_joints]
        pos, vel, eff = js.position, js.velocity, js.effort
        # A driver without velocities (wam_node), or with NaN for a joint that lacks the
        # interface (ros2_control's joint_state_broadcaster): differentiate the positions.
        measured_v = len(vel) == len(pos)
        if not measured_v or not np.isfinite(vel).all():
            estimate = self._velocity.setdefault(js.name, VelocityEstimate(len(pos)))
            derived = estimate.update(pos, js.stamp_s)
            vel = np.where(np.isfinite(vel), vel, derived) if measured_v else derived
        has_effort = len(eff) == len(pos)
        if arm is not None:
            self.interfaces.update(
                arm_velocity=measured_v and bool(np.isfinite(js.velocity[arm[0]])),
                arm_effort=has_effort and bool(np.isfinite(eff[arm]).all()),
                hand_velocity=measured_v
                and all(np.isfinite(js.velocity[i]) for i in hand if i is not None),
            )
        return arm, hand, pos, vel, eff

    def _store(self, arm, hand, pos, vel, eff, stamp_s: float, now: float) -> None:
        """Store a joint state's values as the measured state (under the lock)."""
        m = self._measured
        for k, i in enumerate(hand):
            if i is not None:
                sign = self.options.spread_sign if k == 0 else 1.0  # bhand_j11's reading
                m.hand_q[k] = sign * pos[i]
                m.hand_v[k] = sign * vel[i]
        if any(i is not None for i in hand):
            m.hand_count += 1
            m.hand_stamp_s = stamp_s
        if arm is not None:
            m.arm_q = pos[arm]
            m.arm_v = vel[arm]
            m.arm_effort = eff[arm] if self.interfaces["arm_effort"] else None
            if m.arm_effort is not None and self.observer is not None:
                m.arm_effort = self.observer.update(
                    stamp_s, m.arm_q, m.arm_v, m.arm_effort, m.hand_q, m.hand_v
                )
            if m.arm_effort is not None:
                self._efforts.append(m.arm_effort)
        m.received_s = now

    def _check_arm(self, arm_q, effort, hand_q, move: ActiveMove | None, now: float) -> None:
        """An arm joint state's checks: the watchdog, the joint limits, the effort guard."""
        if self.interfaces != self._interfaces_logged:
            self._interfaces_logged = dict(self.interfaces)
            self.log.info(f"driver joint states: {self.describe_interfaces()}")
        self.joint_count += 1
        self.watchdog.feed("joint_states", now)
        self.hand.set_hand_joints(hand_q[0], hand_q[2:5])
        outside = (arm_q < self.limits.lower) | (arm_q > self.limits.upper)
        if outside.any():
            j = int(np.argmax(outside))
            self.limit_fault = (
                f"measured joint {j + 1} at {arm_q[j]:.3f} rad is outside its limits "
                f"[{self.limits.lower[j]}, {self.limits.upper[j]}] rad"
            )
            excess = float(limit_excess(arm_q, self.limits).max())
            recovering = lambda mv: (
                mv.recovery_excess is not None and excess <= mv.recovery_excess + RECOVERY_SLACK
            )
            # judged on the move running when the stop is made: a recovery move registered
            # since this message arrived is spared
            self.stop_move(
                SafetyCode.JOINT_LIMITS, "joint_limits", self.limit_fault, spare=recovering
            )
            if move is None or not recovering(move):
                self.stop_hand(SafetyCode.JOINT_LIMITS, "joint_limits", self.limit_fault)
        else:
            self.limit_fault = ""
        if move is not None and move.guard is not None and effort is not None:
            self.contact(move.guard.check_effort(effort), move)

    def on_wrench(self, finger: int, wrench: np.ndarray, received_s: float) -> None:
        """A fingertip sample (load on the fingertip, sensor frame) from a box or a topic."""
        tips = self.hand.set_tip(finger, wrench)
        self.watchdog.feed(f"fingertip{finger + 1}", received_s)
        move, motion = self.move, self.hand_motion
        if move is None and motion is None:
            return
        self._while_stopping(move, tips)
        loads = self.hand.loads()  # the ceiling limits the load itself, whatever the tare
        over = self.ceiling.check(loads)
        if over is not None and move is None and motion.closing and np.isfinite(loads).all():
            motion.squeezed |= self.ceiling.over(loads)  # the squeeze's limit: that finger stops
        elif over is not None:
            # a guarded move stopped by the ceiling stopped on a contact too (its trip names
            # the sensors that crossed; the result's are those that fired until the hold)
            trip = None
            if move is not None and move.guard is not None and over.code == SafetyCode.FORCE_LIMIT:
                trip = Trip(move.guard.fired(self.hand.pads(), tips))
            self.stop_move(over.code, over.check, over.message, trip)
            self.stop_hand(over.code, over.check, over.message)
        elif move is not None and move.guard is not None:  # derived pads: read afresh per sample
            self.contact(
                move.guard.check_sensors(self.hand.pads(), tips, self.hand.derive_pads), move
            )

    def _while_stopping(self, move: ActiveMove | None, tips: np.ndarray) -> None:
        """Keep what a stopped guarded move's contact fires as the arm comes to rest
        (ActiveMove.stop_sensing); tips: the tared fingertip loads (3,6)."""
        if move is None or move.guard is None or move.code is None:
            return
        fired = move.guard.fired(self.hand.pads(), tips)
        with self.lock:
            move.stop_sensing.add(fired, tips)

    def on_sensor_fault(self, finger: int, kind: str, detail: str) -> None:
        """A Net F/T fault: the arm holds and the hand stops. A status word is first answered
        with RESET_THRESHOLD_LATCH (a latched threshold bit clears; goals run again once the
        stream has been clean for BRIDGE.sensor_fault_hold); one that persists after the reset
        is a real condition of the box, and the refusal says so."""
        now = time.monotonic()
        message = f"fingertip{finger + 1} Net F/T {kind}: {detail}"
        if kind == "status":
            since_reset = now - self._latch_reset_s[finger]
            if since_reset > BRIDGE.sensor_fault_hold:
                self._latch_reset_s[finger] = now
                self.sensors.reset_latch(finger)
                message += " (RESET_THRESHOLD_LATCH sent)"
            else:
                message += (
                    f", still there {since_reset:.2f} s after RESET_THRESHOLD_LATCH: a condition "
                    "of the box, not a latched threshold (its status page says which)"
                )
        self.sensor_fault(message)

    def on_box_config(self, finger: int, config, error: str) -> None:
        """A Net F/T box's netftapi2.xml was read (config), or could not be (error)."""
        name = f"fingertip{finger + 1}"
        if config is not None:
            self.log.info(f"{name}: {config.describe()}")
        else:
            self.log.warning(
                f"{name}: {error}; its records are not used until it is read",
                throttle_duration_sec=10.0,
            )

    def on_pads(self, forces: np.ndarray) -> None:
        """A pad sample (7,) [N]: fed to the watchdog, and to the running guarded move."""
        self.watchdog.feed("pads", time.monotonic())
        self.pad_count += 1
        self.hand.set_pads(forces)
        move = self.move
        self._while_stopping(move, self.hand.tips())
        if move is not None and move.guard is not None:
            self.contact(move.guard.check_sensors(self.hand.pads(), self.hand.tips(), True), move)

    def on_estop(self, engaged: bool) -> None:
        """An E-stop message (true: engaged)."""
        latched = self.estop.on_message(engaged, time.monotonic())
        if engaged:
            self.emergency_stop("E-stop engaged", latched)

    def on_watchdog(self) -> None:
        """The periodic check: arm_on_start, the E-stop's heartbeat, the streams' freshness."""
        now = time.monotonic()
        timeout = self.options.watchdog_timeout
        stalled = now - self._watchdog_tick_s > WATCHDOG_SELF_STALL * timeout
        self._watchdog_tick_s = now
        if stalled and not self._watchdog_skipped:  # the bridge was not running: read first
            self._watchdog_skipped = True
            self.estop.resumed(now)  # a heartbeat that stalled with it gets a whole timeout
            return
        self._watchdog_skipped = False
        if self._arm_at is not None and now >= self._arm_at:
            self._arm_at = None
            if self.estop.reason == EStop.NOT_ARMED:  # no E-stop came meanwhile
                armed, message = self.estop.reset(now)
                if armed:
                    self.log.info("armed (arm_on_start)")
                else:
                    self.log.warning(f"arm_on_start did not arm: {message}")
        if self.estop.check_heartbeat(now):
            self.emergency_stop(self.estop.reason, True)
        stale = self.watchdog.stale(now)
        if stale and stale != self._stale:
            self.log.error(f"watchdog: no fresh data from {', '.join(stale)}")
        elif not stale and self._stale:
            self.log.info("watchdog: every stream is fresh again")
        self._stale = stale
        if stale:
            self.stop_all(SafetyCode.STALE_DATA, "watchdog", self.stale_message(stale))

    def bias(self) -> tuple[bool, str]:
        """Bias the fingertip sensors and tare the hand on records that follow it →
        (done, message for people)."""
        if self.move is not None:
            return False, "a move is running; bias only an unloaded hand"
        requested_s = time.monotonic()
        self.sensors.bias()
        if self.sensors.biased_by_box:  # tare on records that carry the box's new bias
            fresh_s = requested_s + BIAS_SETTLE_S
            names = [f"fingertip{i + 1}" for i in range(3)]
            deadline = time.monotonic() + BIAS_TIMEOUT_S
            while time.monotonic() < deadline and any(
                self.watchdog.newest(n) < fresh_s for n in names
            ):
                time.sleep(0.002)
            late = [n for n in names if self.watchdog.newest(n) < fresh_s]
            if late:
                return False, (
                    f"biased, but no record from {', '.join(late)} within "
                    f"{BIAS_TIMEOUT_S:.1f} s after it: not tared"
                )
        self.hand.tare()
        return True, f"biased {self.sensors.describe()}"
