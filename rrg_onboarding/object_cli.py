"""``rrg-object``: the installed objects.

    rrg-object add MESH --name NAME [--units mm] [--up y] [--mass KG] [--goal-through X Y Z]
    rrg-object check NAME [--trials 20]   # a short physics campaign and its success table
    rrg-object list              # every installed object: built-in or user, and what it has
    rrg-object remove NAME       # delete a user object and its cached observation tables

``add`` onboards a mesh file (STL, OBJ, PLY) in stages (rrg_onboarding.onboard):
check and stand the mesh, decompose it, choose or take the goal grasp, write the object file,
run the physics studies, build the tables and render the goal grasp.

User objects live in ``$RRG_OBJECTS_DIR`` (default ``~/.local/share/rrg/objects``); the
paper's ten ship with the package and cannot be removed. Every CLI and node takes an
installed object by its name.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

from rrg_estimator.obs_tables import DEFAULT_CACHE_DIR
from rrg_models.objects import (
    PAPER_OBJECTS,
    ObjectFileError,
    get_object,
    object_folders,
    unknown_object_message,
    user_objects_dir,
)
from rrg_models.objects.mesh_import import UNITS_M, UP_AXES
from rrg_models.objects.object_model import REORIENTATION_FILE, SETTLING_FILE

from .onboard import (
    DEFAULT_FRICTION,
    DEFAULT_TOL,
    FUNNEL_SCALES,
    RANKING_GRASPS,
    SETTLE_GRASPS,
    AddOptions,
    GoalSpec,
    OnboardError,
    add_object,
)


def cached_tables(name: str, cache_dir: Path = DEFAULT_CACHE_DIR) -> list[Path]:
    """The object's observation tables in the cache (rrg_estimator.obs_tables file names)."""
    return sorted(Path(cache_dir).glob(f"{name}__*.npz"))


def describe(name: str, folder: Path) -> str:
    """One line about an installed object: origin, parts, mass, studies, tables, goal."""
    origin = "built-in" if name in PAPER_OBJECTS else "user"
    studies = [f for f in (SETTLING_FILE, REORIENTATION_FILE) if (folder / f).exists()]
    try:
        obj = get_object(name)
    except ObjectFileError as exc:
        return f"{name:14s} {origin:8s} INVALID: {exc}"
    return (
        f"{name:14s} {origin:8s} {len(obj.parts):3d} parts {obj.mass:6.3f} kg  "
        f"studies: {', '.join(s.removesuffix('.json') for s in studies) or 'none':24s} "
        f"tables: {len(cached_tables(name)):2d}  {obj.description}"
    )


def cmd_list(args: argparse.Namespace) -> int:
    folders = object_folders()
    for name, folder in folders.items():
        print(describe(name, folder))
    print(f"{len(folders)} objects; user objects in {user_objects_dir()}")
    return 0


def remove_object(name: str, cache_dir: Path = DEFAULT_CACHE_DIR) -> Path:
    """Delete the user object ``name`` and its tables cached in ``cache_dir``; returns its
    folder. KeyError if it is not installed, ValueError for a built-in one."""
    folders = object_folders()
    if name not in folders:
        raise KeyError(unknown_object_message(name))
    if name in PAPER_OBJECTS:
        raise ValueError(f"{name!r} is built in (one of the paper's objects): not removed")
    for table in cached_tables(name, cache_dir):
        table.unlink()
    shutil.rmtree(folders[name])
    return folders[name]


def cmd_remove(args: argparse.Namespace) -> int:
    try:
        folder = remove_object(args.name)
    except (KeyError, ValueError) as exc:
        print(f"rrg-object remove: {exc.args[0]}", file=sys.stderr)
        return 2
    print(f"removed {args.name} ({folder}) and its cached tables")
    return 0


def cmd_add(args: argparse.Namespace) -> int:
    goal = None
    if args.goal_through is not None:
        goal = GoalSpec(
            through_m=tuple(args.goal_through),
            approach=args.goal_approach,
            yaw_rad=args.goal_yaw,
            pitch_rad=args.goal_pitch,
            roll_rad=args.goal_roll,
            standoff_m=args.goal_standoff,
            spread_rad=args.goal_spread,
            tol=DEFAULT_TOL if args.goal_tol is None else tuple(args.goal_tol),
        )
    options = AddOptions(
        args.mesh,
        args.name,
        units=args.units,
        up=args.up,
        mass_kg=args.mass,
        friction=args.friction,
        goal=goal,
        goal_tol=None if args.goal_tol is None else tuple(args.goal_tol),
        allow_size=args.allow_size,
        settle_grasps=args.settle_grasps,
        ranking_grasps=args.ranking_grasps,
        workers=args.workers,
        seed=args.seed,
    )
    try:
        report = add_object(options)
    except OnboardError as exc:
        print(f"rrg-object add: {exc} (nothing was installed)", file=sys.stderr)
        return 2
    total = sum(report.stage_s.values())
    print("stage times: " + ", ".join(f"{k} {v:.1f} s" for k, v in report.stage_s.items()))
    print(f"total {total:.0f} s; rrg-launch --grasp {args.name} runs it")
    return 0


#: What ``check`` runs: both levels, RRG-Info against open-loop (chosen: the paper's Fig. 7
#: contrast), 20 trials per cell by default (about a minute per object on two cores).
CHECK_LEVELS = ["low", "high"]
CHECK_STRATEGIES = ["rrg-info", "open-loop"]
CHECK_TRIALS = 20


def cmd_check(args: argparse.Namespace) -> int:
    from rrg_experiments.experiment_cli import base_seed, campaign_specs, run_and_report
    from rrg_experiments.provenance import code_version

    if args.name not in object_folders():
        print(f"rrg-object check: {unknown_object_message(args.name)}", file=sys.stderr)
        return 2
    if args.trials < 1:
        print("rrg-object check: --trials must be at least 1", file=sys.stderr)
        return 2
    version = code_version()
    seed, seed_source = base_seed(version, args.seed, args.dev)
    out = args.out or Path("results/check") / args.name
    specs = campaign_specs(
        [args.name], CHECK_LEVELS, CHECK_STRATEGIES, args.trials, 0, seed, args.world
    )
    return run_and_report(
        specs,
        out,
        [args.name],
        CHECK_LEVELS,
        (version, seed, seed_source, args.world),
        args.workers,
    )


def _check_parser(sub) -> None:
    from rrg_experiments.experiment_cli import add_seed_options
    from rrg_sim.config import WORLD_PROFILES

    check = sub.add_parser(
        "check", help="a short physics campaign: RRG-Info and open-loop at both levels"
    )
    check.add_argument("name")
    check.add_argument("--trials", type=int, default=CHECK_TRIALS, help="trials per cell")
    check.add_argument("--world", default="nominal", choices=list(WORLD_PROFILES))
    check.add_argument("--workers", type=int, default=2)
    check.add_argument("--out", type=Path, help="output folder (default: results/check/NAME)")
    add_seed_options(check)
    check.set_defaults(run=cmd_check)


def _add_parser(sub) -> None:
    add = sub.add_parser("add", help="onboard a mesh file as a new object")
    add.add_argument("mesh", type=Path, help="STL, OBJ or PLY file")
    add.add_argument("--name", required=True, help="the new object's name")
    add.add_argument("--units", default="m", choices=list(UNITS_M), help="the mesh's units")
    add.add_argument("--up", default="z", choices=list(UP_AXES), help="the mesh's up axis")
    add.add_argument("--mass", type=float, help="mass [kg] (default: volume at 1000 kg/m³)")
    add.add_argument("--friction", type=float, default=DEFAULT_FRICTION)
    add.add_argument("--allow-size", action="store_true", help="accept a size outside 0.02-0.6 m")
    goal = add.add_argument_group("goal grasp (default: proposed from the mesh)")
    goal.add_argument("--goal-through", type=float, nargs=3, metavar=("X", "Y", "Z"))
    goal.add_argument("--goal-approach", default="top_down", choices=["top_down", "side"])
    goal.add_argument("--goal-yaw", type=float, default=0.0, help="[rad]")
    goal.add_argument("--goal-pitch", type=float, default=0.0, help="side approach [rad]")
    goal.add_argument("--goal-roll", type=float, default=0.0, help="side approach [rad]")
    goal.add_argument("--goal-standoff", type=float, default=0.0, help="[m]")
    goal.add_argument("--goal-spread", type=float, default=0.0, help="[rad]")
    goal.add_argument(
        "--goal-tol",
        type=float,
        nargs=3,
        metavar=("DX", "DY", "DTHETA"),
        help=f"goal region [m, m, rad] (default: measured, from {DEFAULT_TOL[0]}, "
        f"{DEFAULT_TOL[1]}, {DEFAULT_TOL[2]:.3f} up to {FUNNEL_SCALES[-1]:g} times it; inf "
        "ignores θ)",
    )
    add.add_argument(
        "--settle-grasps", type=int, default=SETTLE_GRASPS, help="settling study grasps"
    )
    add.add_argument(
        "--ranking-grasps", type=int, default=RANKING_GRASPS, help="grasps per goal candidate"
    )
    add.add_argument("--workers", type=int, default=2)
    add.add_argument("--seed", type=int, default=0, help="seeds CoACD and the studies")
    add.set_defaults(run=cmd_add)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="rrg-object", description=__doc__.split("\n\n")[0].strip("`: ")
    )
    sub = parser.add_subparsers(dest="command", required=True)
    _add_parser(sub)
    _check_parser(sub)
    sub.add_parser("list", help="every installed object").set_defaults(run=cmd_list)
    remove = sub.add_parser("remove", help="delete a user object and its cached tables")
    remove.add_argument("name")
    remove.set_defaults(run=cmd_remove)
    args = parser.parse_args(argv)
    return args.run(args)


if __name__ == "__main__":
    sys.exit(main())
