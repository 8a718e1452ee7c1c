"""A naive reference of the belief update, written state by state in plain Python the way the
paper's "non-optimized Python implementation" would be. It shares no code with the fast
path (only the Belief container), so tests check the vectorized update against it on small
grids, and the benchmark uses it as the baseline.

Cost: the likelihood is O(N) Python iterations; the bump transition is a double loop over
states, O(N · support of the bump kernel), i.e. O(N²) on fine grids: keep grids small.
"""

from __future__ import annotations

import math

import numpy as np

from rrg_estimator.belief import Belief
from rrg_estimator.config import LIKELIHOOD, TRANSITION, LikelihoodParams, TransitionParams
from rrg_estimator.obs_model import ObsFeatures, TableLike
from rrg_models.config import FINGER_SENSORS
from rrg_models.observation import Observation
from rrg_models.poses import wrap_angle

#: Per-axis bump factors below this are skipped (≈ 7σ out; far below float32 likelihoods).
_NEGLIGIBLE = 1e-12


def _cell_mass(offset_cells: float, sigma_cells: float) -> float:
    """Mass of N(0, σ²) over the unit cell [offset - ½, offset + ½] (cells)."""
    sigma = max(sigma_cells, 1e-6)
    cdf = lambda x: 0.5 * (1.0 + math.erf(x / (sigma * math.sqrt(2.0))))
    return cdf(offset_cells + 0.5) - cdf(offset_cells - 0.5)


def _unravel(flat: int, shape) -> tuple[int, int, int]:
    nx, ny, nt = shape
    return flat // (ny * nt), (flat // nt) % ny, flat % nt


def table_index_reference(w, e, table) -> int:
    """Flat index of the table entry nearest to the offset of state w from estimate e (clamped)."""
    dx, dy = w[0] - e[0], w[1] - e[1]
    c, s = math.cos(e[2]), math.sin(e[2])
    rel = (c * dx + s * dy, -s * dx + c * dy, wrap_angle(w[2] - e[2]))
    idx = []
    for k in range(3):
        d = rel[k] - table.grid.center[k]
        if k == 2:
            d = wrap_angle(d)
        n = table.grid.shape[k]
        i = round(d / table.grid.spacing[k] + (n - 1) / 2)
        idx.append(min(max(i, 0), n - 1))
    return (idx[0] * table.grid.shape[1] + idx[1]) * table.grid.shape[2] + idx[2]


def closure_sigma_reference(
    table: TableLike, j: int, f: int, sigma: float, unsensed: tuple[int, ...] = ()
) -> float:
    """σ of entry j's closure of finger f: √(σ² + Σ_axis g²/12), g the larger change of that
    closure to the entry's neighbours along each grid axis; infinite where only sensors in
    ``unsensed`` of finger f fired (obs_model.closure_sigma)."""
    if not math.isfinite(sigma):
        return sigma
    own = FINGER_SENSORS[f]
    if any(table.sensors[j][s] for s in own if s in unsensed) and not any(
        table.sensors[j][s] for s in own if s not in unsensed
    ):
        return math.inf
    shape = table.grid.shape
    index = list(np.unravel_index(j, shape))
    var = 0.0
    for axis in range(3):
        g = 0.0
        for step in (-1, 1):
            other = list(index)
            other[axis] += step
            if 0 <= other[axis] < shape[axis]:
                k = int(np.ravel_multi_index(other, shape))
                g = max(g, abs(float(table.closure[k][f]) - float(table.closure[j][f])))
        var += g * g / 12.0
    return math.sqrt(sigma * sigma + var)


def sensor_prediction_reference(table: TableLike, j: int, s: int) -> float:
    """Probability that contact on sensor s is predicted within entry j's cell: the flags of
    the entry and its neighbours weighted ⅛, ¾, ⅛ along each axis, an index past the table's
    edge clamped to it (obs_model.sensor_prediction)."""
    shape = table.grid.shape
    centre = np.unravel_index(j, shape)
    q = 0.0
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            for dk in (-1, 0, 1):
                weight = 1.0
                index = []
                for axis, d in enumerate((di, dj, dk)):
                    weight *= 0.75 if d == 0 else 0.125
                    index.append(min(max(int(centre[axis]) + d, 0), shape[axis] - 1))
                q += weight * float(bool(table.sensors[int(np.ravel_multi_index(index, shape))][s]))
    return q


def likelihood_reference(
    table: TableLike, j: int, obs: dict, params: LikelihoodParams = LIKELIHOOD
) -> float:
    """Floored likelihood of one observation (dict of plain values) at table entry j, term by
    term."""
    like = 1.0
    predicted_contact = bool(table.contact[j])
    like *= (
        (1.0 - params.p_contact_mismatch)
        if obs["contact"] == predicted_contact
        else params.p_contact_mismatch
    )
    if obs["contact"] and predicted_contact:
        z = (obs["progress"] - float(table.progress[j])) / params.sigma_progress
        like *= max(math.exp(-0.5 * z * z), params.outlier_progress)
    for s in range(len(obs["sensors"])):
        if s in params.unsensed:
            continue
        q = sensor_prediction_reference(table, j, s)
        p_fired = q * params.p_detect + (1.0 - q) * params.p_false_alarm
        like *= p_fired if obs["sensors"][s] else 1.0 - p_fired
    for f in range(3):
        z = (obs["closure"][f] - float(table.closure[j][f])) / closure_sigma_reference(
            table, j, f, params.sigma_closure, tuple(params.unsensed)
        )
        like *= max(math.exp(-0.5 * z * z), params.outlier_closure)
    for f in range(3):
        o, t = obs["tip_points"][f], table.tip_points[j][f]
        if any(math.isnan(v) for v in o) or any(math.isnan(float(v)) for v in t):
            continue
        d2 = sum((o[k] - float(t[k])) ** 2 for k in range(3))
        like *= max(math.exp(-0.5 * d2 / params.sigma_tip**2), params.outlier_tip)
    return (1.0 - params.floor) * like + params.floor


def bump_reference(
    belief: Belief, direction_xy_world, params: TransitionParams = TRANSITION
) -> list[float]:
    """Bump transition as an explicit double loop over (source, destination) states; the
    destination loops skip coordinates where the kernel factor is negligible."""
    g = belief.grid
    (nx, ny, nt), (sx, sy, st) = g.shape, g.spacing
    dx, dy = float(direction_xy_world[0]), float(direction_xy_world[1])
    norm = math.hypot(dx, dy)
    if norm > 1.0:
        dx, dy = dx / norm, dy / norm
    # kernel factor per axis and index offset (destination - source)
    fx = {
        o: _cell_mass(o - params.bump_mean * dx / sx, params.bump_sigma_xy / sx)
        for o in range(-nx, nx)
    }
    fy = {
        o: _cell_mass(o - params.bump_mean * dy / sy, params.bump_sigma_xy / sy)
        for o in range(-ny, ny)
    }
    ft = {o: _cell_mass(o, params.bump_sigma_theta / st) for o in range(-nt, nt)}
    n = len(belief.weights)
    moved = [0.0] * n
    for src in range(n):
        w = float(belief.weights[src])
        if w == 0.0:
            continue
        i, j, k = _unravel(src, g.shape)
        for a in range(nx):
            px = fx[a - i]
            if px < _NEGLIGIBLE:
                continue
            for b in range(ny):
                py = fy[b - j]
                if py < _NEGLIGIBLE:
                    continue
                for c in range(nt):
                    pt = ft[c - k]
                    if pt >= _NEGLIGIBLE:
                        moved[(a * ny + b) * nt + c] += w * px * py * pt
    out = [
        params.p_stay * float(belief.weights[s]) + (1.0 - params.p_stay) * moved[s]
        for s in range(n)
    ]
    total = sum(out)
    return [v / total for v in out]


def _observation_dict(obs_or_features: Observation | ObsFeatures, e) -> dict:
    """Plain-Python observation; motion direction in ``world``."""
    if isinstance(obs_or_features, Observation):
        o = obs_or_features
        motion = [float(v) for v in o.motion_dir]
        contact, progress, sensors, closure, tips = (
            o.contact,
            o.progress,
            o.sensors,
            o.closure,
            o.tip_points,
        )
    else:
        f = obs_or_features
        m = [float(v) for v in f.motion_dir[0]]
        c, s = math.cos(e[2]), math.sin(e[2])
        motion = [c * m[0] - s * m[1], s * m[0] + c * m[1], m[2]]
        contact, progress, sensors, closure, tips = (
            f.contact[0],
            f.progress[0],
            f.sensors[0],
            f.closure[0],
            f.tip_points[0],
        )
    return {
        "contact": bool(contact),
        "progress": float(progress),
        "sensors": [bool(v) for v in sensors],
        "closure": [float(v) for v in closure],
        "tip_points": [[float(v) for v in row] for row in tips],
        "motion_dir": motion,
    }


def update_reference(
    belief: Belief,
    table: TableLike,
    e,
    obs_or_features: Observation | ObsFeatures,
    transition: bool = True,
    params: LikelihoodParams = LIKELIHOOD,
) -> Belief:
    """SE(b, τ(e), o) state by state: bump (if contact), likelihood per state, normalize."""
    e = [float(v) for v in e]
    obs = _observation_dict(obs_or_features, e)
    if transition and obs["contact"]:
        prior = bump_reference(belief, obs["motion_dir"][:2])
    else:
        prior = [float(v) for v in belief.weights]
    points = belief.grid.points()
    post = []
    for s in range(len(prior)):
        w = [float(v) for v in points[s]]
        post.append(
            prior[s] * likelihood_reference(table, table_index_reference(w, e, table), obs, params)
        )
    total = sum(post)
    return Belief(belief.grid, np.array([v / total for v in post]))
