"""Seeded, resumable physics trials: objects × levels × strategies (× horizons × δ) × N.

Each trial's true pose is drawn from the initial belief's Gaussian (the paper: "placed at
random positions drawn from the same distribution as the initial uncertainty"), seeded by
(base seed, object, level, trial index) only, so every strategy faces the same poses. Any
trial replays alone from its id (cell key and index) and the base seed. Results append to a
JSONL file, one line per trial, so a stopped campaign resumes where it left off.
"""

from __future__ import annotations

import json
import logging
import multiprocessing as mp
import time
import zlib
from collections.abc import Iterable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from rrg_estimator.config import LEVELS
from rrg_planner.config import SEARCH
from rrg_sim.config import WORLD
from rrg_sim.poses import compose_planar

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Cell:
    """One experimental condition."""

    object: str
    level: str
    strategy: str
    horizon: int = SEARCH.horizon
    delta: float = SEARCH.delta

    @property
    def key(self) -> str:
        """e.g. 'powerdrill/high/rrg-info' (H and δ appended when not the defaults)."""
        k = f"{self.object}/{self.level}/{self.strategy}"
        if self.strategy == "rrg-info" and self.horizon != SEARCH.horizon:
            k += f"/H{self.horizon}"
        if self.delta != SEARCH.delta:
            k += f"/d{self.delta:g}"
        return k

    @classmethod
    def from_key(cls, key: str) -> Cell:
        """The cell a ``key`` names (its inverse); ValueError for anything else."""
        parts = key.split("/")
        if len(parts) < 3:
            raise ValueError(f"cell key {key!r} is not object/level/strategy[/H<h>][/d<δ>]")
        kw = {}
        for part in parts[3:]:
            if part[:1] == "H" and part[1:].isdigit():
                kw["horizon"] = int(part[1:])
            elif part[:1] == "d":
                kw["delta"] = float(part[1:])  # ValueError if it is no number
            else:
                raise ValueError(f"cell key {key!r}: unexpected {part!r}")
        cell = cls(*parts[:3], **kw)
        if cell.key != key:  # repeated or reordered parts, or default H/δ written out
            raise ValueError(f"cell key {key!r} is not canonical (expected {cell.key!r})")
        return cell


@dataclass(frozen=True)
class TrialSpec:
    cell: Cell
    index: int
    base_seed: int

    @property
    def seed(self) -> int:
        """Depends on the object, level and index only: strategies are compared on the same
        poses."""
        return zlib.crc32(
            f"{self.base_seed}/{self.cell.object}/{self.cell.level}/{self.index}".encode()
        )

    @property
    def id(self) -> str:
        return f"{self.cell.key}#{self.index}"

    def true_pose(self) -> np.ndarray:
        rng = np.random.default_rng(self.seed)
        return compose_planar(
            np.asarray(WORLD.nominal_pose), rng.normal(0.0, LEVELS[self.cell.level].sigma)
        )


def model_levels(level: str) -> tuple[str, ...]:
    """Tables a level needs: high also loads every finer level, for the variable-resolution grid."""
    return tuple(LEVELS) if level == "high" else (level,)


# ------------------------------------------------------------ worker process
_MODELS: dict = {}
_ENVS: dict = {}


def _model(obj: str, level: str):
    from rrg_planner.planning_model import PlanningModel

    key = (obj, model_levels(level))
    if key not in _MODELS:
        _MODELS[key] = PlanningModel(
            obj, levels=key[1], workers=1, progress=False
        )  # no nested pools
    return _MODELS[key]


def _env(obj: str):
    from rrg_planner.physics_env import PhysicsEnvironment

    if obj not in _ENVS:
        _ENVS[obj] = PhysicsEnvironment.for_object(obj)
    return _ENVS[obj]


def run_trial(spec: TrialSpec) -> dict:
    """Run one physics trial and return its JSON-able record."""
    from rrg_planner.agent import RobustGraspAgent
    from rrg_planner.closed_loop import run_in_process

    cell = spec.cell
    t0 = time.perf_counter()
    true = spec.true_pose()
    env = _env(cell.object)
    env.reset(true, seed=spec.seed)
    agent = RobustGraspAgent(
        _model(cell.object, cell.level),
        strategy=cell.strategy,
        horizon=cell.horizon,
        delta=cell.delta,
    )
    try:
        res = run_in_process(agent, env, cell.level, WORLD.nominal_pose)
        out = dict(
            success=res.success,
            declared=res.declared,
            n_actions=res.n_actions,
            actions=[s.wrt for s in res.steps],
            p_goal=res.p_goal,
            planning_time_s=res.planning_time,
            error=res.error,
            judge=_jsonable(env.last_judgement),
        )
    except Exception as exc:
        log.exception("trial %s failed", spec.id)
        out = dict(
            success=False,
            declared=False,
            n_actions=0,
            actions=[],
            p_goal=float("nan"),
            planning_time_s=0.0,
            error=f"{type(exc).__name__}: {exc}",
            judge={},
        )
    return dict(
        id=spec.id,
        cell=cell.key,
        **asdict(cell),
        trial=spec.index,
        seed=spec.seed,
        true_pose=[float(v) for v in true],
        wall_s=time.perf_counter() - t0,
        **out,
    )


def _jsonable(info: dict) -> dict:
    """The judge's findings as plain JSON values (numpy scalars and bools converted)."""
    return {
        k: (
            v.tolist()
            if isinstance(v, np.ndarray)
            else v.item()
            if isinstance(v, np.generic)
            else v
        )
        for k, v in info.items()
    }


# ------------------------------------------------------------------ campaign
def load_records(path: Path) -> list[dict]:
    """Records already in a JSONL file (a torn last line from a killed run is ignored)."""
    if not path.exists():
        return []
    records = []
    for line in path.read_text().splitlines():
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:
            log.warning("ignoring a torn line in %s", path)
    return records


def prepare_models(specs: Iterable[TrialSpec]) -> None:
    """Build (or load) every table the trials need, in this process, with progress bars,
    so the workers only read the cache."""
    from rrg_planner.planning_model import PlanningModel

    for obj, level in sorted({(s.cell.object, s.cell.level) for s in specs}):
        PlanningModel(obj, levels=model_levels(level), progress=True)


def run_campaign(specs: list[TrialSpec], out: Path, workers: int = 2) -> list[dict]:
    """Run the trials not yet in out (JSONL), appending each as it finishes."""
    out.parent.mkdir(parents=True, exist_ok=True)
    done = {r["id"] for r in load_records(out)}
    todo = [s for s in specs if s.id not in done]
    if todo:
        prepare_models(todo)
    log.info(
        "%d trials, %d already done, %d to run on %d workers",
        len(specs),
        len(done),
        len(todo),
        workers,
    )
    with out.open("a") as f:
        for rec in _imap(todo, workers, desc=f"trials ({len(done)} done before)"):
            f.write(json.dumps(rec) + "\n")
            f.flush()
    ids = {s.id for s in specs}
    return [r for r in load_records(out) if r["id"] in ids]


def _imap(todo: list[TrialSpec], workers: int, desc: str) -> Iterator[dict]:
    bar = tqdm(total=len(todo), desc=desc, unit="trial", dynamic_ncols=True)
    # Group by object so each worker keeps few models and worlds in memory.
    todo = sorted(todo, key=lambda s: (s.cell.object, s.cell.level, s.index))
    if workers <= 1:
        for spec in todo:
            yield run_trial(spec)
            bar.update()
    else:
        with mp.get_context("fork").Pool(workers, maxtasksperchild=200) as pool:
            for rec in pool.imap_unordered(run_trial, todo, chunksize=4):
                yield rec
                bar.update()
    bar.close()
