"""``rrg-bag``: inspect RRG's bags (rosbag2 layout, MCAP storage).

    rrg-bag info bags/NAME        topics, types, message counts, duration
    rrg-bag plot bags/NAME        PNGs of the belief over the actions (like the paper's Fig. 4)
    rrg-bag summary bags/NAME     actions, observations, P(goal) per step, outcome

The bag may be given as its folder or as its ``.mcap`` file. A bag whose recorder was killed
before it could write the MCAP summary is read by scanning its records instead.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mcap.exceptions import McapError

from rrg_planner.bags.bag_info import bag_info, format_info


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
    return parser


def run_plot(args: argparse.Namespace) -> None:
    from rrg_planner.bags.bag_plot import plot_bag

    bag = args.bag.parent if args.bag.is_file() else args.bag
    out = args.out or bag.with_name(f"{bag.name}_plots")
    paths = plot_bag(args.bag, out)
    print(f"wrote {len(paths)} PNGs to {out}: {', '.join(p.name for p in paths)}")


def run_summary(args: argparse.Namespace) -> None:
    from rrg_planner.bags.bag_summary import format_summary, summarize

    print(format_summary(summarize(args.bag)))


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        args.run(args)
    except (FileNotFoundError, McapError, ValueError) as exc:
        print(f"rrg-bag: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
