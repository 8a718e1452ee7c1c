"""``rrg-bench service``: the planner's ``/rrg/select_action`` under load from several client
processes, as other robot software would call it (speed is printed, never asserted in tests).

    rrg-bench service [--clients 8] [--calls 1250] [--horizon 1] [--busy 0] [--json]

Starts the planner node (its planning model preloaded from the table cache) in a DDS domain of
its own on loopback, then ``--clients`` client processes, each an ``RRGClient`` that waits for
the graph and then makes ``--calls`` calls back to back with a Gaussian belief at the nominal
pose (each call with ``--call-timeout``). ``--busy N`` adds N processes that only burn CPU, for
a busy machine. Prints calls per second over the whole load, the latency quantiles, the
planner's own planning time and the calls never answered, with the planner's log lines about
responses it could not send.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
#: The select-action figures the issue asks of the service (8 client processes, H = 1).
TARGET_CALLS_PER_S = 100.0
TARGET_P99_MS = 100.0


def client_main(argv: list[str]) -> int:
    """One client process: JSON lines on stdout, one per call (latency [s], planning time [s],
    or the error), after a line that says the graph was ready."""
    from rrg_models.config import WORLD
    from rrg_planner.client import Gaussian, RRGClient, RRGError

    ap = argparse.ArgumentParser()
    ap.add_argument("--object", required=True)
    ap.add_argument("--level", required=True)
    ap.add_argument("--horizon", type=int, required=True)
    ap.add_argument("--calls", type=int, required=True)
    ap.add_argument("--call-timeout", type=float, required=True)
    ap.add_argument("--start-at", type=float, required=True, help="time.time() to start at")
    args = ap.parse_args(argv)
    belief = Gaussian(tuple(WORLD.nominal_pose), level=args.level).belief()
    with RRGClient(node_name=f"bench_client_{os.getpid()}") as rrg:
        rrg.wait_until_ready(600.0)  # the planner loads its model first
        print(json.dumps({"ready": True}), flush=True)
        time.sleep(max(0.0, args.start_at - time.time()))
        for _ in range(args.calls):
            t0 = time.perf_counter()
            try:
                choice = rrg.select_action(
                    args.object, belief, horizon=args.horizon, timeout_s=args.call_timeout
                )
                row = {"latency_s": time.perf_counter() - t0, "planning_s": choice.planning_time_s}
            except RRGError as exc:
                row = {"error": f"{type(exc).__name__}: {exc}"}
            print(json.dumps(row), flush=True)
    return 0


def start_node(module: str, params: dict, env: dict, log_path: Path) -> subprocess.Popen:
    """``python -m module --ros-args -p k:=v ...``, its output in ``log_path``."""
    from rrg_bringup.supervisor import ros_args

    with log_path.open("w") as log:
        return subprocess.Popen(
            [sys.executable, "-m", module, *ros_args(params)],
            env=env,
            cwd=ROOT,
            stdout=log,
            stderr=subprocess.STDOUT,
        )


def service_parser() -> argparse.ArgumentParser:
    """``rrg-bench service``'s arguments."""
    ap = argparse.ArgumentParser(
        prog="rrg-bench service",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--object", default="powerdrill")
    ap.add_argument("--level", default="high")
    ap.add_argument("--horizon", type=int, default=1, choices=(1, 2, 3))
    ap.add_argument("--clients", type=int, default=8, help="client processes")
    ap.add_argument("--calls", type=int, default=1250, help="calls per client")
    ap.add_argument("--call-timeout", type=float, default=120.0, help="per call [s]")
    ap.add_argument("--busy", type=int, default=0, help="CPU-burning processes beside the load")
    ap.add_argument("--domain-id", type=int, default=96)
    ap.add_argument("--json", action="store_true", help="print the figures as JSON last")
    return ap


def bench_service(argv: list[str]) -> int:
    from rrg_bringup.graph import warm_tables
    from rrg_bringup.supervisor import ros_environment

    args = service_parser().parse_args(argv)
    warm_tables(args.object, [args.level])
    env = ros_environment(args.domain_id)
    with tempfile.TemporaryDirectory(prefix="rrg_bench_service_") as tmp:
        log_path = Path(tmp) / "planner.log"
        nodes = [
            start_node(
                "rrg_planner.ros.planner_node",
                {"levels": [args.level], "preload": [args.object]},
                env,
                log_path,
            ),
            start_node("rrg_estimator.ros.estimator_node", {}, env, Path(tmp) / "estimator.log"),
        ]
        try:
            rows, failed, load_s = run_clients(args, env, Path(tmp))
        finally:
            for node in nodes:
                node.send_signal(2)
            for node in nodes:
                try:
                    node.wait(10)
                except subprocess.TimeoutExpired:
                    node.kill()
        planner_log = log_path.read_text()
    out, errors, send_failures = service_figures(args, rows, failed, load_s, planner_log)
    print_service_table(args, out, errors, failed, send_failures)
    if args.json:
        print(json.dumps(out))
    return 0


def run_clients(args: argparse.Namespace, env: dict[str, str], tmp: Path):
    """The client processes' calls, all starting at one instant → (their rows, the log tails
    of clients that failed, the calls' wall time [s])."""
    procs: list[subprocess.Popen] = []
    busy: list[subprocess.Popen] = []
    try:
        start_at = time.time() + 20.0 + 2.0 * args.clients  # all ready by then
        for _ in range(args.clients):
            procs.append(
                subprocess.Popen(
                    [sys.executable, "-m", "rrg_bringup.benchmarks.service_benchmark", "client"]
                    + ["--object", args.object, "--level", args.level]
                    + ["--horizon", str(args.horizon), "--calls", str(args.calls)]
                    + ["--call-timeout", str(args.call_timeout)]
                    + ["--start-at", str(start_at)],
                    env=env,
                    cwd=ROOT,
                    stdout=subprocess.PIPE,
                    stderr=(tmp / f"client_{len(procs)}.log").open("w"),
                    text=True,
                )
            )
        busy += [
            subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.busy)
        ]
        print(
            f"[service] planner + {args.clients} clients × {args.calls} calls "
            f"(H={args.horizon}, {args.object}/{args.level}), {args.busy} busy processes",
            flush=True,
        )
        rows = []
        failed = []  # clients that exited with an error: their log's tail
        for i, p in enumerate(procs):
            for line in p.stdout:
                row = json.loads(line)
                if "ready" not in row:
                    rows.append(row)
            if p.wait() != 0:
                failed.append((tmp / f"client_{i}.log").read_text()[-2000:])
        return rows, failed, time.time() - start_at
    finally:
        for p in [*procs, *busy]:
            if p.poll() is None:
                p.kill()


def service_figures(args, rows: list[dict], failed: list[str], load_s: float, planner_log: str):
    """(the figures, the calls' errors, the planner's failed sends)."""
    lat = np.array([r["latency_s"] for r in rows if "latency_s" in r])
    plan = np.array([r["planning_s"] for r in rows if "planning_s" in r])
    errors = [r["error"] for r in rows if "error" in r]
    send_failures = [ln for ln in planner_log.splitlines() if "send response" in ln]
    out = {
        "clients": args.clients,
        "calls": len(rows),
        "answered": int(lat.size),
        "unanswered": len(errors),
        "calls_per_s": lat.size / load_s,
        "latency_p50_ms": float(np.percentile(lat, 50) * 1e3) if lat.size else None,
        "latency_p99_ms": float(np.percentile(lat, 99) * 1e3) if lat.size else None,
        "planning_p50_ms": float(np.percentile(plan, 50) * 1e3) if plan.size else None,
        "overhead_p50_ms": float(np.percentile(lat - plan, 50) * 1e3) if lat.size else None,
        "planner_send_failures": len(send_failures),
        "client_failures": failed,
        "busy": args.busy,
        "horizon": args.horizon,
    }
    return out, errors, send_failures


def print_service_table(args, out: dict, errors: list, failed: list, send_failures: list) -> None:
    """The figures against their targets, as a Markdown table, and the first problems."""
    print("\n| figure | value | target |")
    print("|---|---|---|")
    calls = f"{out['calls_per_s']:.1f}"
    print(f"| calls/s ({args.clients} clients) | {calls} | ≥ {TARGET_CALLS_PER_S:.0f} |")
    if out["answered"]:
        p50, p99 = out["latency_p50_ms"], out["latency_p99_ms"]
        print(f"| latency p50 / p99 | {p50:.1f} / {p99:.1f} ms | p99 ≤ {TARGET_P99_MS:.0f} ms |")
        plan_ms, over_ms = out["planning_p50_ms"], out["overhead_p50_ms"]
        print(f"| planning p50, overhead p50 | {plan_ms:.1f}, {over_ms:.1f} ms | – |")
    print(f"| unanswered | {out['unanswered']} of {out['calls']} | 0 |")
    for e in sorted(set(errors))[:5]:
        print(f"  {errors.count(e)} × {e}")
    for text in failed:
        print(f"  a client failed:\n{text}")
    for ln in send_failures[:5]:
        print(f"  planner: {ln}")


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "client":
        raise SystemExit(client_main(sys.argv[2:]))
    raise SystemExit(bench_service(sys.argv[1:]))
