"""Reading an rrg_msgs/GuardedMove goal into joint via-points: shared by the arm/hand
interface nodes (the simulator and the hardware bridge), so that both accept the same goals."""

from __future__ import annotations

import numpy as np

from rrg_msgs.action import GuardedMove
from rrg_sim import wam
from rrg_sim.executor.trajectory import DensePath, sample_times
from rrg_sim.ros_common.msg_conversions import ARM_JOINT_NAMES

#: Largest distance [rad] between the arm and a trajectory's first via-point at time 0.
START_TOLERANCE = 0.05


class GoalError(ValueError):
    """A goal the interface refuses: ``message`` and the GuardedMove result ``code``."""

    def __init__(self, message: str, code: int):
        super().__init__(message)
        self.code = code


def goal_via_points(goal: GuardedMove.Goal, q0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(q (M,7) [rad], t (M,) [s]) of a goal in ARM_JOINT_NAMES order, the arm's configuration
    q0 prepended at t = 0; without timing (all times zero), the executor's default timing
    (trajectory.sample_times). Joint limits are the caller's to check. Raises GoalError."""
    R = GuardedMove.Result
    traj = goal.trajectory
    if sorted(traj.joint_names) != sorted(ARM_JOINT_NAMES) or len(traj.joint_names) != 7:
        raise GoalError(
            f"joint_names must be the 7 arm joints {list(ARM_JOINT_NAMES)}, got "
            f"{list(traj.joint_names)}",
            R.INVALID_TRAJECTORY,
        )
    if not traj.points:
        raise GoalError("the trajectory has no points", R.INVALID_TRAJECTORY)
    if any(len(p.positions) != 7 for p in traj.points):
        raise GoalError("every point needs 7 positions", R.INVALID_TRAJECTORY)
    order = [list(traj.joint_names).index(n) for n in ARM_JOINT_NAMES]
    q = np.array([np.asarray(p.positions)[order] for p in traj.points])
    t = np.array([p.time_from_start.sec + 1e-9 * p.time_from_start.nanosec for p in traj.points])
    if not np.all(np.isfinite(q)):
        raise GoalError("non-finite positions", R.INVALID_TRAJECTORY)
    if np.any(np.diff(t) < 0.0):
        raise GoalError("time_from_start must not decrease", R.INVALID_TRAJECTORY)
    q = np.vstack([q0, q])
    if not np.any(t > 0.0):  # no timing: the executor's default speeds
        return q, sample_times(DensePath(wam.fk(q), q, np.zeros(len(q), int)))
    if t[0] == 0.0 and np.abs(q[1] - q0).max() > START_TOLERANCE:
        raise GoalError(
            "the first point is away from the arm's configuration at time 0",
            R.INVALID_TRAJECTORY,
        )
    return q, np.r_[0.0, t]


def client_fraction(index: float, n: int) -> float:
    """Fraction [0, 1] of a client's n via-points done at fractional index ``index`` of the
    followed points (the arm's configuration prepended to the client's)."""
    return float(np.clip(index if n == 1 else (index - 1.0) / (n - 1), 0.0, 1.0))
