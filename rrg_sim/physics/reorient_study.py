"""Where a reorientation leaves the object: the reorientation study.

A reorientation WRT grasps the object, lifts it PHYSICS.reorient_lift, turns it about the
vertical through the estimate e and puts it down. Turned rigidly, an object at offset
Δ = relative_planar(e, w) ends at the same offset Δ from the turned estimate
e' = (e_x, e_y, e_θ + angle). It does not quite (MuJoCo): the closing fingers pull a handle
into the palm and the object slides as it is put down; the giant teacup ends some 0.05 rad
short of the turn. ``measure`` runs each of an object's reorientation WRTs from seeded starts
Δ ~ N(0, diag START_SIGMA²) and records, for every run whose grasp held the object
(goal.holds_object: the belief turns only then), Δ and the offset Δ' from e' after the
retreat. ``fit`` keeps the full turns (Δ'_θ within FULL_TURN_FRACTION of the angle of Δ_θ
or of 0; partial and failed turns are the transition's mixture) and gives the mean and σ of
Δ' - Δ, valid in a box of BOX_SIGMAS × START_SIGMA: the WRT's ``ReorientOutcome``. (An
affine fit Δ' = A·Δ + b explains more of the spread, the grasp pulling the object toward the
palm, but it lets the planner count on reorientations to localize the teacup, whose
reorientation grasp holds only within a few millimetres: in MuJoCo 32 of 40 teacup trials
succeed with it, against 36 with the mean shift.)

``python -m rrg_sim.physics.reorient_study [objects…] [--runs N] [--workers W]`` measures and
writes each object's ``reorientation.json`` into its folder, where the object loads it into
its reorientation WRTs.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rrg_models.config import REORIENT_MIN_FINGERS, WORLD
from rrg_models.goal import holds_object
from rrg_models.objects import PAPER_OBJECTS, get_object
from rrg_models.objects.object_model import REORIENTATION_FILE
from rrg_models.poses import compose_planar, relative_planar, wrap_angle
from rrg_models.trajectory import InfeasiblePath
from rrg_sim.physics.settle import run_study, study_args
from rrg_sim.physics.world import PhysicsWorld

#: σ of the start offsets Δ [m, m, rad] (chosen: the low uncertainty level's 1 cm in x, y and
#: a belief still some 6° wide in θ, as when the planner reorients).
START_SIGMA = np.array([0.01, 0.01, 0.1])
#: A run is a full turn when Δ'_θ lies within this fraction of the angle of Δ_θ or of 0.
FULL_TURN_FRACTION = 0.25
#: The fit holds for starts within this many START_SIGMA of e (chosen: ~ 95 % of the samples).
BOX_SIGMAS = 2.0


def measure(object_name: str, runs: int, seed: int = 0) -> list[dict]:
    """Run each reorientation WRT from ``runs`` seeded starts; one record per start whose
    grasp held the object: the WRT, Δ and Δ' (see the module doc)."""
    world = PhysicsWorld(object_name, seed=seed)
    rng = np.random.default_rng(seed)
    e = np.asarray(WORLD.nominal_pose, dtype=float)
    records = []
    for wrt in world.obj.reorient_wrts:
        for delta in rng.normal(size=(runs, 3)) * START_SIGMA:
            w = compose_planar(e, delta)
            world.reset(w)
            try:
                obs = world.execute_wrt(wrt, e)
            except InfeasiblePath:
                continue
            world.retreat()
            if not holds_object(obs.contact, obs.sensors, REORIENT_MIN_FINGERS):
                continue
            after = relative_planar(e + [0.0, 0.0, wrt.reorient_angle], world.true_object_pose())
            records.append(dict(wrt=wrt.name, start=delta.tolist(), after=after.tolist()))
    return records


class TooFewTurns(ValueError):
    """A reorientation WRT turned the object fully in too few runs to fit its outcome."""


def fit(object_name: str, records: list[dict]) -> dict:
    """Per reorientation WRT: runs that held, full turns, the box, and the mean (``shift``) and
    σ of Δ' - Δ over the full turns [m, m, rad] (θ 0 for an object whose goal ignores it)."""
    out = {}
    ignores = get_object(object_name).goal.ignores_theta
    for wrt in get_object(object_name).reorient_wrts:
        rows = [r for r in records if r["wrt"] == wrt.name]
        start = np.array([r["start"] for r in rows]).reshape(-1, 3)
        after = np.array([r["after"] for r in rows]).reshape(-1, 3)
        off = np.minimum(
            np.abs(wrap_angle(after[:, 2] - start[:, 2])), np.abs(wrap_angle(after[:, 2]))
        )
        full = off < FULL_TURN_FRACTION * abs(wrt.reorient_angle)
        if full.sum() < 8:
            raise TooFewTurns(
                f"{object_name}/{wrt.name}: only {full.sum()} of {len(rows)} runs turned it "
                "fully; too few to fit"
            )
        moved = after[full] - start[full]
        moved[:, 2] = 0.0 if ignores else wrap_angle(moved[:, 2])
        out[wrt.name] = dict(
            held=len(rows),
            full=int(full.sum()),
            box=(BOX_SIGMAS * START_SIGMA).tolist(),
            shift=np.round(moved.mean(axis=0), 5).tolist(),
            sigma=np.round(moved.std(axis=0, ddof=1), 5).tolist(),
        )
    return out


def _measure_job(args: tuple[str, int, int]) -> tuple[str, list[dict]]:
    name, runs, seed = args
    return name, measure(name, runs, seed)


def _report(name: str, fits: dict, records: list[dict]) -> str:
    return "\n".join(
        f"{name}/{w}: {f['full']}/{f['held']} full turns; shift {f['shift']} σ {f['sigma']}"
        for w, f in fits.items()
    )


def study(
    objects: list[str], runs: int, seed: int = 0, workers: int = 2, out_dir: Path | None = None
) -> None:
    """Measure and write each object's reorientation outcomes (``REORIENTATION_FILE``)."""
    run_study(
        objects,
        runs,
        seed,
        workers,
        REORIENTATION_FILE,
        _measure_job,
        fit,
        _report,
        "reorientation",
        f"python -m rrg_sim.physics.reorient_study --runs {runs} --seed {seed} "
        "(MuJoCo, reorientation WRTs at the nominal pose)",
        out_dir,
    )


def main(argv: list[str] | None = None) -> None:
    args = study_args(
        argv,
        __doc__,
        [n for n in PAPER_OBJECTS if get_object(n).reorient_wrts],
        "runs",
        40,
        "runs per reorientation WRT",
    )
    study(args.objects, args.runs, args.seed, args.workers, args.out_dir)


if __name__ == "__main__":
    main()
