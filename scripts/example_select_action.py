#!/usr/bin/env python3
r"""Ask RRG's planner for the next action, as other robot software would.

Builds a Gaussian belief over the object's pose (x, y, theta) on the level's grid itself
(41 x 41 x 33 at high uncertainty, 31 x 31 x 25 at low),
sends it to the ``/rrg/select_action`` service (rrg_msgs/SelectAction), and prints the answer.
It needs only rclpy, numpy and the rrg_msgs interfaces, not RRG's Python packages.

    # with the graph running (rrg-launch) in the same ROS_DOMAIN_ID:
    .venv/bin/python scripts/example_select_action.py \
        --object powerdrill --x 0.64 --y -0.02 --theta 0.2

The planner has observation tables for two grid spacings only (RRG's uncertainty levels):
high = 1 cm, 1 cm, 0.1 rad and low = 2 mm, 2 mm, 0.013 rad.
"""

from __future__ import annotations

import argparse
import array
import math
import sys

import numpy as np
import rclpy
from rclpy.executors import SingleThreadedExecutor

from rrg_msgs.msg import BeliefGrid
from rrg_msgs.srv import SelectAction

GRID_SHAPE = {
    "high": (41, 41, 33),
    "low": (31, 31, 25),
}  # points along x, y, theta (rrg_sim.config)
SPACING = {"high": (0.01, 0.01, 0.1), "low": (0.002, 0.002, 0.013)}  # [m, m, rad]
SIGMA = {
    "high": (0.05, 0.05, math.radians(30.0)),
    "low": (0.01, 0.01, math.radians(3.0)),
}  # [m, m, rad]


def gaussian_belief(mean: tuple[float, float, float], level: str) -> BeliefGrid:
    """N(mean, diag(sigma^2)) sampled on a grid centred at the mean, weights in C
    order (x, y, theta)."""
    spacing, sigma = np.array(SPACING[level]), np.array(SIGMA[level])
    axes = [
        (np.arange(n) - (n - 1) / 2) * s for n, s in zip(GRID_SHAPE[level], spacing)
    ]  # offsets from the mean
    dx, dy, dt = np.meshgrid(*axes, indexing="ij")
    w = np.exp(-0.5 * ((dx / sigma[0]) ** 2 + (dy / sigma[1]) ** 2 + (dt / sigma[2]) ** 2)).ravel()
    msg = BeliefGrid()
    msg.header.frame_id = "world"
    m = msg.metadata
    m.resolution_x, m.resolution_y, m.resolution_theta = (float(s) for s in spacing)
    m.size_x, m.size_y, m.size_theta = GRID_SHAPE[level]
    m.origin.x, m.origin.y, m.origin.theta = mean
    msg.weights = array.array("d", (w / w.sum()).tobytes())
    return msg


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--object", default="powerdrill")
    ap.add_argument("--x", type=float, default=0.62, help="mean x [m] in the WAM base frame")
    ap.add_argument("--y", type=float, default=0.0, help="mean y [m]")
    ap.add_argument("--theta", type=float, default=0.0, help="mean theta [rad]")
    ap.add_argument(
        "--level", choices=sorted(SPACING), default="high", help="grid spacing and sigma"
    )
    ap.add_argument("--strategy", default=SelectAction.Request.STRATEGY_RRG_INFO)
    ap.add_argument("--horizon", type=int, default=2)
    ap.add_argument("--delta", type=float, default=0.1)
    args = ap.parse_args()

    rclpy.init()
    node = rclpy.create_node("example_select_action")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        client = node.create_client(SelectAction, "/rrg/select_action")
        if not client.wait_for_service(timeout_sec=10.0):
            print(
                "no /rrg/select_action: is the graph running (rrg-launch) in this ROS_DOMAIN_ID?",
                file=sys.stderr,
            )
            return 1
        req = SelectAction.Request(
            belief=gaussian_belief((args.x, args.y, args.theta), args.level),
            object_name=args.object,
            strategy=args.strategy,
            horizon=args.horizon,
            delta=args.delta,
        )
        future = client.call_async(req)
        while not future.done():  # one persistent executor (works around an rclpy 7.1.6 slowdown)
            executor.spin_once(timeout_sec=0.1)
        resp = future.result()
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    if resp.error_code != SelectAction.Response.NONE:
        print(f"error {resp.error_code}: {resp.error_msg}", file=sys.stderr)
        return 1
    print(
        f"next action: {resp.wrt_name}  (value {resp.value:.3f}, P(goal) now {resp.p_goal:.3f}, "
        f"planned in {resp.planning_time * 1e3:.0f} ms)"
    )
    for name, value in zip(resp.action_names, resp.action_values):
        print(f"  {name:<14} {value:8.3f}" if math.isfinite(value) else f"  {name:<14} infeasible")
    return 0


if __name__ == "__main__":
    sys.exit(main())
