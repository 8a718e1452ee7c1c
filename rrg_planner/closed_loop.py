"""The closed loop of one robust grasp (algorithm §6): decide → execute → update, written once.

The in-process agent, the planner node's robust-grasp action and the experiment runner all run
``ClosedLoop``. What differs between them sits behind two small interfaces, as in pomdp_py's
agent / environment split:

* a ``World`` runs a WRT at an estimate and returns what the hand observed: an in-process
  environment (MuJoCo physics, the geometric simulator), or the executor node over ROS, which
  drives the simulator node or the hardware bridge;
* an ``Estimator`` owns the belief: it updates it with each observation and applies the
  retreat's transition (``rrg_estimator.tracker.BeliefTracker`` in-process, the estimator node
  over ROS).

The agent (``rrg_planner.agent.RobustGraspAgent``) only decides: it never changes the belief.

One step: the agent chooses a WRT and the estimate to run it at; the world executes it (a WRT
found infeasible before anything moved is ruled out at that estimate and the agent chooses
again); the estimator updates the belief with the observation; for a goal grasp the agent reads
P_b(G) off the updated belief, and verifies the grasp against its own observation: a goal grasp
whose sensors show it is not the goal's (it stopped early, too few fingers, a required
contact's fingers silent) is not believed to hold, its P(goal) is 0, and the loop goes on. The
run stops after a goal grasp believed to hold (P_b(G) > 1 − δ) or the last action allowed.
Otherwise the world retreats the hand and the estimator applies the retreat's transition
before the next decision.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from rrg_estimator.belief import Belief
from rrg_estimator.config import LEVELS, UncertaintyLevel
from rrg_estimator.tracker import BeliefTracker
from rrg_models.config import SENSOR_NAMES, WORLD
from rrg_models.observation import Observation
from rrg_models.wrt import WRT, InfeasibleWRT
from rrg_planner.agent import MAX_BLOCKED, RobustGraspAgent
from rrg_planner.planning_model import PlanningModel
from rrg_planner.search import SearchResult

log = logging.getLogger(__name__)


class ExecutionLost(RuntimeError):
    """The execution was lost (with a node that died, or stopped by the safety layer on a
    transient fault); the hand is back home, and the belief holds whatever of it the estimator
    saw. The agent chooses again on the current belief, up to MAX_LOST times in a run."""


#: Lost executions after which a run ends with an error (chosen: a stall that recurs three
#: times in one grasp is no passing hiccup).
MAX_LOST = 3


class World(Protocol):
    """What executes the agent's WRTs: an in-process environment, or the executor node."""

    def execute(self, wrt: WRT, e: np.ndarray) -> Observation:
        """Run τ(e) with guarded moves, close the fingers, and return the observation; raise
        InfeasibleWRT when τ(e) cannot run (nothing moved), ExecutionLost when the execution
        was lost and the hand brought home."""

    def retreat(self) -> None:
        """Open the hand and retrace the last WRT's path back home."""


class Environment(World, Protocol):
    """An in-process world that can also judge the final grasp (evaluation only)."""

    def judge(self, wrt: WRT, e: np.ndarray) -> bool:
        """Whether the goal grasp just executed relative to e holds."""


class Estimator(Protocol):
    """What owns the belief: the in-process BeliefTracker, or the estimator node."""

    @property
    def belief(self) -> Belief:
        """The current belief."""

    def update(self, wrt_name: str, e: np.ndarray, obs: Observation) -> Belief:
        """The belief after WRT ``wrt_name`` ran at estimate e and observed ``obs``."""

    def retreated(self) -> Belief:
        """The belief once the hand retreated from the last WRT (its transition applied)."""


class GraspCanceled(RuntimeError):
    """The run was canceled between two steps."""


@dataclass
class Decision:
    """The agent's choice at one step, before the world runs it."""

    number: int  # 1-based action count (an execution found infeasible is not an action)
    action: int  # index into the planning model's actions; -1 when nothing can run
    wrt: str
    kind: str
    estimate: np.ndarray  # (3,) e = (x [m], y [m], θ [rad]) to run the WRT at
    last: bool  # the last action allowed: the goal grasp, run open-loop
    value: float  # the chosen action's value (v(b) without a search)
    p_goal: float  # v(b): P_b(G) of the goal grasp at its best estimate now
    planning_time: float  # s
    search: SearchResult | None = None
    #: the value of every action the search weighed, by WRT name (empty without a search)
    action_values: dict[str, float] = field(default_factory=dict)
    #: the goal grasp p_goal is of: the chosen one, else the best under the belief ("" if none)
    goal_wrt: str = ""


@dataclass
class Step:
    """One executed action."""

    wrt: str
    kind: str
    estimate: np.ndarray  # (3,) the estimate the WRT was executed relative to
    contact: bool
    sensors: list[str]
    #: after a goal grasp, P(G) of the grasp just made (0 if its check failed); else the
    #: search's v(b)
    p_goal: float
    planning_time: float  # s
    action_values: dict[str, float] = field(default_factory=dict)
    #: after a goal grasp: P_b(G) under the updated belief, before the grasp's own check
    p_goal_belief: float = float("nan")
    #: after a goal grasp: what its own observation says is wrong with it (empty: nothing)
    mismatches: list[str] = field(default_factory=list)


@dataclass
class GraspRun:
    """How one robust grasp ended."""

    declared: bool  # the agent believed P(G) > 1 − δ when it stopped
    steps: list[Step]
    p_goal: float  # P_b(G) of the last goal grasp (NaN when none ran)
    planning_time: float  # s, total
    belief: Belief  # the estimator's belief when the run stopped
    error: str = ""  # why the run stopped without a goal grasp; "" when one ran
    final: Decision | None = None  # the last action that ran (the goal grasp to judge)
    success: bool = False  # the world's judgement of the final grasp, where it judges (in-process)

    @property
    def n_actions(self) -> int:
        return len(self.steps)


def decide(agent: RobustGraspAgent, belief: Belief, number: int) -> Decision:
    """The agent's number-th decision (1-based) on ``belief``, timed."""
    t0 = time.perf_counter()
    action, e, res, last = agent.plan_step(belief, number)
    planning_time = time.perf_counter() - t0
    if action < 0:
        return Decision(number, -1, "", "", e, last, float("nan"), float("nan"), planning_time, res)
    act = agent.model.actions[action]
    if res is None:
        goal, p_goal = agent.static_goal(belief)
        value = p_goal
        values = {}
    else:
        goal, p_goal, value = res.goal_action, res.p_goal, float(res.action_values[action])
        values = {name: float(v) for name, v in zip(agent.model.names, res.action_values)}
    goal_wrt = act.name if act.kind == "goal" else agent.model.names[goal] if goal >= 0 else ""
    return Decision(
        number,
        action,
        act.name,
        act.kind,
        e,
        last,
        value,
        p_goal,
        planning_time,
        res,
        values,
        goal_wrt,
    )


class ClosedLoop:
    """One robust grasp: the agent decides, the world executes, the estimator updates.

    Hooks (each optional): ``on_decision(decision)`` before a WRT runs, ``on_infeasible(decision,
    reason)`` when it could not run, ``on_lost(decision, reason)`` when its execution was lost,
    ``on_step(step, belief)`` after its update; ``canceled()`` is asked before every decision
    and stops the run with GraspCanceled.
    """

    def __init__(
        self,
        agent: RobustGraspAgent,
        world: World,
        estimator: Estimator,
        on_decision: Callable[[Decision], None] | None = None,
        on_infeasible: Callable[[Decision, str], None] | None = None,
        on_step: Callable[[Step, Belief], None] | None = None,
        canceled: Callable[[], bool] | None = None,
        on_lost: Callable[[Decision, str], None] | None = None,
    ):
        self.agent, self.world, self.estimator = agent, world, estimator
        self.on_decision, self.on_infeasible, self.on_step = on_decision, on_infeasible, on_step
        self.on_lost = on_lost
        self.canceled = canceled or (lambda: False)
        self.steps: list[Step] = []
        #: (action, estimate (3,)) of every execution found infeasible, as the agent blocked it
        self.blocked: list[tuple[int, np.ndarray]] = []
        self.planning_time = 0.0  # s
        self.p_goal = float("nan")
        self.lost = 0  # executions lost (ExecutionLost) in this run

    def run(self, resume: bool = False) -> GraspRun:
        """Step until the agent stops (a goal grasp believed to hold, or the last action).
        resume: go on from the steps the loop holds (rrg_planner.grasp_state) instead of
        starting afresh."""
        if not resume:
            self.agent.search.clear()
        belief = self.estimator.belief
        while True:  # ends at the last action, which is always the goal grasp
            run, belief = self.step(belief)
            if run is not None:
                return run

    def step(self, belief: Belief) -> tuple[GraspRun | None, Belief]:
        """One decide → execute → update step on ``belief``. Returns (the run's end or None,
        the belief to decide on next)."""
        if self.canceled():
            raise GraspCanceled("canceled")
        agent = self.agent
        decision = decide(agent, belief, len(self.steps) + 1)
        self.planning_time += decision.planning_time
        if decision.action < 0:
            return self._end(
                False, belief, f"no feasible action at w*={np.round(decision.estimate, 3).tolist()}"
            ), belief
        if self.on_decision:
            self.on_decision(decision)
        e = decision.estimate
        try:
            obs = self.world.execute(agent.model.actions[decision.action].wrt, e)
        except InfeasibleWRT as exc:  # nothing moved: rule it out at e and choose again
            log.warning(
                "%s infeasible at %s (%s): replanning", decision.wrt, np.round(e, 3).tolist(), exc
            )
            if self.on_infeasible:
                self.on_infeasible(decision, str(exc))
            agent.search.block(decision.action, e)
            self.blocked.append((decision.action, np.array(e, dtype=float)))
            if len(agent.search.blocked) > MAX_BLOCKED:
                return self._end(
                    False, belief, f"{len(agent.search.blocked)} infeasible executions"
                ), belief
            return None, belief
        except ExecutionLost as exc:  # the hand is home again: choose again on the belief now
            log.warning("%s at %s lost (%s): replanning", decision.wrt, np.round(e, 3), exc)
            if self.on_lost:
                self.on_lost(decision, str(exc))
            self.lost += 1
            if self.lost >= MAX_LOST:
                return self._end(False, belief, f"{self.lost} executions lost: {exc}"), belief
            return None, self.estimator.belief
        agent.executed(decision.action, e)
        posterior = self.estimator.update(decision.wrt, e, obs)
        p_belief = agent.grasp_probability(posterior, decision.action, e)
        mismatches = agent.verify_goal(decision.action, obs)
        p_exec = 0.0 if mismatches else p_belief
        search_p_goal = decision.search.p_goal if decision.search is not None else float("nan")
        step = Step(
            wrt=decision.wrt,
            kind=decision.kind,
            estimate=e,
            contact=bool(obs.contact),
            sensors=[s for s, on in zip(SENSOR_NAMES, obs.sensors) if on],
            p_goal=float(p_exec if decision.kind == "goal" else search_p_goal),
            planning_time=decision.planning_time,
            action_values=decision.action_values,
            p_goal_belief=float(p_belief),
            mismatches=mismatches,
        )
        self.steps.append(step)
        log.info(
            "action %d: %s at %s → contact=%s sensors=%s P(goal)=%.3f (%.1f ms)",
            decision.number,
            decision.wrt,
            np.round(e, 3).tolist(),
            obs.contact,
            step.sensors,
            step.p_goal,
            decision.planning_time * 1e3,
        )
        if np.isfinite(obs.table_height):
            log.info(
                "%s began with a table touch: the table read %+.1f mm in its posture, and it "
                "ran that much higher",
                decision.wrt,
                1e3 * (obs.table_height - WORLD.table_top_z),
            )
        if mismatches:
            log.info(
                "goal grasp check failed (%s): not believed to hold (P_b(G) %.3f); %s",
                "; ".join(mismatches),
                p_belief,
                "the last action" if decision.last else "opening and planning again",
            )
        if self.on_step:
            self.on_step(step, posterior)
        self.p_goal = step.p_goal
        if agent.finished(decision.action, p_exec, decision.last):
            run = self._end(bool(p_exec > 1.0 - agent.delta), posterior)
            run.final = decision
            return run, posterior
        self.world.retreat()
        return None, self.estimator.retreated()

    def _end(self, declared: bool, belief: Belief, error: str = "") -> GraspRun:
        return GraspRun(declared, self.steps, self.p_goal, self.planning_time, belief, error)


def in_process_estimator(
    model: PlanningModel, level: UncertaintyLevel | str, mean, variable_resolution: bool = True
) -> BeliefTracker:
    """The estimator of an in-process run: the level's Gaussian belief about ``mean``, updated
    with the planning model's own tables and frames, re-gridded over the model's levels (when
    it has the finest, ``low``)."""
    level = LEVELS[level] if isinstance(level, str) else level
    return BeliefTracker(
        model.obj,
        Belief.for_level(level, mean),
        tables=model,
        levels=model.levels.values(),
        variable_resolution=variable_resolution and "low" in model.levels,
        calibration=model.calibration,
        world=model.world.name,
    )


def run_in_process(
    agent: RobustGraspAgent,
    env: Environment,
    level: UncertaintyLevel | str,
    mean,
    on_step: Callable[[Step, Belief], None] | None = None,
    variable_resolution: bool = True,
) -> GraspRun:
    """One robust grasp in an in-process environment, judged there at the end."""
    estimator = in_process_estimator(agent.model, level, mean, variable_resolution)
    run = ClosedLoop(agent, env, estimator, on_step=on_step).run()
    if run.final is not None:
        run.success = bool(env.judge(agent.model.actions[run.final.action].wrt, run.final.estimate))
    return run
