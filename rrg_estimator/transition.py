"""Transition models (paper, "Computing the transition model"; algorithm §3).

* No contact: the object does not move (identity; the caller skips the transition).
* Contact (``bump``): a mixture of two outcomes: the object stays (p_stay), or it is
  bumped along the hand's horizontal motion by a Gaussian displacement of mean bump_mean
  with σ = bump_sigma_xy in x, y and bump_sigma_theta in θ.
* Reorientation grasp (``reorient``): the object turns by the commanded angle
  (p_reorient_success), half of it (p_reorient_partial), or not at all, each give or take
  reorient_sigma_theta.
* Firm goal grasp that arrived, then its retreat (``settle``): the object's offset from the
  estimate moves as the object's measured settling map says (objects.Settling, fitted in
  physics by rrg_sim.physics.settle), blurred by the map's residual σ.

Both work on the (nx, ny, nθ) weight array. Mass moved off the grid is dropped and the
rest renormalized.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import map_coordinates
from scipy.special import ndtr
from threadpoolctl import ThreadpoolController

from rrg_estimator.config import TRANSITION, TransitionParams
from rrg_estimator.grid import Grid
from rrg_models.goal import Settling
from rrg_models.poses import compose_planar, relative_planar, wrap_angle
from rrg_models.wrt import ReorientOutcome

from .belief import Belief

#: The displacement's matrices are small (41×41 by 41×1353 on the high grid): a second BLAS
#: thread only spins and, on a busy 2-core machine, made a bump 20× slower; one thread.
_BLAS = ThreadpoolController()

#: Smallest kernel σ in grid cells (a zero σ would divide by zero; this one is a pure shift).
_MIN_SIGMA_CELLS = 1e-6


def displacement_kernel(n: int, shift_cells: float, sigma_cells: float) -> np.ndarray:
    """(n, n) K[dst, src]: the mass moving from cell src to cell dst under a Gaussian
    displacement N(shift, σ²) (in cells), integrated over each destination cell.

    Columns sum to less than 1 where mass leaves the grid.
    """
    sigma = max(float(sigma_cells), _MIN_SIGMA_CELLS)
    off = np.arange(n)[:, None] - np.arange(n)[None, :] - float(shift_cells)
    return ndtr((off + 0.5) / sigma) - ndtr((off - 0.5) / sigma)


def bump(belief: Belief, direction_xy_world, params: TransitionParams = TRANSITION) -> Belief:
    """Contact transition: p_stay·b + (1 - p_stay)·(b shifted by bump_mean·direction and blurred).

    direction_xy_world: (2,) horizontal part of the unit hand-motion direction in ``world``;
    its length (≤ 1) scales the push, so a vertical approach blurs without shifting.
    """
    d = np.asarray(direction_xy_world, dtype=float).reshape(2)
    norm = np.linalg.norm(d)
    if not np.isfinite(norm):
        raise ValueError(f"bump direction must be finite, got {d}")
    if norm > 1.0:
        d = d / norm
    a = belief.as_grid_array()
    moved = displace(
        a,
        belief.grid,
        (params.bump_mean * d[0], params.bump_mean * d[1], 0.0),
        (params.bump_sigma_xy, params.bump_sigma_xy, params.bump_sigma_theta),
    )
    return belief.with_weights(params.p_stay * a + (1.0 - params.p_stay) * moved)


def displace(a: np.ndarray, grid: Grid, shift, sigma) -> np.ndarray:
    """The grid array ``a`` moved by a Gaussian displacement N(shift, σ²) per axis (x [m],
    y [m], θ [rad]); mass pushed off the grid is dropped."""
    (nx, ny, nt), sp = grid.shape, grid.spacing
    kx, ky, kt = (
        displacement_kernel(n, m / h, s / h) for n, m, s, h in zip((nx, ny, nt), shift, sigma, sp)
    )
    with _BLAS.limit(limits=1, user_api="blas"):
        out = (kx @ a.reshape(nx, ny * nt)).reshape(nx, ny, nt)
        return np.matmul(ky, out) @ kt.T


def change_frame(belief: Belief, sigma, frame: str) -> Belief:
    """The belief moved to another posture's frame (rrg_sim.posture_calibration): blurred by
    the σ (x [m], y [m], θ [rad], world axes) of the offset between the two frames, which is
    one fixed, unknown error of the robot's calibration. It is applied once per change, so
    readings in one frame can sharpen the belief only down to that error, never below it."""
    a = displace(belief.as_grid_array(), belief.grid, (0.0, 0.0, 0.0), sigma)
    return Belief(belief.grid, a.ravel(), frame)


def rotated_density(belief: Belief, grid: Grid, angle: float, center_xy=None) -> np.ndarray:
    """(N,) the belief's density after turning the object by ``angle`` [rad], sampled at the
    points of ``grid`` (trilinear interpolation; zero off the belief's grid).

    center_xy None: each state turns about its own centre (x, y unchanged). Otherwise the
    object turns about the vertical axis through center_xy, so x, y rotate about it too.
    """
    q = grid.points()
    src = q.copy()
    src[:, 2] = q[:, 2] - angle
    if center_xy is not None:
        c = np.asarray(center_xy, dtype=float)
        ca, sa = np.cos(angle), np.sin(angle)
        d = q[:, :2] - c
        src[:, 0] = c[0] + ca * d[:, 0] + sa * d[:, 1]
        src[:, 1] = c[1] - sa * d[:, 0] + ca * d[:, 1]
    return sample_density(belief, src)


def sample_density(belief: Belief, poses: np.ndarray) -> np.ndarray:
    """Trilinear interpolation of the belief's weights at poses (K,3); 0 beyond the grid."""
    coords = belief.grid.fractional_index(poses)
    return map_coordinates(
        belief.as_grid_array(), coords.T, order=1, mode="grid-constant", cval=0.0
    )


def reorient(
    belief: Belief,
    angle: float,
    params: TransitionParams = TRANSITION,
    center_xy=None,
    outcome: ReorientOutcome | None = None,
    e=None,
) -> Belief:
    """Reorientation transition: turned by ``angle`` [rad] with p_reorient_success, by angle/2
    with p_reorient_partial, not at all otherwise, each blurred by reorient_sigma_theta.

    The result lives on the belief's grid turned with the object (θ centre + angle, and the
    x, y centre rotated about center_xy if given), so the likely full turn stays on the grid;
    the parts of the partial and failed turns that fall off it are dropped (on a narrow grid,
    e.g. the low-uncertainty one, the failed turn is lost for angles beyond its θ range).
    With the WRT's measured ``outcome`` and its estimate e, the full turn moves each state
    whose offset Δ from e lies in the outcome's box to e' ⊕ (Δ + shift), e' = e turned by the
    angle, blurred by its σ; the rest turn rigidly.
    """
    g = belief.grid
    cx, cy, ct = g.center
    if center_xy is not None:
        c = np.asarray(center_xy, dtype=float)
        ca, sa = np.cos(angle), np.sin(angle)
        cx, cy = (
            c[0] + ca * (cx - c[0]) - sa * (cy - c[1]),
            c[1] + sa * (cx - c[0]) + ca * (cy - c[1]),
        )
    grid = Grid((float(cx), float(cy), float(wrap_angle(ct + angle))), g.spacing, g.shape)
    p_full, p_half = params.p_reorient_success, params.p_reorient_partial
    mix = [(p_full, angle), (p_half, angle / 2.0), (1.0 - p_full - p_half, 0.0)]
    blur = (0.0, 0.0, params.reorient_sigma_theta)
    if outcome is None or e is None:
        w = sum(p * rotated_density(belief, grid, a, center_xy) for p, a in mix if p > 0.0)
        return belief.on_grid(
            grid, displace(w.reshape(grid.shape), grid, (0.0, 0.0, 0.0), blur).ravel()
        )
    w = sum(
        (p * rotated_density(belief, grid, a, center_xy) for p, a in mix[1:] if p > 0.0),
        np.zeros(grid.size),
    )
    w = displace(w.reshape(grid.shape), grid, (0.0, 0.0, 0.0), blur)
    e = np.asarray(e, dtype=float).reshape(3)
    live = np.flatnonzero(belief.weights > 0.0)
    delta = relative_planar(e, belief.grid.points()[live])
    inside = outcome.inside(delta)
    mass = belief.weights[live]
    e_turned = e + np.array([0.0, 0.0, angle])
    rigid = splat(grid, compose_planar(e_turned, delta[~inside]), mass[~inside])
    moved = splat(grid, compose_planar(e_turned, outcome.mean(delta[inside])), mass[inside])
    sigma = np.hypot(outcome.sigma, blur)  # the measured spread and the transition's θ blur
    full = displace(rigid, grid, (0.0, 0.0, 0.0), blur) + displace(
        moved, grid, (0.0, 0.0, 0.0), sigma
    )
    return belief.on_grid(grid, (w + p_full * full).ravel())


def splat(grid: Grid, poses: np.ndarray, mass: np.ndarray) -> np.ndarray:
    """(nx, ny, nθ) the masses (K,) at poses (K,3) spread trilinearly onto the grid's points
    (θ offsets from the grid centre wrapped); mass beyond the grid is dropped."""
    n = np.asarray(grid.shape)
    c = grid.fractional_index(poses)
    lo = np.floor(c).astype(np.int64)
    frac = c - lo
    out = np.zeros(grid.size)
    for corner in np.ndindex(2, 2, 2):
        idx = lo + np.array(corner)
        share = np.prod(np.where(np.array(corner), frac, 1.0 - frac), axis=1)
        ok = np.all((idx >= 0) & (idx < n), axis=1)
        flat = np.ravel_multi_index(idx[ok].T, grid.shape)
        out += np.bincount(flat, weights=mass[ok] * share[ok], minlength=grid.size)
    return out.reshape(grid.shape)


def settle(belief: Belief, settling: Settling, e) -> Belief:
    """Settling transition of a firm goal grasp run at estimate e that arrived, then retreated
    from: each state whose offset Δ = relative_planar(e, w) lies in the studied box moves to
    e ⊕ μ(Δ) of the retreat map (Settling.outcome), blurred by its σ(Δ) averaged over the
    moving mass; the others stay."""
    e = np.asarray(e, dtype=float).reshape(3)
    pts = belief.grid.points()
    w = belief.weights
    live = np.nonzero(w > 0.0)[0]
    delta = relative_planar(e, pts[live])
    moving = settling.inside(delta)
    if not moving.any():
        return belief
    stay = w.copy()
    stay[live[moving]] = 0.0
    mass = w[live[moving]]
    mean, sigma = settling.outcome(delta[moving], "retreated")
    moved = splat(belief.grid, compose_planar(e, mean), mass)
    blur = np.sqrt(mass @ sigma**2 / mass.sum())
    return belief.with_weights(stay + displace(moved, belief.grid, (0.0, 0.0, 0.0), blur).ravel())
