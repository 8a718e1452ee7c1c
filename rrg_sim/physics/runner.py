"""Execute one WRT τ(e) end to end in physics, through the core's IK
(algorithm §4, operations §8).

``run_wrt(world, wrt, e)`` checks F_τ(e) as the planner does (``wam.feasible_path``), runs
the guarded moves and the closing, optionally judges the grasp (lift and hold), and
retreats to home. ``python -m rrg_sim.physics.runner powerdrill --offset 0.02 0 0.1`` runs an
object's goal WRT relative to an estimate offset from the true pose and prints the result.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass

import numpy as np

from rrg_models import wam
from rrg_models.observation import Observation
from rrg_models.poses import compose_planar
from rrg_models.trajectory import InfeasiblePath
from rrg_models.wrt import WRT
from rrg_sim.physics.judge import judge_grasp
from rrg_sim.physics.world import PhysicsWorld


@dataclass
class WrtRun:
    """Outcome of one WRT execution in physics.

    feasible: F_τ(e) held and IK found a continuous path (else nothing moved).
    observation: what the robot sensed (None when infeasible).
    success / judge: the judged grasp (None unless judged).
    wall_s / sim_s: wall-clock and simulated time of the execution [s].
    """

    wrt: str
    kind: str
    e: np.ndarray
    feasible: bool
    observation: Observation | None = None
    success: bool | None = None
    judge: dict | None = None
    wall_s: float = 0.0
    sim_s: float = 0.0


def run_wrt(world: PhysicsWorld, wrt: WRT, e, judge: bool = False, retreat: bool = True) -> WrtRun:
    """Execute τ(e) in ``world``; with ``judge`` lift and hold the grasp and judge it against
    the world's object goal region (the hand then stays up); else retreat if asked."""
    e = np.asarray(e, dtype=float)
    run = WrtRun(wrt.name, wrt.kind, e, feasible=bool(wam.feasible_path(wrt.world_poses(e))))
    if not run.feasible:
        return run
    wall, sim = time.perf_counter(), world.sim_time
    try:
        run.observation = world.execute_wrt(wrt, e)
    except InfeasiblePath:
        run.feasible = False
        return run
    if judge:
        run.success, run.judge = judge_grasp(world, world.obj, e, goal=wrt.name)
    elif retreat:
        world.retreat()
    run.wall_s, run.sim_s = time.perf_counter() - wall, world.sim_time - sim
    return run


def main(argv: list[str] | None = None) -> int:
    """Run an object's WRT in physics relative to the true pose ⊕ an offset; print the outcome."""
    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("object")
    parser.add_argument("--wrt", default=None, help="WRT name (default: the goal WRT)")
    parser.add_argument(
        "--offset",
        type=float,
        nargs=3,
        default=(0.0, 0.0, 0.0),
        metavar=("DX", "DY", "DTH"),
        help="estimate error e ⊖ w in the object frame [m m rad]",
    )
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    world = PhysicsWorld(args.object, seed=args.seed)
    wrt = world.obj.goal_wrt if args.wrt is None else world.obj.wrt(args.wrt)
    e = compose_planar(world.true_object_pose(), np.asarray(args.offset))
    run = run_wrt(world, wrt, e, judge=wrt.kind == "goal")
    print(
        f"{args.object} / {wrt.name} ({wrt.kind}) at e = {np.round(e, 4)}: feasible {run.feasible}"
    )
    if run.observation is not None:
        o = run.observation
        print(
            f"  contact {o.contact}  progress {o.progress:.3f} m  closure {np.round(o.closure, 3)}"
        )
        print(
            f"  sensors {np.nonzero(o.sensors)[0].tolist()}  motion_dir {np.round(o.motion_dir, 3)}"
        )
    if run.judge is not None:
        print(f"  success {run.success}  {run.judge}")
    print(f"  wall {run.wall_s * 1000:.0f} ms  simulated {run.sim_s:.2f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
