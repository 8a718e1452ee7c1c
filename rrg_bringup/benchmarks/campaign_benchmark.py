"""``rrg-bench campaign``: where a campaign's time goes, and how long the whole campaign takes.

It runs a sample of a campaign's own trials: ``--per-cell`` of every cell that ``rrg-experiment``
would run (the main cells and Fig. 9's), on base seed ``--seed``, in this process, with one
BLAS thread, as a campaign worker runs them, and times each; then runs them again under
cProfile (``--no-profile``: not). Each planning model and world is loaded once per run of its
cells, as a worker does, and that load is timed apart (a worker keeps only its latest models,
trials.KEPT_MODELS).

The profile's own time (cProfile's tottime) is split into parts by the code it is spent in:
the physics steps (MuJoCo's ``mj_step``), the sensors and guards read around every step, IK and
paths, the forward search, the belief update, the judge, numba's compiler, and the rest.
Time spent in numpy or the standard library is charged to the part that called it, in
proportion to the calls' cumulative time. The projection of the whole campaign is each cell's
mean trial time × its number of trials (``--trials``, ``--fig9-trials``), plus one load of
each model per worker, spread over ``--workers`` workers at ``--efficiency`` (the measured
slowdown of two workers on two cores).
"""

from __future__ import annotations

import argparse
import cProfile
import json
import pstats
import time
from collections import defaultdict
from pathlib import Path

from tqdm import tqdm

#: Parts of a trial, each with the path fragments (or builtin names) of the code it covers;
#: the first match wins.
PARTS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("physics steps", ("mj_step", "mj_forward")),
    ("numba compiler", ("/numba/", "/llvmlite/")),
    ("sensors and guards", ("rrg_sim/physics/sensing.py", "rrg_models/hand_sensing.py")),
    ("control loop", ("rrg_sim/physics/world.py", "rrg_sim/executor/wrt_executor.py")),
    ("IK and paths", ("rrg_models/trajectory.py", "rrg_models/wam.py", "wam_feasibility")),
    ("judge", ("rrg_sim/physics/judge.py",)),
    ("belief update", ("rrg_estimator/",)),
    (
        "forward search",
        ("rrg_planner/search.py", "rrg_planner/clustering.py", "rrg_planner/planning_model.py"),
    ),
    ("agent and loop", ("rrg_planner/agent.py", "rrg_planner/closed_loop.py")),
)
OTHER = "other"
#: The measured two-worker efficiency on the 2-core machine (docs/benchmarks.md, "--ray").
TWO_WORKER_EFFICIENCY = 0.86


def part_of(func: tuple[str, int, str]) -> str | None:
    """The PARTS name of a pstats function key (file, line, name), or None (numpy, stdlib)."""
    where = f"{func[0]}:{func[2]}"
    for name, fragments in PARTS:
        if any(f in where for f in fragments):
            return name
    return None


def split_by_part(stats: pstats.Stats) -> dict[str, float]:
    """Seconds of own time per part, uncategorized code charged to its callers' parts."""
    table = stats.stats  # func → (cc, nc, tt, ct, callers{caller: (cc, nc, tt, ct)})
    memo: dict = {}

    def shares(func, depth: int = 0) -> dict[str, float]:
        """The parts a second of func's time belongs to (fractions summing to 1)."""
        if func in memo:
            return memo[func]
        own = part_of(func)
        if own is not None:
            return {own: 1.0}
        callers = table.get(func, (0, 0, 0, 0, {}))[4]
        total = sum(c[3] for c in callers.values())
        if depth > 40 or total <= 0:
            return {OTHER: 1.0}
        out: dict[str, float] = defaultdict(float)
        memo[func] = {OTHER: 1.0}  # a cycle through func resolves to "other"
        for caller, c in callers.items():
            for part, f in shares(caller, depth + 1).items():
                out[part] += f * c[3] / total
        memo[func] = dict(out)
        return memo[func]

    seconds: dict[str, float] = defaultdict(float)
    for func, (_, _, tt, _, _) in table.items():
        for part, f in shares(func).items():
            seconds[part] += tt * f
    return dict(seconds)


def campaign_parser() -> argparse.ArgumentParser:
    """``rrg-bench campaign``'s arguments."""
    from rrg_models.objects import PAPER_OBJECTS
    from rrg_planner.request_checks import STRATEGIES
    from rrg_sim.config import WORLD_PROFILES

    ap = argparse.ArgumentParser(
        prog="rrg-bench campaign",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--world", default="realistic", choices=sorted(WORLD_PROFILES))
    ap.add_argument("--objects", default=",".join(PAPER_OBJECTS))
    ap.add_argument("--levels", default="low,high")
    ap.add_argument("--strategies", default=",".join(STRATEGIES))
    ap.add_argument("--per-cell", type=int, default=2, help="sampled trials per cell")
    ap.add_argument("--trials", type=int, default=100, help="the campaign's trials per cell")
    ap.add_argument("--fig9-trials", type=int, default=100, help="its trials per Fig. 9 point")
    ap.add_argument("--seed", type=int, default=4242, help="base seed of the sampled trials")
    ap.add_argument("--workers", type=int, default=2, help="workers of the projection")
    ap.add_argument("--efficiency", type=float, default=TWO_WORKER_EFFICIENCY)
    ap.add_argument(
        "--no-profile",
        dest="profile",
        action="store_false",
        help="time the sample only (the profile runs it a second time, under cProfile)",
    )
    ap.add_argument("--profile-out", type=Path, help="write the cProfile stats here (.prof)")
    ap.add_argument("--json", action="store_true", help="print one JSON object last")
    return ap


def run(argv: list[str]) -> int:
    from rrg_experiments.experiment_cli import campaign_specs
    from rrg_experiments.trials import schedule

    args = campaign_parser().parse_args(argv)
    objects, levels = args.objects.split(","), args.levels.split(",")
    strategies = args.strategies.split(",")
    sample = campaign_specs(
        objects, levels, strategies, args.per_cell, args.per_cell, args.seed, args.world
    )
    full = campaign_specs(
        objects, levels, strategies, args.trials, args.fig9_trials, args.seed, args.world
    )
    counts: dict[str, int] = defaultdict(int)
    for s in full:
        counts[s.cell.key] += 1

    sample = schedule(sample)  # as a campaign runs them: each model's cells together
    per_cell, loads, trials_s = time_sample(sample)
    load_s = sum(loads.values())
    parts = profile_sample(sample, args.profile_out) if args.profile else {}
    profiled = sum(parts.values())
    # Every worker loads each model once (the schedule keeps a model's cells together).
    worker_s = sum(counts[k] * sum(v) / len(v) for k, v in per_cell.items())
    worker_s += args.workers * load_s
    wall_s = worker_s / (args.workers * (args.efficiency if args.workers > 1 else 1.0))

    print(f"{len(sample)} trials sampled in {trials_s:.1f} s (models and worlds: {load_s:.1f} s)")
    if parts:
        print(f"{'part (under cProfile)':<22} {'seconds':>8} {'share':>6}")
        for name, sec in sorted(parts.items(), key=lambda kv: -kv[1]):
            print(f"{name:<22} {sec:8.2f} {100 * sec / profiled:5.1f} %")
    print(
        f"projected campaign: {len(full)} trials, {worker_s:.0f} worker-seconds, "
        f"{wall_s / 60:.1f} min on {args.workers} workers at efficiency {args.efficiency:.2f}"
    )
    if args.json:
        out = dict(
            world=args.world,
            sampled=len(sample),
            sample_s=trials_s,
            load_s=load_s,
            parts_s=parts,
            mean_trial_s={k: sum(v) / len(v) for k, v in per_cell.items()},
            campaign_trials=len(full),
            campaign_worker_s=worker_s,
            campaign_wall_s=wall_s,
            workers=args.workers,
            efficiency=args.efficiency,
        )
        print(json.dumps(out))
    return 0


def time_sample(sample) -> tuple[dict[str, list[float]], dict[tuple, float], float]:
    """Each sampled trial's wall time per cell [s], each model's load time [s] (timed apart
    from its trials), and the whole sample's time [s]."""
    from threadpoolctl import threadpool_limits

    from rrg_experiments.trials import _env, _model, model_key, run_trial

    per_cell: dict[str, list[float]] = defaultdict(list)
    loads: dict[tuple, float] = {}  # model key → seconds to load its model and world
    t0 = time.perf_counter()
    with threadpool_limits(1):
        for spec in tqdm(sample, desc="timing", unit="trial", dynamic_ncols=True):
            cell = spec.cell
            key = model_key(cell.object, cell.level, spec.world, cell.without)
            if key not in loads:  # a worker's load of the model, timed apart from its trials
                t = time.perf_counter()
                _model(cell.object, cell.level, spec.world, cell.without)
                _env(cell.object, spec.world, "confirm" not in cell.without)
                loads[key] = time.perf_counter() - t
            per_cell[cell.key].append(run_trial(spec)["wall_s"])
    return per_cell, loads, time.perf_counter() - t0


def profile_sample(sample, profile_out: Path | None) -> dict[str, float]:
    """The sample again, under cProfile (its overhead stays out of the timing): seconds per
    part of the code (split_by_part)."""
    from threadpoolctl import threadpool_limits

    from rrg_experiments.trials import _env, _model, run_trial

    profiler = cProfile.Profile()
    with threadpool_limits(1):
        for spec in tqdm(sample, desc="profiling", unit="trial", dynamic_ncols=True):
            cell = spec.cell
            _model(cell.object, cell.level, spec.world, cell.without)  # loaded unprofiled
            _env(cell.object, spec.world, "confirm" not in cell.without)
            profiler.enable()
            run_trial(spec)
            profiler.disable()
    stats = pstats.Stats(profiler)
    if profile_out:
        stats.dump_stats(str(profile_out))
    return split_by_part(stats)
