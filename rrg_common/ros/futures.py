"""Calling services and actions from inside a callback of a MultiThreadedExecutor.

The callback blocks its own thread on an Event while the executor's other threads deliver the
response, so the clients must be in a reentrant callback group. Waits poll in short slices so
that a cancel request or a shutdown interrupts them. Action clients must be
``ThreadSafeActionClient``s (see there).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from rclpy.action import ActionClient
from rclpy.task import Future

from rrg_common.ros.liveliness import PeerLost, PeerWatch

POLL_S = 0.05


class WaitTimeout(TimeoutError):
    """The future did not complete in time."""


class WaitInterrupted(RuntimeError):
    """The wait was interrupted (cancel requested, or the node is shutting down)."""


def wait_for(
    future: Future,
    timeout_s: float,
    interrupted: Callable[[], bool] | None = None,
    peer: PeerWatch | None = None,
):
    """The future's result, waiting at most ``timeout_s``; raises WaitTimeout, WaitInterrupted
    as soon as ``interrupted()`` turns true, or PeerLost as soon as ``peer`` (the node that
    answers) is down or goes away."""
    done = threading.Event()
    future.add_done_callback(lambda _: done.set())
    deadline = time.monotonic() + timeout_s
    losses = peer.losses if peer is not None else 0
    while not done.wait(POLL_S):
        if interrupted is not None and interrupted():
            raise WaitInterrupted("interrupted while waiting")
        if peer is not None and peer.lost_since(losses):
            raise PeerLost(f"the {peer.name} went away")
        if time.monotonic() > deadline:
            raise WaitTimeout(f"no answer within {timeout_s:.0f} s")
    return future.result()


class ThreadSafeActionClient(ActionClient):
    """An ActionClient whose requests and responses do not race.

    rclpy 7.1.6's ActionClient sends a goal, cancel or result request and only then registers
    its future; in a MultiThreadedExecutor another thread can handle the response in between,
    which is then dropped ("Ignoring unexpected goal response") and the future never completes.
    Here sending and registering happen under one lock that the response handling takes too.
    """

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._request_lock = threading.Lock()

    def send_goal_async(self, *args, **kwargs):
        with self._request_lock:
            return super().send_goal_async(*args, **kwargs)

    def _cancel_goal_async(self, *args, **kwargs):
        with self._request_lock:
            return super()._cancel_goal_async(*args, **kwargs)

    def _get_result_async(self, *args, **kwargs):
        with self._request_lock:
            return super()._get_result_async(*args, **kwargs)

    async def execute(self, taken_data):
        replies = {k: v for k, v in taken_data.items() if k in ("goal", "cancel", "result")}
        if replies:
            with self._request_lock:  # this part of execute() never suspends
                await super().execute(replies)
        rest = {k: v for k, v in taken_data.items() if k not in replies}
        if rest:  # feedback callbacks run outside the lock
            await super().execute(rest)
