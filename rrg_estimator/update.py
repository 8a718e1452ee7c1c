"""The belief update SE(b, τ(e), o) (algorithm §3): transition, then likelihood, then
normalization."""

from __future__ import annotations

import numpy as np
from numba import njit

from rrg_estimator.config import LIKELIHOOD, LikelihoodParams
from rrg_estimator.grid import Grid
from rrg_models.observation import Observation

from .belief import Belief
from .obs_model import (
    ObsFeatures,
    TableLike,
    features_from_observation,
    likelihood_over_table,
    table_index_axes,
    table_indices,
)
from .transition import bump


def _single_features(obs_or_features: Observation | ObsFeatures, e) -> ObsFeatures:
    feats = (
        obs_or_features
        if isinstance(obs_or_features, ObsFeatures)
        else features_from_observation(obs_or_features, e)
    )
    if len(feats) != 1:
        raise ValueError(f"update takes one observation, got {len(feats)} feature rows")
    return feats


def predict(belief: Belief, e, feats: ObsFeatures) -> Belief:
    """The transition for one observation made by τ(e): a bump along the hand's motion if the
    guarded move stopped on a contact, no motion otherwise."""
    if not feats.contact[0]:
        return belief
    m = feats.motion_dir[0].astype(float)
    if not np.isfinite(m[:2]).all():
        raise ValueError(
            "contact observation without a finite motion direction (features built without "
            "the estimate e, or a malformed observation)"
        )
    c, s = np.cos(e[2]), np.sin(e[2])
    return bump(belief, (c * m[0] - s * m[1], s * m[0] + c * m[1]))


@njit(cache=True)
def _weighted_likelihood(out, weights, table_likelihood, xy, theta):
    """out[i] = weights[i]·L[xy[p] + θ[k]] for belief state i = p·len(θ) + k (float64)."""
    nt = theta.shape[0]
    for p in range(xy.shape[0]):
        base = xy[p]
        for k in range(nt):
            out[p * nt + k] = weights[p * nt + k] * np.float64(table_likelihood[base + theta[k]])


def _posterior(
    prior: Belief, table_likelihood: np.ndarray, xy: np.ndarray, theta: np.ndarray
) -> tuple[Belief, float]:
    """``apply_likelihood`` with the table indices in product form (obs_model.table_index_axes:
    state p·len(θ) + k reads entry xy[p] + θ[k]); the indices must lie within the row."""
    post = np.empty(len(xy) * len(theta))
    if post.shape != prior.weights.shape:
        raise ValueError(f"table indices cover {len(post)} states, not {len(prior.weights)}")
    _weighted_likelihood(post, prior.weights, table_likelihood, xy, theta)
    z = float(post.sum())
    if not np.isfinite(z):
        raise ValueError("likelihood holds NaN or inf (check the table and the observation)")
    if z <= 0.0:
        raise ValueError(
            "the observation has zero probability under the belief (likelihood without floor?)"
        )
    post /= z
    return Belief.from_normalized(prior.grid, post, prior.frame), z


def apply_likelihood(
    prior: Belief, table_likelihood: np.ndarray, idx: np.ndarray
) -> tuple[Belief, float]:
    """b'(w) ∝ b(w)·L[idx(w)] for a likelihood row over table entries (N_table,) and the table
    index of every belief state (N,); returns the posterior and P(o | b) = Σ_w b(w)·L[idx(w)]."""
    lik = np.ascontiguousarray(table_likelihood)
    if lik.dtype not in (np.float32, np.float64):
        lik = lik.astype(np.float64)
    idx = np.ascontiguousarray(idx, dtype=np.int64).ravel()
    if len(idx) and (idx.min() < 0 or idx.max() >= len(lik)):
        raise IndexError(f"table indices beyond the likelihood's {len(lik)} entries")
    return _posterior(prior, lik, idx, np.zeros(1, dtype=np.int64))


def update(
    belief: Belief,
    table: TableLike,
    e,
    obs_or_features: Observation | ObsFeatures,
    transition: bool = True,
    params: LikelihoodParams = LIKELIHOOD,
) -> Belief:
    """SE(b, τ(e), o): the belief after τ(e) (the table's WRT run relative to estimate e)
    produced observation o (an Observation, or one row of ObsFeatures); ``params``: the WRT's
    likelihood parameters (obs_model.likelihood_params)."""
    e = np.asarray(e, dtype=float).reshape(3)
    if not np.all(np.isfinite(e)):
        raise ValueError(f"estimate e must be finite, got {e}")
    feats = _single_features(obs_or_features, e)
    prior = predict(belief, e, feats) if transition else belief
    lik = likelihood_over_table(table, feats, params)[0]
    xy, theta = table_index_axes(belief.grid, e, table.grid)  # within the table by construction
    if len(lik) != table.grid.size:
        raise ValueError(f"table has {len(lik)} entries for a grid of {table.grid.size}")
    posterior, _ = _posterior(prior, lik, xy, theta)
    return posterior


def goal_probability(
    belief: Belief, goal_indicator: np.ndarray, e, table_grid: Grid | None = None
) -> float:
    """P_b(G) of a goal WRT executed relative to e: Σ_w b(w)·G[idx(e, w)].

    goal_indicator: (N_table,) P(G | Δ) (or bool) over the goal WRT's table offsets;
    table_grid defaults to the level grid of the belief's spacing and shape, centred at
    (0, 0, 0), as the tables are built.
    """
    if table_grid is None:
        table_grid = Grid((0.0, 0.0, 0.0), belief.grid.spacing, belief.grid.shape)
    g = np.asarray(goal_indicator, dtype=np.float64).ravel()
    if g.size != table_grid.size:
        raise ValueError(f"goal indicator has {g.size} entries, table grid has {table_grid.size}")
    idx = table_indices(belief.grid, np.asarray(e, dtype=float).reshape(3), table_grid)
    return float(belief.weights @ g[idx])
