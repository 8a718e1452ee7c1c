"""The RRG agent: chooses the next WRT for a belief with a strategy (algorithm §6); the closed loop
that runs its choices is rrg_planner.closed_loop.

Strategies (paper, "Experiments"):
* ``open-loop``: the goal WRT once, relative to the initial mean.
* ``rrg-goal``: the goal WRT relative to w*(b), repeated until P_b(G) > 1 − δ, with a
  reorientation first when the goal grasp is infeasible at w*(b).
* ``rrg-info``: forward search over every WRT (search.py). When the belief already says
  the goal grasp succeeds with probability ≥ 1 − δ, the goal grasp is taken: δ is the
  user's stopping rule, and no information action can do better than stopping then.
After the 9th action the 10th is the goal grasp, executed open-loop, then judged.
"""

from __future__ import annotations

import logging

import numpy as np

from rrg_estimator.belief import Belief
from rrg_estimator.update import goal_probability
from rrg_models.goal import goal_grasp_mismatches
from rrg_models.observation import Observation
from rrg_planner.config import SEARCH
from rrg_planner.planning_model import PlanningModel
from rrg_planner.request_checks import check_choice
from rrg_planner.search import ForwardSearch, SearchResult, SparseBelief

log = logging.getLogger(__name__)

MAX_BLOCKED = 20  # infeasible executions tolerated in one run before giving up
MAX_FALLBACK_STATES = 300  # most likely states searched for one where the goal grasp is feasible


class RobustGraspAgent:
    """Chooses WRTs with a strategy (the pomdp_py 'agent'); the belief it decides on is the
    estimator's, and the search remembers what ran (``executed``) and what could not (``block``)."""

    def __init__(
        self,
        model: PlanningModel,
        strategy: str = "rrg-info",
        horizon: int = SEARCH.horizon,
        delta: float = SEARCH.delta,
        max_actions: int = SEARCH.max_actions,
        verify: bool = True,
    ):
        """verify: check each goal grasp's own observation against what the goal needs
        (``verify_goal``) before believing it; off only to measure what the check gains."""
        check_choice(strategy, horizon, delta)
        self.model = model
        self.search = ForwardSearch(model)
        self.strategy = strategy
        self.horizon = horizon
        self.delta = delta
        self.max_actions = max_actions
        self.verify = verify

    # --------------------------------------------------------------- choice
    def _goal_or_reorient(self, belief: Belief) -> int:
        """RRG-Goal's choice: the goal grasp that can run at w*(b) with the highest P_b(G)
        there, or a reorientation that makes one feasible."""
        e = belief.w_star()
        feasible = [g for g in self.model.goal_actions if self.search.feasible(g, e)]
        if feasible:
            return max(feasible, key=lambda g: self.grasp_probability(belief, g, e))
        best, best_gap = -1, np.inf
        for i, act in enumerate(self.model.actions):
            if act.kind != "reorient" or not self.search.feasible(i, e):
                continue
            turned = e + np.array([0.0, 0.0, act.wrt.reorient_angle])
            reaches = any(self.search.feasible(g, turned) for g in self.model.goal_actions)
            gap = 0.0 if reaches else abs(act.wrt.reorient_angle)
            if gap < best_gap:
                best, best_gap = i, gap
        return best

    def choose(self, belief: Belief) -> tuple[int, SearchResult | None]:
        """The next action index (-1 if nothing is feasible) and the search result, if any."""
        if self.strategy != "rrg-info":
            return self._goal_or_reorient(belief), None
        res = self.search.select(belief, self.horizon, self.delta)
        if res.p_goal >= 1.0 - self.delta and res.goal_action >= 0:
            return res.goal_action, res
        # goal_action < 0: no goal grasp can run at w*(b) or its aim, or where one can, its
        # P_b(G) is 0 (then the most likely feasible state may be w*(b) itself)
        if res.goal_action < 0:
            goal, _, p = self.goal_beyond_w_star(belief)
            if p >= min(1.0 - self.delta, res.value):
                return goal, res  # plan_step runs it at the most likely state where it can run
        return res.action, res

    def goal_beyond_w_star(self, belief: Belief) -> tuple[int, np.ndarray | None, float]:
        """Of the goal grasps, the one with the highest P_b(G) at the most likely state where
        it is feasible: (goal action, that state or None, P_b(G), 0 if none is feasible); the
        root's value of grasping now when no goal grasp can run at w*(b) or its aim. The
        search values a goal grasp only there, so without this it keeps gathering information,
        or turns the object, while a grasp a cell or two away would already succeed (MuJoCo:
        without this rule a pitcher run at high uncertainty read the pitcher six more times
        and never grasped it; with it, the same run grasps at θ 0.25 rad from w* and
        succeeds)."""
        best = (self.model.goal_actions[0], None, 0.0)
        for g in self.model.goal_actions:
            alt = self.most_likely_feasible(belief, g)
            if alt is not None:
                p = self.grasp_probability(belief, g, alt)
                if best[1] is None or p > best[2]:
                    best = (g, alt, p)
        return best

    def next_action(self, belief: Belief, step: int) -> tuple[int, SearchResult | None, bool]:
        """The step-th action of a run (1-based): (action index or -1, the search result if
        any, whether it is the last); the last is a goal grasp, executed open-loop."""
        if step >= self.max_actions or self.strategy == "open-loop":
            return self.static_goal(belief)[0], None, True
        action, res = self.choose(belief)
        return action, res, False

    def plan_step(
        self, belief: Belief, step: int
    ) -> tuple[int, np.ndarray, SearchResult | None, bool]:
        """next_action and the estimate e to run it at: w*(b), or, when the chosen action (or
        every action) cannot run there, the goal grasp at the most likely state where it can.
        Returns (action, or -1 when nothing can run; e; the search result, if any; last)."""
        action, res, last = self.next_action(belief, step)
        e = belief.w_star()
        if action >= 0 and self.model.actions[action].kind == "goal":
            e = self.goal_estimate(belief, action, res)
        if action >= 0 and self.search.feasible(action, e):
            return action, e, res, last
        goal, alt, _ = self.goal_beyond_w_star(belief)
        if alt is None:
            return -1, e, res, last
        log.info(
            "%s infeasible at w*=%s: goal grasp %s at %s instead",
            self.model.names[action] if action >= 0 else "every action",
            np.round(e, 3).tolist(),
            self.model.names[goal],
            np.round(alt, 3).tolist(),
        )
        return goal, alt, res, last

    def goal_estimate(
        self, belief: Belief, action: int, res: SearchResult | None = None
    ) -> np.ndarray:
        """Where to run goal WRT ``action``: of w*(b) and its aimed estimate
        (ForwardSearch.goal_estimates), the one with the highest P_b(G); w*(b) if neither is
        feasible. Reuses the search result's when it is for this action."""
        if res is not None and res.goal_action == action and res.goal_estimate is not None:
            return res.goal_estimate
        sb = SparseBelief.from_belief(belief, self.model.level_of(belief.grid), self.search.params)
        _, g, e = self.search.best_goal(sb, goals=(action,))
        return e if g >= 0 else belief.w_star()

    def most_likely_feasible(
        self, belief: Belief, action: int, candidates: int = MAX_FALLBACK_STATES
    ) -> np.ndarray | None:
        """The most likely of the belief's ``candidates`` most likely states at which
        ``action`` is feasible, or None."""
        w = belief.weights
        top = np.argpartition(-w, min(candidates, w.size) - 1)[:candidates]
        points = belief.grid.points()
        for i in top[np.argsort(-w[top], kind="stable")]:
            if w[i] > 0 and self.search.feasible(action, points[i]):
                return points[i]
        return None

    def grasp_probability(self, posterior: Belief, action: int, e: np.ndarray) -> float:
        """For a goal WRT just executed at e: P_b(G) under the updated belief, valued from the
        belief's frame (PlanningModel.goal_table); NaN otherwise."""
        if self.model.actions[action].kind != "goal":
            return float("nan")
        level = self.model.level_of(posterior.grid)
        return goal_probability(posterior, self.model.goal_table(action, level, posterior.frame), e)

    def verify_goal(self, action: int, obs: Observation) -> list[str]:
        """For a goal WRT just executed: what its own observation says is wrong with the grasp
        (rrg_models.goal.goal_grasp_mismatches); [] for any other WRT, or with
        verification off. A grasp with a mismatch is not believed to hold, whatever the
        belief's P_b(G): its observation has already entered the belief, and the loop opens
        the hand and plans again."""
        if not self.verify or self.model.actions[action].kind != "goal":
            return []
        region = self.model.obj.goal_region(self.model.names[action])
        return goal_grasp_mismatches(obs.contact, obs.sensors, region)

    def static_goal(self, belief: Belief) -> tuple[int, float]:
        """The goal grasp with the highest P_b(G) at its best estimate (goal_estimate; 0 where
        it cannot run, or an execution found it could not run near there), and that P_b(G); the
        object's first goal grasp when none is above 0. The grasp of an open-loop run, and of a
        run's last action."""
        best = (self.model.goal_actions[0], 0.0)
        for g in self.model.goal_actions:
            e = self.goal_estimate(belief, g)
            if self.search.feasible(g, e):
                p = self.grasp_probability(belief, g, e)
                if p > best[1]:
                    best = (g, p)
        return best

    def static_value(self, belief: Belief) -> float:
        """v(b) without a search: static_goal's P_b(G)."""
        return self.static_goal(belief)[1]

    def finished(self, action: int, p_exec: float, last: bool) -> bool:
        """Whether a run stops after this action: a goal grasp believed to hold, or the last one."""
        return self.model.actions[action].kind == "goal" and (p_exec > 1.0 - self.delta or last)

    def executed(self, action: int, e: np.ndarray) -> None:
        """Note that ``action`` ran at e: an information-gathering WRT's reading at e is spent
        (ForwardSearch.spend). It left the object in place, or (an early contact) nudged it
        a few mm where it stopped; run again, it reads the same or nearly. In MuJoCo, counting
        a repeat as a second reading made the drill's belief certain of a θ 0.12 rad off, and a
        teacup was swept three times with one reading, twice at the same estimate."""
        if self.model.actions[action].kind == "info":
            self.search.spend(action, e)
