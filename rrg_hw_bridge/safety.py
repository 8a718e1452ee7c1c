"""The bridge's safety layer, without ROS: trajectory checks before anything is sent, the
speed-scaling cap, the fingertip force ceiling, the stale-data watchdog and the latched E-stop.

``check_trajectory`` validates joint via-points q (M,7) [rad] at times t (M,) [s], where q[0]
is the arm's measured configuration at t[0] = 0 and the arm is at rest at both ends, against
an ``ArmLimits`` (rrg_hw_bridge.arm_limits), in this order:

1. shapes, finite values, t[0] = 0 and t strictly increasing → INVALID_TRAJECTORY;
2. every via-point within the joint position limits → JOINT_LIMITS;
3. every segment's velocity Δq/Δt within the velocity limits → JOINT_VELOCITY_LIMIT;
4. the acceleration at every via-point, (v_out - v_in) / mean(Δt_in, Δt_out), within the
   acceleration limits → JOINT_ACCELERATION_LIMIT. The arm rests before the first and after
   the last via-point (v = 0 over a segment of zero duration): a_0 = v_1 / (Δt_1 / 2). This is
   exact for a constant acceleration (segment mean velocities are mid-segment velocities);
5. the hand frame origin (rrg_models.wam.fk) and the arm's joint centres (rrg_models.wam.arm_points)
   of every via-point inside the workspace box → WORKSPACE.

A failed check returns a ``Refusal`` whose message names the first offending via-point (or
segment), the worst joint (or point) there, its value and the limit, with units.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from enum import IntEnum
from pathlib import Path
from typing import TypeVar

import numpy as np

from rrg_models import wam

from .arm_limits import ArmLimits

#: Slack on the position limits [rad] and the workspace box [m] for round-off.
POSITION_TOL = 1e-9
#: Relative slack on the velocity and acceleration limits for round-off (the executor times
#: joints at exactly their speed limit, which its via-points reproduce to ~ 1e-14).
RATE_REL_TOL = 1e-9
#: Names of the points the workspace check tests at every via-point: the hand frame origin,
#: then rrg_models.wam.arm_points (frames 3 and 4 origins either side of the elbow, frame 5 origin).
WORKSPACE_POINTS = (
    "hand frame origin",
    "elbow (frame 3 origin)",
    "elbow (frame 4 origin)",
    "wrist centre",
)
_AXES = ("x", "y", "z")
T = TypeVar("T")


class SafetyCode(IntEnum):
    """Result codes of rrg_msgs/action/GuardedMove (a ROS-free mirror)."""

    NONE = 0
    UNKNOWN = 100
    INVALID_TRAJECTORY = 101
    JOINT_LIMITS = 102
    CANCELED = 103
    TIMEOUT = 104
    JOINT_VELOCITY_LIMIT = 105
    JOINT_ACCELERATION_LIMIT = 106
    WORKSPACE = 107
    FORCE_LIMIT = 108
    STALE_DATA = 109
    SENSOR_FAULT = 110
    ESTOP = 111
    DRY_RUN = 112
    CONTROLLER_FAILED = 113


@dataclass(frozen=True)
class Refusal:
    """Why a command was refused or stopped: the code, the check's name, a message for people."""

    code: SafetyCode
    check: str
    message: str


# ------------------------------------------------------------------ trajectory checks
def check_shape(q, t, limits: ArmLimits) -> Refusal | None:
    """INVALID_TRAJECTORY unless q is (M,7) and t (M,) with M ≥ 2, all finite, t[0] = 0 and t
    strictly increasing."""
    bad = lambda msg: Refusal(SafetyCode.INVALID_TRAJECTORY, "trajectory", msg)
    try:
        q, t = np.asarray(q), np.asarray(t)
    except ValueError as exc:  # ragged nested sequences
        return bad(f"via-points or times are not rectangular arrays: {exc}")
    n = len(limits.joint_names)
    if q.ndim != 2 or q.shape[1] != n:
        return bad(f"via-points have shape {q.shape}, expected (M, {n}) joint angles [rad]")
    if t.shape != (q.shape[0],):
        return bad(f"times have shape {t.shape}, expected ({q.shape[0]},) for {q.shape[0]} points")
    if q.shape[0] < 2:
        return bad(f"{q.shape[0]} via-point(s): need the start and at least one target")
    real = lambda a: np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)
    if not (real(q) and real(t)):
        return bad(f"via-points ({q.dtype}) and times ({t.dtype}) must be real numbers")
    nonfinite = ~np.isfinite(q)
    if nonfinite.any():
        i, j = np.argwhere(nonfinite)[0]
        return bad(f"via-point {i}: {limits.joint_names[j]} is {q[i, j]}, not a finite angle")
    if not np.isfinite(t).all():
        i = int(np.argmax(~np.isfinite(t)))
        return bad(f"via-point {i}: time is {t[i]}, not a finite time")
    if t[0] != 0.0:
        return bad(f"via-point 0 (the measured start) is at t = {t[0]} s, expected 0 s")
    dt = np.diff(t)
    if (dt <= 0).any():
        k = int(np.argmax(dt <= 0))
        return bad(
            f"via-point {k + 1} at t = {t[k + 1]:.6g} s is not after via-point {k} at "
            f"t = {t[k]:.6g} s: times must increase strictly"
        )
    return None


def check_positions(q, limits: ArmLimits) -> Refusal | None:
    """JOINT_LIMITS unless every via-point (M,7) [rad] lies within the joint limits."""
    q = np.asarray(q, dtype=float)
    below = limits.lower - POSITION_TOL - q  # > 0: past the lower limit [rad]
    above = q - limits.upper - POSITION_TOL
    excess = np.maximum(below, above)
    bad = np.nonzero((excess > 0).any(axis=1))[0]
    if not bad.size:
        return None
    i = int(bad[0])
    j = int(np.argmax(excess[i]))
    side, limit = ("lower", limits.lower[j]) if below[i, j] > 0 else ("upper", limits.upper[j])
    return Refusal(
        SafetyCode.JOINT_LIMITS,
        "joint_limits",
        f"via-point {i}: {limits.joint_names[j]} at {q[i, j]:.4f} rad is past its {side} limit "
        f"{limit:.4f} rad by {excess[i, j]:.4f} rad ({bad.size} of {len(q)} via-points outside "
        "the joint limits)",
    )


def segment_velocities(q, t) -> np.ndarray:
    """(M-1,7) mean joint velocity [rad/s] of every segment between via-points q (M,7) [rad]
    at times t (M,) [s]."""
    q, t = np.asarray(q, dtype=float), np.asarray(t, dtype=float)
    return np.diff(q, axis=0) / np.diff(t)[:, None]


def via_point_accelerations(q, t) -> np.ndarray:
    """(M,7) joint acceleration [rad/s²] at every via-point: the change of the segment
    velocities over the mean of the two segments' durations, at rest before the first and
    after the last via-point (see the module doc)."""
    t = np.asarray(t, dtype=float)
    v = segment_velocities(q, t)
    zero = np.zeros((1, v.shape[1]))
    v = np.vstack([zero, v, zero])
    dt = np.r_[0.0, np.diff(t), 0.0]
    return np.diff(v, axis=0) / ((dt[:-1] + dt[1:]) / 2)[:, None]


def _rate_refusal(
    values: np.ndarray,
    limit: np.ndarray,
    limits: ArmLimits,
    code: SafetyCode,
    check: str,
    what: str,
    unit: str,
    where,
) -> Refusal | None:
    """The refusal for the first row of values (K,7) over limit (7,) with relative slack, naming
    the worst joint there; ``where(k)`` describes row k."""
    ratio = np.abs(values) / limit
    bad = np.nonzero((ratio > 1.0 + RATE_REL_TOL).any(axis=1))[0]
    if not bad.size:
        return None
    k = int(bad[0])
    j = int(np.argmax(ratio[k]))
    return Refusal(
        code,
        check,
        f"{where(k)}: {limits.joint_names[j]} {what} {abs(values[k, j]):.4g} {unit} exceeds its "
        f"limit {limit[j]:.4g} {unit} ({ratio[k, j]:.3f}x; {bad.size} of {len(values)} over, "
        f"worst {ratio.max():.3f}x)",
    )


def check_velocities(q, t, limits: ArmLimits) -> Refusal | None:
    """JOINT_VELOCITY_LIMIT unless every segment's |Δq/Δt| is within the velocity limits
    (shape-checked q, t)."""
    return _rate_refusal(
        segment_velocities(q, t),
        limits.max_velocity,
        limits,
        SafetyCode.JOINT_VELOCITY_LIMIT,
        "joint_velocity",
        "velocity",
        "rad/s",
        lambda k: f"segment via-point {k} → {k + 1}",
    )


def check_accelerations(q, t, limits: ArmLimits) -> Refusal | None:
    """JOINT_ACCELERATION_LIMIT unless the acceleration at every via-point
    (``via_point_accelerations``) is within the acceleration limits (shape-checked q, t)."""
    return _rate_refusal(
        via_point_accelerations(q, t),
        limits.max_acceleration,
        limits,
        SafetyCode.JOINT_ACCELERATION_LIMIT,
        "joint_acceleration",
        "acceleration",
        "rad/s²",
        lambda k: f"via-point {k}",
    )


def workspace_points(q) -> np.ndarray:
    """(M,4,3) points [m] the workspace check tests at via-points q (M,7): the hand frame
    origin and the arm's joint centres, in ``WORKSPACE_POINTS`` order."""
    q = np.asarray(q, dtype=float)
    hand = wam.fk(q)[..., :3, 3]
    return np.concatenate([hand[:, None, :], wam.arm_points(q)], axis=1)


def check_workspace(q, limits: ArmLimits) -> Refusal | None:
    """WORKSPACE unless the hand frame origin and the joint centres of every via-point (M,7)
    lie inside the workspace box."""
    p = workspace_points(q)
    below = limits.workspace_min - POSITION_TOL - p  # (M,4,3) > 0: outside [m]
    above = p - limits.workspace_max - POSITION_TOL
    excess = np.maximum(below, above)
    bad = np.nonzero((excess > 0).any(axis=(1, 2)))[0]
    if not bad.size:
        return None
    i = int(bad[0])
    k, a = np.unravel_index(int(np.argmax(excess[i])), excess[i].shape)
    axis = _AXES[a]
    if below[i, k, a] > 0:
        bound = f"below the box's min {axis} = {limits.workspace_min[a]:.3f} m"
    else:
        bound = f"above the box's max {axis} = {limits.workspace_max[a]:.3f} m"
    x, y, z = p[i, k]
    return Refusal(
        SafetyCode.WORKSPACE,
        "workspace",
        f"via-point {i}: the {WORKSPACE_POINTS[k]} at ({x:.3f}, {y:.3f}, {z:.3f}) m is "
        f"{excess[i, k, a]:.3f} m {bound} ({bad.size} of {len(p)} via-points outside the "
        "workspace box)",
    )


def check_trajectory(q, t, limits: ArmLimits) -> Refusal | None:
    """The first failed check of via-points q (M,7) [rad] at times t (M,) [s] (q[0]: the arm's
    measured configuration at t[0] = 0; at rest at both ends), in the module doc's order, or
    None when the trajectory may be sent."""
    refusal = check_shape(q, t, limits)
    if refusal is not None:
        return refusal
    q, t = np.asarray(q, dtype=float), np.asarray(t, dtype=float)
    return (
        check_positions(q, limits)
        or check_velocities(q, t, limits)
        or check_accelerations(q, t, limits)
        or check_workspace(q, limits)
    )


#: A recovery move (a measured joint outside its limits, moved back toward them) runs at most
#: at this fraction of the velocity limits (chosen: 10 %, a crawl an operator can watch) ...
RECOVERY_SPEED_FRACTION = 0.1
#: ... and every joint inside its limits stays within this of where it is [rad] (chosen).
RECOVERY_STILL_TOL = 1e-3


def limit_excess(q, limits: ArmLimits) -> np.ndarray:
    """(...,7) how far each joint of q [rad] is past its nearer limit (0 inside) [rad]."""
    q = np.asarray(q, dtype=float)
    return np.maximum(np.maximum(limits.lower - q, q - limits.upper), 0.0)


def check_recovery(q, t, limits: ArmLimits) -> Refusal | None:
    """None when via-points q (M,7) [rad] at times t (M,) [s], from a measured q[0] with joints
    outside their limits, only bring those joints back toward their limits, slowly: each one
    never farther outside than at the via-point before, no joint faster than
    RECOVERY_SPEED_FRACTION of its velocity limit, every other joint still
    (RECOVERY_STILL_TOL), the accelerations and the workspace box kept; otherwise the
    JOINT_LIMITS refusal that says why. The move may end inside the limits."""
    refusal = check_shape(q, t, limits)
    if refusal is not None:
        return refusal
    q, t = np.asarray(q, dtype=float), np.asarray(t, dtype=float)
    excess = limit_excess(q, limits)
    outside = excess[0] > POSITION_TOL
    names = lambda mask: ", ".join(n for n, m in zip(limits.joint_names, mask) if m)
    refuse = lambda msg: Refusal(SafetyCode.JOINT_LIMITS, "joint_limits", f"recovery: {msg}")
    if not outside.any():
        return refuse("no measured joint is outside its limits")
    moved = np.abs(q - q[0]).max(axis=0) > RECOVERY_STILL_TOL
    if (moved & ~outside).any():
        return refuse(f"only {names(outside)} may move, not {names(moved & ~outside)}")
    farther = np.diff(excess[:, outside], axis=0) > POSITION_TOL
    if farther.any():
        k = int(np.nonzero(farther.any(axis=1))[0][0]) + 1
        return refuse(f"via-point {k} takes {names(outside)} farther outside its limits")
    speed = np.abs(segment_velocities(q, t)) / (RECOVERY_SPEED_FRACTION * limits.max_velocity)
    if speed.max() > 1.0 + RATE_REL_TOL:
        k, j = np.unravel_index(int(np.argmax(speed)), speed.shape)
        share, cap = 100 * RECOVERY_SPEED_FRACTION * speed[k, j], 100 * RECOVERY_SPEED_FRACTION
        return refuse(
            f"segment {k}: {limits.joint_names[j]} at {share:.0f} % of its velocity limit, over "
            f"the {cap:.0f} % a recovery may use"
        )
    return check_accelerations(q, t, limits) or check_workspace(q, limits)


def scale_time(t, speed_scale: float) -> np.ndarray:
    """Via-point times t [s] stretched by the speed-scaling cap speed_scale in (0, 1]: t /
    speed_scale (velocities scale by speed_scale, accelerations by its square)."""
    if isinstance(speed_scale, bool) or not (
        isinstance(speed_scale, (int, float, np.integer, np.floating)) and 0.0 < speed_scale <= 1.0
    ):
        raise ValueError(f"speed_scale must be in (0, 1], got {speed_scale!r}")
    return np.asarray(t, dtype=float) / float(speed_scale)


def slowdown_to_limits(q, t, limits: ArmLimits) -> float:
    """The smallest uniform time stretch k ≥ 1 after which via-points q (M,7) [rad] at times
    t (M,) [s] keep the velocity and acceleration limits (velocities scale by 1/k,
    accelerations by 1/k²)."""
    v = np.abs(segment_velocities(q, t)) / np.asarray(limits.max_velocity)
    a = np.abs(via_point_accelerations(q, t)) / np.asarray(limits.max_acceleration)
    return float(max(1.0, v.max(initial=0.0), np.sqrt(a.max(initial=0.0))))


# ------------------------------------------------------------------ force ceiling
class ForceCeiling:
    """Fingertip wrench ceiling: a fingertip force magnitude above force_limit_n [N] or torque
    magnitude above torque_limit_nm [N m] stops any move."""

    def __init__(self, force_limit_n: float, torque_limit_nm: float):
        for name, value in (("force_limit_n", force_limit_n), ("torque_limit_nm", torque_limit_nm)):
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite number, got {value!r}")
        self.force_limit_n = float(force_limit_n)
        self.torque_limit_nm = float(torque_limit_nm)
        self._square_limits = np.array([self.force_limit_n, self.torque_limit_nm]) ** 2

    def over(self, wrenches) -> np.ndarray:
        """(fingers,) bool: which fingertips' wrenches (fingers,6) exceed the ceiling (a
        non-finite reading counts as over)."""
        w = np.asarray(wrenches, dtype=float)
        # squared magnitudes: this runs on every Net F/T record, and norms cost 4x as much
        square = (w * w).reshape(len(w), 2, 3).sum(axis=2)  # (fingers, 2): |force|², |torque|²
        return ~(square <= self._square_limits).all(axis=1)  # NaN compares False: over

    def check(self, wrenches) -> Refusal | None:
        """Fingertip wrenches (3,6) (Fx, Fy, Fz [N], Tx, Ty, Tz [N m], fingers 1-3) → FORCE_LIMIT
        naming the fingertip most over its ceiling, SENSOR_FAULT for a non-finite reading, or
        None."""
        w = np.asarray(wrenches, dtype=float)
        if w.ndim != 2 or w.shape[1] != 6:
            raise ValueError(f"wrenches must be (fingers, 6), got shape {w.shape}")
        if not self.over(w).any():  # the common case, cheaply: every fingertip within
            return None
        nonfinite = ~np.isfinite(w).all(axis=1)
        if nonfinite.any():
            f = int(np.argmax(nonfinite))
            return Refusal(
                SafetyCode.SENSOR_FAULT,
                "force_ceiling",
                f"fingertip {f + 1}: non-finite wrench reading {w[f].tolist()}",
            )
        force = np.linalg.norm(w[:, :3], axis=1)
        torque = np.linalg.norm(w[:, 3:], axis=1)
        ratio = np.stack([force / self.force_limit_n, torque / self.torque_limit_nm], axis=1)
        f, kind = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
        if ratio[f, kind] <= 1.0:
            return None
        what, value, limit, unit = (
            ("force", force[f], self.force_limit_n, "N")
            if kind == 0
            else ("torque", torque[f], self.torque_limit_nm, "N m")
        )
        return Refusal(
            SafetyCode.FORCE_LIMIT,
            "force_ceiling",
            f"fingertip {f + 1}: {what} {value:.3g} {unit} exceeds the ceiling {limit:.3g} {unit}",
        )


# ------------------------------------------------------------------ watchdog
class Watchdog:
    """Stale-data watchdog over named streams: a stream whose newest sample is older than
    timeout_s [s], or that was never fed, is stale. Thread-safe."""

    def __init__(self, timeout_s: float, streams: Iterable[str]):
        if not (np.isfinite(timeout_s) and timeout_s > 0):
            raise ValueError(f"timeout_s must be a positive finite number, got {timeout_s!r}")
        self.timeout_s = float(timeout_s)
        self.streams = tuple(streams)
        if not self.streams or len(set(self.streams)) != len(self.streams):
            raise ValueError(f"streams must be distinct names, got {self.streams!r}")
        self._last = dict.fromkeys(self.streams, -np.inf)
        self._lock = threading.Lock()

    def feed(self, stream: str, now_s: float) -> None:
        """A sample of ``stream`` arrived at now_s [s] (a monotonic clock)."""
        with self._lock:
            if stream not in self._last:
                raise KeyError(f"unknown stream {stream!r}; watched: {', '.join(self.streams)}")
            self._last[stream] = max(self._last[stream], float(now_s))

    def newest(self, stream: str) -> float:
        """Monotonic time [s] of ``stream``'s newest sample (-inf when never fed)."""
        with self._lock:
            return self._last[stream]

    def age(self, stream: str, now_s: float) -> float:
        """Seconds since ``stream``'s newest sample (inf when never fed)."""
        with self._lock:
            return float(now_s) - self._last[stream]

    def stale(self, now_s: float) -> list[str]:
        """The streams, in the order given, whose newest sample is older than timeout_s at
        now_s [s], or that were never fed."""
        with self._lock:
            return [s for s in self.streams if now_s - self._last[s] > self.timeout_s]


# ------------------------------------------------------------------ E-stop
class EStop:
    """Fail-safe latched E-stop. Thread-safe.

    It starts latched ("not armed"): only ``reset`` arms it. An engaged message latches it; it
    stays latched, whatever later messages say, until ``reset``, which is refused while the
    last message said engaged, or while the heartbeat is silent. With ``heartbeat_timeout_s``
    > 0 the E-stop topic is a deadman: no message for that long latches it. With
    ``latch_file``, a latch by a message or the heartbeat is written there and survives a
    restart (a new EStop over that file starts latched for that reason, and only ``reset``
    removes the file). ``run_if_released`` runs a command under the latch's lock, so an
    engaged message either comes before it (the command is not run) or after it (the command
    went out first and is stopped by the caller).
    """

    NOT_ARMED = "not armed: reset the E-stop to arm the bridge"
    #: A latch's reason starts so when the bridge latched it for a robot fault.
    ROBOT_FAULT = "robot fault: "

    def __init__(
        self,
        heartbeat_timeout_s: float = 0.0,
        latch_file: str | Path | None = None,
        now_s: float = 0.0,
    ) -> None:
        if not (np.isfinite(heartbeat_timeout_s) and heartbeat_timeout_s >= 0.0):
            raise ValueError(f"heartbeat_timeout_s must be >= 0, got {heartbeat_timeout_s!r}")
        self.heartbeat_timeout_s = float(heartbeat_timeout_s)
        self.latch_file = Path(latch_file).expanduser() if latch_file else None
        self._lock = threading.Lock()
        self._engaged = True
        self._reason = self.NOT_ARMED
        self._message_engaged = False
        self._last_message_s = float(now_s)  # the heartbeat's grace starts at construction
        self._listening_s = float(now_s)  # since when the bridge has run without a stall
        self.latched_s = -np.inf  # monotonic time of the newest latch by a message or silence
        if self.latch_file is not None and self.latch_file.exists():
            text = self.latch_file.read_text(encoding="utf-8", errors="replace").strip()
            text = text or "no reason recorded"
            self._reason = f"latched before this start ({text}): {self.NOT_ARMED}"

    # ------------------------------------------------------------------ inputs
    def on_message(self, engaged: bool, now_s: float = 0.0) -> bool:
        """An E-stop topic message (True: engaged) at now_s [s, monotonic]; True when this
        message latched a released E-stop."""
        with self._lock:
            self._message_engaged = bool(engaged)
            self._last_message_s = max(self._last_message_s, float(now_s))
            if engaged:
                return self._latch("the E-stop topic said engaged", now_s)
            return False

    def resumed(self, now_s: float) -> None:
        """The bridge itself did not run until now_s [s] (a stalled process or host): the
        heartbeat's silence counts from here, so a publisher that stalled with it has a whole
        timeout to be heard again."""
        with self._lock:
            self._listening_s = max(self._listening_s, float(now_s))

    def check_heartbeat(self, now_s: float) -> bool:
        """Latch when the topic has been silent longer than the heartbeat timeout while the
        bridge listened; True when this call latched it."""
        if self.heartbeat_timeout_s <= 0.0:
            return False
        with self._lock:
            silent = now_s - max(self._last_message_s, self._listening_s)
            if silent > self.heartbeat_timeout_s:
                return self._latch(f"no E-stop heartbeat for {silent:.2f} s", now_s)
            return False

    def latch_fault(self, what: str, now_s: float) -> bool:
        """Latch for a robot fault (``what`` for people; e.g. a controller that ignored a
        cancel); only ``reset`` clears it. True when this call latched it."""
        with self._lock:
            was = self._engaged
            self._engaged = False  # the fault's reason replaces any other
            self._latch(self.ROBOT_FAULT + what, now_s)
            return not was

    def _latch(self, reason: str, now_s: float) -> bool:
        was = self._engaged
        self._engaged, self.latched_s = True, float(now_s)
        if not was or self._reason == self.NOT_ARMED or self._reason.startswith("latched before"):
            self._reason = reason
        if self.latch_file is not None:
            try:
                self.latch_file.parent.mkdir(parents=True, exist_ok=True)
                self.latch_file.write_text(f"{reason}, {time.strftime('%Y-%m-%d %H:%M:%S')}\n")
            except OSError:
                pass  # the latch itself holds; the file only carries it over a restart
        return not was

    # ------------------------------------------------------------------ state
    @property
    def engaged(self) -> bool:
        """True while latched (also before the first reset: not armed)."""
        with self._lock:
            return self._engaged

    @property
    def reason(self) -> str:
        """Why it is latched ("" when armed)."""
        with self._lock:
            return self._reason if self._engaged else ""

    def run_if_released(self, command: Callable[[], T]) -> tuple[bool, T | None]:
        """(True, command()) when the E-stop is released, run under its lock so that no
        message latches it meanwhile; (False, None) when it is latched."""
        with self._lock:
            if self._engaged:
                return False, None
            return True, command()

    def reset(self, now_s: float = 0.0) -> tuple[bool, str]:
        """Release the latch (arm) → (done, message for people)."""
        with self._lock:
            if self._message_engaged:
                return False, "the E-stop topic still says engaged: release the E-stop first"
            silent = now_s - self._last_message_s
            if self.heartbeat_timeout_s > 0.0 and silent > self.heartbeat_timeout_s:
                return False, (
                    f"no E-stop heartbeat for {silent:.2f} s: start the E-stop's publisher first"
                )
            if not self._engaged:
                return True, "the E-stop was not engaged"
            self._engaged, self._reason = False, ""
            if self.latch_file is not None:
                try:
                    self.latch_file.unlink(missing_ok=True)
                except OSError as exc:
                    return True, f"armed, but the latch file stays: {exc}"
            return True, "E-stop released: commands are accepted again"
