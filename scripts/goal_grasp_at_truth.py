"""How a goal grasp does when the robot knows exactly where the object is in its hand's frame.

    python scripts/goal_grasp_at_truth.py powerdrill can --draws 100 [--height touch|none|oracle]

For each draw of the world profile's conditions (joint offsets, table, friction, centre of mass,
pads), the goal grasp runs once at the nominal pose to find where the hand truly stands, then
again with the object placed there (so its planar calibration error is undone) and judged by
the campaign's judge (rrg_sim.physics.judge). ``--height``: ``touch`` the table first
(rrg_sim.table_touch, the realistic world's default), ``none``, or ``oracle``: the goal grasp
lowered by the hand's true vertical error. Prints the success rate and the failure reasons.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections import Counter

import numpy as np

from rrg_common.parallel import fork_map
from rrg_experiments.report import judged_failures
from rrg_models.config import WORLD
from rrg_models.poses import compose_planar, raised
from rrg_models.trajectory import InfeasiblePath
from rrg_sim.physics.judge import judge_grasp
from rrg_sim.physics.world import PhysicsWorld


def run(args: tuple[str, str, str, list[int]]) -> list[str]:
    """The outcome of each seed's grasp: "" for a success, else its reasons."""
    name, world_name, height, seeds = args
    world = PhysicsWorld(name, profile=world_name, touch_table=height == "touch")
    e = np.asarray(WORLD.nominal_pose, dtype=float)
    outcomes = []
    for seed in seeds:
        world.reseed(seed)
        world.reset(e)
        wrt = world.obj.goal_wrt
        try:
            world.execute_wrt(wrt, e)
        except InfeasiblePath:
            outcomes.append("infeasible")
            continue
        where = compose_planar(world.hand_pose_error(), e)
        if height == "oracle":
            dz = world.true_hand_pose()[2, 3] - world.hand_pose()[2, 3]
            wrt = dataclasses.replace(wrt, poses=raised(wrt.poses, -dz))
        world.reseed(seed)
        world.reset(where)
        try:
            obs = world.execute_wrt(wrt, e)
        except InfeasiblePath:
            outcomes.append("infeasible")
            continue
        success, judged = judge_grasp(world, world.obj, e, obs)
        early = ["early contact"] if judged["early_contact"] else []
        outcomes.append("" if success else ", ".join(early + judged_failures(judged)))
    return outcomes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("objects", nargs="+")
    parser.add_argument("--draws", type=int, default=100)
    parser.add_argument("--world", default="realistic")
    parser.add_argument("--height", choices=("touch", "none", "oracle"), default="touch")
    parser.add_argument("--seed", type=int, default=777)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    seeds = [
        int(np.random.SeedSequence([args.seed, i]).generate_state(1)[0]) for i in range(args.draws)
    ]
    for name in args.objects:
        jobs = [
            (name, args.world, args.height, seeds[k :: args.workers]) for k in range(args.workers)
        ]
        outcomes = [o for part in fork_map(run, jobs, args.workers) for o in part]
        judged = [o for o in outcomes if o != "infeasible"]
        ok = sum(o == "" for o in judged)
        print(
            f"{name} ({args.world}, height: {args.height}): {ok}/{len(judged)} succeeded "
            f"({100 * ok / max(len(judged), 1):.0f} %), {len(outcomes) - len(judged)} infeasible"
        )
        for reason, n in Counter(o for o in judged if o).most_common():
            print(f"  {n:3d}  {reason}")


if __name__ == "__main__":
    main()
