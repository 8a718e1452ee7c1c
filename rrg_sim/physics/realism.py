"""A world profile's per-trial draws, and how they change the MuJoCo model (config.WorldProfile).

``draw_conditions`` draws one trial's conditions from the profile with the trial's own
generator; ``TrialConditions.apply`` writes them into the model from its built values, so a
world reused across trials never accumulates them:

* joint zero offsets: each arm servo regulates q_true + offset to its target (a constant term
  in the position actuator's bias), and the encoders read q_true + offset;
* the servos' torque limits;
* the table top's height relative to the robot (the robot's base moves down by it, which is
  the same geometry: MuJoCo does not re-collide a world-body plane moved after compiling);
* the object's friction against the table (set on both, as MuJoCo takes the larger of a
  contact's two coefficients), and the offset of its centre of mass.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np

from rrg_sim.config import NOMINAL, WorldProfile


@dataclass(frozen=True)
class TrialConditions:
    """One trial's draws: joint offsets (7,) [rad], the table top's height change [m], the
    object–table friction coefficient (None: the model's), and the centre-of-mass offset (3,)
    [m] in the object frame."""

    joint_offset: np.ndarray
    table_dz: float = 0.0
    friction: float | None = None
    com_offset: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @classmethod
    def nominal(cls) -> TrialConditions:
        """No departure from the models."""
        return cls(np.zeros(7))


def draw_conditions(profile: WorldProfile, rng: np.random.Generator) -> TrialConditions:
    """One trial's conditions drawn from ``profile`` (nothing drawn for the nominal world)."""
    if profile == NOMINAL:
        return TrialConditions.nominal()
    heading = rng.uniform(-np.pi, np.pi)
    distance = rng.uniform(*profile.com_offset_range)
    return TrialConditions(
        joint_offset=rng.normal(0.0, profile.joint_offset_sigma, 7),
        table_dz=float(rng.normal(0.0, profile.table_height_sigma)),
        friction=None
        if profile.friction_range is None
        else float(rng.uniform(*profile.friction_range)),
        com_offset=np.array([distance * np.cos(heading), distance * np.sin(heading), 0.0]),
    )


class ModelConditions:
    """Applies TrialConditions to one model, restoring its built values first.

    arm_actuators: the 7 arm servo ids; robot_base: the body the WAM is mounted on;
    table_geoms: the table top and slab; object_body and object_geoms: the free object.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        profile: WorldProfile,
        arm_actuators: np.ndarray,
        robot_base: int,
        table_geoms: np.ndarray,
        object_body: int,
        object_geoms: np.ndarray,
    ):
        self.model, self.profile = model, profile
        self._arm, self._base, self._table, self._body, self._obj = (
            arm_actuators,
            robot_base,
            table_geoms,
            object_body,
            object_geoms,
        )
        self._bias0 = model.actuator_biasprm[arm_actuators, 0].copy()
        self._kp = model.actuator_gainprm[arm_actuators, 0].copy()
        self._base_pos = model.body_pos[robot_base].copy()
        self._friction = model.geom_friction.copy()
        self._ipos = model.body_ipos[object_body].copy()
        if profile.arm_torque_limit is not None:
            limit = np.asarray(profile.arm_torque_limit, dtype=float)
            model.actuator_forcelimited[arm_actuators] = 1
            model.actuator_forcerange[arm_actuators] = np.c_[-limit, limit]

    def apply(self, c: TrialConditions) -> None:
        """Write ``c`` into the model (the robot's state is the caller's to reset)."""
        m = self.model
        m.actuator_biasprm[self._arm, 0] = self._bias0 - self._kp * c.joint_offset
        m.body_pos[self._base] = self._base_pos - np.array([0.0, 0.0, c.table_dz])
        m.geom_friction[:] = self._friction
        if c.friction is not None:
            m.geom_friction[self._obj, 0] = c.friction
            m.geom_friction[self._table, 0] = c.friction
        m.body_ipos[self._body] = self._ipos + c.com_offset


def quantize(q: np.ndarray, resolution: np.ndarray) -> np.ndarray:
    """q rounded to multiples of resolution (entries of resolution 0 kept exact)."""
    res = np.asarray(resolution, dtype=float)
    safe = np.where(res > 0, res, 1.0)
    return np.where(res > 0, np.round(q / safe) * safe, q)
