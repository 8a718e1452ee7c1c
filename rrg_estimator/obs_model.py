"""The observation model P(o | w, τ(e)) (design §5) on top of the offline observation tables.

An observation made by τ(e) with the object at w depends only on the relative offset
Δ = e⁻¹ ⊕ w (paper, Fig. 3), so the likelihood of every belief state is read from the
WRT's table at the entry nearest to its offset (``table_indices``).

The likelihood of one table entry is the product of
  * contact agreement: 1 - p_contact_mismatch, or p_contact_mismatch;
  * where the hand stopped: max(exp(-½((p_o - p_t)/σ_progress)²), κ_progress) when both
    report an early contact (when neither does, both stopped at the path's end: 1);
  * each of the 10 sensors: P(fired) = q·p_detect + (1 - q)·p_false_alarm (silent: 1 minus
    that), q the probability that contact on it is predicted anywhere in the entry's cell
    (``sensor_prediction``: 1 or 0 where the neighbours agree);
  * max(exp(-½((c_o - c_t)/σ_t)²), κ_closure) per finger closure angle, σ_t the entry's own
    closure σ: σ_closure widened by its nearest-entry discretization (``closure_sigma``);
  * max(exp(-½(|x_o - x_t|/σ_tip)²), κ_tip) per fingertip contact point present on both
    sides (a point present on one side only is already judged by that tip's sensor term);
(the closure term is left out for a WRT whose closures physics does not reproduce, e.g.
a firm goal grasp that pulls the object as it closes: ``likelihood_params``); the κ are
per-term outlier floors (LIKELIHOOD.outlier_*): a finger that pushes a light object on while
closing disagrees with the geometric prediction in one term, which then costs a bounded
factor instead of flooring every state and erasing what the other terms said;
and is then floored: L' = (1 - ε)·L + ε with ε = LIKELIHOOD.floor, so no single
observation can rule out a state (the true state survives a surprising reading, e.g.
from unmodelled dynamics, and later observations can bring it back).
"""

from __future__ import annotations

import weakref
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Protocol, TypeVar

import numpy as np
from scipy.ndimage import convolve1d

from rrg_estimator.config import LIKELIHOOD, LikelihoodParams
from rrg_estimator.grid import Grid
from rrg_sim.config import N_SENSORS
from rrg_sim.observation import Observation
from rrg_sim.poses import wrap_angle
from rrg_sim.wrt import WRT

T = TypeVar("T")


class TableLike(Protocol):
    """The fields of rrg_estimator.obs_tables.ObservationTable the estimator reads."""

    grid: Grid
    path_length: float
    contact: np.ndarray  # (N,) bool
    progress: np.ndarray  # (N,) m
    sensors: np.ndarray  # (N,10) bool
    closure: np.ndarray  # (N,3) rad
    tip_points: np.ndarray  # (N,3,3) m, hand frame, NaN = no contact
    motion_dir: np.ndarray  # (N,3) in the estimate's frame


@dataclass(frozen=True, eq=False)
class ObsFeatures:
    """M observations in table-comparable form.

    contact (M,) bool; progress (M,) float32 m; sensors (M,10) bool; closure (M,3) float32
    rad; tip_points (M,3,3) float32 m in the hand frame (NaN rows = no contact);
    motion_dir (M,3) float32: the hand's motion at the stop in the frame of the estimate e
    the WRT ran relative to (as the tables store it; NaN when unknown).
    """

    contact: np.ndarray
    progress: np.ndarray
    sensors: np.ndarray
    closure: np.ndarray
    tip_points: np.ndarray
    motion_dir: np.ndarray

    def __len__(self) -> int:
        return len(self.contact)

    def take(self, rows) -> ObsFeatures:
        """The features of the given rows."""
        rows = np.atleast_1d(np.asarray(rows, dtype=np.int64))
        return ObsFeatures(
            *(
                getattr(self, f)[rows]
                for f in ("contact", "progress", "sensors", "closure", "tip_points", "motion_dir")
            )
        )


def _features(contact, progress, sensors, closure, tip_points, motion_dir) -> ObsFeatures:
    return ObsFeatures(
        contact=np.asarray(contact, dtype=bool).reshape(-1),
        progress=np.asarray(progress, dtype=np.float32).reshape(-1),
        sensors=np.asarray(sensors, dtype=bool).reshape(-1, N_SENSORS),
        closure=np.asarray(closure, dtype=np.float32).reshape(-1, 3),
        tip_points=np.asarray(tip_points, dtype=np.float32).reshape(-1, 3, 3),
        motion_dir=np.asarray(motion_dir, dtype=np.float32).reshape(-1, 3),
    )


def features_from_observation(obs: Observation, e=None) -> ObsFeatures:
    """One observation as features (M = 1).

    obs.motion_dir is in ``world``; it is rotated into the frame of the estimate e when e is
    given (needed by the bump transition), and NaN otherwise (the likelihood does not use it).
    """
    if e is None:
        motion = np.full(3, np.nan)
    else:
        c, s = np.cos(e[2]), np.sin(e[2])
        m = obs.motion_dir
        motion = np.array([c * m[0] + s * m[1], -s * m[0] + c * m[1], m[2]])
    return _features(obs.contact, obs.progress, obs.sensors, obs.closure, obs.tip_points, motion)


def features_from_table_rows(table: TableLike, rows) -> ObsFeatures:
    """The predicted observations Ω_τ(Δ_j) of the given table rows, as features."""
    rows = np.atleast_1d(np.asarray(rows, dtype=np.int64))
    return _features(
        table.contact[rows],
        table.progress[rows],
        table.sensors[rows],
        table.closure[rows],
        table.tip_points[rows],
        table.motion_dir[rows],
    )


#: Weights of an entry and its two neighbours along one grid axis in the probability that a
#: sensor's predicted contact holds somewhere in the entry's cell: where the prediction
#: differs from a neighbour's, the switch lies anywhere between the two grid points, so on
#: average 1/8 of the cell (±½ cell about its point) is on the neighbour's side.
CELL_WEIGHTS = np.array([0.125, 0.75, 0.125])

_SENSOR_LOG: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _per_table(
    cache: weakref.WeakKeyDictionary, table: TableLike, key, build: Callable[[], T]
) -> T:
    """``build()`` for ``table``, remembered in ``cache`` (weakly referenced) while ``key``
    (the parameters it depends on) stays the same."""
    cached = cache.get(table)
    if cached is None or cached[0] != key:
        cached = cache[table] = (key, build())
    return cached[1]


def sensor_prediction(table: TableLike) -> np.ndarray:
    """(N, 10) float: the probability q that contact on each sensor is predicted within each
    table entry's cell (the entry's flags averaged with its neighbours' by CELL_WEIGHTS along
    each axis; the table's edges count their own flag). A flag that flickers between
    neighbouring entries (a finger grazing one facet of a polygonal rim every 0.31 rad of
    θ) is about 0.4 instead of a certain 1 or 0, so it no longer makes the likelihood spike
    on the grid points that happen to sample it."""
    q = np.asarray(table.sensors, dtype=np.float64).reshape(*table.grid.shape, -1)
    for axis in range(3):
        q = convolve1d(q, CELL_WEIGHTS, axis=axis, mode="nearest")
    return q.reshape(len(table.sensors), -1)


def sensor_log_likelihood(
    table: TableLike, params: LikelihoodParams
) -> tuple[np.ndarray, np.ndarray]:
    """(silent (N,), gain (10, N)) float32: every sensor silent, Σ_s log P(silent | q_s), per
    entry, and log P(fired | q) - log P(silent | q) per sensor (``sensor_prediction``); a
    reading's sensor term is silent + o @ gain. The params' unsensed sensors have no term (their
    gain is 0). Cached per table (weakly referenced)."""

    def build() -> tuple[np.ndarray, np.ndarray]:
        q = sensor_prediction(table)
        fired = q * params.p_detect + (1.0 - q) * params.p_false_alarm
        silent = np.log1p(-fired)
        gain = np.log(fired) - silent
        unsensed = list(params.unsensed)
        silent[:, unsensed] = 0.0
        gain[:, unsensed] = 0.0
        return (
            silent.sum(axis=1).astype(np.float32),
            np.ascontiguousarray(gain.T.astype(np.float32)),
        )

    key = (params.p_detect, params.p_false_alarm, tuple(params.unsensed))
    return _per_table(_SENSOR_LOG, table, key, build)


def likelihood_params(wrt: WRT, params: LikelihoodParams = LIKELIHOOD) -> LikelihoodParams:
    """The likelihood parameters of observations made by ``wrt``: an infinite σ_closure (the
    closure term is 1) when its closures are not informative (WRT.closure_informative)."""
    return params if wrt.closure_informative else replace(params, sigma_closure=float("inf"))


_CLOSURE_SIGMA: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def closure_sigma(table: TableLike, sigma: float) -> np.ndarray:
    """(3, N) float32 σ of each table entry's predicted closure angles: √(σ² + Σ_axis g²/12),
    with σ the spread of physics about the geometric prediction at the exact offset and g the
    larger change to a grid neighbour along each axis. An observation is compared with the
    entry nearest its offset, which lies anywhere within ± half a cell; where a finger's
    closure changes fast with the offset (the drill's info3 pinch: 0.14 rad per cm) that
    discretization dominates, where it is flat σ does. Cached per table (weakly referenced)."""
    n = len(table.closure)
    if not np.isfinite(sigma):
        return np.full((3, n), sigma, dtype=np.float32)

    def build() -> np.ndarray:
        c = np.asarray(table.closure, dtype=np.float64).reshape(*table.grid.shape, 3)
        var = np.zeros_like(c)
        for axis in range(3):
            d = np.abs(np.diff(c, axis=axis))
            before, after = [(0, 0)] * 4, [(0, 0)] * 4
            before[axis], after[axis] = (1, 0), (0, 1)
            g = np.maximum(np.pad(d, before), np.pad(d, after))  # the larger change to a neighbour
            var += g * g / 12.0
        return np.ascontiguousarray(np.sqrt(sigma * sigma + var).reshape(n, 3).T.astype(np.float32))

    return _per_table(_CLOSURE_SIGMA, table, sigma, build)


def log_likelihood_over_table(
    table: TableLike, feats: ObsFeatures, params: LikelihoodParams = LIKELIHOOD
) -> np.ndarray:
    """(M, N_table) float32 log L (before the floor) of each observation at each table entry."""
    f32 = np.float32
    n = len(table.contact)
    t_contact = np.asarray(table.contact, dtype=bool)
    # contact agreement
    agree = feats.contact[:, None] == t_contact[None, :]
    logl = np.where(
        agree, f32(np.log1p(-params.p_contact_mismatch)), f32(np.log(params.p_contact_mismatch))
    )
    # progress, where both stopped early
    if feats.contact.any():
        zp = (feats.progress[:, None] - np.asarray(table.progress, dtype=f32)[None, :]) / f32(
            params.sigma_progress
        )
        cost = np.minimum(f32(0.5) * zp * zp, f32(-np.log(params.outlier_progress)))
        logl -= np.where(feats.contact[:, None] & t_contact[None, :], cost, f32(0.0))
    # sensors: Σ_s log P(o_s | q_s)
    #   = Σ_s log P(silent | q_s) + Σ_s o_s (log P(fired | q_s) - log P(silent | q_s))
    silent, gain = sensor_log_likelihood(table, params)
    logl += silent[None, :]
    logl += feats.sensors.astype(f32) @ gain
    # closure angles (component rows made contiguous once)
    closure = np.ascontiguousarray(np.asarray(table.closure, dtype=f32).T)  # (3, N)
    sig = closure_sigma(table, params.sigma_closure)
    for k in range(3):
        z = (feats.closure[:, k, None] - closure[k][None, :]) / sig[k][None, :]
        logl -= np.minimum(f32(0.5) * z * z, f32(-np.log(params.outlier_closure)))
    # fingertip contact points present on both sides
    tips = np.ascontiguousarray(np.asarray(table.tip_points, dtype=f32).reshape(n, 9).T)  # (9, N)
    for f in range(3):
        seen = ~np.isnan(feats.tip_points[:, f, 0])
        if not seen.any():
            continue
        d2 = sum(
            (feats.tip_points[:, f, k, None] - tips[3 * f + k][None, :]) ** 2 for k in range(3)
        )
        cost = np.minimum(d2 * f32(0.5 / params.sigma_tip**2), f32(-np.log(params.outlier_tip)))
        logl -= np.where(np.isnan(d2), f32(0.0), cost)
    return logl


def likelihood_over_table(
    table: TableLike, feats: ObsFeatures, params: LikelihoodParams = LIKELIHOOD
) -> np.ndarray:
    """(M, N_table) float32: the floored likelihood (1-ε)·L + ε of each observation at each entry.

    Raises ValueError when an observation's progress or closure is NaN.
    """
    bad = [
        n
        for n, v in (("progress", feats.progress), ("closure", feats.closure))
        if not np.isfinite(v).all()
    ]
    if bad:
        raise ValueError(f"observation features hold non-finite {' and '.join(bad)} (NaN or inf)")
    eps = np.float32(params.floor)
    return np.exp(log_likelihood_over_table(table, feats, params)) * (np.float32(1.0) - eps) + eps


def table_indices(belief_grid: Grid, e, table_grid: Grid) -> np.ndarray:
    """(N,) int64: for each belief grid point w, the flat index of the table entry nearest to
    Δ = relative_planar(e, w), clamped to the table border.

    Same arithmetic as ``table_grid.nearest_index(relative_planar(e, belief_grid.points()))``,
    but exploiting the product structure of the belief grid (x, y separate from θ).
    """
    ex, ey, et = (float(v) for v in e)
    ax, ay, at = belief_grid.axes()
    c, s = np.cos(np.array([et])), np.sin(np.array([et]))
    dx, dy = (ax - ex)[:, None], (ay - ey)[None, :]
    rel = (c * dx + s * dy, -s * dx + c * dy, wrap_angle(at - et))
    n = np.asarray(table_grid.shape)
    idx = []
    for k, (r, c0, sp) in enumerate(zip(rel, table_grid.center, table_grid.spacing)):
        d = r - c0
        if k == 2:
            d = wrap_angle(d)
        idx.append(np.clip(np.rint(d / sp + (n[k] - 1) / 2).astype(np.int64), 0, n[k] - 1))
    ix, iy, it = idx
    flat = (ix * n[1] + iy)[:, :, None] * n[2] + it[None, None, :]
    return flat.ravel()
