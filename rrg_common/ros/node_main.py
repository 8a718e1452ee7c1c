"""The ``main()`` every RRG node shares (ros2/examples style): init, build the node, spin one
persistent executor until shutdown, and exit cleanly on Ctrl-C or SIGINT/SIGTERM.

``spin_once`` in a ``while rclpy.ok()`` loop, not ``spin()``: a node blocked in ``spin()``
sometimes missed the first SIGINT (docs/sources.md §5).

The first SIGINT or SIGTERM is latched, not raised: rclpy's own handlers chain to Python's,
which raises KeyboardInterrupt at whatever bytecode the main thread is running. Landing inside
rclpy's ``Task.__init__`` it left a half-built task, whose ``__del__`` printed a traceback
("'Task' object has no attribute '_exception'"); in a single-threaded node it cut the callback
in hand short. The spin loop ends at the latch, once the callback in hand has returned, and
``run_node`` shuts the context down. A second signal while the node spins (the launcher's
escalation) raises KeyboardInterrupt, for a callback that does not return.
"""

from __future__ import annotations

import ctypes
import functools
import logging
import signal
import sys
import time
from collections.abc import Callable
from concurrent.futures import Future
from concurrent.futures import wait as wait_futures

import rclpy
from rclpy.action import ActionClient, ActionServer
from rclpy.executors import (
    ConditionReachedException,
    Executor,
    ExternalShutdownException,
    MultiThreadedExecutor,
    ShutdownException,
    SingleThreadedExecutor,
    TimeoutException,
)
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Task

log = logging.getLogger(__name__)

#: How long the spin loop yields the interpreter when the task it is handed is still queued for
#: a worker [s].
QUEUED_YIELD_S = 0.001
#: rclpy's error from its C layer (the type rclpy itself catches; not in its public API).
RCLError = rclpy_implementation.RCLError


def keep_serving(method: Callable) -> Callable:
    """Decorate a service callback ``(node, request, response)``: an unexpected exception is
    logged and answered with the response's UNKNOWN error code and the message (``success``
    false for std_srvs/Trigger), so one bad request never takes the node down."""

    @functools.wraps(method)
    def callback(node: Node, request, response):
        try:
            return method(node, request, response)
        except Exception as exc:
            text = f"{type(exc).__name__}: {exc}"
            node.get_logger().error(f"{method.__name__} failed: {text}")
            if hasattr(response, "error_code"):
                response.error_code, response.error_msg = response.UNKNOWN, text
            else:
                response.success, response.message = False, text
            return response

    return callback


class SubmitOnceExecutor(MultiThreadedExecutor):
    """rclpy's MultiThreadedExecutor, handing a task to the thread pool once at a time.

    rclpy's spin loop hands over again, on every turn, each task that is not executing, including
    one still queued for a worker, and then scans every task it has handed over. Holding the
    interpreter, it handed one action server goal to the pool thousands of times before a worker
    started it (4,085 copies measured in the executor node), so the scans burnt a core and each
    robust grasp took about twice as long. A task is handed over again only once its last
    hand-over has run (a coroutine awaiting a future is resumed that way).
    """

    def __init__(self, num_threads: int, *, context: rclpy.Context | None = None):
        super().__init__(num_threads, context=context)
        self._handed: dict[int, tuple[Task, Future]] = {}  # id(task) → (task, its last hand-over)

    def _spin_once_impl(self, timeout_sec=None, wait_condition=lambda: False) -> None:
        try:
            task, _, _ = self.wait_for_ready_callbacks(timeout_sec, None, wait_condition)
        except (
            ExternalShutdownException,
            ShutdownException,
            TimeoutException,
            ConditionReachedException,
        ):
            return
        last = self._handed.get(id(task))
        if last is not None and not last[1].done():
            time.sleep(QUEUED_YIELD_S)  # still queued: let a worker start it
            return
        self._handed[id(task)] = (task, self._executor.submit(task))
        for key, (handed, _) in list(self._handed.items()):
            if handed.done():
                del self._handed[key]
                handed.result()  # raise the handler's exception, as rclpy does

    def shutdown(self, timeout_sec: float | None = None) -> bool:
        """rclpy's shutdown, then wait up to ``timeout_sec`` for the callbacks already handed to
        the pool and collect what they raised. A callback that the context's shutdown cut short
        (a publish after a signal: "publisher's context is invalid") is logged at debug level,
        where rclpy would print it as an exception "never retrieved"; any other is logged as an
        error."""
        finished = super().shutdown(timeout_sec)
        wait_futures([hand_over for _, hand_over in self._handed.values()], timeout=timeout_sec)
        for task, _ in self._handed.values():
            error = task.exception() if task.done() else None
            if error is None:
                continue
            if self.context.ok():
                log.error("a callback failed before the shutdown: %r", error)
            else:
                log.debug("a callback ended by the shutdown: %r", error)
        self._handed.clear()
        return finished


def release_free_memory() -> None:
    """Hand the allocator's whole free pages back to the OS (glibc's ``malloc_trim``; nothing
    where there is none). Large buffers freed and allocated again, often from other threads,
    otherwise stay resident: an estimator loading another object's tables at every reset grew
    by about 10 % over 200 grasps."""
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def spin_until_shutdown(executor: Executor, stop: Callable[[], bool] = lambda: False) -> None:
    """Spin ``executor`` until its context shuts down, or until ``stop()`` turns true (the
    caller then shuts the context down). A shutdown (a signal's handler) that lands while it
    waits makes rclpy raise RCLError ("the given context is not valid") from the wait; that
    ends the spin like any other shutdown."""
    context = executor.context
    while context.ok() and not stop():
        try:
            executor.spin_once(timeout_sec=0.1)
        except RCLError:
            if context.ok():
                raise


class ShutdownSignals:
    """SIGINT and SIGTERM, latched while the node spins (see the module doc): the first asks
    the spin to end, a second raises KeyboardInterrupt; once the spin has ended, signals are
    only counted, so the node's clean-up runs to its end."""

    def __init__(self) -> None:
        self.received: list[int] = []
        self.spinning = True

    def install(self) -> None:
        """Handle SIGINT and SIGTERM in this process (call from the main thread)."""
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self._on_signal)

    def _on_signal(self, signum: int, _frame) -> None:
        self.received.append(signum)
        if self.spinning and len(self.received) > 1:
            raise KeyboardInterrupt

    def __bool__(self) -> bool:
        return bool(self.received)


def destroy_action_endpoints(node: Node) -> None:
    """Destroy the node's action servers and clients. rclpy's ``Node.destroy_node`` leaves its
    waitables alone, and they keep the node's handle, so a node destroyed in a process that
    goes on (a test's, a launcher's) would still serve its actions to the domain."""
    for waitable in list(node.waitables):
        if isinstance(waitable, ActionServer | ActionClient):
            waitable.destroy()


def run_node(
    make_node: Callable[[], Node], multi_threaded: bool = False, argv: list[str] | None = None
) -> int:
    """Run one node in this process until shutdown; returns the exit status.

    multi_threaded: use a MultiThreadedExecutor (nodes whose callbacks block, e.g. action
    servers that call other servers or step a simulation).
    """
    logging.basicConfig(level=logging.INFO, format="[%(levelname)s] [%(name)s]: %(message)s")
    signals = ShutdownSignals()
    rclpy.init(
        args=sys.argv if argv is None else argv, signal_handler_options=SignalHandlerOptions.NO
    )
    signals.install()
    node = None
    executor: Executor = (
        SubmitOnceExecutor(num_threads=4) if multi_threaded else SingleThreadedExecutor()
    )
    try:
        node = make_node()
        executor.add_node(node)
        spin_until_shutdown(executor, stop=lambda: bool(signals))
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        signals.spinning = False
        rclpy.try_shutdown()  # callbacks still waiting in the pool see the shutdown
        executor.shutdown(timeout_sec=1.0)
        if node is not None:
            node.destroy_node()
    return 0
