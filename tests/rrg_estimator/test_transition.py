"""Transition models: the contact bump, the reorientation mixture and the grasp settling."""

import dataclasses

import numpy as np
import pytest

from rrg_estimator.belief import Belief
from rrg_estimator.config import HIGH, LOW, TRANSITION
from rrg_estimator.grid import Grid
from rrg_estimator.transition import bump, displacement_kernel, reorient, settle, splat
from rrg_models.goal import AffineSettle, Settling
from rrg_models.poses import relative_planar

EXACT_TURNS = dataclasses.replace(TRANSITION, reorient_sigma_theta=0.0)


def narrow(level=HIGH, mean=(0.62, 0.0, 0.2), sigma=(0.012, 0.012, 0.12)) -> Belief:
    return Belief.gaussian(Grid.for_level(level, center=mean), mean, sigma)


def test_displacement_kernel_conserves_interior_mass_and_shifts():
    k = displacement_kernel(41, 2.3, 0.8)
    np.testing.assert_allclose(k[:, 20].sum(), 1.0, atol=1e-12)
    assert (np.arange(41) @ k[:, 20]) == pytest.approx(22.3, abs=1e-4)
    assert k[:, 40].sum() < 0.1  # pushed off the edge


@pytest.mark.parametrize("direction", [(1.0, 0.0), (0.6, -0.8), (0.0, 0.0), (0.3, 0.4)])
def test_bump_moves_mass_along_the_direction_and_keeps_the_stay_part(direction):
    b = narrow()
    after = bump(b, direction)
    expected = (1 - TRANSITION.p_stay) * TRANSITION.bump_mean * np.asarray(direction)
    np.testing.assert_allclose(after.mean()[:2] - b.mean()[:2], expected, atol=2e-5)
    assert after.mean()[2] == pytest.approx(b.mean()[2], abs=1e-6)
    # the "stays" component is kept in place (renormalization only adds mass)
    assert np.all(after.weights >= TRANSITION.p_stay * b.weights - 1e-15)
    # the bumped component is blurred: every variance grows
    assert np.all(np.diag(after.cov()) > np.diag(b.cov()))


def test_bump_direction_longer_than_one_is_normalized():
    b = narrow()
    np.testing.assert_allclose(bump(b, (3.0, 4.0)).weights, bump(b, (0.6, 0.8)).weights, atol=1e-15)


def test_bump_drops_mass_pushed_off_the_grid():
    g = Grid.for_level(HIGH, center=(0.62, 0.0, 0.0))
    edge = np.zeros(g.shape)
    edge[-1, 15, 12] = 1.0  # on the +x border
    after = bump(Belief(g, edge), (1.0, 0.0))
    assert abs(after.weights.sum() - 1.0) < 1e-12
    # the stay part is relatively larger: part of the bumped part left the grid
    assert after.as_grid_array()[-1, 15, 12] > TRANSITION.p_stay + 0.05


def test_reorient_rotates_the_mass_by_the_angle():
    b = narrow(sigma=(0.012, 0.012, 0.02))
    angle = 0.4  # 4 cells: every component lands on grid points
    after = reorient(b, angle, EXACT_TURNS)
    assert after.grid.center[2] == pytest.approx(b.grid.center[2] + angle)
    assert after.w_star()[2] == pytest.approx(b.w_star()[2] + angle)
    np.testing.assert_allclose(after.w_star()[:2], b.w_star()[:2])
    mt, at = after.marginal_theta(), after.grid.axes()[2]
    theta0 = b.mean()[2]
    for target, p in [
        (theta0 + angle, TRANSITION.p_reorient_success),
        (theta0 + angle / 2, TRANSITION.p_reorient_partial),
        (theta0, 1 - TRANSITION.p_reorient_success - TRANSITION.p_reorient_partial),
    ]:
        assert mt[np.abs(at - target) < 0.05].sum() == pytest.approx(p, abs=1e-4)
    np.testing.assert_allclose(after.marginal_xy(), b.marginal_xy(), atol=1e-12)


def test_reorient_about_a_centre_moves_off_centre_states():
    g = Grid.for_level(HIGH, center=(0.62, 0.0, 0.0))
    a = np.zeros(g.shape)
    cx, cy, ct = (n // 2 for n in g.shape)
    a[cx + 5, cy, ct] = 1.0  # object 5 cm in +x from the hand's axis at the grid centre, θ = 0
    after = reorient(Belief(g, a), np.pi / 2, center_xy=(0.62, 0.0))
    np.testing.assert_allclose(after.w_star(), [0.62, 0.05, np.pi / 2], atol=1e-9)


def test_reorient_on_a_narrow_grid_keeps_the_full_turn():
    b = narrow(LOW, sigma=(0.004, 0.004, 0.02))
    after = reorient(b, 1.0, EXACT_TURNS)  # far beyond the low grid's ±0.156 rad
    np.testing.assert_allclose(after.as_grid_array(), b.as_grid_array(), atol=1e-12)
    assert after.grid.center[2] == pytest.approx(b.grid.center[2] + 1.0)


def test_reorient_spreads_the_turn_by_its_sigma():
    b = narrow(LOW, sigma=(0.004, 0.004, 0.02))
    after = reorient(b, 1.0)  # the full turn only stays on the low grid
    var = after.cov()[2, 2] - b.cov()[2, 2]
    assert var == pytest.approx(TRANSITION.reorient_sigma_theta**2, rel=0.15)


def test_a_measured_reorientation_moves_the_full_turn_to_its_fitted_offset():
    """With a WRT's ReorientOutcome, a state at offset Δ from e inside the box ends, on the
    full turn, at e' ⊕ (Δ + shift) (e' = e turned by the angle); one outside turns rigidly; the
    planner's mixture (search.reorient_mixture) puts its full turn at the same poses."""
    from rrg_models.poses import compose_planar
    from rrg_models.wrt import ReorientOutcome
    from rrg_planner.search import reorient_mixture

    g = Grid.for_level(HIGH, center=(0.62, 0.0, 0.0))
    e = np.array([0.62, 0.0, 0.0])
    outcome = ReorientOutcome(
        np.array([0.02, 0.02, 0.2]), np.array([0.002, -0.004, 0.05]), np.zeros(3)
    )
    angle = 0.6
    e_turned = e + [0.0, 0.0, angle]
    for delta, expected in [
        ((0.01, -0.01, 0.1), (0.01 + 0.002, -0.01 - 0.004, 0.1 + 0.05)),
        ((0.05, 0.0, 0.0), (0.05, 0.0, 0.0)),
    ]:  # the second lies outside the box
        start = compose_planar(e, np.array(delta))
        a = np.zeros(g.size)
        a[g.nearest_index(start[None])[0]] = 1.0
        on_grid = g.points()[np.argmax(a)]
        after = reorient(Belief(g, a), angle, EXACT_TURNS, center_xy=e[:2], outcome=outcome, e=e)
        d = relative_planar(e, on_grid[None])[0]
        mean = outcome.mean(d) if outcome.inside(d) else d
        target = compose_planar(e_turned, mean)
        np.testing.assert_allclose(mean, expected, atol=0.011)  # Δ rounded to the grid
        near = np.all(
            np.abs(relative_planar(target, after.grid.points()))
            <= np.array(after.grid.spacing) + 1e-9,
            axis=1,
        )
        w = after.weights[near]
        assert w.sum() > 0.75  # the full turn, 0.8 (the sampled partial turns renormalize it)
        np.testing.assert_allclose(w @ after.grid.points()[near] / w.sum(), target, atol=1e-3)
        pts, _ = reorient_mixture(on_grid[None], np.ones(1), e, angle, outcome=outcome)
        np.testing.assert_allclose(pts[0], target, atol=1e-12)


def settling(
    b=(0.0, 0.0, 0.0), A=np.eye(3), sigma=(0.0, 0.0, 0.0), box=(0.03, 0.03, 0.3)
) -> Settling:
    fit = AffineSettle(np.asarray(A, float), np.asarray(b, float), np.asarray(sigma, float))
    return Settling(np.asarray(box, float), fit, fit, source="test")


def test_splat_keeps_the_mass_and_its_mean():
    g = Grid.for_level(LOW, center=(0.62, 0.0, 0.0))
    rng = np.random.default_rng(3)
    poses = np.array([0.62, 0.0, 0.0]) + rng.uniform(-0.02, 0.02, (50, 3))
    mass = rng.uniform(0.1, 1.0, 50)
    a = splat(g, poses, mass)
    assert a.sum() == pytest.approx(mass.sum(), rel=1e-12)
    np.testing.assert_allclose(
        Belief(g, a).mean(), mass @ poses / mass.sum(), atol=1e-7
    )  # θ: circular mean
    assert (
        splat(g, np.array([[0.9, 0.0, 0.0]]), np.ones(1)).sum() == 0.0
    )  # beyond the grid: dropped


def test_identity_settling_leaves_the_belief():
    b = narrow(LOW, mean=(0.62, 0.0, 0.0), sigma=(0.004, 0.004, 0.02))
    np.testing.assert_allclose(
        settle(b, settling(), (0.62, 0.0, 0.0)).weights, b.weights, atol=1e-15
    )


def test_settling_shifts_states_in_the_box_by_the_map_in_the_estimate_frame():
    e = np.array(
        [0.62, 0.0, 0.5]
    )  # shifts are in e's frame: +x of e is (cos 0.5, sin 0.5) in world
    b = narrow(LOW, mean=e, sigma=(0.004, 0.004, 0.02))
    after = settle(b, settling(b=(0.01, 0.0, 0.03)), e)
    shift = relative_planar(e, after.mean()) - relative_planar(e, b.mean())
    np.testing.assert_allclose(shift, [0.01, 0.0, 0.03], atol=2e-4)


def test_settling_funnels_the_box_and_leaves_the_rest():
    e = np.array([0.62, 0.0, 0.0])
    g = Grid.for_level(LOW, center=e)
    inside, outside = (
        np.array([0.01, -0.01, 0.05]),
        np.array([0.0, 0.02, 0.0]),
    )  # the box is ±1.5 cm in y
    w = np.zeros(g.size)
    w[g.nearest_index(e + inside)] = w[g.nearest_index(e + outside)] = 0.5
    after = settle(
        Belief(g, w),
        settling(A=np.zeros((3, 3)), sigma=(0.002, 0.002, 0.01), box=(0.015, 0.015, 0.3)),
        e,
    )
    assert after.weights[g.nearest_index(e + outside)] == pytest.approx(0.5)
    near = np.all(np.abs(relative_planar(e, g.points())) <= (0.005, 0.005, 0.03), axis=1)
    assert after.probability(near) == pytest.approx(
        0.5, abs=0.02
    )  # the funnel's mass: at Δ = 0 ± 2.5σ
    assert after.probability(near) > after.weights[g.nearest_index(e)] * 2  # and is blurred by σ


def test_the_reorientation_study_fits_the_full_turns_shift_and_the_catalogue_loads_it():
    """reorient_study.fit: the mean and σ of Δ' - Δ over the full turns (a partial turn,
    Δ'_θ half the angle away, is left to the mixture); the catalogue's reorientation WRTs
    carry the committed fits."""
    from rrg_models.objects import get_object
    from rrg_sim.physics.reorient_study import TooFewTurns, fit

    rng = np.random.default_rng(0)
    records = []
    for name in ("reorient_ccw", "reorient_cw"):
        for start in rng.normal(size=(12, 3)) * [0.01, 0.01, 0.1]:
            records.append(
                dict(
                    wrt=name, start=start.tolist(), after=(start + [0.003, -0.002, -0.05]).tolist()
                )
            )
        records.append(dict(wrt=name, start=[0.0, 0.0, 0.0], after=[0.0, 0.0, -0.3]))  # a half turn
    fits = fit("giant_teacup", records)
    assert fits["reorient_ccw"]["full"] == 12 and fits["reorient_ccw"]["held"] == 13
    np.testing.assert_allclose(fits["reorient_cw"]["shift"], [0.003, -0.002, -0.05], atol=1e-5)
    np.testing.assert_allclose(fits["reorient_cw"]["sigma"], 0.0, atol=1e-5)
    for name in ("giant_teacup", "powerdrill", "brita_pitcher", "cup"):
        for wrt in get_object(name).wrts():
            assert (wrt.reorient_outcome is not None) == (wrt.kind == "reorient")
    half_turns = [r for r in records if r["wrt"] == "reorient_cw"]
    for r in half_turns[:6]:
        r["after"] = [0.0, 0.0, -0.3]
    with pytest.raises(TooFewTurns, match="only 6 of 13 runs turned it fully"):
        fit("giant_teacup", records)
