"""The arm's external joint torques from the torques its motors apply: a momentum observer on the
project's MuJoCo model of the WAM with the BarrettHand (no ROS).

A WAM driver reports as effort the torque its motors apply (ros2_control's effort state
interface, wam_node's getJointTorques): gravity and the arm's own motion are in it, so a change
of it is no contact. With M the inertia matrix (rotor armature included), b = C(q, q̇) q̇ + g(q)
the bias torque and τ the motors' torque, the arm obeys M q̈ + b = τ + τ_ext. Over one interval
between joint states the external torque is

    τ_ext ≈ (M Δq̇ - (τ - b) Δt) / Δt,        M and b at the interval's start,

the increment of the generalized momentum p = M q̇ that the motors and the model do not explain.
The torque is known only at the samples, so an interval longer than GAP_FACTOR controller
periods (the median of recent intervals), left by a lost message, is not used: the torque in a
gap at the start of a motion is anything between its ends.
Low-passed with time constant 1/K it is the momentum observer (De Luca and Mattone, ICRA 2003;
Haddadin, De Luca and Albu-Schäffer, "Robot Collisions", IEEE T-RO 33(6), 2017, sec. V-C),
ṙ = K (τ_ext - r): it needs no acceleration, so the steps of a trajectory's acceleration do not
show up as torque, and the motors' torque noise is averaged over 1/K.

The model is what rrg_sim simulates (rrg_models.description.mjcf_robot); on a real arm its error
(friction, mass parameters, cable stretch) remains in the estimate, which is why the bridge
reports the residual it sees in free motion (docs/hardware.md, first day).
"""

from __future__ import annotations

import math
from collections import deque

import mujoco
import numpy as np

from rrg_models.description.mjcf_robot import ARM_JOINTS, HAND_JOINTS, robot_xml

from .config import BRIDGE

#: An interval longer than this many controller periods is a gap, not used (chosen: one lost
#: message at least doubles the interval).
GAP_FACTOR = 1.5
#: Intervals whose median is the controller's period.
PERIOD_WINDOW = 51


class ExternalTorqueObserver:
    """External torque (7,) [N m] on the WAM's joints from its joint states (the module doc).

    gain_per_s: K [1/s]. max_gap_s: a longer gap between joint states restarts the observer.
    gap_factor: an interval longer than this many periods is skipped.
    """

    def __init__(
        self,
        gain_per_s: float = BRIDGE.observer_gain,
        max_gap_s: float = BRIDGE.observer_max_gap,
        gap_factor: float = GAP_FACTOR,
    ):
        self.gain_per_s, self.max_gap_s, self.gap_factor = gain_per_s, max_gap_s, gap_factor
        m = mujoco.MjModel.from_xml_string(robot_xml())
        m.body_gravcomp[:] = 0.0  # the motors carry the arm's weight: gravity is in b
        self.model, self.data = m, mujoco.MjData(m)
        joint = lambda n: m.joint(n).id
        self._arm_q = np.array([m.jnt_qposadr[joint(n)] for n in ARM_JOINTS])
        self._arm_v = np.array([m.jnt_dofadr[joint(n)] for n in ARM_JOINTS])
        self._hand_q = np.array([m.jnt_qposadr[joint(n)] for n in HAND_JOINTS])
        self._hand_v = np.array([m.jnt_dofadr[joint(n)] for n in HAND_JOINTS])
        self._mass = np.zeros((m.nv, m.nv))
        self.reset()

    def reset(self) -> None:
        """Forget the history: the next joint state starts the observer at zero."""
        self.estimate = np.zeros(7)
        self.gaps = 0  # intervals not used
        self._intervals: deque[float] = deque(maxlen=PERIOD_WINDOW)
        self._period = np.inf  # [s] the controller's, the median of the recent intervals
        self._samples = 0
        self._t: float | None = None
        self._v = np.zeros(self.model.nv)
        self._mass_arm = np.zeros((7, self.model.nv))
        self._bias = np.zeros(7)

    def update(
        self,
        t_s: float,
        arm_q: np.ndarray,
        arm_v: np.ndarray,
        arm_torque: np.ndarray,
        hand_q: np.ndarray,
        hand_v: np.ndarray,
    ) -> np.ndarray:
        """The estimate after a joint state at time t_s [s]: arm positions, velocities and motor
        torques (7,) [rad, rad/s, N m]; hand positions and velocities (8,) in HAND_JOINTS order
        (NaN, for a joint not measured, counts as 0)."""
        v = self._state(arm_q, arm_v, hand_q, hand_v)
        dt = None if self._t is None else t_s - self._t
        if dt is not None and 0.0 < dt <= self.max_gap_s:
            self._intervals.append(dt)
            self._samples += 1
            if self._samples % 10 == 1:  # the median, refreshed now and then (cheap)
                self._period = float(np.median(self._intervals))
            if dt <= self.gap_factor * self._period:
                applied = np.asarray(arm_torque, dtype=float) - self._bias
                raw = (self._mass_arm @ (v - self._v) - applied * dt) / dt
                self.estimate += (raw - self.estimate) * (1.0 - math.exp(-self.gain_per_s * dt))
            else:
                self.gaps += 1
        elif dt is None or dt > self.max_gap_s:
            self.estimate = np.zeros(7)
        if dt is None or dt > 0.0:
            self._t, self._v = t_s, v
            self._mass_arm = self._mass[self._arm_v].copy()
            self._bias = self.data.qfrc_bias[self._arm_v].copy()
        return self.estimate.copy()

    def _state(self, arm_q, arm_v, hand_q, hand_v) -> np.ndarray:
        """Set the model to a state; M into self._mass, b into data.qfrc_bias; returns q̇ (nv,)."""
        m, d = self.model, self.data
        hand_q, hand_v = np.asarray(hand_q, dtype=float), np.asarray(hand_v, dtype=float)
        d.qpos[self._arm_q] = arm_q
        d.qpos[self._hand_q] = np.where(hand_q == hand_q, hand_q, 0.0)  # NaN: 0
        d.qvel[self._arm_v] = arm_v
        d.qvel[self._hand_v] = np.where(hand_v == hand_v, hand_v, 0.0)
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_crb(m, d)
        mujoco.mj_comVel(m, d)
        mujoco.mj_rne(m, d, 0, d.qfrc_bias)
        mujoco.mj_fullM(m, d, self._mass)
        return d.qvel.copy()
