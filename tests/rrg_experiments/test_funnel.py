"""The funnel analysis: the model's expected values after single information WRTs and pairs,
the funnels it finds, and the trials' first-action statistics."""

from __future__ import annotations

import pytest

from rrg_experiments.funnel import funnels, markdown, model_funnel, trial_funnel


def test_funnels_are_pairs_where_the_second_grasp_gains_more_after_the_first():
    view = dict(
        v0=0.1,
        single=dict(info1=0.3, info2=0.2),
        pair=dict(info1=dict(info1=0.3, info2=0.35), info2=dict(info1=0.6, info2=0.2)),
        q={},
    )
    # info1 gains 0.4 after info2 (0.6 - 0.2) but 0.2 first (0.3 - 0.1): a funnel;
    # info2 gains 0.05 after info1 and 0.1 first: none.
    assert funnels(view) == [("info2", "info1", pytest.approx(0.4), pytest.approx(0.2))]
    text = markdown(view, None, "powerdrill", "high")
    assert "info2 funnels info1" in text and "| info2 | 0.200 | 0.600 | 0.200 |" in text


def test_trial_funnel_groups_a_cells_trials_by_their_first_two_actions():
    base = dict(object="powerdrill", level="high", strategy="rrg-info")
    records = [
        dict(base, cell="c", actions=["info2", "info1", "goal"], success=True, n_actions=3),
        dict(
            base, cell="c", actions=["info2", "info1", "goal", "goal"], success=False, n_actions=4
        ),
        dict(base, cell="c", actions=["sweep", "goal"], success=True, n_actions=2),
        dict(base, cell="d", actions=["goal"], success=True, n_actions=1, strategy="rrg-goal"),
    ]
    t = trial_funnel(records)
    assert list(t) == ["c"]
    assert t["c"]["info2→info1"] == dict(trials=2, successes=1, mean_actions=3.5)
    assert t["c"]["sweep→goal"]["trials"] == 1


@pytest.mark.slow  # loads a planning model
def test_the_models_view_expands_every_information_wrt_from_the_initial_belief():
    from rrg_planner.planning_model import PlanningModel

    model = PlanningModel("box", levels=("low",), progress=False)
    view = model_funnel(model, "low", deltas=(0.1,))
    info = [a.wrt.name for a in model.actions if a.kind == "info"]
    assert sorted(view["single"]) == sorted(info) and 0.0 <= view["v0"] <= 1.0
    for a in info:
        assert 0.0 <= view["single"][a] <= 1.0
        assert sorted(view["pair"][a]) == sorted(info)
    assert set(view["q"]["0.1"]) == {"H1", "H2"}
