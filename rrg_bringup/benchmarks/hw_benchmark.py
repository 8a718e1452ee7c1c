"""``rrg-bench hw``: the hardware bridge's stop latency and sensor streaming, on the emulated
drivers (speed is printed, never asserted in tests).

    rrg-bench hw [--trials 50] [--force 2.0] [--idle 5] [--rdt-rates 1000,3000,7000]
                 [--guard-window 4] [--domain-id N] [--log-dir DIR] [--seed 0] [--json]

It starts the emulated WAM, BarrettHand and Net F/T drivers (``rrg_fake_hw.fake_hw_node``)
and the bridge (``rrg_hw_bridge.ros.bridge_node``) as ``rrg-launch --mode hw --fake-hw`` does:
the launcher's ``Graph`` starts only the arm/hand interface (``--domain-id``, default 98), with
the Net F/T boxes at ``rdt_addresses(domain)``. It waits until the bridge reports every
stream fresh on ``/rrg/bridge/status``, places the object (``/rrg/reset_sim``, arm home), and
measures the CPU use of both processes (``/proc/<pid>/stat``) over ``--idle`` seconds of plain
streaming. At each of ``--rdt-rates`` it sets the boxes' RDT rate through comm.cgi and measures,
during ``--guard-window`` seconds of a guarded move without contact (the guard checks every
record), the records the bridge receives and the CPU its receive threads spend per record
(``HwBench.guard_cost``). Then, with the boxes back at 1 kHz, per trial:

1. a slow guarded move from the arm's measured configuration (``stop_on_contact``, tip
   threshold SENSING.tip_force_threshold): J1 turns by MOVE_J1 rad on a minimum-jerk profile
   over MOVE_S seconds, about 4 cm of hand motion, clear of the table and the object;
2. while it runs (after a random 0.3-1.2 s), one parameter call to the fake arms the boxes'
   first crossing of the tip threshold (``bench.crossing_threshold``) and adds ``--force``
   newtons to fingertip 1 (``fault.extra_force``); the bridge must trip on it and cancel the
   controller's goal;
3. the latency is the fake's ``cancel_received`` instant minus its ``first_crossing`` instant
   (both ``time.monotonic()`` on the machine, published on ``/fake_hw/events``): from the
   emulated sensor sending the first record over the threshold to the cancel reaching the
   emulated controller: the UDP hop, the RDT decode, the guard and the action cancel;
4. the fault is cleared and the arm moves back (a move without contact stop; a refusal, e.g.
   the watchdog's on a loaded machine, is retried and listed as an incident).

A trial fails when the move does not stop on that contact or stops before the force is applied.
It prints the median and p99 latency against LATENCY_MEDIAN_TARGET_MS and
LATENCY_P99_TARGET_MS, each Net F/T box's receive rate
at the bridge (``/rrg/bridge/status``: median and lowest second during the trials, idle median)
and the records it lost, against RATE_TARGET_HZ, the CPU use of both processes, streaming idle
and during the trials [% of one core], with the benchmark's own and everything else's on the
machine (it warns when other work is busy), and the load average.
With ``--json`` the last line is one JSON object: ``latency_median_ms``, ``latency_p99_ms``,
``latency_max_ms``, ``latency_ms`` (per trial), ``rdt_rate_hz``, ``rdt_rate_min_hz`` and
``rdt_rate_idle_hz`` (per box), ``lost`` (per box, during the trials), ``trials``, ``failed``,
``failures``, ``cpu``, ``guard_cost``, ``incidents``,
``load_average`` and the settings. Exit status 1 when a
trial failed or the processes could not be run.

Ctrl-C (or SIGTERM) stops both processes as rrg-launch stops its graph: SIGINT, then SIGTERM
and SIGKILL.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from builtin_interfaces.msg import Duration
from diagnostic_msgs.msg import DiagnosticStatus
from rcl_interfaces.srv import SetParameters
from rclpy.action import ActionClient
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from tqdm import tqdm
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from rrg_bringup.graph import FAKE_NETFT_HTTP_PORT, Graph, rdt_addresses
from rrg_bringup.supervisor import LaunchError, ros_environment
from rrg_common.ros.msg_conversions import ARM_JOINT_NAMES, planar_to_msg
from rrg_hw_bridge.config import BRIDGE as BRIDGE_DEFAULTS
from rrg_hw_bridge.rdt import set_box_rdt_rate
from rrg_models.config import SENSING, SENSOR_NAMES, WORLD
from rrg_msgs.action import GuardedMove
from rrg_msgs.srv import ResetSim

#: Targets [ms] of the wrench crossing → cancel at the controller latency: its median and p99.
LATENCY_MEDIAN_TARGET_MS = 5.0
LATENCY_P99_TARGET_MS = 10.0
RATE_TARGET_HZ = 1000.0  # the target: every Net F/T box streaming at ≥ 1 kHz
#: The bridge counts a box's records over a 1 s window, so a steady 1 kHz stream reads 995-1005
#: Hz: the median rate meets the target within this fraction.
RATE_COUNT_TOL = 0.005
#: Turn of J1 [rad] of the guarded move: ~4 cm of hand motion at home (hand 0.45 m from the base
#: axis), over MOVE_S [s], on VIA_POINTS via-points of a minimum-jerk profile.
MOVE_J1 = 0.09
MOVE_S = 2.0
VIA_POINTS = 20
#: The move back after a trial [s] (no contact stop: the fault is cleared first).
BACK_S = 1.5
#: The fault appears this long after the move starts [s], uniformly at random (seeded).
FAULT_DELAY_S = (0.3, 1.2)
#: The two processes (rrg-launch's names).
FAKE, BRIDGE = "fake_hw", "hw_bridge"
#: Pause [s] after the move back, before the next trial's tare.
SETTLE_S = 0.2
#: Other work on the machine using more than this [% of a core] while the boxes stream idle
#: earns a warning (2-core machine: the two processes take ~80 %).
BUSY_OTHER_PCT = 20.0
#: Tries of the move back, and the pause between them [s].
BACK_ATTEMPTS = 3
BACK_RETRY_S = 0.5
BOXES = ("fingertip1", "fingertip2", "fingertip3")
#: After the boxes' RDT rate changes, the bridge's 1 s rate window refills for this long [s].
RATE_SETTLE_S = 1.5
_BOX_STATUS = re.compile(r"([\d.]+) Hz, (\d+) lost")
_BOX_CPU = re.compile(r"([\d.]+) µs CPU/record")


def cpu_seconds(pid: int) -> float:
    """User + system CPU time [s] of process ``pid``, all its threads (/proc/<pid>/stat)."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def all_cpu_seconds() -> dict[int, float]:
    """CPU time [s] of every process on the machine (those that end while read are skipped)."""
    out = {}
    for name in os.listdir("/proc"):
        if name.isdigit():
            try:
                out[int(name)] = cpu_seconds(int(name))
            except (OSError, IndexError, ValueError):
                pass
    return out


class CpuMeter:
    """CPU use [% of one core] between start() and stop() of some processes, of this one
    ('benchmark') and of every other process on the machine ('other': those that started in
    between count whole, those that ended are missed)."""

    def __init__(self, pids: dict[str, int]):
        self.pids = {**pids, "benchmark": os.getpid()}
        self._t0 = 0.0
        self._cpu0: dict[int, float] = {}

    def start(self) -> None:
        self._t0 = time.monotonic()
        self._cpu0 = all_cpu_seconds()

    def stop(self) -> dict[str, float]:
        wall = time.monotonic() - self._t0
        used = {pid: cpu - self._cpu0.get(pid, 0.0) for pid, cpu in all_cpu_seconds().items()}
        ours = {k: used.get(p, 0.0) for k, p in self.pids.items()}
        other = sum(u for pid, u in used.items() if pid not in self.pids.values())
        return {k: 100.0 * v / wall for k, v in {**ours, "other": other}.items()}


def min_jerk(q0: np.ndarray, q1: np.ndarray, duration: float, n: int):
    """n via-points (n,7) and their times (n,) [s] of a rest-to-rest minimum-jerk move from q0
    (not included) to q1."""
    tau = np.arange(1, n + 1) / n
    s = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
    return q0 + s[:, None] * (q1 - q0), tau * duration


def guarded_goal(q: np.ndarray, t: np.ndarray, stop_on_contact: bool) -> GuardedMove.Goal:
    traj = JointTrajectory(joint_names=list(ARM_JOINT_NAMES))
    for qk, tk in zip(q, t):
        sec = int(tk)
        traj.points.append(
            JointTrajectoryPoint(
                positions=[float(x) for x in qk],
                time_from_start=Duration(sec=sec, nanosec=int(round((tk - sec) * 1e9))),
            )
        )
    return GuardedMove.Goal(
        trajectory=traj,
        stop_on_contact=stop_on_contact,
        tip_force_threshold=SENSING.tip_force_threshold,
        pad_force_threshold=0.0,
    )


@dataclass
class Observed:
    """What the benchmark's node has heard: the fake's events, the bridge's status, the arm."""

    events: list[tuple[str, float, dict[str, str]]] = field(default_factory=list)
    status: list[tuple[float, str, dict[str, str]]] = field(default_factory=list)
    arm_q: np.ndarray | None = None

    def on_event(self, msg) -> None:
        values = {v.key: v.value for v in msg.values}
        self.events.append((msg.name, float(values.get("time", "nan")), values))

    def on_status(self, msg) -> None:
        self.status.append((time.monotonic(), msg.message, {v.key: v.value for v in msg.values}))

    def on_joints(self, msg) -> None:
        index = {n: i for i, n in enumerate(msg.name)}
        if all(n in index for n in ARM_JOINT_NAMES):
            self.arm_q = np.array([msg.position[index[n]] for n in ARM_JOINT_NAMES])

    def first(self, name: str, since: float) -> float | None:
        """The earliest instant of a ``name`` event at or after ``since`` (monotonic [s])."""
        times = [t for n, t, _ in self.events if n == name and t >= since]
        return min(times) if times else None


def box_figures(status: list[dict[str, str]]) -> dict[str, tuple[list[float], list[int]]]:
    """Per box, the receive rates [Hz] and the lost-record counts of bridge status messages."""
    out: dict[str, tuple[list[float], list[int]]] = {b: ([], []) for b in BOXES}
    for values in status:
        for b in BOXES:
            m = _BOX_STATUS.match(values.get(b, ""))
            if m:
                out[b][0].append(float(m.group(1)))
                out[b][1].append(int(m.group(2)))
    return out


class HwBench:
    """The emulated drivers and the bridge (rrg-launch's Graph, interface 'fake_hw'), and the
    benchmark's own subscriptions and clients on the graph's node."""

    def __init__(self, domain_id: int, log_dir: Path):
        self.domain_id = domain_id
        # a process that dies ends the benchmark (no restarts)
        self.graph = Graph(ros_environment(domain_id), None, log_dir, "fake_hw", respawn_max=0)
        self.obs = Observed()
        self.incidents: list[str] = []  # what went wrong outside the measurements

    def start(self, seed: int) -> None:
        """Start the emulated drivers and the bridge, and the benchmark's node."""
        self.graph.start_interface("powerdrill", seed)
        self.graph.connect()
        node = self.graph.node
        node.create_subscription(DiagnosticStatus, "/fake_hw/events", self.obs.on_event, 100)
        node.create_subscription(DiagnosticStatus, "/rrg/bridge/status", self.obs.on_status, 10)
        node.create_subscription(JointState, "/rrg/joint_states", self.obs.on_joints, 10)
        self.move = ActionClient(node, GuardedMove, "/rrg/guarded_move")
        self.params = node.create_client(SetParameters, "/fake_hw/set_parameters")
        self.reset = node.create_client(ResetSim, "/rrg/reset_sim")

    def stop(self) -> None:
        self.graph.disconnect()
        self.graph.stop()

    def spin_until(self, condition, timeout_s: float, what: str) -> None:
        self.graph.spin_until(condition, timeout_s, what)

    def result(self, future, timeout_s: float, what: str):
        return self.graph.result(future, timeout_s, what)

    def wait(self, seconds: float) -> None:
        """Spin for ``seconds``."""
        end = time.monotonic() + seconds
        self.spin_until(lambda: time.monotonic() >= end, seconds + 5.0, "time to pass")

    def wait_ready(self, timeout_s: float) -> float:
        """Wait for the servers, place the object (arm home), then for a 'ready' bridge status
        with every box streaming; returns the seconds since the start."""
        deadline = time.monotonic() + timeout_s
        left = lambda: deadline - time.monotonic()
        self.spin_until(self.move.server_is_ready, left(), "/rrg/guarded_move")
        self.spin_until(self.params.service_is_ready, left(), "/fake_hw/set_parameters")
        self.spin_until(self.reset.service_is_ready, left(), "/rrg/reset_sim")
        req = ResetSim.Request(object_name="powerdrill", pose=planar_to_msg(WORLD.nominal_pose))
        answer = self.result(self.reset.call_async(req), left(), "reset_sim")
        if answer.error_code != ResetSim.Response.NONE:
            raise LaunchError(f"reset_sim failed: {answer.error_msg}")
        since = time.monotonic()

        def ready() -> bool:
            for t, message, values in self.obs.status:
                if t > since and message == "ready" and self.obs.arm_q is not None:
                    rates = box_figures([values])
                    if all(r and r[0] > 0 for r, _ in rates.values()):
                        return True
            return False

        self.spin_until(ready, left(), "a 'ready' status of the bridge with every box streaming")
        return time.monotonic() - self.graph.started

    def set_params(self, values: dict[str, object]) -> None:
        """Set run-time parameters of the fake, in this order, in one call."""
        req = SetParameters.Request(
            parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in values.items()]
        )
        answer = self.result(self.params.call_async(req), 10.0, "set_parameters")
        bad = [r.reason for r in answer.results if not r.successful]
        if bad:
            raise LaunchError(f"the fake refused {values}: {'; '.join(bad)}")

    def run_move(self, q_to: np.ndarray, duration: float, stop_on_contact: bool, during=None):
        """A guarded move from the measured configuration to q_to; ``during()`` is called once
        while it runs. Returns the result."""
        q, t = min_jerk(self.obs.arm_q.copy(), q_to, duration, VIA_POINTS)
        handle = self.result(
            self.move.send_goal_async(guarded_goal(q, t, stop_on_contact)), 10.0, "guarded_move"
        )
        if not handle.accepted:
            raise LaunchError("the bridge rejected the guarded move")
        future = handle.get_result_async()
        if during is not None:
            during()
        return self.result(future, duration + 15.0, "the guarded move's result").result

    def trial(self, q_home: np.ndarray, force: float, delay: float) -> tuple[float | None, str]:
        """One trial: (latency [ms], or None when it failed; what went wrong)."""
        armed = [np.inf]

        def fault() -> None:
            self.wait(delay)
            armed[0] = time.monotonic()
            self.set_params(
                {
                    "bench.crossing_threshold": SENSING.tip_force_threshold,
                    "fault.extra_force": force,
                }
            )

        q_to = q_home.copy()
        q_to[0] += MOVE_J1
        problem, latency = "", None
        sent = time.monotonic()
        try:
            result = self.run_move(q_to, MOVE_S, True, fault)
            fired = [n for n, f in zip(SENSOR_NAMES, result.sensors) if f]
            stop = f"at {result.path_fraction:.2f} of the path, sensors fired: {fired}"
            early = self.obs.first("cancel_received", sent)
            if result.error_code != GuardedMove.Result.NONE:
                problem = f"guarded move error {result.error_code}: {result.error_msg}"
            elif not result.stopped_on_contact:
                problem = "the guarded move did not stop on the contact"
            elif early is not None and early < armed[0]:
                problem = f"the move stopped before the force was applied ({stop})"
            got = lambda: (
                self.obs.first("first_crossing", armed[0]) is not None
                and self.obs.first("cancel_received", armed[0]) is not None
            )
            if not problem:
                self.spin_until(got, 3.0, "the fake's first_crossing and cancel_received events")
                crossing = self.obs.first("first_crossing", armed[0])
                latency = (self.obs.first("cancel_received", armed[0]) - crossing) * 1e3
        except LaunchError as exc:  # a failed trial is recorded, the run goes on
            self.graph.supervise()
            problem = problem or str(exc)
        finally:
            self.set_params({"fault.extra_force": 0.0, "bench.crossing_threshold": 0.0})
        self.move_back(q_home)
        return (None if problem else latency), problem

    def set_rdt_rate(self, rate_hz: float) -> None:
        """Set every emulated box's RDT rate [Hz] through comm.cgi, as a lab would; then wait
        until the bridge's 1 s rate window has refilled."""
        for host in rdt_addresses(self.domain_id):
            config = set_box_rdt_rate(host, FAKE_NETFT_HTTP_PORT, rate_hz)
            if config.rdt_rate_hz < rate_hz:
                raise LaunchError(f"the box at {host} took {config.rdt_rate_hz:g} Hz")
        self.wait(RATE_SETTLE_S)

    def guard_cost(
        self, q_home: np.ndarray, rate_hz: float, window_s: float, pids: dict[str, int]
    ) -> dict[str, float]:
        """The bridge's CPU while its guard checks every record: the boxes set to ``rate_hz``
        through comm.cgi (as a lab would), then a guarded move without contact during which
        the processes' CPU and the records the bridge receives are measured over ``window_s``.
        Returns the rate set, the records received per second (all boxes), the CPU [% of a
        core] of each process and the median CPU [µs] the bridge's receive threads spent per
        record (their thread clocks, in the bridge's status: decode and guard), which other
        work competing for the cores does not inflate."""
        self.set_rdt_rate(rate_hz)
        figures: dict[str, float] = {"rate_set_hz": rate_hz}

        def measure() -> None:
            self.wait(0.3)  # the move is under way
            meter = CpuMeter(pids)
            meter.start()
            since = time.monotonic()
            self.wait(window_s)
            cpu = meter.stop()
            # each status counts the second before it: those wholly inside the window
            values = [v for t, _, v in self.obs.status if since + 1.0 < t <= since + window_s]
            received = sum(
                statistics.mean(r) if r else 0.0 for r, _ in box_figures(values).values()
            )
            per_record = [
                float(m.group(1))
                for v in values
                for b in BOXES
                if (m := _BOX_CPU.search(v.get(b, "")))
            ]
            figures.update({f"cpu_{k}_pct": v for k, v in cpu.items()})
            figures["records_per_s"] = received
            figures["guard_us_per_record"] = (
                statistics.median(per_record) if per_record else float("nan")
            )

        q_to = q_home.copy()
        q_to[0] += MOVE_J1
        result = self.run_move(q_to, window_s + 1.0, True, measure)
        if result.error_code != GuardedMove.Result.NONE or result.stopped_on_contact:
            self.incidents.append(
                f"the {rate_hz:g} Hz guard-cost move ended with {result.error_code} "
                f"{result.error_msg!r} (stopped on contact: {result.stopped_on_contact})"
            )
        self.move_back(q_home)
        return figures

    def move_back(self, q_home: np.ndarray) -> None:
        """Back to where the trials start (the tips unloaded before the next tare). A refusal
        (e.g. the watchdog's, on a loaded machine) is noted and the move tried again; the next
        trial starts from wherever the arm is anyway."""
        for _ in range(BACK_ATTEMPTS):
            back = self.run_move(q_home, BACK_S, False)
            if back.error_code == GuardedMove.Result.NONE:
                break
            self.incidents.append(f"move back refused ({back.error_code}): {back.error_msg}")
            self.wait(BACK_RETRY_S)
        self.wait(SETTLE_S)


def finite_or_none(x):
    """x with every non-finite float replaced by None (strict JSON has no NaN)."""
    if isinstance(x, dict):
        return {k: finite_or_none(v) for k, v in x.items()}
    if isinstance(x, list):
        return [finite_or_none(v) for v in x]
    return None if isinstance(x, float) and not np.isfinite(x) else x


def percentile(values: list[float], p: float) -> float:
    return float(np.percentile(values, p)) if values else float("nan")


def bench_hw(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(
        prog="rrg-bench hw",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--trials", type=int, default=50)
    ap.add_argument(
        "--force", type=float, default=2.0, help="force [N] added to fingertip 1 in each trial"
    )
    ap.add_argument("--idle", type=float, default=5.0, help="seconds of idle streaming timed")
    ap.add_argument(
        "--rdt-rates",
        default="1000,3000,7000",
        help="RDT rates [Hz] at which the guard's CPU per record is measured, comma-separated "
        "(empty: not measured)",
    )
    ap.add_argument(
        "--guard-window", type=float, default=4.0, help="seconds of guarded move timed per rate"
    )
    ap.add_argument("--domain-id", type=int, default=98, help="DDS domain of the processes")
    ap.add_argument("--log-dir", type=Path, help="keep the two processes' logs here")
    ap.add_argument("--seed", type=int, default=0, help="seeds the sensor noise and fault delays")
    ap.add_argument(
        "--json", action="store_true", help="print the figures as JSON on the last line"
    )
    args = ap.parse_args(argv)
    try:
        args.rdt_rates = [float(r) for r in args.rdt_rates.split(",") if r.strip()]
    except ValueError:
        ap.error(f"--rdt-rates must be numbers separated by commas, got {args.rdt_rates!r}")
    if any(not 1.0 <= r <= 7000.0 for r in args.rdt_rates):
        ap.error("each --rdt-rates value must be within 1-7000 Hz (the Net F/T's range)")
    if args.trials < 1 or not (
        SENSING.tip_force_threshold < args.force < BRIDGE_DEFAULTS.force_ceiling
    ):
        ap.error("--trials must be ≥ 1 and --force between the tip threshold and the ceiling")

    return run_bench(args)


@dataclass
class HwRun:
    """What one run of the hardware benchmark measured."""

    latencies: list[float] = field(default_factory=list)  # ms, crossing → cancel
    problems: list[str] = field(default_factory=list)  # failed trials
    cpu: dict[str, dict[str, float]] = field(default_factory=dict)  # % of a core
    guard: list[dict[str, float]] = field(default_factory=list)  # per RDT rate (guard_cost)
    idle_status: list = field(default_factory=list)  # bridge status while streaming idle
    status: list = field(default_factory=list)  # bridge status during the trials


def run_bench(args: argparse.Namespace) -> int:
    load_before = os.getloadavg()[0]
    run = HwRun()
    with tempfile.TemporaryDirectory(prefix="rrg_bench_hw_") as tmp:
        log_dir = args.log_dir or Path(tmp) / "logs"
        bench = HwBench(args.domain_id, log_dir)

        def interrupt(signum, _frame):  # Ctrl-C or SIGTERM: acted on in Graph.spin_until
            bench.graph.interrupted = True

        signal.signal(signal.SIGTERM, interrupt)
        signal.signal(signal.SIGINT, interrupt)
        try:
            measure(bench, args, run)
        except KeyboardInterrupt:
            print("[hw] interrupted: stopping the processes", flush=True)
            return 1
        except LaunchError as exc:
            print(f"[hw] error: {exc} (logs in {log_dir})", file=sys.stderr, flush=True)
            return 1
        finally:
            signal.signal(signal.SIGINT, signal.SIG_IGN)  # a second Ctrl-C must not cut it short
            bench.stop()
            signal.signal(signal.SIGINT, signal.default_int_handler)
    out = figures(run, args, bench.incidents, load_before)
    print_table(out, run, args)
    if args.json:
        print(json.dumps(finite_or_none(out)))
    return 0 if not run.problems else 1


def measure(bench: HwBench, args: argparse.Namespace, run: HwRun) -> None:
    """Start the emulated drivers and the bridge, measure the idle stream and the guard's cost
    per RDT rate, then the trials; fills ``run``."""
    rng = np.random.default_rng(args.seed)
    obs = bench.obs
    bench.start(args.seed)
    print(f"[hw] emulated drivers and bridge in DDS domain {args.domain_id}", flush=True)
    ready_s = bench.wait_ready(120.0)
    print(f"[hw] bridge ready after {ready_s:.1f} s", flush=True)
    pids = {c.name: c.proc.pid for c in bench.graph.children}
    meter = CpuMeter(pids)
    meter.start()
    idle_start = time.monotonic()
    bench.wait(args.idle)
    idle = meter.stop()
    print(
        "[hw] CPU while streaming idle [% of a core]: "
        + ", ".join(f"{k} {v:.0f} %" for k, v in idle.items()),
        flush=True,
    )
    if idle["other"] > BUSY_OTHER_PCT:
        print(
            f"[hw] warning: other work on the machine uses {idle['other']:.0f} % of a "
            f"core ({os.cpu_count()} cores): the latencies and rates will show it",
            flush=True,
        )
    q_home = obs.arm_q.copy()
    run.idle_status = [v for t, _, v in obs.status if t > idle_start + 1.0]
    for rate in args.rdt_rates:
        cost = bench.guard_cost(q_home, rate, args.guard_window, pids)
        run.guard.append(cost)
        print(
            f"[hw] boxes at {rate:.0f} Hz, guarded move: the bridge receives "
            f"{cost['records_per_s']:.0f} records/s, {cost['guard_us_per_record']:.1f} "
            f"µs CPU per record, {cost[f'cpu_{BRIDGE}_pct']:.0f} % of a core in all",
            flush=True,
        )
    if args.rdt_rates:  # the trials at the boxes' 1 kHz
        bench.set_rdt_rate(RATE_TARGET_HZ)
    first_status = len(obs.status)
    meter.start()
    bar = tqdm(range(args.trials), desc="[hw] trials", unit="trial", file=sys.stderr)
    for _ in bar:
        delay = float(rng.uniform(*FAULT_DELAY_S))
        latency, problem = bench.trial(q_home, args.force, delay)
        if latency is None:
            run.problems.append(problem)
            tqdm.write(f"[hw] trial failed: {problem}", file=sys.stderr)
        else:
            run.latencies.append(latency)
            bar.set_postfix(latency=f"{latency:.2f} ms")
    bar.close()
    busy = meter.stop()
    run.cpu = {k: {"idle_pct": idle[k], "trials_pct": busy[k]} for k in idle}
    run.status = [values for _, _, values in obs.status[first_status:]]


def figures(run: HwRun, args: argparse.Namespace, incidents: list, load_before: float) -> dict:
    """The benchmark's figures (the --json object)."""
    latencies = run.latencies
    median = lambda r: statistics.median(r) if r else float("nan")
    rate_idle = {b: median(r) for b, (r, _) in box_figures(run.idle_status).items()}
    boxes = box_figures(run.status)
    med, p99 = (
        (statistics.median(latencies), percentile(latencies, 99))
        if latencies
        else (float("nan"), float("nan"))
    )
    return {
        "latency_median_ms": med,
        "latency_p99_ms": p99,
        "latency_max_ms": max(latencies) if latencies else float("nan"),
        "latency_ms": [round(x, 4) for x in latencies],
        "rdt_rate_hz": {b: median(r) for b, (r, _) in boxes.items()},
        "rdt_rate_min_hz": {b: min(r) if r else float("nan") for b, (r, _) in boxes.items()},
        "rdt_rate_idle_hz": rate_idle,
        "lost": {b: (n[-1] - n[0]) if n else None for b, (_, n) in boxes.items()},
        "lost_since_start": {b: n[-1] if n else None for b, (_, n) in boxes.items()},
        "trials": args.trials,
        "failed": len(run.problems),
        "failures": run.problems,
        "cpu": run.cpu,
        "guard_cost": run.guard,
        "force_n": args.force,
        "threshold_n": SENSING.tip_force_threshold,
        "incidents": incidents,
        "load_average": [load_before, os.getloadavg()[0]],
        "domain_id": args.domain_id,
    }


def print_table(out: dict, run: HwRun, args: argparse.Namespace) -> None:
    """The figures against their targets, as a Markdown table."""
    med, p99 = out["latency_median_ms"], out["latency_p99_ms"]
    rate, rate_min, lost = out["rdt_rate_hz"], out["rdt_rate_min_hz"], out["lost"]
    ok = lambda good: "met" if good else "MISSED"
    print("\n| figure | value | target |")
    print("|---|---|---|")
    print(
        f"| crossing → cancel at the controller, median of {len(run.latencies)} "
        f"| {med:.2f} ms | ≤ {LATENCY_MEDIAN_TARGET_MS:.0f} ms "
        f"({ok(med <= LATENCY_MEDIAN_TARGET_MS)}) |"
    )
    print(
        f"| crossing → cancel at the controller, p99 (max {out['latency_max_ms']:.2f} ms) "
        f"| {p99:.2f} ms | ≤ {LATENCY_P99_TARGET_MS:.0f} ms ({ok(p99 <= LATENCY_P99_TARGET_MS)}) |"
    )
    for b in BOXES:
        met = rate[b] >= RATE_TARGET_HZ * (1.0 - RATE_COUNT_TOL)
        print(
            f"| {b}'s Net F/T at the bridge during the trials: median rate (lowest second), "
            f"records lost; idle median | {rate[b]:.0f} Hz ({rate_min[b]:.0f} Hz), {lost[b]} lost; "
            f"{out['rdt_rate_idle_hz'][b]:.0f} Hz | ≥ {RATE_TARGET_HZ:.0f} Hz ({ok(met)}) |"
        )
    for k, v in run.cpu.items():
        what = {"other": "other work on the machine", "benchmark": "the benchmark's own node"}
        print(
            f"| CPU of {what.get(k, k)}, streaming idle / during the trials "
            f"| {v['idle_pct']:.0f} % / {v['trials_pct']:.0f} % of a core | – |"
        )
    for g in run.guard:
        print(
            f"| the bridge with the boxes at {g['rate_set_hz']:.0f} Hz during a guarded move: "
            f"records received (all boxes), CPU per record of its receive threads (decode and "
            f"guard), its whole CPU | {g['records_per_s']:.0f} /s, "
            f"{g['guard_us_per_record']:.1f} µs, {g[f'cpu_{BRIDGE}_pct']:.0f} % of a core | – |"
        )
    if run.problems:
        print(f"| failed trials | {len(run.problems)} of {args.trials} | 0 |")
    if out["incidents"]:
        print(f"| incidents outside the measurements | {len(out['incidents'])} | 0 |")
    print(
        f"| load average (1 min) before / after | {out['load_average'][0]:.1f} / "
        f"{out['load_average'][1]:.1f} on {os.cpu_count()} cores | – |"
    )


if __name__ == "__main__":
    sys.exit(bench_hw(sys.argv[1:]))
