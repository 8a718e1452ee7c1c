"""Offline observation tables Ω_τ(Δ) (algorithm §5; the paper's "Computing the observation
matrix").

Thanks to the relative-transform insight, one geometric simulation per grid offset Δ gives
the predicted observation of a WRT for every (w, e) pair with e⁻¹ ⊕ w = Δ: the WRT runs
relative to e₀ = identity and the object sits at Δ. Tables are cached on disk as .npz,
keyed by object, WRT, a hash of everything they depend on, and the grid.

A *marginal* table (build_marginal_table) holds, per offset Δ, the observations under K
seeded draws of a world's nuisance (nuisance_offsets: the hand's vertical calibration error
and the table's height error, as one vertical offset of the hand from where the robot
measures it); nothing reads it yet.

``python -m rrg_estimator.obs_tables --bench OBJECT`` times fresh builds (see ``main``).
"""

from __future__ import annotations

import argparse
import hashlib
import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from rrg_common.parallel import fork_map
from rrg_estimator.config import LEVELS, UncertaintyLevel
from rrg_estimator.grid import Grid
from rrg_models import config
from rrg_models.observation import Observation
from rrg_models.wrt import WRT
from rrg_sim.config import WorldProfile, world_profile
from rrg_sim.geometric_sim import (
    SIM_VERSION,
    GeometricSimulator,
    ObjectLike,
    ObservationArrays,
    SweptPath,
)

log = logging.getLogger(__name__)

DEFAULT_CACHE_DIR = Path(__file__).resolve().parents[1] / ".cache" / "tables"
CHUNK = 256  # grid points per worker task
ARRAY_FIELDS = tuple(ObservationArrays.__dataclass_fields__)


@dataclass(eq=False)
class ObservationTable:
    """Ω_τ(Δ) of one WRT and object over a grid of offsets Δ (centre (0,0,0)).

    Arrays are over the grid's N points in flat order (see rrg_models.observation.Observation):
    contact (N,) bool, progress (N,) float32 [m], sensors (N,10) bool, closure (N,3) float32
    [rad], tip_points / tip_normals (N,3,3) float32 in the hand frame (NaN = no contact),
    motion_dir (N,3) float32 and stop_pose (N,4,4) float32 in the estimate's frame e₀.
    """

    object_name: str
    wrt_name: str
    grid: Grid
    path_length: float
    contact: np.ndarray
    progress: np.ndarray
    sensors: np.ndarray
    closure: np.ndarray
    tip_points: np.ndarray
    tip_normals: np.ndarray
    motion_dir: np.ndarray
    stop_pose: np.ndarray

    def __len__(self) -> int:
        return len(self.contact)

    def observation(self, j: int) -> Observation:
        """Row j as an Observation in the frame of e₀ (hand_pose = stop pose)."""
        return Observation(
            bool(self.contact[j]),
            float(self.progress[j]),
            self.stop_pose[j],
            self.sensors[j],
            self.closure[j],
            self.tip_points[j],
            self.tip_normals[j],
            self.motion_dir[j],
        )

    def save(self, path: Path, key: str) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp.npz")
        np.savez(
            tmp,
            key=key,
            object_name=self.object_name,
            wrt_name=self.wrt_name,
            grid=np.array([*self.grid.center, *self.grid.spacing, *self.grid.shape], float),
            path_length=self.path_length,
            **{f: getattr(self, f) for f in ARRAY_FIELDS},
        )
        tmp.replace(path)

    @classmethod
    def load(cls, path: Path) -> tuple[ObservationTable, str]:
        """(table, key) from a file written by ``save``."""
        with np.load(path) as z:
            g = z["grid"]
            grid = Grid(tuple(g[0:3]), tuple(g[3:6]), tuple(int(n) for n in g[6:9]))
            table = cls(
                str(z["object_name"]),
                str(z["wrt_name"]),
                grid,
                float(z["path_length"]),
                **{f: z[f] for f in ARRAY_FIELDS},
            )
            return table, str(z["key"])


def _as_grid(level_or_grid: UncertaintyLevel | Grid) -> Grid:
    return level_or_grid if isinstance(level_or_grid, Grid) else Grid.for_level(level_or_grid)


_worker_sim: GeometricSimulator | None = None
_worker_offset = np.zeros(3)


def _run_chunk(deltas: np.ndarray) -> ObservationArrays:
    return _worker_sim.simulate_batch_offset(deltas, _worker_offset)


def _simulate_grid(
    sim: GeometricSimulator,
    deltas: np.ndarray,
    hand_offset: np.ndarray,
    workers: int,
    bar: tqdm,
) -> ObservationArrays:
    """sim's predicted observations at every offset, on ``workers`` forked processes (which
    inherit the simulator: one probe model, compiled code loaded once)."""
    global _worker_sim, _worker_offset
    chunks = [deltas[s : s + CHUNK] for s in range(0, len(deltas), CHUNK)]
    results: list[ObservationArrays] = []
    _worker_sim, _worker_offset = sim, np.asarray(hand_offset, dtype=float)
    try:
        if workers <= 1:
            for c in chunks:
                results.append(_run_chunk(c))
                bar.update(len(c))
        else:
            for r in fork_map(_run_chunk, chunks, workers):
                results.append(r)
                bar.update(len(r.contact))
    finally:
        _worker_sim = None
    return ObservationArrays.concatenate(results)


def _table(obj: ObjectLike, wrt: WRT, grid: Grid, arrays: ObservationArrays) -> ObservationTable:
    return ObservationTable(
        obj.name,
        wrt.name,
        grid,
        SweptPath.from_wrt(wrt).length,
        **{f: getattr(arrays, f) for f in ARRAY_FIELDS},
    )


def build_table(
    obj: ObjectLike,
    wrt: WRT,
    level_or_grid: UncertaintyLevel | Grid,
    workers: int = 2,
    progress: bool = True,
) -> ObservationTable:
    """One geometric simulation per grid offset Δ, on ``workers`` processes, with a progress
    bar."""
    grid = _as_grid(level_or_grid)
    deltas = grid.points()
    bar = tqdm(total=len(deltas), desc=f"Ω {obj.name}/{wrt.name}", unit="Δ", disable=not progress)
    sim = GeometricSimulator(obj, wrt)
    arrays = _simulate_grid(sim, deltas, np.zeros(3), workers, bar)
    bar.close()
    return _table(obj, wrt, grid, arrays)


# ------------------------------------------------------------------ marginal tables
#: σ of the hand's vertical error at a grasp [m] per rad of σ of the WAM's joint offsets
#: (docs/world.md, the realistic settling study: σ ≈ 7 mm at 10 mrad). The planar part of the
#: calibration error is the posture frames' to model (rrg_sim.posture_calibration), not drawn.
VERTICAL_ERROR_PER_JOINT_OFFSET = 0.7


def nuisance_offsets(profile: WorldProfile | str, draws: int, seed: int) -> np.ndarray:
    """(draws, 3) seeded offsets [m] of the hand from where the robot measures it, relative to
    the table and the object, under ``profile``: vertical only, the hand's calibration error
    (σ VERTICAL_ERROR_PER_JOINT_OFFSET × joint_offset_sigma) less the table's height error
    (σ table_height_sigma). All zero in the nominal world."""
    profile = world_profile(profile)
    rng = np.random.default_rng(seed)
    hand = rng.normal(0.0, VERTICAL_ERROR_PER_JOINT_OFFSET * profile.joint_offset_sigma, draws)
    table = rng.normal(0.0, profile.table_height_sigma, draws)
    offsets = np.zeros((draws, 3))
    offsets[:, 2] = hand - table
    return offsets


@dataclass(eq=False)
class MarginalObservationTable:
    """Ω_τ(Δ) under K nuisance draws: tables[k] is the table with the hand truly off by
    offsets[k] (3,) [m] (stop poses as the robot measures them, i.e. undisplaced)."""

    offsets: np.ndarray
    tables: tuple[ObservationTable, ...]

    def __len__(self) -> int:
        return len(self.tables[0])

    def observations(self, j: int) -> list[Observation]:
        """The K observations of grid offset j, one per draw."""
        return [t.observation(j) for t in self.tables]


def build_marginal_table(
    obj: ObjectLike,
    wrt: WRT,
    level_or_grid: UncertaintyLevel | Grid,
    offsets: Sequence[Sequence[float]] | np.ndarray,
    workers: int = 2,
    progress: bool = True,
) -> MarginalObservationTable:
    """build_table under each of the (K,3) hand offsets [m] (nuisance_offsets): one probe
    model, K sweeps of the grid. A zero offset gives build_table's arrays exactly."""
    grid = _as_grid(level_or_grid)
    offsets = np.asarray(offsets, dtype=float).reshape(-1, 3)
    deltas = grid.points()
    bar = tqdm(
        total=len(deltas) * len(offsets),
        desc=f"Ω {obj.name}/{wrt.name} × {len(offsets)}",
        unit="Δ",
        disable=not progress,
    )
    sim = GeometricSimulator(obj, wrt)
    tables = tuple(
        _table(obj, wrt, grid, _simulate_grid(sim, deltas, off, workers, bar)) for off in offsets
    )
    bar.close()
    return MarginalObservationTable(offsets, tables)


def table_key(obj: ObjectLike, wrt: WRT, grid: Grid) -> str:
    """Hash of everything a table depends on: object parts, WRT, grid, model and simulator."""
    h = hashlib.sha256()
    for p in obj.parts:
        h.update(
            repr(
                (
                    p.kind,
                    *(np.round(np.asarray(v, float), 9).tolist() for v in (p.size, p.pos, p.quat)),
                )
            ).encode()
        )
    h.update(np.ascontiguousarray(np.round(wrt.poses, 9)).tobytes())
    h.update(
        repr(
            (
                wrt.spread,
                wrt.preclose,
                grid.key(),
                config.MODEL_VERSION,
                SIM_VERSION,
                config.HAND,
                config.GEOMSIM,
            )
        ).encode()
    )
    return h.hexdigest()[:16]


def load_or_build(
    obj: ObjectLike,
    wrt: WRT,
    grid: UncertaintyLevel | Grid,
    cache_dir: Path | str = DEFAULT_CACHE_DIR,
    workers: int = 2,
    progress: bool = True,
) -> ObservationTable:
    """The cached table if it is current, else build it, store it, and drop stale versions."""
    grid = _as_grid(grid)
    key = table_key(obj, wrt, grid)
    cache_dir = Path(cache_dir)
    # One file per object, WRT and grid: rebuilding replaces only that grid's stale version.
    stem = f"{obj.name}__{wrt.name}__{hashlib.sha256(grid.key().encode()).hexdigest()[:8]}__"
    path = cache_dir / f"{stem}{key}.npz"
    if path.exists():
        table, stored = ObservationTable.load(path)
        if stored == key:
            return table
    log.info(
        "building observation table %s/%s over %d offsets (%s)",
        obj.name,
        wrt.name,
        grid.size,
        grid.key(),
    )
    table = build_table(obj, wrt, grid, workers=workers, progress=progress)
    for stale in cache_dir.glob(f"{stem}*.npz"):
        stale.unlink()
    table.save(path, key)
    return table


# ------------------------------------------------------------------ timing a fresh build
def main(argv: Sequence[str] | None = None) -> None:
    """``--bench OBJECT``: time fresh builds of an object's tables (no cache) and print the
    figures: per WRT, seconds and µs per simulation; with ``--draws K``, the marginal table's
    too."""
    from rrg_models.objects import get_object

    p = argparse.ArgumentParser(prog="python -m rrg_estimator.obs_tables", description=main.__doc__)
    p.add_argument("--bench", metavar="OBJECT", required=True, help="catalogue object name")
    p.add_argument("--wrt", action="append", help="a WRT name (repeatable; default: all)")
    p.add_argument("--level", default="high", choices=sorted(LEVELS))
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--draws", type=int, default=0, help="also a marginal table of K draws")
    p.add_argument("--world", default="realistic", help="world profile of the draws")
    p.add_argument("--seed", type=int, default=0, help="seed of the draws")
    args = p.parse_args(argv)
    obj = get_object(args.bench)
    grid = Grid.for_level(LEVELS[args.level])
    wrts = [w for w in obj.wrts() if args.wrt is None or w.name in args.wrt]
    if not wrts:
        p.error(f"no WRT named {args.wrt}; {obj.name} has {[w.name for w in obj.wrts()]}")
    offsets = nuisance_offsets(args.world, args.draws, args.seed) if args.draws else None
    print(f"{obj.name}, {args.level} grid ({grid.size} offsets), {args.workers} workers")
    for wrt in wrts:
        t0 = time.perf_counter()
        build_table(obj, wrt, grid, workers=args.workers, progress=False)
        s = time.perf_counter() - t0
        line = f"  {wrt.name:14s} table {s:6.2f} s ({1e6 * s / grid.size:5.1f} µs/simulation)"
        if offsets is not None:
            t0 = time.perf_counter()
            build_marginal_table(obj, wrt, grid, offsets, workers=args.workers, progress=False)
            line += f"  marginal ×{args.draws} ({args.world}) {time.perf_counter() - t0:6.2f} s"
        print(line, flush=True)


if __name__ == "__main__":
    main()
