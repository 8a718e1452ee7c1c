"""Receding-horizon POMDP forward search over WRTs (paper: "POMDP forward search"; algorithm §6).

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
grasp is valued from the frame its belief is in (PlanningModel.goal_table). A reading in
another frame than the belief's starts, as in the estimator (rrg_estimator.transition.
change_frame), from the belief blurred by the σ between the two frames (``in_frame``): without
the blur the search took a change of frame to cost nothing, went back and forth between the
top-down readings and a side goal's probes, and never held a belief sharp in the goal's frame.
A reorientation is valued only where half the
belief (SearchParams.reorient_min_in_box) lies in its measured outcome's box about w*(b)
(``turn_is_measured``): held from further off, the object turns unpredictably.

The work over a belief's support runs in compiled kernels (search_kernels.py) that compute
every value with NumPy's own operations and order (so ties between actions break as NumPy's
sums break them); only the posteriors' moments, which decide merges by tolerances, are summed
in another order.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from threadpoolctl import ThreadpoolController

from rrg_estimator.belief import Belief
from rrg_estimator.config import TRANSITION
from rrg_estimator.grid import Grid
from rrg_estimator.transition import displace
from rrg_models.poses import compose_planar, relative_planar
from rrg_models.wrt import ReorientOutcome
from rrg_planner import search_kernels as kernels
from rrg_planner.config import SEARCH, SearchParams
from rrg_planner.planning_model import PlanningModel
from rrg_planner.request_checks import check_search


def _wrap(a: np.ndarray) -> np.ndarray:
    """Angles to [-π, π] by rounding (3x faster than the modulo in poses.wrap_angle; the two
    differ only in the sign chosen at exactly ±π, which the search never distinguishes)."""
    return a - (2 * np.pi) * np.round(a / (2 * np.pi))


#: Ties, which a symmetric object's mirror-image states and branches make exact, are broken
#: by index, not by rounding: weights this close (relative) to the maximum tie for w*(b), and
#: branch probabilities are ordered rounded to TIE_DECIMALS (search_kernels.most_probable_first;
#: ReferenceSearch does the same).
TIE_RTOL = 1e-9
TIE_DECIMALS = 12
_TIE_SCALE = 10.0**TIE_DECIMALS  # np.round's factor for TIE_DECIMALS


#: The search's BLAS calls are dot products over a belief's support: multi-threaded BLAS only
#: spins on 2 cores, and one thread sums them in the same order in any process.
_BLAS = ThreadpoolController()


@dataclass(eq=False)
class SparseBelief:
    """A belief restricted to its support: points (S,3) in world (x, y, θ), weights (S,) sum 1,
    held in ``frame`` (Belief.frame; a reading puts its posterior in the reading's frame).

    table_index caches, per point, the table entry of its offset from w*(b) (set when the
    search expands the belief, and only then: best_goal reads it); features the weighted
    moment features (11,S) of its posteriors (search_kernels.weighted_features); parent_index,
    for a posterior the search made, (e, the parent's table_index about e, the indices of its
    points among the parent's): its points' table entries about e, without recomputing them;
    _w_star w*(b), when whoever made the belief found it already (``w_star``).
    """

    points: np.ndarray
    weights: np.ndarray
    level: str
    table_index: np.ndarray | None = None
    features: np.ndarray | None = None
    frame: str = ""
    parent_index: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    _w_star: np.ndarray | None = None
    #: the belief as readings in other frames start from (ForwardSearch.in_frame), by frame
    moved: dict[str, SparseBelief] | None = None

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
        pts, w, star = kernels.compact(
            np.ascontiguousarray(points, dtype=float),
            np.ascontiguousarray(weights, dtype=float),
            params.support_rel,
            1.0 - TIE_RTOL,
        )
        return cls(pts, w, level, frame=frame, _w_star=pts[star])

    @classmethod
    def from_belief(cls, belief: Belief, level: str, params: SearchParams = SEARCH) -> SparseBelief:
        ax, ay, at = belief.grid.axes()
        pts, w, star = kernels.compact_grid(
            belief.weights, params.support_rel, 1.0 - TIE_RTOL, ax, ay, at
        )
        return cls(pts, w, level, frame=belief.frame, _w_star=pts[star])

    @property
    def w_star(self) -> np.ndarray:
        """The most likely point; of points tied within TIE_RTOL, the first (the same array
        each time)."""
        if self._w_star is None:
            w = self.weights
            self._w_star = self.points[int(np.argmax(w >= w.max() * (1.0 - TIE_RTOL)))]
        return self._w_star


def merge_branches(
    probs: np.ndarray, entropies: np.ndarray, covs: np.ndarray, params: SearchParams = SEARCH
) -> list[tuple[int, float]]:
    """Online merging (paper): branches whose posteriors have similar entropy and covariance
    are merged into the more probable one; then the most probable merged branches that
    cover ``online_keep_mass`` of the mass are kept and renormalized (search_kernels.merge).

    Returns [(branch index, probability)], most probable first.
    """
    kept, p = kernels.merge(
        np.asarray(probs, dtype=float),
        np.asarray(entropies, dtype=float),
        np.ascontiguousarray(covs, dtype=float).reshape(len(covs), 9),
        params.merge_entropy_tol,
        params.merge_cov_tol,
        params.online_keep_mass,
        _TIE_SCALE,
    )
    return [(int(k), float(q)) for k, q in zip(kept, p)]


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


def _compose(e: np.ndarray, d: tuple[float, float, float]) -> np.ndarray:
    """compose_planar(e, d) of one pose e (3,) and offset d [m, m, rad]: the same operations
    on scalars, to the bit (NumPy's cos and sin, Python's float remainder as NumPy's)."""
    c, s = float(np.cos(e[2])), float(np.sin(e[2]))
    x, y, th = float(e[0]), float(e[1]), float(e[2])
    wrapped = (th + d[2] + np.pi) % (2 * np.pi) - np.pi
    return np.array([x + c * d[0] - s * d[1], y + s * d[0] + c * d[1], wrapped])


def _close(a: np.ndarray, b: np.ndarray) -> bool:
    """np.allclose(a, b) of two finite poses (3,), on scalars."""
    return all(abs(float(u) - float(v)) <= 1e-8 + 1e-5 * abs(float(v)) for u, v in zip(a, b))


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


def _blurred(
    sb: SparseBelief, sigma: np.ndarray, frame: str, grid, params: SearchParams
) -> SparseBelief:
    """``sb`` blurred by a Gaussian of σ (x [m], y [m], θ [rad]) per axis, held in ``frame``:
    its points put on the lattice of ``grid``'s spacing through w*(b), in a box with 3σ of
    margin, moved by rrg_estimator.transition.displace, and compacted again (the points of the
    reorientation mixture, off the lattice, go to their nearest lattice point)."""
    spacing = np.asarray(grid.spacing, dtype=float)
    e = sb.w_star
    d = sb.points - e
    d[:, 2] = _wrap(d[:, 2])
    cells = np.rint(d / spacing).astype(np.int64)
    margin = np.ceil(3.0 * np.asarray(sigma) / spacing).astype(np.int64)
    lo, hi = cells.min(axis=0) - margin, cells.max(axis=0) + margin
    half = np.maximum(-lo, hi)  # a box centred on w*(b): odd counts, as a Grid has
    box = Grid(tuple(float(v) for v in e), tuple(spacing), tuple(int(n) for n in 2 * half + 1))
    a = np.zeros(box.shape)
    np.add.at(a, tuple((cells + half).T), sb.weights)
    out = displace(a, box, (0.0, 0.0, 0.0), sigma).ravel()
    return SparseBelief.compact(box.points(), out, sb.level, params, frame=frame)


def table_index(points: np.ndarray, e: np.ndarray, grid) -> np.ndarray:
    """Flat table index of each point's offset from e (relative_planar + Grid.nearest_index,
    clamped), fused in float32: the search's hot path (search_kernels.table_index)."""
    e = np.asarray(e, dtype=float)
    return kernels.table_index(
        np.ascontiguousarray(points, dtype=float),
        e,
        np.cos(e[2]),
        np.sin(e[2]),
        np.asarray(grid.spacing, dtype=float),
        np.asarray(grid.shape, dtype=np.int64),
    )


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
        #: goal_estimates by (w*(b)'s bytes, level), during one ``select`` only (None outside
        #: it): blocked and spent pairs, which they depend on, cannot change within one
        self._estimates_memo: dict[tuple[bytes, str], list[tuple[int, np.ndarray | None]]] | None
        self._estimates_memo = None
        #: per (goal action, level), ``_aim_offset``
        self._aim_offsets: dict[tuple[int, str], tuple[float, float, float]] = {}
        #: per level: grid spacing (3,) [m, m, rad], shape (3,), and the goal's reach about an
        #: estimate: radius in x, y [m] and |θ| [rad], each with one cell of margin
        self._geometry: dict[str, tuple[np.ndarray, np.ndarray, float, float]] = {}

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
        e = sb.w_star
        inside = kernels.mass_in_box(
            sb.points, sb.weights, e, np.cos(e[2]), np.sin(e[2]), np.asarray(outcome.box, float)
        )
        return inside >= self.params.reorient_min_in_box

    # ---------------------------------------------------------------- helpers
    def _table_index(self, sb: SparseBelief) -> np.ndarray:
        """Table entry of every support point's offset from w*(b) (cached on the belief)."""
        if sb.table_index is None:
            e = sb.w_star
            spacing, shape, _, _ = self._level_geometry(sb.level)
            sb.table_index = kernels.table_index(
                sb.points, e, np.cos(e[2]), np.sin(e[2]), spacing, shape
            )
        return sb.table_index

    def _grid(self, level: str):
        return self.model.actions[0].tables[level].grid

    def _level_geometry(self, level: str) -> tuple[np.ndarray, np.ndarray, float, float]:
        """The level's table spacing and shape, and the goal's reach (``_geometry``)."""
        geo = self._geometry.get(level)
        if geo is None:
            grid = self._grid(level)
            reach = self.model.goal_reach[level]
            geo = self._geometry[level] = (
                np.asarray(grid.spacing, dtype=float),
                np.asarray(grid.shape, dtype=np.int64),
                np.hypot(reach[0], reach[1]) + np.hypot(grid.spacing[0], grid.spacing[1]),
                reach[2] + grid.spacing[2],
            )
        return geo

    def goal_estimates(self, w_star: np.ndarray, level: str) -> list[tuple[int, np.ndarray]]:
        """(goal action, estimate) pairs a goal grasp may run at, the feasible ones of: w*(b)
        first, and w*(b) moved so that an object at w*(b) sits at the action's aim Δ_aim
        (model.goal_aim: where the measured closing leaves it best placed)."""
        out = []
        for g in self.model.goal_actions:
            for e in (w_star, _compose(w_star, self._aim_offset(g, level))):
                if self.feasible(g, e) and not any(g == h and _close(e, f) for h, f in out):
                    out.append((g, e))
        return out

    def _aim_offset(self, g: int, level: str) -> tuple[float, float, float]:
        """relative_planar(Δ_aim, 0) of goal action g: composed with w*(b), the estimate that
        puts an object at w*(b) at the aim (cached per action and level)."""
        offset = self._aim_offsets.get((g, level))
        if offset is None:
            aim = self.model.actions[g].aim[level]
            offset = tuple(float(v) for v in relative_planar(aim, np.zeros(3)))
            self._aim_offsets[(g, level)] = offset
        return offset

    def best_goal(
        self, sb: SparseBelief, goals: tuple[int, ...] | None = None
    ) -> tuple[float, int, np.ndarray | None]:
        """v(b) and where it is reached: (P_b(G), goal action or -1, estimate or None), the
        best over goal_estimates (of the ``goals`` actions only, if given). Only states whose
        offset from the estimate can have P(G | Δ) > 0 are indexed, except at w*(b) when its
        table index is cached."""
        best = (0.0, -1, None)
        w_star = sb.w_star
        spacing, shape, radius, reach_theta = self._level_geometry(sb.level)
        for g, e in self._goal_estimates(w_star, sb.level):
            if goals is not None and g not in goals:
                continue
            table = self.model.goal_table(g, sb.level, sb.frame)
            if sb.table_index is not None and e is w_star:
                p = float(sb.weights @ table[sb.table_index])
            else:
                w, goal = kernels.goal_terms(
                    sb.points,
                    sb.weights,
                    e,
                    np.cos(e[2]),
                    np.sin(e[2]),
                    spacing,
                    shape,
                    radius,
                    reach_theta,
                    table,
                )
                p = float(w @ goal)
            if p > best[0]:
                best = (p, g, e)
        return best

    def _goal_estimates(self, w_star: np.ndarray, level: str) -> list[tuple[int, np.ndarray]]:
        """goal_estimates, remembered during a ``select`` (w*(b) itself is returned as given,
        so that best_goal may tell it from the aimed estimates)."""
        if self._estimates_memo is None:
            return self.goal_estimates(w_star, level)
        key = (w_star.tobytes(), level)
        known = self._estimates_memo.get(key)
        if known is None:
            known = self._estimates_memo[key] = [
                (g, None if e is w_star else e) for g, e in self.goal_estimates(w_star, level)
            ]
        return [(g, w_star if e is None else e) for g, e in known]

    def static_value(self, sb: SparseBelief) -> float:
        """v(b): max over feasible goal WRTs and their estimates (goal_estimates) of P_b(goal
        after executing it there)."""
        return self.best_goal(sb)[0]

    def in_frame(self, sb: SparseBelief, frame: str) -> SparseBelief:
        """The belief as a reading in ``frame`` starts from: itself in its own frame, else
        blurred by the σ between the two frames, as the estimator does before such a reading
        (rrg_estimator.transition.change_frame), on the lattice of the level's spacing through
        w*(b). Its table entries stay about w*(b) of ``sb``, where the action runs (cached on
        ``sb``, per frame)."""
        sigma = self.model.calibration.sigma(sb.frame, frame)
        if frame == sb.frame or not sigma.any():
            return sb
        if sb.moved is None:
            sb.moved = {}
        moved = sb.moved.get(frame)
        if moved is None:
            moved = sb.moved[frame] = _blurred(sb, sigma, frame, self._grid(sb.level), self.params)
            e = sb.w_star
            spacing, shape, _, _ = self._level_geometry(sb.level)
            moved.table_index = kernels.table_index(
                moved.points, e, np.cos(e[2]), np.sin(e[2]), spacing, shape
            )
        return moved

    def expand(self, sb: SparseBelief, a: int) -> list[tuple[float, SparseBelief]]:
        """Observation branches of action a at w*(b): [(P(c | b, a), SE(b, a, o_c))], from the
        belief moved to the frame of a's reading (``in_frame``)."""
        act = self.model.actions[a]
        clusters = act.clusters[sb.level]
        e = sb.w_star
        frame = self.model.reading_frame(a, sb.frame)  # the frame the posterior is held in
        sb = self.in_frame(sb, frame)
        idx = self._table_index(sb)
        if sb.features is None:
            sigma = np.asarray(self.model.levels[sb.level].sigma, dtype=float)
            sb.features = kernels.weighted_features(sb.points, sb.weights, e, sigma)
        kept, probs = kernels.expand_branches(
            clusters.assign,
            clusters.count,
            clusters.likelihood,
            clusters.l_log_l,
            idx,
            sb.weights,
            sb.features,
            self.params.merge_entropy_tol,
            self.params.merge_cov_tol,
            self.params.online_keep_mass,
            _TIE_SCALE,
        )
        branches = []
        for c, p in zip(kept.tolist(), probs.tolist()):
            if act.kind == "reorient" and act.turns[sb.level][c]:  # the mixture comes out compact
                child = SparseBelief(
                    *reorient_mixture(
                        sb.points,
                        kernels.child_weights(clusters.likelihood[c], idx, sb.weights),
                        e,
                        act.wrt.reorient_angle,
                        self.params.support_rel,
                        act.wrt.reorient_outcome,
                    ),
                    sb.level,
                    frame=frame,
                )
            else:
                pts, w, star, keep = kernels.child(
                    clusters.likelihood[c],
                    idx,
                    sb.points,
                    sb.weights,
                    self.params.support_rel,
                    1.0 - TIE_RTOL,
                )
                child = SparseBelief(
                    pts, w, sb.level, frame=frame, parent_index=(e, idx, keep), _w_star=pts[star]
                )
            branches.append((p, child))
        return branches

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
        if child.parent_index is not None and child.parent_index[0] is e:
            idx = child.parent_index[1][child.parent_index[2]]  # table_index is per point
        else:
            spacing, shape, _, _ = self._level_geometry(child.level)
            idx = kernels.table_index(child.points, e, np.cos(e[2]), np.sin(e[2]), spacing, shape)
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
        self._estimates_memo = {}
        try:
            with _BLAS.limit(limits=1, user_api="blas"):
                q = self.action_values(sb, horizon, delta)
                p_goal, g, e_goal = self.best_goal(sb)
        finally:
            self._estimates_memo = None
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
