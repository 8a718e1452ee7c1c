"""The belief: weights over a regular (x, y, θ) grid of object poses in ``world`` (algorithm §3).

Weights are proportional to the probability density at the grid points (paper, "The state
space and belief space") and always sum to 1. A Belief is immutable: its weight array is
read-only, and every update returns a new Belief.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rrg_estimator.config import UncertaintyLevel
from rrg_estimator.grid import Grid
from rrg_models.poses import wrap_angle


@dataclass(frozen=True, eq=False)
class Belief:
    """grid: the support, in ``world``; weights: (N,) float64 over grid.points(), summing to 1;
    frame: the posture class whose readings made it ("" for the prior, a camera's; see
    rrg_sim.posture_calibration): where the object is as the hand in that posture sees it.

    The constructor copies and normalizes the weights; it raises ValueError on a wrong
    shape, NaN/inf, negative weights or zero total mass.
    """

    grid: Grid
    weights: np.ndarray
    frame: str = ""

    def __post_init__(self) -> None:
        w = np.array(self.weights, dtype=np.float64).ravel()
        if w.shape != (self.grid.size,):
            raise ValueError(
                f"belief needs {self.grid.size} weights for grid shape {self.grid.shape}, "
                f"got {w.shape}"
            )
        if not np.all(np.isfinite(w)):
            raise ValueError("belief weights contain NaN or inf")
        if w.min() < 0.0:
            raise ValueError(f"belief weights must be non-negative (min {w.min():.3g})")
        total = w.sum()
        if not total > 0.0:
            raise ValueError("belief weights sum to zero: no state is possible")
        if (
            abs(total - 1.0) > 1e-12
        ):  # weights already normalized stay bit-exact (a message round trip)
            w /= total
        w.flags.writeable = False
        object.__setattr__(self, "weights", w)

    # ------------------------------------------------------------ construction
    @classmethod
    def gaussian(cls, grid: Grid, mean, sigma) -> Belief:
        """A Gaussian N(mean, diag(sigma²)) sampled at the grid points (θ deviations wrapped)."""
        d = grid.points() - np.asarray(mean, dtype=float)
        d[:, 2] = wrap_angle(d[:, 2])
        z = d / np.asarray(sigma, dtype=float)
        return cls(grid, np.exp(-0.5 * np.einsum("ij,ij->i", z, z)))

    @classmethod
    def for_level(cls, level: UncertaintyLevel, mean) -> Belief:
        """The initial belief of an uncertainty level: its Gaussian on its grid centred on the
        mean."""
        return cls.gaussian(Grid.for_level(level, center=mean), mean, level.sigma)

    @classmethod
    def from_normalized(cls, grid: Grid, weights: np.ndarray, frame: str = "") -> Belief:
        """A Belief of weights the estimator's own arithmetic made normalized: (N,) float64,
        finite, non-negative, summing to 1 (e.g. b·L / Σ b·L). Taken as they are, without the
        constructor's copy and checks, and made read-only; anything else: the constructor."""
        w = weights.ravel()
        size = math.prod(grid.shape)
        if w.dtype != np.float64 or w.shape != (size,):
            raise ValueError(f"needs ({size},) float64 weights, got {w.shape} {w.dtype}")
        w.flags.writeable = False
        belief = object.__new__(cls)
        object.__setattr__(belief, "grid", grid)
        object.__setattr__(belief, "weights", w)
        object.__setattr__(belief, "frame", frame)
        return belief

    def with_weights(self, weights: np.ndarray) -> Belief:
        """A new Belief on the same grid and in the same frame (weights are normalized)."""
        return Belief(self.grid, weights, self.frame)

    def on_grid(self, grid: Grid, weights: np.ndarray) -> Belief:
        """A new Belief on another grid, in the same frame (weights are normalized)."""
        return Belief(grid, weights, self.frame)

    # ------------------------------------------------------------- statistics
    def as_grid_array(self) -> np.ndarray:
        """Read-only (nx, ny, nθ) view of the weights."""
        return self.weights.reshape(self.grid.shape)

    def w_star(self) -> np.ndarray:
        """w*(b): the grid point with the largest weight, (3,) (x [m], y [m], θ [rad])."""
        i = np.unravel_index(int(np.argmax(self.weights)), self.grid.shape)
        return np.array([ax[k] for ax, k in zip(self.grid.axes(), i)])

    def marginal_xy(self) -> np.ndarray:
        """(nx, ny) mass summed over θ."""
        return self.as_grid_array().sum(axis=2)

    def marginal_theta(self) -> np.ndarray:
        """(nθ,) mass summed over x and y."""
        return self.as_grid_array().sum(axis=(0, 1))

    def mean(self) -> np.ndarray:
        """(3,) mean pose; θ is the circular mean, wrapped to [-π, π)."""
        ax, ay, at = self.grid.axes()
        a = self.as_grid_array()
        mx = a.sum(axis=(1, 2)) @ ax
        my = a.sum(axis=(0, 2)) @ ay
        mt = self.marginal_theta()
        return np.array([mx, my, wrap_angle(np.arctan2(mt @ np.sin(at), mt @ np.cos(at)))])

    def cov(self) -> np.ndarray:
        """(3,3) covariance about mean(); θ deviations wrapped to [-π, π)."""
        d = self.grid.points() - self.mean()
        d[:, 2] = wrap_angle(d[:, 2])
        return (d * self.weights[:, None]).T @ d

    def entropy(self) -> float:
        """Discrete entropy -Σ b log b [nats] of the grid weights."""
        w = self.weights[self.weights > 0.0]
        return float(-(w @ np.log(w)))

    def probability(self, mask: np.ndarray) -> float:
        """Mass of the states selected by a boolean mask, (N,) or grid-shaped."""
        mask = np.asarray(mask, dtype=bool).ravel()
        if mask.shape != self.weights.shape:
            raise ValueError(f"mask has {mask.size} entries, belief has {self.weights.size}")
        return float(self.weights[mask].sum())
