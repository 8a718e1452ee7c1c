"""The emulated drivers' wiring without ROS: the drivers' joint names and the ``/joint_states``
layout of each arm interface, the three Net F/T boxes on the emulated robot's fingertip loads,
and the run-time faults and benchmarks (``fault.*``, ``bench.*``) put into effect on the robot
and the boxes. ``rrg_fake_hw.fake_hw_node`` turns parameters into these and their answers into
messages."""

from __future__ import annotations

import array
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from rrg_hw_bridge.rdt import Calibration
from rrg_models.config import PHYSICS, SENSING

from .emulated_robot import EmulatedRobot, Event, Snapshot
from .fake_netft import FakeNetFtBox

NODE_NAME = "fake_hw"
#: Driver joint names (ros2_control / Barrett URDF; PLAN.md).
ARM_JOINTS = tuple(f"wam_j{i}_joint" for i in range(1, 8))
SPREAD_JOINTS = ("bhand_j11_joint", "bhand_j21_joint")
PROXIMAL_JOINTS = ("bhand_j12_joint", "bhand_j22_joint", "bhand_j32_joint")
DISTAL_JOINTS = ("bhand_j13_joint", "bhand_j23_joint", "bhand_j33_joint")
JOINT_NAMES = ARM_JOINTS + SPREAD_JOINTS + PROXIMAL_JOINTS + DISTAL_JOINTS
#: The arm interfaces the node can serve (parameter arm_interface): the trajectory controller,
#: Barrett's wam_node (WamNodeInterface), or both on the one arm.
ARM_INTERFACES = ("follow_joint_trajectory", "wam_node", "both")
#: wam_node's arm joint names in /joint_states (wam_publishers.h: "q" + (i + 1)).
WAM_NODE_ARM_JOINTS = tuple(f"q{i}" for i in range(1, 8))
#: Efforts of the hand joints in wam_node's /joint_states: never set, so 0.
WAM_NODE_HAND_EFFORT = np.zeros(8)
#: Efforts of the hand joints in /joint_states: not measured.
UNMEASURED_EFFORT = np.full(8, np.nan)
#: The interfaces the trajectory controller's joint states may publish as NaN (parameter
#: unmeasured_interfaces).
UNMEASURABLE = {"arm_effort", "hand_velocity"}
#: How many boxes fault.silent_box can silence at once: 3 means all of them.
ALL_BOXES = 3


def _doubles(*parts: np.ndarray) -> array.array:
    """The parts concatenated as an array.array of doubles (a message field that skips the
    per-element checks)."""
    return array.array("d", np.concatenate(parts).tobytes())


class JointStateLayout:
    """What ``/joint_states`` carries for an arm interface: the trajectory controller's arm
    joints (effort: the motors' torque [N m]), wam_node's (effort: commanded torque [N m]), or
    both, then the hand's; ValueError for an unknown interface."""

    def __init__(self, arm_interface: str, unmeasured: list[str]) -> None:
        if arm_interface not in ARM_INTERFACES:
            raise ValueError(f"arm_interface must be one of {ARM_INTERFACES}")
        self.arm_interface = arm_interface
        self.unmeasured = set(unmeasured) - {""}
        if not self.unmeasured <= UNMEASURABLE:
            raise ValueError(f"unmeasured_interfaces: unknown {self.unmeasured}")

    def names(self) -> tuple[str, ...]:
        """The joint names, arm first."""
        arm = {
            "follow_joint_trajectory": ARM_JOINTS,
            "wam_node": WAM_NODE_ARM_JOINTS,
            "both": ARM_JOINTS + WAM_NODE_ARM_JOINTS,
        }[self.arm_interface]
        return arm + JOINT_NAMES[len(ARM_JOINTS) :]

    def arrays(self, s: Snapshot) -> tuple[array.array, array.array, array.array]:
        """(position [rad], velocity [rad/s], effort [N m]) of a snapshot in names() order.
        wam_node's alone has no velocities and zero hand efforts, as wam_node's
        (wam_publishers.h)."""
        hand_q = (s.spread, s.proximal, s.distal)
        hand_v = (s.spread_velocity, s.proximal_velocity, s.distal_velocity)
        arm_effort = s.arm_effort
        if "hand_velocity" in self.unmeasured:
            hand_v = (np.full(8, np.nan),)
        if "arm_effort" in self.unmeasured:
            arm_effort = np.full(7, np.nan)
        if self.arm_interface == "follow_joint_trajectory":
            return (
                _doubles(s.arm_q, *hand_q),
                _doubles(s.arm_qd, *hand_v),
                _doubles(arm_effort, UNMEASURED_EFFORT),
            )
        if self.arm_interface == "wam_node":
            return (
                _doubles(s.arm_q, *hand_q),
                array.array("d"),
                _doubles(s.arm_torque, WAM_NODE_HAND_EFFORT),
            )
        return (
            _doubles(s.arm_q, s.arm_q, *hand_q),
            _doubles(s.arm_qd, s.arm_qd, *hand_v),
            _doubles(arm_effort, s.arm_torque, UNMEASURED_EFFORT),
        )


def open_boxes(
    tip_load: Callable[[int], np.ndarray],
    hosts: list[str],
    counts_per_force: float,
    counts_per_torque: float,
    factors: list[float],
    *,
    rate_hz: float,
    port: int,
    sensor_noise: float,
    seed: int,
    zero_offset: list[float],
    http_port: int | None,
) -> list[FakeNetFtBox]:
    """One streaming Net F/T box per fingertip at ``hosts[i]``:``port``, box i calibrated with
    ``factors[i]`` times counts_per_force [counts/N] and counts_per_torque [counts/(N m)];
    ValueError for bad factors, OSError (the opened ones closed) when a box cannot bind."""
    factors = list(factors)
    if len(factors) != len(hosts) or min(factors) <= 0.0:
        raise ValueError("box_calibration_factors: one positive factor per box")
    boxes: list[FakeNetFtBox] = []
    try:
        for i, host in enumerate(hosts):
            boxes.append(
                FakeNetFtBox(
                    host,
                    lambda i=i: tip_load(i),
                    Calibration(counts_per_force * factors[i], counts_per_torque * factors[i]),
                    rate_hz=rate_hz,
                    port=port,
                    noise_n=SENSING.nano17_force_noise * sensor_noise,
                    noise_nm=PHYSICS.nano17_torque_noise * sensor_noise,
                    seed=seed + 1 + i,
                    zero_offset=zero_offset,
                    http_port=http_port,
                )
            )
    except OSError:
        for box in boxes:
            box.close()
        raise
    return boxes


@dataclass(frozen=True)
class Fault:
    """A run-time parameter: its default, description and range."""

    default: object
    description: str
    lo: float | None = None
    hi: float | None = None


FAULTS: dict[str, Fault] = {
    "fault.silent_box": Fault(-1, "Silence one Net F/T box (0-2), all (3) or none (-1)", -1, 3),
    "fault.drop_probability": Fault(0.0, "Drop each RDT record with this probability", 0.0, 1.0),
    "fault.packet_delay": Fault(0.0, "Send every RDT record this late [s]", 0.0, 1.0),
    "fault.status_word": Fault(0, "Status word in every RDT record (0: healthy)", 0, 2**32 - 1),
    "fault.wrong_length": Fault(False, "Send 35-byte datagrams instead of RDT records"),
    "fault.joint_limit": Fault(False, "Report joint 4 past its upper limit (encoder glitch)"),
    "fault.zero_drift": Fault(
        0.0, "Drift [N] of every Net F/T box's unloaded Fx (temperature)", -20.0, 20.0
    ),
    "fault.silent_tactile": Fault(
        False, "Stop publishing the pads, tactile pucks and ContactPads (a hand driver hung)"
    ),
    "fault.ignore_cancel": Fault(
        False, "The trajectory controller accepts a cancel and keeps the goal running"
    ),
    "fault.stuck_finger": Fault(-1, "Finger (0-2) that ignores every command; -1: none", -1, 2),
    "fault.extra_force": Fault(
        0.0, "Force [N] added to fingertip 1's load along its z (synthetic contact)", -100.0, 100.0
    ),
    "fault.palm_push": Fault(
        0.0, "Force [N] pushing the palm up (world +z): a contact on the arm", -100.0, 100.0
    ),
    "bench.crossing_threshold": Fault(
        0.0, "Record every box's first |force| over this [N] (0: off)", 0.0, 1000.0
    ),
}


def checked_fault(name: str, value: object) -> object:
    """A fault/bench parameter's new value, an int widened to a float one; ValueError with the
    reason when it is of another type or out of range."""
    f, v = FAULTS[name], value
    kind = type(f.default)
    if kind is float and type(v) is int:
        v = float(v)
    if type(v) is not kind or (f.lo is not None and not (np.isfinite(v) and f.lo <= v <= f.hi)):
        raise ValueError(f"{name}: {v!r} is not a {kind.__name__} in [{f.lo}, {f.hi}]")
    return v


class FaultInjector:
    """The faults and benchmarks in effect on the emulated robot and its Net F/T boxes."""

    def __init__(
        self, robot: EmulatedRobot, boxes: list[FakeNetFtBox], zero_offset: list[float]
    ) -> None:
        self.robot, self.boxes = robot, boxes
        self._zero_offset = np.asarray(zero_offset, dtype=float)  # [N, N m] without drift
        self._crossing: tuple[float, list[bool]] | None = None  # (threshold [N], reported)

    def apply(self, name: str, v: object) -> None:
        """Put a validated fault/bench parameter value into effect."""
        if name == "fault.silent_box":
            for i, box in enumerate(self.boxes):
                box.silence(v in (i, ALL_BOXES))
        elif name == "fault.drop_probability":
            for box in self.boxes:
                box.drop_probability(v)
        elif name == "fault.packet_delay":
            for box in self.boxes:
                box.delay(v)
        elif name == "fault.status_word":
            for box in self.boxes:
                box.status_word(v)
        elif name == "fault.wrong_length":
            for box in self.boxes:
                box.wrong_length(v)
        elif name == "fault.joint_limit":
            self.robot.set_joint_limit_fault(v)
        elif name == "fault.stuck_finger":
            self.robot.set_stuck_finger(None if v < 0 else v)
        elif name == "fault.zero_drift":
            for box in self.boxes:
                box.zero_offset = self._zero_offset + np.array([v, 0.0, 0.0, 0.0, 0.0, 0.0])
        elif name in ("fault.ignore_cancel", "fault.silent_tactile"):
            pass  # read where they act: the cancel callback, the publishing loop
        elif name == "fault.extra_force":
            self.robot.set_extra_force(v)
        elif name == "fault.palm_push":
            self.robot.set_palm_push(v)
        elif name == "bench.crossing_threshold":
            self._crossing = None
            if v > 0.0:
                for box in self.boxes:
                    box.arm_crossing(v)
                self._crossing = (v, [False] * len(self.boxes))

    def new_crossings(self) -> list[Event]:
        """A first_crossing event for each armed box whose first |force| over the threshold
        has not been reported yet."""
        crossing = self._crossing
        if crossing is None:
            return []
        threshold, reported = crossing
        events = []
        for i, box in enumerate(self.boxes):
            t = box.first_crossing(threshold)
            if t is not None and not reported[i]:
                reported[i] = True
                events.append(
                    Event("first_crossing", t, {"box": i, "host": box.host, "threshold": threshold})
                )
        return events
