"""Belief: Gaussian initial beliefs, statistics, immutability and validation."""

import math

import numpy as np
import pytest

from rrg_estimator.belief import Belief
from rrg_estimator.config import HIGH, LOW
from rrg_estimator.grid import Grid
from rrg_models.config import WORLD
from rrg_models.poses import wrap_angle


def wide_grid(center, sigma, n=(41, 41, 41)) -> Grid:
    """A grid spanning ±5σ, so truncation does not bias the moments."""
    spacing = tuple(10 * s / (k - 1) for s, k in zip(sigma, n))
    return Grid(tuple(center), spacing, n)


def test_gaussian_has_the_right_mean_and_covariance():
    mean, sigma = np.array([0.61, -0.03, 0.4]), np.array([0.02, 0.01, 0.2])
    b = Belief.gaussian(wide_grid(mean + [0.004, -0.002, 0.03], sigma), mean, sigma)
    np.testing.assert_allclose(b.mean(), mean, atol=1e-6)
    np.testing.assert_allclose(b.cov(), np.diag(sigma**2), rtol=2e-3, atol=1e-9)
    assert abs(b.weights.sum() - 1.0) < 1e-12


@pytest.mark.parametrize("level", [HIGH, LOW])
def test_level_belief_is_centred_on_the_mean(level):
    mean = np.array(WORLD.nominal_pose) + [0.013, -0.007, 0.2]
    b = Belief.for_level(level, mean)
    assert b.grid.shape == level.shape and b.grid.spacing == level.spacing
    np.testing.assert_allclose(b.grid.center, mean)
    np.testing.assert_allclose(b.w_star(), mean, atol=1e-12)
    np.testing.assert_allclose(b.mean(), mean, atol=1e-9)
    # truncated at the grid border: variances at most σ², and within 25 % of it
    var = np.diag(b.cov())
    assert np.all(var <= np.square(level.sigma) * 1.001) and np.all(
        var >= 0.75 * np.square(level.sigma)
    )


@pytest.mark.parametrize("level", [HIGH, LOW])
def test_level_grid_spans_three_sigma_of_the_prior_on_every_axis(level):
    """True poses are drawn from the prior; one off the grid can never be found. The paper's
    25 θ points at 0.1 rad span only ±2.3σ of the high level's 30°."""
    half_extent = (np.array(level.shape) - 1) / 2 * np.array(level.spacing)
    assert np.all(half_extent >= 2.95 * np.array(level.sigma)), half_extent / np.array(level.sigma)


def test_theta_statistics_wrap_across_pi():
    sigma = np.array([0.01, 0.01, 0.1])
    near_pi = Belief.gaussian(
        wide_grid((0.6, 0.0, math.pi - 0.05), sigma), (0.6, 0.0, math.pi - 0.02), sigma
    )
    near_zero = Belief.gaussian(wide_grid((0.6, 0.0, -0.05), sigma), (0.6, 0.0, -0.02), sigma)
    assert abs(wrap_angle(near_pi.mean()[2] - (math.pi - 0.02))) < 1e-6
    np.testing.assert_allclose(near_pi.cov(), near_zero.cov(), rtol=1e-6, atol=1e-12)
    assert near_pi.cov()[2, 2] == pytest.approx(0.01, rel=2e-3)


def test_weights_are_copied_normalized_and_read_only():
    g = Grid((0.0, 0.0, 0.0), (0.01, 0.01, 0.1), (3, 3, 3))
    raw = np.arange(1.0, 28.0)
    b = Belief(g, raw)
    raw[:] = 0.0
    assert abs(b.weights.sum() - 1.0) < 1e-12 and b.weights[0] > 0
    with pytest.raises(ValueError):
        b.weights[0] = 1.0
    with pytest.raises(ValueError):
        b.as_grid_array()[0, 0, 0] = 1.0
    c = b.with_weights(np.ones(27))
    assert c is not b and np.allclose(c.weights, 1 / 27) and not np.allclose(b.weights, 1 / 27)


@pytest.mark.parametrize("bad", [np.full(27, np.nan), -np.ones(27), np.zeros(27), np.ones(26)])
def test_invalid_weights_are_refused(bad):
    with pytest.raises(ValueError):
        Belief(Grid((0.0, 0.0, 0.0), (0.01, 0.01, 0.1), (3, 3, 3)), bad)


def test_marginals_probability_and_entropy():
    rng = np.random.default_rng(3)
    g = Grid((0.6, 0.0, 0.0), (0.01, 0.01, 0.1), (5, 7, 9))
    b = Belief(g, rng.random(g.size))
    a = b.as_grid_array()
    assert b.marginal_xy().shape == (5, 7) and b.marginal_theta().shape == (9,)
    np.testing.assert_allclose(b.marginal_xy(), a.sum(axis=2))
    np.testing.assert_allclose(b.marginal_theta(), a.sum(axis=(0, 1)))
    pts = g.points()
    mask = pts[:, 0] > 0.6
    assert b.probability(mask) == pytest.approx(b.weights[mask].sum())
    assert b.probability(mask.reshape(g.shape)) == pytest.approx(b.weights[mask].sum())
    assert b.probability(np.ones(g.size, bool)) == pytest.approx(1.0)
    assert Belief(g, np.ones(g.size)).entropy() == pytest.approx(math.log(g.size))
    delta = np.zeros(g.size)
    delta[17] = 1.0
    point = Belief(g, delta)
    assert point.entropy() == 0.0
    np.testing.assert_allclose(point.w_star(), pts[17])
