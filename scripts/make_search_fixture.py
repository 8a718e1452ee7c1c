"""Record ForwardSearch's decisions on seeded beliefs into tests/data/search_decisions.json.

    python scripts/make_search_fixture.py

tests/rrg_planner/test_search_equivalence.py rebuilds the same beliefs (``belief_of``: from
each case's model, level, kind and seed) and replays them against the search: a change to the
search's speed must leave these decisions as recorded. The beliefs: centred on the nominal
pose (exactly symmetric, and with noise), off-centre, two-peaked, at a corner of the grid, and
posteriors after one or two simulated readings; the box and giant teacup of
tests/rrg_planner/test_search.py on their small grids, and the powerdrill, giant teacup and box
(symmetric) on the high and low grids, the drill also in the realistic world (beliefs in its
readings' frames).
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from rrg_estimator.belief import Belief
from rrg_estimator.config import LEVELS, UncertaintyLevel
from rrg_estimator.grid import Grid
from rrg_estimator.obs_model import likelihood_params
from rrg_estimator.update import update
from rrg_models.config import WORLD
from rrg_models.poses import compose_planar
from rrg_planner.config import SEARCH
from rrg_planner.planning_model import PlanningModel
from rrg_planner.search import ForwardSearch
from rrg_sim.geometric_sim import GeometricSimulator

FIXTURE = Path(__file__).resolve().parents[1] / "tests" / "data" / "search_decisions.json"

#: tests/rrg_planner/test_search.py's small grids (the same levels, so the same cached tables)
SMALL = UncertaintyLevel(
    "small", sigma=(0.02, 0.02, 0.2), spacing=(0.01, 0.01, 0.1), shape=(9, 9, 5)
)
TURNS = UncertaintyLevel(
    "turns", sigma=(0.02, 0.02, 0.2), spacing=(0.01, 0.01, 0.08), shape=(9, 9, 7)
)

#: model key → (object, levels, world, WRT names or None for all)
MODELS: dict[str, tuple[str, tuple[UncertaintyLevel, ...], str, tuple[str, ...] | None]] = {
    "box-small": ("box", (SMALL,), "nominal", None),
    "teacup-turns": (
        "giant_teacup",
        (TURNS,),
        "nominal",
        ("goal", "info_handle", "reorient_ccw", "reorient_cw"),
    ),
    "powerdrill": ("powerdrill", (LEVELS["high"], LEVELS["low"]), "nominal", None),
    "giant_teacup": ("giant_teacup", (LEVELS["high"], LEVELS["low"]), "nominal", None),
    "box": ("box", (LEVELS["high"], LEVELS["low"]), "nominal", None),
    "powerdrill-realistic": ("powerdrill", (LEVELS["low"],), "realistic", None),
}


def build_model(key: str) -> PlanningModel:
    """The planning model a case's key names (tables from the on-disk cache, or built)."""
    obj, levels, world, names = MODELS[key]
    return PlanningModel(obj, levels=levels, progress=False, world=world, wrt_names=names)


def _level(model: PlanningModel, name: str) -> UncertaintyLevel:
    return model.levels[name]


def _noisy(belief: Belief, rng: np.random.Generator) -> Belief:
    """The belief's weights times seeded noise in [0.8, 1.2] (no exact ties)."""
    return Belief(belief.grid, belief.weights * rng.uniform(0.8, 1.2, belief.weights.size))


def _cells(level: UncertaintyLevel, cells) -> np.ndarray:
    """An offset (3,) [m, m, rad] of ``cells`` grid steps."""
    return np.asarray(cells, dtype=float) * np.asarray(level.spacing)


def centred(model: PlanningModel, level: UncertaintyLevel, rng: np.random.Generator) -> Belief:
    """The level's initial belief, centred on the nominal pose (exact mirror ties)."""
    return Belief.for_level(level, np.asarray(WORLD.nominal_pose))


def centred_noisy(
    model: PlanningModel, level: UncertaintyLevel, rng: np.random.Generator
) -> Belief:
    """The initial belief with σ scaled by 0.4-1.0 and seeded noise."""
    mean = np.asarray(WORLD.nominal_pose)
    grid = Grid.for_level(level, center=mean)
    sigma = np.asarray(level.sigma) * rng.uniform(0.4, 1.0, 3)
    return _noisy(Belief.gaussian(grid, mean, sigma), rng)


def off_centre(model: PlanningModel, level: UncertaintyLevel, rng: np.random.Generator) -> Belief:
    """A Gaussian whose mean lies 1.5-6 cells off the grid's centre in x, y and θ."""
    mean = np.asarray(WORLD.nominal_pose)
    grid = Grid.for_level(level, center=mean)
    offset = _cells(level, rng.uniform(1.5, 6.0, 3) * rng.choice([-1.0, 1.0], 3))
    sigma = np.asarray(level.sigma) * rng.uniform(0.2, 0.8, 3)
    return _noisy(Belief.gaussian(grid, compose_planar(mean, offset), sigma), rng)


def two_peaked(model: PlanningModel, level: UncertaintyLevel, rng: np.random.Generator) -> Belief:
    """Two narrow Gaussians on opposite sides of the grid's centre (weights 0.55 and 0.45)."""
    mean = np.asarray(WORLD.nominal_pose)
    grid = Grid.for_level(level, center=mean)
    d = _cells(level, rng.uniform(1.5, 4.0, 3))
    sigma = np.asarray(level.sigma) * rng.uniform(0.15, 0.4, 3)
    peaks = [Belief.gaussian(grid, compose_planar(mean, s * d), sigma).weights for s in (1.0, -1.0)]
    return _noisy(Belief(grid, 0.55 * peaks[0] + 0.45 * peaks[1]), rng)


def edge_of_grid(model: PlanningModel, level: UncertaintyLevel, rng: np.random.Generator) -> Belief:
    """A Gaussian centred on a corner of the grid (x and y at their last points)."""
    mean = np.asarray(WORLD.nominal_pose)
    grid = Grid.for_level(level, center=mean)
    half = (np.asarray(level.shape) - 1) / 2
    corner = _cells(level, half * rng.choice([-1.0, 1.0], 3) * np.array([1.0, 1.0, 0.3]))
    sigma = np.asarray(level.sigma) * rng.uniform(0.2, 0.6, 3)
    return _noisy(Belief.gaussian(grid, compose_planar(mean, corner), sigma), rng)


def posterior(model: PlanningModel, level: UncertaintyLevel, rng: np.random.Generator) -> Belief:
    """The initial belief after one or two readings of seeded actions, the object at a seeded
    true pose; in the readings' frame where the model has frames."""
    mean = np.asarray(WORLD.nominal_pose)
    b = Belief.for_level(level, mean)
    true = compose_planar(mean, rng.normal(0.0, level.sigma))
    frame = ""
    for _ in range(int(rng.integers(1, 3))):
        a = int(rng.integers(len(model.actions)))
        act = model.actions[a]
        e = b.w_star()
        obs = GeometricSimulator(model.obj, act.wrt).simulate(true, e)
        b = update(b, act.tables[level.name], e, obs, params=likelihood_params(act.wrt))
        frame = model.reading_frame(a, frame)
    return Belief(b.grid, b.weights, frame)


KINDS: dict[str, Callable[[PlanningModel, UncertaintyLevel, np.random.Generator], Belief]] = {
    "centred": centred,
    "centred-noisy": centred_noisy,
    "off-centre": off_centre,
    "two-peaked": two_peaked,
    "edge-of-grid": edge_of_grid,
    "posterior": posterior,
}


def belief_of(case: dict, model: PlanningModel) -> Belief:
    """The case's belief, rebuilt from its kind and seed."""
    level = _level(model, case["level"])
    return KINDS[case["kind"]](model, level, np.random.default_rng(case["seed"]))


def checksum(belief: Belief) -> float:
    """A number that changes with the belief (to catch beliefs rebuilt differently)."""
    w = belief.weights
    return float(w @ np.cos(np.arange(len(w)) * 0.001))


def cases() -> list[dict]:
    """Every case: model, level, belief kind and seed, horizon and δ (in replay order)."""
    out = []
    plan = [  # model, level, beliefs per kind, horizons cycled over, H = 3 cases
        ("box-small", "small", 3, (1, 2), 2),
        ("teacup-turns", "turns", 3, (1, 2), 2),
        ("powerdrill", "high", 6, (1, 1, 2), 2),
        ("powerdrill", "low", 6, (1, 1, 2), 1),
        ("giant_teacup", "high", 5, (1, 1, 2), 1),
        ("giant_teacup", "low", 5, (1, 1, 2), 1),
        ("box", "high", 5, (1, 1, 2), 1),
        ("box", "low", 5, (1, 1, 2), 1),
        ("powerdrill-realistic", "low", 4, (1, 2), 0),
    ]
    seed = 1000
    for model, level, per_kind, horizons, n_h3 in plan:
        group = []
        for kind in KINDS:
            for _ in range(1 if kind == "centred" else per_kind):
                seed += 1
                group.append(dict(model=model, level=level, kind=kind, seed=seed))
        for i, case in enumerate(group):
            case["horizon"] = horizons[i % len(horizons)]
            case["delta"] = (SEARCH.delta, 0.3)[(i // len(horizons)) % 2]
        # H = 3 on the first beliefs of the kinds most unlike the centred one
        picks = [c for c in group if c["kind"] in ("posterior", "two-peaked", "off-centre")]
        for case in picks[::-1][:n_h3]:
            case["horizon"] = 3
        out += group
    return out


def record(search: ForwardSearch, belief: Belief, case: dict) -> dict:
    """The case with the search's decision on its belief."""
    res = search.select(belief, case["horizon"], case["delta"])
    e = belief.w_star()
    return dict(
        case,
        checksum=checksum(belief),
        action=res.action,
        value=res.value,
        action_values=[float(v) for v in res.action_values],
        p_goal=res.p_goal,
        goal_action=res.goal_action,
        goal_estimate=None if res.goal_estimate is None else [float(v) for v in res.goal_estimate],
        feasible=[search.feasible(a, e) for a in range(len(search.model.actions))],
    )


def main() -> int:
    models: dict[str, PlanningModel] = {}
    searches: dict[str, ForwardSearch] = {}
    out = []
    t0 = time.perf_counter()
    for case in cases():
        key = case["model"]
        if key not in models:
            models[key] = build_model(key)
            searches[key] = ForwardSearch(models[key])  # one per model, as an agent's
        out.append(record(searches[key], belief_of(case, models[key]), case))
        print(
            f"{len(out):4d} {key}/{case['level']} {case['kind']} H={case['horizon']} "
            f"δ={case['delta']}: action {out[-1]['action']} ({time.perf_counter() - t0:.0f} s)",
            file=sys.stderr,
            flush=True,
        )
    FIXTURE.parent.mkdir(parents=True, exist_ok=True)
    FIXTURE.write_text(json.dumps(out, indent=0) + "\n")
    print(f"{len(out)} cases -> {FIXTURE} ({FIXTURE.stat().st_size / 1e3:.0f} kB)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
