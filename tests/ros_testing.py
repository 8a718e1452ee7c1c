"""Helpers shared by the ROS tests: a DDS domain id no other test process on this machine holds,
node processes in that domain, and a test-side rclpy node with one persistent executor (the
rclpy 7.1.6 spin_until_future_complete bug: see docs/sources.md §5)."""

from __future__ import annotations

import fcntl
import json
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import rclpy
from rclpy.executors import SingleThreadedExecutor

ROOT = Path(__file__).resolve().parents[1]
#: Foxglove's bag readers, which scripts/setup.sh installs with npm.
NODE_MODULES = ROOT / ".cache" / "npm" / "node_modules"
#: Domain ids 1-101 (ids above 101 collide with Linux's ephemeral ports; domain 0 is the default
#: every unconfigured ROS process on the host uses).
DOMAIN_IDS = range(1, 102)
LOCK_PATTERN = "/tmp/rrg-ros-domain-{}.lock"


@contextmanager
def exclusive_domain_id() -> Iterator[int]:
    """The first domain id in 1-101 whose lock file no other open file holds, held (an exclusive
    ``flock``) until the block ends. Every ROS test takes its domain here, so two test processes
    on one host (two checkouts, or two runs) never share a domain; the kernel drops the lock
    when a process dies, so a killed run leaves nothing behind."""
    for domain_id in DOMAIN_IDS:
        try:
            lock = open(LOCK_PATTERN.format(domain_id), "a")  # held until the block ends
        except OSError:  # e.g. another user's lock file
            continue
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:  # held by another open file: a test process using that domain
            lock.close()
            continue
        try:
            yield domain_id
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
            lock.close()
        return
    raise RuntimeError(f"every ROS domain id {DOMAIN_IDS.start}-{DOMAIN_IDS.stop - 1} is taken")


@contextmanager
def environment(values: dict[str, str | None]) -> Iterator[None]:
    """os.environ with ``values`` set (None: unset) inside the block, restored after it."""
    saved = {k: os.environ.get(k) for k in values}
    for k, v in values.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


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


def ros_settings(env: dict) -> dict[str, str | None]:
    """The DDS settings of a ros_env environment (for ``environment``)."""
    return {
        "ROS_DOMAIN_ID": env["ROS_DOMAIN_ID"],
        "ROS_AUTOMATIC_DISCOVERY_RANGE": env["ROS_AUTOMATIC_DISCOVERY_RANGE"],
        "ROS_LOCALHOST_ONLY": None,
    }


#: Sets up a network namespace's links: loopback, and a veth pair on 10.77.0.0/24 that carries
#: multicast, so DDS discovery beyond loopback (SUBNET) has a network to find its peers on.
NETNS_SETUP = """set -e
ip link set lo up
ip link add rrg0 type veth peer name rrg1
ip addr add 10.77.0.1/24 dev rrg0
ip addr add 10.77.0.2/24 dev rrg1
ip link set rrg0 up
ip link set rrg1 up
ip route add 224.0.0.0/4 dev rrg0
exec "$@"
"""


def network_namespace(tmp_path: Path) -> list[str] | None:
    """A command prefix that runs a command in a new network namespace of its own (an
    unprivileged user namespace) with a veth pair (NETNS_SETUP), or None where this machine
    cannot make one."""
    script = tmp_path / "netns_setup.sh"
    script.write_text(NETNS_SETUP)
    prefix = ["unshare", "-rn", "bash", str(script)]
    try:
        ok = subprocess.run([*prefix, "true"], capture_output=True, timeout=10).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        ok = False
    return prefix if ok else None


def start_node(
    module: str, env: dict, log_path: Path, params: dict | None = None, options: list[str] = ()
) -> subprocess.Popen:
    """``python -m module OPTIONS --ros-args -p k:=v ...`` with stdout and stderr in
    ``log_path``."""
    args = [sys.executable, "-m", module, *options]
    if params:
        args.append("--ros-args")
        for k, v in params.items():
            args += ["-p", f"{k}:={v}"]
    with log_path.open("w") as log:  # the child writes to its own copy of the descriptor
        return subprocess.Popen(args, env=env, stdout=log, stderr=subprocess.STDOUT, cwd=ROOT)


def foxglove_read(mcap: Path) -> dict:
    """What Foxglove's readers decode of one MCAP file (tests/foxglove_bag_reader.cjs prints it:
    profile, indexed, per topic its schema and message count, each topic's last message)."""
    out = subprocess.run(
        ["node", str(ROOT / "tests" / "foxglove_bag_reader.cjs"), str(NODE_MODULES), str(mcap)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


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
        # rcl reads the domain and the discovery range when the context starts: set them for
        # that call only, so this process's environment is left as it was
        self.context = rclpy.Context()
        with environment(ros_settings(env)):
            rclpy.init(context=self.context, domain_id=int(env["ROS_DOMAIN_ID"]))
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

    def try_call(self, client, request, timeout_s: float):
        """The answer, or None when none came within ``timeout_s`` [s]: a server that has just
        started drops a response while it has not yet matched the client's response reader
        (rmw_fastrtps waits 100 ms for it; ros2/rmw_fastrtps#390), so a caller may retry."""
        future = client.call_async(request)
        if self.spin_until(future.done, timeout_s):
            return future.result()
        client.remove_pending_request(future)
        return None

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


class Launcher:
    """``rrg-launch`` as a process in the test's domain, recording to ``tmp_path/name``, with
    its output read line by line."""

    def __init__(self, tmp_path: Path, name: str, domain_id: int, *args: str):
        self.bag = tmp_path / name
        self.log_dir = tmp_path / "logs"
        self.lines: list[str] = []
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "rrg_bringup.launch", *args]
            + ["--domain-id", str(domain_id), "--bags", str(tmp_path), "--bag-name", name]
            + ["--log-dir", str(self.log_dir)],
            env=ros_env(domain_id),
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )

    def read_until(self, what: str) -> str:
        """The first line from here on that contains ``what``."""
        for line in self.proc.stdout:
            self.lines.append(line)
            if what in line:
                return line
        raise AssertionError(f"no {what!r} in the output:\n{''.join(self.lines)}")

    def pid(self, node: str) -> int:
        """The process id of a child, as the launcher printed it at the start."""
        return int(re.search(rf"\b{node} pid (\d+)", "".join(self.lines))[1])

    def finish(self) -> str:
        """Its whole output once it has exited."""
        rest, _ = self.proc.communicate(timeout=300)
        return "".join(self.lines) + rest

    def disturb_while_moving(
        self, step: int, watcher: RosClient, disturb: Callable[[], None]
    ) -> str:
        """Once step ``step`` is under way and the arm has left home (as ``watcher`` sees its
        joint states), call ``disturb()``; then its whole output once it has exited. The
        process is killed if anything fails on the way."""
        arm = ArmWatch(watcher)
        try:
            self.read_until(f"step {step}:")
            arm.states.clear()
            assert watcher.spin_until(arm.left_home, 120.0), "the arm did not move"
            disturb()
            return self.finish()
        except BaseException:
            self.proc.kill()
            raise


class ArmWatch:
    """The arm's joint states on ``/rrg/joint_states``, as a client node receives them."""

    def __init__(self, client: RosClient, tolerance_rad: float = 0.05):
        from sensor_msgs.msg import JointState

        self.tolerance_rad = tolerance_rad
        self.states: list = []
        client.node.create_subscription(JointState, "/rrg/joint_states", self.states.append, 10)

    def left_home(self) -> bool:
        """Whether the last state has a joint more than ``tolerance_rad`` from home."""
        import numpy as np

        from rrg_common.ros.msg_conversions import ARM_JOINT_NAMES
        from rrg_models import wam

        if not self.states:
            return False
        js = self.states[-1]
        q = np.array([js.position[js.name.index(n)] for n in ARM_JOINT_NAMES])
        return bool(np.abs(q - wam.HOME_Q).max() > self.tolerance_rad)
