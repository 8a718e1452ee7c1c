"""``rrg-bench``: benchmarks that print numbers (speed is never asserted in tests).

    rrg-bench plan [--object powerdrill] [--level high] [--json]
    rrg-bench sim  [--json]
    rrg-bench ros  [--json]

``plan`` times action selection at H = 1, 2, 3, one belief update and one table build,
for the fast and the naive reference implementations, and prints their ratios. With
``--json`` the last line is one JSON object with the medians.
"""

from __future__ import annotations

import argparse
import json
import logging
import statistics
import sys
import time
from collections.abc import Callable

import numpy as np

PAPER_SELECT_S = {1: 3.0, 2: 30.0, 3: 180.0}  # the paper's reported times (non-optimized Python)


def _median_time(fn: Callable[[], object], repeats: int, warmup: bool = True) -> float:
    """Median wall time of fn over repeats calls, after one untimed warm-up call (lazy loads)
    unless warmup is False (the slow reference runs)."""
    if warmup:
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def bench_plan(argv: list[str]) -> int:
    from rrg_estimator.config import LEVELS
    from rrg_estimator.grid import Grid
    from rrg_estimator.obs_tables import build_table
    from rrg_estimator.reference_update import update_reference
    from rrg_estimator.update import update
    from rrg_planner.agent import initial_belief
    from rrg_planner.planning_model import PlanningModel
    from rrg_planner.reference_search import ReferenceSearch
    from rrg_planner.search import ForwardSearch
    from rrg_sim.config import WORLD
    from rrg_sim.geometric_sim import GeometricSimulator
    from rrg_sim.poses import compose_planar

    ap = argparse.ArgumentParser(
        prog="rrg-bench plan",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--object", default="powerdrill")
    ap.add_argument("--level", default="high", choices=sorted(LEVELS))
    ap.add_argument("--repeats", type=int, default=5, help="timed repeats per figure (median)")
    ap.add_argument(
        "--reference-horizons",
        default="1,2",
        help="horizons to also time with the naive reference search (H=3 takes ~hours)",
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--json", action="store_true", help="print the medians as JSON on the last line"
    )
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    level = LEVELS[args.level]
    rng = np.random.default_rng(args.seed)

    print(
        f"[plan] object={args.object} level={args.level} grid={level.shape} "
        f"({int(np.prod(level.shape))} points)",
        flush=True,
    )
    model = PlanningModel(args.object, levels=(args.level,), progress=True)
    print(f"[plan] {len(model.actions)} WRTs: {', '.join(model.names)}", flush=True)

    # Table build, timed fresh (no cache) for the goal WRT.
    goal = model.actions[model.goal_actions[0]]
    t0 = time.perf_counter()
    build_table(model.obj, goal.wrt, Grid.for_level(level), workers=2, progress=False)
    table_s = time.perf_counter() - t0

    mean = np.asarray(WORLD.nominal_pose)
    belief = initial_belief(level, mean)
    fast = ForwardSearch(model)
    ref = ReferenceSearch(model)
    ref_h = {int(h) for h in args.reference_horizons.split(",") if h.strip()}

    rows: dict[str, tuple[float, float | None]] = {}
    for h in (1, 2, 3):
        t_fast = _median_time(
            lambda: fast.select(belief, h), args.repeats if h < 3 else max(1, args.repeats // 2)
        )
        t_ref = _median_time(lambda: ref.select(belief, h), 1, warmup=False) if h in ref_h else None
        rows[f"select H={h}"] = (t_fast, t_ref)
        print(
            f"[plan] select H={h}: fast {t_fast * 1e3:.1f} ms"
            + (f", reference {t_ref:.2f} s" if t_ref else ""),
            flush=True,
        )

    # Belief update with an observation simulated at a random true pose.
    true = compose_planar(mean, rng.normal(0.0, level.sigma))
    obs = GeometricSimulator(model.obj, goal.wrt).simulate(true, mean)
    table = goal.tables[args.level]
    t_upd = _median_time(lambda: update(belief, table, mean, obs), max(20, args.repeats))
    t_upd_ref = _median_time(lambda: update_reference(belief, table, mean, obs), 1, warmup=False)
    rows["belief update"] = (t_upd, t_upd_ref)
    rows["table build / WRT"] = (table_s, None)

    print("\n| figure | fast | reference | speed-up | paper |")
    print("|---|---|---|---|---|")
    for name, (tf, tr) in rows.items():
        paper = f"{PAPER_SELECT_S[int(name[-1])]:.0f} s" if name.startswith("select") else "–"
        ratio = f"{tr / tf:.0f}×" if tr else "–"
        ref_txt = f"{tr * 1e3:.0f} ms" if tr else "not run"
        print(f"| {name} | {tf * 1e3:.1f} ms | {ref_txt} | {ratio} | {paper} |")
    out = {
        "select_ms_h1": rows["select H=1"][0] * 1e3,
        "select_ms_h2": rows["select H=2"][0] * 1e3,
        "select_ms_h3": rows["select H=3"][0] * 1e3,
        "update_ms": t_upd * 1e3,
        "table_s_per_wrt": table_s,
        "ref_speedup_h1": (rows["select H=1"][1] / rows["select H=1"][0])
        if rows["select H=1"][1]
        else None,
        "ref_speedup_update": t_upd_ref / t_upd,
    }
    if args.json:
        print(json.dumps(out))
    return 0


def bench_sim(argv: list[str]) -> int:
    from rrg_sim.physics.sim_benchmark import bench_sim as run

    return run(argv)


def bench_ros(argv: list[str]) -> int:
    from rrg_planner.bringup.graph_benchmark import bench_ros as run

    return run(argv)


COMMANDS = {"plan": bench_plan, "sim": bench_sim, "ros": bench_ros}


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] not in COMMANDS:
        print(f"usage: rrg-bench {{{','.join(COMMANDS)}}} [--json] [options]", file=sys.stderr)
        return 2
    return COMMANDS[argv[0]](argv[1:])


if __name__ == "__main__":
    raise SystemExit(main())
