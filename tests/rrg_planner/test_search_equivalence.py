"""The forward search's decisions are pinned: tests/data/search_decisions.json holds recorded
decisions on seeded beliefs (scripts/make_search_fixture.py, which also rebuilds the beliefs),
and the search must take the same action with every action valued the same (to 1e-9), and find
the same goal grasp, estimate and feasibility."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from rrg_estimator.belief import Belief
from rrg_estimator.transition import change_frame
from rrg_planner.search import ForwardSearch, SparseBelief

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location(
    "make_search_fixture", ROOT / "scripts" / "make_search_fixture.py"
)
fixture = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(fixture)

CASES = json.loads(fixture.FIXTURE.read_text())
TOL = 1e-9


def test_the_fixture_covers_what_it_should():
    kinds = {c["kind"] for c in CASES}
    assert len(CASES) >= 200
    assert kinds == set(fixture.KINDS)
    assert {c["horizon"] for c in CASES} == {1, 2, 3}
    assert len({c["delta"] for c in CASES}) >= 2
    assert {"powerdrill", "giant_teacup", "box"} <= {c["model"] for c in CASES}
    assert {"high", "low"} <= {c["level"] for c in CASES}


@pytest.fixture(scope="module")
def searches() -> dict[str, ForwardSearch]:
    """One search per model, replaying its cases in order (as an agent's search lives)."""
    return {key: ForwardSearch(fixture.build_model(key)) for key in fixture.MODELS}


@pytest.mark.parametrize("model_key", list(fixture.MODELS))
def test_decisions_are_unchanged(searches, model_key):
    search = searches[model_key]
    for case in (c for c in CASES if c["model"] == model_key):
        name = f"{model_key}/{case['level']} {case['kind']} seed {case['seed']} H={case['horizon']}"
        belief = fixture.belief_of(case, search.model)
        assert fixture.checksum(belief) == pytest.approx(case["checksum"], abs=1e-12), name
        res = search.select(belief, case["horizon"], case["delta"])
        q, expected = res.action_values, np.asarray(case["action_values"], dtype=float)
        assert np.array_equal(np.isfinite(q), np.isfinite(expected)), name
        finite = np.isfinite(q)
        assert np.all(np.abs(q[finite] - expected[finite]) <= TOL), name
        assert res.action == case["action"] or abs(res.value - case["value"]) <= TOL, name
        assert res.p_goal == pytest.approx(case["p_goal"], abs=TOL), name
        assert res.goal_action == case["goal_action"], name
        if case["goal_estimate"] is None:
            assert res.goal_estimate is None, name
        else:
            np.testing.assert_allclose(res.goal_estimate, case["goal_estimate"], atol=1e-12)
        e = belief.w_star()
        assert [search.feasible(a, e) for a in range(len(q))] == case["feasible"], name


def _moments(sb) -> tuple[np.ndarray, np.ndarray]:
    """Mean (3,) and standard deviations (3,) of a sparse belief's points."""
    mean = sb.weights @ sb.points
    d = sb.points - mean
    return mean, np.sqrt(sb.weights @ d**2)


def test_a_reading_in_another_frame_starts_from_the_estimators_blurred_belief(searches):
    """The search moves a belief to a reading's frame as the estimator does (change_frame):
    the same mean, and the spread grown by the σ between the frames; in its own frame a belief
    is left as it is."""
    search = searches["powerdrill-realistic"]
    model = search.model
    level = fixture._level(model, "low")
    held = fixture.centred(model, level, np.random.default_rng(3))
    belief = Belief(held.grid, held.weights, "info1")
    sigma = model.calibration.sigma("info1", "goal")
    assert np.all(sigma > [0.002, 0.005, 0.01])  # the frames differ by millimetres
    sb = SparseBelief.from_belief(belief, "low")
    assert search.in_frame(sb, "info1") is sb
    moved = search.in_frame(sb, "goal")
    assert moved.frame == "goal" and search.in_frame(sb, "goal") is moved
    expected = SparseBelief.from_belief(change_frame(belief, sigma, "goal"), "low")
    (m_moved, s_moved), (m_expected, s_expected) = _moments(moved), _moments(expected)
    _, s_before = _moments(sb)
    assert np.all(np.abs(m_moved - m_expected) <= [2e-4, 2e-4, 2e-3])
    np.testing.assert_allclose(s_moved, s_expected, rtol=0.05)
    assert np.all(s_moved > s_before)
    # a probe's branches are taken from the moved belief; the goal's own reading stays put
    probe, goal = model.index("goal_probe"), model.index("goal")
    assert all(child.frame == "goal" for _, child in search.expand(sb, probe))
    assert all(child.frame == "info1" for _, child in search.expand(sb, goal))
