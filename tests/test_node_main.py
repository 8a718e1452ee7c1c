"""The nodes' executor (rrg_sim.ros_common.node_main.SubmitOnceExecutor): with its thread pool
busy, rclpy's MultiThreadedExecutor hands a queued task over again on every turn; this one
hands each task over once, still raises a callback's exception from the spin, and ends quietly
on a shutdown that lands while it waits."""

from __future__ import annotations

import collections
import threading
import time

import pytest
import rclpy
from rclpy.executors import MultiThreadedExecutor

from rrg_sim.ros_common.node_main import RCLError, SubmitOnceExecutor, spin_until_shutdown


def hand_overs(executor_class, ros_domain: int, seconds: float = 1.0) -> collections.Counter:
    """Spin a node whose timer callback blocks for 50 ms every 5 ms, and another that fires
    every 1 ms, on a pool of one thread; count how often each task was handed to the pool."""
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=ros_domain)
    try:
        node = rclpy.create_node("submit_once_test", context=context)
        node.create_timer(0.005, lambda: time.sleep(0.05))
        node.create_timer(0.001, lambda: None)  # the wait set is always ready, as with 50 Hz topics
        executor = executor_class(num_threads=1, context=context)
        executor.add_node(node)
        counts: collections.Counter = collections.Counter()
        kept = []  # every task stays alive, so no two share an id
        submit = executor._executor.submit

        def counting_submit(task, *args):
            kept.append(task)
            counts[id(task)] += 1
            return submit(task, *args)

        executor._executor.submit = counting_submit
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        executor.shutdown(timeout_sec=1.0)
        node.destroy_node()
        return counts
    finally:
        rclpy.try_shutdown(context=context)


def test_a_queued_task_is_handed_to_the_pool_once(ros_domain):
    counts = hand_overs(SubmitOnceExecutor, ros_domain)
    assert len(counts) >= 5  # the timer's callbacks ran
    assert max(counts.values()) == 1
    # rclpy's own executor hands a queued task over again (2 or 3 times each, measured)
    assert max(hand_overs(MultiThreadedExecutor, ros_domain).values()) > 1


def test_a_callbacks_exception_is_raised_from_the_spin(ros_domain):
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=ros_domain)
    try:
        node = rclpy.create_node("submit_once_error", context=context)
        fired = threading.Event()

        def fail() -> None:
            fired.set()
            raise ValueError("from the callback")

        node.create_timer(0.01, fail)
        executor = SubmitOnceExecutor(num_threads=2, context=context)
        executor.add_node(node)
        with pytest.raises(ValueError, match="from the callback"):
            deadline = time.monotonic() + 5.0
            while time.monotonic() < deadline:
                executor.spin_once(timeout_sec=0.1)
        assert fired.is_set()
        executor.shutdown(timeout_sec=1.0)
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


def test_a_shutdown_while_the_executor_waits_ends_the_spin_quietly(ros_domain):
    """A signal's handler can shut the context down between the spin's check and its wait;
    rclpy then raises RCLError from the wait (seen at a bridge node's SIGINT)."""
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=ros_domain)
    try:
        node = rclpy.create_node("shutdown_race", context=context)
        executor = SubmitOnceExecutor(num_threads=2, context=context)
        executor.add_node(node)
        spin_once = executor.spin_once
        calls = []

        def shut_down_then_wait(timeout_sec=None):
            calls.append(timeout_sec)
            if len(calls) == 3:
                rclpy.shutdown(context=context)  # after the loop's check, before the wait
                with pytest.raises(RCLError, match="context is not valid"):
                    spin_once(timeout_sec=timeout_sec)  # what rclpy does then
            return spin_once(timeout_sec=timeout_sec)

        executor.spin_once = shut_down_then_wait
        spin_until_shutdown(executor)  # returns, no RCLError
        assert len(calls) == 3 and not context.ok()
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


def test_a_callback_the_shutdown_cuts_short_is_collected_not_left_unretrieved(ros_domain, capfd):
    """A callback still running in the pool when a signal shuts the context down fails (the
    simulator's state publisher: "publisher's context is invalid"); the executor's shutdown
    waits for it and collects the error, so rclpy never prints it as "never retrieved"."""
    import gc

    gc.collect()  # earlier tests' rclpy tasks print their own reports when collected
    capfd.readouterr()
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=ros_domain)
    node = rclpy.create_node("cut_short", context=context)
    started, release = threading.Event(), threading.Event()

    def publish_late() -> None:
        started.set()
        release.wait(5.0)
        raise RuntimeError("Failed to publish: publisher's context is invalid")

    node.create_timer(0.01, publish_late)
    executor = SubmitOnceExecutor(num_threads=2, context=context)
    executor.add_node(node)
    while not started.is_set():
        executor.spin_once(timeout_sec=0.1)
    rclpy.shutdown(context=context)  # the signal, while the callback runs
    release.set()
    assert executor.shutdown(timeout_sec=5.0)
    assert executor._handed == {}
    node.destroy_node()
    del executor, node
    gc.collect()
    assert "never retrieved: Failed to publish" not in capfd.readouterr().err


@pytest.mark.parametrize("destroy_actions", [True, False])
def test_a_destroyed_node_serves_its_action_no_longer(ros_domain, destroy_actions):
    """rclpy's destroy_node leaves a node's action servers alive (they hold its handle): a
    node destroyed in a process that goes on kept serving, and a client in its domain found the
    server ready and then waited for an acceptance that never came. destroy_action_endpoints
    takes them down with the node."""
    from rclpy.action import ActionClient, ActionServer

    from rrg_msgs.action import RobustGrasp
    from rrg_sim.ros_common.node_main import destroy_action_endpoints

    contexts = [rclpy.Context(), rclpy.Context()]
    for c in contexts:
        rclpy.init(context=c, domain_id=ros_domain)
    try:
        server = rclpy.create_node("action_owner", context=contexts[0])
        ActionServer(server, RobustGrasp, "/leak_test/grasp", execute_callback=lambda g: None)
        client_node = rclpy.create_node("action_user", context=contexts[1])
        client = ActionClient(client_node, RobustGrasp, "/leak_test/grasp")
        assert client.wait_for_server(timeout_sec=10.0)
        if destroy_actions:
            destroy_action_endpoints(server)
        server.destroy_node()
        deadline = time.monotonic() + 5.0
        while client.server_is_ready() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert client.server_is_ready() is not destroy_actions
    finally:
        for c in contexts:
            rclpy.try_shutdown(context=c)
