"""The BarrettHand's tactile pucks as RRG's pads, without ROS.

Barrett's ROS 2 BarrettHand node publishes ``wam_msgs/TactilePressureArray``: four pucks in
libbarrett's order (finger 1, finger 2, finger 3, palm), 24 cells each, pressure in N/cm². RRG's
seven pads (rrg_models.config.SENSOR_NAMES: palm, prox1-3, dist1-3) take a puck's force: the sum of
its cells' pressures times the cell area. The real hand has no pads on its proximal links, so
those never fire (as with derived pads).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: Cells per tactile puck (Barrett's BarrettHand node: TactilePressure.pressure has 24 entries).
CELLS = 24
#: RRG pad index of each puck, in the message's order: finger 1-3's distal pads, then the palm.
PUCK_PADS = (4, 5, 6, 0)
#: Pads the real hand has no puck for: they never fire.
TACTILE_PADS_UNSENSED = ("prox1", "prox2", "prox3")
#: Area of one tactile cell [cm²] (an **assumption**: a puck's 24 cells cover about 6 cm², a
#: fingertip pad of 2.5 × 2.4 cm; no per-cell area is published). It scales pressure into the
#: force the pad threshold (SENSING.pad_force_threshold) applies to.
CELL_AREA_CM2 = 0.25


class TactileError(ValueError):
    """A tactile message that does not have the pucks and cells the bridge reads."""


def pads_from_pucks(pressures: Sequence[Sequence[float]]) -> np.ndarray:
    """(7,) pad forces [N] from the pucks' cell pressures [N/cm²] (4 pucks × CELLS, the
    message's order); TactileError for another shape or a non-finite cell."""
    if len(pressures) != len(PUCK_PADS):
        raise TactileError(f"{len(pressures)} tactile pucks, expected {len(PUCK_PADS)}")
    pads = np.zeros(7)
    for pad, cells in zip(PUCK_PADS, pressures):
        cells = np.asarray(cells, dtype=float)
        if cells.shape != (CELLS,):
            raise TactileError(f"a puck with {cells.size} cells, expected {CELLS}")
        if not np.isfinite(cells).all():
            raise TactileError("a non-finite cell pressure")
        pads[pad] = float(cells.sum()) * CELL_AREA_CM2
    return pads


def pucks_from_pads(pads: np.ndarray, rng: np.random.Generator | None = None) -> np.ndarray:
    """(4, CELLS) cell pressures [N/cm²] carrying each puck's pad force (7,) [N] (the emulated
    hand): the force on a few neighbouring cells, as a contact presses a patch of the pad,
    chosen at random when ``rng`` is given (else the first ones)."""
    pucks = np.zeros((len(PUCK_PADS), CELLS))
    patch = 4  # cells a contact covers (chosen: about 1 cm² at CELL_AREA_CM2)
    for k, pad in enumerate(PUCK_PADS):
        force = max(float(pads[pad]), 0.0) if np.isfinite(pads[pad]) else 0.0
        start = int(rng.integers(0, CELLS - patch + 1)) if rng is not None else 0
        pucks[k, start : start + patch] = force / (patch * CELL_AREA_CM2)
    return pucks
