"""The agent's loop rules: the last action is the goal grasp, open-loop runs it once, and an
execution found infeasible (nothing moved) rules that action out at that estimate without
counting as an action."""
from __future__ import annotations

import numpy as np
import pytest

from rrg_planner.agent import RobustGraspAgent, initial_belief
from rrg_planner.geometric_env import GeometricEnvironment
from rrg_planner.model import PlanningModel
from rrg_sim.config import WORLD, UncertaintyLevel
from rrg_sim.poses import compose_planar
from rrg_sim.wrt import WRT, InfeasibleWRT

SMALL = UncertaintyLevel("small", sigma=(0.02, 0.02, 0.2), spacing=(0.01, 0.01, 0.1), shape=(9, 9, 5))


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
    res = agent.run(env, SMALL, WORLD.nominal_pose)
    refused = model.index(env.refused[0])
    e0 = np.asarray(WORLD.nominal_pose)
    assert agent.search.blocked == {agent.search._key(refused, e0)}
    assert not agent.search.feasible(refused, e0)
    # The run went on with another action at the same estimate, and the refusal was not counted.
    assert res.steps and res.steps[0].wrt != env.refused[0]
    assert np.allclose(res.steps[0].estimate, e0)
    assert res.n_actions == 3 and res.steps[-1].kind == "goal"


def test_open_loop_runs_the_goal_once_and_max_actions_ends_with_the_goal(model):
    open_loop = RobustGraspAgent(model, strategy="open-loop").run(
        GeometricEnvironment(model.obj, true_pose(), seed=2), SMALL, WORLD.nominal_pose)
    assert [s.wrt for s in open_loop.steps] == ["goal"]
    # δ this small is never reached: the run ends with the goal grasp as action max_actions.
    agent = RobustGraspAgent(model, strategy="rrg-info", horizon=1, delta=1e-9, max_actions=4)
    res = agent.run(GeometricEnvironment(model.obj, true_pose(), seed=3), SMALL, WORLD.nominal_pose)
    assert res.n_actions == 4 and res.steps[-1].kind == "goal" and not res.declared


def test_goal_grasp_falls_back_to_the_most_likely_state_where_it_is_feasible(model):
    agent = RobustGraspAgent(model, strategy="rrg-goal")
    belief = initial_belief(SMALL, WORLD.nominal_pose)
    e = belief.w_star()
    assert np.array_equal(agent.most_likely_feasible(belief, agent.goal), e)  # feasible at w*
    agent.search.block(agent.goal, e)  # now it is not: the next most likely state is used
    alt = agent.most_likely_feasible(belief, agent.goal)
    points = belief.grid.points()
    i = int(np.flatnonzero(np.all(points == alt, axis=1))[0])
    assert not np.array_equal(alt, e) and belief.weights[i] == np.sort(belief.weights)[-2]
