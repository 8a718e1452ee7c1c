"""The bridge's view of the hand and the guarded-move trip logic, without ROS.

``HandState`` keeps the newest reading of every sensor the drivers stream (Nano17 loads, pad
forces, measured joint angles, arm joint efforts), tared for a guarded move as the simulator
tares its sensors, and turns it into the ``Reading`` the executor gets (rrg_models.hand_sensing:
the same thresholds and contact localisation as the simulator). ``ContactGuard`` decides, on
every new sample, whether a guarded move must stop: a Nano17 over its threshold, a pad over
its threshold in two pad samples running (rrg_models.hand_sensing.StopConfirmation, the
simulator's rule), or an arm joint's effort changed by more than the collision threshold
since the move started.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field, replace

import numpy as np

from rrg_models.config import N_SENSORS, SENSING, TIP_SENSORS
from rrg_models.hand_sensing import Reading, StopConfirmation, fired_sensors, reading_from_joints

from .tactile import TACTILE_PADS_UNSENSED

#: Pads a BarrettHand without pad feedback cannot sense; with derived pads the distal pads
#: take the fingertip Nano17s' force magnitude (the sensor sits in the distal link's tip).
DERIVED_PADS_UNSENSED = ("palm", "prox1", "prox2", "prox3")
#: Where the bridge's pad forces come from (its parameter pad_source), and the pads each source
#: has no reading of: Barrett's tactile pucks cover the fingertips and the palm
#: (tactile.TACTILE_PADS_UNSENSED); a ContactPads topic is taken to carry all seven.
UNSENSED_PADS = {
    "tactile": TACTILE_PADS_UNSENSED,
    "topic": (),
    "derived": DERIVED_PADS_UNSENSED,
}
PAD_SOURCES = tuple(UNSENSED_PADS)
DEFAULT_PAD_SOURCE = "tactile"


def derived_pads(tip_wrench: np.ndarray) -> np.ndarray:
    """(7,) pad forces [N] derived from the fingertip loads (3,6): the distal pads read their
    fingertip's force magnitude, the palm and proximal pads nothing."""
    pads = np.zeros(7)
    pads[4:7] = np.linalg.norm(np.asarray(tip_wrench)[:, :3], axis=1)
    return pads


def path_index(q_via: np.ndarray, q: np.ndarray) -> float:
    """Fractional via-point index (0 … M-1) of the point of the joint-space polyline q_via
    (M,7) [rad] nearest to the configuration q (7,)."""
    a, b = q_via[:-1], q_via[1:]
    d = b - a
    length2 = np.einsum("ij,ij->i", d, d)
    s = np.clip(np.einsum("ij,ij->i", q - a, d) / np.where(length2 > 0, length2, 1.0), 0.0, 1.0)
    dist = np.linalg.norm(a + s[:, None] * d - q, axis=1)
    k = int(np.argmin(dist)) if len(dist) else 0
    return float(k + s[k]) if len(dist) else 0.0


@dataclass
class StopSensing:
    """What a guarded move's contact fired from the move's stop until the arm was at rest:
    the sensors (10,) bool, and each fingertip's tared load (3,6) at its largest force then.
    The simulator's arm halts in the period it trips and reads its sensors there; a real arm
    decelerates after the cancel, and a contact it makes meanwhile belongs to the stop."""

    fired: np.ndarray = field(default_factory=lambda: np.zeros(N_SENSORS, dtype=bool))
    tips: np.ndarray = field(default_factory=lambda: np.zeros((3, 6)))

    def add(self, fired: np.ndarray, tips: np.ndarray) -> None:
        """One sample: the sensors over the guard's thresholds (10,) and the tared loads."""
        self.fired |= fired
        stronger = np.linalg.norm(tips[:, :3], axis=1) > np.linalg.norm(self.tips[:, :3], axis=1)
        self.tips[stronger] = tips[stronger]

    def copy(self) -> StopSensing:
        return StopSensing(self.fired.copy(), self.tips.copy())


@dataclass
class Trip:
    """Why a guarded move stops: the sensors over threshold (10,) bool, or a joint effort."""

    sensors: np.ndarray
    effort_joint: int | None = None
    effort_change_nm: float = 0.0

    def describe(self, names: tuple[str, ...]) -> str:
        if self.effort_joint is not None:
            return (
                f"joint {self.effort_joint + 1} effort changed by {self.effort_change_nm:.2f} N m"
            )
        return "contact on " + ", ".join(n for n, f in zip(names, self.sensors) if f)


class HandState:
    """Newest sensor readings from the drivers (thread-safe), tared for guarded moves."""

    def __init__(self, derive_pads: bool):
        self.derive_pads = derive_pads
        self._lock = threading.Lock()
        self._tips = np.zeros((3, 6))  # loads on the fingertips [N, N m], sensor frames
        self._tare = np.zeros((3, 6))
        self._pads = np.zeros(7)
        self.spread = 0.0
        self.proximal = np.zeros(3)

    def set_tip(self, finger: int, wrench: np.ndarray) -> np.ndarray:
        """Store fingertip ``finger``'s load (6,); returns all three tared loads (3,6)."""
        with self._lock:
            self._tips[finger] = wrench
            return self._tips - self._tare

    def set_pads(self, forces: np.ndarray) -> None:
        with self._lock:
            self._pads = np.asarray(forces, dtype=float).reshape(7)

    def set_hand_joints(self, spread: float, proximal: np.ndarray) -> None:
        with self._lock:
            self.spread, self.proximal = float(spread), np.asarray(proximal, dtype=float)

    def tare(self) -> None:
        """Bias the fingertip loads at their current values (before a guarded move)."""
        with self._lock:
            self._tare = self._tips.copy()

    def loads(self) -> np.ndarray:
        """(3,6) fingertip loads as the sensors measure them, not tared: what the force
        ceiling limits (a guarded move's tare only shifts where a contact is detected)."""
        with self._lock:
            return self._tips.copy()

    def tips(self, stop: StopSensing | None = None) -> np.ndarray:
        """(3,6) tared fingertip loads; with ``stop``, a fingertip below its threshold now that
        fired while a guarded move stopped reads its strongest load then."""
        with self._lock:
            tips = self._tips - self._tare
        if stop is None:
            return tips
        silent = ~fired_sensors(np.zeros(7), tips)[list(TIP_SENSORS)]
        held = silent & stop.fired[list(TIP_SENSORS)]
        return np.where(held[:, None], stop.tips, tips)

    def pads(self) -> np.ndarray:
        """(7,) pad forces [N] (derived from the fingertips when the hand has no pads)."""
        with self._lock:
            return derived_pads(self._tips - self._tare) if self.derive_pads else self._pads.copy()

    def fired(self) -> np.ndarray:
        """(10,) sensors over their thresholds now."""
        return fired_sensors(self.pads(), self.tips())

    def reading(self, stop: StopSensing | None = None) -> Reading:
        """The executor's reading now: fired sensors and fingertip contacts in the hand frame;
        with ``stop``, also what fired while a guarded move stopped (``tips``)."""
        with self._lock:
            spread, proximal = self.spread, self.proximal.copy()
        reading = reading_from_joints(self.pads(), self.tips(stop), spread, proximal)
        if stop is None:
            return reading
        return replace(reading, fired=reading.fired | stop.fired)


class ContactGuard:
    """Trip logic of one guarded move: sensor thresholds [N] and the arm's effort threshold."""

    def __init__(
        self,
        tip_force_threshold: float = SENSING.tip_force_threshold,
        pad_force_threshold: float = SENSING.pad_force_threshold,
        effort_threshold: float = SENSING.arm_torque_threshold,
        confirm_stops: bool = True,
    ):
        """confirm_stops: a lone pad trips the move only when the next pad sample agrees."""
        self.thresholds = np.r_[np.full(7, pad_force_threshold), np.full(3, tip_force_threshold)]
        self.effort_threshold = effort_threshold  # [N m]; <= 0: efforts are not watched
        self._effort0: np.ndarray | None = None
        #: the largest effort change seen so far [N m] and its joint (0-6): the margin the
        #: arm's free motion leaves under the threshold
        self.peak_effort_change, self.peak_effort_joint = 0.0, 0
        self.confirmation = StopConfirmation(confirm_stops)
        self._pad_sample = 0  # pad samples seen during the move

    def start(self, effort: np.ndarray | None) -> None:
        """Remember the arm's joint efforts (7,) [N m] at the start of the move."""
        self._effort0 = None if effort is None else np.asarray(effort, dtype=float).copy()

    def check_sensors(
        self, pads: np.ndarray, tips: np.ndarray, new_pad_sample: bool = False
    ) -> Trip | None:
        """A trip when a fingertip load (3,6) is over its threshold, or a pad (7,) is over its
        threshold in this pad sample and the one before (``new_pad_sample``: the pads were
        just read afresh; a lone pad that the next sample does not confirm is not a trip)."""
        self._pad_sample += bool(new_pad_sample)
        fired = self.fired(pads, tips)
        stop = self.confirmation.update(fired if fired.any() else None, False, self._pad_sample)
        return Trip(fired) if stop else None

    def fired(self, pads: np.ndarray, tips: np.ndarray) -> np.ndarray:
        """(10,) bool: the pads (7,) [N] and fingertip loads (3,6) over this move's thresholds."""
        return fired_sensors(pads, tips, self.thresholds)

    def check_effort(self, effort: np.ndarray) -> Trip | None:
        """A trip when a joint's effort (7,) changed by more than the threshold."""
        if self._effort0 is None or self.effort_threshold <= 0 or len(effort) != 7:
            return None
        change = np.abs(np.asarray(effort) - self._effort0)
        j = int(np.argmax(change))
        if change[j] > self.peak_effort_change:
            self.peak_effort_change, self.peak_effort_joint = float(change[j]), j
        if change[j] > self.effort_threshold:
            return Trip(np.zeros(10, bool), j, float(change[j]))
        return None


class VelocityEstimate:
    """Joint velocities [rad/s] from positions alone, for drivers whose joint states carry none
    (Barrett's wam_node): finite differences, low-passed with time constant ``tau_s``."""

    def __init__(self, n: int, tau_s: float = 0.01):
        self.tau_s = tau_s
        self.velocity = np.zeros(n)
        self._q: np.ndarray | None = None
        self._t = 0.0

    def update(self, q: np.ndarray, t_s: float) -> np.ndarray:
        """The estimate after positions q (n,) [rad] measured at time t_s [s]."""
        q = np.asarray(q, dtype=float)
        if self._q is not None and t_s > self._t:
            dt = t_s - self._t
            raw = np.nan_to_num((q - self._q) / dt)
            self.velocity += (raw - self.velocity) * (1.0 - np.exp(-dt / self.tau_s))
        self._q, self._t = q.copy(), t_s
        return self.velocity.copy()
