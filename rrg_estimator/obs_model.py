"""The observation model P(o | w, τ(e)) (algorithm §5) on top of the offline observation tables.

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
    closure σ: σ_closure widened by its nearest-entry discretization, and infinite where
    the table's finger stopped on a sensor the robot lacks (``closure_sigma``);
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

One reading's log-likelihood over a whole table is one compiled pass (numba,
``_log_likelihood_row``) over the table's columns, in float32, term by term in the order
above; the sensor terms are summed in sensor order, so a reading's likelihood is the same to
the bit batched (the planner's clusters) or alone (the estimator's update), whatever BLAS and
thread count. exp and the floor stay numpy's.
"""

from __future__ import annotations

import weakref
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import Protocol, TypeVar

import numpy as np
from numba import njit
from scipy.ndimage import convolve1d

from rrg_estimator.config import LIKELIHOOD, LikelihoodParams
from rrg_estimator.grid import Grid
from rrg_models.config import FINGER_SENSORS, N_SENSORS
from rrg_models.observation import Observation
from rrg_models.poses import wrap_angle
from rrg_models.wrt import WRT

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


def stopped_unsensed(sensors: np.ndarray, unsensed: tuple[int, ...]) -> np.ndarray:
    """(N, 3) bool: the fingers whose predicted sensors (N, 10) include one of ``unsensed``
    and none of the finger's other sensors (a careful closing's stop the robot cannot make)."""
    sensors = np.asarray(sensors, dtype=bool)
    out = np.zeros((len(sensors), 3), dtype=bool)
    for finger, own in enumerate(FINGER_SENSORS):
        lacking = [s for s in own if s in unsensed]
        sensed = [s for s in own if s not in unsensed]
        if lacking:
            out[:, finger] = sensors[:, lacking].any(axis=1) & ~sensors[:, sensed].any(axis=1)
    return out


def closure_sigma(table: TableLike, sigma: float, unsensed: tuple[int, ...] = ()) -> np.ndarray:
    """(3, N) float32 σ of each table entry's predicted closure angles: √(σ² + Σ_axis g²/12),
    with σ the spread of physics about the geometric prediction at the exact offset and g the
    larger change to a grid neighbour along each axis. An observation is compared with the
    entry nearest its offset, which lies anywhere within ± half a cell; where a finger's
    closure changes fast with the offset (the drill's info3 pinch: 0.14 rad per cm) that
    discretization dominates, where it is flat σ does.

    ``unsensed`` (sensor ids the robot has no reading of): a finger the table predicts stopped
    by one of them alone (its own sensed sensors silent) has an infinite σ there. A careful
    closing stops a finger when one of its own sensors fires; the robot's finger does not
    stop there but closes on, off the object or onto it, so its closure says nothing the
    table predicts (a BarrettHand with tactile pucks only, whose proximal link brushed the
    object in a sweep, closes that finger fully). Cached per table (weakly referenced)."""
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
        out = np.sqrt(sigma * sigma + var).reshape(n, 3).T
        if unsensed:
            out[stopped_unsensed(table.sensors, unsensed).T] = np.inf
        return np.ascontiguousarray(out.astype(np.float32))

    return _per_table(_CLOSURE_SIGMA, table, (sigma, tuple(unsensed)), build)


@dataclass(frozen=True, eq=False)
class _TableColumns:
    """A table's fields as the likelihood kernel reads them: contiguous, one row per component."""

    contact: np.ndarray  # (N,) bool
    progress: np.ndarray  # (N,) float32 m
    closure: np.ndarray  # (3, N) float32 rad
    tips: np.ndarray  # (9, N) float32 m, finger f's point in rows 3f..3f+2


_COLUMNS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _table_columns(table: TableLike) -> _TableColumns:
    """The table's columns for the kernel, cached per table (weakly referenced)."""

    def build() -> _TableColumns:
        f32, n = np.float32, len(table.contact)
        return _TableColumns(
            contact=np.ascontiguousarray(table.contact, dtype=bool),
            progress=np.ascontiguousarray(table.progress, dtype=f32),
            closure=np.ascontiguousarray(np.asarray(table.closure, dtype=f32).T),
            tips=np.ascontiguousarray(np.asarray(table.tip_points, dtype=f32).reshape(n, 9).T),
        )

    return _per_table(_COLUMNS, table, None, build)


#: Table entries per block of the likelihood kernel: its output block stays in the L1 cache
#: while each term passes over it.
_BLOCK = 1024


@njit(cache=True, error_model="numpy")  # IEEE division (x/0 = inf, as numpy), vectorizable
def _log_likelihood_row(
    out, contact, progress, closure, tips, sensor_term, tips_seen, columns_contact,
    columns_progress, silent, columns_closure, closure_sig, columns_tips, log_agree, log_mismatch,
    sigma_progress, cap_progress, cap_closure, tip_scale, cap_tip, half,
):  # fmt: skip
    """log L (before the floor) of one observation at every table entry, into out (N,) float32.

    Float32 arithmetic, term by term in the order of the module docstring, each term one
    simple loop over a block of entries (so the compiler vectorizes it). ``sensor_term`` (N,):
    Σ_s o_s·gain_s, computed by the caller with BLAS as it always was, so the result is the
    numpy formula's to the bit; ``tips_seen`` (3,) bool: the reading has finger f's point; the
    cap_* are the per-term outlier caps -log κ.
    """
    n = out.shape[0]
    zero = np.float32(0.0)  # (a bare 0.0 is float64 and would promote the arithmetic)
    for start in range(0, n, _BLOCK):
        stop = min(start + _BLOCK, n)
        block = out[start:stop]  # views of the block: loops from 0 vectorize
        t_contact = columns_contact[start:stop]
        sensors = sensor_term[start:stop]  # joins the other terms where the formula adds it
        t_progress, t_silent = columns_progress[start:stop], silent[start:stop]
        for j in range(block.shape[0]):
            logl = log_agree if contact == t_contact[j] else log_mismatch
            if contact:  # where the hand stopped, where both stopped early
                zp = (progress - t_progress[j]) / sigma_progress
                cost = half * zp * zp
                cost = cap_progress if cost > cap_progress else cost  # NaN stays NaN
                logl -= cost if t_contact[j] else zero
            logl += t_silent[j]
            block[j] = logl + sensors[j]
        for k in range(3):
            observed = closure[k]
            t_closure, sig = columns_closure[k, start:stop], closure_sig[k, start:stop]
            for j in range(block.shape[0]):
                z = (observed - t_closure[j]) / sig[j]
                cost = half * z * z
                block[j] -= cap_closure if cost > cap_closure else cost
        for f in range(3):
            if not tips_seen[f]:
                continue
            tx, ty, tz = tips[f, 0], tips[f, 1], tips[f, 2]
            px = columns_tips[3 * f, start:stop]
            py = columns_tips[3 * f + 1, start:stop]
            pz = columns_tips[3 * f + 2, start:stop]
            for j in range(block.shape[0]):
                dx, dy, dz = tx - px[j], ty - py[j], tz - pz[j]
                d2 = dx * dx + dy * dy + dz * dz
                cost = d2 * tip_scale
                cost = cap_tip if cost > cap_tip else cost
                # a point missing on one side adds nothing (its sensor term judges it)
                block[j] -= zero if np.isnan(d2) else cost


@lru_cache(maxsize=64)
def _kernel_constants(params: LikelihoodParams) -> tuple[np.float32, ...]:
    """The likelihood kernel's float32 constants of ``params``: log(1 - p_mismatch),
    log p_mismatch, σ_progress, the three caps -log κ, ½/σ_tip² and ½."""
    f32 = np.float32
    return (
        f32(np.log1p(-params.p_contact_mismatch)),
        f32(np.log(params.p_contact_mismatch)),
        f32(params.sigma_progress),
        f32(-np.log(params.outlier_progress)),
        f32(-np.log(params.outlier_closure)),
        f32(0.5 / params.sigma_tip**2),
        f32(-np.log(params.outlier_tip)),
        f32(0.5),
    )


def log_likelihood_over_table(
    table: TableLike, feats: ObsFeatures, params: LikelihoodParams = LIKELIHOOD
) -> np.ndarray:
    """(M, N_table) float32 log L (before the floor) of each observation at each table entry."""
    f32 = np.float32
    cols = _table_columns(table)
    silent, gain = sensor_log_likelihood(table, params)
    sig = closure_sigma(table, params.sigma_closure, tuple(params.unsensed))
    constants = _kernel_constants(params)
    logl = np.empty((len(feats), len(cols.contact)), dtype=f32)
    # Σ_s o_s·gain_s for every reading at once, with BLAS (its summation order, which the
    # tables' recorded campaigns were computed with)
    sensor_terms = feats.sensors.astype(f32) @ gain
    for m in range(len(feats)):
        tips = np.ascontiguousarray(feats.tip_points[m], dtype=f32)
        _log_likelihood_row(
            logl[m],
            bool(feats.contact[m]),
            f32(feats.progress[m]),
            np.ascontiguousarray(feats.closure[m], dtype=f32),
            tips,
            sensor_terms[m],
            ~np.isnan(tips[:, 0]),
            cols.contact,
            cols.progress,
            silent,
            cols.closure,
            sig,
            cols.tips,
            *constants,
        )
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
    like = log_likelihood_over_table(table, feats, params)
    np.exp(like, out=like)
    like *= np.float32(1.0) - eps
    like += eps
    return like


@lru_cache(maxsize=16)
def _grid_axes(grid: Grid) -> tuple[np.ndarray, ...]:
    """grid.axes(), remembered per grid (a belief's grid serves many updates); read-only."""
    axes = tuple(grid.axes())
    for a in axes:
        a.flags.writeable = False
    return axes


@njit(cache=True)
def _nearest_cell(d: float, spacing: float, n: int) -> int:
    """Index of the grid point nearest to offset d from the centre of an axis of n points,
    clamped to [0, n - 1] (rint: halves to even, as numpy's)."""
    i = int(np.rint(d / spacing + (n - 1) / 2))
    return min(max(i, 0), n - 1)


@njit(cache=True)
def _table_cells(dx, dy, theta, c, s, center, spacing, shape, xy_out, theta_out):
    """The table cells of the belief grid's axes, into xy_out (nx·ny,) (the flat index of the
    entry with θ index 0) and theta_out (nθ,): x, y relative to e are the rotation (c, s)
    of dx, dy; ``theta``: the θ offsets from the table centre, already wrapped."""
    for i in range(dx.shape[0]):
        for j in range(dy.shape[0]):
            rx = c * dx[i] + s * dy[j]
            ry = -s * dx[i] + c * dy[j]
            ix = _nearest_cell(rx - center[0], spacing[0], shape[0])
            iy = _nearest_cell(ry - center[1], spacing[1], shape[1])
            xy_out[i * dy.shape[0] + j] = (ix * shape[1] + iy) * shape[2]
    for k in range(theta.shape[0]):
        theta_out[k] = _nearest_cell(theta[k], spacing[2], shape[2])


def table_index_axes(belief_grid: Grid, e, table_grid: Grid) -> tuple[np.ndarray, np.ndarray]:
    """The table indices of ``table_indices`` in their product form: (xy (nx·ny,), θ (nθ,))
    int64 such that the flat table index of belief point (ix, iy, iθ) is
    xy[ix·ny + iy] + θ[iθ] (the rotation by e mixes x and y; θ is a shift of its own)."""
    ex, ey, et = (float(v) for v in e)
    ax, ay, at = _grid_axes(belief_grid)
    c, s = np.cos(np.array([et])), np.sin(np.array([et]))
    theta = wrap_angle(wrap_angle(at - et) - table_grid.center[2])
    xy = np.empty(len(ax) * len(ay), dtype=np.int64)
    it = np.empty(len(at), dtype=np.int64)
    _table_cells(
        ax - ex,
        ay - ey,
        theta,
        float(c[0]),
        float(s[0]),
        np.asarray(table_grid.center, dtype=np.float64),
        np.asarray(table_grid.spacing, dtype=np.float64),
        np.asarray(table_grid.shape, dtype=np.int64),
        xy,
        it,
    )
    return xy, it


def table_indices(belief_grid: Grid, e, table_grid: Grid) -> np.ndarray:
    """(N,) int64: for each belief grid point w, the flat index of the table entry nearest to
    Δ = relative_planar(e, w), clamped to the table border.

    Same arithmetic as ``table_grid.nearest_index(relative_planar(e, belief_grid.points()))``,
    but exploiting the product structure of the belief grid (x, y separate from θ:
    ``table_index_axes``).
    """
    xy, theta = table_index_axes(belief_grid, e, table_grid)
    return (xy[:, None] + theta[None, :]).ravel()
