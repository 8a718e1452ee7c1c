"""Variable-resolution grid: refine a concentrated coarse belief onto a finer grid
(HIGH → MID → LOW); its speed: ``rrg-bench plan``."""

import numpy as np
import pytest

from rrg_estimator.belief import Belief
from rrg_estimator.config import HIGH, LOW, MID, VARRES_EPS
from rrg_estimator.grid import Grid
from rrg_estimator.varres import maybe_refine
from rrg_models.poses import wrap_angle

COARSE = Grid.for_level(HIGH, center=(0.62, 0.0, 0.0))


def test_spread_or_already_fine_beliefs_are_not_refined():
    assert maybe_refine(Belief.for_level(HIGH, (0.62, 0.0, 0.0))) is None
    concentrated_fine = Belief.gaussian(
        Grid.for_level(LOW, center=(0.62, 0.0, 0.0)), (0.62, 0.0, 0.0), (0.002, 0.002, 0.01)
    )
    assert maybe_refine(concentrated_fine) is None


def test_separated_modes_refine_only_to_a_grid_that_holds_both():
    a = Belief.gaussian(COARSE, (0.52, 0.0, 0.0), (0.004, 0.004, 0.03)).weights
    b = Belief.gaussian(COARSE, (0.72, 0.0, 0.0), (0.004, 0.004, 0.03)).weights
    assert maybe_refine(Belief(COARSE, a + b)) is None  # 20 cm apart: wider than MID's ±7.5 cm
    c = Belief.gaussian(COARSE, (0.62, 0.0, 0.0), (0.004, 0.004, 0.03)).weights
    mid = maybe_refine(Belief(COARSE, a + c))  # 10 cm apart: MID, not LOW (±3 cm)
    assert mid is not None and mid.grid.spacing == MID.spacing
    assert mid.probability(mid.grid.points()[:, 0] < 0.57) == pytest.approx(0.5, abs=0.01)
    # one mode with 0.5 % of the mass elsewhere is within ε = 1 %
    fine = maybe_refine(Belief(COARSE, a + 0.005 * b))
    assert fine is not None and fine.grid.spacing == LOW.spacing


@pytest.mark.parametrize(
    "mean", [(0.6237, -0.0141, 0.237), (0.58, 0.051, -0.96), (0.62, 0.0, 1.05)]
)
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


def test_skewed_belief_gets_a_box_that_holds_the_cells_of_the_whole_run():
    # x mass over 6 coarse points whose cells span 6 cm, exactly the fine box, with a heavy
    # first point: a box centred on the mean (1.2 points in) would miss the last two cells.
    a = np.zeros(COARSE.shape)
    a[12:18, 20, 16] = [0.6, 0.1, 0.1, 0.1, 0.05, 0.05]
    fine = maybe_refine(Belief(COARSE, a))
    assert fine is not None and fine.grid.spacing == LOW.spacing
    ax, fine_ax, h = COARSE.axes()[0], fine.grid.axes()[0], COARSE.spacing[0] / 2
    assert fine_ax[0] <= ax[12] - h + 1e-9 and fine_ax[-1] >= ax[17] + h - 1e-9


def test_a_run_whose_end_cells_would_stick_out_of_the_fine_box_is_not_refined_to_it():
    # θ mass on 4 coarse points 0.3 rad apart fits LOW's ±0.156 rad as points, but a truth in
    # the outer half of an end point's cell (its cells span 0.4 rad) would lie off that grid.
    a = np.zeros(COARSE.shape)
    a[20, 20, 14:18] = [0.1, 0.4, 0.4, 0.1]
    refined = maybe_refine(Belief(COARSE, a))
    assert refined is not None and refined.grid.spacing == MID.spacing
    th = refined.grid.axes()[2]
    assert (
        th[0] <= COARSE.axes()[2][14] - 0.05 + 1e-9 and th[-1] >= COARSE.axes()[2][17] + 0.05 - 1e-9
    )


def test_a_fine_belief_that_moved_off_centre_is_recentred_on_its_mean():
    fine = Grid.for_level(LOW, center=(0.62, 0.0, 0.0))
    moved = Belief.gaussian(fine, (0.62, 0.004, 0.09), (0.002, 0.002, 0.01))  # θ 0.09 of ±0.156 off
    out = maybe_refine(moved)
    assert out is not None and out.grid.spacing == fine.spacing and out.grid.shape == fine.shape
    assert np.all(
        np.abs(np.asarray(out.grid.center) - moved.mean()) <= np.asarray(LOW.spacing) / 2 + 1e-9
    )
    np.testing.assert_allclose(out.mean(), moved.mean(), atol=1e-4)
    # a belief within a quarter of the half extent stays where it is
    assert maybe_refine(Belief.gaussian(fine, (0.62, 0.004, 0.03), (0.002, 0.002, 0.01))) is None


def test_a_mid_belief_refines_to_low_once_it_concentrates_and_recentres_when_it_moves():
    mid = Grid.for_level(MID, center=(0.62, 0.0, 0.0))
    assert maybe_refine(Belief.gaussian(mid, (0.62, 0.0, 0.05), (0.02, 0.02, 0.1))) is None
    low = maybe_refine(Belief.gaussian(mid, (0.63, 0.01, 0.05), (0.003, 0.003, 0.02)))
    assert low is not None and low.grid.spacing == LOW.spacing
    np.testing.assert_allclose(low.grid.center[:2], (0.63, 0.01), atol=MID.spacing[0])
    moved = Belief.gaussian(mid, (0.62, 0.03, 0.3), (0.02, 0.02, 0.1))  # y 3 cm of ±7.5 cm off
    out = maybe_refine(moved)
    assert out is not None and out.grid.spacing == MID.spacing
    assert np.all(
        np.abs(np.asarray(out.grid.center) - moved.mean()) <= np.asarray(MID.spacing) / 2 + 1e-9
    )
