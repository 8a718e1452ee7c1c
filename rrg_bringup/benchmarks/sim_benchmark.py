"""``rrg-bench sim``: speed of the physics world.

Times full goal-WRT executions at each object's true pose: IK and guarded moves through the
waypoints, closing, and the judged lift with its 2 s hold. With ``--json`` the last printed
line is one JSON object: wrt_exec_ms (median wall time of one execution), wrt_exec_ms_max,
realtime_factor (simulated / wall time over all executions), sim_s_per_exec, steps_per_s
(raw free-space stepping), successes, runs, objects.
"""

from __future__ import annotations

import argparse
import json
import time

import mujoco
import numpy as np

from rrg_models.objects import PAPER_OBJECTS
from rrg_sim.physics.judge import judge_grasp
from rrg_sim.physics.world import PhysicsWorld


def _time_goal(world: PhysicsWorld) -> tuple[float, float, bool]:
    """(wall [s], simulated [s], judged success) of one goal WRT + judged lift from a reset."""
    world.reset()
    e = world.true_object_pose()
    wall, sim = time.perf_counter(), world.sim_time
    world.execute_wrt(world.obj.goal_wrt, e)
    ok, _ = judge_grasp(world, world.obj, e)
    return time.perf_counter() - wall, world.sim_time - sim, ok


def bench_sim(argv: list[str] | None = None) -> int:
    """Run the physics benchmark (see the module doc); returns the exit code."""
    parser = argparse.ArgumentParser(prog="rrg-bench sim", description="Physics world speed.")
    parser.add_argument("--objects", nargs="*", default=list(PAPER_OBJECTS))
    parser.add_argument("--runs", type=int, default=1, help="timed executions per object")
    parser.add_argument(
        "--json", action="store_true", help="print the figures as JSON on the last line"
    )
    args = parser.parse_args(argv)

    walls, sims, oks, steps_per_s = [], [], [], []
    for name in args.objects:
        world = PhysicsWorld(name, seed=0)
        _time_goal(world)  # warm-up: caches, first-call costs
        runs = [_time_goal(world) for _ in range(args.runs)]
        w, s, ok = (np.array(v) for v in zip(*runs))
        walls += w.tolist()
        sims += s.tolist()
        oks += ok.tolist()
        print(
            f"{name:14s} goal WRT + judged lift: {1000 * np.median(w):6.1f} ms wall, "
            f"{np.mean(s):.2f} s simulated, success {int(ok.sum())}/{len(ok)}"
        )
        world.reset()
        t = time.perf_counter()
        mujoco.mj_step(world.model, world.data, nstep=1000)
        steps_per_s.append(1000 / (time.perf_counter() - t))

    figures = dict(
        objects=len(args.objects),
        runs=len(walls),
        successes=int(np.sum(oks)),
        wrt_exec_ms=round(1000 * float(np.median(walls)), 1),
        wrt_exec_ms_max=round(1000 * float(np.max(walls)), 1),
        realtime_factor=round(float(np.sum(sims) / np.sum(walls)), 1),
        sim_s_per_exec=round(float(np.mean(sims)), 3),
        steps_per_s=round(float(np.median(steps_per_s))),
    )
    print(
        f"one goal WRT execution: median {figures['wrt_exec_ms']} ms, "
        f"max {figures['wrt_exec_ms_max']} ms (target ≤ 100 ms); "
        f"real-time factor {figures['realtime_factor']}× (target ≥ 20×); "
        f"free-space stepping {figures['steps_per_s']} steps/s"
    )
    if args.json:
        print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    raise SystemExit(bench_sim())
