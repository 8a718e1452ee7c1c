"""How far physics observations are from the geometric simulator's predictions.

The geometric simulator (rrg_sim.geometric_sim) is the planning core's model of an
execution: the object never moves. ``compare`` runs one WRT τ(e) in physics with the object
at w and diffs the observation against ``GeometricSimulator.simulate(w, e)``;
``agreement_stats`` summarizes many such diffs (the numbers behind config.LIKELIHOOD's σs).
``python -m rrg_sim.physics.agreement [--offsets N] [--json]`` measures them over the
catalogue's goal and info WRTs at seeded estimate errors.
"""

from __future__ import annotations

import argparse
import json
import logging
from dataclasses import asdict, dataclass

import numpy as np

from rrg_models.config import HAND, WORLD
from rrg_models.objects import PAPER_OBJECTS, get_object
from rrg_models.observation import Observation
from rrg_models.poses import compose_planar
from rrg_models.trajectory import InfeasiblePath
from rrg_models.wrt import WRT
from rrg_sim.geometric_sim import GeometricSimulator
from rrg_sim.physics.world import PhysicsWorld

log = logging.getLogger(__name__)

#: The object counts as still when the execution moved it less than this [m] (the geometric
#: simulator's assumption; bumped objects are the transition model's business).
STILL = 0.005
#: A finger "closed on something" below this proximal angle [rad] (its limit is 2.44).
OPEN_LIMIT = HAND.proximal_range[1] - 0.05


@dataclass
class ObservationDiff:
    """Physics minus geometric prediction for one execution (see module doc).

    moved: object displacement in the plane during the execution [m].
    closure: (3,) |Δ| [rad] per finger, NaN unless both closed on something.
    tip: (3,) Nano17 contact point distance [m], NaN unless both sensed a contact.
    """

    obj: str
    wrt: str
    contact_agree: bool
    both_contact: bool
    progress: float
    hamming: int
    detected: int  # predicted sensors that fired
    predicted: int
    false_alarms: int  # fired sensors not predicted
    unpredicted: int
    closure: list[float]
    tip: list[float]
    moved: float


def diff(
    physics: Observation, predicted: Observation, obj: str, wrt: str, moved: float
) -> ObservationDiff:
    """Diff one physics observation against the geometric prediction."""
    both = (physics.closure < OPEN_LIMIT) & (predicted.closure < OPEN_LIMIT)
    return ObservationDiff(
        obj=obj,
        wrt=wrt,
        contact_agree=physics.contact == predicted.contact,
        both_contact=bool(physics.contact and predicted.contact),
        progress=float(physics.progress - predicted.progress),
        hamming=int(np.sum(physics.sensors != predicted.sensors)),
        detected=int(np.sum(physics.sensors & predicted.sensors)),
        predicted=int(predicted.sensors.sum()),
        false_alarms=int(np.sum(physics.sensors & ~predicted.sensors)),
        unpredicted=int((~predicted.sensors).sum()),
        closure=np.where(both, np.abs(physics.closure - predicted.closure), np.nan).tolist(),
        tip=np.linalg.norm(physics.tip_points - predicted.tip_points, axis=1).tolist(),
        moved=moved,
    )


def compare(
    world: PhysicsWorld, wrt: WRT, w, e, geo: GeometricSimulator | None = None
) -> ObservationDiff:
    """Run τ(e) in physics with the object placed at w (then retreat), and diff it against
    the geometric prediction for the same (w, e)."""
    w = np.asarray(w, dtype=float)
    world.reset(w)
    obs = world.execute_wrt(wrt, e)
    moved = float(np.linalg.norm(world.true_object_pose()[:2] - w[:2]))
    world.retreat()
    predicted = (geo or GeometricSimulator(world.obj, wrt)).simulate(w, e)
    return diff(obs, predicted, world.obj.name, wrt.name, moved)


def agreement_stats(diffs: list[ObservationDiff]) -> dict:
    """Summary over the executions that left the object still (module constant STILL)."""
    still = [d for d in diffs if d.moved < STILL]
    closure = np.array([c for d in still for c in d.closure])
    tip = np.array([t for d in still for t in d.tip])
    progress = np.abs([d.progress for d in still if d.both_contact])
    closure, tip = closure[np.isfinite(closure)], tip[np.isfinite(tip)]
    return dict(
        runs=len(diffs),
        still=len(still),
        contact_agreement=float(np.mean([d.contact_agree for d in still])),
        progress_abs_max=float(progress.max(initial=0.0)),
        hamming_hist=np.bincount([d.hamming for d in still], minlength=3).tolist(),
        p_detect=float(sum(d.detected for d in still) / max(1, sum(d.predicted for d in still))),
        p_false_alarm=float(
            sum(d.false_alarms for d in still) / max(1, sum(d.unpredicted for d in still))
        ),
        closure_abs_mean=float(closure.mean()) if closure.size else float("nan"),
        closure_abs_p90=float(np.percentile(closure, 90)) if closure.size else float("nan"),
        tip_dist_median=float(np.median(tip)) if tip.size else float("nan"),
        tip_dist_p90=float(np.percentile(tip, 90)) if tip.size else float("nan"),
    )


def measure(
    names=PAPER_OBJECTS,
    kinds=("goal", "info"),
    offsets: int = 3,
    sigma=(0.015, 0.015, 0.1),
    seed: int = 0,
) -> list[ObservationDiff]:
    """Diffs for every (object, WRT of the given kinds) at Δ = 0 and offsets-1 seeded Gaussian
    estimate errors Δ = e ⊖ w (σ in m, m, rad), the object at the nominal pose; an execution
    the arm cannot make (InfeasiblePath) is skipped."""
    rng = np.random.default_rng(seed)
    w = np.asarray(WORLD.nominal_pose, dtype=float)
    out = []
    for name in names:
        world = PhysicsWorld(name, seed=seed)
        for wrt in get_object(name).wrts():
            if wrt.kind not in kinds:
                continue
            geo = GeometricSimulator(world.obj, wrt)
            for k in range(offsets):
                error = np.zeros(3) if k == 0 else rng.normal(0.0, sigma)
                try:
                    out.append(compare(world, wrt, w, compose_planar(w, error), geo))
                except InfeasiblePath:  # the arm cannot run τ(e) there: nothing to compare
                    log.info(
                        "%s/%s infeasible at Δ=%s", name, wrt.name, np.round(error, 3).tolist()
                    )
    return out


def main(argv: list[str] | None = None) -> int:
    """Measure physics-vs-geometric agreement over the catalogue; print the summary."""
    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("--offsets", type=int, default=3)
    parser.add_argument("--json", action="store_true", help="also print every diff as JSON lines")
    args = parser.parse_args(argv)
    diffs = measure(offsets=args.offsets)
    if args.json:
        for d in diffs:
            print(json.dumps(asdict(d)))
    print(json.dumps(agreement_stats(diffs)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
