#!/usr/bin/env python3
r"""Ask RRG's planner for the next action, as other robot software would, with RRGClient.

Sends a Gaussian belief over the object's pose (x, y, theta), sampled on the uncertainty
level's grid, to the ``/rrg/select_action`` service and prints the answer.

    # with the graph running (rrg-launch) in the same ROS_DOMAIN_ID:
    .venv/bin/python scripts/example_select_action.py \
        --object powerdrill --x 0.64 --y -0.02 --theta 0.2

The planner has observation tables for its levels' grid spacings only:
high = 1 cm, 1 cm, 0.1 rad, mid = 5 mm, 5 mm, 0.05 rad and low = 2 mm, 2 mm, 0.013 rad.
"""

from __future__ import annotations

import argparse
import math
import sys

from rrg_planner.client import STRATEGIES, Gaussian, RRGClient, RRGError


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--object", default="powerdrill")
    ap.add_argument("--x", type=float, default=0.62, help="mean x [m] in the WAM base frame")
    ap.add_argument("--y", type=float, default=0.0, help="mean y [m]")
    ap.add_argument("--theta", type=float, default=0.0, help="mean theta [rad]")
    ap.add_argument("--level", choices=("high", "mid", "low"), default="high")
    ap.add_argument("--strategy", choices=STRATEGIES, default=STRATEGIES[0])
    ap.add_argument("--horizon", type=int, default=2)
    ap.add_argument("--delta", type=float, default=0.1)
    ap.add_argument("--timeout", type=float, default=10.0, help="wait for the graph [s]")
    args = ap.parse_args()

    with RRGClient(node_name="example_select_action") as rrg:
        try:
            rrg.wait_until_ready(args.timeout)
            choice = rrg.select_action(
                args.object,
                Gaussian((args.x, args.y, args.theta), level=args.level),
                strategy=args.strategy,
                horizon=args.horizon,
                delta=args.delta,
            )
        except RRGError as exc:
            print(exc, file=sys.stderr)
            return 1
    print(
        f"next action: {choice.wrt_name}  (value {choice.value:.3f}, P(goal) now "
        f"{choice.p_goal:.3f}, planned in {choice.planning_time_s * 1e3:.0f} ms)"
    )
    for name, value in choice.values.items():
        print(f"  {name:<14} {value:8.3f}" if math.isfinite(value) else f"  {name:<14} infeasible")
    return 0


if __name__ == "__main__":
    sys.exit(main())
