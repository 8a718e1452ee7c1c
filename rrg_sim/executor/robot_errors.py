"""What a ``Robot`` (rrg_sim.executor.wrt_executor) raises when a command does not complete:
ROS-free, so the executor core can tell a stop it can work around from one it cannot."""

from __future__ import annotations


class MotionFailed(RuntimeError):
    """The arm/hand interface refused or failed a command, or did not answer in time."""


class MotionCanceled(RuntimeError):
    """The motion was interrupted (the caller's cancel request, or shutdown)."""


class HandStopped(MotionFailed):
    """The bridge's safety layer stopped a hand command midway (HandCommand STOPPED)."""


class ForceCeilingStop(MotionFailed):
    """The bridge's safety layer stopped an arm move at the fingertip force ceiling and holds
    the arm where it stopped (GuardedMove FORCE_LIMIT): nothing is latched, the next move runs."""


class StaleDataStop(MotionFailed):
    """The bridge's safety layer stopped an arm move because a data stream (joint states, a
    fingertip, the pads) went stale (GuardedMove STALE_DATA): nothing is latched, and the next
    move runs once the data is fresh again."""


class ExecutionStopped(MotionFailed):
    """A WRT's execution was stopped by a transient safety stop (StaleDataStop) and the hand
    brought home: nothing was observed, and the WRT may run again."""


class RobotFault(MotionFailed):
    """The arm/hand interface went away (its process died): nothing moves until it is back."""
