"""The hand's sensors in MuJoCo: 7 binary touch pads and 3 Nano17 fingertip force/torque sensors.

Readings carry seeded Gaussian noise (σ from ``config.SENSING`` / ``config.PHYSICS`` times a
``noise`` scale, 0 = noiseless). The Nano17s are tared (biased) before every motion, as a real
F/T sensor is, which removes the fingertip's own weight. A contact point on a fingertip is
recovered from its wrench: the force's line of action (p × F = τ) enters the fingertip's
capsule surface at the contact; the normal there points from the object into the tip.
"""

from __future__ import annotations

import mujoco
import numpy as np

from rrg_sim.executor.wrt_executor import Reading

from ..config import PHYSICS, SENSING, SENSOR_NAMES
from ..hand import hand_tree
from .mjcf_robot import PAD_TOUCH, PALM_BODY, TIP_BODIES, TIP_FORCE, TIP_TORQUE


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
        self._thresholds = np.r_[
            np.full(7, SENSING.pad_force_threshold), np.full(3, SENSING.tip_force_threshold)
        ]
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
        pads, wrench = self.read()
        return np.concatenate([pads, np.linalg.norm(wrench[:, :3], axis=1)]) > self._thresholds

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
        force = np.linalg.norm(wrench[:, :3], axis=1)
        fired = np.concatenate([pads, force]) > self._thresholds
        points, normals = np.full((3, 3), np.nan), np.full((3, 3), np.nan)
        d = self.data
        R_palm, p_palm = d.xmat[self._palm_body].reshape(3, 3), d.xpos[self._palm_body]
        for i in np.nonzero(fired[7:])[0]:
            p, n = contact_from_wrench(wrench[i, :3], wrench[i, 3:])
            R_tip, p_tip = d.xmat[self._tip_body[i]].reshape(3, 3), d.xpos[self._tip_body[i]]
            points[i] = R_palm.T @ (R_tip @ p + p_tip - p_palm)
            normals[i] = R_palm.T @ (R_tip @ n)
        return Reading(fired, points, normals)

    def sensor_positions(self) -> np.ndarray:
        """(10,3) world position of each sensor (pad site centres, Nano17 site origins)."""
        m, d = self.model, self.data
        sites = [m.site(f"bh/{name}_pad").id for name in SENSOR_NAMES[:7]]
        sites += [m.site(f"{body}_ft").id for body in TIP_BODIES]
        return d.site_xpos[sites]
