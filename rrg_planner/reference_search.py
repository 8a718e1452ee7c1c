"""Naive reference forward search: per-state Python loops, as the paper's "non-optimized
Python" would be written. Same semantics as search.ForwardSearch; tests compare the two on
small grids, and ``rrg-bench plan`` uses this as the speed baseline.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from rrg_estimator.belief import Belief
from rrg_estimator.config import TRANSITION
from rrg_models.poses import compose_planar, relative_planar, wrap_angle
from rrg_planner.config import SEARCH, SearchParams
from rrg_planner.planning_model import PlanningModel

Points = list[tuple[float, float, float]]

# The reference shares no code with the fast search (search.py); these constants must equal its
# own (tests/rrg_planner/test_search.py checks that they do).
#: weights this close (relative) to the maximum tie for w*(b), broken by index
TIE_RTOL = 1e-9
#: branch probabilities are ordered rounded to this many decimals, ties by index
TIE_DECIMALS = 12
#: three-point Gauss–Hermite rule, centre first: offsets [σ] and weights of a turn's θ blur
BLUR_NODES = ((0.0, 2.0 / 3.0), (-math.sqrt(3.0), 1.0 / 6.0), (math.sqrt(3.0), 1.0 / 6.0))


@dataclass
class SearchResult:
    """The root decision: chosen action, its value, every action's value, v(b) and time."""

    action: int
    value: float
    action_values: np.ndarray
    p_goal: float
    planning_time: float


def _most_probable_first(probs) -> list[int]:
    """Indices ordering probabilities from the largest, ties (to TIE_DECIMALS) by index."""
    return sorted(range(len(probs)), key=lambda k: -round(float(probs[k]), TIE_DECIMALS))


def _frobenius(m) -> float:
    """The Frobenius norm of a 3×3 matrix (nested sequences)."""
    return math.sqrt(sum(float(m[i][j]) ** 2 for i in range(3) for j in range(3)))


def merge_branches(
    probs, entropies, covs, params: SearchParams = SEARCH
) -> list[tuple[int, float]]:
    """Online merging (paper), one branch at a time: a branch whose posterior has entropy within
    merge_entropy_tol and covariance within merge_cov_tol (relative Frobenius difference) of an
    earlier, more probable representative's joins it; the most probable merged branches that
    cover online_keep_mass of the mass are kept and renormalized.

    Returns [(branch index, probability)], most probable first.
    """
    reps: list[int] = []
    mass: list[float] = []
    for k in _most_probable_first(probs):
        for r_i, r in enumerate(reps):
            diff = [[covs[k][i][j] - covs[r][i][j] for j in range(3)] for i in range(3)]
            if (
                abs(entropies[k] - entropies[r]) < params.merge_entropy_tol
                and _frobenius(diff) / max(_frobenius(covs[r]), 1e-12) < params.merge_cov_tol
            ):
                mass[r_i] += float(probs[k])
                break
        else:
            reps.append(k)
            mass.append(float(probs[k]))
    total = sum(mass)
    kept, acc = [], 0.0
    for i in _most_probable_first(mass):
        kept.append((reps[i], mass[i]))
        acc += mass[i]
        if acc >= params.online_keep_mass * total:
            break
    z = sum(p for _, p in kept)
    return [(k, p / z) for k, p in kept]


class ReferenceSearch:
    """Forward search with explicit loops over states (slow; for checking and baselines)."""

    def __init__(self, model: PlanningModel, params: SearchParams = SEARCH):
        self.model = model
        self.params = params

    def _table_index(self, level: str, e, p) -> int:
        grid = self.model.actions[0].tables[level].grid
        dx, dy = p[0] - e[0], p[1] - e[1]
        c, s = math.cos(e[2]), math.sin(e[2])
        rel = (c * dx + s * dy, -s * dx + c * dy, wrap_angle(p[2] - e[2]))
        flat = 0
        for k in range(3):
            n = grid.shape[k]
            i = (
                round(wrap_angle(rel[k] - grid.center[k]) / grid.spacing[k] + (n - 1) / 2)
                if k == 2
                else round((rel[k] - grid.center[k]) / grid.spacing[k] + (n - 1) / 2)
            )
            i = min(max(int(i), 0), n - 1)
            flat = flat * n + i
        return flat

    @staticmethod
    def _argmax(points: Points, weights: list[float]):
        """The first point whose weight is within TIE_RTOL of the largest."""
        top = max(weights)
        for j in range(len(weights)):
            if weights[j] >= top * (1.0 - TIE_RTOL):
                return points[j]

    def static_value(self, points: Points, weights: list[float], level: str) -> float:
        w_star = self._argmax(points, weights)
        best = 0.0
        for g in self.model.goal_actions:
            ax, ay, at = (float(v) for v in self.model.actions[g].aim[level])
            c, s = math.cos(w_star[2] - at), math.sin(w_star[2] - at)
            aimed = (
                w_star[0] - c * ax + s * ay,
                w_star[1] - s * ax - c * ay,
                wrap_angle(w_star[2] - at),
            )
            for e in (w_star, aimed):  # w* and the estimate that puts w* at the aim
                if self.model.feasible(g, np.asarray(e)):
                    best = max(best, self._goal_probability(points, weights, level, g, e))
        return best

    def _stats(self, points: Points, post: list[float], e, sigma) -> tuple[float, np.ndarray]:
        ent = 0.0
        mean = [0.0, 0.0, 0.0]
        second = [[0.0] * 3 for _ in range(3)]
        for p, w in zip(points, post):
            if w > 0:
                ent -= w * math.log(w)
            d = [
                (p[0] - e[0]) / sigma[0],
                (p[1] - e[1]) / sigma[1],
                wrap_angle(p[2] - e[2]) / sigma[2],
            ]
            for i in range(3):
                mean[i] += w * d[i]
                for k in range(3):
                    second[i][k] += w * d[i] * d[k]
        cov = np.array([[second[i][k] - mean[i] * mean[k] for k in range(3)] for i in range(3)])
        return ent, cov

    def expand(self, points: Points, weights: list[float], level: str, a: int):
        act = self.model.actions[a]
        clusters = act.clusters[level]
        e = self._argmax(points, weights)
        index = [self._table_index(level, e, p) for p in points]
        pc = [0.0] * clusters.count
        for t, w in zip(index, weights):
            c = int(clusters.assign[t])
            if c >= 0:
                pc[c] += w
        total = sum(pc)
        if total <= 0:
            return []
        pc = [p / total for p in pc]
        cand, acc = [], 0.0
        for c in _most_probable_first(pc):
            if pc[c] <= 0:
                break
            cand.append(c)
            acc += pc[c]
            if acc >= 0.95:
                break
        posts, ents, covs = [], [], []
        sigma = self.model.levels[level].sigma
        for c in cand:
            row = clusters.likelihood[c]
            post = [w * float(row[t]) for t, w in zip(index, weights)]
            z = sum(post)
            post = [v / z for v in post]
            ent, cov = self._stats(points, post, e, sigma)
            posts.append(post)
            ents.append(ent)
            covs.append(cov)
        branches = []
        for k, p in merge_branches([pc[c] for c in cand], ents, covs, self.params):
            child_pts, child_w = points, posts[k]
            if act.kind == "reorient" and act.turns[level][cand[k]]:
                child_pts, child_w = self._reorient(
                    child_pts, child_w, e, act.wrt.reorient_angle, act.wrt.reorient_outcome
                )
            branches.append((p, *self._compact(child_pts, child_w)))
        return branches

    def _compact(self, points: Points, weights: list[float]) -> tuple[Points, list[float]]:
        """Support pruning relative to the max weight, then renormalization."""
        top = max(weights)
        pts = [p for p, w in zip(points, weights) if w >= self.params.support_rel * top]
        w = [v for v in weights if v >= self.params.support_rel * top]
        z = sum(w)
        return pts, [v / z for v in w]

    @staticmethod
    def _reorient(points: Points, weights: list[float], e, angle: float, outcome=None):
        outs_p, outs_w = [], []
        blur = TRANSITION.reorient_sigma_theta
        for frac, prob in (
            (1.0, TRANSITION.p_reorient_success),
            (0.5, TRANSITION.p_reorient_partial),
            (0.0, 1.0 - TRANSITION.p_reorient_success - TRANSITION.p_reorient_partial),
        ):
            c, s = math.cos(angle * frac), math.sin(angle * frac)
            for p, w in zip(points, weights):
                delta = (
                    relative_planar(e, np.array(p)) if frac == 1.0 and outcome is not None else None
                )
                if delta is not None and outcome.inside(delta):
                    moved = compose_planar(
                        np.array([e[0], e[1], e[2] + angle]), outcome.mean(delta)
                    )
                    turned = tuple(float(v) for v in moved)
                    sigma = math.hypot(float(outcome.sigma[2]), blur)
                else:
                    dx, dy = p[0] - e[0], p[1] - e[1]
                    turned = (
                        e[0] + c * dx - s * dy,
                        e[1] + s * dx + c * dy,
                        wrap_angle(p[2] + angle * frac),
                    )
                    sigma = blur
                for z, q in BLUR_NODES:  # the turn's spread in θ
                    outs_p.append((turned[0], turned[1], wrap_angle(turned[2] + z * sigma)))
                    outs_w.append(w * prob * q)
        return outs_p, outs_w

    def _goal_probability(
        self, points: Points, weights: list[float], level: str, goal: int, e
    ) -> float:
        """P_b(G) of goal WRT ``goal`` run at e, under the belief (points, weights)."""
        table_g = self.model.actions[goal].goal[level]
        return sum(
            w * float(table_g[self._table_index(level, e, p)]) for p, w in zip(points, weights)
        )

    def action_values(
        self,
        points: Points,
        weights: list[float],
        level: str,
        horizon: int,
        delta: float = SEARCH.delta,
    ) -> np.ndarray:
        e = np.asarray(self._argmax(points, weights))
        q = np.full(len(self.model.actions), -np.inf)
        for a in range(len(self.model.actions)):
            if not self.model.feasible(a, e):
                continue
            outcome = self.model.actions[a].wrt.reorient_outcome
            if (
                outcome is not None
            ):  # a turn only where it is measured (SearchParams.reorient_min_in_box)
                inside = sum(
                    w
                    for p, w in zip(points, weights)
                    if outcome.inside(relative_planar(e, np.array(p)))
                )
                if inside < self.params.reorient_min_in_box:
                    continue
            branches = self.expand(points, weights, level, a)
            if not branches:
                continue
            total = 0.0
            for p, pts, w in branches:
                held = (
                    self._goal_probability(pts, w, level, a, e)
                    if self.model.actions[a].kind == "goal"
                    else 0.0
                )
                # a goal grasp the agent would declare ends the run with its P_b(G)
                total += p * (
                    held if held > 1.0 - delta else self.value(pts, w, level, horizon - 1, delta)
                )
            q[a] = total - self.params.cost_per_delta * delta
        return q

    def value(
        self,
        points: Points,
        weights: list[float],
        level: str,
        horizon: int,
        delta: float = SEARCH.delta,
    ) -> float:
        if horizon > 0:
            q = self.action_values(points, weights, level, horizon, delta)
            if np.isfinite(q).any():
                return float(q.max())
        return self.static_value(points, weights, level) - self.params.cost_per_delta * delta

    def select(
        self, belief: Belief, horizon: int = SEARCH.horizon, delta: float = SEARCH.delta
    ) -> SearchResult:
        t0 = time.perf_counter()
        level = self.model.level_of(belief.grid)
        pts, w = self._compact(
            [tuple(p) for p in belief.grid.points().tolist()], belief.weights.tolist()
        )
        q = self.action_values(pts, w, level, horizon, delta)
        p_goal = self.static_value(pts, w, level)
        best = int(np.argmax(q)) if np.isfinite(q).any() else -1
        return SearchResult(
            action=best,
            value=float(q[best]) if best >= 0 else float("nan"),
            action_values=q,
            p_goal=p_goal,
            planning_time=time.perf_counter() - t0,
        )
