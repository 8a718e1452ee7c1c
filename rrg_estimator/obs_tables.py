"""Offline observation tables Ω_τ(Δ) (design §5; the paper's "Computing the observation matrix").

Thanks to the relative-transform insight, one geometric simulation per grid offset Δ gives
the predicted observation of a WRT for every (w, e) pair with e⁻¹ ⊕ w = Δ: the WRT runs
relative to e₀ = identity and the object sits at Δ. Tables are cached on disk as .npz,
keyed by object, WRT, a hash of everything they depend on, and the grid.
"""

from __future__ import annotations

import hashlib
import logging
import multiprocessing as mp
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from rrg_estimator.config import UncertaintyLevel
from rrg_estimator.grid import Grid
from rrg_sim import config
from rrg_sim.geometric_sim import (
    SIM_VERSION,
    GeometricSimulator,
    ObjectLike,
    ObservationArrays,
    SweptPath,
)
from rrg_sim.observation import Observation
from rrg_sim.wrt import WRT

log = logging.getLogger(__name__)

DEFAULT_CACHE_DIR = Path(__file__).resolve().parents[1] / ".cache" / "tables"
CHUNK = 256  # grid points per worker task
ARRAY_FIELDS = tuple(ObservationArrays.__dataclass_fields__)


@dataclass(eq=False)
class ObservationTable:
    """Ω_τ(Δ) of one WRT and object over a grid of offsets Δ (centre (0,0,0)).

    Arrays are over the grid's N points in flat order (see rrg_sim.observation.Observation):
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


def _init_worker(obj: ObjectLike, wrt: WRT) -> None:
    global _worker_sim
    _worker_sim = GeometricSimulator(obj, wrt)


def _run_chunk(deltas: np.ndarray) -> ObservationArrays:
    return _worker_sim.simulate_batch(deltas)


def build_table(
    obj: ObjectLike,
    wrt: WRT,
    level_or_grid: UncertaintyLevel | Grid,
    workers: int = 2,
    progress: bool = True,
) -> ObservationTable:
    """One geometric simulation per grid offset Δ, on ``workers`` processes (each builds its
    own probe model), with a progress bar."""
    grid = _as_grid(level_or_grid)
    deltas = grid.points()
    chunks = [deltas[s : s + CHUNK] for s in range(0, len(deltas), CHUNK)]
    bar = tqdm(total=len(deltas), desc=f"Ω {obj.name}/{wrt.name}", unit="Δ", disable=not progress)
    results: list[ObservationArrays] = []
    if workers <= 1:
        sim = GeometricSimulator(obj, wrt)
        for c in chunks:
            results.append(sim.simulate_batch(c))
            bar.update(len(c))
    else:
        with mp.get_context("fork").Pool(workers, _init_worker, (obj, wrt)) as pool:
            for r in pool.imap(_run_chunk, chunks):
                results.append(r)
                bar.update(len(r.contact))
    bar.close()
    arrays = ObservationArrays.concatenate(results)
    return ObservationTable(
        obj.name,
        wrt.name,
        grid,
        SweptPath.from_wrt(wrt).length,
        **{f: getattr(arrays, f) for f in ARRAY_FIELDS},
    )


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
