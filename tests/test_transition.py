"""Transition models: the contact bump and the reorientation mixture."""
import time

import numpy as np
import pytest

from rrg_estimator.belief import Belief
from rrg_estimator.transition import bump, displacement_kernel, reorient
from rrg_sim.config import HIGH, LOW, TRANSITION
from rrg_sim.grid import Grid


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


def test_bump_is_fast_on_the_full_grid():
    b = Belief.for_level(LOW, (0.62, 0.0, 0.0))
    bump(b, (0.6, 0.8))
    t0 = time.perf_counter()
    for _ in range(50):
        bump(b, (0.6, 0.8))
    print(f"\nbump on 24,025 points: {(time.perf_counter() - t0) / 50 * 1e3:.3f} ms")


def test_reorient_rotates_the_mass_by_the_angle():
    b = narrow(sigma=(0.012, 0.012, 0.02))
    angle = 0.4  # 4 cells: every component lands on grid points
    after = reorient(b, angle)
    assert after.grid.center[2] == pytest.approx(b.grid.center[2] + angle)
    assert after.w_star()[2] == pytest.approx(b.w_star()[2] + angle)
    np.testing.assert_allclose(after.w_star()[:2], b.w_star()[:2])
    mt, at = after.marginal_theta(), after.grid.axes()[2]
    theta0 = b.mean()[2]
    for target, p in [(theta0 + angle, TRANSITION.p_reorient_success),
                      (theta0 + angle / 2, TRANSITION.p_reorient_partial),
                      (theta0, 1 - TRANSITION.p_reorient_success - TRANSITION.p_reorient_partial)]:
        assert mt[np.abs(at - target) < 0.05].sum() == pytest.approx(p, abs=1e-4)
    np.testing.assert_allclose(after.marginal_xy(), b.marginal_xy(), atol=1e-12)


def test_reorient_about_a_centre_moves_off_centre_states():
    g = Grid.for_level(HIGH, center=(0.62, 0.0, 0.0))
    a = np.zeros(g.shape)
    a[20, 15, 12] = 1.0  # object 5 cm in +x from the hand's axis at the grid centre
    after = reorient(Belief(g, a), np.pi / 2, center_xy=(0.62, 0.0))
    np.testing.assert_allclose(after.w_star(), [0.62, 0.05, np.pi / 2], atol=1e-9)


def test_reorient_on_a_narrow_grid_keeps_the_full_turn():
    b = narrow(LOW, sigma=(0.004, 0.004, 0.02))
    after = reorient(b, 1.0)  # far beyond the low grid's ±0.156 rad
    np.testing.assert_allclose(after.as_grid_array(), b.as_grid_array(), atol=1e-12)
    assert after.grid.center[2] == pytest.approx(b.grid.center[2] + 1.0)
