"""Offline observation clustering (paper: "Reducing the observation branching factor").

Predicted observations of one WRT are grouped by their contact signature, independent of
the absolute pose: early contact or not, which sensors fired, where along the path the
hand stopped (binned) and how far each finger closed (binned). Groups whose aggregate
prior probability is below ``SEARCH.offline_prune`` are pruned. Each kept group is
represented by one canonical observation: its most probable member.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rrg_estimator.config import LIKELIHOOD, LikelihoodParams, UncertaintyLevel
from rrg_estimator.obs_model import features_from_table_rows, likelihood_over_table
from rrg_estimator.obs_tables import ObservationTable
from rrg_planner.config import SEARCH

#: Signature bin widths (chosen: about two σ of the likelihood's progress and closure terms).
PROGRESS_BIN = 0.02  # m
CLOSURE_BIN = 0.25  # rad


@dataclass(frozen=True)
class ObservationClusters:
    """Clusters of one table.

    assign: (N_table,) cluster id of every table entry, -1 where the cluster was pruned.
    representatives: (C,) table row of each cluster's canonical observation.
    prior: (C,) aggregate prior probability of each cluster.
    likelihood: (C, N_table) float32, P(o_c | Δ_j) of the canonical observations.
    l_log_l: (C, N_table) float32, likelihood · log likelihood (for posterior entropies).
    contact: (C,) bool, whether the canonical observation has an early contact.
    """

    assign: np.ndarray
    representatives: np.ndarray
    prior: np.ndarray
    likelihood: np.ndarray
    l_log_l: np.ndarray
    contact: np.ndarray

    @property
    def count(self) -> int:
        return len(self.representatives)


def signature_keys(
    table: ObservationTable, closure: bool = True, unsensed: tuple[int, ...] = ()
) -> np.ndarray:
    """(N,) int64 key of each entry's contact signature (equal keys = same cluster);
    closure False: the closure angles do not split clusters (the likelihood ignores them);
    the unsensed sensors do not split them either (the robot cannot tell them apart)."""
    sensed = np.ones(table.sensors.shape[1], dtype=np.int64)
    sensed[list(unsensed)] = 0
    bits = table.sensors.astype(np.int64) @ (
        sensed << np.arange(table.sensors.shape[1], dtype=np.int64)
    )
    prog = np.rint(table.progress / PROGRESS_BIN).astype(np.int64)
    clos = (
        np.rint(table.closure / CLOSURE_BIN).astype(np.int64)
        if closure
        else np.zeros((len(table), 0), np.int64)
    )
    cols = np.column_stack([table.contact.astype(np.int64), bits, prog, clos])
    _, inverse = np.unique(cols, axis=0, return_inverse=True)
    return inverse.ravel()


def offset_prior(table: ObservationTable, level: UncertaintyLevel) -> np.ndarray:
    """Prior over the table's offsets Δ: the level's initial Gaussian centred on the estimate."""
    d = table.grid.points()
    z = d / np.asarray(level.sigma)
    p = np.exp(-0.5 * np.sum(z * z, axis=1))
    return p / p.sum()


def cluster_table(
    table: ObservationTable,
    level: UncertaintyLevel,
    prune: float = SEARCH.offline_prune,
    params: LikelihoodParams = LIKELIHOOD,
) -> ObservationClusters:
    """Group a table's predicted observations and precompute their likelihood rows
    (``params``: the WRT's likelihood parameters, obs_model.likelihood_params)."""
    keys = signature_keys(table, np.isfinite(params.sigma_closure), tuple(params.unsensed))
    prior = offset_prior(table, level)
    mass = np.bincount(keys, weights=prior)
    kept = np.flatnonzero(mass >= prune)
    kept = kept[np.argsort(-mass[kept])]
    remap = np.full(mass.shape[0], -1, dtype=np.int64)
    remap[kept] = np.arange(len(kept))
    assign = remap[keys]
    # Canonical observation: the most probable member of each kept cluster.
    order = np.lexsort((-prior, assign))  # by cluster, then by decreasing prior
    sorted_assign = assign[order]
    first = np.flatnonzero(np.r_[True, sorted_assign[1:] != sorted_assign[:-1]])
    reps_by_cluster = {int(sorted_assign[i]): int(order[i]) for i in first if sorted_assign[i] >= 0}
    reps = np.array([reps_by_cluster[c] for c in range(len(kept))], dtype=np.int64)
    feats = features_from_table_rows(table, reps)
    like = likelihood_over_table(table, feats, params).astype(np.float32)
    return ObservationClusters(
        assign=assign,
        representatives=reps,
        prior=mass[kept],
        likelihood=like,
        l_log_l=like * np.log(like),
        contact=table.contact[reps].astype(bool),
    )
