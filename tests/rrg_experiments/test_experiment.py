"""The experiment runner: the --quick preset runs real physics trials and writes consistent
outputs, the same on Ray as in local processes; a second run resumes (runs nothing new) and
refuses other campaigns' records; Fig. 9 is drawn from its records."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rrg_estimator.config import LEVELS
from rrg_experiments.experiment_cli import QUICK, main
from rrg_experiments.provenance import DEV_SEED, campaign_seed, code_version
from rrg_experiments.report import (
    fig9,
    fig9_frontier,
    fig9_paired,
    fig9_paired_table,
    fig9_table,
    summarize,
    wilson,
)
from rrg_experiments.trials import (
    CampaignMismatch,
    Cell,
    TrialSpec,
    check_stamps,
    drop_torn_tail,
    load_records,
    model_key,
    outcome,
    schedule,
)
from rrg_models.config import WORLD
from rrg_models.poses import relative_planar


@pytest.mark.slow  # a MuJoCo campaign
def test_quick_campaign_outputs_are_consistent_and_resumable(tmp_path):
    assert main(["--quick", "--dev", "--out", str(tmp_path), "--workers", "2"]) == 0
    for name in ("trials.jsonl", "table.md", "summary.json", "fig7_low.png", "fig8_high.png"):
        assert (tmp_path / name).stat().st_size > 0, name
    records = load_records(tmp_path / "trials.jsonl")
    n_cells = len(QUICK["objects"]) * len(QUICK["levels"]) * 3
    assert len(records) == n_cells * QUICK["trials"]
    summary = json.loads((tmp_path / "summary.json").read_text())
    campaign, summary = summary["campaign"], summary["cells"]
    assert campaign["commit"] == code_version() and campaign["world"] == "nominal"
    assert campaign["seed"] == DEV_SEED and campaign["seed_source"] == "--dev"
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
        assert (r["commit"], r["base_seed"], r["world"]) == (code_version(), DEV_SEED, "nominal")
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
    assert main(["--quick", "--dev", "--out", str(tmp_path), "--workers", "1"]) == 0
    assert len(load_records(tmp_path / "trials.jsonl")) == len(records)
    # The same campaign on a local Ray cluster: the same records, the same table.
    ray_out = tmp_path / "ray"
    assert main(["--quick", "--dev", "--out", str(ray_out), "--ray", "auto", "--workers", "2"]) == 0
    by_id = lambda rs: sorted((outcome(r) for r in rs), key=lambda r: r["id"])
    assert by_id(load_records(ray_out / "trials.jsonl")) == by_id(records)
    assert (ray_out / "table.md").read_bytes() == (tmp_path / "table.md").read_bytes()
    # Another seed, or another world, is refused rather than mixed in.
    assert main(["--quick", "--seed", "7", "--out", str(tmp_path)]) == 2
    assert main(["--quick", "--dev", "--world", "realistic", "--out", str(tmp_path)]) == 2
    assert len(load_records(tmp_path / "trials.jsonl")) == len(records)


def test_wilson_interval_matches_hand_computed_values_where_wald_fails():
    """1 of 10: Wilson's 95 % interval, by hand, is (p + z²/2n ± z √(p(1-p)/n + z²/4n²)) /
    (1 + z²/n) = 0.21102 ± 0.19314 → [0.0179, 0.4042]; the Wald interval p ± z √(p(1-p)/n)
    = 0.1 ± 0.1859 would reach below 0. 0 of 10: Wald collapses to [0, 0], Wilson's upper
    bound is (z²/n) / (1 + z²/n) = 0.2775. 95 of 100: Wilson [0.8882, 0.9785], Wald
    [0.9073, 0.9927]."""
    lo, hi = wilson(1, 10)
    assert lo == pytest.approx(0.017875, abs=1e-5) and hi == pytest.approx(0.404150, abs=1e-5)
    assert wilson(0, 10) == (0.0, pytest.approx(0.277540, abs=1e-5))
    assert wilson(10, 10) == (pytest.approx(1 - 0.277540, abs=1e-5), 1.0)
    lo, hi = wilson(95, 100)
    assert lo == pytest.approx(0.888246, abs=1e-5) and hi == pytest.approx(0.978457, abs=1e-5)


def test_a_wilson_interval_holds_its_proportion_exactly():
    """At k = n (k = 0) the upper (lower) end is exactly 1 (0): in floating point the formula
    left 1 less a round-off for 740 of n = 1 … 2000 (158, a campaign's top bin, among them),
    and the reliability diagram's error bar of an all-success bin came out negative, which
    matplotlib refuses."""
    for n in range(1, 2001):
        assert wilson(n, n)[1] == 1.0 and wilson(0, n)[0] == 0.0
        lo, hi = wilson(n // 3, n)
        assert lo <= (n // 3) / n <= hi


def test_the_base_seed_comes_from_the_code_version():
    """A reported campaign's seed is a function of the code version: another version,
    another seed; the development seed is reserved for probes."""
    import subprocess

    from rrg_experiments.provenance import CODE_PATHS, REPO_ROOT

    version = code_version()
    assert len(version) >= 12 and campaign_seed(version) == campaign_seed(version)
    # the last commit that changed the code: a commit of results or docs keeps the version
    last_code = subprocess.run(
        ["git", "-C", str(REPO_ROOT), "log", "-1", "--format=%H", "HEAD", "--", *CODE_PATHS],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    assert version.split("+")[0] == last_code
    assert campaign_seed(version) != campaign_seed(version + "x")
    assert campaign_seed(version) != DEV_SEED and 0 <= campaign_seed(version) < 2**32


def _record(i: int, **stamp) -> dict:
    return dict(id=f"box/low/rrg-info#{i}", commit="c1", base_seed=5, world="nominal") | stamp


def test_resume_cuts_a_half_written_line_and_refuses_other_campaigns(tmp_path):
    """A run killed while writing leaves a torn last line: it is dropped before appending, so
    the next record starts a line of its own; records of another code version, seed or world
    stop the resume with a clear error."""
    path = tmp_path / "trials.jsonl"
    lines = [json.dumps(_record(i)) for i in range(3)]
    path.write_text("\n".join(lines) + "\n" + lines[0][:17])
    drop_torn_tail(path)
    assert path.read_text() == "\n".join(lines) + "\n"
    assert [r["id"] for r in load_records(path)] == [f"box/low/rrg-info#{i}" for i in range(3)]
    stamp = dict(commit="c1", base_seed=5, world="nominal")
    check_stamps(load_records(path), stamp, path)  # same campaign: fine
    for key, other in (("commit", "c2"), ("base_seed", 6), ("world", "realistic")):
        with pytest.raises(CampaignMismatch, match=key):
            check_stamps(load_records(path), stamp | {key: other}, path)


@pytest.mark.slow  # a MuJoCo campaign killed partway
def test_a_killed_campaign_runs_only_its_missing_trials(tmp_path):
    """SIGKILL a --quick campaign once its first records are written; the rerun runs only
    the trials that are missing and each trial appears once."""
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "c"
    cmd = [sys.executable, "-m", "rrg_experiments.experiment_cli", "--quick", "--dev"]
    cmd += ["--workers", "1", "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    path = out / "trials.jsonl"
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and len(load_records(path)) < 3:
        time.sleep(0.2)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    before = load_records(path)
    total = len(QUICK["objects"]) * len(QUICK["levels"]) * 3 * QUICK["trials"]
    assert 3 <= len(before) < total
    with path.open("a") as f:  # as if killed mid-write
        f.write(json.dumps(before[0])[:25])
    log = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert log.returncode == 0, log.stderr[-2000:]
    after = load_records(path)
    ids = [r["id"] for r in after]
    assert len(ids) == len(set(ids)) == total
    assert after[: len(before)] == before  # the first run's records were kept as they were
    assert f"{total} trials, {len(before)} already done, {total - len(before)} to run" in log.stderr


def test_fig9(tmp_path):
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
        s["failures"]
        == dict(
            failed=2, declared=1, no_grasp=0, out_of_region=1, not_held=2, fingers=0, required=0
        )
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
    from rrg_experiments.experiment_cli import campaign_specs

    specs = campaign_specs(
        ["powerdrill", "cup"],
        ["low", "high"],
        ["open-loop", "rrg-goal", "rrg-info"],
        1,
        1,
        0,
        ablate=("verify", "probe"),
    )
    cells = {s.cell for s in specs}
    assert (
        len(cells) > 12
        and any(c.horizon != 2 for c in cells)
        and any(c.delta != 0.1 for c in cells)
    )
    ablated = {c for c in cells if c.without}
    assert len(ablated) == 8 and {c.without for c in ablated} == {("verify",), ("probe",)}
    assert Cell("cup", "low", "rrg-info", without=("verify", "confirm")).key == (
        "cup/low/rrg-info/without-confirm+verify"
    )
    for cell in cells:
        assert Cell.from_key(cell.key) == cell
    for bad in (
        "powerdrill/high",
        "powerdrill/high/rrg-info/dx",
        "powerdrill/high/rrg-info/d0.3/H1",
        "powerdrill/high/rrg-info/H2",
        "powerdrill/high/rrg-info/Q1",
        "powerdrill/high/rrg-info/without-verify+confirm",
        "powerdrill/high/rrg-info/without-wings",
    ):
        with pytest.raises(ValueError):
            Cell.from_key(bad)


def test_schedule_keeps_each_model_and_cell_together_longest_first():
    """The cells of one planning model run together (a worker loads it once), the models with
    the longest cells first (high before low, deeper searches first), and within a model its
    planning cells before open-loop; a cell's trials run together in index order; no trial is
    lost or repeated."""
    from rrg_experiments.experiment_cli import campaign_specs

    specs = campaign_specs(
        ["powerdrill", "cup"], ["low", "high"], ["open-loop", "rrg-goal", "rrg-info"], 3, 2, 0
    )
    order = schedule(specs[::-1])
    assert sorted(s.id for s in order) == sorted(s.id for s in specs)
    cells = [s.cell for s in order]
    first = [cells.index(c) for c in dict.fromkeys(cells)]
    runs = [cells[i:j] for i, j in zip(first, first[1:] + [len(cells)], strict=True)]
    assert all(len(set(run)) == 1 for run in runs)  # each cell's trials are contiguous
    for c in dict.fromkeys(cells):
        assert [s.index for s in order if s.cell == c] == sorted(
            s.index for s in specs if s.cell == c
        )
    assert cells[0].horizon == max(c.horizon for c in cells) and cells[0].level == "high"
    models = [model_key(c.object, c.level, "nominal", c.without) for c in cells]
    changes = [i for i in range(1, len(models)) if models[i] != models[i - 1]]
    assert len(changes) == len(set(models)) - 1  # each model's trials are contiguous
    for m in set(models):
        mine = [c for c, k in zip(cells, models, strict=True) if k == m]
        planning = [i for i, c in enumerate(mine) if c.strategy != "open-loop"]
        assert all(c.strategy == "open-loop" for c in mine[max(planning) + 1 :])
    assert all(c.level == "high" for c in cells[: changes[0]])
    assert cells[-1].level == "low" and cells[-1].strategy == "open-loop"


@pytest.mark.parametrize(
    "trial_id",
    ["powerdrill/high#3", "chair/high/rrg-info#3", "box/high/rrg-info#x", "box/medium/rrg-info#1"],
)
def test_replay_refuses_a_bad_trial_id(trial_id, capsys):
    assert main(["--replay", trial_id]) == 2
    assert "bad trial id" in capsys.readouterr().err


def test_replay_writes_records_that_replay_check_reproduces(tmp_path, capsys):
    """Several ids give one JSON line each; --replay-check runs them again and finds the same
    records (a field the old records lack is named, not a difference), and names the trial
    and the field of a record that differs."""
    ids = ["box/low/open-loop#0", "box/low/open-loop#1"]
    assert main(["--replay", *ids, "--seed", "7", "--world", "realistic", "--workers", "1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    records = [json.loads(line) for line in lines]
    assert [r["id"] for r in sorted(records, key=lambda r: r["trial"])] == ids
    assert {(r["base_seed"], r["world"]) for r in records} == {(7, "realistic")}
    assert all(r["commit"] for r in records)
    assert main(["--replay", ids[0], "--seed", "7", "--world", "nominal", "--workers", "1"]) == 0
    lines += capsys.readouterr().out.splitlines()  # the same id in another world
    path = tmp_path / "before.jsonl"
    path.write_text("\n".join(lines) + "\n")
    assert main(["--replay-check", str(path), "--workers", "1"]) == 0
    assert "3/3 trials gave the same records" in capsys.readouterr().out
    for r in records:  # records written before the judge named its goal grasp
        del r["judge"]["goal"]
    path.write_text("".join(json.dumps(r) + "\n" for r in records))
    assert main(["--replay-check", str(path), "--workers", "1"]) == 0
    out = capsys.readouterr().out
    assert "2/2 trials gave the same records" in out
    assert "fields the old records do not have: judge.goal" in out
    records[1]["n_actions"] += 1
    path.write_text("".join(json.dumps(r) + "\n" for r in records))
    assert main(["--replay-check", str(path), "--workers", "1"]) == 1
    out = capsys.readouterr().out
    assert f"DIFFERS {records[1]['id']}" in out and "n_actions: " in out
    assert "1/2 trials gave the same records" in out


def test_fig9_pairs_h2_with_h1_by_trial_with_a_bootstrap_interval():
    """Paired by trial index: H = 2 succeeds where H = 1 fails on 2 of 10 trials and takes
    one action fewer on each; the difference is +20 points and -1 action, its interval
    brackets it, and a constant difference has a degenerate interval."""
    records = [
        dict(
            object="powerdrill",
            level="high",
            strategy="rrg-info",
            horizon=h,
            delta=0.3,
            trial=i,
            success=(i >= 2) if h == 1 else True,
            n_actions=5 if h == 1 else 4,
        )
        for h in (1, 2)
        for i in range(10)
    ]
    paired = fig9_paired(records)
    d = paired["0.3"]
    assert d["pairs"] == 10
    assert d["success"]["diff"] == pytest.approx(0.2)
    lo, hi = d["success"]["ci95"]
    assert 0.0 <= lo < 0.2 < hi <= 0.5
    assert d["actions"]["diff"] == -1.0 and d["actions"]["ci95"] == [-1.0, -1.0]
    assert "| 0.3 | 10 | 80% → 100% | +20.0 pts" in fig9_paired_table(paired)
    # unpaired trials are left out
    records.append(dict(records[-1], trial=99))
    assert fig9_paired(records)["0.3"]["pairs"] == 10


def test_calibration_counts_declared_grasps_bins_and_leaves_out_other_cells():
    """P(goal) against the verdicts of hand-made records: the declared share that succeeded,
    the Brier score, failures observed against predicted per bin; Fig. 9's and the ablation's
    cells are not main cells."""
    from rrg_experiments.calibration import calibration, main_rrg_info

    def rec(obj, p, declared, success, **cell):
        base = dict(strategy="rrg-info", horizon=2, delta=0.1, without=[])
        return dict(
            base,
            **cell,
            object=obj,
            p_goal=p,
            declared=declared,
            success=success,
            judge={"in_region": success},
        )

    records = [
        rec("box", 0.95, True, True),
        rec("box", 0.95, True, False),
        rec("cup", 0.99, True, True),
        rec("cup", 0.2, False, False),
        rec("cup", float("nan"), False, False) | {"judge": {}},  # no goal grasp ran
        rec("box", 0.95, True, False, delta=0.3),  # Fig. 9
        rec("box", 0.95, True, False, without=["verify"]),  # an ablation cell
    ]
    main = main_rrg_info(records)
    assert len(main) == 5
    cal = calibration(main)
    assert cal["declared"]["n"] == 3 and cal["declared"]["k"] == 2
    assert cal["undeclared_share"] == pytest.approx(2 / 5)
    p, ok = np.array([0.95, 0.95, 0.99, 0.2]), np.array([1, 0, 1, 0])
    assert cal["brier"] == pytest.approx(np.mean((p - ok) ** 2))
    bins = {(b["lo"], b["hi"]): b for b in cal["bins"]}
    assert bins[0.95, 0.99]["observed_failures"] == 1
    assert bins[0.95, 0.99]["predicted_failures"] == pytest.approx(0.1)
    assert cal["objects"]["box"]["declared"]["k"] == 1 and cal["objects"]["cup"]["undeclared"] == 2


def test_the_ablation_pairs_each_switched_off_capability_with_every_capability_on():
    """Hand-made records: without ``verify`` the box loses 2 of 10 trials and the cup none;
    the table gives the paired change per object and over both, and leaves out an object
    with no ablation cell; records with no ablation give no ablation."""
    from rrg_experiments.report import ablation, ablation_table

    def rec(obj, i, success, without=()):
        return dict(
            object=obj,
            level="high",
            strategy="rrg-info",
            horizon=2,
            delta=0.1,
            without=list(without),
            trial=i,
            success=success,
            n_actions=4,
        )

    on = [rec(o, i, True) for o in ("box", "cup", "can") for i in range(10)]
    off = [rec("box", i, i >= 2, ["verify"]) for i in range(10)]
    off += [rec("cup", i, True, ["verify"]) for i in range(10)]
    ab = ablation(on + off)
    row = ab["high"]["verify"]
    assert set(row) == {"box", "cup", "all"}
    assert row["box"]["pairs"] == 10 and row["box"]["success"]["diff"] == pytest.approx(-0.2)
    assert row["cup"]["success"]["diff"] == 0.0
    assert row["all"]["pairs"] == 20 and row["all"]["success"]["diff"] == pytest.approx(-0.1)
    table = ablation_table(ab)
    assert "| box | 10 | 100% | -20 (" in table and "| **all** | 20 | 100% | -10 (" in table
    assert "can" not in table
    assert ablation(on) == {}


def test_the_sensed_finger_judge_counts_what_the_robot_sensed_not_what_touched():
    """The judge before it counted true contacts: a grasp held in its region with three
    fingers touching but two sensed fails it (the box needs three), and passes the true one."""
    from rrg_experiments.report import sensed_judge_success, summarize

    judge = dict(held=True, in_region=True, required_ok=True, fingers=3, fingers_ok=True)
    missed_pad = dict(
        object="box",
        level="high",
        strategy="rrg-info",
        horizon=2,
        delta=0.1,
        cell="box/high/rrg-info",
        success=True,
        n_actions=3,
        planning_time_s=0.1,
        error="",
        judge=dict(judge, sensed_fingers=2),
    )
    sensed_all = dict(missed_pad, judge=dict(judge, sensed_fingers=3))
    assert not sensed_judge_success(missed_pad) and sensed_judge_success(sensed_all)
    assert not sensed_judge_success(dict(missed_pad, judge={}))  # no goal grasp judged
    s = summarize([missed_pad, sensed_all])["box/high/rrg-info"]
    assert s["success_rate"] == 1.0 and s["sensed_judge_rate"] == 0.5


def test_report_rewrites_the_outputs_of_recorded_trials_without_running_any(tmp_path, capsys):
    """--report reads trials.jsonl, keeps the records' own code version, seed and world, and
    runs nothing; with no records it exits with status 2."""
    from rrg_experiments.experiment_cli import main

    assert main(["--report", "--out", str(tmp_path)]) == 2
    rec = dict(
        id="box/high/rrg-info#0",
        cell="box/high/rrg-info",
        object="box",
        level="high",
        strategy="rrg-info",
        horizon=2,
        delta=0.1,
        without=[],
        trial=0,
        base_seed=123,
        world="realistic",
        commit="abc1234",
        success=True,
        declared=True,
        p_goal=0.95,
        n_actions=3,
        planning_time_s=0.1,
        error="",
        judge=dict(
            held=True,
            in_region=True,
            required_ok=True,
            fingers=3,
            fingers_ok=True,
            sensed_fingers=3,
            strict_success=True,
        ),
    )
    (tmp_path / "trials.jsonl").write_text(json.dumps(rec) + "\n")
    assert main(["--report", "--out", str(tmp_path)]) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["campaign"]["commit"] == "abc1234" and summary["campaign"]["seed"] == 123
    assert summary["campaign"]["world"] == "realistic" and summary["campaign"]["trials"] == 1
    assert summary["campaign"]["seed_source"] == "--seed"  # not the one drawn from abc1234
    assert (tmp_path / "fig8_high.png").exists() and not (tmp_path / "fig7_low.png").exists()
    assert "| box | – | – | 100% (1/1" in capsys.readouterr().out


def test_a_worker_keeps_its_most_recent_models_only():
    """The worker caches keep the most recently used entries up to their bound, building each
    on a miss only (a campaign of any length has bounded memory)."""
    from collections import OrderedDict

    from rrg_experiments.trials import _cached

    cache, built = OrderedDict(), []

    def get(key):
        return _cached(cache, key, 2, lambda: built.append(key) or key.upper())

    assert [get(k) for k in "abab"] == ["A", "B", "A", "B"] and built == ["a", "b"]
    get("c")  # evicts a, the least recently used
    assert list(cache) == ["b", "c"]
    get("b")
    get("a")  # a again: built anew; c was least recently used
    assert list(cache) == ["b", "a"] and built == ["a", "b", "c", "a"]
