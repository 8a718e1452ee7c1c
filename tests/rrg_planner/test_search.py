"""Forward search: the fast implementation agrees with the naive reference; clustering,
merging and the static evaluation behave as the paper describes."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from rrg_estimator.belief import Belief
from rrg_estimator.config import UncertaintyLevel
from rrg_estimator.grid import Grid
from rrg_estimator.update import goal_probability, update
from rrg_models.config import WORLD
from rrg_models.poses import compose_planar, relative_planar
from rrg_planner import reference_search, search_kernels
from rrg_planner import search as search_module
from rrg_planner.clustering import PROGRESS_BIN
from rrg_planner.config import SEARCH
from rrg_planner.planning_model import PlanningModel
from rrg_planner.reference_search import ReferenceSearch
from rrg_planner.search import ForwardSearch, SparseBelief, merge_branches
from rrg_sim.geometric_sim import GeometricSimulator

SMALL = UncertaintyLevel(
    "small", sigma=(0.02, 0.02, 0.2), spacing=(0.01, 0.01, 0.1), shape=(9, 9, 5)
)
EXACT = dataclasses.replace(SEARCH, support_rel=0.0)


@pytest.fixture(scope="module")
def model() -> PlanningModel:
    return PlanningModel("box", levels=(SMALL,), progress=False)


@pytest.fixture(scope="module")
def beliefs(model):
    """The initial belief and a posterior after one simulated goal grasp (seeded)."""
    mean = np.asarray(WORLD.nominal_pose)
    b0 = Belief.for_level(SMALL, mean)
    goal = model.actions[model.goal_actions[0]]
    true = compose_planar(mean, np.array([0.015, -0.01, 0.1]))
    obs = GeometricSimulator(model.obj, goal.wrt).simulate(true, mean)
    return [b0, update(b0, goal.tables["small"], mean, obs)]


def assert_same_choice(f, r) -> None:
    """The fast search's result f and the reference's r choose alike: the same action, the
    same feasible actions, their values within the float32 tables' rounding, the same v(b)."""
    assert f.action == r.action
    assert np.array_equal(np.isfinite(f.action_values), np.isfinite(r.action_values))
    ok = np.isfinite(f.action_values)
    np.testing.assert_allclose(
        f.action_values[ok], r.action_values[ok], rtol=1e-4, atol=1e-6
    )  # float32 table index and moments
    assert f.p_goal == pytest.approx(r.p_goal, abs=1e-9)


@pytest.mark.parametrize("horizon", [1, 2])
@pytest.mark.parametrize("params", [EXACT, SEARCH], ids=["full-support", "default-support"])
@pytest.mark.parametrize("delta", [SEARCH.delta, 0.5])
def test_fast_search_matches_reference(model, beliefs, horizon, params, delta):
    fast, ref = ForwardSearch(model, params), ReferenceSearch(model, params)
    for b in beliefs:
        assert_same_choice(fast.select(b, horizon, delta), ref.select(b, horizon, delta))


def _noisy(belief: Belief, rng: np.random.Generator) -> Belief:
    """The belief's weights times seeded noise in [0.8, 1.2] (no exact ties), renormalized."""
    w = belief.weights * rng.uniform(0.8, 1.2, belief.weights.size)
    return Belief(belief.grid, w / w.sum())


def off_centre_belief(rng: np.random.Generator) -> Belief:
    """A Gaussian whose mean lies 1.5-3 cells off the grid's centre in x, y and θ."""
    mean = np.asarray(WORLD.nominal_pose)
    offset = rng.uniform(1.5, 3.0, 3) * rng.choice([-1.0, 1.0], 3) * np.asarray(SMALL.spacing)
    grid = Grid.for_level(SMALL, center=mean)
    return _noisy(Belief.gaussian(grid, compose_planar(mean, offset), (0.012, 0.015, 0.12)), rng)


def two_peaked_belief(rng: np.random.Generator) -> Belief:
    """Two narrow Gaussians on opposite sides of the grid's centre (weights 0.55 and 0.45)."""
    mean = np.asarray(WORLD.nominal_pose)
    grid = Grid.for_level(SMALL, center=mean)
    d = rng.uniform(1.5, 2.5, 3) * np.asarray(SMALL.spacing)
    peaks = [
        Belief.gaussian(grid, compose_planar(mean, s * d), (0.008, 0.008, 0.08)).weights
        for s in (1.0, -1.0)
    ]
    return _noisy(Belief(grid, 0.55 * peaks[0] + 0.45 * peaks[1]), rng)


def edge_of_grid_belief(rng: np.random.Generator) -> Belief:
    """A Gaussian centred on a corner of the grid (x and y at their last points)."""
    mean = np.asarray(WORLD.nominal_pose)
    grid = Grid.for_level(SMALL, center=mean)
    corner = np.array([4.0, 4.0, -1.0]) * np.asarray(SMALL.spacing)
    return _noisy(Belief.gaussian(grid, compose_planar(mean, corner), (0.01, 0.01, 0.1)), rng)


H3_BELIEFS = {
    "off-centre": off_centre_belief,
    "two-peaked": two_peaked_belief,
    "edge-of-grid": edge_of_grid_belief,
}


@pytest.mark.parametrize("params", [EXACT, SEARCH], ids=["full-support", "default-support"])
@pytest.mark.parametrize("kind", list(H3_BELIEFS))
def test_fast_search_matches_reference_at_horizon_3(model, kind, params):
    """Beliefs the centred ones above do not cover (seeded), three levels deep."""
    belief = H3_BELIEFS[kind](np.random.default_rng(17))
    cells = (belief.grid.points() - np.asarray(belief.grid.center)) / np.asarray(SMALL.spacing)
    w_star = cells[np.argmax(belief.weights)]
    if kind == "off-centre":
        assert np.all(np.abs(belief.weights @ cells) >= 1.0)  # the mean a cell or more off
    elif kind == "two-peaked":
        assert np.all(np.abs(w_star) >= 1.5)
        other_side = np.sign(cells[:, 0]) == -np.sign(w_star[0])
        assert belief.weights[other_side].sum() > 0.3
    else:
        assert np.all(np.rint(np.abs(w_star[:2])) == 4)  # on the border in x and y
    r = ReferenceSearch(model, params).select(belief, 3, SEARCH.delta)
    assert np.isfinite(r.action_values).sum() >= 3
    assert_same_choice(ForwardSearch(model, params).select(belief, 3, SEARCH.delta), r)


def test_static_value_is_goal_probability_at_w_star(model, beliefs):
    g = model.goal_actions[0]
    for b in beliefs:
        e = b.w_star()
        assert model.feasible(g, e)
        sb = SparseBelief.from_belief(b, "small", EXACT)
        v = ForwardSearch(model, EXACT).static_value(sb)
        assert v == pytest.approx(goal_probability(b, model.actions[g].goal["small"], e), abs=1e-9)


def test_clusters_prune_small_groups_and_keep_most_mass(model):
    for act in model.actions:
        cl = act.clusters["small"]
        assert cl.count >= 1
        assert np.all(cl.prior >= SEARCH.offline_prune)
        assert np.all(np.diff(cl.prior) <= 0)  # sorted by prior
        assert cl.prior.sum() >= 0.8  # pruning drops little mass
        assert np.all(cl.assign[cl.representatives] == np.arange(cl.count))
        # Each canonical observation is nearly most likely at its own entry: exactly, unless
        # the entry lies where a sensor's predicted contact changes and so counts less (the
        # box's lowest ratio to the best entry is 0.58).
        best = cl.likelihood.max(axis=1)
        assert np.all(cl.likelihood[np.arange(cl.count), cl.representatives] >= 0.5 * best)


def test_the_goal_grasps_clusters_are_not_split_by_the_closures_it_ignores(model):
    """The goal WRT's closures are left out of its likelihood (WRT.closure_informative), so
    two of its canonical observations never differ in closure alone; an info WRT's do."""

    def signatures(act):
        t, reps = act.tables["small"], act.clusters["small"].representatives
        progress_bins = np.rint(t.progress[reps] / PROGRESS_BIN).astype(int)
        return {
            (bool(t.contact[r]), t.sensors[r].tobytes(), b) for r, b in zip(reps, progress_bins)
        }, len(reps)

    goal = model.actions[model.goal_actions[0]]
    assert not goal.wrt.closure_informative
    distinct, count = signatures(goal)
    assert len(distinct) == count
    assert any(
        len(signatures(a)[0]) < signatures(a)[1] for a in model.actions if a.wrt.closure_informative
    )


def test_branches_are_normalized_and_informative(model, beliefs):
    search = ForwardSearch(model)
    sb = SparseBelief.from_belief(beliefs[0], "small")
    for a in range(len(model.actions)):
        branches = search.expand(sb, a)
        assert branches, model.names[a]
        assert sum(p for p, _ in branches) == pytest.approx(1.0)
        for _, child in branches:
            assert child.weights.sum() == pytest.approx(1.0)
            assert np.all(child.weights >= 0)


def test_merge_combines_similar_posteriors_and_keeps_half_the_mass():
    probs = np.array([0.4, 0.3, 0.2, 0.1])
    ent = np.array([2.0, 2.01, 3.0, 1.0])
    cov = np.stack([np.eye(3), np.eye(3) * 1.01, np.eye(3) * 3.0, np.eye(3) * 0.3])
    kept = merge_branches(probs, ent, cov)
    # Branches 0 and 1 merge (0.7 ≥ 50 %): one branch survives, renormalized.
    assert kept == [(0, 1.0)]
    kept = merge_branches(probs, np.array([1.0, 2.0, 3.0, 4.0]), cov)
    assert [k for k, _ in kept] == [0, 1]
    assert sum(p for _, p in kept) == pytest.approx(1.0)


def test_select_rejects_bad_horizon_and_delta(model, beliefs):
    with pytest.raises(ValueError, match="horizon"):
        ForwardSearch(model).select(beliefs[0], 4)
    for delta in (0.0, 1.0, float("nan")):
        with pytest.raises(ValueError, match="delta"):
            ForwardSearch(model).select(beliefs[0], 2, delta)


@pytest.mark.parametrize("search_cls", [ForwardSearch, ReferenceSearch])
def test_a_goal_grasp_the_agent_would_declare_ends_its_branch(model, search_cls):
    """Where every reading of the goal grasp leaves P_b(G) > 1 − δ, the run stops there: the
    grasp is worth its P_b(G) less one action's cost (cost_per_delta · δ), at any horizon. On
    a broader belief, where it is not declared, deeper search finds more to do after it."""
    mean = np.asarray(WORLD.nominal_pose)
    g, delta = model.goal_actions[0], 0.5
    sharp = Belief.gaussian(
        Grid.for_level(SMALL, center=mean), mean, np.array([0.004, 0.004, 0.04])
    )
    search = search_cls(model, EXACT)
    q1, q2 = (search.select(sharp, h, delta) for h in (1, 2))
    assert q1.p_goal > 1 - delta
    assert q1.action_values[g] == pytest.approx(q1.p_goal - SEARCH.cost_per_delta * delta, abs=0.01)
    assert q2.action_values[g] == pytest.approx(q1.action_values[g], abs=1e-9)
    broad = Belief.gaussian(Grid.for_level(SMALL, center=mean), mean, np.array([0.01, 0.01, 0.1]))
    q1, q2 = (search.select(broad, h, 1e-3).action_values[g] for h in (1, 2))
    assert q2 > q1 + 0.03


def test_the_reference_shares_the_fast_searchs_constants():
    """reference_search keeps its own copies (it shares no code with search.py)."""
    assert reference_search.TIE_RTOL == search_module.TIE_RTOL
    assert reference_search.TIE_DECIMALS == search_module.TIE_DECIMALS
    assert reference_search.BLUR_NODES == search_module.BLUR_NODES


def test_merging_agrees_with_the_reference():
    """search.merge_branches (compiled) and the reference's Python loops, on seeded branches
    whose entropies and covariances straddle the merge tolerances."""
    rng = np.random.default_rng(11)
    for _ in range(200):
        k = int(rng.integers(1, 12))
        probs = rng.dirichlet(np.ones(k))
        ent = rng.uniform(1.0, 1.6, k)
        a = rng.normal(size=(k, 3, 3)) * 0.1 + np.eye(3)
        covs = a @ a.transpose(0, 2, 1) * rng.uniform(0.8, 1.2, (k, 1, 1))
        fast = merge_branches(probs, ent, covs)
        slow = reference_search.merge_branches(probs, ent, covs)
        assert [i for i, _ in fast] == [i for i, _ in slow]
        np.testing.assert_allclose([p for _, p in fast], [p for _, p in slow], rtol=1e-12)


@pytest.mark.parametrize("shape", [(5,), (130,), (1000,), (54321,)])
def test_kernel_sums_are_numpys(shape):
    """The compiled pairwise sum and the cluster masses are NumPy's to the bit (the search's
    values depend on it)."""
    rng = np.random.default_rng(3)
    w = rng.random(shape) * 10.0 ** rng.integers(-9, 1, shape)
    assert search_kernels.pairwise_sum(w) == w.sum()
    assign = rng.integers(-1, 7, 2 * shape[0])
    idx = rng.integers(0, 2 * shape[0], shape[0])
    cl = assign[idx]
    expected = np.bincount(cl[cl >= 0], weights=w[cl >= 0], minlength=7)
    assert np.array_equal(search_kernels.cluster_mass(assign, idx, w, 7), expected)


def test_kernel_tie_order_is_numpys_rounded_stable_sort():
    """Branch probabilities that tie to TIE_DECIMALS (as a symmetric object's mirror branches
    do, to the last bits) are ordered by index, as np.argsort of np.round ordered them."""
    rng = np.random.default_rng(5)
    scale = 10.0**search_module.TIE_DECIMALS
    for _ in range(500):
        base = rng.dirichlet(np.ones(8))
        probs = np.concatenate([base, base[::-1] * (1 + rng.normal(0, 1e-14, 8))])
        expected = np.argsort(-np.round(probs, search_module.TIE_DECIMALS), kind="stable")
        assert np.array_equal(search_kernels.most_probable_first(probs, scale), expected)


def test_aimed_estimates_are_compose_planars():
    """The goal's aimed estimate and its duplicate test, on scalars, are compose_planar's and
    np.allclose's to the bit (goal_estimates feeds the feasibility memo by the exact bytes)."""
    rng = np.random.default_rng(8)
    for k in range(2000):
        e = np.array([0.62, 0.0, 0.0]) + rng.normal(0, [0.05, 0.05, 2.0])
        if k % 3 == 0:
            e[2] = 0.1 * rng.integers(-35, 35)  # a grid θ, wrapping past ±π
        d = relative_planar(rng.normal(0, [0.01, 0.01, 0.1]), np.zeros(3))
        aimed = search_module._compose(e, tuple(float(v) for v in d))
        assert aimed.tobytes() == compose_planar(e, d).tobytes()
        other = aimed + rng.normal(0, 1e-8, 3) * rng.choice([0.0, 1.0, 1e3], 3)
        assert search_module._close(aimed, other) == np.allclose(aimed, other)


def test_table_index_is_the_grids_nearest_index(beliefs):
    """The compiled table index is Grid.nearest_index of each offset from the estimate
    (float32 rounding aside: offsets off the cell boundaries)."""
    b = beliefs[1]
    e = b.w_star() + np.array([0.003, -0.002, 0.03])
    grid = Grid((0.0, 0.0, 0.0), b.grid.spacing, b.grid.shape)
    idx = search_module.table_index(b.grid.points(), e, grid)
    expected = grid.nearest_index(relative_planar(e, b.grid.points()))
    assert np.mean(idx == expected) > 0.999


#: θ steps of 0.08 rad: the teacup's aim is a whole step (on SMALL's 0.1 rad it is a half step,
#: where the fast search's float32 table index and the reference's float64 one may tie-break apart)
TURNS = UncertaintyLevel(
    "turns", sigma=(0.02, 0.02, 0.2), spacing=(0.01, 0.01, 0.08), shape=(9, 9, 7)
)


@pytest.fixture(scope="module")
def teacup_model() -> PlanningModel:
    return PlanningModel(
        "giant_teacup",
        levels=(TURNS,),
        progress=False,
        wrt_names=("goal", "info_handle", "reorient_ccw", "reorient_cw"),
    )


@pytest.mark.parametrize("horizon", [1, 2])
def test_fast_search_matches_reference_through_reorientations(teacup_model, horizon):
    """The teacup's reorientations, with their measured outcomes and their spread in θ, are
    valued alike by both searches, and a turn costs localization: the spread child is wider."""
    anywhere = dataclasses.replace(EXACT, reorient_min_in_box=0.0)
    fast, ref = ForwardSearch(teacup_model, anywhere), ReferenceSearch(teacup_model, anywhere)
    b0 = Belief.for_level(TURNS, np.asarray(WORLD.nominal_pose))
    f, r = fast.select(b0, horizon), ref.select(b0, horizon)
    turns = [i for i, a in enumerate(teacup_model.actions) if a.kind == "reorient"]
    assert np.isfinite(f.action_values[turns]).all()
    np.testing.assert_allclose(f.action_values, r.action_values, rtol=1e-4, atol=1e-6)
    e = b0.w_star()
    point = np.array([e])
    sharp, _ = search_module.reorient_mixture(point, np.ones(1), e, 0.6, blur=0.0)
    spread, w = search_module.reorient_mixture(point, np.ones(1), e, 0.6, blur=0.04)
    assert len(spread) == 3 * len(sharp) and w.sum() == pytest.approx(1.0)
    full = np.abs(spread[:, 2] - sharp[0, 2]) < 0.1  # the full turn's three nodes
    assert np.sqrt(w[full] @ (spread[full, 2] - sharp[0, 2]) ** 2 / w[full].sum()) == pytest.approx(
        0.04
    )


@pytest.mark.parametrize("search_cls", [ForwardSearch, ReferenceSearch])
def test_a_reorientation_runs_only_where_its_turn_is_measured(teacup_model, search_cls):
    """SearchParams.reorient_min_in_box: the reorientations are ruled out while less of the
    belief than that lies in their measured outcome's box about w*, and valued once enough does."""
    b0 = Belief.for_level(TURNS, np.asarray(WORLD.nominal_pose))
    turns = [i for i, a in enumerate(teacup_model.actions) if a.kind == "reorient"]
    box = teacup_model.actions[turns[0]].wrt.reorient_outcome.box
    inside = np.all(np.abs(b0.grid.points() - b0.w_star()) <= box, axis=1)
    p_inside = float(b0.weights[inside].sum())
    for threshold, allowed in ((p_inside + 0.01, False), (p_inside - 0.01, True)):
        q = (
            search_cls(teacup_model, dataclasses.replace(EXACT, reorient_min_in_box=threshold))
            .select(b0, 1)
            .action_values
        )
        assert np.isfinite(q[turns]).all() == allowed
        assert np.isfinite(q[[i for i in range(len(q)) if i not in turns]]).any()
