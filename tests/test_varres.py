"""Variable-resolution grid: refine a concentrated coarse belief onto the fine grid."""
import time

import numpy as np
import pytest

from rrg_estimator.belief import Belief
from rrg_estimator.varres import maybe_refine
from rrg_sim.config import HIGH, LOW, VARRES_EPS
from rrg_sim.grid import Grid
from rrg_sim.poses import wrap_angle

COARSE = Grid.for_level(HIGH, center=(0.62, 0.0, 0.0))


def test_spread_or_already_fine_beliefs_are_not_refined():
    assert maybe_refine(Belief.for_level(HIGH, (0.62, 0.0, 0.0))) is None
    concentrated_fine = Belief.gaussian(Grid.for_level(LOW, center=(0.62, 0.0, 0.0)), (0.62, 0.0, 0.0),
                                        (0.002, 0.002, 0.01))
    assert maybe_refine(concentrated_fine) is None


def test_two_separated_modes_are_not_refined():
    a = Belief.gaussian(COARSE, (0.57, 0.0, 0.0), (0.004, 0.004, 0.03)).weights
    b = Belief.gaussian(COARSE, (0.67, 0.0, 0.0), (0.004, 0.004, 0.03)).weights
    assert maybe_refine(Belief(COARSE, a + b)) is None
    # one mode with 0.5 % of the mass elsewhere is within ε = 1 %
    assert maybe_refine(Belief(COARSE, a + 0.005 * b)) is not None


@pytest.mark.parametrize("mean", [(0.6237, -0.0141, 0.237), (0.58, 0.051, -0.96), (0.62, 0.0, 1.05)])
def test_concentrated_belief_is_refined_around_its_mean(mean):
    coarse = Belief.gaussian(COARSE, mean, (0.005, 0.004, 0.04))
    fine = maybe_refine(coarse)
    assert fine is not None
    assert fine.grid.spacing == LOW.spacing and fine.grid.shape == LOW.shape
    assert abs(fine.weights.sum() - 1.0) < 1e-12
    d = fine.mean() - coarse.mean()
    d[2] = wrap_angle(d[2])
    assert np.all(np.abs(d) <= np.asarray(LOW.spacing)), d
    # no mass piles up on the fine grid's border: the box holds the belief
    border = np.ones(LOW.shape, bool)
    border[1:-1, 1:-1, 1:-1] = False
    assert fine.probability(border) < VARRES_EPS


def test_skewed_belief_gets_a_box_that_holds_the_whole_run():
    # x mass over 7 coarse cells (6 cm, exactly the fine box) with a heavy first cell:
    # a box centred on the mean (1.2 cells in) would miss the last two cells.
    a = np.zeros(COARSE.shape)
    a[12:19, 15, 12] = [0.6, 0.1, 0.1, 0.05, 0.05, 0.05, 0.05]
    coarse = Belief(COARSE, a)
    fine = maybe_refine(coarse)
    assert fine is not None
    ax = COARSE.axes()[0]
    assert fine.grid.center[0] == pytest.approx(ax[15])
    fine_ax = fine.grid.axes()[0]
    assert fine_ax[0] <= ax[12] + 1e-9 and fine_ax[-1] >= ax[18] - 1e-9


def test_refine_time():
    coarse = Belief.gaussian(COARSE, (0.6237, -0.0141, 0.237), (0.005, 0.004, 0.04))
    maybe_refine(coarse)
    t0 = time.perf_counter()
    for _ in range(20):
        maybe_refine(coarse)
    spread = Belief.for_level(HIGH, (0.62, 0.0, 0.0))
    t1 = time.perf_counter()
    for _ in range(20):
        maybe_refine(spread)
    t2 = time.perf_counter()
    print(f"\nmaybe_refine: refine {(t1 - t0) / 20 * 1e3:.2f} ms, reject {(t2 - t1) / 20 * 1e3:.2f} ms")


def test_a_fine_belief_that_moved_off_centre_is_recentred_on_its_mean():
    fine = Grid.for_level(LOW, center=(0.62, 0.0, 0.0))
    moved = Belief.gaussian(fine, (0.62, 0.004, 0.09), (0.002, 0.002, 0.01))  # θ 0.09 of ±0.156 off
    out = maybe_refine(moved)
    assert out is not None and out.grid.spacing == fine.spacing and out.grid.shape == fine.shape
    assert np.all(np.abs(np.asarray(out.grid.center) - moved.mean()) <= np.asarray(LOW.spacing) / 2 + 1e-9)
    np.testing.assert_allclose(out.mean(), moved.mean(), atol=1e-4)
    # a belief within a quarter of the half extent stays where it is
    assert maybe_refine(Belief.gaussian(fine, (0.62, 0.004, 0.03), (0.002, 0.002, 0.01))) is None
