"""``rrg-experiment``: reproduce the paper's Fig. 7, 8 and 9 in MuJoCo physics.

    rrg-experiment                 # the full campaign into results/paper/
    rrg-experiment --quick --out /tmp/quick
    rrg-experiment --replay 'powerdrill/high/rrg-info#17'   # one trial again, verbosely

A stopped run resumes: trials already in <out>/trials.jsonl are not run again. A replay needs
only the trial's id (and --seed, if the campaign had another).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

from rrg_estimator.config import LEVELS
from rrg_planner.config import SEARCH
from rrg_planner.experiment.report import write_outputs
from rrg_planner.experiment.trials import Cell, TrialSpec, run_campaign, run_trial
from rrg_planner.requests import STRATEGIES
from rrg_sim.objects import OBJECT_NAMES

QUICK = dict(objects=["box"], levels=["low", "high"], trials=2, fig9_trials=0)
FIG9_DELTAS = (0.5, 0.3, 0.1, 0.03)


def unknown_names(objects, levels, strategies) -> list[str]:
    """The objects, levels and strategies that the runner does not know."""
    return (
        [o for o in objects if o not in OBJECT_NAMES]
        + [lv for lv in levels if lv not in LEVELS]
        + [s for s in strategies if s not in STRATEGIES]
    )


def campaign_specs(objects, levels, strategies, trials, fig9_trials, seed) -> list[TrialSpec]:
    specs = [
        TrialSpec(Cell(o, lv, s), i, seed)
        for o in objects
        for lv in levels
        for s in strategies
        for i in range(trials)
    ]
    if fig9_trials:
        cells = [Cell("powerdrill", "high", "rrg-goal", delta=d) for d in FIG9_DELTAS]
        cells += [
            Cell("powerdrill", "high", "rrg-info", horizon=h, delta=d)
            for h in (1, 2, 3)
            for d in FIG9_DELTAS
        ]
        known = {s.cell for s in specs}
        specs += [
            TrialSpec(c, i, seed) for c in cells if c not in known for i in range(fig9_trials)
        ]
    return specs


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="rrg-experiment",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--quick", action="store_true", help=f"small preset for tests: {QUICK}")
    ap.add_argument("--objects", default=",".join(OBJECT_NAMES))
    ap.add_argument("--levels", default="low,high")
    ap.add_argument("--strategies", default=",".join(STRATEGIES))
    ap.add_argument("--trials", type=int, default=100, help="trials per cell")
    ap.add_argument(
        "--fig9-trials",
        type=int,
        default=60,
        help="trials per Fig. 9 point (0: skip Fig. 9); 60 keeps the campaign under an hour",
    )
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("results/paper"))
    ap.add_argument(
        "--replay",
        metavar="TRIAL_ID",
        help="run one trial alone (id as in trials.jsonl: cell key#index)",
    )
    args = ap.parse_args(argv)
    logging.basicConfig(
        level=logging.INFO if args.replay else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )
    if args.replay:
        cell_key, _, idx = args.replay.rpartition("#")
        try:
            cell = Cell.from_key(cell_key)
            index = int(idx)
        except ValueError as exc:
            print(
                f"bad trial id {args.replay!r} (e.g. 'box/high/rrg-info#3'): {exc}", file=sys.stderr
            )
            return 2
        bad = unknown_names([cell.object], [cell.level], [cell.strategy])
        if bad:
            print(f"bad trial id {args.replay!r}: unknown {bad}", file=sys.stderr)
            return 2
        print(json.dumps(run_trial(TrialSpec(cell, index, args.seed)), indent=1))
        return 0

    objects = QUICK["objects"] if args.quick else args.objects.split(",")
    levels = QUICK["levels"] if args.quick else args.levels.split(",")
    trials = QUICK["trials"] if args.quick else args.trials
    fig9_trials = QUICK["fig9_trials"] if args.quick else args.fig9_trials
    strategies = args.strategies.split(",")
    bad = unknown_names(objects, levels, strategies)
    if bad:
        print(f"unknown objects/levels/strategies: {bad}", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    specs = campaign_specs(objects, levels, strategies, trials, fig9_trials, args.seed)
    records = run_campaign(specs, args.out / "trials.jsonl", workers=args.workers)
    summary = write_outputs(records, args.out, objects, levels)
    print((args.out / "table.md").read_text())
    main_cells = [
        s for s in summary.values() if s["delta"] == SEARCH.delta and s["horizon"] == SEARCH.horizon
    ]
    print(f"{len(records)} trials in {len(main_cells)} main cells; outputs in {args.out}/")
    print(f"wall time: {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
