"""The BarrettHand's sensing logic, shared by the MuJoCo world and the hardware bridge: which
sensors fire (config.SENSING thresholds), where a Nano17 fingertip contact lies (from its
wrench), and when each finger of a closing hand stops (stall, or its own contact).

Plain numpy on readings: the simulator feeds it MuJoCo's sensors, the bridge the real Net F/T
boxes, pads and joint states, so both decide the same way.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rrg_models.config import HAND, N_SENSORS, PHYSICS, SENSING
from rrg_models.hand import body_poses, hand_tree
from rrg_models.observation import finger_contacts


@dataclass(frozen=True)
class Reading:
    """What the hand senses at one instant.

    fired: (10,) bool, config.SENSOR_NAMES order. tip_points / tip_normals: (3,3) Nano17
    contact points [m] and unit normals (object → tip) in the hand frame, NaN rows for tips
    below threshold.
    """

    fired: np.ndarray
    tip_points: np.ndarray
    tip_normals: np.ndarray


#: The fingers take this long to get going [s]: no stall is declared earlier, and an opening
#: hand gets this long to settle (chosen: ~ 2× the time to reach closing speed).
CLOSE_START_TIME = 0.05

#: (10,) firing thresholds: pad force [N] for the 7 pads, fingertip force magnitude [N] for
#: the 3 Nano17s (config.SENSING).
SENSOR_THRESHOLDS = np.r_[
    np.full(7, SENSING.pad_force_threshold), np.full(3, SENSING.tip_force_threshold)
]


def _tip_capsule() -> tuple[float, float, float]:
    """Fingertip capsule in its body (= Nano17 site) frame: radius, axis z from, axis z to [m]."""
    tip = next(b for b in hand_tree() if b.name == "f1_tip").geoms[0]
    r, half = tip.size
    return r, tip.pos[2] - half, tip.pos[2] + half


TIP_RADIUS, TIP_Z0, TIP_Z1 = _tip_capsule()


def capsule_entry(point: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where the line point + t·direction (unit) first enters the fingertip capsule (smallest t),
    and the inward surface normal there; the closest surface point when the line misses."""
    r, z0, z1 = TIP_RADIUS, TIP_Z0, TIP_Z1
    hits = []
    # Cylinder wall: |(p + t u)_xy| = r with z0 ≤ z ≤ z1.
    a = direction[0] ** 2 + direction[1] ** 2
    b = 2 * (point[0] * direction[0] + point[1] * direction[1])
    c = point[0] ** 2 + point[1] ** 2 - r * r
    if a > 1e-12 and b * b - 4 * a * c >= 0:
        t = (-b - np.sqrt(b * b - 4 * a * c)) / (2 * a)
        if z0 <= point[2] + t * direction[2] <= z1:
            hits.append(t)
    # End spheres.
    for zc in (z0, z1):
        m = point - np.array([0.0, 0.0, zc])
        bb = m @ direction
        disc = bb * bb - (m @ m - r * r)
        if disc >= 0:
            t = -bb - np.sqrt(disc)
            z = point[2] + t * direction[2]
            if (zc == z1 and z >= z1) or (zc == z0 and z <= z0):
                hits.append(t)
    # The entry point; if the line misses (noise), its point nearest the capsule's axis.
    t = min(hits) if hits else (-(point[:2] @ direction[:2]) / a if a > 1e-12 else 0.0)
    p = point + t * direction
    centre = np.array([0.0, 0.0, np.clip(p[2], z0, z1)])
    radial = p - centre
    norm = np.linalg.norm(radial)
    n = radial / norm if norm > 1e-9 else -direction
    return centre + r * n, -n


def contact_from_wrench(force: np.ndarray, torque: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Contact point and inward normal on a fingertip (site frame) from the force F [N] and
    torque τ [N m] the object applies to it, about the site origin (τ = p × F)."""
    f2 = force @ force
    u = force / np.sqrt(f2)
    return capsule_entry(np.cross(force, torque) / f2, u)


def fired_sensors(
    pads: np.ndarray, tip_wrench: np.ndarray, thresholds: np.ndarray = SENSOR_THRESHOLDS
) -> np.ndarray:
    """(10,) bool: pads (7,) [N] and Nano17 loads (3,6) [N, N m] over their thresholds (10,)."""
    force = np.linalg.norm(np.asarray(tip_wrench)[:, :3], axis=1)
    return np.concatenate([np.asarray(pads, dtype=float), force]) > thresholds


def tip_contacts(
    tip_wrench: np.ndarray, fired: np.ndarray, tip_poses: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Contact points and inward normals (3,3) in the hand frame of the fired fingertips (NaN
    rows elsewhere), from the loads (3,6) in each sensor's frame and the sensor frames' poses
    (3,4,4) in the hand frame."""
    points, normals = np.full((3, 3), np.nan), np.full((3, 3), np.nan)
    for i in np.nonzero(np.asarray(fired)[7:])[0]:
        p, n = contact_from_wrench(tip_wrench[i, :3], tip_wrench[i, 3:])
        R, o = tip_poses[i, :3, :3], tip_poses[i, :3, 3]
        points[i], normals[i] = R @ p + o, R @ n
    return points, normals


def hand_tip_poses(spread: float, proximal: np.ndarray) -> np.ndarray:
    """(3,4,4) Nano17 sensor frames (the fingertip bodies) in the hand frame, from the spread
    and proximal joint angles [rad] (distal coupled, rrg_models.hand)."""
    poses = body_poses(spread, np.asarray(proximal, dtype=float))
    return np.stack([poses[f"f{i}_tip"] for i in (1, 2, 3)])


def reading_from_joints(
    pads: np.ndarray, tip_wrench: np.ndarray, spread: float, proximal: np.ndarray
) -> Reading:
    """The hand's reading (fired sensors, fingertip contacts in the hand frame) from pad forces
    (7,) [N], Nano17 loads (3,6) and the measured hand joint angles [rad]."""
    fired = fired_sensors(pads, tip_wrench)
    points, normals = tip_contacts(tip_wrench, fired, hand_tip_poses(spread, proximal))
    return Reading(fired, points, normals)


class FingerClosing:
    """Which fingers of a closing hand have stopped: a finger stops when it stalls (closing
    slower than PHYSICS.stall_speed for PHYSICS.stall_time after CLOSE_START_TIME: at its torque
    limit on the object, pushed back, or at its joint limit); in a careful (``guarded``) closing
    also in the update any of its own sensors fires. Fed every control period (simulator) or
    every joint-state message (bridge)."""

    def __init__(self, guarded: bool):
        self.guarded = guarded
        self.stopped = np.zeros(3, bool)
        self.touched = np.zeros(N_SENSORS, bool)  # sensors fired at any time while closing
        self._still = np.zeros(3)  # [s] how long each finger has been slow
        self.elapsed = 0.0  # [s] since the closing started

    @property
    def speed(self) -> float:
        """Proximal closing speed [rad/s]."""
        return HAND.careful_close_speed if self.guarded else HAND.close_speed

    @property
    def timeout(self) -> float:
        """Longest closing [s] (PHYSICS.close_timeout at the full closing speed)."""
        return PHYSICS.close_timeout * HAND.close_speed / self.speed

    @property
    def done(self) -> bool:
        return bool(self.stopped.all())

    def update(
        self,
        dt: float,
        finger_speed: np.ndarray,
        fired: np.ndarray | None = None,
    ) -> np.ndarray:
        """Advance by dt [s] with the proximal speeds (3,) [rad/s] and the sensors (10,) fired
        now (None: none can fire); returns the fingers that stop now."""
        started = self.elapsed >= CLOSE_START_TIME - 1e-9
        self.elapsed += dt
        self._still = np.where(np.asarray(finger_speed) < PHYSICS.stall_speed, self._still + dt, 0)
        stop = np.zeros(3, bool)
        if fired is not None:
            self.touched |= fired
            if self.guarded:
                stop |= finger_contacts(fired)
        if started:
            stop |= self._still >= PHYSICS.stall_time
        new = stop & ~self.stopped
        self.stopped |= new
        return new


class StopConfirmation:
    """Whether a guarded move's trip is a contact: confirmed before the move stops, as real
    guarded-move code debounces a binary sensor. Fed every control period (simulator) or every
    sensor message (bridge).

    * A Nano17 over its threshold, or the arm's collision detection, stops the move at once:
      each is a force far above its own noise (ATI's resolution is under 1 % of the 0.5 N
      threshold; the joint-torque noise σ is a sixth of its threshold).
    * A touch pad alone is a binary sample that can fire falsely. It stops the move only when
      the next pad sample also has a pad over its threshold (any pad: a contact may roll onto
      the next one), or a Nano17 or the collision detection agrees first. A pad that fires in
      one sample only is a rejected trip, and the move goes on: at 50 Hz pads and 0.2 m/s,
      a real contact stops one sample later, 4 mm further on.
    """

    def __init__(self, confirm: bool = True):
        self.confirm = confirm  # False: every trip stops at once (the unconfirmed guard)
        self._pending: int | None = None  # the pad sample a lone pad fired in
        self.rejected = 0  # lone pad trips that the next sample did not confirm

    def update(self, fired: np.ndarray | None, collision: bool, pad_sample: int) -> bool:
        """Whether the move must stop now, given the sensors (10,) over their thresholds now
        (None: none), the collision detection's verdict and the index of the pad sample
        they are read from (it changes when a fresh pad sample arrives)."""
        pads = fired is not None and bool(np.asarray(fired)[:7].any())
        tips = fired is not None and bool(np.asarray(fired)[7:].any())
        if collision or tips or (pads and not self.confirm):
            return True
        if pads:
            if self._pending is None:
                self._pending = pad_sample
                return False
            return pad_sample != self._pending
        if self._pending is not None and pad_sample != self._pending:
            self._pending, self.rejected = None, self.rejected + 1
        return False
