"""``rrg-launch``: start RRG's ROS 2 graph as child processes, record every topic, and optionally
run one robust grasp, or many back to back (operations §8).

    rrg-launch                                      # the simulated graph, until Ctrl-C
    rrg-launch --grasp powerdrill --level high --strategy rrg-info
    rrg-launch --grasps 200 --seed 1                # a long run: 200 grasps in one graph (soak.py)
    rrg-launch --mode hw --fake-hw --grasp powerdrill   # the bridge on emulated drivers
    rrg-launch --mode hw --hw-param dry_run:=true       # the bridge on the real robot's drivers

Children: the arm/hand interface (the simulator node in sim mode; in hw mode the hardware bridge,
and with ``--fake-hw`` the emulated WAM, BarrettHand and Net F/T drivers driven by MuJoCo), the
executor, the estimator, the planner and the bag recorder, each in its own process and session, on
loopback (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) in DDS domain ``--domain-id``. Readiness is
waited for, not slept: every service and action server must answer discovery, and the recorder must
be subscribed to every topic that has a publisher. With ``--grasp`` the simulator places the object
at its true pose (``--true-pose``, or drawn from the level's Gaussian with ``--seed``), the
planner's robust-grasp action runs with feedback per step, and the simulator judges the final grasp
(ground truth + lift). With ``--grasps N`` it runs N robust grasps back to back in the same
graph, each of an object and a true pose drawn from ``--seed``, and reports each grasp, each
node's memory, threads and file descriptors, and the event messages the bag lost
(rrg_bringup.soak). Ctrl-C (or SIGTERM) cancels a running grasp, sends SIGINT to the nodes,
escalates to SIGTERM and SIGKILL after a timeout, and stops the recorder last, so the bag in
``bags/<name>/`` is always finalized. A child that dies while the graph runs is restarted, as
launch_ros's ``respawn`` does: up to ``--respawn-max`` times, after a backoff that starts at
``--respawn-delay`` and doubles; a restarted recorder writes the bag's next split. Each exit and
restart is logged and published on ``/rrg/launch/node_events`` (rrg_msgs/NodeEvent), so the bag
records it; when a child has used up its restarts the launcher stops the graph.

Exit status: 0 when the graph ran (and the grasp, if asked for, was executed and judged,
whatever its outcome), 1 on an error (a child that died more often than ``--respawn-max``
allows, too), 2 on a usage error. On the real robot (``--mode hw`` without ``--fake-hw``)
nothing can place or judge the object: ``--grasp`` runs the robust grasp on the object as it
stands and reports the planner's belief only.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import sys
import time
from dataclasses import asdict
from datetime import datetime
from pathlib import Path

import numpy as np

from rrg_bringup.graph import (
    GRASP_TIMEOUT_S,
    ROOT,
    STATE_ROOT,
    Graph,
    GraspOutcome,
    draw_pose,
    warm_tables,
)
from rrg_bringup.supervisor import (
    DISCOVERY_RANGES,
    RESPAWN_DELAY_MAX_S,
    RESPAWN_DELAY_S,
    RESPAWN_MAX,
    LaunchError,
    ros_environment,
)
from rrg_estimator.config import LEVELS
from rrg_models.objects import PAPER_OBJECTS, object_names
from rrg_planner.config import SEARCH
from rrg_planner.request_checks import STRATEGIES
from rrg_sim.config import WORLD_PROFILES, world_spec


def hw_param(text: str) -> tuple[str, str]:
    """'name:=value' → (name, value) (argparse type of --hw-param)."""
    name, sep, value = text.partition(":=")
    if not sep or not name:
        raise argparse.ArgumentTypeError(f"expected NAME:=VALUE, got {text!r}")
    return name, value


def true_pose(args: argparse.Namespace) -> np.ndarray:
    """--true-pose, else a draw from the level's Gaussian around the nominal pose (--seed)."""
    if args.true_pose is not None:
        return np.asarray(args.true_pose, dtype=float)
    return draw_pose(np.random.default_rng(args.seed), args.level)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="rrg-launch", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    _add_graph_arguments(p)
    _add_run_arguments(p)
    _add_grasp_arguments(p)
    _add_output_arguments(p)
    return p


def _add_graph_arguments(p: argparse.ArgumentParser) -> None:
    """How the graph runs: the simulator or the bridge, and DDS."""
    p.add_argument(
        "--mode",
        choices=("sim", "hw"),
        default="sim",
        help="arm/hand interface: simulator or hardware",
    )
    p.add_argument(
        "--fake-hw",
        action="store_true",
        help="with --mode hw: also start the emulated drivers (MuJoCo behind the real protocols)",
    )
    p.add_argument(
        "--hw-param",
        type=hw_param,
        action="append",
        default=[],
        metavar="NAME:=VALUE",
        help="a parameter of the hardware bridge (repeatable), e.g. dry_run:=true, "
        "limits_file:=my_wam.yaml, speed_scale:=0.5",
    )
    p.add_argument(
        "--hw-params",
        type=Path,
        metavar="FILE",
        help="a ROS 2 parameters YAML of the hardware bridge (node /rrg/hw_bridge, or /**); "
        "--hw-param values override it",
    )
    p.add_argument(
        "--discovery-range",
        choices=DISCOVERY_RANGES,
        default="LOCALHOST",
        help="ROS_AUTOMATIC_DISCOVERY_RANGE of the graph: LOCALHOST (default) keeps it on this "
        "host; a robot's drivers on another host need SUBNET, or OFF with --static-peers. DDS "
        "is unauthenticated: use a dedicated network (or SROS2)",
    )
    p.add_argument(
        "--static-peers",
        default="",
        metavar="HOSTS",
        help="ROS_STATIC_PEERS: ';'-separated addresses of the hosts to discover (the WAM's PC)",
    )
    p.add_argument(
        "--domain-id",
        type=int,
        default=int(os.environ.get("ROS_DOMAIN_ID", "0") or 0),
        help="ROS_DOMAIN_ID of the graph (0-101; default: $ROS_DOMAIN_ID or 0)",
    )


def _add_run_arguments(p: argparse.ArgumentParser) -> None:
    """What the run does: the graph alone, one grasp, or many."""
    p.add_argument(
        "--object",
        default="powerdrill",
        choices=object_names(),
        help="object the simulator starts with (--grasp overrides it)",
    )
    p.add_argument(
        "--grasp",
        metavar="OBJECT",
        choices=object_names(),
        help="run one robust grasp of OBJECT, then stop",
    )
    p.add_argument(
        "--grasps",
        type=int,
        metavar="N",
        help="a long run: N robust grasps back to back in one graph, each of an object and a "
        "true pose drawn from --seed; then a report of every grasp and node",
    )
    p.add_argument(
        "--objects",
        default=",".join(PAPER_OBJECTS),
        help="with --grasps: the objects grasped, comma-separated (default: the paper's ten)",
    )
    p.add_argument(
        "--grasp-timeout",
        type=float,
        default=GRASP_TIMEOUT_S,
        metavar="S",
        help=f"with --grasps: a grasp still running after S seconds ({GRASP_TIMEOUT_S:.0f}) is "
        "hung; the run stops",
    )
    p.add_argument(
        "--soak-report",
        type=Path,
        metavar="PATH",
        help="with --grasps: the JSON report (default: beside the bag, <bag>_soak.json)",
    )


def _add_grasp_arguments(p: argparse.ArgumentParser) -> None:
    """The grasp and the simulated world."""
    p.add_argument(
        "--level", default="high", choices=sorted(LEVELS), help="initial uncertainty of the grasp"
    )
    p.add_argument("--strategy", default="rrg-info", choices=STRATEGIES)
    p.add_argument("--horizon", type=int, default=SEARCH.horizon, choices=(1, 2, 3))
    p.add_argument("--delta", type=float, default=SEARCH.delta)
    p.add_argument("--max-actions", type=int, default=SEARCH.max_actions)
    p.add_argument(
        "--true-pose",
        type=float,
        nargs=3,
        metavar=("X", "Y", "THETA"),
        help="the object's true pose [m, m, rad] (default: drawn from the level's Gaussian)",
    )
    p.add_argument(
        "--seed", type=int, default=0, help="seeds the true-pose draw and the sensor noise"
    )
    p.add_argument(
        "--levels",
        default=",".join(LEVELS),
        help="uncertainty levels the planner loads (variable resolution from high needs all three)",
    )
    p.add_argument(
        "--real-time-factor",
        type=float,
        default=0.0,
        help="simulator pacing: 1 = real time, 0 = as fast as it steps",
    )
    p.add_argument(
        "--sensor-noise",
        type=float,
        default=1.0,
        help="scale of the simulated sensors' noise (1 = config values, 0 = noiseless)",
    )
    p.add_argument(
        "--world",
        type=world_spec,
        default="nominal",
        help=f"the simulated world's profile ({', '.join(WORLD_PROFILES)}, or one with some "
        "numbers set: rrg_sim.config.world_profile; sim mode only)",
    )


def _add_output_arguments(p: argparse.ArgumentParser) -> None:
    """The bag, the logs, respawning and the answer."""
    p.add_argument("--bags", type=Path, default=ROOT / "bags", help="folder of the bags")
    p.add_argument("--bag-name", help="bag folder name (default: rrg_<object>_<time>)")
    p.add_argument("--no-bag", action="store_true", help="do not record")
    p.add_argument(
        "--log-dir",
        type=Path,
        help="write each child's output to LOG_DIR/<node>.log (default: stderr)",
    )
    p.add_argument(
        "--respawn-max",
        type=int,
        default=RESPAWN_MAX,
        metavar="N",
        help="restarts of a node that dies, per node, before the launcher stops the graph "
        "(0: none)",
    )
    p.add_argument(
        "--respawn-delay",
        type=float,
        default=RESPAWN_DELAY_S,
        metavar="S",
        help=f"wait before a node's first restart [s], doubled for each next one "
        f"(at most {RESPAWN_DELAY_MAX_S:.0f} s)",
    )
    p.add_argument(
        "--ready-timeout",
        type=float,
        default=600.0,
        help="longest wait for the graph [s] (a first table build takes minutes)",
    )
    p.add_argument(
        "--json",
        action="store_true",
        help="print the grasp's outcome (with --grasps: the summary) as JSON on the last line",
    )


def bags_writable(folder: Path, low_space_bytes: int | None = None) -> bool:
    """Whether bags can be written into ``folder`` (created when missing); prints why not, or a
    warning when less than ``low_space_bytes`` (default: bag_writer.LOW_SPACE_BYTES) are free."""
    from rrg_bags.bag_writer import LOW_SPACE_BYTES, probe_bag_folder

    try:
        free = probe_bag_folder(folder)
    except OSError as exc:
        print(f"rrg-launch: cannot write bags to {folder}: {exc.strerror or exc}", file=sys.stderr)
        return False
    if free < (LOW_SPACE_BYTES if low_space_bytes is None else low_space_bytes):
        print(
            f"rrg-launch: warning: {free / 2**20:.0f} MiB free for bags in {folder}; the "
            "recorder stops recording if the disk fills",
            file=sys.stderr,
        )
    return True


def usage_error(args: argparse.Namespace) -> str | None:
    """Why the arguments cannot run (exit status 2), or None; warns of a graph reachable
    beyond this host."""
    if args.mode == "sim" and (args.fake_hw or args.hw_param or args.hw_params):
        return "--fake-hw and --hw-param need --mode hw"
    if args.hw_params is not None and not args.hw_params.is_file():
        return f"--hw-params: no such file: {args.hw_params}"
    if args.discovery_range != "LOCALHOST" or args.static_peers:
        print(
            f"[rrg-launch] discovery range {args.discovery_range}"
            + (f", static peers {args.static_peers}" if args.static_peers else "")
            + ": the graph is reachable beyond this host, and DDS is unauthenticated; use a "
            "dedicated network, or SROS2",
            flush=True,
        )
    if not 0 <= args.domain_id <= 101:
        return f"--domain-id must be 0-101, got {args.domain_id}"
    if args.respawn_max < 0 or not args.respawn_delay >= 0:
        return "--respawn-max and --respawn-delay must be >= 0"
    return None


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    error = usage_error(args)
    if error is not None:
        print(f"rrg-launch: {error}", file=sys.stderr)
        return 2
    soak = None
    if args.grasps is not None:
        from rrg_bringup import soak as soaking

        try:
            soak = soaking.Soak.from_args(args)
        except ValueError as exc:
            print(f"rrg-launch: {exc}", file=sys.stderr)
            return 2
    label = "soak" if soak else (args.grasp or args.object)
    name = args.bag_name or f"rrg_{label}_{datetime.now():%Y%m%d_%H%M%S}"
    bag_dir = None if args.no_bag else args.bags / name
    if bag_dir is not None and bag_dir.exists():
        print(f"rrg-launch: bag folder already exists: {bag_dir}", file=sys.stderr)
        return 2
    if bag_dir is not None and not bags_writable(args.bags):
        return 2
    interface = "sim" if args.mode == "sim" else ("fake_hw" if args.fake_hw else "hw")
    state_dir = STATE_ROOT / f"{name}_{os.getpid()}"
    graph = Graph(
        ros_environment(args.domain_id, args.discovery_range, args.static_peers),
        bag_dir,
        args.log_dir,
        interface,
        args.respawn_max,
        args.respawn_delay,
        state_dir,
    )
    status, outcome = run(graph, args, soak, interface, bag_dir)
    report_bag(bag_dir)
    if soak is not None:
        soaking.finish(
            soak,
            bag_dir,
            args.soak_report or soaking.default_report_path(bag_dir, args.log_dir, name),
            args.json,
        )
    if outcome is not None:
        report_outcome(outcome, interface)
        if outcome.error:
            status = status or 1
        if args.json:
            print(json.dumps(asdict(outcome)), flush=True)
    return status


def run(graph: Graph, args: argparse.Namespace, soak, interface: str, bag_dir: Path | None):
    """Start the graph, run what the arguments ask, and stop it → (exit status, the grasp's
    outcome or None)."""

    def interrupt(signum, _frame):  # Ctrl-C or SIGTERM: the graph's spin loop raises
        graph.interrupted = True  # KeyboardInterrupt (raised inside rclpy's C++ it would turn
        # into a RuntimeError)

    object_name = soak.draws[0][0] if soak else args.grasp or args.object
    objects = soak.objects if soak else [object_name]
    levels = [lv.strip() for lv in args.levels.split(",") if lv.strip()]
    status, outcome = 0, None
    try:
        print(
            f"[rrg-launch] observation tables of {', '.join(objects)} at levels {levels} "
            "(built once, ~1 min per object and level when missing)",
            flush=True,
        )
        for obj in objects:
            warm_tables(obj, levels)
        signal.signal(
            signal.SIGTERM, interrupt
        )  # after the table workers, which must not inherit it
        # Ctrl-C stops the graph even if this process started with SIGINT ignored (a background
        # job of a non-interactive shell: Python keeps an inherited SIG_IGN), and the nodes
        # started next inherit the default instead of the ignore.
        signal.signal(signal.SIGINT, interrupt)
        graph.start(
            object_name,
            levels,
            args.seed,
            args.real_time_factor,
            args.sensor_noise,
            dict(args.hw_param),
            args.world,
            objects,
            args.hw_params.resolve() if args.hw_params else None,
        )
        graph.connect()
        if soak is not None:
            soak.attach(graph)
        wait_for_graph(graph, args, bag_dir)
        if interface == "hw" and (args.grasp or soak is not None):
            graph.wait_armed(args.ready_timeout)
        if soak is not None:
            status = soak.run(graph)
        elif args.grasp:
            outcome = grasp(graph, args, bag_dir)
        else:
            print("[rrg-launch] running; Ctrl-C stops the graph", flush=True)
            while True:
                graph.spin_until(lambda: False, float("inf"), "Ctrl-C")
    except KeyboardInterrupt:
        print("[rrg-launch] interrupted: stopping the graph", flush=True)
        graph.cancel_grasp()
        status = 1 if args.grasp or soak else 0
    except LaunchError as exc:
        print(f"[rrg-launch] error: {exc}", file=sys.stderr, flush=True)
        status = 1
    finally:
        signal.signal(
            signal.SIGINT, signal.SIG_IGN
        )  # a second Ctrl-C must not cut the shutdown short
        graph.disconnect()
        graph.stop()
        shutil.rmtree(graph.state_dir, ignore_errors=True)
        signal.signal(signal.SIGINT, signal.default_int_handler)
    return status, outcome


def wait_for_graph(graph: Graph, args: argparse.Namespace, bag_dir: Path | None) -> None:
    """Wait until every node of the started graph answers."""
    print(
        f"[rrg-launch] started {len(graph.children)} processes in domain {args.domain_id} ("
        + ", ".join(f"{c.name} pid {c.proc.pid}" for c in graph.children)
        + "); waiting for the graph (the planner loads its models first)",
        flush=True,
    )
    ready_s = graph.wait_ready(args.ready_timeout)
    print(
        f"[rrg-launch] graph ready after {ready_s:.1f} s"
        + (f", recording to {bag_dir}" if bag_dir else ""),
        flush=True,
    )


def grasp(graph: Graph, args: argparse.Namespace, bag_dir: Path | None) -> GraspOutcome:
    """One robust grasp of ``args.grasp`` on the running graph."""
    outcome = GraspOutcome(
        args.grasp,
        args.level,
        args.strategy,
        np.round(true_pose(args), 5).tolist(),
        bag=str(bag_dir or ""),
    )
    print(
        f"[rrg-launch] robust grasp of {args.grasp} "
        f"({args.level} uncertainty, {args.strategy}), true pose {outcome.true_pose}",
        flush=True,
    )

    def first_action() -> None:
        outcome.launch_to_first_action_s = time.monotonic() - graph.started

    graph.grasp(outcome, args.horizon, args.delta, args.max_actions, first_action)
    return outcome


def report_bag(bag_dir: Path | None) -> None:
    """What the run left in its bag (or that it left none)."""
    if bag_dir is not None and not Path(bag_dir).exists():
        print(f"[rrg-launch] no bag: stopped before the recorder started ({bag_dir})", flush=True)
    elif bag_dir is not None:
        from rrg_bags.bag_info import bag_info

        info = bag_info(bag_dir)
        print(
            f"[rrg-launch] bag {bag_dir}: {info.message_count} messages on "
            f"{len(info.topics)} topics in {len(info.files)} "
            f"{'file' if len(info.files) == 1 else 'files'}, "
            + (
                "finalized"
                if info.finalized
                else f"NOT finalized: {', '.join(p.name for p in info.unfinalized)} "
                "(read by scanning)"
            ),
            flush=True,
        )


def report_outcome(outcome: GraspOutcome, interface: str) -> None:
    """The grasp's outcome on one line."""
    print(
        f"[rrg-launch] outcome: actions {outcome.actions}, "
        f"P(goal) = {outcome.p_goal:.3f}, planner "
        f"{'succeeded' if outcome.planner_success else 'did not succeed'}; "
        + (
            f"simulator judged the grasp a {'SUCCESS' if outcome.success else 'FAILURE'}"
            if interface != "hw"
            else "not judged"
        )
        + (f" ({outcome.judge})" if outcome.judge else "")
        + (f"; {outcome.error}" if outcome.error else ""),
        flush=True,
    )


if __name__ == "__main__":
    sys.exit(main())
