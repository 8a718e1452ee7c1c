"""The bridge's guarded moves, without ROS (design §9): a goal's via-points checked by the
safety layer, sent to the arm's driver, watched by the contact guard and the safety state
(rrg_hw_bridge.bridge_core) until the controller answers, and reported as an outcome the node
turns into a GuardedMove result."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from rrg_models.config import SENSING
from rrg_models.trajectory import GOAL_START_TOLERANCE, GoalError, client_fraction

from .bridge_core import ActiveMove, BridgeCore
from .config import BRIDGE
from .contact_guard import ContactGuard, StopSensing, path_index
from .driver_api import DriverError, Latched
from .safety import (
    SafetyCode,
    check_recovery,
    check_trajectory,
    limit_excess,
    scale_time,
    slowdown_to_limits,
)

#: via_points(q0) → (q (M,7) [rad], t (M,) [s]) of a goal, the arm's configuration q0 first;
#: raises GoalError for a goal it refuses.
ViaPoints = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class MoveRequest:
    """A guarded move as the interface asked for it."""

    via_points: ViaPoints
    stop_on_contact: bool
    tip_force_threshold: float = 0.0  # N, 0: the default (SENSING)
    pad_force_threshold: float = 0.0  # N, 0: the default (SENSING)


@dataclass
class MoveOutcome:
    """How a guarded move ended: ``status`` "succeeded", "aborted" or "canceled"; the result
    code and message; for a move that ran, how far it got along the client's path and whether
    a contact stopped it."""

    status: str
    code: int = SafetyCode.NONE
    message: str = ""
    ran: bool = False
    path_fraction: float = 0.0
    stopped_on_contact: bool = False
    unconfirmed_stops: int = 0
    #: for a move a contact stopped, what fired from its stop until the arm was at rest
    #: (ActiveMove.stop_sensing); None otherwise
    stop_sensing: StopSensing | None = None


class ArmMotion:
    """Runs one guarded move at a time on the bridge's core and the arm's driver."""

    def __init__(self, core: BridgeCore, publish_plan: Callable[[np.ndarray, np.ndarray], None]):
        self.core = core
        self.publish_plan = publish_plan
        self.busy = threading.Lock()

    def plan(self, request: MoveRequest) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """(q (K,7), t (K,) [s, speed-scaled], the kept points' indices into the followed
        points, the client's point count) of a goal, refusing it (GoalError)."""
        q, t = request.via_points(self.core.measured().arm_q)
        keep = [0]
        for k in range(1, len(t)):
            # A point less than one control period after the last kept one is the same instant:
            # dropped if it is where that one is, refused if it jumps.
            if t[k] - t[keep[-1]] >= BRIDGE.min_segment_time:
                keep.append(k)
            elif np.abs(q[k] - q[keep[-1]]).max() > GOAL_START_TOLERANCE:
                raise GoalError(
                    f"points {keep[-1]} and {k} are {np.abs(q[k] - q[keep[-1]]).max():.3f} rad "
                    f"apart within {BRIDGE.min_segment_time * 1e3:.0f} ms",
                    SafetyCode.INVALID_TRAJECTORY,
                )
        if len(keep) < 2:
            raise GoalError("the trajectory does not move the arm", SafetyCode.INVALID_TRAJECTORY)
        keep = np.asarray(keep)
        return q[keep], scale_time(t[keep], self.core.speed_scale), keep, len(t) - 1

    def retime(self, q: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Times t stretched uniformly until the velocity and acceleration limits hold (when
        ``retime`` is on and the stretch is at most ``max_slowdown``; otherwise unchanged, and
        the check refuses the trajectory)."""
        options = self.core.options
        k = slowdown_to_limits(q, t, self.core.limits)
        if k <= 1.0 or not options.retime or k > options.max_slowdown:
            return t
        self.core.log.info(
            f"retimed: {len(q) - 1} via-points slowed {k:.2f}x to the arm's velocity and "
            f"acceleration limits ({t[-1]:.2f} s → {t[-1] * k:.2f} s)"
        )
        return t * k * (1.0 + 1e-9)

    def execute(
        self, request: MoveRequest, cancel_requested: Callable[[], bool], ok: Callable[[], bool]
    ) -> MoveOutcome:
        """Check, send and watch one guarded move; every refusal is reported."""
        with self.busy:
            checked = self._check(request)
            if isinstance(checked, MoveOutcome):
                return checked
            q, t, keep, n_client, guard, recovery = checked
            move = ActiveMove(guard)
            if recovery:
                move.recovery_excess = float(limit_excess(q[0], self.core.limits).max())
            with self.core.lock:
                self.core.move = move
            try:
                return self._run(move, q, t, keep, n_client, cancel_requested, ok)
            finally:
                with self.core.lock:
                    self.core.move = None

    def _check(self, request: MoveRequest):
        """The move's via-points, times and guard once every check passes (q, t, keep,
        n_client, guard, recovery), or the refusal's outcome."""
        core = self.core
        refusal = core.gate()
        # a measured joint outside its limits refuses every goal but a slow recovery
        recovery = refusal is not None and refusal.check == "joint_limits"
        if refusal is not None and not recovery:
            return self._refuse(refusal.code, refusal.message, refusal.check)
        try:
            q, t, keep, n_client = self.plan(request)
        except GoalError as exc:
            return self._refuse(exc.code, str(exc), "goal")
        if recovery:
            refusal = check_recovery(q, t, core.limits)
            if refusal is not None:
                message = f"{core.limit_fault}; {refusal.message}"
                return self._refuse(refusal.code, message, refusal.check)
            core.log.warning(f"recovery move: {core.limit_fault}; moving it back")
        else:
            t = self.retime(q, t)
            refusal = check_trajectory(q, t, core.limits)
            if refusal is not None:
                return self._refuse(refusal.code, refusal.message, refusal.check)
        self.publish_plan(q, t)
        if core.options.dry_run:
            message = (
                f"dry run: {len(q) - 1} via-points over {t[-1]:.2f} s "
                "validated and published on bridge/plan"
            )
            return MoveOutcome("aborted", SafetyCode.DRY_RUN, message)
        effort_threshold = core.options.effort_threshold
        if request.stop_on_contact and effort_threshold > 0.0 and not core.interfaces["arm_effort"]:
            return self._refuse(
                SafetyCode.SENSOR_FAULT,
                f"the effort guard ({effort_threshold} N m) cannot run: the driver's joint "
                "states carry no arm efforts (missing or NaN); set effort_threshold:=0.0 "
                "to guard on the fingertips and pads alone",
                "effort_guard",
            )
        return q, t, keep, n_client, self._guard(request), recovery

    def _guard(self, request: MoveRequest) -> ContactGuard | None:
        """The move's contact guard (tared and started), or None for an unguarded move."""
        if not request.stop_on_contact:
            return None
        core = self.core
        core.hand.tare()
        tip, pad = request.tip_force_threshold, request.pad_force_threshold
        guard = ContactGuard(
            tip if tip > 0 else SENSING.tip_force_threshold,
            pad if pad > 0 else SENSING.pad_force_threshold,
            core.options.effort_threshold,
            core.options.confirm_stops,
        )
        guard.start(core.effort_baseline())
        return guard

    def _refuse(self, code: int, message: str, check: str) -> MoveOutcome:
        self.core.report(int(code), check, message, True)
        return MoveOutcome("aborted", int(code), message)

    def _run(self, move, q, t, keep, n_client, cancel_requested, ok) -> MoveOutcome:
        # The move is registered before the goal goes out, and the goal goes out through the
        # E-stop's gate: a latch either comes first (nothing is sent) or finds this move and
        # marks it, and the goal is canceled as soon as the controller has accepted it.
        core, arm = self.core, self.core.arm
        try:
            arm_handle = arm.send(arm.goal(q[1:], t[1:], BRIDGE.goal_time_tolerance))
        except Latched as exc:
            return self._refuse(SafetyCode.ESTOP, f"the E-stop is latched ({exc})", "estop")
        except DriverError as exc:
            return self._refuse(SafetyCode.CONTROLLER_FAILED, str(exc), "controller")
        if core.estop.engaged:  # latched while the controller accepted the goal
            core.stop_move(SafetyCode.ESTOP, "estop", "E-stop engaged")
        with core.lock:
            move.handle = arm_handle
            stopped = move.code is not None
        if stopped:  # a stop arrived while the goal was on its way
            arm_handle.cancel_goal_async()
        answer = arm_handle.get_result_async()
        self._wait(move, answer, t[-1], cancel_requested, ok)
        self.settle()
        index = path_index(q, core.measured().arm_q)
        original = float(np.interp(index, np.arange(len(keep)), keep))
        outcome = MoveOutcome("succeeded", ran=True)
        outcome.path_fraction = client_fraction(original, n_client)
        outcome.stopped_on_contact = move.trip is not None
        if move.trip is not None:
            with core.lock:
                outcome.stop_sensing = move.stop_sensing.copy()
        controller = answer.result().result if answer.done() else None
        return self._finish(move, controller, outcome)

    def _wait(self, move: ActiveMove, answer, duration_s: float, cancel_requested, ok) -> None:
        """Until the controller answers: cancel on the client's request or a timeout, and
        escalate a cancel the controller ignores."""
        core = self.core
        deadline = time.monotonic() + duration_s + BRIDGE.goal_time_tolerance + 5.0
        escalated = False
        while not answer.done():
            if cancel_requested() or not ok():
                core.stop_move(SafetyCode.CANCELED, "canceled", "canceled by the client")
            if time.monotonic() > deadline:
                core.stop_move(
                    SafetyCode.TIMEOUT, "timeout", "the controller did not finish in time"
                )
            core.wait_joint_state(0.01)
            since_stop = time.monotonic() - move.stopped_s
            if move.code is not None and since_stop > BRIDGE.cancel_escalation and not escalated:
                escalated = True
                self.escalate(move)
            if move.code is not None and since_stop > BRIDGE.cancel_escalation + 2.0:
                break  # the controller answers neither its cancel nor the hold

    def _finish(self, move: ActiveMove, controller, outcome: MoveOutcome) -> MoveOutcome:
        """The outcome of a move that ran, from why it stopped and the controller's answer."""
        core = self.core
        if move.code is None and controller is not None and controller.error_code != 0:
            outcome.status, outcome.code = "aborted", SafetyCode.CONTROLLER_FAILED
            outcome.message = (
                f"the controller aborted ({controller.error_code}): {controller.error_string}"
            )
            core.report(SafetyCode.CONTROLLER_FAILED, "controller", outcome.message, False)
        elif move.code is None or move.code == SafetyCode.NONE:
            guard = move.guard
            if guard is not None:
                outcome.unconfirmed_stops = guard.confirmation.rejected
                if guard.effort_threshold > 0.0 and move.trip is None:
                    core.log.info(
                        f"guarded move: peak effort change {guard.peak_effort_change:.2f}"
                        f" N m (joint {guard.peak_effort_joint + 1}) of the "
                        f"{guard.effort_threshold} N m threshold"
                    )
            if move.trip is not None:
                core.log.info(
                    f"guarded move stopped at {outcome.path_fraction:.2f} of its path: "
                    f"{move.message}"
                )
        elif move.code == SafetyCode.CANCELED:
            outcome.status, outcome.code, outcome.message = "canceled", move.code, "canceled"
        else:
            outcome.status, outcome.code, outcome.message = "aborted", int(move.code), move.message
        return outcome

    def escalate(self, move: ActiveMove) -> None:
        """The controller has not ended a canceled goal in time: hold the arm where it is
        measured, and declare a robot fault that refuses every command until reset."""
        core = self.core
        core.arm.hold(core.measured().arm_q, BRIDGE.hold_time)
        what = (
            f"the controller ignored a cancel ({move.message}) for "
            f"{BRIDGE.cancel_escalation:.1f} s; a hold was sent"
        )
        core.estop.latch_fault(what, time.monotonic())
        move.message = f"{move.message}; {what}: robot fault, reset to go on"
        core.report(SafetyCode.CONTROLLER_FAILED, "controller", what, False)

    def settle(self) -> None:
        """Wait until the arm has stopped (every joint slower than BRIDGE.settle_speed)."""
        deadline = time.monotonic() + BRIDGE.settle_timeout
        while time.monotonic() < deadline:
            if np.abs(self.core.measured().arm_v).max() < BRIDGE.settle_speed:
                return
            self.core.wait_joint_state(0.01)
