"""Helpers shared by the tests/test_ros_*.py files: node processes in a test's own DDS domain, and
a test-side rclpy node with one persistent executor (the rclpy 7.1.6 spin_until_future_complete
bug: see shared/notes/ros2-on-pip.md)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import rclpy
from rclpy.executors import SingleThreadedExecutor

ROOT = Path(__file__).resolve().parents[1]


def ros_env(domain_id: int) -> dict:
    """This process's environment on loopback in DDS domain ``domain_id`` (1-101)."""
    env = dict(
        os.environ,
        ROS_DOMAIN_ID=str(domain_id),
        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
        PYTHONUNBUFFERED="1",
    )
    env.pop("ROS_LOCALHOST_ONLY", None)
    return env


def start_node(
    module: str, env: dict, log_path: Path, params: dict | None = None
) -> subprocess.Popen:
    """``python -m module --ros-args -p k:=v ...`` with stdout and stderr in ``log_path``."""
    args = [sys.executable, "-m", module]
    if params:
        args.append("--ros-args")
        for k, v in params.items():
            args += ["-p", f"{k}:={v}"]
    log = log_path.open("w")
    return subprocess.Popen(args, env=env, stdout=log, stderr=subprocess.STDOUT, cwd=ROOT)


def stop_process(proc: subprocess.Popen, timeout_s: float = 10.0) -> int:
    """SIGINT, then SIGKILL if it does not exit in time; returns the exit status."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.returncode


class RosClient:
    """A test-side node with one persistent executor."""

    def __init__(self, env: dict, name: str = "rrg_test_client"):
        os.environ.update({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")})
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin_until(self, condition, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while not condition():
            if time.monotonic() > deadline:
                return False
            self.executor.spin_once(timeout_sec=0.05)
        return True

    def result(self, future, timeout_s: float = 30.0):
        assert self.spin_until(future.done, timeout_s), "no answer in time"
        return future.result()

    def wait_for_services(self, clients, procs: list[subprocess.Popen], timeout_s: float) -> None:
        """Wait until every client's server is up; fail at once if a node process died."""
        deadline = time.monotonic() + timeout_s
        for c in clients:
            while not c.wait_for_service(timeout_sec=0.5):
                dead = [p.args for p in procs if p.poll() is not None]
                assert not dead, f"node process exited: {dead}"
                assert time.monotonic() < deadline, f"{c.srv_name} did not come up"

    def call(self, client, request, timeout_s: float = 30.0):
        return self.result(client.call_async(request), timeout_s)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@contextmanager
def node_processes(specs: list[tuple[str, dict]], env: dict, log_dir: Path):
    """Start ``(module, params)`` node processes; stop them all on exit."""
    procs = []
    try:
        for module, params in specs:
            procs.append(
                start_node(module, env, log_dir / f"{module.rsplit('.', 1)[-1]}.log", params)
            )
        yield procs
    finally:
        for p in procs:
            stop_process(p)
