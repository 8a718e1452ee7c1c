"""The emulated trajectory controller's goals without ROS: a FollowJointTrajectory goal's
trajectory checked as a JointTrajectoryController checks it, and the bookkeeping of the goals
the action server runs on the emulated arm (which goal was accepted last, which robot goal each
one follows, and when it finished). ``rrg_fake_hw.ros.trajectory_controller`` serves the action
on them."""

from __future__ import annotations

import threading

import numpy as np

from rrg_models.trajectory import GOAL_START_TOLERANCE

from .emulated_robot import EmulatedRobot, Event, GoalState
from .fake_hw_core import ARM_JOINTS

#: Feedback period [s] of a trajectory goal (chosen; JTC's action_monitor_rate default, 20 Hz,
#: is coarser).
FEEDBACK_PERIOD = 0.02


def _seconds(duration) -> float:
    """A builtin_interfaces/Duration-shaped value in seconds."""
    return duration.sec + 1e-9 * duration.nanosec


def validate_trajectory(traj, q_now: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(q (M,7) in ARM_JOINTS order [rad], t (M,) [s]) of a trajectory_msgs/JointTrajectory-shaped
    ``traj``; ValueError with the reason when a JTC would reject it (q_now (7,) [rad]: the arm's
    configuration)."""
    names = list(traj.joint_names)
    if len(names) != 7 or set(names) != set(ARM_JOINTS):
        raise ValueError(f"joint_names must be the 7 arm joints {list(ARM_JOINTS)}, got {names}")
    if not traj.points:
        raise ValueError("the trajectory has no points")
    order = [names.index(n) for n in ARM_JOINTS]
    q, t = [], []
    for k, p in enumerate(traj.points):
        if len(p.positions) != 7:
            raise ValueError(f"point {k} has {len(p.positions)} positions, not 7")
        for field in ("velocities", "accelerations"):
            n = len(getattr(p, field))
            if n not in (0, 7):
                raise ValueError(f"point {k} has {n} {field}, not 0 or 7")
            if n and not np.all(np.isfinite(getattr(p, field))):
                raise ValueError(f"point {k} has non-finite {field}")
        q.append(np.asarray(p.positions, dtype=float)[order])
        t.append(_seconds(p.time_from_start))
    q, t = np.array(q), np.array(t)
    if not np.all(np.isfinite(q)):
        raise ValueError("non-finite positions")
    if t[0] < 0.0 or np.any(np.diff(t) <= 0.0):
        raise ValueError(f"time_from_start must increase strictly from >= 0, got {t.tolist()}")
    last_v = traj.points[-1].velocities
    if len(last_v) and np.any(np.asarray(last_v) != 0.0):
        raise ValueError("the last point must have zero velocity")
    if t[0] == 0.0 and np.abs(q[0] - q_now).max() > GOAL_START_TOLERANCE:
        raise ValueError("the first point, at time 0, is away from the arm's configuration")
    return q, t


class TrajectoryGoals:
    """The action server's goals, keyed by their goal id's bytes: numbered in the order they
    are accepted (the newest one runs: JTC preempts by arrival, whatever order the executor
    runs the execute callbacks in), and while one runs, its robot goal and an event set when
    that goal finishes. Thread-safe."""

    def __init__(self, robot: EmulatedRobot) -> None:
        self.robot = robot
        self._goal_done: dict[int, threading.Event] = {}
        self._goal_ids: dict[bytes, int] = {}
        self._map_lock = threading.RLock()
        self._accepted = 0  # trajectory goals accepted so far
        self._accept_order: dict[bytes, int] = {}  # goal id → its acceptance number

    def accept(self, key: bytes) -> None:
        """Number a newly accepted goal."""
        with self._map_lock:
            self._accepted += 1
            self._accept_order[key] = self._accepted

    def robot_goal(self, key: bytes) -> int | None:
        """The robot goal a running goal follows (None: not running)."""
        with self._map_lock:
            return self._goal_ids.get(key)

    def start(self, key: bytes, q: np.ndarray, t: np.ndarray) -> tuple[int, threading.Event] | None:
        """Have the arm follow a goal's via-points q (M,7) [rad] at t (M,) [s]: (its robot goal,
        an event set when that goal finishes), or None when a newer goal was accepted before
        this one started (it is preempted at once)."""
        done = threading.Event()
        with self._map_lock:
            if self._accept_order.pop(key, self._accepted) < self._accepted:
                return None
            goal_id = self.robot.follow(q, t)
            self._goal_ids[key] = goal_id
            self._goal_done[goal_id] = done
            if self.robot.goal_status(goal_id).state is not GoalState.ACTIVE:
                done.set()
        return goal_id, done

    def forget(self, key: bytes, goal_id: int) -> None:
        """Drop a goal that has ended."""
        with self._map_lock:
            self._goal_ids.pop(key, None)
            self._goal_done.pop(goal_id, None)

    def on_event(self, event: Event) -> None:
        """The robot's event listener: a goal_finished event wakes the goal's waiter."""
        if event.name == "goal_finished":
            with self._map_lock:
                done = self._goal_done.get(event.details["goal_id"])
            if done is not None:
                done.set()
