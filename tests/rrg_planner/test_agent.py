"""The agent's loop rules: the last action is the goal grasp, open-loop runs it once, an
execution found infeasible (nothing moved) rules that action out at that estimate without
counting as an action, and a lost execution is chosen again, three ending the run."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rrg_estimator.belief import Belief
from rrg_estimator.config import UncertaintyLevel
from rrg_models.config import WORLD
from rrg_models.poses import compose_planar, relative_planar
from rrg_models.wrt import WRT, InfeasibleWRT
from rrg_planner.agent import RobustGraspAgent
from rrg_planner.closed_loop import ExecutionLost, run_in_process
from rrg_planner.config import SEARCH
from rrg_planner.geometric_env import GeometricEnvironment
from rrg_planner.planning_model import PlanningModel
from rrg_planner.search import ForwardSearch

SMALL = UncertaintyLevel(
    "small", sigma=(0.02, 0.02, 0.2), spacing=(0.01, 0.01, 0.1), shape=(9, 9, 5)
)


@pytest.fixture(scope="module")
def model() -> PlanningModel:
    return PlanningModel("box", levels=(SMALL,), progress=False)


class RefusesFirst(GeometricEnvironment):
    """Raises InfeasibleWRT for the first execution asked of it, whatever the WRT."""

    refused: list[str] = []

    def execute(self, wrt: WRT, e: np.ndarray):
        if not self.refused:
            self.refused = [wrt.name]
            raise InfeasibleWRT("no continuous IK chain (test)")
        return super().execute(wrt, e)


def true_pose():
    return compose_planar(np.asarray(WORLD.nominal_pose), np.array([0.005, -0.004, 0.05]))


def test_infeasible_execution_is_blocked_and_not_counted(model):
    agent = RobustGraspAgent(model, strategy="rrg-info", horizon=1, delta=0.01, max_actions=3)
    env = RefusesFirst(model.obj, true_pose(), seed=1)
    res = run_in_process(agent, env, SMALL, WORLD.nominal_pose)
    refused = model.index(env.refused[0])
    e0 = np.asarray(WORLD.nominal_pose)
    assert agent.search.blocked == {agent.search._key(refused, e0)}
    assert not agent.search.feasible(refused, e0)
    # The run went on with another action at the same estimate, and the refusal was not counted.
    assert res.steps and res.steps[0].wrt != env.refused[0]
    first = res.steps[0]  # at w*, or for the goal grasp possibly at w* moved to its aim
    aim = (
        model.actions[model.index(first.wrt)].aim["small"] if first.kind == "goal" else np.zeros(3)
    )
    assert np.allclose(first.estimate, e0) or np.allclose(relative_planar(first.estimate, e0), aim)
    assert res.n_actions == 3 and res.steps[-1].kind == "goal"


class LosesExecutions(GeometricEnvironment):
    """Its first ``losses`` executions are lost (ExecutionLost: the safety layer stopped them
    and the hand is home), the rest run."""

    def __init__(self, *args, losses: int, **kwargs):
        super().__init__(*args, **kwargs)
        self.losses, self.lost = losses, []

    def execute(self, wrt: WRT, e: np.ndarray):
        if len(self.lost) < self.losses:
            self.lost.append(wrt.name)
            raise ExecutionLost(f"{wrt.name} stopped by the safety layer (test)")
        return super().execute(wrt, e)


def test_a_lost_execution_is_planned_again_and_three_end_the_run(model):
    """A lost execution (a stale-data stop; the hand is home, nothing observed) is not an
    action: the agent chooses again on the same belief. MAX_LOST of them end the run."""
    from rrg_planner.closed_loop import MAX_LOST

    agent = RobustGraspAgent(model, strategy="rrg-info", horizon=1, delta=0.01, max_actions=3)
    env = LosesExecutions(model.obj, true_pose(), seed=1, losses=1)
    res = run_in_process(agent, env, SMALL, WORLD.nominal_pose)
    assert len(env.lost) == 1 and not res.error
    assert res.steps[0].wrt == env.lost[0]  # the same choice on the same belief, run again
    assert res.n_actions == 3 and res.steps[-1].kind == "goal"
    agent = RobustGraspAgent(model, strategy="rrg-info", horizon=1, delta=0.01, max_actions=3)
    env = LosesExecutions(model.obj, true_pose(), seed=1, losses=MAX_LOST)
    res = run_in_process(agent, env, SMALL, WORLD.nominal_pose)
    assert len(env.lost) == MAX_LOST and res.n_actions == 0
    assert res.error.startswith(f"{MAX_LOST} executions lost") and not res.declared


def test_an_info_reading_is_spent_at_its_estimate(model):
    """The same information-gathering trajectory against an object it did not move reads
    the same: the agent does not run it again at that estimate, elsewhere it may."""
    agent = RobustGraspAgent(model, strategy="rrg-info")
    info = next(i for i, a in enumerate(model.actions) if a.kind == "info")
    goal = model.goal_actions[0]
    e0, e1 = np.asarray(WORLD.nominal_pose), np.asarray(WORLD.nominal_pose) + [0.01, 0.0, 0.0]
    assert agent.search.feasible(info, e0)
    agent.executed(goal, e0)  # a closing grasp moves the object
    assert agent.search.feasible(info, e0) and agent.search.feasible(goal, e0)
    agent.executed(info, e0)
    assert not agent.search.feasible(info, e0) and agent.search.feasible(info, e1)
    assert agent.search.blocked == set()  # not counted as an infeasible execution
    agent.search.clear()
    assert agent.search.feasible(info, e0)


def test_open_loop_runs_the_goal_once_and_max_actions_ends_with_the_goal(model):
    open_loop = run_in_process(
        RobustGraspAgent(model, strategy="open-loop"),
        GeometricEnvironment(model.obj, true_pose(), seed=2),
        SMALL,
        WORLD.nominal_pose,
    )
    assert [s.wrt for s in open_loop.steps] == ["goal"]
    # δ this small is never reached: the run ends with the goal grasp as action max_actions.
    agent = RobustGraspAgent(model, strategy="rrg-info", horizon=1, delta=1e-9, max_actions=4)
    res = run_in_process(
        agent, GeometricEnvironment(model.obj, true_pose(), seed=3), SMALL, WORLD.nominal_pose
    )
    assert res.n_actions == 4 and res.steps[-1].kind == "goal" and not res.declared


def test_goal_grasp_falls_back_to_the_most_likely_state_where_it_is_feasible(model):
    agent = RobustGraspAgent(model, strategy="rrg-goal")
    goal = model.goal_actions[0]
    belief = Belief.for_level(SMALL, WORLD.nominal_pose)
    e = belief.w_star()
    assert np.array_equal(agent.most_likely_feasible(belief, goal), e)  # feasible at w*
    agent.search.block(goal, e)  # now it is not, nor near it: the most likely state beyond is used
    alt = agent.most_likely_feasible(belief, goal)
    points = belief.grid.points()
    beyond = ~np.all(np.abs(points - e) <= np.asarray(agent.search.params.block_box) + 1e-9, axis=1)
    feasible = np.array([model.feasible(goal, p) for p in points])
    i = int(np.flatnonzero(np.all(points == alt, axis=1))[0])
    assert beyond[i] and belief.weights[i] == belief.weights[beyond & feasible].max(), (alt, e)


@pytest.mark.parametrize(
    "sigma, grasps", [((0.003, 0.003, 0.03), True), ((0.02, 0.02, 0.2), False)]
)
def test_a_goal_grasp_that_cannot_run_at_w_star_runs_beside_it_when_that_is_worth_more(
    model, sigma, grasps
):
    """The goal grasp ruled out around w*(b) and its aim: the search alone values no grasp and
    would gather information. A concentrated belief is better served by the grasp one cell
    away (P_b(G) > 1 - δ there); a broad one still gathers information."""
    agent = RobustGraspAgent(model, strategy="rrg-info", horizon=1)
    goal = model.goal_actions[0]
    agent.search = ForwardSearch(
        model, replace(SEARCH, block_box=(0.009, 0.009, 0.09))
    )  # within a cell
    belief = Belief.for_level(replace(SMALL, name="b", sigma=sigma), WORLD.nominal_pose)
    e = belief.w_star()
    agent.search.block(goal, e)
    res = agent.search.select(belief, agent.horizon)
    assert res.goal_action == -1 and res.action not in (-1, goal)
    alt = agent.most_likely_feasible(belief, goal)
    p_alt = agent.grasp_probability(belief, goal, alt)
    action, e_run, _, _ = agent.plan_step(belief, step=1)
    if grasps:
        assert p_alt > 1.0 - agent.delta and not np.allclose(alt, e)
        assert action == goal and np.array_equal(e_run, alt)
    else:
        assert p_alt < res.value and action == res.action and np.array_equal(e_run, e)


def test_an_infeasible_execution_rules_the_action_out_around_its_estimate(model):
    """Where the executor finds no continuous IK chain, nearby estimates have none either
    (SearchParams.block_box); beyond the box the feasibility map answers again."""
    agent = RobustGraspAgent(model, strategy="rrg-info")
    goal = model.goal_actions[0]
    e = np.asarray(WORLD.nominal_pose)
    box = np.asarray(agent.search.params.block_box)
    assert agent.search.feasible(goal, e + box) and agent.search.feasible(goal, e + 2 * box)
    agent.search.block(goal, e)
    assert not agent.search.feasible(goal, e + 0.9 * box)
    assert not agent.search.feasible(goal, e - 0.9 * box)
    assert agent.search.feasible(goal, e + [2 * box[0], 0.0, 0.0])
    assert agent.search.feasible(goal, e + [0.0, 0.0, 2 * box[2]])
    assert all(
        agent.search.feasible(i, e)
        for i in range(len(model.actions))
        if i != goal and model.feasible(i, e)
    )
    agent.search.clear()
    assert agent.search.feasible(goal, e)


def test_the_goal_grasp_runs_where_the_measured_closing_leaves_the_drill_best_placed():
    """The drill's closing turns it about -0.03 rad (the committed settling study), so its goal
    grasp aims at a drill turned the other way: run at w* moved by the aim, the grasp is more
    likely to succeed than at w* itself, and the agent runs it there."""
    fine = UncertaintyLevel(
        "fine", sigma=(0.005, 0.005, 0.05), spacing=(0.004, 0.004, 0.03), shape=(9, 9, 13)
    )
    drill = PlanningModel("powerdrill", levels=(fine,), progress=False, wrt_names=("goal",))
    agent = RobustGraspAgent(drill, strategy="rrg-goal")
    goal = drill.goal_actions[0]
    aim = drill.actions[goal].aim["fine"]
    assert aim[2] > 0.02
    w_star = np.asarray(WORLD.nominal_pose)
    belief = Belief.for_level(
        UncertaintyLevel(
            "tight", sigma=(0.002, 0.002, 0.05), spacing=fine.spacing, shape=fine.shape
        ),
        w_star,
    )
    e = agent.goal_estimate(belief, goal)
    np.testing.assert_allclose(relative_planar(e, w_star), aim, atol=1e-9)
    p_aimed, p_w_star = (agent.grasp_probability(belief, goal, x) for x in (e, w_star))
    assert p_aimed > p_w_star, (p_aimed, p_w_star)
    action, e_run, _, _ = agent.plan_step(belief, step=1)
    assert action == goal and np.allclose(e_run, e)


class SilentFinger3(GeometricEnvironment):
    """Every goal grasp's observation has finger 3's sensors silent (a pad that missed, or a
    finger that truly missed): the robot senses two fingers where the goal needs three."""

    def execute(self, wrt: WRT, e: np.ndarray):
        obs = super().execute(wrt, e)
        if wrt.kind == "goal":
            obs.sensors[[3, 6, 9]] = False
        return obs


def test_a_goal_grasp_whose_own_sensors_show_too_few_fingers_is_never_declared(model):
    """With verification, each such goal grasp gets P(goal) 0, the loop plans again, and the
    run ends undeclared at its last action; without it, the belief's P_b(G) declares it."""
    runs = {}
    for verify in (True, False):
        agent = RobustGraspAgent(model, strategy="rrg-info", max_actions=4, verify=verify)
        env = SilentFinger3(model.obj, true_pose(), seed=1)
        runs[verify] = run_in_process(agent, env, SMALL, WORLD.nominal_pose)
    checked = runs[True]
    goals = [s for s in checked.steps if s.kind == "goal"]
    assert not checked.declared and checked.n_actions == 4 and len(goals) >= 2
    assert all(s.p_goal == 0.0 and s.mismatches == ["2 of 3 fingers sensed"] for s in goals)
    assert all(s.p_goal_belief > 1.0 - SEARCH.delta for s in goals)
    unchecked = runs[False]
    assert unchecked.declared and unchecked.steps[-1].mismatches == []
    assert unchecked.n_actions < 4


def test_goal_grasp_mismatches_name_what_the_sensors_miss():
    from rrg_models.goal import goal_grasp_mismatches
    from rrg_models.objects import get_object

    drill = get_object("powerdrill").goal
    sensors = np.zeros(10, bool)
    sensors[[3, 6, 9]] = True  # finger 3 only
    assert goal_grasp_mismatches(True, sensors, drill) == [
        "stopped early",
        "1 of 3 fingers sensed",
        "trigger: no sensor of finger 1 or 2 fired",
    ]
    sensors[[1, 4]] = True  # and finger 1 (proximal pad, distal pad)
    assert goal_grasp_mismatches(False, sensors, drill) == ["2 of 3 fingers sensed"]
    sensors[8] = True  # and finger 2's Nano17
    assert goal_grasp_mismatches(False, sensors, drill) == []
