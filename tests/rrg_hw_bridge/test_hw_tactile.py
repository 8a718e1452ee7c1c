"""Barrett's tactile pucks as RRG's pads (rrg_hw_bridge.tactile): the emulated hand's cells
carry each pad's force, the bridge reads it back, and a malformed message is refused."""

from __future__ import annotations

import numpy as np
import pytest

from rrg_hw_bridge.tactile import (
    CELL_AREA_CM2,
    CELLS,
    PUCK_PADS,
    TactileError,
    pads_from_pucks,
    pucks_from_pads,
)
from rrg_models.config import SENSOR_NAMES


def test_a_pads_force_goes_through_the_cells_and_back():
    rng = np.random.default_rng(9)
    pads = np.array([1.5, 0.7, 0.8, 0.9, 2.0, 0.0, 3.25])  # palm, prox1-3, dist1-3 [N]
    pucks = pucks_from_pads(pads, rng)
    assert pucks.shape == (4, CELLS)
    assert np.count_nonzero(pucks[0]) == 4  # a contact presses a patch of cells
    back = pads_from_pucks(pucks)
    sensed = list(PUCK_PADS)
    np.testing.assert_allclose(back[sensed], pads[sensed], rtol=1e-12)
    unsensed = [SENSOR_NAMES.index(n) for n in ("prox1", "prox2", "prox3")]
    assert not back[unsensed].any()  # the real hand has no proximal pucks
    assert pucks[0].max() == pytest.approx(pads[4] / (4 * CELL_AREA_CM2))  # N/cm²


@pytest.mark.parametrize(
    "pucks, why",
    [
        (np.zeros((3, CELLS)), "3 tactile pucks"),
        (np.zeros((4, CELLS - 1)), "23 cells"),
        (np.full((4, CELLS), np.nan), "non-finite"),
    ],
)
def test_a_malformed_tactile_message_is_refused(pucks, why):
    with pytest.raises(TactileError, match=why):
        pads_from_pucks(pucks)
