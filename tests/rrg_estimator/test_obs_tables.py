"""Observation tables: the relative-transform invariance, no-contact rows, the disk cache."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rrg_estimator import obs_tables
from rrg_estimator.config import HIGH
from rrg_estimator.grid import Grid
from rrg_estimator.obs_tables import ObservationTable, build_table, load_or_build
from rrg_models.objects.primitives import Primitive
from rrg_models.poses import compose_planar, make_pose
from rrg_models.wrt import WRT
from rrg_sim.geometric_sim import GeometricSimulator

COARSE = Grid((0.0, 0.0, 0.0), (0.03, 0.03, 0.5), (9, 9, 5))  # a sub-lattice of the HIGH grid


@dataclass(frozen=True)
class Obj:
    name: str
    parts: tuple[Primitive, ...]


BOX = Obj("testbox", (Primitive("box", (0.1, 0.05, 0.075), (0.0, 0.0, 0.075)),))
TOP_DOWN = WRT(
    "top_down",
    "goal",
    make_pose(np.array([[0.0, 0.0, 0.5], [0.0, 0.0, 0.235]]), Rotation.from_rotvec([np.pi, 0, 0])),
    spread=0.0,
    preclose=0.2,
)
SIDE = WRT(
    "side",
    "info",
    make_pose(
        np.array([[-0.45, 0.0, 0.075], [-0.2, 0.0, 0.075]]), Rotation.from_rotvec([0, np.pi / 2, 0])
    ),
    spread=0.0,
    preclose=0.3,
)


@pytest.fixture(scope="module")
def side_table() -> ObservationTable:
    return build_table(BOX, SIDE, COARSE, workers=2, progress=False)


def test_world_simulation_equals_the_table_row_of_its_relative_offset(side_table):
    sim = GeometricSimulator(BOX, SIDE)
    rng = np.random.default_rng(3)
    rows = rng.choice(len(side_table), 24, replace=False)
    deltas = COARSE.points()[rows]
    es = np.column_stack(
        [rng.uniform(0.4, 0.9, 24), rng.uniform(-0.3, 0.3, 24), rng.uniform(-np.pi, np.pi, 24)]
    )
    assert 0 < side_table.contact[rows].sum() < len(rows)
    for j, d, e in zip(rows, deltas, es):
        o = sim.simulate(compose_planar(e, d), e)
        assert o.contact == side_table.contact[j]
        np.testing.assert_array_equal(o.sensors, side_table.sensors[j])
        assert abs(o.progress - side_table.progress[j]) < 1e-3
        np.testing.assert_allclose(o.closure, side_table.closure[j], atol=0.02)
        np.testing.assert_allclose(o.tip_points, side_table.tip_points[j], atol=2e-3)


def test_far_offsets_give_no_contact_rows():
    grid = Grid((0.5, 0.0, 0.0), (0.05, 0.05, 0.5), (3, 3, 3))  # object 40-60 cm off the path
    table = build_table(BOX, TOP_DOWN, grid, workers=1, progress=False)
    assert not table.contact.any() and not table.sensors.any()
    np.testing.assert_allclose(table.progress, table.path_length, atol=1e-6)
    assert table.path_length == pytest.approx(0.5 - 0.235)


def test_table_rows_match_single_simulations(side_table):
    sim = GeometricSimulator(BOX, SIDE)
    for j in (0, len(side_table) // 2, len(side_table) - 7):
        o = sim.simulate_relative(COARSE.points()[j])
        row = side_table.observation(j)
        assert o.contact == row.contact and (o.sensors == row.sensors).all()
        np.testing.assert_allclose(row.hand_pose, o.hand_pose, atol=1e-6)


def test_cache_round_trip_and_rebuild_when_stale(tmp_path, monkeypatch):
    builds = []

    def counted_build(*args, **kwargs):
        builds.append(args[1].name)
        return build_table(*args, **kwargs)

    def no_build(*args, **kwargs):
        raise AssertionError("the table was built, not loaded from the cache")

    monkeypatch.setattr(obs_tables, "build_table", counted_build)
    first = load_or_build(BOX, TOP_DOWN, COARSE, cache_dir=tmp_path, workers=1, progress=False)
    assert builds == ["top_down"]
    monkeypatch.setattr(obs_tables, "build_table", no_build)
    second = load_or_build(BOX, TOP_DOWN, COARSE, cache_dir=tmp_path, workers=1, progress=False)
    assert (second.grid, second.object_name, second.wrt_name) == (COARSE, "testbox", "top_down")
    for field in obs_tables.ARRAY_FIELDS:
        np.testing.assert_array_equal(getattr(second, field), getattr(first, field))
    assert len(list(tmp_path.glob("*.npz"))) == 1
    monkeypatch.setattr(obs_tables, "build_table", counted_build)
    changed = replace(TOP_DOWN, preclose=0.4)  # same name, different WRT → stale
    third = load_or_build(BOX, changed, COARSE, cache_dir=tmp_path, workers=1, progress=False)
    assert builds == ["top_down"] * 2
    assert not np.array_equal(third.closure, first.closure)
    assert len(list(tmp_path.glob("*.npz"))) == 1
    # A table of the same WRT on another grid is kept beside it, not replaced.
    finer = Grid((0.0, 0.0, 0.0), (0.01, 0.01, 0.2), (5, 5, 3))
    load_or_build(BOX, changed, finer, cache_dir=tmp_path, workers=1, progress=False)
    assert builds == ["top_down"] * 3
    assert len(list(tmp_path.glob("*.npz"))) == 2
    monkeypatch.setattr(obs_tables, "build_table", no_build)
    again = load_or_build(BOX, changed, COARSE, cache_dir=tmp_path, workers=1, progress=False)
    np.testing.assert_array_equal(again.closure, third.closure)


@pytest.mark.slow  # a full-size table
def test_full_high_grid_build_agrees_with_the_coarse_table(side_table):
    full = build_table(BOX, SIDE, HIGH, workers=2, progress=False)
    assert len(full) == int(np.prod(HIGH.shape))  # every point of the high grid
    idx = Grid.for_level(HIGH).nearest_index(COARSE.points())
    np.testing.assert_array_equal(full.contact[idx], side_table.contact)
    np.testing.assert_array_equal(full.sensors[idx], side_table.sensors)
    np.testing.assert_allclose(full.progress[idx], side_table.progress, atol=1e-6)


def test_one_zero_draw_gives_the_nominal_table_exactly(side_table):
    marginal = obs_tables.build_marginal_table(
        BOX, SIDE, COARSE, np.zeros((1, 3)), workers=1, progress=False
    )
    (table,) = marginal.tables
    for field in obs_tables.ARRAY_FIELDS:
        np.testing.assert_array_equal(getattr(table, field), getattr(side_table, field))
    assert len(marginal) == len(side_table)
    assert len(marginal.observations(5)) == 1


def test_nuisance_draws_are_seeded_vertical_and_zero_in_the_nominal_world():
    a = obs_tables.nuisance_offsets("realistic", 64, seed=3)
    np.testing.assert_array_equal(a, obs_tables.nuisance_offsets("realistic", 64, seed=3))
    assert not a[:, :2].any() and a[:, 2].std() > 0.003  # σ ≈ 7.4 mm: 7 mm hand, 2.3 mm table
    assert not obs_tables.nuisance_offsets("nominal", 4, seed=3).any()


def test_a_marginal_table_holds_one_table_per_draw():
    """Draws of the hand's height move a top-down grasp's stop by as much, draw by draw; stop
    poses stay where the robot measures its hand."""
    offsets = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.008], [0.0, 0.0, -0.005]])
    grid = Grid((0.0, 0.0, 0.0), (0.01, 0.01, 0.5), (3, 3, 3))
    marginal = obs_tables.build_marginal_table(
        BOX, TOP_DOWN, grid, offsets, workers=2, progress=False
    )
    nominal = build_table(BOX, TOP_DOWN, grid, workers=1, progress=False)
    np.testing.assert_array_equal(marginal.tables[0].progress, nominal.progress)
    assert nominal.contact.all()  # the box under the hand everywhere
    for k in (1, 2):
        t = marginal.tables[k]
        np.testing.assert_allclose(t.progress, nominal.progress + offsets[k, 2], atol=2e-4)
        np.testing.assert_allclose(
            t.stop_pose[:, 2, 3], nominal.stop_pose[:, 2, 3] - offsets[k, 2], atol=2e-4
        )
    obs = marginal.observations(4)
    assert [o.progress for o in obs] == [t.progress[4] for t in marginal.tables]


def test_the_bench_entry_times_a_fresh_build(capsys, monkeypatch):
    monkeypatch.setattr(Grid, "for_level", classmethod(lambda cls, level: COARSE))
    obs_tables.main(["--bench", "box", "--wrt", "goal", "--workers", "1", "--draws", "2"])
    out = capsys.readouterr().out
    assert "box, high grid (405 offsets), 1 workers" in out
    assert "goal" in out and "µs/simulation" in out and "marginal ×2 (realistic)" in out
