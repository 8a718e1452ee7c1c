"""Replay 32 seeded campaign trials and print one JSON record per line; or compare two such
outputs, ignoring the timing fields (trials.TIMING_FIELDS).

    python scripts/replay_trials_check.py run [--prepare] > new.jsonl
    python scripts/replay_trials_check.py compare old.jsonl new.jsonl

The trials (base seed 4242, trial 0 of each cell): the ten paper objects × rrg-info/high/nominal
and × rrg-info/low/realistic, the first six × rrg-goal/high/nominal and × open-loop/high/realistic.
To run another tree's code, put it first on PYTHONPATH and run from its folder; the module
actually imported is reported on stderr.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

BASE_SEED = 4242


def specs() -> list:
    """The 32 trial specs: (strategy, level, world) × objects."""
    from rrg_planner.experiment.trials import Cell, TrialSpec
    from rrg_sim.objects import PAPER_OBJECTS

    groups = (
        ("rrg-info", "high", "nominal", PAPER_OBJECTS),
        ("rrg-info", "low", "realistic", PAPER_OBJECTS),
        ("rrg-goal", "high", "nominal", PAPER_OBJECTS[:6]),
        ("open-loop", "high", "realistic", PAPER_OBJECTS[:6]),
    )
    return [
        TrialSpec(Cell(obj, level, strategy), 0, BASE_SEED, world)
        for strategy, level, world, objects in groups
        for obj in objects
    ]


def run(prepare: bool) -> None:
    """Run every trial in this process and print its record."""
    import rrg_planner.search
    from rrg_planner.experiment.trials import prepare_models, run_trial

    print(f"search module: {rrg_planner.search.__file__}", file=sys.stderr, flush=True)
    todo = specs()
    if prepare:
        prepare_models(todo)
    for spec in todo:
        print(json.dumps(run_trial(spec)), flush=True)


def compare(old: Path, new: Path) -> int:
    """Print the trials whose records differ beyond timing; 0 if all are identical."""
    from rrg_planner.experiment.trials import load_records, outcome

    # as JSON text, so that NaN fields (p_goal of a failed trial) compare equal
    a = {r["id"]: json.dumps(outcome(r), sort_keys=True) for r in load_records(old)}
    b = {r["id"]: json.dumps(outcome(r), sort_keys=True) for r in load_records(new)}
    same = 0
    for trial_id in sorted(a.keys() | b.keys()):
        if a.get(trial_id) == b.get(trial_id):
            same += 1
            continue
        print(f"DIFFERS {trial_id}")
        ra, rb = json.loads(a.get(trial_id, "{}")), json.loads(b.get(trial_id, "{}"))
        for k in sorted(ra.keys() | rb.keys()):
            if json.dumps(ra.get(k)) != json.dumps(rb.get(k)):
                print(f"  {k}: {ra.get(k)!r} -> {rb.get(k)!r}")
    total = len(a.keys() | b.keys())
    print(f"{same}/{total} identical")
    return 0 if same == total == len(specs()) else 1


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("--prepare", action="store_true", help="build missing tables first")
    c = sub.add_parser("compare")
    c.add_argument("old", type=Path)
    c.add_argument("new", type=Path)
    args = ap.parse_args()
    if args.cmd == "run":
        run(args.prepare)
        return 0
    return compare(args.old, args.new)


if __name__ == "__main__":
    sys.exit(main())
