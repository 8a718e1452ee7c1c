"""Observation model and belief update, checked against the naive reference on small grids.

The observation tables come from a synthetic, ObservationTable-shaped probe whose predicted
observation varies smoothly with the offset Δ, so likelihoods are informative in x, y and θ.
"""

import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import pytest
from synthetic_tables import synthetic_table

from rrg_estimator.belief import Belief
from rrg_estimator.config import HIGH, LIKELIHOOD, LOW, likelihood_without
from rrg_estimator.grid import Grid
from rrg_estimator.obs_model import (
    ObsFeatures,
    closure_sigma,
    features_from_observation,
    features_from_table_rows,
    likelihood_over_table,
    likelihood_params,
    log_likelihood_over_table,
    sensor_prediction,
    table_index_axes,
    table_indices,
)
from rrg_estimator.obs_tables import ObservationTable
from rrg_estimator.reference_update import table_index_reference, update_reference
from rrg_estimator.update import apply_likelihood, goal_probability, update
from rrg_models.observation import Observation
from rrg_models.poses import compose_planar, planar_pose, relative_planar
from rrg_models.wrt import WRT

E = np.array([0.62, 0.01, 0.3])


def observation_of_row(table: ObservationTable, row: int, e) -> Observation:
    """The Observation the robot would report for table row `row` when τ(e) ran (motion in
    world)."""
    m = table.motion_dir[row].astype(float)
    c, s = math.cos(e[2]), math.sin(e[2])
    return Observation(
        contact=bool(table.contact[row]),
        progress=float(table.progress[row]),
        hand_pose=planar_pose(e),
        sensors=table.sensors[row],
        closure=table.closure[row],
        tip_points=table.tip_points[row],
        motion_dir=[c * m[0] - s * m[1], s * m[0] + c * m[1], m[2]],
    )


@pytest.fixture(scope="module")
def high_table() -> ObservationTable:
    return synthetic_table(Grid.for_level(HIGH))


# ----------------------------------------------------------------- table indices
@pytest.mark.parametrize(
    "level,e",
    [
        (HIGH, E),
        (HIGH, (0.55, -0.04, -2.9)),
        (LOW, (0.6, 0.0, 3.1)),
        (LOW, (0.631, 0.0123, 0.0071)),
    ],
)
def test_table_indices_match_a_per_point_computation(level, e):
    belief_grid = Grid.for_level(level, center=np.asarray(e) + [0.004, -0.011, 0.05])
    table_grid = Grid.for_level(level)
    expected = table_grid.nearest_index(
        relative_planar(np.asarray(e), belief_grid.points()), clip=True
    )
    np.testing.assert_array_equal(table_indices(belief_grid, e, table_grid), expected)


# ------------------------------------------------------------------- likelihood
def test_likelihood_terms(high_table):
    t = high_table
    row = int(np.flatnonzero(t.contact & t.sensors[:, 7] & t.sensors[:, 9])[0])
    f = features_from_table_rows(t, [row])
    base = log_likelihood_over_table(t, f)[0]
    lp = LIKELIHOOD
    q = sensor_prediction(t)[row]  # each sensor's predicted contact within the row's cell
    p_fired = q * lp.p_detect + (1 - q) * lp.p_false_alarm
    expected = math.log(1 - lp.p_contact_mismatch) + sum(
        math.log(p if s else 1 - p) for s, p in zip(t.sensors[row], p_fired)
    )
    assert base[row] == pytest.approx(expected, abs=1e-5)
    assert np.argmax(base) == row

    def change(field: str, index, value) -> float:
        """log L at the row's own entry after setting one feature value, minus the exact-match
        log L."""
        g = features_from_table_rows(t, [row])
        getattr(g, field)[(0, *np.atleast_1d(index))] = value
        return float(log_likelihood_over_table(t, g)[0, row] - base[row])

    assert change("progress", (), f.progress[0] + lp.sigma_progress) == pytest.approx(
        -0.5, abs=1e-4
    )
    sigma = float(closure_sigma(t, lp.sigma_closure)[1, row])  # the entry's own σ, ≥ the base σ
    assert sigma >= lp.sigma_closure
    assert change("closure", 1, f.closure[0, 1] + sigma) == pytest.approx(-0.5, abs=1e-4)
    assert change("tip_points", (2, 2), f.tip_points[0, 2, 2] + 2 * lp.sigma_tip) == pytest.approx(
        -2.0, abs=1e-3
    )
    # a tip point missing on one side adds no distance term (its sensor term judges it)
    assert change("tip_points", 2, np.nan) == pytest.approx(0.0, abs=1e-6)
    assert not t.sensors[row, 5] and t.sensors[row, 7]
    assert change("sensors", 5, True) == pytest.approx(
        math.log(p_fired[5] / (1 - p_fired[5])), abs=1e-5
    )
    assert change("sensors", 7, False) == pytest.approx(
        math.log((1 - p_fired[7]) / p_fired[7]), abs=1e-5
    )
    mismatch = math.log(lp.p_contact_mismatch / (1 - lp.p_contact_mismatch))
    assert change("contact", (), False) == pytest.approx(mismatch, abs=1e-5)


def test_closure_sigma_adds_each_entrys_discretization():
    """A closure that changes by 0.12 rad per cell along x (and not along y or θ) is known
    only to ± half a cell at the nearest entry: σ² = σ₀² + 0.12²/12 there; where it is flat,
    σ₀; a jump (a finger that misses) makes the closure uninformative around it; an ignored
    closure (σ₀ = ∞) stays ignored. The per-state reference computes the same."""
    from rrg_estimator.reference_update import closure_sigma_reference

    class Table:  # the two fields closure_sigma reads
        def __init__(self, grid: Grid, closure: np.ndarray):
            self.grid, self.closure = grid, closure

    grid = Grid((0.0, 0.0, 0.0), (0.01, 0.01, 0.1), (5, 3, 3))
    ix = np.arange(grid.size) // 9  # x index of each flat entry
    closure = np.zeros((grid.size, 3), np.float32)
    closure[:, 0] = 0.12 * ix  # finger 1: a ramp along x
    closure[:, 2] = np.where(ix >= 3, 2.4, 0.3)  # finger 3: a jump between x indices 2 and 3
    table = Table(grid, closure)
    sig = closure_sigma(table, 0.05)
    assert sig.shape == (3, grid.size) and sig.dtype == np.float32
    np.testing.assert_allclose(sig[0], math.sqrt(0.05**2 + 0.12**2 / 12), rtol=1e-5)
    np.testing.assert_allclose(sig[1], 0.05, rtol=1e-6)
    assert np.all(sig[2][(ix == 2) | (ix == 3)] > 0.6) and np.allclose(sig[2][ix == 0], 0.05)
    for j in (0, 13, 22, 44):
        for f in range(3):
            assert closure_sigma_reference(table, j, f, 0.05) == pytest.approx(
                float(sig[f, j]), rel=1e-5
            )
    assert np.all(np.isinf(closure_sigma(table, math.inf)))


def test_a_finger_the_table_stops_on_a_sensor_the_robot_lacks_has_no_closure_term():
    """Without proximal pads, an entry whose finger stopped on its proximal pad alone (its
    distal pad and Nano17 silent) predicts nothing of that finger's closure: the robot's
    finger closes on. A finger whose Nano17 fired too, and the other fingers, keep their σ;
    with every sensor read, nothing changes."""

    class Table:  # the fields closure_sigma reads
        def __init__(self, grid: Grid, closure: np.ndarray, sensors: np.ndarray):
            self.grid, self.closure, self.sensors = grid, closure, sensors

    grid = Grid((0.0, 0.0, 0.0), (0.01, 0.01, 0.1), (3, 3, 3))
    closure = np.full((grid.size, 3), 1.0, np.float32)
    sensors = np.zeros((grid.size, 10), bool)
    sensors[:9, 2] = True  # prox2 at x index 0
    sensors[:3, 8] = True  # ... with tip2 at y index 0 of those
    table = Table(grid, closure, sensors)
    unsensed = likelihood_without(["prox1", "prox2", "prox3"]).unsensed
    sig = closure_sigma(table, 0.05, unsensed)
    assert np.all(np.isinf(sig[1, 3:9])) and np.all(np.isfinite(sig[1, :3]))
    np.testing.assert_allclose(sig[1, 9:], 0.05)
    np.testing.assert_allclose(sig[[0, 2]], 0.05)
    np.testing.assert_allclose(closure_sigma(table, 0.05), 0.05)
    from rrg_estimator.reference_update import closure_sigma_reference

    for j in (0, 4, 13):
        assert closure_sigma_reference(table, j, 1, 0.05, unsensed) == pytest.approx(
            float(sig[1, j]), rel=1e-6
        )


def test_a_sensors_predicted_contact_stands_for_the_entrys_cell():
    """A sensor predicted from x index 3 on (not along y or θ) is predicted in 1/8 of the cells
    of index 2 and 7/8 of those of index 3 (its switch lies anywhere between the two points),
    certainly elsewhere; a flag on one grid point alone (a finger grazing one facet) counts
    (3/4)³ there. The per-state reference computes the same; the edges count their own flag."""
    from rrg_estimator.reference_update import sensor_prediction_reference

    class Table:  # the two fields sensor_prediction reads
        def __init__(self, grid: Grid, sensors: np.ndarray):
            self.grid, self.sensors = grid, sensors

    grid = Grid((0.0, 0.0, 0.0), (0.01, 0.01, 0.1), (5, 3, 3))
    ix = np.arange(grid.size) // 9
    sensors = np.zeros((grid.size, 10), bool)
    sensors[:, 0] = ix >= 3
    sensors[13, 4] = True  # the centre entry (2, 1, 1) alone
    table = Table(grid, sensors)
    q = sensor_prediction(table)
    expected = np.array([0.0, 0.0, 0.125, 0.875, 1.0])[ix]
    np.testing.assert_allclose(q[:, 0], expected, atol=1e-12)
    assert q[13, 4] == pytest.approx(0.75**3) and q[:, 4].sum() == pytest.approx(1.0)
    np.testing.assert_array_equal(q[:, 1], 0.0)
    for j in (0, 13, 22, 44):
        for s in (0, 4):
            assert sensor_prediction_reference(table, j, s) == pytest.approx(
                float(q[j, s]), abs=1e-12
            )


def test_likelihood_is_floored_batched_and_float32(high_table):
    rows = [0, 5000, 12012, 20000]
    feats = features_from_table_rows(high_table, rows)
    like = likelihood_over_table(high_table, feats)
    assert like.dtype == np.float32 and like.shape == (4, high_table.grid.size)
    assert like.min() >= np.float32(LIKELIHOOD.floor) and like.max() <= 1.0
    for i, r in enumerate(rows):
        # the sensor terms are summed in a fixed order: a reading's likelihood is the same
        # to the bit batched or alone (a BLAS product's order changes with the batch's shape)
        np.testing.assert_array_equal(like[i], likelihood_over_table(high_table, feats.take(i))[0])
        assert (
            like[i, r] == like[i].max()
        )  # its own offset explains it best (ties: the same reading)


def assert_left_out(table, prior: Belief, params, feats, other) -> list[np.ndarray]:
    """Two readings that differ in one term update ``prior`` alike under ``params`` (the term
    is left out) and differently under the default parameters; the two posteriors' weights."""
    left_out = [
        update(prior, table, E, f, transition=False, params=params).weights for f in (feats, other)
    ]
    np.testing.assert_array_equal(left_out[0], left_out[1])
    used = update(prior, table, E, other, transition=False).weights
    assert np.abs(used - left_out[1]).max() > 1e-3 * left_out[1].max()
    return left_out


def test_a_wrt_whose_closures_are_not_informative_is_updated_without_them(high_table):
    """A firm goal grasp drags the object as it closes (WRT.closure_informative False): its
    closure angles must not move the belief, while every other term still does."""
    poses = np.tile(np.eye(4), (2, 1, 1))
    assert likelihood_params(WRT("probe", "info", poses)) is LIKELIHOOD
    params = likelihood_params(WRT("drag", "goal", poses, closure_informative=False))
    row = high_table.grid.nearest_index(np.array([0.0, 0.02, 0.3]))
    feats = features_from_table_rows(high_table, [row])
    other = features_from_table_rows(high_table, [row])
    other.closure[0] += np.float32(0.4)
    prior = Belief.for_level(HIGH, E)
    ignored = assert_left_out(high_table, prior, params, feats, other)
    # the sensors still speak: sensor 1 fired (Δy > 1 cm), so the states at Δy < -1 cm lose
    # most of their prior mass
    far = relative_planar(E, prior.grid.points())[:, 1] < -0.01
    assert ignored[0][far].sum() < 0.25 * prior.weights[far].sum()


def test_an_unsensed_sensor_does_not_move_the_belief(high_table):
    """A robot without a reading of sensor 1 (likelihood_without): its silence, where the table
    predicts it fires, leaves the belief as if it had fired; the other sensors still speak."""
    from rrg_estimator.config import likelihood_without
    from rrg_models.config import SENSOR_NAMES
    from rrg_planner.clustering import signature_keys

    params = likelihood_without([SENSOR_NAMES[1]])
    assert params.unsensed == (1,)
    with pytest.raises(ValueError, match="unknown sensors"):
        likelihood_without(["elbow"])
    row = high_table.grid.nearest_index(np.array([0.0, 0.03, 0.3]))  # sensor 1 fires there
    fired = features_from_table_rows(high_table, [row])
    assert fired.sensors[0, 1]
    silent = features_from_table_rows(high_table, [row])
    silent.sensors[0, 1] = False
    assert_left_out(high_table, Belief.for_level(HIGH, E), params, fired, silent)
    # the planner's clusters do not split on it either: two entries that differ in sensor 1
    pair = SimpleNamespace(
        contact=np.zeros(2, bool),
        sensors=np.zeros((2, 10), bool),
        progress=np.zeros(2),
        closure=np.zeros((2, 3)),
    )
    pair.sensors[0, 1] = True
    assert len(set(signature_keys(pair))) == 2
    assert len(set(signature_keys(pair, unsensed=(1,)))) == 1


# ------------------------------------------------------------------------ update
def test_update_is_normalized_and_keeps_the_floor(high_table):
    prior = Belief.for_level(HIGH, E)
    row = high_table.grid.nearest_index(np.array([0.03, -0.02, 0.3]))
    feats = features_from_table_rows(high_table, [row])
    post = update(prior, high_table, E, feats, transition=False)
    assert abs(post.weights.sum() - 1.0) < 1e-9
    like = likelihood_over_table(high_table, feats)[0][
        table_indices(prior.grid, E, high_table.grid)
    ]
    z = float(prior.weights @ like.astype(float))
    # every state keeps at least ε of its prior weight (relative to the evidence Z)
    assert np.all(post.weights >= LIKELIHOOD.floor * prior.weights / z * (1 - 1e-5))
    # a state whose prediction contradicts the observation keeps exactly that floor
    raw = np.exp(log_likelihood_over_table(high_table, feats)[0])[
        table_indices(prior.grid, E, high_table.grid)
    ]
    contradicted = int(np.argmin(raw))
    assert raw[contradicted] < 1e-9  # negligible next to ε: the floor decides its weight
    assert post.weights[contradicted] == pytest.approx(
        LIKELIHOOD.floor * prior.weights[contradicted] / z, rel=1e-4
    )


def test_informative_observation_moves_w_star_to_the_truth(high_table):
    prior = Belief.for_level(HIGH, E)
    true_offset = high_table.grid.points()[
        high_table.grid.nearest_index(np.array([0.03, -0.02, 0.3]))
    ]
    truth = compose_planar(E, true_offset)
    row = high_table.grid.nearest_index(true_offset)
    post = update(prior, high_table, E, observation_of_row(high_table, row, E), transition=False)
    scale = np.asarray(HIGH.spacing)
    before = np.abs(relative_planar(truth, prior.w_star())) / scale
    after = np.abs(relative_planar(truth, post.w_star())) / scale
    assert np.all(after <= 1.0) and before.max() >= 3.0
    assert post.entropy() < prior.entropy() - 1.0


def test_observation_and_features_give_the_same_update(high_table):
    prior = Belief.for_level(HIGH, E)
    row = high_table.grid.nearest_index(np.array([0.03, 0.01, -0.1]))
    assert high_table.contact[row]
    from_obs = update(prior, high_table, E, observation_of_row(high_table, row, E))
    from_feats = update(prior, high_table, E, features_from_table_rows(high_table, [row]))
    np.testing.assert_allclose(from_obs.weights, from_feats.weights, rtol=1e-5, atol=1e-12)


@pytest.mark.parametrize(
    "offset,transition,unsensed",
    [
        ((0.03, 0.01, -0.1), True, ()),
        ((0.03, 0.01, -0.1), False, ()),
        ((-0.02, 0.0, 0.2), True, ()),
        ((0.02, -0.03, 0.1), True, ()),
        # a hand without proximal pads: the entries whose finger 3 stopped on prox3 alone
        ((0.02, -0.03, -0.1), True, ("prox1", "prox2", "prox3")),
    ],
)
def test_fast_update_matches_the_reference(offset, transition, unsensed):
    table_grid = Grid((0.0, 0.0, 0.0), HIGH.spacing, (7, 7, 5))
    table = synthetic_table(table_grid)
    params = likelihood_without(unsensed)
    e = np.array([0.6, -0.02, 0.4])
    # the belief grid reaches beyond the table, so clamped indices are exercised
    belief = Belief.gaussian(
        Grid(tuple(e + [0.01, -0.01, 0.1]), HIGH.spacing, (7, 7, 5)), e, (0.02, 0.02, 0.2)
    )
    row = table_grid.nearest_index(np.array(offset))
    obs = observation_of_row(table, row, e)
    fast = update(belief, table, e, obs, transition=transition, params=params)
    if unsensed:  # the reference and the fast path both leave the prox3-alone closures out
        assert np.isinf(closure_sigma(table, params.sigma_closure, params.unsensed)[2]).any()
    ref = update_reference(belief, table, e, obs, transition=transition, params=params)
    np.testing.assert_allclose(fast.weights, ref.weights, rtol=2e-5, atol=1e-12)
    ref_feats = update_reference(
        belief,
        table,
        e,
        features_from_table_rows(table, [row]),
        transition=transition,
        params=params,
    )
    np.testing.assert_allclose(ref_feats.weights, ref.weights, rtol=1e-6, atol=1e-12)
    idx = [table_index_reference(list(w), list(e), table) for w in belief.grid.points()]
    np.testing.assert_array_equal(table_indices(belief.grid, e, table_grid), idx)


def test_bad_inputs_raise(high_table):
    prior = Belief.for_level(HIGH, E)
    row = high_table.grid.nearest_index(np.array([0.03, 0.0, 0.0]))
    obs = observation_of_row(high_table, row, E)
    obs.closure[1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        update(prior, high_table, E, obs)
    with pytest.raises(ValueError, match="finite"):
        update(prior, high_table, (np.nan, 0.0, 0.0), features_from_table_rows(high_table, [row]))
    with pytest.raises(ValueError, match="one observation"):
        update(prior, high_table, E, features_from_table_rows(high_table, [row, row]))
    no_direction = features_from_observation(
        observation_of_row(high_table, row, E)
    )  # no e: motion unknown
    with pytest.raises(ValueError, match="motion direction"):
        update(prior, high_table, E, no_direction)
    with pytest.raises(ValueError, match="zero probability"):
        apply_likelihood(
            prior, np.zeros(high_table.grid.size, np.float32), np.zeros(prior.grid.size, np.int64)
        )


def test_goal_probability_is_the_belief_mass_on_the_goal_offsets(high_table):
    prior = Belief.for_level(HIGH, E)
    offsets = high_table.grid.points()
    goal = (np.abs(offsets[:, 0]) <= 0.015) & (np.abs(offsets[:, 1]) <= 0.015)
    idx = high_table.grid.nearest_index(relative_planar(E, prior.grid.points()))
    expected = float(prior.weights[goal[idx]].sum())
    assert goal_probability(prior, goal, E) == pytest.approx(expected, rel=1e-12)
    assert goal_probability(prior, goal, E, high_table.grid) == pytest.approx(expected, rel=1e-12)
    assert goal_probability(prior, np.ones_like(goal), E) == pytest.approx(1.0)
    with pytest.raises(ValueError):
        goal_probability(prior, goal[:-1], E)


# ---------------------------------------------- the fast path against the naive reference
def simulated_features(table_grid: Grid, rng: np.random.Generator, contact: bool) -> ObsFeatures:
    """A reading of the synthetic world at a random offset between the table's grid points
    (ahead of the 1.5 cm contact line or not): its exact prediction there (a one-entry
    synthetic table), with the spread a real reading has about it (progress, closures and
    tip points blurred, each sensor flipped with 5 %)."""
    half = np.asarray(table_grid.spacing) * (np.asarray(table_grid.shape) - 1) / 2
    offset = rng.uniform(-half, half)
    offset[0] = rng.uniform(0.016, half[0]) if contact else rng.uniform(-half[0], 0.014)
    f = features_from_table_rows(
        synthetic_table(Grid(tuple(offset), table_grid.spacing, (1, 1, 1))), [0]
    )
    f.progress[0] += np.float32(rng.normal(0.0, 0.005)) if f.contact[0] else 0.0
    f.closure[0] += rng.normal(0.0, 0.03, 3).astype(np.float32)
    f.tip_points[0] += rng.normal(0.0, 0.003, (3, 3)).astype(np.float32)
    f.sensors[0] ^= rng.random(10) < 0.05
    return f


#: Per level: the table's grid shape (spanning the synthetic world's contact and sensor
#: switches) and the belief's coarser spacing, so each state reads a different entry.
FAST_PATH_CASES = {
    "high": (HIGH, (9, 9, 7), (0.01, 0.01, 0.1)),
    "low": (LOW, (25, 25, 9), (0.006, 0.006, 0.026)),
}


@pytest.mark.parametrize("level_name", sorted(FAST_PATH_CASES))
@pytest.mark.parametrize("kind", ["table rows", "simulated"])
def test_fast_update_matches_the_reference_on_many_readings(level_name, kind):
    """50 seeded readings per level and kind (200 in all), contact and no contact, each
    updating a belief whose grid reaches past the table (clamped indices) at an estimate
    turned by up to ±π: the fast update (float32 likelihood, bump and all) agrees with the
    per-state float64 reference within 2e-5 of each weight."""
    level, table_shape, belief_spacing = FAST_PATH_CASES[level_name]
    table_grid = Grid((0.0, 0.0, 0.0), level.spacing, table_shape)
    table = synthetic_table(table_grid)
    rng = np.random.default_rng(40 + 2 * sorted(FAST_PATH_CASES).index(level_name) + len(kind))
    contact_rows, free_rows = np.flatnonzero(table.contact), np.flatnonzero(~table.contact)
    contacts = 0
    for i in range(50):
        if kind == "table rows":
            rows = contact_rows if i % 2 else free_rows
            feats = features_from_table_rows(table, [int(rng.choice(rows))])
        else:
            feats = simulated_features(table_grid, rng, contact=bool(i % 2))
        contacts += bool(feats.contact[0])
        e = np.array([0.6, -0.02, 0.0]) + rng.normal(0.0, [0.01, 0.01, 1.5])
        belief = Belief.gaussian(
            Grid(tuple(e + rng.normal(0.0, [0.004, 0.004, 0.05])), belief_spacing, (5, 5, 3)),
            e,
            np.asarray(belief_spacing) * 2.0,
        )
        transition = bool(i % 3)
        fast = update(belief, table, e, feats, transition=transition)
        ref = update_reference(belief, table, e, feats, transition=transition)
        np.testing.assert_allclose(fast.weights, ref.weights, rtol=2e-5, atol=1e-12)
        assert fast.weights.sum() == pytest.approx(1.0, abs=1e-12)
    assert contacts == 25  # half of them stopped early


def test_the_posterior_is_the_prior_times_the_likelihood_row_to_the_bit(high_table):
    """Given the likelihood row, the update's posterior is b·L[idx] / Σ b·L exactly as numpy
    computes it (the fused gather adds no rounding of its own), from the table indices'
    product form as from the flat indices."""
    rng = np.random.default_rng(7)
    for _ in range(5):
        e = E + rng.normal(0.0, [0.02, 0.02, 1.0])
        prior = Belief.gaussian(Grid.for_level(HIGH, center=e + 0.01), e, (0.03, 0.03, 0.4))
        feats = features_from_table_rows(high_table, [int(rng.integers(high_table.grid.size))])
        like = likelihood_over_table(high_table, feats)[0]
        idx = table_indices(prior.grid, e, high_table.grid)
        expected = prior.weights * like[idx]
        z = expected.sum()
        expected = expected / z
        fast = update(prior, high_table, e, feats, transition=False)
        np.testing.assert_array_equal(fast.weights, expected)
        post, evidence = apply_likelihood(prior, like, idx)
        np.testing.assert_array_equal(post.weights, expected)
        assert evidence == z
        assert not fast.weights.flags.writeable and fast.frame == prior.frame


def test_the_table_indices_product_form_is_the_flat_one(high_table):
    rng = np.random.default_rng(11)
    for _ in range(20):
        e = E + rng.normal(0.0, [0.05, 0.05, 2.0])
        grid = Grid.for_level(HIGH, center=e + rng.normal(0.0, [0.01, 0.01, 0.2]))
        xy, theta = table_index_axes(grid, e, high_table.grid)
        assert xy.shape == (41 * 41,) and theta.shape == (33,)
        np.testing.assert_array_equal(
            (xy[:, None] + theta[None, :]).ravel(),
            high_table.grid.nearest_index(relative_planar(e, grid.points()), clip=True),
        )


def test_apply_likelihood_rejects_indices_beyond_the_row():
    """The fused gather reads without bounds checks, so the indices are checked first."""
    prior = Belief.for_level(LOW, E)
    like = np.full(100, 0.5, np.float32)
    idx = np.zeros(prior.grid.size, np.int64)
    idx[-1] = 100
    with pytest.raises(IndexError):
        apply_likelihood(prior, like, idx)
    idx[-1] = -1
    with pytest.raises(IndexError):
        apply_likelihood(prior, like, idx)
    with pytest.raises(ValueError, match="states"):
        apply_likelihood(prior, like, idx[:-1])


def test_a_belief_from_normalized_weights_is_taken_as_it_is():
    grid = Grid.for_level(LOW, center=E)
    w = np.full(grid.size, 1.0 / grid.size)
    b = Belief.from_normalized(grid, w, "camera")
    assert b.weights is w or np.shares_memory(b.weights, w)  # no copy
    assert not b.weights.flags.writeable and b.frame == "camera" and b.grid == grid
    with pytest.raises(ValueError):
        Belief.from_normalized(grid, w[:-1])
    with pytest.raises(ValueError):
        Belief.from_normalized(grid, w.astype(np.float32))


def test_a_nan_in_the_table_reaches_the_update_as_an_error(high_table):
    """The kernel keeps numpy's NaN semantics (a NaN closure in the table is not capped away):
    the update refuses instead of returning a silently wrong belief."""
    row = high_table.grid.nearest_index(np.array([0.03, 0.0, 0.0]))
    feats = features_from_table_rows(high_table, [row])
    closure = high_table.closure.copy()
    closure[row + 1, 0] = np.nan
    broken = dataclasses.replace(high_table, closure=closure)
    assert np.isnan(log_likelihood_over_table(broken, feats)[0, row + 1])
    with pytest.raises(ValueError, match="NaN"):
        update(Belief.for_level(HIGH, E), broken, E, feats, transition=False)
