"""How a firm goal grasp moves the object it closes on: the grasp-settling study.

A goal grasp that arrives closes firmly, and the closing fingers pull the object toward
where the grasp settles it (a handle turns into the palm, a pinch twists a cup). The
belief must know, or it drifts from the truth with every goal grasp it does not stop on.
``measure`` runs the goal WRT from seeded start offsets Δ = relative_planar(e, w) drawn
uniformly in a box around the goal region, and records Δ after the closing (what the judge
sees) and after the retreat (where the next action finds the object). Each grasp is also
judged from a copy of the closed state (physics.judge): whether it made the goal's fingers
and required contacts and held through the lift and the hold, the rest of the success test.
``fit`` fits the affine maps Δ_after = A·Δ + b to the grasps that arrived (no early contact)
with least squares and their residual σ, and keeps those grasps' samples (Δ, Δ_closed,
Δ_retreated, held), with which the goal model and the belief's settling correct the affine
maps near each Δ and predict the hold (objects.Settling.outcome, Settling.hold_probability);
the result is the object's ``objects.Settling`` model.

``python -m rrg_sim.physics.settle [objects…] [--grasps N] [--workers W]`` measures and
writes each object's ``settling.json`` into its folder (rrg_models.objects.catalogue), where
the object loads it. ``--world realistic`` measures in that world profile instead, each grasp
with a trial's draws of its own (friction, centre of mass, table height, pads, the joint
offsets' vertical error), and writes ``settling.realistic.json`` (settling_file), which the
planner's goal model reads in that world (ObjectModel.settling_in). The offsets are then
taken from where the hand truly is at the grasp (PhysicsWorld.hand_pose_error, as the judge
takes them): the planar calibration error between postures is the posture frames' to model
(rrg_sim.posture_calibration), not the study's.
"""

from __future__ import annotations

import argparse
import copy
import json
import logging
import re
import time
from functools import partial
from pathlib import Path

import mujoco
import numpy as np
from tqdm import tqdm

from rrg_common.parallel import fork_map
from rrg_models.config import WORLD
from rrg_models.objects import PAPER_OBJECTS, get_object, object_folders
from rrg_models.objects.object_model import SETTLING_THETA_BOX, settling_file
from rrg_models.observation import fingers_in_contact
from rrg_models.poses import compose_planar, relative_planar, wrap_angle
from rrg_models.trajectory import InfeasiblePath
from rrg_sim.config import WORLD_PROFILES
from rrg_sim.physics.judge import judge_grasp
from rrg_sim.physics.world import PhysicsWorld

log = logging.getLogger(__name__)

#: The start box is this many goal tolerances wide each way (θ: at most SETTLING_THETA_BOX, or
#: the θ tolerance where that is wider, and ±π for objects whose goal ignores θ), so the fit
#: covers the goal region's edges.
BOX_TOLERANCES = 2.0


def start_box(object_name: str, goal_name: str = "goal") -> np.ndarray:
    """(3,) half-widths [m, m, rad] of the box of start offsets Δ the study of the goal grasp
    ``goal_name`` samples (about its own region)."""
    goal = get_object(object_name).goal_region(goal_name)
    cap = max(SETTLING_THETA_BOX, goal.tol[2])
    theta = np.pi if goal.ignores_theta else min(cap, BOX_TOLERANCES * goal.tol[2])
    return np.array([BOX_TOLERANCES * goal.tol[0], BOX_TOLERANCES * goal.tol[1], theta])


def measure(
    object_name: str, grasps: int, seed: int = 0, profile: str = "nominal", goal: str = "goal"
) -> list[dict]:
    """Run goal grasp ``goal`` from ``grasps`` seeded starts in world ``profile``; one record
    per start (see module doc)."""
    world = PhysicsWorld(object_name, seed=seed, profile=profile)
    wrt = world.obj.wrt(goal)
    rng = np.random.default_rng(seed)
    e = np.asarray(WORLD.nominal_pose, dtype=float)
    box = start_box(object_name, goal)
    records = []
    for i, delta in enumerate(rng.uniform(-1.0, 1.0, (grasps, 3)) * box):
        if world.profile.name != "nominal":  # a trial's draws of its own for every grasp
            world.reseed(int(np.random.SeedSequence([seed, i]).generate_state(1)[0]))
        w = compose_planar(e, delta)
        world.reset(w)
        try:
            obs = world.execute_wrt(wrt, e)
        except InfeasiblePath:
            continue
        e_hand = compose_planar(world.hand_pose_error(), e)  # e itself in the nominal world
        start = relative_planar(e_hand, w)
        closed = relative_planar(e_hand, world.true_object_pose())
        state = copy.copy(world.data)
        _, judged = judge_grasp(world, world.obj, e, obs, goal=goal)
        mujoco.mj_copyData(world.data, world.model, state)  # back to the closed hand
        world.retreat()
        after = relative_planar(e_hand, world.true_object_pose())
        records.append(
            dict(
                start=start.tolist(),
                closed=closed.tolist(),
                retreated=after.tolist(),
                contact=bool(obs.contact),
                fingers=int(fingers_in_contact(obs.sensors)),
                held=bool(judged["held"] and judged["required_ok"] and judged["fingers_ok"]),
            )
        )
    return records


def _unwrapped(after: np.ndarray, start: np.ndarray) -> np.ndarray:
    """``after`` with θ unwrapped next to ``start`` (a small turn never reads as ±2π)."""
    out = after.copy()
    out[:, 2] = start[:, 2] + wrap_angle(after[:, 2] - start[:, 2])
    return out


def fit_affine(start: np.ndarray, after: np.ndarray, ignores_theta: bool) -> dict:
    """Least-squares Δ_after = A·Δ + b over the rows; returns A (3,3), b (3,), sigma (3,)
    (the residuals' standard deviation). θ of an object whose goal ignores it is left as is
    (A row and column of the identity, b 0, σ 0): it turns freely and nothing depends on it."""
    after = _unwrapped(after, start)
    dims = 2 if ignores_theta else 3
    X = np.hstack([start[:, :dims], np.ones((len(start), 1))])
    coef, *_ = np.linalg.lstsq(X, after[:, :dims], rcond=None)
    A, b, sigma = np.eye(3), np.zeros(3), np.zeros(3)
    A[:dims, :dims], b[:dims] = coef[:dims].T, coef[dims]
    sigma[:dims] = np.std(after[:, :dims] - X @ coef, axis=0, ddof=dims + 1)
    return dict(A=A.tolist(), b=b.tolist(), sigma=sigma.tolist())


def fit(object_name: str, records: list[dict], goal: str = "goal") -> dict:
    """The settling model of an object's goal grasp ``goal`` from its records: the maps for
    the closing and the retreat, fitted to the grasps that arrived (no early contact)."""
    arrived = [r for r in records if not r["contact"]]
    if len(arrived) < 8:
        raise ValueError(
            f"{object_name}: only {len(arrived)} of {len(records)} grasps arrived; too few to fit"
        )
    start = np.array([r["start"] for r in arrived])
    closed = np.array([r["closed"] for r in arrived])
    retreated = np.array([r["retreated"] for r in arrived])
    ignores = get_object(object_name).goal.ignores_theta
    return dict(
        box=start_box(object_name, goal).tolist(),
        grasps=len(records),
        arrived=len(arrived),
        closed=fit_affine(start, closed, ignores),
        retreated=fit_affine(start, retreated, ignores),
        held=int(sum(r["held"] for r in arrived)),
        samples=dict(
            start=np.round(start, 5).tolist(),
            closed=np.round(_unwrapped(closed, start), 5).tolist(),
            retreated=np.round(_unwrapped(retreated, start), 5).tolist(),
            held=[int(r["held"]) for r in arrived],
        ),
    )


def _dumps(fits: dict) -> str:
    """The fits as indented JSON with every innermost list of numbers on one line."""
    text = json.dumps(fits, indent=1)
    return re.sub(
        r"\[\s*([-+0-9.eE,\s]+?)\s*\]", lambda m: "[" + re.sub(r"\s+", " ", m.group(1)) + "]", text
    )


def _measure_job(args: tuple[str, int, int, str, str]) -> tuple[str, list[dict]]:
    name, grasps, seed, profile, goal = args
    return name, measure(name, grasps, seed, profile, goal)


def run_study(
    objects: list[str],
    count: int,
    seed: int,
    workers: int,
    filename: str,
    measure_job,
    fit_fn,
    report,
    desc: str,
    source: str,
    out_dir: Path | None = None,
    extra: tuple = (),
) -> None:
    """Measure ``objects`` in parallel (measure_job((name, count, seed, *extra)) → (name,
    records)), fit each (fit_fn(name, records)), print report(name, fit, records), and write
    each fit with its ``source`` to ``filename`` in the object's folder (or in
    out_dir/<name>/). Shared by this study and physics.reorient_study."""
    folders = object_folders()
    t0 = time.perf_counter()
    jobs = [(name, count, seed, *extra) for name in objects]
    for name, records in tqdm(
        fork_map(measure_job, jobs, workers, ordered=False), total=len(jobs), desc=desc
    ):
        fit = fit_fn(name, records)
        print(report(name, fit, records), flush=True)
        folder = folders[name] if out_dir is None else out_dir / name
        folder.mkdir(parents=True, exist_ok=True)
        (folder / filename).write_text(_dumps({"source": source, **fit}) + "\n")
        print(f"wrote {folder / filename}")
    print(f"{desc}: {len(jobs)} objects in {time.perf_counter() - t0:.0f} s")


def _report(name: str, f: dict, records: list[dict]) -> str:
    c = f["closed"]
    return (
        f"{name}: {f['arrived']}/{len(records)} arrived, {f['held']} held; "
        f"closed b={np.round(c['b'], 3).tolist()} "
        f"σ={np.round(c['sigma'], 3).tolist()} diag(A)={np.round(np.diag(c['A']), 2).tolist()}"
    )


def study_args(
    argv: list[str] | None,
    doc: str,
    objects: list[str],
    count: str,
    count_default: int,
    count_help: str,
    worlds: tuple[str, ...] = (),
    goals: bool = False,
) -> argparse.Namespace:
    """The command line of a study: objects, --<count>, --seed, --workers, --out-dir,
    --world when ``worlds`` names the profiles it can run in, and --goal (the goal grasp
    measured) with ``goals``."""
    parser = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    parser.add_argument(
        "objects", nargs="*", default=objects, help="objects (default: %(default)s)"
    )
    parser.add_argument(f"--{count}", type=int, default=count_default, help=count_help)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument(
        "--out-dir",
        type=Path,
        help="write <out-dir>/<object>/<fit file> (default: into each object's folder)",
    )
    if worlds:
        parser.add_argument("--world", choices=worlds, default="nominal", help="world profile")
    if goals:
        parser.add_argument(
            "--goal", default="goal", help="the goal grasp measured (default: %(default)s)"
        )
    return parser.parse_args(argv)


def study(
    objects: list[str],
    grasps: int,
    seed: int = 0,
    workers: int = 2,
    out_dir: Path | None = None,
    profile: str = "nominal",
    goal: str = "goal",
) -> None:
    """Measure and write the settling fit of each object's goal grasp ``goal``
    (settling_file(profile, goal) in its folder)."""
    run_study(
        objects,
        grasps,
        seed,
        workers,
        settling_file(profile, goal),
        _measure_job,
        partial(fit, goal=goal),
        _report,
        "settling",
        _source(grasps, seed, profile, goal),
        out_dir,
        extra=(profile, goal),
    )


def goal_studies(
    name: str,
    goals: tuple[str, ...],
    grasps: int,
    seed: int = 0,
    workers: int = 2,
    profile: str = "nominal",
) -> dict[str, str]:
    """Measure and write the settling fit of each of object ``name``'s goal grasps ``goals``
    in world ``profile``, one job per goal grasp on ``workers`` processes; returns why, for
    each goal grasp too few of whose grasps arrived to fit (none written)."""
    folder = object_folders()[name]
    jobs = [(name, grasps, seed, profile, goal) for goal in goals]
    unfitted = {}
    for goal, (_, records) in zip(goals, fork_map(_measure_job, jobs, workers)):
        try:
            f = fit(name, records, goal)
        except ValueError as exc:
            unfitted[goal] = str(exc)
            continue
        print(_report(name, f, records), flush=True)
        text = _dumps({"source": _source(grasps, seed, profile, goal), **f})
        (folder / settling_file(profile, goal)).write_text(text + "\n")
    return unfitted


def _source(grasps: int, seed: int, profile: str, goal: str) -> str:
    """The command that measures a settling study, as its file records it."""
    return (
        f"python -m rrg_sim.physics.settle --grasps {grasps} --seed {seed}"
        + ("" if profile == "nominal" else f" --world {profile}")
        + ("" if goal == "goal" else f" --goal {goal}")
        + f" (MuJoCo, goal grasp {goal} at the nominal pose)"
    )


def main(argv: list[str] | None = None) -> None:
    args = study_args(
        argv,
        __doc__,
        list(PAPER_OBJECTS),
        "grasps",
        60,
        "goal grasps per object",
        worlds=tuple(WORLD_PROFILES),
        goals=True,
    )
    study(args.objects, args.grasps, args.seed, args.workers, args.out_dir, args.world, args.goal)


if __name__ == "__main__":
    main()
