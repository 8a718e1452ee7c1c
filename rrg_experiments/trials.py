"""Seeded, resumable physics trials: objects × levels × strategies (× horizons × δ) × N.

Each trial's true pose is drawn from the initial belief's Gaussian (the paper: "placed at
random positions drawn from the same distribution as the initial uncertainty"), seeded by
(base seed, object, level, trial index) only, so every strategy faces the same poses. Any
trial replays alone from its id (cell key and index), the base seed and the world profile.
Results append to a JSONL file, one line per trial, each stamped with the code version, the
base seed and the world profile, so a stopped campaign resumes where it left off, and
refuses to mix in records of other code, another seed or another world.
"""

from __future__ import annotations

import json
import logging
import sys
import time
import zlib
from collections import OrderedDict
from collections.abc import Callable, Iterable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from rrg_common.parallel import fork_map
from rrg_estimator.config import LEVELS
from rrg_models.config import WORLD
from rrg_models.poses import compose_planar
from rrg_planner.config import SEARCH

log = logging.getLogger(__name__)


#: The capabilities an ablation can switch off (Cell.without): the goal grasp's own check
#: (RobustGraspAgent.verify), the guarded moves' stop confirmation (PhysicsWorld.confirm_stops),
#: the posture frames of the planner's models (PlanningModel(world=...): off, they assume a
#: robot without calibration error), the goal probe (objects.wrt_generation.goal_probe_wrt)
#: and the table touch before the goal grasp and its probe (PhysicsWorld.touch_table).
CAPABILITIES = ("verify", "confirm", "frames", "probe", "touch")


@dataclass(frozen=True)
class Cell:
    """One experimental condition; ``without``: the CAPABILITIES switched off (sorted)."""

    object: str
    level: str
    strategy: str
    horizon: int = SEARCH.horizon
    delta: float = SEARCH.delta
    without: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        unknown = set(self.without) - set(CAPABILITIES)
        if unknown:
            raise ValueError(f"unknown capabilities {sorted(unknown)}; valid: {CAPABILITIES}")
        object.__setattr__(self, "without", tuple(sorted(set(self.without))))

    @property
    def key(self) -> str:
        """e.g. 'powerdrill/high/rrg-info' (H and δ appended when not the defaults, then the
        capabilities switched off, as in 'powerdrill/high/rrg-info/without-confirm+verify')."""
        k = f"{self.object}/{self.level}/{self.strategy}"
        if self.strategy == "rrg-info" and self.horizon != SEARCH.horizon:
            k += f"/H{self.horizon}"
        if self.delta != SEARCH.delta:
            k += f"/d{self.delta:g}"
        if self.without:
            k += "/without-" + "+".join(self.without)
        return k

    @classmethod
    def from_key(cls, key: str) -> Cell:
        """The cell a ``key`` names (its inverse); ValueError for anything else."""
        parts = key.split("/")
        if len(parts) < 3:
            raise ValueError(
                f"cell key {key!r} is not object/level/strategy[/H<h>][/d<δ>][/without-<a>+<b>]"
            )
        kw = {}
        for part in parts[3:]:
            if part.startswith("without-"):
                kw["without"] = tuple(part[len("without-") :].split("+"))
            elif part[:1] == "H" and part[1:].isdigit():
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
    """One trial: its cell, its index in the cell, the campaign's base seed and world profile."""

    cell: Cell
    index: int
    base_seed: int
    world: str = "nominal"

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
#: Planning models a worker keeps loaded (about 0.3 GB and 5 s to load each at high
#: uncertainty): ``schedule`` runs the cells of one model together, so a worker loads each
#: model about once per campaign, and its memory stays bounded over a campaign of any length.
KEPT_MODELS = 2
#: Physics worlds a worker keeps (about 0.1 s to build each).
KEPT_ENVS = 4
_MODELS: OrderedDict = OrderedDict()
_ENVS: OrderedDict = OrderedDict()


def _cached(cache: OrderedDict, key, kept: int, build: Callable[[], object]):
    """cache[key], built on a miss; the least recently used entries beyond ``kept`` dropped."""
    if key in cache:
        cache.move_to_end(key)
    else:
        cache[key] = build()
        while len(cache) > kept:
            cache.popitem(last=False)
    return cache[key]


def model_key(obj: str, level: str, world: str, without: tuple[str, ...] = ()) -> tuple:
    """What a trial's planning model depends on (``_model``): the object, the level's grids,
    the world profile, and the capabilities switched off."""
    return (obj, model_levels(level), world, tuple(without))


def _model(obj: str, level: str, world: str, without: tuple[str, ...] = ()):
    """The planning model of a trial: the object's tables at the level's grids, and the world
    profile's calibration frames (the planner knows the profile, never a trial's draw), less
    the capabilities switched off."""
    from rrg_models.objects import get_object
    from rrg_planner.planning_model import PlanningModel

    def build() -> PlanningModel:
        names = None
        if "probe" in without:
            wrts = get_object(obj).wrts()
            names = tuple(w.name for w in wrts if "probe_of" not in w.meta)  # every goal probe
        return PlanningModel(
            obj,
            levels=model_levels(level),
            workers=1,  # no nested pools
            progress=False,
            world="nominal" if "frames" in without else world,
            wrt_names=names,
        )

    return _cached(_MODELS, model_key(obj, level, world, without), KEPT_MODELS, build)


def _env(obj: str, world: str, confirm_stops: bool = True, touch_table: bool = True):
    """The physics environment of a trial (kept: KEPT_ENVS); ``touch_table`` off: never, on:
    where the profile calls for it (PhysicsWorld.touch_table)."""
    from rrg_experiments.physics_env import PhysicsEnvironment

    return _cached(
        _ENVS,
        (obj, world, confirm_stops, touch_table),
        KEPT_ENVS,
        lambda: PhysicsEnvironment.for_object(
            obj,
            profile=world,
            confirm_stops=confirm_stops,
            touch_table=None if touch_table else False,
        ),
    )


def run_trial(spec: TrialSpec) -> dict:
    """Run one physics trial and return its JSON-able record. BLAS runs on one thread, so
    the record is the same bit for bit in any process (sums over threads round differently)."""
    with threadpool_limits(1):
        return _run_trial(spec)


def _run_trial(spec: TrialSpec) -> dict:
    from rrg_planner.agent import RobustGraspAgent
    from rrg_planner.closed_loop import run_in_process

    cell = spec.cell
    t0 = time.perf_counter()
    true = spec.true_pose()
    env = _env(cell.object, spec.world, "confirm" not in cell.without, "touch" not in cell.without)
    env.reset(true, seed=spec.seed)
    agent = RobustGraspAgent(
        _model(cell.object, cell.level, spec.world, cell.without),
        strategy=cell.strategy,
        horizon=cell.horizon,
        delta=cell.delta,
        verify="verify" not in cell.without,
    )
    try:
        res = run_in_process(agent, env, cell.level, WORLD.nominal_pose)
        out = dict(
            success=res.success,
            declared=res.declared,
            n_actions=res.n_actions,
            actions=[s.wrt for s in res.steps],
            p_goal=res.p_goal,
            # the last goal grasp's P_b(G) before its own check, and what the check found
            p_goal_belief=res.steps[-1].p_goal_belief if res.steps else float("nan"),
            mismatches=res.steps[-1].mismatches if res.steps else [],
            goal_grasps_rejected=sum(bool(s.mismatches) for s in res.steps),
            planning_time_s=res.planning_time,
            error=res.error,
            judge=_jsonable(env.last_judgement),
            table_touch_m=env.world.executor.touched_height,
        )
    except Exception as exc:
        log.exception("trial %s failed", spec.id)
        out = dict(
            success=False,
            declared=False,
            n_actions=0,
            actions=[],
            p_goal=float("nan"),
            p_goal_belief=float("nan"),
            mismatches=[],
            goal_grasps_rejected=0,
            planning_time_s=0.0,
            error=f"{type(exc).__name__}: {exc}",
            judge={},
        )
    return dict(
        id=spec.id,
        cell=cell.key,
        **asdict(cell),
        trial=spec.index,
        base_seed=spec.base_seed,
        world=spec.world,
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
#: Record fields that measure time: they differ between runs of the same trial; every other
#: field is a function of the trial's spec and the code.
TIMING_FIELDS = ("wall_s", "planning_time_s")

#: The campaign-wide stamp of every record: the code version, the base seed and the world.
STAMP_FIELDS = ("commit", "base_seed", "world")


class CampaignMismatch(ValueError):
    """A results file holds records of another code version, base seed or world profile."""


def outcome(record: dict) -> dict:
    """A record without its TIMING_FIELDS: equal for two runs of the same trial."""
    return {k: v for k, v in record.items() if k not in TIMING_FIELDS}


def _fields(value, path: str = "") -> dict[str, str]:
    """A record's leaves by dotted path (judge.held), each as JSON text."""
    if isinstance(value, dict) and value:
        leaves: dict[str, str] = {}
        for k, v in value.items():
            leaves.update(_fields(v, f"{path}.{k}" if path else str(k)))
        return leaves
    return {path: json.dumps(value, sort_keys=True)}


def record_differences(old: dict, new: dict) -> list[str]:
    """The fields of ``old`` whose value in ``new``, a record of the same trial, differs or
    is gone, beyond timing and the code version, as 'field: old -> new' lines (none: the same
    behaviour; a field only ``new`` has is a new output, not a difference). Compared as JSON
    text, so that NaN fields (the P(goal) of a failed run) are equal."""
    a = _fields({k: v for k, v in outcome(old).items() if k != "commit"})
    b = _fields({k: v for k, v in outcome(new).items() if k != "commit"})
    return [f"{k}: {a[k]} -> {b.get(k, '(gone)')}" for k in sorted(a) if a[k] != b.get(k)]


def added_fields(old: dict, new: dict) -> list[str]:
    """The fields a newer record of the same trial has and ``old`` has not (dotted paths)."""
    return sorted(_fields(outcome(new)).keys() - _fields(outcome(old)).keys())


def spec_of(record: dict) -> TrialSpec:
    """The spec a record was run from (its cell, index, base seed and world)."""
    return TrialSpec(
        Cell.from_key(record["cell"]), record["trial"], record["base_seed"], record["world"]
    )


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


def drop_torn_tail(path: Path) -> None:
    """Cut a half-written last line (a run killed while writing) off a JSONL file, so that
    records appended next start on a line of their own."""
    if not path.exists():
        return
    data = path.read_bytes()
    end = data.rfind(b"\n") + 1
    if end < len(data):
        log.warning("%s: dropping a half-written last line (%d bytes)", path, len(data) - end)
        with path.open("r+b") as f:
            f.truncate(end)


def check_stamps(records: list[dict], stamp: dict, path: Path) -> None:
    """Raise CampaignMismatch if any record's stamp differs from ``stamp``."""
    for r in records:
        theirs = {k: r.get(k) for k in STAMP_FIELDS}
        if theirs != stamp:
            diff = ", ".join(
                f"{k} {theirs[k]!r} (this run: {stamp[k]!r})"
                for k in STAMP_FIELDS
                if theirs[k] != stamp[k]
            )
            raise CampaignMismatch(
                f"{path} holds trial {r.get('id')!r} of another campaign: {diff}. "
                "Resume it with the same code, seed and world, or write to another --out."
            )


def prepare_models(specs: Iterable[TrialSpec]) -> None:
    """Build (or load) every table the trials need, in this process, with progress bars,
    so the workers only read the cache."""
    from rrg_planner.planning_model import PlanningModel

    for obj, level in sorted({(s.cell.object, s.cell.level) for s in specs}):
        PlanningModel(obj, levels=model_levels(level), progress=True)


def run_campaign(
    specs: list[TrialSpec], out: Path, commit: str, workers: int = 2, ray: str | None = None
) -> list[dict]:
    """Run the trials not yet in ``out`` (JSONL), appending each as it finishes, stamped with
    ``commit`` (the code version). Raises CampaignMismatch if ``out`` holds records of another
    code version, base seed or world. ``ray``: run on Ray at this address ("auto": a running
    cluster, or a local one of ``workers`` CPUs) instead of a local process pool."""
    out.parent.mkdir(parents=True, exist_ok=True)
    drop_torn_tail(out)
    before = load_records(out)
    stamps = {(s.base_seed, s.world) for s in specs}
    if len(stamps) > 1:
        raise ValueError(f"one campaign, one base seed and world; got {sorted(stamps)}")
    if specs:
        base_seed, world = stamps.pop()
        check_stamps(before, dict(commit=commit, base_seed=base_seed, world=world), out)
    done = {r["id"] for r in before}
    todo = [s for s in specs if s.id not in done]
    if todo:
        prepare_models(todo)
    print(
        f"{len(specs)} trials, {len(done)} already done, {len(todo)} to run on "
        + (f"Ray ({ray})" if ray else f"{workers} workers"),
        file=sys.stderr,
        flush=True,
    )
    with out.open("a") as f:
        for rec in imap_trials(todo, workers, ray, desc=f"trials ({len(done)} done before)"):
            f.write(json.dumps(dict(rec, commit=commit)) + "\n")
            f.flush()
    ids = {s.id for s in specs}
    return [r for r in load_records(out) if r["id"] in ids]


def schedule(todo: list[TrialSpec]) -> list[TrialSpec]:
    """The trials in the order to run them: the cells of one planning model (``model_key``)
    together, so a worker loads each model about once; the models whose cells are likely
    longest first (planning before open-loop, high uncertainty before low, deeper searches
    first, RRG-Info before RRG-Goal), and within a model its longest cells first, each cell's
    trials together, so the last to run are short and the workers finish together. The order
    changes no record: each trial depends on its spec only."""

    def cell_order(c: Cell) -> tuple:
        return (
            c.strategy == "open-loop",
            c.level != "high",
            -c.horizon,
            c.strategy != "rrg-info",
            c.key,
        )

    def key(s: TrialSpec) -> tuple:
        return model_key(s.cell.object, s.cell.level, s.world, s.cell.without)

    first: dict[tuple, tuple] = {}  # model key → the order of its longest cell
    for s in todo:
        first[key(s)] = min(first.get(key(s), cell_order(s.cell)), cell_order(s.cell))
    return sorted(todo, key=lambda s: (first[key(s)], cell_order(s.cell), s.index))


def imap_trials(
    todo: list[TrialSpec], workers: int, ray: str | None = None, desc: str = "trials"
) -> Iterator[dict]:
    """Run the trials (in ``schedule`` order) on ``workers`` processes, or on Ray at address
    ``ray``, with a progress bar; yields each record as it finishes."""
    bar = tqdm(total=len(todo), desc=desc, unit="trial", dynamic_ncols=True)
    todo = schedule(todo)
    if ray:
        from rrg_experiments.ray_pool import ray_imap

        for rec in ray_imap(run_trial, todo, address=ray, workers=workers):
            yield rec
            bar.update()
    elif workers <= 1:
        for spec in todo:
            yield run_trial(spec)
            bar.update()
    else:
        for rec in fork_map(run_trial, todo, workers, ordered=False):
            yield rec
            bar.update()
    bar.close()
