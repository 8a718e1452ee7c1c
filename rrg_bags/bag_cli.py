"""``rrg-bag``: inspect RRG's bags (rosbag2 layout, MCAP storage).

    rrg-bag info bags/NAME        topics, types, message counts, duration
    rrg-bag plot bags/NAME        PNGs of the belief over the actions (like the paper's Fig. 4)
    rrg-bag summary bags/NAME     actions, observations, P(goal) per step, outcome
    rrg-bag replay bags/NAME      the estimator (--planner: and the planner) again on its events

The bag may be given as its folder or as its ``.mcap`` file. A bag whose recorder was killed
before it could write the MCAP summary is read by scanning its records instead. ``replay``
exits with 0 when it reproduced the recording, 1 when it did not, and 2 for a bag it cannot
replay.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from mcap.exceptions import McapError

from rrg_bags.bag_info import bag_info, format_info
from rrg_planner.config import REPLAY_TOLERANCE, SEARCH


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="rrg-bag", description="Inspect RRG's MCAP bags.")
    commands = parser.add_subparsers(dest="command", required=True)
    info = commands.add_parser("info", help="topics, types, message counts and duration")
    info.add_argument("bag", type=Path, help="bag folder (bags/NAME) or its .mcap file")
    info.set_defaults(run=lambda a: print(format_info(bag_info(a.bag))))
    plot = commands.add_parser(
        "plot", help="PNGs of the belief over the actions (x-y and theta marginals)"
    )
    plot.add_argument("bag", type=Path, help="bag folder (bags/NAME) or its .mcap file")
    plot.add_argument(
        "--out", type=Path, default=None, help="output folder (default: <bag>_plots beside the bag)"
    )
    plot.set_defaults(run=run_plot)
    summary = commands.add_parser(
        "summary", help="actions, observations, P(goal) per step and outcome"
    )
    summary.add_argument("bag", type=Path, help="bag folder (bags/NAME) or its .mcap file")
    summary.set_defaults(run=run_summary)
    replay = commands.add_parser(
        "replay",
        help="the estimator again on the recorded observations and retreats, compared with the "
        "recorded beliefs (--planner: the decisions too)",
    )
    replay.add_argument("bag", type=Path, help="bag folder (bags/NAME) or its .mcap file")
    replay.add_argument(
        "--planner",
        action="store_true",
        help="also make every recorded decision again on the replayed belief",
    )
    replay.add_argument(
        "--levels",
        help="the planner's levels, comma-separated (default: the recorded planner's); "
        "implies --planner",
    )
    replay.add_argument(
        "--horizon", type=int, help="search depth H (default: the recorded); implies --planner"
    )
    replay.add_argument("--delta", type=float, help="δ (default: the recorded); implies --planner")
    replay.add_argument(
        "--max-actions",
        type=int,
        help=f"the grasp's action limit (not recorded; default {SEARCH.max_actions}); "
        "implies --planner",
    )
    replay.add_argument(
        "--tolerance",
        type=float,
        default=REPLAY_TOLERANCE,
        help=f"largest |Δp| of a reproduced belief (default {REPLAY_TOLERANCE:g})",
    )
    replay.add_argument(
        "--json", action="store_true", help="also print the replay as one JSON object, last"
    )
    replay.set_defaults(run=run_replay)
    return parser


def run_plot(args: argparse.Namespace) -> None:
    from rrg_bags.bag_plot import plot_bag

    bag = args.bag.parent if args.bag.is_file() else args.bag
    out = args.out or bag.with_name(f"{bag.name}_plots")
    paths = plot_bag(args.bag, out)
    print(f"wrote {len(paths)} PNGs to {out}: {', '.join(p.name for p in paths)}")


def run_summary(args: argparse.Namespace) -> None:
    from rrg_bags.bag_summary import format_summary, summarize

    print(format_summary(summarize(args.bag)))


def replay_settings(args: argparse.Namespace) -> dict:
    """The planner settings asked for, checked (InvalidRequest otherwise)."""
    from rrg_planner.request_checks import check_level, check_search, max_actions

    levels = None
    if args.levels is not None:
        levels = tuple(lv.strip() for lv in args.levels.split(",") if lv.strip())
        for level in levels or ("",):
            check_level(level)
    check_search(
        SEARCH.horizon if args.horizon is None else args.horizon,
        SEARCH.delta if args.delta is None else args.delta,
    )
    if args.max_actions is not None:
        max_actions(args.max_actions)
    return dict(levels=levels, horizon=args.horizon, delta=args.delta, max_actions=args.max_actions)


def run_replay(args: argparse.Namespace) -> int:
    from rrg_bags.bag_replay import UnusableBag, format_replay, replay_bag
    from rrg_planner.request_checks import InvalidRequest

    try:
        settings = replay_settings(args)
    except InvalidRequest as exc:
        print(f"rrg-bag replay: {exc}", file=sys.stderr)
        return 2
    planner = args.planner or any(v is not None for v in settings.values())
    logging.basicConfig(level=logging.WARNING, format="rrg-bag: %(message)s")
    logging.getLogger("rrg_estimator.obs_tables").setLevel(logging.INFO)  # a missing table: ~1 min
    try:
        replay = replay_bag(args.bag, planner, tolerance=args.tolerance, **settings)
    except UnusableBag as exc:
        print(f"rrg-bag replay: {exc}", file=sys.stderr)
        return 2
    print(format_replay(replay))
    if args.json:
        print(json.dumps(replay.to_dict()))
    return 0 if replay.reproduced else 1


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.run(args) or 0
    except (FileNotFoundError, McapError, ValueError) as exc:
        print(f"rrg-bag: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
