"""Child processes for ``rrg-launch`` (operations §8): each node in its own process and session,
restarted with a doubling backoff when it dies, stopped SIGINT → SIGTERM → SIGKILL; and the
environment and arguments a ROS 2 child starts with. ROS-free: ``rrg_bringup.graph.Graph``
adds the launcher's node and publishes each child's events."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

#: SIGINT, then SIGTERM after this long [s], then SIGKILL after as long again (notes: a node
#: sometimes misses the first SIGINT).
STOP_ESCALATE_S = 3.0
#: Restarts per child before the launcher gives up and stops the graph (launch_ros respawns
#: without a limit; chosen: a node that dies three times in one run has a cause to fix).
RESPAWN_MAX = 3
#: Wait before a child's first restart [s], doubled for each next one up to RESPAWN_DELAY_MAX_S
#: (chosen: short beside a node's start-up of ~1 s, so the recorder loses little, while a node
#: that dies at start does not spin in a loop).
RESPAWN_DELAY_S = 0.5
RESPAWN_DELAY_MAX_S = 30.0


class LaunchError(RuntimeError):
    """The graph could not be started or a call into it failed."""


class LaunchTimeout(LaunchError):
    """A wait on the graph timed out."""


@dataclass
class Child:
    """A child process of the graph and what its restarts need."""

    name: str
    proc: subprocess.Popen
    log: TextIO | None
    args: list[str]  # after the interpreter
    restart_args: list[str]  # added when it restarts (the recorder's --append)
    restarts: int = 0  # restarts made or scheduled
    restart_at: float | None = None  # time.monotonic() of the scheduled restart

    def restart_command(self) -> list[str]:
        """``args`` with ``restart_args`` before the ROS arguments."""
        i = self.args.index("--ros-args") if "--ros-args" in self.args else len(self.args)
        return [*self.args[:i], *self.restart_args, *self.args[i:]]


def exit_description(returncode: int) -> str:
    """How a process ended, from Popen's returncode (negative: the signal that killed it)."""
    if returncode < 0:
        try:
            return f"killed by {signal.Signals(-returncode).name}"
        except ValueError:
            return f"killed by signal {-returncode}"
    return f"exited with status {returncode}"


def respawn_delay(attempt: int, first_s: float, max_s: float = RESPAWN_DELAY_MAX_S) -> float:
    """The wait [s] before restart ``attempt`` (1-based): ``first_s``, doubled per attempt."""
    return min(first_s * 2.0 ** (attempt - 1), max_s)


#: ROS 2's automatic discovery ranges (ROS_AUTOMATIC_DISCOVERY_RANGE, Jazzy).
DISCOVERY_RANGES = ("LOCALHOST", "SUBNET", "SYSTEM_DEFAULT", "OFF")


def ros_environment(
    domain_id: int, discovery_range: str = "LOCALHOST", static_peers: str = ""
) -> dict[str, str]:
    """The children's environment in the given DDS domain: loopback discovery by default (a
    real robot's drivers on another host need SUBNET, or OFF with ``static_peers``, the
    ``;``-separated addresses of ROS_STATIC_PEERS)."""
    if discovery_range not in DISCOVERY_RANGES:
        raise ValueError(f"discovery range must be one of {DISCOVERY_RANGES}")
    env = dict(
        os.environ,
        ROS_DOMAIN_ID=str(domain_id),
        ROS_AUTOMATIC_DISCOVERY_RANGE=discovery_range,
        ROS_STATIC_PEERS=static_peers,
        PYTHONUNBUFFERED="1",
    )
    env.pop("ROS_LOCALHOST_ONLY", None)  # deprecated; the discovery range replaces it
    env.setdefault("AMENT_PREFIX_PATH", sys.prefix)
    return env


def ros_args(params: dict[str, object], params_file: Path | None = None) -> list[str]:
    """``--ros-args [--params-file FILE] -p k:=v ...`` (the -p values override the file's; a
    list or tuple becomes a ROS list of its items' Python literals)."""
    args = ["--ros-args"]
    if params_file is not None:
        args += ["--params-file", str(params_file)]
    for k, v in params.items():
        if isinstance(v, (list, tuple)):
            v = f"[{','.join(map(repr, v))}]"
        args += ["-p", f"{k}:={v}"]
    return args


class Supervisor:
    """Child processes, each ``python ARGS`` in its own session, restarted with a backoff when
    they die, and stopped in order."""

    def __init__(
        self,
        env: dict[str, str],
        log_dir: Path | None,
        respawn_max: int = RESPAWN_MAX,
        respawn_delay_s: float = RESPAWN_DELAY_S,
        cwd: Path | None = None,
    ):
        self.env = env
        self.log_dir = log_dir
        self.respawn_max = respawn_max  # restarts per child
        self.respawn_delay_s = respawn_delay_s  # before a child's first restart
        self.cwd = cwd
        self.children: list[Child] = []
        self.stopping = False  # the graph is being stopped: no more restarts

    def spawn(self, name: str, args: list[str], restart_args: list[str] | None = None) -> None:
        """Start a child process, ``python ARGS``; its restarts add ``restart_args``."""
        log = None
        if self.log_dir is not None:
            self.log_dir.mkdir(parents=True, exist_ok=True)
            log = (self.log_dir / f"{name}.log").open("w")
        self.children.append(Child(name, self.popen(args, log), log, args, restart_args or []))

    def popen(self, args: list[str], log: TextIO | None) -> subprocess.Popen:
        # Own session: a terminal's Ctrl-C reaches only the launcher, which stops
        # the children in order.
        return subprocess.Popen(
            [sys.executable, *args],
            env=self.env,
            cwd=self.cwd,
            start_new_session=True,
            stdout=log or sys.stderr,
            stderr=subprocess.STDOUT,
        )

    def process(self, name: str) -> subprocess.Popen | None:
        """The running process of child ``name`` (None if it is not running, or not a child)."""
        for c in self.children:
            if c.name == name and c.proc.poll() is None:
                return c.proc
        return None

    def supervise(self) -> None:
        """Restart the children that died, each after its backoff; LaunchError when one has died
        more often than ``respawn_max`` allows."""
        if self.stopping:
            return
        now = time.monotonic()
        for c in self.children:
            if c.restart_at is not None:
                if now >= c.restart_at:
                    self.restart(c)
                continue
            status = c.proc.poll()
            if status is None:
                continue
            ended = f"{c.name} {exit_description(status)} (pid {c.proc.pid})"
            if c.restarts >= self.respawn_max:
                message = (
                    f"{ended}; gave up after {c.restarts} restart{'s' * (c.restarts != 1)}"
                    if self.respawn_max
                    else f"{ended}; not restarted (--respawn-max 0)"
                )
                self.publish_event(c, "EVENT_GAVE_UP", message, c.restarts)
                raise LaunchError(message)
            c.restarts += 1
            delay = respawn_delay(c.restarts, self.respawn_delay_s)
            c.restart_at = now + delay
            self.publish_event(
                c,
                "EVENT_EXITED",
                f"{ended}; restarting it in {delay:.1f} s "
                f"(attempt {c.restarts} of {self.respawn_max})",
                c.restarts,
                delay,
            )

    def restart(self, c: Child) -> None:
        """Start a new process of a dead child (its log continues)."""
        c.restart_at = None
        c.proc = self.popen(c.restart_command(), c.log)
        self.publish_event(
            c,
            "EVENT_RESTARTED",
            f"{c.name} restarted (pid {c.proc.pid}, attempt {c.restarts} of {self.respawn_max})",
            c.restarts,
        )

    def publish_event(
        self, c: Child, event: str, message: str, attempt: int, delay: float = 0.0
    ) -> None:
        """Log a child's exit, restart or the end of its restarts (``event``: a NodeEvent
        constant's name; the LaunchError that follows the end reports it), then hand it to
        ``on_event``."""
        if event != "EVENT_GAVE_UP":
            print(f"[rrg-launch] {message}", file=sys.stderr, flush=True)
        if c.log is not None:
            c.log.write(f"[rrg-launch] {message}\n")
            c.log.flush()
        self.on_event(c, event, message, attempt, delay)

    def on_event(self, c: Child, event: str, message: str, attempt: int, delay: float) -> None:
        """A child's event, after it was logged (a subclass publishes it)."""

    def stop(self, escalate_s: float = STOP_ESCALATE_S) -> None:
        """Stop the nodes (SIGINT → SIGTERM → SIGKILL, ``escalate_s`` apart), then the recorder
        the same way."""
        self.stopping = True
        nodes = [c for c in self.children if c.name != "recorder"]
        recorder = [c for c in self.children if c.name == "recorder"]
        for group in (nodes, recorder):
            for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
                running = [c for c in group if c.proc.poll() is None]
                if not running:
                    break
                for c in running:
                    c.proc.send_signal(sig)
                deadline = time.monotonic() + escalate_s
                for c in running:
                    try:
                        c.proc.wait(max(0.0, deadline - time.monotonic()))
                    except subprocess.TimeoutExpired:
                        pass
        for c in self.children:
            if c.log is not None:
                c.log.close()
