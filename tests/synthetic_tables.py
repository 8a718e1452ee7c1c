"""The synthetic observation table of the update tests (rrg_estimator/test_update.py), which
the roofline's tests (rrg_bringup/test_update_roofline.py) count on too."""

import numpy as np

from rrg_estimator.grid import Grid
from rrg_estimator.obs_tables import ObservationTable


def synthetic_table(grid: Grid) -> ObservationTable:
    """Early contact when the object is ≥ 1.5 cm ahead; sensors, closures and tip points vary
    with Δ."""
    d = grid.points()
    n = len(d)
    path = 0.30
    contact = d[:, 0] > 0.015
    progress = np.where(contact, 0.25 - 2.0 * d[:, 0], path).astype(np.float32)
    sensors = np.zeros((n, 10), bool)
    sensors[:, 0] = ~contact
    sensors[:, 1] = d[:, 1] > 0.01
    sensors[:, 3] = d[:, 1] < -0.01
    sensors[:, 7] = np.abs(d[:, 1]) < 0.04
    sensors[:, 9] = d[:, 2] > 0.0
    closure = (1.0 + np.stack([10 * d[:, 1], -10 * d[:, 1], 3 * d[:, 2]], axis=1)).astype(
        np.float32
    )
    tips = np.full((n, 3, 3), np.nan, np.float32)
    tips[:, 0] = np.where(
        sensors[:, 7, None], np.stack([d[:, 0], 0.05 + d[:, 1], np.full(n, 0.12)], 1), np.nan
    )
    tips[:, 2] = np.where(
        sensors[:, 9, None],
        np.stack([d[:, 0] + 0.05 * d[:, 2], np.full(n, -0.05), np.full(n, 0.12)], 1),
        np.nan,
    )
    motion = np.where(contact[:, None], [0.6, 0.0, -0.8], [0.0, 0.0, -1.0]).astype(np.float32)
    return ObservationTable(
        "synthetic",
        "probe",
        grid,
        path,
        contact,
        progress,
        sensors,
        closure,
        tips,
        np.full((n, 3, 3), np.nan, np.float32),
        motion,
        np.tile(np.eye(4), (n, 1, 1)),
    )
