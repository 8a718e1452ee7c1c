"""Feasibility maps: F_τ(e) of one WRT precomputed over object poses e = (x, y, θ)
(algorithm §4).

The WAM is symmetric about J1's (vertical) axis: turning the object about the base by φ turns
every hand pose by φ, adds φ to J1 and turns the elbow and wrist about the base, and changes
nothing else. The map therefore lives on a polar grid e = (r cos φ, r sin φ, φ + ψ): IK runs
once per (r, ψ) and waypoint with J1 unchecked, and each solution is then valid for the φ at
which J1 + φ stays within J1's limits and the turned arm points clear the table. Solutions
valid for the whole φ range (J1 far from its limits, elbow and wrist above the clearance
height) settle their cell at once; only the rest are checked φ by φ. Every grid point gets
what ``wam.feasible_path`` says there (up to round-off at the limits).
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from rrg_models import wam
from rrg_models.config import MODEL_VERSION, WAM, WORLD
from rrg_models.poses import planar_pose, wrap_angle

CACHE_DIR = Path(__file__).resolve().parents[1] / ".cache" / "feasibility"


@dataclass(frozen=True)
class PolarGrid:
    """Object poses on a polar lattice: r [m] from the WAM base, bearing φ [rad] from world x,
    and ψ = θ - φ [rad], the object's heading relative to its bearing (full circle)."""

    r0: float
    dr: float
    nr: int
    phi0: float
    dphi: float
    nphi: int
    npsi: int

    @classmethod
    def covering(
        cls,
        center=WORLD.nominal_pose[:2],
        half_extent: float = 0.25,
        dr: float = 0.01,
        dphi: float = 0.015,
        npsi: int = 126,
    ) -> PolarGrid:
        """The lattice covering the square center ± half_extent [m] (which must not contain the
        base). Defaults (chosen): 1 cm in r, 0.015 rad in φ (≤ 1.4 cm at r = 0.9 m), and
        126 headings (0.05 rad)."""
        cx, cy = center
        corners = np.array(
            [[cx + sx * half_extent, cy + sy * half_extent] for sx in (-1, 1) for sy in (-1, 1)]
        )
        r_min = np.hypot(max(abs(cx) - half_extent, 0.0), max(abs(cy) - half_extent, 0.0))
        r_max = np.hypot(*corners.T).max()
        phis = np.arctan2(corners[:, 1], corners[:, 0])
        nr = int(np.ceil((r_max - r_min) / dr)) + 1
        nphi = int(np.ceil((phis.max() - phis.min()) / dphi)) + 1
        return cls(float(r_min), dr, nr, float(phis.min()), dphi, nphi, npsi)

    def axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Coordinates along r, φ and ψ (ψ from -π in steps of 2π / npsi)."""
        return (
            self.r0 + self.dr * np.arange(self.nr),
            self.phi0 + self.dphi * np.arange(self.nphi),
            -np.pi + 2 * np.pi / self.npsi * np.arange(self.npsi),
        )

    def index(self, e) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Nearest cell (ir, iφ, iψ) of object poses e (…,3), and whether e lies on the grid."""
        e = np.asarray(e, dtype=float)
        phi = np.arctan2(e[..., 1], e[..., 0])
        ir = np.rint((np.hypot(e[..., 0], e[..., 1]) - self.r0) / self.dr).astype(np.int64)
        iphi = np.rint((phi - self.phi0) / self.dphi).astype(np.int64)
        ipsi = (
            np.rint((wrap_angle(e[..., 2] - phi) + np.pi) * self.npsi / (2 * np.pi)).astype(
                np.int64
            )
            % self.npsi
        )
        inside = (ir >= 0) & (ir < self.nr) & (iphi >= 0) & (iphi < self.nphi)
        return np.clip(ir, 0, self.nr - 1), np.clip(iphi, 0, self.nphi - 1), ipsi, inside


def _waypoint_feasibility(pose: np.ndarray, grid: PolarGrid) -> np.ndarray:
    """(nr, nφ, nψ) F of one object-frame hand pose (4,4) over the grid."""
    r, phi, psi = grid.axes()
    R, PSI = np.meshgrid(r, psi, indexing="ij")
    reduced = np.stack([R.ravel(), np.zeros(R.size), PSI.ravel()], axis=1)  # objects at bearing 0
    T = planar_pose(reduced) @ pose
    cells = np.zeros((R.size, grid.nphi), dtype=bool)
    # J1 + φ stays within J1's limits for every φ on the grid while J1 lies in this interval:
    j1_lo, j1_hi = wam.LOWER[0] - phi[0], wam.UPPER[0] - phi[-1]
    for lo in range(0, R.size, wam.BATCH_CHUNK):
        sol = wam.ik_solutions(T[lo : lo + wam.BATCH_CHUNK], check_j1=False)
        ok = sol.valid.any(axis=0)  # (2,2,S,M): some wrist branch within the limits
        q1 = np.arctan2(sol.cs12[1], sol.cs12[0])
        high = np.all(sol.elbows[:, 2] >= wam.CLEARANCE_Z, axis=0) & (
            sol.wrist[2] >= wam.CLEARANCE_Z
        )
        everywhere = (
            (ok & high & (q1 >= j1_lo) & (q1 <= j1_hi)).reshape(-1, ok.shape[-1]).any(axis=0)
        )
        cells[lo : lo + wam.BATCH_CHUNK][everywhere] = True
        rest = np.nonzero(ok & ~everywhere)
        if rest[0].size:
            m = rest[-1]
            points = np.concatenate(
                [sol.elbows[(slice(None), slice(None)) + rest], sol.wrist[None, :, m]], axis=0
            )  # (3 points, 3 xyz, N)
            c, s = np.cos(phi)[:, None, None], np.sin(phi)[:, None, None]  # (nφ,1,1)
            x, y = c * points[:, 0] - s * points[:, 1], s * points[:, 0] + c * points[:, 1]
            clear = np.all(wam.point_clear_of_table(x, y, points[:, 2]), axis=1)  # (nφ, N)
            j1 = wrap_angle(q1[rest][None] + phi[:, None])
            fine = clear & (j1 >= wam.LOWER[0]) & (j1 <= wam.UPPER[0])
            where_phi, where_n = np.nonzero(fine)
            cells[lo + m[where_n], where_phi] = True
    return cells.reshape(grid.nr, grid.npsi, grid.nphi).transpose(0, 2, 1)


def _cache_key(poses: np.ndarray, grid: PolarGrid) -> str:
    h = hashlib.sha1(np.ascontiguousarray(poses, dtype=float).tobytes())
    h.update(
        repr(
            (
                MODEL_VERSION,
                asdict(WAM),
                WORLD.table_top_z,
                WORLD.table_x,
                WORLD.table_y,
                wam.IK_REDUNDANCY_SAMPLES,
                asdict(grid),
            )
        ).encode()
    )
    return h.hexdigest()[:20]


class FeasibilityMap:
    """F_τ(e) of one WRT (object-frame hand poses (K,4,4)) over object poses around the nominal
    placement, built with the batched IK (or loaded from ``CACHE_DIR``). ``lookup`` answers by
    the nearest grid cell, and exactly (``wam.feasible_paths``) for poses off the grid."""

    def __init__(self, poses, grid: PolarGrid | None = None, cache: bool = True):
        self.poses = np.asarray(poses, dtype=float)
        self.grid = grid or PolarGrid.covering()
        self.build_seconds = 0.0
        path = CACHE_DIR / f"{_cache_key(self.poses, self.grid)}.npz"
        if cache and path.exists():
            with np.load(path) as data:
                self.feasible = data["feasible"]
            return
        start = time.perf_counter()
        self.feasible = np.ones((self.grid.nr, self.grid.nphi, self.grid.npsi), dtype=bool)
        for pose in np.unique(self.poses, axis=0):
            self.feasible &= _waypoint_feasibility(pose, self.grid)
        self.build_seconds = time.perf_counter() - start
        if cache:
            _save_atomic(path, self.feasible)

    def lookup(self, e) -> np.ndarray:
        """F_τ(e) for object poses e (…,3) → bool (…)."""
        e = np.asarray(e, dtype=float)
        ir, iphi, ipsi, inside = self.grid.index(e)
        out = self.feasible[ir, iphi, ipsi]
        if not np.all(inside):
            off = e[~inside]
            out = np.array(out, copy=True)
            out[~inside] = wam.feasible_paths(planar_pose(off)[:, None] @ self.poses)
        return out


def _save_atomic(path: Path, feasible: np.ndarray) -> None:
    """Write the map so that concurrent builders never see a partial file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".npz.tmp")
    with os.fdopen(fd, "wb") as f:
        np.savez_compressed(f, feasible=feasible)
    os.replace(tmp, path)
