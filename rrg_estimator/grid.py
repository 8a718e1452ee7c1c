"""A regular (x, y, θ) lattice: the support of the belief and of the observation tables."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rrg_models.poses import wrap_angle

from .config import UncertaintyLevel


@dataclass(frozen=True)
class Grid:
    """Regular grid centred on ``center`` with ``shape`` points and ``spacing`` between them.

    center: (x [m], y [m], θ [rad]); spacing: (m, m, rad); shape: odd counts per axis.
    Flat indices are C-order over (ix, iy, iθ).
    """

    center: tuple[float, float, float]
    spacing: tuple[float, float, float]
    shape: tuple[int, int, int]

    @classmethod
    def for_level(cls, level: UncertaintyLevel, center=(0.0, 0.0, 0.0)) -> Grid:
        return cls(tuple(float(c) for c in center), tuple(level.spacing), tuple(level.shape))

    @property
    def size(self) -> int:
        return int(np.prod(self.shape))

    @property
    def half_extent(self) -> np.ndarray:
        """Distance from the centre to the outermost grid point per axis."""
        return (np.asarray(self.shape) - 1) / 2 * np.asarray(self.spacing)

    def axes(self) -> list[np.ndarray]:
        """Coordinates along x, y and θ (θ not wrapped, so axes stay monotonic)."""
        return [
            c + (np.arange(n) - (n - 1) / 2) * s
            for c, s, n in zip(self.center, self.spacing, self.shape)
        ]

    def points(self) -> np.ndarray:
        """(N,3) grid points (x, y, θ) in flat-index order."""
        ax = self.axes()
        X, Y, TH = np.meshgrid(*ax, indexing="ij")
        return np.stack([X.ravel(), Y.ravel(), TH.ravel()], axis=1)

    def fractional_index(self, q: np.ndarray) -> np.ndarray:
        """(…,3) fractional (ix, iy, iθ) of each pose in q (…,3), θ offsets from the centre
        wrapped to [-π, π)."""
        d = np.asarray(q, dtype=float) - np.asarray(self.center)
        d[..., 2] = wrap_angle(d[..., 2])
        return d / np.asarray(self.spacing) + (np.asarray(self.shape) - 1) / 2

    def nearest_index(self, q: np.ndarray, clip: bool = True) -> np.ndarray:
        """Flat index of the grid point nearest to each pose in q (…,3).

        θ offsets are wrapped to [-π, π) around the centre. With ``clip`` the indices are
        clamped to the grid border; otherwise points outside get -1.
        """
        n = np.asarray(self.shape)
        i = np.rint(self.fractional_index(q)).astype(np.int64)
        if clip:
            i = np.clip(i, 0, n - 1)
            return (i[..., 0] * n[1] + i[..., 1]) * n[2] + i[..., 2]
        inside = np.all((i >= 0) & (i < n), axis=-1)
        flat = (i[..., 0] * n[1] + i[..., 1]) * n[2] + i[..., 2]
        return np.where(inside, flat, -1)

    def key(self) -> str:
        """Stable text key (cache file names)."""
        f = lambda t: "_".join(f"{v:.6g}" for v in t)
        return f"c{f(self.center)}-s{f(self.spacing)}-n{f(self.shape)}"
