"""``rrg-bench``: benchmarks that print numbers (speed is never asserted in tests).

    rrg-bench plan [--object powerdrill] [--level high] [--json]
    rrg-bench sim  [--json]
    rrg-bench ros  [--json]
    rrg-bench hw   [--trials 50] [--json]
    rrg-bench service | tables | campaign  (each with --help)

``plan`` times action selection at H = 1, 2, 3, one belief update and one table build,
for the fast and the naive reference implementations, and prints their ratios; the update's
roofline (update_roofline: its bytes and flops against the memory bandwidth measured on the
spot, so its distance to the floor is printed); then the core operations on full-size grids:
a belief update on a contact reading (with its bump) and the naive reference's likelihood
pass, the table indices, the bump, the re-gridding (varres.maybe_refine), and the WAM's batch
IK, reachability test and feasibility-map build. With ``--json`` the last line is one JSON
object with the medians (the roofline's under "roofline"). ``sim``, ``ros`` and ``hw``
(the hardware bridge's stop latency and sensor rates on the emulated drivers) are described in
their own modules.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time

import numpy as np

from rrg_bringup.benchmarks.update_roofline import median_seconds

PAPER_SELECT_S = {1: 3.0, 2: 30.0, 3: 180.0}  # the paper's reported times (non-optimized Python)
UPDATE_REPEATS = 200  # timed belief updates per figure (a fraction of a millisecond each)


def plan_parser() -> argparse.ArgumentParser:
    """``rrg-bench plan``'s arguments."""
    from rrg_estimator.config import LEVELS

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
    return ap


def bench_plan(argv: list[str]) -> int:
    from rrg_estimator.belief import Belief
    from rrg_estimator.config import LEVELS
    from rrg_estimator.grid import Grid
    from rrg_estimator.obs_tables import build_table
    from rrg_models.config import WORLD
    from rrg_planner.planning_model import PlanningModel

    args = plan_parser().parse_args(argv)
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
    belief = Belief.for_level(level, mean)
    rows = time_selection(model, belief, args)
    t_upd, t_upd_ref, update_case = time_update(model, belief, goal, mean, level, args, rng)
    rows["belief update"] = (t_upd, t_upd_ref)
    rows["table build / WRT"] = (table_s, None)
    print_plan_table(rows)
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
        **update_case["contact"],
        **bench_core(),
        "roofline": update_case["roofline"],
    }
    if args.json:
        print(json.dumps(out))
    return 0


def time_selection(model, belief, args) -> dict[str, tuple[float, float | None]]:
    """Median seconds of action selection at H = 1, 2, 3, fast and (where asked) reference."""
    from rrg_planner.reference_search import ReferenceSearch
    from rrg_planner.search import ForwardSearch

    fast = ForwardSearch(model)
    ref = ReferenceSearch(model)
    ref_h = {int(h) for h in args.reference_horizons.split(",") if h.strip()}
    rows: dict[str, tuple[float, float | None]] = {}
    for h in (1, 2, 3):
        t_fast = median_seconds(
            lambda h=h: fast.select(belief, h),
            args.repeats if h < 3 else max(1, args.repeats // 2),
        )
        t_ref = (
            median_seconds(lambda h=h: ref.select(belief, h), 1, warmup=False)
            if h in ref_h
            else None
        )
        rows[f"select H={h}"] = (t_fast, t_ref)
        print(
            f"[plan] select H={h}: fast {t_fast * 1e3:.1f} ms"
            + (f", reference {t_ref:.2f} s" if t_ref else ""),
            flush=True,
        )
    return rows


def time_update(model, belief, goal, mean, level, args, rng) -> tuple[float, float, dict]:
    """Median seconds of a belief update at the mean ``mean`` (3,), fast and reference, with an
    observation simulated at a true pose drawn from ``level``; and the update's roofline and
    contact figures ({"roofline": …, "contact": …})."""
    from rrg_estimator.reference_update import update_reference
    from rrg_estimator.update import update
    from rrg_models.poses import compose_planar
    from rrg_sim.geometric_sim import GeometricSimulator

    true = compose_planar(mean, rng.normal(0.0, level.sigma))
    obs = GeometricSimulator(model.obj, goal.wrt).simulate(true, mean)
    table = goal.tables[args.level]
    t_upd = median_seconds(lambda: update(belief, table, mean, obs), UPDATE_REPEATS)
    t_upd_ref = median_seconds(lambda: update_reference(belief, table, mean, obs), 1, warmup=False)
    print(
        f"[plan] belief update of {belief.grid.size:,} points "
        f"({'contact' if obs.contact else 'no contact'}): {t_upd * 1e3:.3f} ms "
        f"(median of {UPDATE_REPEATS})",
        flush=True,
    )
    roof = bench_roofline(belief, table, mean, obs, args.repeats)
    contact = bench_contact_update(belief, table, mean, rng, args.repeats)
    return t_upd, t_upd_ref, {"roofline": roof, "contact": contact}


def print_plan_table(rows: dict[str, tuple[float, float | None]]) -> None:
    """The timings against the reference and the paper, as a Markdown table."""
    print("\n| figure | fast | reference | speed-up | paper |")
    print("|---|---|---|---|---|")
    for name, (tf, tr) in rows.items():
        paper = f"{PAPER_SELECT_S[int(name[-1])]:.0f} s" if name.startswith("select") else "–"
        ratio = f"{tr / tf:.0f}×" if tr else "–"
        ref_txt = f"{tr * 1e3:.0f} ms" if tr else "not run"
        print(f"| {name} | {tf * 1e3:.1f} ms | {ref_txt} | {ratio} | {paper} |")


def bench_roofline(belief, table, e, obs, repeats: int) -> dict:
    """The roofline of one update by ``obs`` without its transition (what update_roofline
    counts), timed here, against the memory bandwidth measured now."""
    from rrg_bringup.benchmarks.update_roofline import describe, roofline
    from rrg_estimator.obs_model import features_from_observation
    from rrg_estimator.update import update

    feats = features_from_observation(obs, e)
    t = median_seconds(lambda: update(belief, table, e, feats, transition=False), UPDATE_REPEATS)
    nx, ny, nt = belief.grid.shape
    r = roofline(belief.grid.size, nx * ny, nt, table, feats, t, repeats)
    print(describe(r), flush=True)
    return r


def bench_contact_update(belief, table, e, rng, repeats: int) -> dict:
    """A belief update on a contact reading (so with the bump transition), from a seeded
    contact row of the table, and the naive reference's likelihood pass on it (no bump)."""
    from rrg_estimator.obs_model import features_from_table_rows
    from rrg_estimator.reference_update import update_reference
    from rrg_estimator.update import update

    row = int(rng.choice(np.flatnonzero(table.contact)))
    feats = features_from_table_rows(table, [row])
    fast = median_seconds(lambda: update(belief, table, e, feats), UPDATE_REPEATS)
    naive = median_seconds(
        lambda: update_reference(belief, table, e, feats, transition=False), 1, warmup=False
    )
    print(
        f"[plan] update of {belief.grid.size:,} points (contact, with bump): "
        f"{fast * 1e3:.3f} ms; naive reference likelihood pass alone: {naive:.2f} s",
        flush=True,
    )
    return {"update_contact_ms": fast * 1e3, "update_reference_likelihood_s": naive}


def bench_core() -> dict:
    """The core operations on full-size grids: updates, index lookups, refinement, IK."""
    from scipy.spatial.transform import Rotation

    from rrg_estimator.belief import Belief
    from rrg_estimator.config import HIGH, LOW
    from rrg_estimator.grid import Grid
    from rrg_estimator.obs_model import table_indices
    from rrg_estimator.transition import bump
    from rrg_estimator.varres import maybe_refine
    from rrg_models import wam
    from rrg_models.config import HAND
    from rrg_models.poses import make_pose
    from rrg_models.wam_feasibility import FeasibilityMap

    out = {}
    e = np.array([0.62, 0.01, 0.3])
    grid, table_grid = Grid.for_level(HIGH, center=e), Grid.for_level(HIGH)
    out["table_indices_ms"] = 1e3 * median_seconds(lambda: table_indices(grid, e, table_grid), 100)
    low = Belief.for_level(LOW, (0.62, 0.0, 0.0))
    out["bump_ms"] = 1e3 * median_seconds(lambda: bump(low, (0.6, 0.8)), 50)
    coarse = Grid.for_level(HIGH, center=(0.62, 0.0, 0.0))
    concentrated = Belief.gaussian(coarse, (0.6237, -0.0141, 0.237), (0.005, 0.004, 0.04))
    spread = Belief.for_level(HIGH, (0.62, 0.0, 0.0))
    out["refine_ms"] = 1e3 * median_seconds(lambda: maybe_refine(concentrated), 20)
    out["refine_reject_ms"] = 1e3 * median_seconds(lambda: maybe_refine(spread), 20)
    print(
        f"[plan] table_indices for {grid.size:,} points: {out['table_indices_ms']:.3f} ms; "
        f"bump on {low.grid.size:,} points: {out['bump_ms']:.3f} ms; maybe_refine: refine "
        f"{out['refine_ms']:.2f} ms, reject {out['refine_reject_ms']:.2f} ms",
        flush=True,
    )

    # 2000 random in-limit postures whose elbow and wrist centre clear the table (seeded)
    q = np.random.default_rng(9).uniform(wam.LOWER, wam.UPPER, (6000, 7))
    T = wam.fk(q[wam.arm_clear_of_table(q)][:2000])
    wam.ik_batch(T[:200])
    t0 = time.perf_counter()
    _, ok = wam.ik_batch(T)
    out["ik_batch_us_per_pose"] = (time.perf_counter() - t0) / len(T) * 1e6
    out["ik_solved_fraction"] = float(ok.mean())
    t0 = time.perf_counter()
    wam.reachable(T)
    out["reachable_us_per_pose"] = (time.perf_counter() - t0) / len(T) * 1e6
    down = Rotation.from_rotvec([np.pi, 0.0, 0.0])
    top_down = np.stack(
        [make_pose([0, 0, h - HAND.palm_surface_z], down) for h in (0.35, 0.25, 0.18)]
    )
    fmap = FeasibilityMap(top_down, cache=False)
    out["feasibility_map_build_s"] = fmap.build_seconds
    g = fmap.grid
    print(
        f"[plan] wam: ik_batch {out['ik_batch_us_per_pose']:.1f} µs/pose (solved "
        f"{out['ik_solved_fraction']:.3f}); reachable {out['reachable_us_per_pose']:.1f} µs/pose; "
        f"FeasibilityMap of 3 waypoints over {g.nr}x{g.nphi}x{g.npsi} cells: "
        f"{fmap.build_seconds:.2f} s",
        flush=True,
    )
    return out


def bench_sim(argv: list[str]) -> int:
    from rrg_bringup.benchmarks.sim_benchmark import bench_sim as run

    return run(argv)


def bench_ros(argv: list[str]) -> int:
    from rrg_bringup.benchmarks.graph_benchmark import bench_ros as run

    return run(argv)


def bench_hw(argv: list[str]) -> int:
    from rrg_bringup.benchmarks.hw_benchmark import bench_hw as run

    return run(argv)


def bench_service(argv: list[str]) -> int:
    from rrg_bringup.benchmarks.service_benchmark import bench_service as run

    return run(argv)


def bench_campaign(argv: list[str]) -> int:
    from rrg_bringup.benchmarks.campaign_benchmark import run

    return run(argv)


def bench_tables(argv: list[str]) -> int:
    """``rrg-bench tables OBJECT [--wrt NAME] [--draws K]``: fresh table builds, timed."""
    from rrg_estimator.obs_tables import main as run

    run(["--bench", *argv])
    return 0


COMMANDS = {
    "plan": bench_plan,
    "sim": bench_sim,
    "ros": bench_ros,
    "hw": bench_hw,
    "service": bench_service,
    "tables": bench_tables,
    "campaign": bench_campaign,
}


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] not in COMMANDS:
        print(f"usage: rrg-bench {{{','.join(COMMANDS)}}} [--json] [options]", file=sys.stderr)
        return 2
    return COMMANDS[argv[0]](argv[1:])


if __name__ == "__main__":
    raise SystemExit(main())
