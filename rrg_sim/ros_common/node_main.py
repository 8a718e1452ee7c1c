"""The ``main()`` every RRG node shares (ros2/examples style): init, build the node, spin one
persistent executor until shutdown, and exit cleanly on Ctrl-C or SIGINT/SIGTERM.

``spin_once`` in a ``while rclpy.ok()`` loop, not ``spin()``: a node blocked in ``spin()``
sometimes missed the first SIGINT (shared/notes/ros2-on-pip.md). In Jazzy SIGINT raises
ExternalShutdownException, so both it and KeyboardInterrupt end the loop.
"""

from __future__ import annotations

import functools
import logging
import sys
from collections.abc import Callable

import rclpy
from rclpy.executors import (
    Executor,
    ExternalShutdownException,
    MultiThreadedExecutor,
    SingleThreadedExecutor,
)
from rclpy.node import Node


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


def run_node(
    make_node: Callable[[], Node], multi_threaded: bool = False, argv: list[str] | None = None
) -> int:
    """Run one node in this process until shutdown; returns the exit status.

    multi_threaded: use a MultiThreadedExecutor (nodes whose callbacks block, e.g. action
    servers that call other servers or step a simulation).
    """
    logging.basicConfig(level=logging.INFO, format="[%(levelname)s] [%(name)s]: %(message)s")
    rclpy.init(args=sys.argv if argv is None else argv)
    node = None
    executor: Executor = (
        MultiThreadedExecutor(num_threads=4) if multi_threaded else SingleThreadedExecutor()
    )
    try:
        node = make_node()
        executor.add_node(node)
        while rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown(timeout_sec=1.0)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
