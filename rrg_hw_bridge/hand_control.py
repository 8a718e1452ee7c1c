"""The bridge's hand commands, without ROS (design §9): positioning the spread and the fingers,
and closing each finger until it stops, as the simulator's closing does
(rrg_models.hand_sensing.FingerClosing), on the driver's joint states and clock, under the
safety state's stops (rrg_hw_bridge.bridge_core)."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from enum import IntEnum

import numpy as np

from rrg_models.config import HAND, PHYSICS
from rrg_models.hand_sensing import FingerClosing

from .bridge_core import BridgeCore, HandMotion, HandStopped, Measured
from .config import BRIDGE
from .safety import SafetyCode

#: A close command moves the spread first only when it is this far from the request [rad]
#: (as the simulator node).
SPREAD_TOLERANCE = 0.01


class HandMode(IntEnum):
    """The modes of rrg_msgs/srv/HandCommand (a ROS-free mirror)."""

    POSITION = 0
    OPEN = 1
    CLOSE = 2
    CLOSE_GUARDED = 3


class HandControl:
    """Runs one hand command at a time on the bridge's core and the hand's driver."""

    def __init__(self, core: BridgeCore, ros_time):
        self.core = core
        #: the node's clock now [s] (the time drivers stamp their messages with)
        self.ros_time = ros_time
        self.busy = threading.Lock()

    def run(self, mode: HandMode, spread: float, proximal: np.ndarray) -> np.ndarray | None:
        """Run a command to its end → the sensors (10,) fired while closing (None when it does
        not close). Raises HandStopped (the safety layer stopped it), the driver's errors, or
        TimeoutError."""
        core = self.core
        with self.busy:
            with core.lock:
                core.hand_motion = HandMotion()
            try:
                if mode == HandMode.POSITION:
                    self.move_hand(spread, proximal)
                    return None
                if mode == HandMode.OPEN:
                    self.move_hand(spread, np.zeros(3))
                    return None
                m = core.measured()
                if abs(spread - m.hand_q[0]) > SPREAD_TOLERANCE:
                    self.move_hand(spread, m.hand_q[2:5])
                return self.close_hand(mode == HandMode.CLOSE_GUARDED)
            finally:
                with core.lock:
                    core.hand_motion = None

    def hand_states(
        self, since_s: float, timeout_s: float, what: str
    ) -> Iterator[tuple[float, Measured]]:
        """Each driver joint state with hand joints measured since ``since_s`` (the node's
        clock [s]: when the command went out), with the time [s] on the driver's clock since
        the one before (0 for the first). A hand loop counts stalls in the driver's time on
        states that can show its command's effect, so a late, queued or bursty stream cannot
        fake a stall. A state that arrives BRIDGE.hand_stamp_grace after the start counts
        whatever its stamp (a driver whose clock is behind). Checks the safety layer's stops
        meanwhile; TimeoutError after ``timeout_s`` [s] of wall time."""
        core = self.core
        start = time.monotonic()
        last = core.measured()
        first = True
        while time.monotonic() < start + timeout_s:
            core.wait_joint_state(0.02)
            self.check_hand_motion()
            m = core.measured()
            if m.hand_count == last.hand_count:
                continue
            if first and m.hand_stamp_s < since_s:
                if m.received_s - start < BRIDGE.hand_stamp_grace:
                    last = m
                    continue  # measured before the command: it cannot show its effect
            yield (0.0 if first else max(m.hand_stamp_s - last.hand_stamp_s, 0.0)), m
            first, last = False, m
        raise TimeoutError(f"the hand did not {what} within {timeout_s:.1f} s")

    def move_hand(self, spread: float, proximal: np.ndarray) -> None:
        """Move the spread and the proximal joints to their targets [rad] and wait until they
        are there or have stopped (e.g. on the object) for BRIDGE.hand_still_time of the
        driver's time."""
        driver = self.core.hand_driver
        since = self.ros_time()
        driver.move_spread(spread)
        driver.move_fingers(proximal)
        target = np.r_[spread, proximal]
        travel = np.abs(target - self.core.measured().hand_q[[0, 2, 3, 4]])
        speed = np.r_[PHYSICS.spread_speed, np.full(3, HAND.close_speed)]
        timeout = float(np.max(travel / speed)) + 2.0
        still = 0.0  # [s] of driver time every commanded joint has been slow
        what = f"reach {np.round(target, 3).tolist()} rad"
        for dt, m in self.hand_states(since, timeout, what):
            q, v = m.hand_q[[0, 2, 3, 4]], m.hand_v[[0, 2, 3, 4]]
            if np.all(np.abs(q - target) < BRIDGE.hand_position_tolerance):
                return
            still = still + dt if np.all(np.abs(v) < PHYSICS.stall_speed) else 0.0
            if still > BRIDGE.hand_still_time:
                return

    def close_hand(self, guarded: bool) -> np.ndarray:
        """Close every finger until it stops (FingerClosing, as the simulator's closing, fed
        each driver joint state on the driver's clock); returns the sensors (10,) fired at any
        time while closing."""
        core = self.core
        closing = FingerClosing(guarded)
        motion = core.hand_motion
        motion.closing = True  # the ceiling now limits each finger's squeeze
        velocity = np.full(3, closing.speed)
        since = self.ros_time()
        self.command_fingers(velocity, wait=True)
        sent = time.monotonic()
        # the driver's clock bounds the closing; the wall clock only a driver that stalls
        states = self.hand_states(since, 2.0 * closing.timeout + 2.0, "finish closing")
        try:
            for dt, m in states:
                now = time.monotonic()
                new = closing.update(dt, m.hand_v[2:5], core.hand.fired())
                squeezed = motion.squeezed & ~closing.stopped
                if squeezed.any():
                    core.log.info(
                        f"fingers {(np.nonzero(squeezed)[0] + 1).tolist()} stopped at the force "
                        "ceiling while closing"
                    )
                    closing.stopped |= squeezed
                    new = new | squeezed
                if closing.done or closing.elapsed >= closing.timeout:
                    break
                if new.any():
                    velocity[closing.stopped] = 0.0
                    self.command_fingers(velocity, wait=False)
                    sent = now
                elif now - sent > BRIDGE.finger_command_period:
                    self.command_fingers(velocity, wait=False)
                    sent = now
        finally:
            states.close()
            core.hand_driver.finger_velocities(np.zeros(3))
        return closing.touched

    def command_fingers(self, velocity: np.ndarray, wait: bool) -> None:
        """Send the closing loop's finger velocities, unless the safety layer has stopped the
        hand: checked and sent under the lock a stop takes, so no command follows a stop."""
        with self.core.hand_command_lock:
            self.check_hand_motion()
            self.core.hand_driver.finger_velocities(velocity, wait=wait)

    def check_hand_motion(self) -> None:
        """HandStopped when the safety layer stopped the running hand command (the E-stop, the
        force ceiling, the watchdog, a sensor fault or a joint-limit fault)."""
        core = self.core
        motion = core.hand_motion
        if motion is not None and motion.code is not None:
            raise HandStopped(motion.code, f"stopped by the safety layer: {motion.message}")
        if core.estop.engaged:  # a latch that came before this motion registered
            reason = core.estop.reason
            core.stop_hand(SafetyCode.ESTOP, "estop", f"E-stop latched ({reason})")
            raise HandStopped(SafetyCode.ESTOP, f"the E-stop is latched ({reason})")
