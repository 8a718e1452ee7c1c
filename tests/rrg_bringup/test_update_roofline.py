"""The update's roofline (rrg-bench plan): what it counts. Its numbers are printed, never
asserted."""

import numpy as np
import pytest
from synthetic_tables import synthetic_table

from rrg_bringup.benchmarks.update_roofline import (
    _read_all,
    likelihood_columns_bytes,
    likelihood_flops,
    read_bandwidth,
    roofline,
)
from rrg_estimator.config import HIGH
from rrg_estimator.grid import Grid
from rrg_estimator.obs_model import features_from_table_rows


@pytest.fixture(scope="module")
def table():
    return synthetic_table(Grid((0.0, 0.0, 0.0), HIGH.spacing, (9, 9, 7)))


def test_the_likelihood_reads_the_columns_the_readings_terms_use(table):
    """Contact 1 B, the silent-sensor sum 4 B and closure with its σ 24 B per entry always;
    progress 4 B if the reading stopped early, 4 B per fired sensor, 12 B per tip point."""
    n = len(table.contact)
    free = int(np.flatnonzero(~table.contact & ~table.sensors[:, 7] & ~table.sensors[:, 9])[0])
    feats = features_from_table_rows(table, [free])
    fired = int(feats.sensors[0].sum())
    assert np.isnan(feats.tip_points[0, :, 0]).all()
    assert likelihood_columns_bytes(table, feats) == n * (29 + 4 * fired)
    assert likelihood_flops(table, feats) == n * (1 + 2 + fired + 18 + 3)
    hit = int(np.flatnonzero(table.contact & table.sensors[:, 7] & table.sensors[:, 9])[0])
    feats = features_from_table_rows(table, [hit])
    fired = int(feats.sensors[0].sum())
    assert likelihood_columns_bytes(table, feats) == n * (29 + 4 + 4 * fired + 2 * 12)
    assert likelihood_flops(table, feats) == n * (1 + 6 + 2 + fired + 18 + 2 * 11 + 3)


def test_the_floors_are_the_bytes_at_the_measured_bandwidths(table):
    feats = features_from_table_rows(table, [0])
    n_xy, n_theta = 41 * 41, 33
    r = roofline(n_xy * n_theta, n_xy, n_theta, table, feats, 2e-4, 3, main_memory_bytes=8 << 20)
    n_states = n_xy * n_theta
    # prior and posterior weights 8 B a state, the likelihood row 4 B an entry, indices 8 B
    assert r["gather_bytes"] == 16 * n_states + 4 * len(table.contact) + 8 * (n_xy + n_theta)
    assert r["update_bytes"] == r["gather_bytes"] + likelihood_columns_bytes(table, feats)
    for name in ("gather", "update"):
        for roof, gbs in (("memory", "main_memory_read_gbs"), ("cache", "cache_read_gbs")):
            floor_s = r[f"{name}_floor_{roof}_ms"] / 1e3
            assert floor_s == pytest.approx(r[f"{name}_bytes"] / (r[gbs] * 1e9), rel=1e-12)
            assert r[f"{name}_ratio_{roof}"] == pytest.approx(2e-4 / floor_s, rel=1e-12)
    assert r["flops_per_byte"] == pytest.approx(r["update_flops"] / r["update_bytes"])


def test_the_bandwidth_probe_reads_every_element():
    a = np.random.default_rng(3).random(100_003)
    assert _read_all(a) == pytest.approx(a.sum(), rel=1e-12)
    assert read_bandwidth(1 << 20, 3) > 0.0
