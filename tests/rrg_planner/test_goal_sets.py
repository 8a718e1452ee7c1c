"""An object with several goal grasps: the planner runs the one with the highest P_b(G) that
can run, names it in its decision, and the judge judges it against its own region."""

from __future__ import annotations

import numpy as np
import pytest
from goal_set_objects import box_with_goal_end

from rrg_estimator.belief import Belief
from rrg_estimator.config import UncertaintyLevel
from rrg_models.config import WORLD
from rrg_models.objects.catalogue import USER_DIR_ENV
from rrg_planner.agent import RobustGraspAgent
from rrg_planner.closed_loop import decide
from rrg_planner.geometric_env import GeometricEnvironment
from rrg_planner.planning_model import PlanningModel

SMALL = UncertaintyLevel(
    "small", sigma=(0.02, 0.02, 0.2), spacing=(0.01, 0.01, 0.1), shape=(9, 9, 5)
)


@pytest.fixture
def shoebox(tmp_path, monkeypatch):
    """The PlanningModel of a user copy of the box with a second goal grasp, at SMALL; its
    cached tables are removed after the test."""
    from rrg_onboarding.object_cli import remove_object

    folder = box_with_goal_end(tmp_path / "objects", "shoebox")
    monkeypatch.setenv(USER_DIR_ENV, str(folder.parent))
    try:
        yield PlanningModel("shoebox", levels=(SMALL,), progress=False)
    finally:
        remove_object("shoebox")


def test_the_goal_grasp_that_can_run_with_the_highest_p_goal_runs_and_is_judged(shoebox):
    model = shoebox
    goal, end = model.index("goal"), model.index("goal_end")
    assert model.goal_actions == [goal, end]
    belief = Belief.for_level(SMALL, WORLD.nominal_pose)
    e = belief.w_star()
    agent = RobustGraspAgent(model, strategy="rrg-goal")
    p = {g: agent.grasp_probability(belief, g, e) for g in (goal, end)}
    assert p[goal] > 0.2 and p[end] > 0.2, p  # σ 2 cm about a ±1.5 cm region
    best = max(p, key=p.get)
    assert agent.static_goal(belief) == (best, pytest.approx(p[best]))
    first = decide(agent, belief, 1)
    assert first.action == best and first.goal_wrt == model.names[best]

    # the better one ruled out around w*(b) (an executor found no IK chain there): the other
    other = end if best == goal else goal
    agent.search.block(best, e)
    second = decide(agent, belief, 2)
    assert second.action == other and second.goal_wrt == model.names[other]
    assert second.p_goal == pytest.approx(p[other])

    # RRG-Info's decision names the goal grasp its P(goal) is of, whatever it chose
    info = RobustGraspAgent(model, strategy="rrg-info", horizon=1)
    info.search.block(best, e)
    d = decide(info, belief, 1)
    assert d.goal_wrt == model.names[other] or d.kind == "goal" and d.goal_wrt == d.wrt

    # the judge takes the region of the goal grasp that ran
    env = GeometricEnvironment(model.obj, np.asarray(e), seed=0)
    assert env.judge(model.obj.wrt("goal_end"), e)
