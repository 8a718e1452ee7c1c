"""Variable-resolution grid (algorithm §3; beyond the paper, which names it as the fix for its
cup and teabox failures at high uncertainty): once a coarse belief has concentrated, re-grid
it at a finer level's spacing over a box the size of that level's grid (HIGH → MID → LOW,
straight to LOW when it already fits).

Each coarse point stands for its cell, so the box must hold the cells, not only the points:
the run of coarse points is sought in a box half a coarse spacing smaller on every side
(otherwise a truth in the outer half of an end cell lies beyond the fine grid).

The box centre is the belief's mean when the box there already holds 1 - ε of the mass.
Otherwise (a skewed belief) it is found by searching all axis-aligned runs of coarse grid
points a box can span, taking the one holding the most mass, and placing the box as close
to the mean as it can be while still containing that run.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from rrg_estimator.config import LEVELS, VARRES_EPS, VARRES_RECENTER, UncertaintyLevel
from rrg_estimator.grid import Grid
from rrg_models.poses import wrap_angle

from .belief import Belief
from .transition import sample_density


def _window_sums(a: np.ndarray, lengths) -> np.ndarray:
    """Sums of a over every axis-aligned window of the given lengths ('valid' positions)."""
    for axis, n in enumerate(lengths):
        c = np.cumsum(a, axis=axis)
        c = np.concatenate([np.zeros_like(c.take([0], axis=axis)), c], axis=axis)
        a = c.take(np.arange(n, c.shape[axis]), axis=axis) - c.take(
            np.arange(c.shape[axis] - n), axis=axis
        )
    return a


def refinement_center(belief: Belief, half_extent: np.ndarray, eps: float) -> np.ndarray | None:
    """Centre (3,) of a box of ±half_extent holding ≥ 1 - eps of the belief's mass, or None."""
    g = belief.grid
    axes = g.axes()
    spacing = np.asarray(g.spacing)
    a = belief.as_grid_array()
    mean = belief.mean()
    mean[2] = g.center[2] + wrap_angle(mean[2] - g.center[2])  # in the grid's unwrapped θ frame
    inside = [
        np.abs(ax - m) <= h + 1e-9 * s for ax, m, h, s in zip(axes, mean, half_extent, spacing)
    ]
    if a[np.ix_(*inside)].sum() >= 1.0 - eps:
        return mean
    lengths = [
        min(int(np.floor(2 * h / s + 1e-9)) + 1, n)
        for h, s, n in zip(half_extent, spacing, g.shape)
    ]
    sums = _window_sums(a, lengths)
    best = sums.max()
    if best < 1.0 - eps:
        return None
    starts = np.argwhere(sums >= best - 1e-12)  # (K,3) first grid index of each best run
    lo = np.stack([axes[k][starts[:, k]] for k in range(3)], axis=1)
    hi = np.stack([axes[k][starts[:, k] + lengths[k] - 1] for k in range(3)], axis=1)
    centers = np.clip(mean, hi - half_extent, lo + half_extent)
    return centers[np.argmin(np.sum(((centers - mean) / spacing) ** 2, axis=1))]


def _off_centre(belief: Belief) -> bool:
    """A fine belief whose mean has left the middle of its grid (the object moved: a bump, a
    firm grasp): more than VARRES_RECENTER of the half extent off the centre on some axis."""
    off = belief.mean() - np.asarray(belief.grid.center)
    off[2] = wrap_angle(off[2])
    return bool(np.any(np.abs(off) > VARRES_RECENTER * belief.grid.half_extent))


def _regrid(belief: Belief, level: UncertaintyLevel, center: np.ndarray) -> Belief:
    center[2] = wrap_angle(center[2])
    fine = Grid.for_level(level, center)
    return belief.on_grid(fine, sample_density(belief, fine.points()))


def maybe_refine(
    belief: Belief, levels: Iterable[UncertaintyLevel] = LEVELS.values(), eps: float = VARRES_EPS
) -> Belief | None:
    """The belief re-gridded at the finest of ``levels`` finer than its grid whose box holds
    at least 1 - eps of its mass with half a cell of margin (see the module); None when none
    does. A belief already on one of ``levels``' refined grids and on no finer one is
    re-centred on its mean once the mean is more than VARRES_RECENTER of the grid's half
    extent off its centre on some axis (the fixed grid of the paper cannot follow an object
    that moves further than that), even when that drops more than eps: mass piling up on
    one border says the object lies beyond it (MuJoCo, without re-centring: a sweep pushed the
    drill 0.2 rad off a MID grid whose tail kept every eps-box where it was, until the belief
    collapsed on the border and the goal grasp ran 0.2 rad off).

    Weights on the fine grid are the coarse density interpolated trilinearly, renormalized
    (the ≤ eps of mass outside the box is dropped).
    """
    spacing = np.asarray(belief.grid.spacing)
    finer = sorted(
        (lv for lv in levels if np.all(np.asarray(lv.spacing) < spacing * (1 - 1e-9))),
        key=lambda lv: float(np.prod(lv.spacing)),
    )
    for level in finer:
        center = refinement_center(belief, Grid.for_level(level).half_extent - spacing / 2, eps)
        if center is not None:
            return _regrid(belief, level, center)
    coarsest = max(LEVELS.values(), key=lambda lv: float(np.prod(lv.spacing)))
    own = [
        lv
        for lv in levels
        if np.allclose(lv.spacing, spacing)
        and tuple(lv.shape) == belief.grid.shape
        and not np.allclose(lv.spacing, coarsest.spacing)
    ]  # HIGH's grid spans the prior: it stays
    if not own or not _off_centre(belief):
        return None
    return _regrid(belief, own[0], belief.mean())
