"""The nodes' executor (rrg_common.ros.node_main.SubmitOnceExecutor): with its thread pool
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

from rrg_common.ros.node_main import RCLError, SubmitOnceExecutor, spin_until_shutdown


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

    from rrg_common.ros.node_main import destroy_action_endpoints
    from rrg_msgs.action import RobustGrasp

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


#: A node (run by run_node, single-threaded) whose timer callback takes argv[1] seconds.
SLOW_CALLBACK_NODE = """
import sys, time
from rclpy.node import Node
from rrg_common.ros.node_main import run_node

class SlowCallback(Node):
    def __init__(self):
        super().__init__("slow_callback")
        self.create_timer(0.05, self.work)

    def work(self):
        print("started", flush=True)
        time.sleep(float(sys.argv[1]))
        print("finished", flush=True)

sys.exit(run_node(SlowCallback, argv=[]))
"""


def signalled_node(ros_domain: int, callback_s: float, signals: list[int]) -> tuple[int, str]:
    """Run SLOW_CALLBACK_NODE, send ``signals`` 0.3 s apart once its first callback started;
    its exit status and output."""
    import signal
    import subprocess
    import sys

    from ros_testing import ROOT, ros_env

    proc = subprocess.Popen(
        [sys.executable, "-c", SLOW_CALLBACK_NODE, str(callback_s)],
        env=ros_env(ros_domain),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=ROOT,
    )
    try:
        assert proc.stdout.readline() == "started\n"
        for sig in signals:
            proc.send_signal(sig)
            time.sleep(0.3)
        output, _ = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
            proc.wait()
    return proc.returncode, "started\n" + output


def test_a_signal_lets_the_callback_in_hand_finish_then_ends_the_node(ros_domain):
    """rclpy's handlers raised KeyboardInterrupt at whatever bytecode the main thread ran: it
    cut this callback short, and landing in rclpy's Task.__init__ it left a half-built task
    whose __del__ printed a traceback."""
    import signal

    status, output = signalled_node(ros_domain, 1.0, [signal.SIGINT])
    assert status == 0, output
    assert output.splitlines() == ["started", "finished"], output
    assert "Traceback" not in output


def test_a_second_signal_interrupts_a_callback_that_does_not_return(ros_domain):
    """The launcher's escalation (SIGINT, then SIGTERM) still ends a node stuck in a callback."""
    import signal

    start = time.monotonic()
    status, output = signalled_node(ros_domain, 60.0, [signal.SIGINT, signal.SIGTERM])
    assert status == 0, output
    assert "finished" not in output and "Traceback" not in output, output
    assert time.monotonic() - start < 20.0
