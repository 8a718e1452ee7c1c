"""The hand's sensors in MuJoCo: 7 binary touch pads and 3 Nano17 fingertip force/torque sensors.

Readings carry seeded Gaussian noise (σ from ``config.SENSING`` / ``config.PHYSICS`` times a
``noise`` scale, 0 = noiseless). The Nano17s are tared (biased) before every motion, as a real
F/T sensor is, which removes the fingertip's own weight. A contact point on a fingertip is
recovered from its wrench: the force's line of action (p × F = τ) enters the fingertip's
capsule surface at the contact; the normal there points from the object into the tip
(rrg_sim.hand_sensing, which the hardware bridge shares).
"""

from __future__ import annotations

import mujoco
import numpy as np

from rrg_sim.executor.wrt_executor import Reading

from ..config import PHYSICS, SENSING, SENSOR_NAMES
from ..hand_sensing import fired_sensors, tip_contacts
from .mjcf_robot import PAD_TOUCH, PALM_BODY, TIP_BODIES, TIP_FORCE, TIP_TORQUE

#: A noise-free signal this many σ below its threshold cannot fire (P < 1e-9): skip the noise.
QUIET_SIGMAS = 6.0


class HandSensors:
    """Noisy readings of the touch pads and Nano17s of one MuJoCo model/data pair."""

    def __init__(
        self,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        rng: np.random.Generator,
        noise: float = 1.0,
    ):
        self.model, self.data, self.rng, self.noise = model, data, rng, noise
        adr = lambda name: int(model.sensor_adr[model.sensor(name).id])
        self._pad = np.array([adr(n) for n in PAD_TOUCH])
        self._force = np.array([adr(n) for n in TIP_FORCE])[:, None] + np.arange(3)
        self._torque = np.array([adr(n) for n in TIP_TORQUE])[:, None] + np.arange(3)
        self._tip_body = np.array([model.body(b).id for b in TIP_BODIES])
        self._palm_body = model.body(PALM_BODY).id
        self._sigma = (
            np.r_[
                np.full(7, PHYSICS.pad_force_noise),
                np.full(9, SENSING.nano17_force_noise),
                np.full(9, PHYSICS.nano17_torque_noise),
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
            max(
                0.0,
                SENSING.tip_force_threshold
                - QUIET_SIGMAS * np.sqrt(3) * SENSING.nano17_force_noise * noise,
            )
            ** 2
        )

    def _raw(self) -> np.ndarray:
        """Pads (7,), then tip forces (9,) and torques (9,), with noise."""
        raw = self.data.sensordata[self._all]
        return raw + self.rng.normal(0.0, 1.0, raw.shape) * self._sigma if self.noise > 0 else raw

    def tare(self) -> None:
        """Bias the Nano17s at their current (unloaded) reading."""
        s = self.data.sensordata
        self.bias = np.hstack([s[self._force], s[self._torque]])
        self._bias_force = self.bias[:, :3]

    def read(self) -> tuple[np.ndarray, np.ndarray]:
        """(pad forces (7,) [N], tip wrenches (3,6) the object applies to each tip, site frame)."""
        raw = self._raw()
        wrench = np.hstack([raw[7:16].reshape(3, 3), raw[16:].reshape(3, 3)])
        return raw[:7], -(wrench - self.bias)

    def fired(self) -> np.ndarray:
        """(10,) bool: sensors over their thresholds (config.SENSING), pads then tips."""
        return fired_sensors(*self.read())

    def any_fired(self) -> bool:
        """Whether any sensor fires now: ``fired().any()``, skipping the noisy reading while
        every noise-free signal is more than QUIET_SIGMAS noise σ below its threshold."""
        s = self.data.sensordata
        f = s[self._force] - self._bias_force
        if s[self._pad].max() < self._quiet_pad and (f * f).sum(axis=1).max() < self._quiet_tip2:
            return False
        return bool(self.fired().any())

    def arm_collision(self, arm_dofs: np.ndarray) -> bool:
        """Whether the WAM's collision detection trips now: the external (contact) torque on
        any of the arm joints ``arm_dofs``, with noise (PHYSICS.arm_torque_noise), over
        SENSING.arm_torque_threshold. Skips the noise draw while every joint is more than
        QUIET_SIGMAS σ below the threshold."""
        external = np.abs(self.data.qfrc_constraint[arm_dofs])
        sigma = PHYSICS.arm_torque_noise * self.noise
        if external.max() < SENSING.arm_torque_threshold - QUIET_SIGMAS * sigma:
            return False
        noisy = external + (self.rng.normal(0.0, sigma, external.shape) if sigma > 0 else 0.0)
        return bool((np.abs(noisy) > SENSING.arm_torque_threshold).any())

    def reading(self) -> Reading:
        """One noisy reading of every sensor, with the Nano17 contact points and normals."""
        pads, wrench = self.read()
        fired = fired_sensors(pads, wrench)
        d = self.data
        R_palm, p_palm = d.xmat[self._palm_body].reshape(3, 3), d.xpos[self._palm_body]
        tips = np.zeros((3, 4, 4))
        tips[:, 3, 3] = 1.0
        tips[:, :3, :3] = R_palm.T @ d.xmat[self._tip_body].reshape(3, 3, 3)
        tips[:, :3, 3] = (d.xpos[self._tip_body] - p_palm) @ R_palm
        return Reading(fired, *tip_contacts(wrench, fired, tips))

    def sensor_positions(self) -> np.ndarray:
        """(10,3) world position of each sensor (pad site centres, Nano17 site origins)."""
        m, d = self.model, self.data
        sites = [m.site(f"bh/{name}_pad").id for name in SENSOR_NAMES[:7]]
        sites += [m.site(f"{body}_ft").id for body in TIP_BODIES]
        return d.site_xpos[sites]
