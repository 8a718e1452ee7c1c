"""The RRG agent: a belief, a strategy and the closed loop act → observe → update (DESIGN §6).

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
import time
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np

from rrg_estimator.belief import Belief
from rrg_estimator.tracker import settle_after_grasp, wrt_posterior
from rrg_estimator.update import goal_probability
from rrg_estimator.varres import maybe_refine
from rrg_estimator.config import LEVELS, UncertaintyLevel
from rrg_planner.config import SEARCH
from rrg_sim.config import SENSOR_NAMES
from rrg_estimator.grid import Grid
from rrg_sim.observation import Observation
from rrg_sim.wrt import WRT, InfeasibleWRT

from rrg_planner.planning_model import PlanningModel
from .search import ForwardSearch, SearchResult, SparseBelief

log = logging.getLogger(__name__)

STRATEGIES = ("open-loop", "rrg-goal", "rrg-info")
MAX_BLOCKED = 20  # infeasible executions tolerated in one run before giving up
MAX_FALLBACK_STATES = 300  # most likely states searched for one where the goal grasp is feasible


class Environment(Protocol):
    """What the agent acts on: the geometric simulator, MuJoCo physics, or the robot."""

    def execute(self, wrt: WRT, e: np.ndarray) -> Observation:
        """Run τ(e) with guarded moves, close the fingers, and return the observation."""

    def retreat(self) -> None:
        """Open the hand and retrace back to the home pose."""

    def judge(self, wrt: WRT, e: np.ndarray) -> bool:
        """Whether the goal grasp just executed relative to e holds (evaluation only)."""


@dataclass
class Step:
    """One executed action."""

    wrt: str
    kind: str
    estimate: np.ndarray  # (3,) w*(b) the WRT was executed relative to
    contact: bool
    sensors: list[str]
    p_goal: float  # v(b) or, after a goal grasp, P_b(G) of the grasp just made
    planning_time: float  # s
    action_values: dict[str, float] = field(default_factory=dict)


@dataclass
class TrialResult:
    """Outcome of one robust-grasp run."""

    success: bool
    declared: bool  # the agent believed P(G) > 1 − δ when it stopped
    steps: list[Step]
    p_goal: float
    planning_time: float  # s, total
    belief: Belief
    error: str = ""

    @property
    def n_actions(self) -> int:
        return len(self.steps)


def initial_belief(level: UncertaintyLevel, mean) -> Belief:
    """The Gaussian initial belief of a level, on its grid centred at the mean."""
    mean = np.asarray(mean, dtype=float)
    return Belief.gaussian(Grid.for_level(level, center=mean), mean, np.asarray(level.sigma))


class RobustGraspAgent:
    """Chooses WRTs with a strategy and tracks the belief (the pomdp_py 'agent')."""

    def __init__(self, model: PlanningModel, strategy: str = "rrg-info", horizon: int = SEARCH.horizon,
                 delta: float = SEARCH.delta, max_actions: int = SEARCH.max_actions,
                 variable_resolution: bool = True):
        if strategy not in STRATEGIES:
            raise ValueError(f"unknown strategy {strategy!r}; valid: {STRATEGIES}")
        if not 1 <= horizon <= 3:
            raise ValueError(f"horizon must be 1, 2 or 3, got {horizon}")
        if not 0.0 < delta < 1.0:
            raise ValueError(f"delta must be in (0, 1), got {delta}")
        self.model = model
        self.search = ForwardSearch(model)
        self.strategy = strategy
        self.horizon = horizon
        self.delta = delta
        self.max_actions = max_actions
        self.variable_resolution = variable_resolution and "low" in model.levels
        self.goal = model.goal_actions[0]

    # --------------------------------------------------------------- choice
    def _goal_or_reorient(self, e: np.ndarray) -> int:
        """RRG-Goal's choice: the goal WRT, or a reorientation that makes it feasible."""
        if self.search.feasible(self.goal, e):
            return self.goal
        best, best_gap = -1, np.inf
        for i, act in enumerate(self.model.actions):
            if act.kind != "reorient" or not self.search.feasible(i, e):
                continue
            turned = e + np.array([0.0, 0.0, act.wrt.reorient_angle])
            gap = 0.0 if self.search.feasible(self.goal, turned) else abs(act.wrt.reorient_angle)
            if gap < best_gap:
                best, best_gap = i, gap
        return best

    def choose(self, belief: Belief) -> tuple[int, SearchResult | None]:
        """The next action index (-1 if nothing is feasible) and the search result, if any."""
        e = belief.w_star()
        if self.strategy != "rrg-info":
            return self._goal_or_reorient(e), None
        res = self.search.select(belief, self.horizon, self.delta)
        if res.p_goal >= 1.0 - self.delta and res.goal_action >= 0:
            return res.goal_action, res
        # goal_action < 0: no goal grasp can run at w*(b) or its aim, or where one can, its
        # P_b(G) is 0 (then the most likely feasible state may be w*(b) itself)
        if res.goal_action < 0 and self.goal_beyond_w_star(belief) >= min(1.0 - self.delta, res.value):
            return self.goal, res  # plan_step runs it at the most likely state where it can run
        return res.action, res

    def goal_beyond_w_star(self, belief: Belief) -> float:
        """P_b(G) of the goal grasp at the most likely state where it is feasible (0 if none):
        the root's value of grasping now when it cannot run at w*(b) or its aim. The search
        values a goal grasp only there, so without this it keeps gathering information, or
        turns the object, while a grasp a cell or two away would already succeed (MuJoCo:
        brita_pitcher/high/rrg-info#63 of campaign 9d89825 read the pitcher six more times
        and never grasped it; with this rule it grasps at θ 0.25 rad from w* and succeeds)."""
        alt = self.most_likely_feasible(belief, self.goal)
        return 0.0 if alt is None else self.grasp_probability(belief, self.goal, alt)

    def next_action(self, belief: Belief, step: int) -> tuple[int, SearchResult | None, bool]:
        """The step-th action of a run (1-based): (action index or -1, the search result if
        any, whether it is the last); the last is the goal grasp, executed open-loop."""
        if step >= self.max_actions or self.strategy == "open-loop":
            return self.goal, None, True
        action, res = self.choose(belief)
        return action, res, False

    def plan_step(self, belief: Belief, step: int) -> tuple[int, np.ndarray, SearchResult | None, bool]:
        """next_action and the estimate e to run it at: w*(b), or, when the chosen action (or
        every action) cannot run there, the goal grasp at the most likely state where it can.
        Returns (action, or -1 when nothing can run; e; the search result, if any; last)."""
        action, res, last = self.next_action(belief, step)
        e = belief.w_star()
        if action >= 0 and self.model.actions[action].kind == "goal":
            e = self.goal_estimate(belief, action, res)
        if action >= 0 and self.search.feasible(action, e):
            return action, e, res, last
        alt = self.most_likely_feasible(belief, self.goal)
        if alt is None:
            return -1, e, res, last
        log.info("%s infeasible at w*=%s: goal grasp at %s instead",
                 self.model.names[action] if action >= 0 else "every action",
                 np.round(e, 3).tolist(), np.round(alt, 3).tolist())
        return self.goal, alt, res, last

    def goal_estimate(self, belief: Belief, action: int, res: SearchResult | None = None) -> np.ndarray:
        """Where to run goal WRT ``action``: of w*(b) and its aimed estimate
        (ForwardSearch.goal_estimates), the one with the highest P_b(G); w*(b) if neither is
        feasible. Reuses the search result's when it is for this action."""
        if res is not None and res.goal_action == action and res.goal_estimate is not None:
            return res.goal_estimate
        sb = SparseBelief.from_belief(belief, self.model.level_of(belief.grid), self.search.params)
        _, g, e = self.search.best_goal(sb, goals=(action,))
        return e if g >= 0 else belief.w_star()

    def most_likely_feasible(self, belief: Belief, action: int, candidates: int = MAX_FALLBACK_STATES) -> np.ndarray | None:
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
        """For a goal WRT just executed at e: P_b(G) under the updated belief; NaN otherwise."""
        act = self.model.actions[action]
        if act.kind != "goal":
            return float("nan")
        return goal_probability(posterior, act.goal[self.model.level_of(posterior.grid)], e)

    def finished(self, action: int, p_exec: float, last: bool) -> bool:
        """Whether a run stops after this action: a goal grasp believed to hold, or the last one."""
        return self.model.actions[action].kind == "goal" and (p_exec > 1.0 - self.delta or last)

    def executed(self, action: int, e: np.ndarray) -> None:
        """Note that ``action`` ran at e: an information-gathering WRT's reading at e is spent
        (ForwardSearch.spend). It left the object in place, or (an early contact) nudged it
        a few mm where it stopped; run again, it reads the same or nearly. In MuJoCo, counting
        a repeat as a second reading made the drill's belief certain of a θ 0.12 rad off
        (probe trial powerdrill/high/rrg-info#28), and a teacup was swept three times with
        one reading, twice at the same estimate (campaign cc990d4, giant_teacup#10)."""
        if self.model.actions[action].kind == "info":
            self.search.spend(action, e)

    def observe(self, belief: Belief, action: int, e: np.ndarray, obs: Observation) -> tuple[Belief, float]:
        """SE(b, τ(e), o); returns the new belief and, for goal WRTs, P_b(G) of the grasp made."""
        act = self.model.actions[action]
        post = wrt_posterior(belief, act.tables[self.model.level_of(belief.grid)], act.wrt, e, obs)
        return post, self.grasp_probability(post, action, e)

    def after_retreat(self, belief: Belief, action: int, e: np.ndarray, contact: bool) -> Belief:
        """The belief once the robot retreated from an action run at e: a goal grasp that
        arrived (no early contact: it closed firmly) moved the object as its settling says."""
        return settle_after_grasp(belief, self.model.obj, self.model.actions[action].wrt, e, contact)

    # ------------------------------------------------------------ closed loop
    def run(self, env: Environment, level: UncertaintyLevel | str, mean,
            on_step: Callable[[Step, Belief], None] | None = None) -> TrialResult:
        """One robust grasp: act until the goal is believed achieved or actions run out."""
        level = LEVELS[level] if isinstance(level, str) else level
        belief = initial_belief(level, mean)
        self.search.clear()
        steps: list[Step] = []
        total_plan = 0.0
        p_goal = float("nan")
        while True:  # ends at the last action, which is always the goal grasp
            n = len(steps) + 1  # an execution found infeasible (nothing moved) is not an action
            t0 = time.perf_counter()
            action, e, res, last = self.plan_step(belief, n)
            plan_t = time.perf_counter() - t0
            total_plan += plan_t
            if action < 0:
                return TrialResult(False, False, steps, p_goal, total_plan, belief,
                                   error=f"no feasible action at w*={np.round(e, 3).tolist()}")
            act = self.model.actions[action]
            try:
                obs = env.execute(act.wrt, e)
            except InfeasibleWRT as exc:  # nothing moved: rule it out at e and choose again
                log.warning("%s infeasible at %s (%s): replanning", act.name, np.round(e, 3).tolist(), exc)
                self.search.block(action, e)
                if len(self.search.blocked) > MAX_BLOCKED:
                    return TrialResult(False, False, steps, p_goal, total_plan, belief,
                                       error=f"{len(self.search.blocked)} infeasible executions")
                continue
            self.executed(action, e)
            belief, p_exec = self.observe(belief, action, e, obs)
            p_goal = p_exec if act.kind == "goal" else (res.p_goal if res else float("nan"))
            step = Step(wrt=act.name, kind=act.kind, estimate=e, contact=bool(obs.contact),
                        sensors=[s for s, on in zip(SENSOR_NAMES, obs.sensors) if on],
                        p_goal=float(p_goal), planning_time=plan_t,
                        action_values=({self.model.names[i]: float(v) for i, v in enumerate(res.action_values)}
                                       if res else {}))
            steps.append(step)
            log.info("action %d: %s at %s → contact=%s sensors=%s P(goal)=%.3f (%.1f ms)", n, act.name,
                     np.round(e, 3).tolist(), obs.contact, step.sensors, p_goal, plan_t * 1e3)
            if on_step:
                on_step(step, belief)
            if self.finished(action, p_exec, last):
                success = env.judge(act.wrt, e)
                return TrialResult(bool(success), bool(p_exec > 1.0 - self.delta), steps, p_exec,
                                   total_plan, belief)
            env.retreat()
            if self.variable_resolution:  # as the estimator node does, before the settling
                belief = maybe_refine(belief, self.model.levels.values()) or belief
            belief = self.after_retreat(belief, action, e, bool(obs.contact))
