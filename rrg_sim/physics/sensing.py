"""The hand's sensors in MuJoCo: 7 binary touch pads and 3 Nano17 fingertip force/torque sensors.

Readings carry seeded Gaussian noise (σ from ``config.SENSING`` / ``config.PHYSICS``, or the
world profile's, times a ``noise`` scale, 0 = noiseless). A world profile (config.WorldProfile)
may also sample the pads slower than the control period (each sample held until the next),
leave a touched pad silent for a whole guarded move (a miss), and fire a pad for one sample
when nothing touches it (a false alarm). The Nano17s are tared (biased) before every motion,
as a real F/T sensor is, which removes the fingertip's own weight. A contact point on a
fingertip is recovered from its wrench: the force's line of action (p × F = τ) enters the
fingertip's capsule surface at the contact; the normal there points from the object into the
tip (rrg_models.hand_sensing, which the hardware bridge shares).
"""

from __future__ import annotations

import mujoco
import numpy as np
from numba import njit

from rrg_models.config import N_SENSORS, PHYSICS, SENSING
from rrg_models.description.mjcf_robot import (
    PAD_TOUCH,
    PALM_BODY,
    TIP_BODIES,
    TIP_FORCE,
    TIP_TORQUE,
)
from rrg_models.hand_sensing import Reading, fired_sensors, tip_contacts
from rrg_sim.config import NOMINAL, WorldProfile

#: A noise-free signal this many σ below its threshold cannot fire (P < 1e-9): skip the noise.
QUIET_SIGMAS = 6.0


@njit(cache=True)
def _may_fire(
    sensordata: np.ndarray,
    pads: np.ndarray,
    forces: np.ndarray,
    bias_force: np.ndarray,
    quiet_pad: float,
    quiet_tip2: float,
) -> bool:
    """Whether a noise-free pad force (sensordata[pads], [N]) reaches quiet_pad or a tared tip
    force (sensordata[forces] (3,3) − bias_force, [N]) has a squared norm reaching quiet_tip2
    (NaN counts as reaching): one pass instead of the numpy calls of every control period."""
    for i in pads:
        if not sensordata[i] < quiet_pad:
            return True
    for t in range(forces.shape[0]):
        norm2 = 0.0
        for k in range(forces.shape[1]):
            f = sensordata[forces[t, k]] - bias_force[t, k]
            norm2 += f * f
        if not norm2 < quiet_tip2:
            return True
    return False


@njit(cache=True)
def _any_reaches(values: np.ndarray, index: np.ndarray, limit: float) -> bool:
    """Whether any |values[index]| reaches limit (NaN counts as reaching)."""
    for i in index:  # noqa: SIM110 (a loop numba compiles; any() of a generator it does not)
        if not abs(values[i]) < limit:
            return True
    return False


class HandSensors:
    """Noisy readings of the touch pads and Nano17s of one MuJoCo model/data pair."""

    def __init__(
        self,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        rng: np.random.Generator,
        noise: float = 1.0,
        profile: WorldProfile = NOMINAL,
    ):
        self.model, self.data, self.rng, self.noise = model, data, rng, noise
        adr = lambda name: int(model.sensor_adr[model.sensor(name).id])
        self._pad = np.array([adr(n) for n in PAD_TOUCH])
        self._force = np.array([adr(n) for n in TIP_FORCE])[:, None] + np.arange(3)
        self._torque = np.array([adr(n) for n in TIP_TORQUE])[:, None] + np.arange(3)
        self._tip_body = np.array([model.body(b).id for b in TIP_BODIES])
        self._palm_body = model.body(PALM_BODY).id
        force_sigma = (
            SENSING.nano17_force_noise
            if profile.nano17_force_noise is None
            else profile.nano17_force_noise
        )
        torque_sigma = (
            PHYSICS.nano17_torque_noise
            if profile.nano17_torque_noise is None
            else profile.nano17_torque_noise
        )
        self._sigma = (
            np.r_[
                np.full(7, PHYSICS.pad_force_noise),
                np.full(9, force_sigma),
                np.full(9, torque_sigma),
            ]
            * noise
        )
        self.bias = np.zeros((3, 6))
        self._all = np.concatenate([self._pad, self._force.ravel(), self._torque.ravel()])
        self._bias_force = np.zeros((3, 3))
        self._quiet_pad = (
            SENSING.pad_force_threshold - QUIET_SIGMAS * PHYSICS.pad_force_noise * noise
        )
        self._quiet_tip2 = (
            max(0.0, SENSING.tip_force_threshold - QUIET_SIGMAS * np.sqrt(3) * force_sigma * noise)
            ** 2
        )
        # The pads as the profile samples them (nominal: every period, never missed or false).
        self.pad_period = max(1, round(profile.pad_period / PHYSICS.timestep))  # control periods
        self.pad_miss = profile.pad_miss
        self.pad_false_alarm = profile.pad_false_alarm
        self.dead = np.zeros(7, dtype=bool)  # pads that miss every touch until the next tare
        self.false_alarm_at = np.full(7, -1)  # the control period of each pad's false alarm
        self._pad_sample_at = -1  # the control period of the held pad sample
        self._pad_held = np.zeros(7, dtype=bool)
        self._pad_held_any = False
        # Read every control period: the arrays over the data's own buffers, made once.
        self._sensordata, self._qfrc = data.sensordata, data.qfrc_constraint
        self._arm_sigma = PHYSICS.arm_torque_noise * noise  # N m
        self._arm_quiet = SENSING.arm_torque_threshold - QUIET_SIGMAS * self._arm_sigma

    def _raw(self) -> np.ndarray:
        """Pads (7,), then tip forces (9,) and torques (9,), with noise."""
        raw = self.data.sensordata[self._all]
        return raw + self.rng.normal(0.0, 1.0, raw.shape) * self._sigma if self.noise > 0 else raw

    def tare(self) -> None:
        """Bias the Nano17s at their current (unloaded) reading; a new guarded move starts, so
        each pad misses its touches until the next tare with probability ``pad_miss``."""
        s = self.data.sensordata
        self.bias = np.hstack([s[self._force], s[self._torque]])
        self._bias_force = self.bias[:, :3]
        if self.pad_miss > 0:
            self.dead = self.rng.random(7) < self.pad_miss

    def restart(self) -> None:
        """Forget the held pad sample, misses and false alarms (the simulation was reset)."""
        self.dead[:] = False
        self.false_alarm_at[:] = -1
        self._pad_sample_at = -1

    def schedule_false_alarms(self, periods: int) -> None:
        """Each pad fires falsely with probability ``pad_false_alarm`` once, for one sample, at
        a uniformly drawn one of the next ``periods`` control periods (a guarded move's)."""
        self.false_alarm_at[:] = -1
        if self.pad_false_alarm > 0 and periods > 0:
            now = self._period()
            fires = self.rng.random(7) < self.pad_false_alarm
            self.false_alarm_at[fires] = now + self.rng.integers(0, periods, int(fires.sum()))

    def _period(self) -> int:
        """The control period the simulation is in (since the last reset)."""
        return int(round(self.data.time / PHYSICS.timestep))

    def _pads(self, pads: np.ndarray | None) -> np.ndarray:
        """(7,) bool: the pads as sampled (held between samples, dead ones silent, false alarms
        added); ``pads``: the pad forces now [N], or None when all are quiet."""
        k = self._period()
        sample = k - k % self.pad_period
        if sample != self._pad_sample_at:
            self._pad_sample_at = sample
            now = (
                np.zeros(7, dtype=bool)
                if pads is None
                else np.asarray(pads) > SENSING.pad_force_threshold
            )
            false = (self.false_alarm_at >= sample) & (
                self.false_alarm_at < sample + self.pad_period
            )
            self._pad_held = (now & ~self.dead) | false
            self._pad_held_any = bool(self._pad_held.any())
        return self._pad_held

    def read(self) -> tuple[np.ndarray, np.ndarray]:
        """(pad forces (7,) [N], tip wrenches (3,6) the object applies to each tip, site frame)."""
        raw = self._raw()
        wrench = np.hstack([raw[7:16].reshape(3, 3), raw[16:].reshape(3, 3)])
        return raw[:7], -(wrench - self.bias)

    def _fired(self, pads: np.ndarray, wrench: np.ndarray) -> np.ndarray:
        """(10,) bool: the readings (read()) over their thresholds (config.SENSING), pads then
        tips, the pads as the profile samples them."""
        out = fired_sensors(pads, wrench)
        out[:7] = self._pads(pads)
        return out

    def fired(self) -> np.ndarray:
        """(10,) bool: the sensors that fire now (see _fired)."""
        return self._fired(*self.read())

    def fired_now(self) -> np.ndarray | None:
        """(10,) bool: the sensors that fire now (``fired()``), or None when none can: the
        noisy reading is skipped while every noise-free signal is more than QUIET_SIGMAS noise
        σ below its threshold and no pad sample is held high."""
        if not _may_fire(
            self._sensordata,
            self._pad,
            self._force,
            self._bias_force,
            self._quiet_pad,
            self._quiet_tip2,
        ):
            pads = self._pads(None)
            if not self._pad_held_any:
                return None
            out = np.zeros(N_SENSORS, dtype=bool)
            out[:7] = pads
            return out
        return self.fired()

    def pad_sample(self) -> int:
        """The index (control period) of the pad sample held now: it changes when a fresh
        sample arrives (every period in the nominal world, at 50 Hz in the realistic one)."""
        k = self._period()
        return k - k % self.pad_period

    def arm_collision(self, arm_dofs: np.ndarray) -> bool:
        """Whether the WAM's collision detection trips now: the external (contact) torque on
        any of the arm joints ``arm_dofs``, with noise (PHYSICS.arm_torque_noise), over
        SENSING.arm_torque_threshold. Skips the noise draw while every joint is more than
        QUIET_SIGMAS σ below the threshold."""
        if not _any_reaches(self._qfrc, arm_dofs, self._arm_quiet):
            return False
        sigma = self._arm_sigma
        external = np.abs(self._qfrc[arm_dofs])
        noisy = external + (self.rng.normal(0.0, sigma, external.shape) if sigma > 0 else 0.0)
        return bool((np.abs(noisy) > SENSING.arm_torque_threshold).any())

    def reading(self) -> Reading:
        """One noisy reading of every sensor, with the Nano17 contact points and normals."""
        pads, wrench = self.read()
        fired = self._fired(pads, wrench)
        d = self.data
        R_palm, p_palm = d.xmat[self._palm_body].reshape(3, 3), d.xpos[self._palm_body]
        tips = np.zeros((3, 4, 4))
        tips[:, 3, 3] = 1.0
        tips[:, :3, :3] = R_palm.T @ d.xmat[self._tip_body].reshape(3, 3, 3)
        tips[:, :3, 3] = (d.xpos[self._tip_body] - p_palm) @ R_palm
        return Reading(fired, *tip_contacts(wrench, fired, tips))
