"""``rrg-bench ros``: the ROS graph's own costs (speed is printed, never asserted in tests).

    rrg-bench ros [--object powerdrill] [--level high] [--calls 200] [--json]

1. **Launch to first action**: start the whole simulated graph as ``rrg-launch`` does (recorder
   included), wait until it is ready, place the object, send a robust-grasp goal, and time
   from the first process start to the planner's first feedback (the first action chosen and
   sent to the executor); the grasp is then cancelled. Planning models come from the on-disk
   cache (a first build of an object's tables takes minutes and is not what this measures).
2. **Select-action overhead**: ``--calls`` calls of ``/rrg/select_action`` with a Gaussian
   belief in the request (as other robot software would send it); the overhead of a call is
   its round-trip time minus the planning time the core reports. Median over the calls.

With ``--json`` the last line is one JSON object: ``select_overhead_ms``,
``launch_to_first_action_s`` and the figures behind them.
"""

from __future__ import annotations

import argparse
import json
import signal
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from rrg_estimator.config import LEVELS
from rrg_models.config import WORLD

SELECT_TARGET_MS = 5.0  # the required target for the median select-action overhead
LEVEL_NAMES = list(LEVELS)  # the planner loads all, as rrg-launch does (variable resolution)


def select_overhead(graph, object_name: str, level: str, horizon: int, calls: int) -> dict:
    """Median round trip, planning time and overhead [ms] of ``calls`` select-action calls."""
    from builtin_interfaces.msg import Time

    from rrg_estimator.belief import Belief
    from rrg_estimator.ros.belief_msgs import belief_to_msg

    mean = np.asarray(WORLD.nominal_pose)
    belief = Belief.for_level(LEVELS[level], mean)
    msg = belief_to_msg(belief, Time())
    rtt, plan = [], []
    for i in range(calls + 5):  # 5 warm-up calls
        t0 = time.perf_counter()
        choice = graph.rrg.select_action(object_name, msg, horizon=horizon, timeout_s=60.0)
        dt = time.perf_counter() - t0
        if i >= 5:
            rtt.append(dt)
            plan.append(choice.planning_time_s)
    over = np.asarray(rtt) - np.asarray(plan)
    return {
        "select_rtt_ms": statistics.median(rtt) * 1e3,
        "select_planning_ms": statistics.median(plan) * 1e3,
        "select_overhead_ms": float(np.median(over)) * 1e3,
        "select_overhead_p90_ms": float(np.percentile(over, 90)) * 1e3,
        "select_calls": calls,
        "belief_points": belief.grid.size,
    }


def first_action(graph, object_name: str, level: str, horizon: int) -> float:
    """Seconds from the launch to the first robust-grasp feedback; cancels the grasp after it."""
    from rrg_common.ros.msg_conversions import planar_to_msg
    from rrg_msgs.srv import ResetSim

    reset = graph.result(
        graph.clients["/rrg/reset_sim"].call_async(
            ResetSim.Request(object_name=object_name, pose=planar_to_msg(WORLD.nominal_pose))
        ),
        60.0,
        "reset_sim",
    )
    if reset.error_code != ResetSim.Response.NONE:
        raise RuntimeError(f"reset_sim failed: {reset.error_msg}")
    first: list[float] = []
    task = graph.rrg.start_robust_grasp(
        object_name,
        level=level,
        horizon=horizon,
        on_feedback=lambda _: first.append(time.monotonic()),
        timeout_s=30.0,
    )
    graph.spin_until(lambda: bool(first), 600.0, "the first action")
    graph.result(task.cancel(), 30.0, "the cancellation")
    task.result(600.0)
    return first[0] - graph.started


def bench_ros(argv: list[str]) -> int:
    from rrg_bringup.graph import Graph, warm_tables
    from rrg_bringup.supervisor import ros_environment

    ap = argparse.ArgumentParser(
        prog="rrg-bench ros",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--object", default="powerdrill")
    ap.add_argument("--level", default="high", choices=sorted(LEVELS))
    ap.add_argument(
        "--horizon",
        type=int,
        default=1,
        choices=(1, 2, 3),
        help="H of the timed select-action calls",
    )
    ap.add_argument("--calls", type=int, default=200)
    ap.add_argument("--domain-id", type=int, default=97)
    ap.add_argument(
        "--json", action="store_true", help="print the figures as JSON on the last line"
    )
    args = ap.parse_args(argv)

    warm_tables(args.object, LEVEL_NAMES)  # not part of the launch time: built once, then cached

    def terminate(
        signum, _frame
    ):  # SIGTERM stops the graph like Ctrl-C (set after the table workers exist)
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, terminate)
    with tempfile.TemporaryDirectory(prefix="rrg_bench_ros_") as tmp:
        graph = Graph(ros_environment(args.domain_id), Path(tmp) / "bag", Path(tmp) / "logs")
        try:
            graph.start(args.object, LEVEL_NAMES, seed=0, real_time_factor=0.0)
            graph.connect()
            ready_s = graph.wait_ready(900.0)
            print(f"[ros] graph ready after {ready_s:.1f} s", flush=True)
            launch_s = first_action(graph, args.object, args.level, max(args.horizon, 2))
            print(f"[ros] launch to first action: {launch_s:.1f} s", flush=True)
            sel = select_overhead(graph, args.object, args.level, args.horizon, args.calls)
        finally:
            graph.disconnect()
            graph.stop()
    out = {
        "select_overhead_ms": sel["select_overhead_ms"],
        "launch_to_first_action_s": launch_s,
        "graph_ready_s": ready_s,
        **{k: v for k, v in sel.items() if k != "select_overhead_ms"},
        "object": args.object,
        "level": args.level,
        "horizon": args.horizon,
    }
    print("\n| figure | value | target |")
    print("|---|---|---|")
    print(
        f"| select-action overhead (median of {args.calls}, "
        f"{sel['belief_points']}-point belief in the request) "
        f"| {sel['select_overhead_ms']:.2f} ms | ≤ {SELECT_TARGET_MS:.0f} ms |"
    )
    print(
        f"| select-action round trip / core planning time (H={args.horizon}) | "
        f"{sel['select_rtt_ms']:.1f} ms / "
        f"{sel['select_planning_ms']:.1f} ms | – |"
    )
    print(f"| launch → graph ready | {ready_s:.1f} s | – |")
    print(f"| launch → first action ({args.object}, {args.level}) | {launch_s:.1f} s | – |")
    if args.json:
        print(json.dumps(out))
    return 0
