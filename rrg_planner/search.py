"""Receding-horizon POMDP forward search over WRTs (paper: "POMDP forward search"; design §6).

V_0(b) = v(b) − c, the static evaluation: the best probability, over feasible goal WRTs g,
that executing g relative to w*(b) achieves the goal (or relative to w*(b) moved to g's
aim: ForwardSearch.goal_estimates; P(G | Δ) is the measured physics closing's, model.py),
less the cost c of that grasp, still to run.
V_h(b) = max_a [ Σ_c P(c | b, a) · U_{h-1}(a, o_c) − c ], infeasible a skipped, where
U(a, o_c) = P_{b_c}(G) when a is a goal grasp whose posterior b_c = SE(b, a, o_c) gives
its grasp P_{b_c}(G) > 1 − δ (the agent declares success and stops there), and
V_{h-1}(b_c) otherwise. An action costs c = SearchParams.cost_per_delta · δ, in the
currency of success probability: the user's δ says how much success one more action is
worth (a run stops as soon as it believes the goal reached with probability 1 − δ).

Beliefs inside the search are sparse: the grid points whose weight is above
``support_rel`` of the maximum, as (points, weights). Observation branches come from the
offline clusters (clustering.py): P(c | b, a) is a weighted bincount of the cluster id of
each state's predicted observation, posteriors are b · P(o_c | ·), and branches with
similar entropy and covariance are merged before keeping the most probable ones that
cover ``online_keep_mass`` of the mass (paper: 50 %).

The bump transition is left out of the search's posteriors (it blurs each contact branch
by a few mm and costs a convolution per branch); the estimator applies it to the real
belief. Reorientation's rotation is kept, because feasibility depends on it, and so is its
spread in θ (three nodes per state), because it is what a turn costs in localization.
A reading puts its posterior in its posture's frame (rrg_sim.posture_calibration), and a goal
grasp is valued from the frame its belief is in (PlanningModel.goal_table); the blur that the
estimator applies when a belief changes frame (rrg_estimator.transition.change_frame) is left
out of the search's posteriors, as the bump is. A reorientation is valued only where half the
belief (SearchParams.reorient_min_in_box) lies in its measured outcome's box about w*(b)
(``turn_is_measured``): held from further off, the object turns unpredictably.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from threadpoolctl import ThreadpoolController

from rrg_estimator.belief import Belief
from rrg_estimator.config import TRANSITION
from rrg_planner.config import SEARCH, SearchParams
from rrg_planner.planning_model import PlanningModel
from rrg_planner.requests import check_search
from rrg_sim.poses import compose_planar, relative_planar
from rrg_sim.wrt import ReorientOutcome


def _wrap(a: np.ndarray) -> np.ndarray:
    """Angles to [-π, π] by rounding (3x faster than the modulo in poses.wrap_angle; the two
    differ only in the sign chosen at exactly ±π, which the search never distinguishes)."""
    return a - (2 * np.pi) * np.round(a / (2 * np.pi))


#: A belief whose support fills at least this fraction of its span of table entries gets its
#: posterior moments in table space (scatter_moments: one matrix product per action); a sparser
#: one gathers its likelihood rows per point instead (measured cross-over ≈ 0.4 on this machine).
DENSE_FRACTION = 0.4

#: Ties, which a symmetric object's mirror-image states and branches make exact, are broken
#: by index, not by rounding: weights this close (relative) to the maximum tie for w*(b), and
#: branch probabilities are ordered rounded to TIE_DECIMALS (ReferenceSearch does the same).
TIE_RTOL = 1e-9
TIE_DECIMALS = 12


def _most_probable_first(probs) -> np.ndarray:
    """Indices ordering probabilities (…,) from the largest, ties (to TIE_DECIMALS) by index."""
    return np.argsort(-np.round(probs, TIE_DECIMALS), kind="stable")


#: The search's matrices are small (K×S by S×11): multi-threaded BLAS only spins and roughly
#: doubles the time on 2 cores, so planning runs with one BLAS thread.
_BLAS = ThreadpoolController()


@dataclass(eq=False)
class SparseBelief:
    """A belief restricted to its support: points (S,3) in world (x, y, θ), weights (S,) sum 1,
    held in ``frame`` (Belief.frame; a reading puts its posterior in the reading's frame).

    table_index caches, per point, the table entry of its offset from w*(b); moments the
    belief's weighted moment_features, per table entry (scatter_moments) or per point (set by
    the search).
    """

    points: np.ndarray
    weights: np.ndarray
    level: str
    table_index: np.ndarray | None = None
    moments: tuple | None = None
    frame: str = ""

    @classmethod
    def compact(
        cls,
        points: np.ndarray,
        weights: np.ndarray,
        level: str,
        params: SearchParams = SEARCH,
        frame: str = "",
    ) -> SparseBelief:
        """Drop the points below support_rel of the max weight and renormalize."""
        keep = np.flatnonzero(weights >= params.support_rel * weights.max())
        return cls(points[keep], weights[keep] / weights[keep].sum(), level, frame=frame)

    @classmethod
    def from_belief(cls, belief: Belief, level: str, params: SearchParams = SEARCH) -> SparseBelief:
        return cls.compact(belief.grid.points(), belief.weights, level, params, belief.frame)

    @property
    def w_star(self) -> np.ndarray:
        """The most likely point; of points tied within TIE_RTOL, the first."""
        w = self.weights
        return self.points[int(np.argmax(w >= w.max() * (1.0 - TIE_RTOL)))]


def moment_features(
    points: np.ndarray, weights: np.ndarray, ref: np.ndarray, sigma: np.ndarray
) -> np.ndarray:
    """(S,11) per-point features whose weighted sums give a posterior's mass, first and second
    moments and Σ p·log w: [1, d (3), d⊗d (6 unique), log w], with deviations d from ``ref``
    (θ wrapped) scaled by ``sigma`` so the axes compare."""
    d = points - ref
    d[:, 2] = _wrap(d[:, 2])
    d = d / sigma
    iu = np.triu_indices(3)
    with np.errstate(divide="ignore"):
        logw = np.log(weights)
    return np.column_stack(
        [np.ones(len(d)), d, d[:, iu[0]] * d[:, iu[1]], np.where(weights > 0, logw, 0.0)]
    )


def scatter_moments(
    idx: np.ndarray, weights: np.ndarray, features: np.ndarray
) -> tuple[int, np.ndarray]:
    """Σ over the states of each table entry of weight · moment_features, for the entries
    lo … max(idx): (lo, (m, 11) float32). The moments of every posterior b·L_c are then one
    product L_c[lo:lo+m] @ it, with no gather per cluster."""
    lo = int(idx.min())
    local = idx - lo
    m = int(idx.max()) - lo + 1
    weighted = weights[:, None] * features
    if np.bincount(local, minlength=m).max() <= 1:  # one state per entry (the usual case)
        tab = np.zeros((m, features.shape[1]), dtype=np.float32)
        tab[local] = weighted
    else:
        tab = np.column_stack([np.bincount(local, weights=col, minlength=m) for col in weighted.T])
    return lo, tab.astype(np.float32, copy=False)


def branch_statistics(
    moments: np.ndarray, sum_l_log_l: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mass Z (K,), entropy (K,) and covariance (K,3,3) of K posteriors b·L_k, given their
    moments Σ b L_k f (K,11) over moment_features f and Σ b L_k log L_k (K,):
    H = log Z − Σ b L (log L + log b) / Z."""
    mom = moments.astype(np.float64)
    z = mom[:, 0]
    mean = mom[:, 1:4] / z[:, None]
    second = np.empty((len(z), 3, 3))
    iu = np.triu_indices(3)
    second[:, iu[0], iu[1]] = mom[:, 4:10] / z[:, None]
    second[:, iu[1], iu[0]] = second[:, iu[0], iu[1]]
    cov = second - mean[:, :, None] * mean[:, None, :]
    ent = np.log(z) - (sum_l_log_l.astype(np.float64) + mom[:, 10]) / z
    return z, ent, cov


def merge_branches(
    probs: np.ndarray, entropies: np.ndarray, covs: np.ndarray, params: SearchParams = SEARCH
) -> list[tuple[int, float]]:
    """Online merging (paper): branches whose posteriors have similar entropy and covariance
    are merged into the more probable one; then the most probable merged branches that
    cover ``online_keep_mass`` of the mass are kept and renormalized.

    Returns [(branch index, probability)], most probable first.
    """
    flat = covs.reshape(len(covs), -1)
    scale = np.maximum(np.linalg.norm(flat, axis=1), 1e-12)  # Frobenius norm of each covariance
    # similar[k, r]: branch k may merge into representative r (criteria of the paper)
    similar = (np.abs(entropies[:, None] - entropies[None, :]) < params.merge_entropy_tol) & (
        np.linalg.norm(flat[:, None, :] - flat[None, :, :], axis=2) / scale[None, :]
        < params.merge_cov_tol
    )
    reps: list[int] = []
    mass: list[float] = []
    for k in _most_probable_first(probs):
        for r_i, r in enumerate(reps):
            if similar[k, r]:
                mass[r_i] += float(probs[k])
                break
        else:
            reps.append(int(k))
            mass.append(float(probs[k]))
    order = _most_probable_first(mass)
    total = float(np.sum(mass))
    kept, acc = [], 0.0
    for i in order:
        kept.append((reps[i], mass[i]))
        acc += mass[i]
        if acc >= params.online_keep_mass * total:
            break
    z = sum(p for _, p in kept)
    return [(k, p / z) for k, p in kept]


def rotate_about(points: np.ndarray, center_xy: np.ndarray, angle: float) -> np.ndarray:
    """Rotate planar poses about a vertical axis through center_xy by angle [rad]."""
    c, s = np.cos(angle), np.sin(angle)
    d = points[:, :2] - center_xy
    out = points.copy()
    out[:, 0] = center_xy[0] + c * d[:, 0] - s * d[:, 1]
    out[:, 1] = center_xy[1] + s * d[:, 0] + c * d[:, 1]
    out[:, 2] = _wrap(points[:, 2] + angle)
    return out


def _full_turn(
    points: np.ndarray, e: np.ndarray, angle: float, outcome: ReorientOutcome | None
) -> tuple[np.ndarray, np.ndarray]:
    """``full_turn`` and (K,) bool: which states the outcome moved (inside its box)."""
    turned = rotate_about(points, e[:2], angle)
    inside = np.zeros(len(points), dtype=bool)
    if outcome is not None:
        delta = relative_planar(e, points)
        inside = outcome.inside(delta)
        turned[inside] = compose_planar(
            e + np.array([0.0, 0.0, angle]), outcome.mean(delta[inside])
        )
    return turned, inside


def full_turn(
    points: np.ndarray, e: np.ndarray, angle: float, outcome: ReorientOutcome | None = None
) -> np.ndarray:
    """Poses (K,3) of objects at points (K,3) after a reorientation's full turn by ``angle``
    [rad] about the vertical through e: rigid, except that the states inside the WRT's
    measured ``outcome`` box move to its mean (rrg_estimator.transition.reorient, without the
    blur)."""
    return _full_turn(points, e, angle, outcome)[0]


#: Three-point Gauss–Hermite rule, centre first: offsets [σ] and weights that give a Gaussian
#: blur's mean and variance exactly.
BLUR_NODES = ((0.0, 2.0 / 3.0), (-np.sqrt(3.0), 1.0 / 6.0), (np.sqrt(3.0), 1.0 / 6.0))


def reorient_mixture(
    points: np.ndarray,
    weights: np.ndarray,
    e: np.ndarray,
    angle: float,
    support_rel: float = 0.0,
    outcome: ReorientOutcome | None = None,
    blur: float = TRANSITION.reorient_sigma_theta,
) -> tuple[np.ndarray, np.ndarray]:
    """Transition of a reorientation grasp run at e: full rotation (``full_turn``, with the
    WRT's measured ``outcome``), half, or none (TRANSITION), about the vertical through e,
    each spread in θ by its σ on the three BLUR_NODES. Without the spread
    the search took a turn to keep the belief as sharp as before it, and chose
    reorientations to localize the objects whose turns scatter them most (the teacup's, σ_θ
    0.08 rad, which the estimator then applies).

    Returns the mixture's points and normalized weights, without the points below
    ``support_rel`` of the mixture's largest weight (as SparseBelief.compact would drop them,
    but before rotating, which is the cost).
    """
    p_full, p_half = TRANSITION.p_reorient_success, TRANSITION.p_reorient_partial
    parts = ((angle, p_full), (angle / 2, p_half), (0.0, 1.0 - p_full - p_half))
    nodes = BLUR_NODES if blur > 0 else ((0.0, 1.0),)
    threshold = support_rel * float(weights.max()) * max(q for _, q in parts) * nodes[0][1]
    pts, ws = [], []
    for a, q in parts:
        keep = (
            np.flatnonzero(weights * q * nodes[0][1] >= threshold) if threshold > 0 else slice(None)
        )
        if a == angle:
            turned, moved_by_outcome = _full_turn(points[keep], e, a, outcome)
        else:
            turned = rotate_about(points[keep], e[:2], a) if a else points[keep]
            moved_by_outcome = np.zeros(len(turned), dtype=bool)
        # σ_θ of each state's turn: the blur, and the outcome's σ as well where it moved it
        # (as rrg_estimator.transition.reorient)
        sigma = np.full(len(turned), blur)
        if moved_by_outcome.any():
            sigma[moved_by_outcome] = np.hypot(outcome.sigma[2], blur)
        for z, qz in nodes:
            w = weights[keep] * (q * qz)
            on = w >= threshold
            moved = turned[on]
            if z:
                moved[:, 2] = _wrap(moved[:, 2] + z * sigma[on])
            pts.append(moved)
            ws.append(w[on])
    w = np.concatenate(ws)
    return np.concatenate(pts), w / w.sum()


def table_index(points: np.ndarray, e: np.ndarray, grid) -> np.ndarray:
    """Flat table index of each point's offset from e (relative_planar + Grid.nearest_index,
    clamped), fused in float32: the search's hot path."""
    n = np.asarray(grid.shape)
    half = (n - 1) / 2
    c, s_ = np.cos(e[2]), np.sin(e[2])
    p = points.astype(np.float32)
    dx, dy = p[:, 0] - np.float32(e[0]), p[:, 1] - np.float32(e[1])
    sx, sy, st = (np.float32(v) for v in grid.spacing)
    ix = np.rint((np.float32(c) * dx + np.float32(s_) * dy) / sx + np.float32(half[0]))
    iy = np.rint((np.float32(c) * dy - np.float32(s_) * dx) / sy + np.float32(half[1]))
    dth = (p[:, 2] - np.float32(e[2]) + np.float32(np.pi)) % np.float32(2 * np.pi) - np.float32(
        np.pi
    )
    it = np.rint(dth / st + np.float32(half[2]))
    np.clip(ix, 0, n[0] - 1, out=ix)
    np.clip(iy, 0, n[1] - 1, out=iy)
    np.clip(it, 0, n[2] - 1, out=it)
    return (ix.astype(np.int64) * n[1] + iy.astype(np.int64)) * n[2] + it.astype(np.int64)


@dataclass
class SearchResult:
    """The root decision: chosen action, its value, every action's value, v(b) and time."""

    action: int
    value: float
    action_values: np.ndarray
    p_goal: float
    planning_time: float
    #: where the goal grasp reaches p_goal: (goal action, estimate), or (-1, None)
    goal_action: int = -1
    goal_estimate: np.ndarray | None = None


class ForwardSearch:
    """Fast forward search over a PlanningModel (vectorized over the belief's support)."""

    def __init__(self, model: PlanningModel, params: SearchParams = SEARCH):
        self.model = model
        self.params = params
        #: (action, estimate) pairs an executor found infeasible during the current run.
        self.blocked: set[tuple[int, bytes]] = set()
        #: per action, the (K,3) estimates it was found infeasible at (``block``)
        self._blocked_at: dict[int, np.ndarray] = {}
        #: (action, estimate) pairs whose reading the belief already holds (``spend``).
        self.spent: set[tuple[int, bytes]] = set()
        #: the feasibility maps' answers by (action, the estimate's exact bytes): a search
        #: asks about the same estimates over and over (the drill at H = 3: 6,674 asks, 1,838
        #: distinct)
        self._feasible_memo: dict[tuple[int, bytes], bool] = {}

    @staticmethod
    def _key(action: int, e) -> tuple[int, bytes]:
        return action, np.round(np.asarray(e, dtype=float), 6).tobytes()

    def block(self, action: int, e) -> None:
        """Rule an action out within params.block_box of estimate e (its execution was found
        infeasible there)."""
        self.blocked.add(self._key(action, e))
        e = np.asarray(e, dtype=float).reshape(1, 3)
        self._blocked_at[action] = np.concatenate(
            [self._blocked_at.get(action, np.empty((0, 3))), e]
        )

    def _near_blocked(self, action: int, e: np.ndarray) -> bool:
        at = self._blocked_at.get(action)
        if at is None:
            return False
        d = np.abs(at - e)
        d[:, 2] = np.abs(_wrap(at[:, 2] - e[2]))
        return bool(np.any(np.all(d <= np.asarray(self.params.block_box), axis=1)))

    def spend(self, action: int, e) -> None:
        """Rule an action out at estimate e because it ran there and its reading is in the
        belief: run again against an object it did not move, the same trajectory reads the
        same, which the update would count as a second, independent reading."""
        self.spent.add(self._key(action, e))

    def clear(self) -> None:
        """Forget the blocked and spent pairs (a new run) and the remembered feasibility."""
        self.blocked.clear()
        self._blocked_at.clear()
        self.spent.clear()
        self._feasible_memo.clear()

    def feasible(self, action: int, e) -> bool:
        """F_τ(e) from the model's feasibility map, unless execution found it infeasible near e
        or its reading there is already spent."""
        e = np.asarray(e, dtype=float)
        exact = (action, e.tobytes())
        ok = self._feasible_memo.get(exact)
        if ok is None:
            ok = self._feasible_memo[exact] = self.model.feasible(action, e)
        if not ok or not (self.blocked or self.spent):
            return ok
        return self._key(action, e) not in self.spent and not self._near_blocked(action, e)

    def turn_is_measured(self, sb: SparseBelief, action: int) -> bool:
        """False for a reorientation with less than ``reorient_min_in_box`` of the belief inside
        its measured outcome's box about w*(b); True for any other action."""
        outcome = self.model.actions[action].wrt.reorient_outcome
        if outcome is None:
            return True
        inside = outcome.inside(relative_planar(sb.w_star, sb.points))
        return float(sb.weights[inside].sum()) >= self.params.reorient_min_in_box

    # ---------------------------------------------------------------- helpers
    def _table_index(self, sb: SparseBelief) -> np.ndarray:
        """Table entry of every support point's offset from w*(b) (cached on the belief)."""
        if sb.table_index is None:
            sb.table_index = table_index(sb.points, sb.w_star, self._grid(sb.level))
        return sb.table_index

    def _grid(self, level: str):
        return self.model.actions[0].tables[level].grid

    def goal_estimates(self, w_star: np.ndarray, level: str) -> list[tuple[int, np.ndarray]]:
        """(goal action, estimate) pairs a goal grasp may run at, the feasible ones of: w*(b)
        first, and w*(b) moved so that an object at w*(b) sits at the action's aim Δ_aim
        (model.goal_aim: where the measured closing leaves it best placed)."""
        out = []
        for g in self.model.goal_actions:
            aim = self.model.actions[g].aim[level]
            for e in (w_star, compose_planar(w_star, relative_planar(aim, np.zeros(3)))):
                if self.feasible(g, e) and not any(g == h and np.allclose(e, f) for h, f in out):
                    out.append((g, e))
        return out

    def best_goal(
        self, sb: SparseBelief, goals: tuple[int, ...] | None = None
    ) -> tuple[float, int, np.ndarray | None]:
        """v(b) and where it is reached: (P_b(G), goal action or -1, estimate or None), the
        best over goal_estimates (of the ``goals`` actions only, if given). Only states whose
        offset from the estimate can have P(G | Δ) > 0 are indexed, except at w*(b) when its
        table index is cached."""
        best = (0.0, -1, None)
        w_star = sb.w_star
        for g, e in self.goal_estimates(w_star, sb.level):
            if goals is not None and g not in goals:
                continue
            if sb.table_index is not None and e is w_star:
                idx, w = sb.table_index, sb.weights
            else:
                near = self._near_goal(sb.points, e, sb.level)
                idx, w = table_index(sb.points[near], e, self._grid(sb.level)), sb.weights[near]
            p = float(w @ self.model.goal_table(g, sb.level, sb.frame)[idx])
            if p > best[0]:
                best = (p, g, e)
        return best

    def static_value(self, sb: SparseBelief) -> float:
        """v(b): max over feasible goal WRTs and their estimates (goal_estimates) of P_b(goal
        after executing it there)."""
        return self.best_goal(sb)[0]

    def _near_goal(self, points: np.ndarray, e: np.ndarray, level: str) -> np.ndarray:
        """Indices of points whose offset from e may have P(G | Δ) > 0 (one cell of margin;
        x, y as a radius, since the offsets are in e's frame)."""
        grid = self._grid(level)
        reach = self.model.goal_reach[level]
        radius = np.hypot(reach[0], reach[1]) + np.hypot(grid.spacing[0], grid.spacing[1])
        d = points[:, :2] - e[:2]
        ok = np.einsum("ij,ij->i", d, d) <= radius * radius
        return np.flatnonzero(
            ok & (np.abs(_wrap(points[:, 2] - e[2])) <= reach[2] + grid.spacing[2])
        )

    def expand(self, sb: SparseBelief, a: int) -> list[tuple[float, SparseBelief]]:
        """Observation branches of action a at w*(b): [(P(c | b, a), SE(b, a, o_c))]."""
        act = self.model.actions[a]
        clusters = act.clusters[sb.level]
        e = sb.w_star
        frame = self.model.reading_frame(a, sb.frame)  # the frame the posterior is held in
        idx = self._table_index(sb)
        cl = clusters.assign[idx]
        known = cl >= 0
        pc = np.bincount(cl[known], weights=sb.weights[known], minlength=clusters.count)
        total = pc.sum()
        if total <= 0:
            return []
        pc /= total
        order = _most_probable_first(pc)
        cum = np.cumsum(pc[order])
        n_cand = int(np.searchsorted(cum, 0.95) + 1)
        cand = order[:n_cand][pc[order[:n_cand]] > 0]
        z, ent, cov = branch_statistics(*self._posterior_moments(sb, clusters, cand))
        branches = []
        for k, p in merge_branches(pc[cand], ent, cov, self.params):
            w = clusters.likelihood[cand[k]][idx] * sb.weights
            w /= w.sum()
            if (
                act.kind == "reorient" and act.turns[sb.level][cand[k]]
            ):  # the mixture comes out compact
                child = SparseBelief(
                    *reorient_mixture(
                        sb.points,
                        w,
                        e,
                        act.wrt.reorient_angle,
                        self.params.support_rel,
                        act.wrt.reorient_outcome,
                    ),
                    sb.level,
                    frame=frame,
                )
            else:
                child = SparseBelief.compact(sb.points, w, sb.level, self.params, frame)
            branches.append((p, child))
        return branches

    def _posterior_moments(
        self, sb: SparseBelief, clusters, cand: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Σ b L_c f (K,11) over moment_features f, and Σ b L_c log L_c (K,), for clusters cand."""
        idx = sb.table_index
        if sb.moments is None:
            sigma = np.asarray(self.model.levels[sb.level].sigma)
            features = moment_features(sb.points, sb.weights, sb.w_star, sigma)
            if len(idx) >= DENSE_FRACTION * (int(idx.max()) - int(idx.min()) + 1):
                sb.moments = scatter_moments(idx, sb.weights, features)
            else:
                sb.moments = (features.astype(np.float32), sb.weights.astype(np.float32))
        if isinstance(sb.moments[0], int):  # table space: no per-cluster gathers
            lo, tab = sb.moments
            cols = slice(lo, lo + len(tab))
            return (clusters.likelihood[:, cols] @ tab)[cand], (
                clusters.l_log_l[:, cols] @ tab[:, 0]
            )[cand]
        features, weights32 = sb.moments
        # take on a row subset is ~3x faster than 2-D fancy indexing
        return (
            (np.take(clusters.likelihood[cand], idx, axis=1) * weights32) @ features,
            np.take(clusters.l_log_l[cand], idx, axis=1) @ weights32,
        )

    # ---------------------------------------------------------------- search
    def action_values(
        self, sb: SparseBelief, horizon: int, delta: float = SEARCH.delta
    ) -> np.ndarray:
        """Q_h(b, a) for every action (−inf where infeasible at w*(b))."""
        e = sb.w_star
        q = np.full(len(self.model.actions), -np.inf)
        for a in range(len(self.model.actions)):
            if not self.feasible(a, e) or not self.turn_is_measured(sb, a):
                continue
            branches = self.expand(sb, a)
            if branches:
                q[a] = (
                    sum(p * self._outcome_value(a, e, b, horizon - 1, delta) for p, b in branches)
                    - self.params.cost_per_delta * delta
                )
        return q

    def held_probability(self, child: SparseBelief, goal: int, e: np.ndarray) -> float:
        """P_b(G) of goal grasp ``goal`` just made at e, under its posterior ``child``."""
        idx = table_index(child.points, e, self._grid(child.level))
        return float(child.weights @ self.model.goal_table(goal, child.level, child.frame)[idx])

    def _outcome_value(
        self, a: int, e: np.ndarray, child: SparseBelief, horizon: int, delta: float
    ) -> float:
        """U(a, o): the child's value, or, after a goal grasp at e that the agent would declare
        (P_b(G) > 1 − δ: RobustGraspAgent.finished), that grasp's P_b(G), the run over."""
        if self.model.actions[a].kind == "goal":
            held = self.held_probability(child, a, e)
            if held > 1.0 - delta:
                return held
        return self.value(child, horizon, delta)

    def value(self, sb: SparseBelief, horizon: int, delta: float = SEARCH.delta) -> float:
        """V_h(b); V_0(b) = v(b) less the goal grasp's cost."""
        if horizon > 0:
            q = self.action_values(sb, horizon, delta)
            if np.isfinite(q).any():
                return float(q.max())
        return self.static_value(sb) - self.params.cost_per_delta * delta

    def select(
        self, belief: Belief, horizon: int = SEARCH.horizon, delta: float = SEARCH.delta
    ) -> SearchResult:
        """Choose the root action for a belief (grid) with a forward search of depth horizon,
        for a run that stops at P(G) > 1 − delta."""
        check_search(horizon, delta)
        t0 = time.perf_counter()
        sb = SparseBelief.from_belief(belief, self.model.level_of(belief.grid), self.params)
        with _BLAS.limit(limits=1, user_api="blas"):
            q = self.action_values(sb, horizon, delta)
            p_goal, g, e_goal = self.best_goal(sb)
        best = int(np.argmax(q)) if np.isfinite(q).any() else -1
        return SearchResult(
            action=best,
            value=float(q[best]) if best >= 0 else float("nan"),
            action_values=q,
            p_goal=p_goal,
            planning_time=time.perf_counter() - t0,
            goal_action=g,
            goal_estimate=e_goal,
        )
