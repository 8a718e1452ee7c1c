"""``rrg-experiment``: reproduce the paper's Fig. 7, 8 and 9 in MuJoCo physics.

    rrg-experiment --world realistic   # the full campaign into results/realistic/
    rrg-experiment                     # the nominal world into results/paper/
    rrg-experiment --dev --quick --out /tmp/quick
    rrg-experiment --replay 'powerdrill/high/rrg-info#17' --seed 1234   # one trial, verbosely
    rrg-experiment --replay 'box/low/open-loop#0' 'cup/high/rrg-goal#3' --seed 1234 > before.jsonl
    rrg-experiment --replay-check before.jsonl   # the same records from this code?

The base seed comes from the code version (its git commit), so a campaign runs on trials no
earlier version was tuned on; --seed sets it, and --dev uses the development seed for probes
whose results are not to be reported. A stopped run resumes: trials already in
<out>/trials.jsonl are not run again, and records of another code version, seed or world are
refused.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from collections.abc import Iterator
from pathlib import Path

from rrg_estimator.config import LEVELS
from rrg_experiments.provenance import DEV_SEED, campaign_seed, code_version
from rrg_experiments.report import write_outputs
from rrg_experiments.trials import (
    CAPABILITIES,
    CampaignMismatch,
    Cell,
    TrialSpec,
    added_fields,
    imap_trials,
    load_records,
    prepare_models,
    record_differences,
    run_campaign,
    spec_of,
)
from rrg_models.objects import PAPER_OBJECTS, object_names
from rrg_planner.config import SEARCH
from rrg_planner.request_checks import STRATEGIES
from rrg_sim.config import PROFILE_KNOBS, WORLD_PROFILES, world_spec

QUICK = dict(objects=["box"], levels=["low", "high"], trials=2, fig9_trials=0)
FIG9_DELTAS = (0.5, 0.3, 0.1, 0.03)


def unknown_names(objects, levels, strategies) -> list[str]:
    """The objects, levels and strategies that the runner does not know."""
    installed = object_names()
    return (
        [o for o in objects if o not in installed]
        + [lv for lv in levels if lv not in LEVELS]
        + [s for s in strategies if s not in STRATEGIES]
    )


#: Where each world profile's campaign goes by default.
DEFAULT_OUT = {"nominal": Path("results/paper"), "realistic": Path("results/realistic")}


def campaign_specs(
    objects, levels, strategies, trials, fig9_trials, seed, world="nominal", ablate=()
) -> list[TrialSpec]:
    """Every trial of a campaign: the main cells, then Fig. 9's δ and horizon sweep on the
    drill at high uncertainty (its cells that the main ones already hold are not repeated);
    with ``ablate`` (capabilities, trials.CAPABILITIES), RRG-Info's main cells again with each
    of them switched off in turn, on the same trials."""
    specs = [
        TrialSpec(Cell(o, lv, s), i, seed, world)
        for o in objects
        for lv in levels
        for s in strategies
        for i in range(trials)
    ]
    specs += [
        TrialSpec(Cell(o, lv, "rrg-info", without=(c,)), i, seed, world)
        for c in ablate
        for o in objects
        for lv in levels
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
            TrialSpec(c, i, seed, world)
            for c in cells
            if c not in known
            for i in range(fig9_trials)
        ]
    return specs


def base_seed(version: str, seed: int | None, dev: bool) -> tuple[int, str]:
    """The campaign's base seed and where it came from: --seed, --dev, or the code version."""
    if seed is not None:
        return seed, "--seed"
    if dev:
        return DEV_SEED, "--dev"
    return campaign_seed(version), "code version"


def add_seed_options(ap: argparse.ArgumentParser) -> None:
    """--seed and --dev (mutually exclusive)."""
    group = ap.add_mutually_exclusive_group()
    group.add_argument("--seed", type=int, help="base seed (default: drawn from the code version)")
    group.add_argument(
        "--dev", action="store_true", help=f"the development seed ({DEV_SEED}): for probes only"
    )


def build_parser() -> argparse.ArgumentParser:
    """``rrg-experiment``'s arguments."""
    ap = argparse.ArgumentParser(
        prog="rrg-experiment",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--quick", action="store_true", help=f"small preset for tests: {QUICK}")
    ap.add_argument(
        "--objects", default=",".join(PAPER_OBJECTS), help="installed objects (rrg-object list)"
    )
    ap.add_argument("--levels", default="low,high")
    ap.add_argument("--strategies", default=",".join(STRATEGIES))
    ap.add_argument("--trials", type=int, default=100, help="trials per cell")
    ap.add_argument(
        "--fig9-trials", type=int, default=100, help="trials per Fig. 9 point (0: skip Fig. 9)"
    )
    ap.add_argument(
        "--world",
        type=world_spec,
        default="nominal",
        help=f"world profile: {', '.join(WORLD_PROFILES)}, or one with some of "
        f"{', '.join(PROFILE_KNOBS)} set, e.g. realistic:joint_offset_sigma=0.0025 "
        "(rrg_sim.config.world_profile)",
    )
    ap.add_argument(
        "--ablate",
        default="",
        help="also run RRG-Info with each of these capabilities switched off in turn "
        f"({','.join(CAPABILITIES)}, or all)",
    )
    ap.add_argument("--workers", type=int, default=2, help="worker processes (or Ray CPUs)")
    ap.add_argument(
        "--ray",
        metavar="ADDRESS",
        help="run the trials on Ray: 'auto' (a running cluster, else a local one of --workers "
        "CPUs) or a cluster address",
    )
    add_seed_options(ap)
    ap.add_argument(
        "--out", type=Path, help="output folder (default: results/paper, or results/realistic)"
    )
    ap.add_argument(
        "--report",
        action="store_true",
        help="run nothing: write the tables and figures again from <out>/trials.jsonl, "
        "for the code version, seed and world its records were made with",
    )
    ap.add_argument(
        "--replay",
        nargs="+",
        metavar="TRIAL_ID",
        help="run these trials (ids as in trials.jsonl: cell key#index) at --seed and --world, "
        "and write their records on standard output, a JSON line each (one trial: with its log)",
    )
    ap.add_argument(
        "--replay-check",
        type=Path,
        metavar="RECORDS",
        help="run every trial of a JSONL file of records (a campaign's or --replay's) again, at "
        "its own base seed and world, and print those whose records differ beyond the timing "
        "fields and the code version; status 1 if any does",
    )
    return ap


def main(argv: list[str] | None = None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    logging.basicConfig(
        level=logging.INFO if args.replay and len(args.replay) == 1 else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )
    version = code_version()
    seed, seed_source = base_seed(version, args.seed, args.dev)
    if args.replay_check:
        return replay_check(args.replay_check, version, args.workers)
    if args.replay:
        return replay(args.replay, seed, args.world, version, args.workers)

    objects = QUICK["objects"] if args.quick else args.objects.split(",")
    levels = QUICK["levels"] if args.quick else args.levels.split(",")
    trials = QUICK["trials"] if args.quick else args.trials
    fig9_trials = QUICK["fig9_trials"] if args.quick else args.fig9_trials
    strategies = args.strategies.split(",")
    bad = unknown_names(objects, levels, strategies)
    if bad:
        print(f"unknown objects/levels/strategies: {bad}", file=sys.stderr)
        return 2
    if args.out is None and args.world not in DEFAULT_OUT:
        ap.error(f"--world {args.world} needs --out")
    ablate = CAPABILITIES if args.ablate == "all" else tuple(filter(None, args.ablate.split(",")))
    if set(ablate) - set(CAPABILITIES):
        ap.error(f"--ablate: unknown {sorted(set(ablate) - set(CAPABILITIES))}")
    out = args.out or DEFAULT_OUT[args.world]
    if args.report:
        return report_only(out, objects, levels)
    specs = campaign_specs(
        objects, levels, strategies, trials, fig9_trials, seed, args.world, ablate
    )
    return run_and_report(
        specs,
        out,
        objects,
        levels,
        (version, seed, seed_source, args.world),
        args.workers,
        args.ray,
    )


def parse_trial_id(trial_id: str, seed: int, world: str) -> TrialSpec:
    """The trial an id (cell key#index) names; ValueError for a malformed id or an unknown
    object, level or strategy."""
    cell_key, _, index = trial_id.rpartition("#")
    try:
        cell, i = Cell.from_key(cell_key), int(index)
    except ValueError as exc:
        raise ValueError(f"bad trial id {trial_id!r} (e.g. 'box/high/rrg-info#3'): {exc}") from exc
    bad = unknown_names([cell.object], [cell.level], [cell.strategy])
    if bad:
        raise ValueError(f"bad trial id {trial_id!r}: unknown {bad}")
    return TrialSpec(cell, i, seed, world)


def run_records(specs: list[TrialSpec], version: str, workers: int) -> Iterator[dict]:
    """Run the trials (tables built first, with progress bars); yields each record, stamped
    with the code version, as it finishes."""
    prepare_models(specs)
    for record in imap_trials(specs, workers, desc="replay"):
        yield dict(record, commit=version)


def replay(ids: list[str], seed: int, world: str, version: str, workers: int) -> int:
    """Run the trials ``ids`` and print their records as JSON lines (status 2 for a bad id)."""
    try:
        specs = [parse_trial_id(i, seed, world) for i in ids]
    except ValueError as exc:
        print(exc, file=sys.stderr)
        return 2
    for record in run_records(specs, version, workers if len(specs) > 1 else 1):
        print(json.dumps(record), flush=True)
    return 0


def replay_check(path: Path, version: str, workers: int) -> int:
    """Run the trials of the records in ``path`` again and print the ones whose records
    differ; 0 when every one is the same, 1 otherwise, 2 when there is nothing to run."""
    key = lambda r: (r["id"], r["world"], r["base_seed"])  # one id runs in several worlds
    old = {key(r): r for r in load_records(path)}
    if not old:
        print(f"error: no trial records in {path}", file=sys.stderr)
        return 2
    specs = [spec_of(r) for r in old.values()]
    differing, added = 0, set()
    for record in run_records(specs, version, workers):
        changes = record_differences(old[key(record)], record)
        added.update(added_fields(old[key(record)], record))
        if changes:
            differing += 1
            print(f"DIFFERS {record['id']} ({record['world']}, base seed {record['base_seed']})")
            print("\n".join(f"  {c}" for c in changes), flush=True)
    print(f"{len(old) - differing}/{len(old)} trials gave the same records (code {version})")
    if added:
        print(f"fields the old records do not have: {', '.join(sorted(added))}")
    return 1 if differing else 0


def report_only(out: Path, objects: list[str], levels: list[str]) -> int:
    """Write the outputs of the records in ``out`` again (status 2 when there are none)."""
    records = load_records(out / "trials.jsonl")
    if not records:
        print(f"error: no trial records in {out / 'trials.jsonl'}", file=sys.stderr)
        return 2
    first = records[0]
    seed = first["base_seed"]
    source = {campaign_seed(first["commit"]): "code version", DEV_SEED: "--dev"}.get(seed, "--seed")
    campaign = dict(commit=first["commit"], seed=seed, seed_source=source, world=first["world"])
    objects = [o for o in objects if any(r["object"] == o for r in records)]
    levels = [lv for lv in levels if any(r["level"] == lv for r in records)]
    write_outputs(records, out, objects, levels, campaign)
    print((out / "table.md").read_text())
    return 0


def run_and_report(
    specs: list[TrialSpec],
    out: Path,
    objects: list[str],
    levels: list[str],
    provenance: tuple[str, int, str, str],
    workers: int,
    ray: str | None = None,
) -> int:
    """Run (or resume) the trials into ``out``, write the tables and figures, and print the
    success table; provenance is (code version, base seed, where the seed came from, world).
    Returns the exit status: 2 when ``out`` holds another campaign's records."""
    version, seed, seed_source, world = provenance
    if "+dirty" in version:
        print(f"note: uncommitted changes to the code: version {version}", file=sys.stderr)
    print(f"code {version}, base seed {seed} ({seed_source}), world {world}", flush=True)
    t0 = time.perf_counter()
    try:
        records = run_campaign(specs, out / "trials.jsonl", version, workers=workers, ray=ray)
    except CampaignMismatch as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    campaign = dict(commit=version, seed=seed, seed_source=seed_source, world=world)
    summary = write_outputs(records, out, objects, levels, campaign)
    print((out / "table.md").read_text())
    main_cells = [
        s
        for s in summary["cells"].values()
        if s["delta"] == SEARCH.delta and s["horizon"] == SEARCH.horizon
    ]
    print(f"{len(records)} trials in {len(main_cells)} main cells; outputs in {out}/")
    print(f"wall time: {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
