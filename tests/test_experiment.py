"""The experiment runner: the --quick preset runs real physics trials and writes consistent
outputs; a second run resumes (runs nothing new); Fig. 9 is drawn from its records."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rrg_estimator.config import LEVELS
from rrg_planner.experiment.experiment_cli import QUICK, main
from rrg_planner.experiment.report import fig9, fig9_frontier, fig9_table, summarize, wilson
from rrg_planner.experiment.trials import Cell, TrialSpec, load_records
from rrg_sim.config import WORLD
from rrg_sim.poses import relative_planar


@pytest.mark.slow  # a MuJoCo campaign
def test_quick_campaign_outputs_are_consistent_and_resumable(tmp_path):
    assert main(["--quick", "--out", str(tmp_path), "--workers", "2"]) == 0
    for name in ("trials.jsonl", "table.md", "summary.json", "fig7_low.png", "fig8_high.png"):
        assert (tmp_path / name).stat().st_size > 0, name
    records = load_records(tmp_path / "trials.jsonl")
    n_cells = len(QUICK["objects"]) * len(QUICK["levels"]) * 3
    assert len(records) == n_cells * QUICK["trials"]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert len(summary) == n_cells
    for key, s in summary.items():
        rs = [r for r in records if r["cell"] == key]
        assert s["trials"] == len(rs) == QUICK["trials"]
        assert s["successes"] == sum(r["success"] for r in rs)
        assert s["success_rate"] == pytest.approx(s["successes"] / s["trials"])
        assert s["ci95"][0] <= s["success_rate"] <= s["ci95"][1]
    table = (tmp_path / "table.md").read_text()
    for s in summary.values():  # every cell's rate appears in its object's row
        row = next(
            line
            for line in table.splitlines()
            if line.startswith(f"| {s['object']} |")
            and line in table.split(f"**{s['level']} uncertainty**")[1].split("**")[0]
        )
        assert f"{s['successes']}/{s['trials']}" in row
    for r in records:
        assert not r["error"], r
        assert 1 <= r["n_actions"] <= 10 and len(r["actions"]) == r["n_actions"]
        assert r["strategy"] != "open-loop" or r["actions"] == ["goal"]
        # The record's seed replays its true pose, drawn from the level's initial Gaussian.
        spec = TrialSpec(Cell(r["object"], r["level"], r["strategy"]), r["trial"], 0)
        assert spec.seed == r["seed"]
        np.testing.assert_allclose(spec.true_pose(), r["true_pose"])
        d = relative_planar(np.asarray(WORLD.nominal_pose), np.asarray(r["true_pose"]))
        assert np.all(np.abs(d) < 5 * np.asarray(LEVELS[r["level"]].sigma))
    # Strategies of a level face the same true poses (paired comparison).
    by_trial = {}
    for r in records:
        by_trial.setdefault((r["level"], r["trial"]), set()).add(tuple(r["true_pose"]))
    assert all(len(v) == 1 for v in by_trial.values())
    # Resume: nothing new runs, nothing is duplicated.
    assert main(["--quick", "--out", str(tmp_path), "--workers", "1"]) == 0
    assert len(load_records(tmp_path / "trials.jsonl")) == len(records)


def test_wilson_interval_and_fig9(tmp_path):
    assert wilson(0, 10)[0] == 0.0 and wilson(10, 10)[1] == 1.0
    lo, hi = wilson(95, 100)
    assert lo < 0.95 < hi and hi - lo < 0.1
    records = [
        dict(
            cell=f"powerdrill/high/rrg-info/H{h}/d{d}",
            object="powerdrill",
            level="high",
            strategy="rrg-info",
            horizon=h,
            delta=d,
            success=i % 3 != 0,
            n_actions=3 + h,
            planning_time_s=0.1,
            error="",
            declared=i == 3,
            judge=dict(in_region=i != 0, held=False) if i in (0, 3) else {},
        )
        for h in (1, 2, 3)
        for d in (0.3, 0.1)
        for i in range(6)
    ]
    summary = summarize(records)
    assert len(summary) == 6
    # trials 0 and 3 of every cell failed: 0 out of the goal region and dropped, 3 dropped
    # though declared
    assert all(
        s["failures"] == dict(failed=2, declared=1, no_grasp=0, out_of_region=1, not_held=2)
        for s in summary.values()
    )
    fig9(summary, tmp_path / "fig9.png")
    assert (tmp_path / "fig9.png").stat().st_size > 0


def test_fig9_frontier_is_each_curves_fewest_actions_at_90_percent():
    """A curve's frontier point is its cheapest δ that still succeeds ≥ 90 %; a curve whose
    points all fall short has none."""
    cells = {
        (1, 0.5): (8, 3.0),
        (1, 0.3): (9, 4.0),
        (1, 0.1): (10, 5.0),  # (successes of 10, actions)
        (2, 0.5): (9, 3.5),
        (2, 0.3): (10, 4.5),
        (3, 0.3): (8, 4.0),
    }
    records = [
        dict(
            cell=f"powerdrill/high/rrg-info/H{h}/d{d}",
            object="powerdrill",
            level="high",
            strategy="rrg-info",
            horizon=h,
            delta=d,
            success=i < k,
            n_actions=n,
            planning_time_s=0.1,
            error="",
            declared=False,
            judge={},
        )
        for (h, d), (k, n) in cells.items()
        for i in range(10)
    ]
    front = fig9_frontier(summarize(records))
    assert front["RRG-Info H=1"]["delta"] == 0.3 and front["RRG-Info H=1"]["mean_actions"] == 4.0
    assert front["RRG-Info H=2"]["delta"] == 0.5 and front["RRG-Info H=2"]["mean_actions"] == 3.5
    assert front["RRG-Info H=3"] is None
    table = fig9_table(summarize(records))
    assert "| RRG-Info H=2 | 90% (9/10) | 3.50 | 0.5 |" in table and "none reaches 90%" in table


def test_a_cell_key_names_its_cell_and_nothing_else():
    """Cell.from_key inverts Cell.key for every campaign cell (so a trial replays from its id
    alone); malformed or non-canonical keys are refused."""
    from rrg_planner.experiment.experiment_cli import campaign_specs

    specs = campaign_specs(
        ["powerdrill", "cup"], ["low", "high"], ["open-loop", "rrg-goal", "rrg-info"], 1, 1, 0
    )
    cells = {s.cell for s in specs}
    assert (
        len(cells) > 12
        and any(c.horizon != 2 for c in cells)
        and any(c.delta != 0.1 for c in cells)
    )
    for cell in cells:
        assert Cell.from_key(cell.key) == cell
    for bad in (
        "powerdrill/high",
        "powerdrill/high/rrg-info/dx",
        "powerdrill/high/rrg-info/d0.3/H1",
        "powerdrill/high/rrg-info/H2",
        "powerdrill/high/rrg-info/Q1",
    ):
        with pytest.raises(ValueError):
            Cell.from_key(bad)


@pytest.mark.parametrize(
    "trial_id",
    ["powerdrill/high#3", "chair/high/rrg-info#3", "box/high/rrg-info#x", "box/medium/rrg-info#1"],
)
def test_replay_refuses_a_bad_trial_id(trial_id, capsys):
    assert main(["--replay", trial_id]) == 2
    assert "bad trial id" in capsys.readouterr().err
