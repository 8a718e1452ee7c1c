"""The observation o of one WRT execution, shared by the geometric and physics simulators."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rrg_models.config import FINGER_SENSORS, GEOMSIM, N_SENSORS


def finger_contacts(sensors: np.ndarray) -> np.ndarray:
    """(…,10) sensor flags → (…,3) bool: fingers 1-3 with any link's sensor fired."""
    return np.asarray(sensors)[..., FINGER_SENSORS].any(axis=-1)


def grasp_arrived(kind: str, remaining_m: float) -> bool:
    """Whether a WRT of ``kind`` whose guarded move stopped ``remaining_m`` [m] short of its
    end has arrived: a goal or reorientation grasp within GEOMSIM.grasp_arrival_tolerance
    (it closes firmly, and its observation reports no early contact, in the tables and in
    execution alike); an information-gathering WRT never arrives early."""
    return kind != "info" and remaining_m <= GEOMSIM.grasp_arrival_tolerance


def fingers_in_contact(sensors: np.ndarray) -> np.ndarray:
    """(…,10) sensor flags → (…,) number of fingers with any link's sensor fired."""
    return finger_contacts(sensors).sum(axis=-1)


@dataclass
class Observation:
    """What the robot senses when one WRT ends (algorithm §5).

    contact: True if a guarded move stopped early on a sensed contact.
    progress: path length [m] the palm travelled from the WRT's first pose when it stopped
        (the whole path length when it reached the end).
    hand_pose: (4,4) hand pose in ``world`` where it stopped.
    sensors: (10,) bool, config.SENSOR_NAMES order: which sensors fired (at the stop or
        while closing).
    closure: (3,) proximal joint angles [rad] after closing the fingers.
    tip_points: (3,3) Nano17 contact points in the hand frame [m]; NaN rows where no contact.
    tip_normals: (3,3) unit contact normals in the hand frame; NaN rows where no contact.
    motion_dir: (3,) unit direction of the hand's motion in ``world`` when it stopped
        (the direction an object is bumped in; the transition model uses it).
    unconfirmed_stops: lone pad trips of the WRT's guarded moves that the next pad sample did
        not confirm, so the move went on (hand_sensing.StopConfirmation; not used by the
        belief, reported for the log and the bag).
    table_height: the table's height [m] in ``world`` that the table touch run before this
        WRT read (rrg_sim.table_touch); the WRT was raised by it, or by as much of it as the
        arm reaches; NaN without a touch (not used by the belief, reported for the log and
        the bag).
    """

    contact: bool
    progress: float
    hand_pose: np.ndarray
    sensors: np.ndarray
    closure: np.ndarray
    tip_points: np.ndarray = field(default_factory=lambda: np.full((3, 3), np.nan))
    tip_normals: np.ndarray = field(default_factory=lambda: np.full((3, 3), np.nan))
    motion_dir: np.ndarray = field(default_factory=lambda: np.zeros(3))
    unconfirmed_stops: int = 0
    table_height: float = float("nan")

    def __post_init__(self) -> None:
        self.sensors = np.asarray(self.sensors, dtype=bool).reshape(N_SENSORS)
        self.closure = np.asarray(self.closure, dtype=float).reshape(3)
        self.tip_points = np.asarray(self.tip_points, dtype=float).reshape(3, 3)
        self.tip_normals = np.asarray(self.tip_normals, dtype=float).reshape(3, 3)
        self.hand_pose = np.asarray(self.hand_pose, dtype=float).reshape(4, 4)
        self.motion_dir = np.asarray(self.motion_dir, dtype=float).reshape(3)
