"""Campaign outputs: per-cell summary with 95 % intervals, the markdown table, and the
paper's Fig. 7 (low), Fig. 8 (high) and Fig. 9 (δ sweep on the drill) as PNGs."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from rrg_experiments.calibration import (
    calibration,
    calibration_table,
    main_rrg_info,
    reliability_diagram,
    rrg_info_at_defaults,
    wilson,
)
from rrg_models.objects import PAPER_OBJECTS
from rrg_models.objects.catalogue import get_object
from rrg_planner.config import SEARCH

STRATEGY_LABELS = {"open-loop": "Open-loop", "rrg-goal": "RRG-Goal", "rrg-info": "RRG-Info"}


def paper_rrg_info(obj: str, level: str) -> str:
    """What the paper's text reports for RRG-Info (H = 2), for the side-by-side table ("–"
    for an object not in the paper)."""
    if obj not in PAPER_OBJECTS:
        return "–"
    if level == "low":
        return "89%" if obj == "teabox" else ">97%"
    return "<95%" if obj in ("cup", "teabox") else ">95%"


def sensed_judge_success(record: dict) -> bool:
    """The trial's verdict under the judge that counted the fingers the robot *sensed* (a pad
    or fingertip fired) instead of those truly touching: kept so that a campaign shows what
    judging the truth changed (rrg_sim.physics.judge)."""
    j = record.get("judge") or {}
    if not j:
        return False
    if "sensed_fingers" in j:
        enough = j["sensed_fingers"] >= get_object(record["object"]).goal.min_fingers
    else:  # a record of that judge itself: its fingers were the sensed ones
        enough = j.get("fingers_ok", True)
    return bool(j.get("held") and j.get("in_region") and j.get("required_ok", True) and enough)


def summarize(records: list[dict]) -> dict[str, dict]:
    """Per cell key: trials, successes, rate, 95 % interval, the success under the sensed-finger
    judge, mean actions, planning time, errors."""
    by_cell: dict[str, list[dict]] = defaultdict(list)
    for r in records:
        by_cell[r["cell"]].append(r)
    out = {}
    for key, rs in sorted(by_cell.items()):
        k = sum(bool(r["success"]) for r in rs)
        lo, hi = wilson(k, len(rs))
        strict = sum(bool((r.get("judge") or {}).get("strict_success", False)) for r in rs)
        out[key] = dict(
            object=rs[0]["object"],
            level=rs[0]["level"],
            strategy=rs[0]["strategy"],
            horizon=rs[0]["horizon"],
            delta=rs[0]["delta"],
            trials=len(rs),
            successes=k,
            success_rate=k / len(rs),
            ci95=[lo, hi],
            strict_successes=strict,
            strict_rate=strict / len(rs),
            strict_ci95=list(wilson(strict, len(rs))),
            sensed_judge_rate=sum(sensed_judge_success(r) for r in rs) / len(rs),
            mean_actions=float(np.mean([r["n_actions"] for r in rs])),
            mean_planning_s=float(np.mean([r["planning_time_s"] for r in rs])),
            errors=sum(bool(r["error"]) for r in rs),
            failures=failure_reasons(rs),
        )
    return out


#: The judge's reasons for a failed grasp: (key, label, the judged field that must hold)
JUDGE_REASONS = (
    ("out_of_region", "out of goal region", "in_region"),
    ("not_held", "not held", "held"),
    ("fingers", "too few fingers", "fingers_ok"),
    ("required", "required contact missed", "required_ok"),
)


def judged_failures(judged: dict) -> list[str]:
    """The labels of the JUDGE_REASONS a judged grasp (physics.judge.judge_grasp) fails."""
    return [label for _, label, field in JUDGE_REASONS if not judged.get(field, True)]


def failure_reasons(records: list[dict]) -> dict[str, int]:
    """Why the failed trials of a cell failed (a trial can count under several judge reasons):
    declared (the agent believed P(G) > 1 − δ), no_grasp (no goal grasp judged: nothing was
    feasible, or the trial crashed), out_of_region, not_held, fingers (too few in contact),
    required (a required contact missed)."""
    failed = [r for r in records if not r["success"]]
    judged = [r.get("judge") or {} for r in failed]
    labels = [judged_failures(j) for j in judged if j]
    return dict(
        failed=len(failed),
        declared=sum(bool(r["declared"]) for r in failed),
        no_grasp=sum(not j for j in judged),
        **{key: sum(label in f for f in labels) for key, label, _ in JUDGE_REASONS},
    )


def failure_table(
    summary: dict[str, dict], objects: list[str], levels: list[str], strategy: str = "rrg-info"
) -> str:
    """Markdown: the failed trials of one strategy per object and level, by reason."""
    lines = [
        f"**why {STRATEGY_LABELS[strategy]} trials failed** (a trial may have several reasons)",
        "",
        "| object | level | failed | declared success | no grasp judged | out of goal region "
        "| not held | too few fingers | required contact missed |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for level in levels:
        for obj in objects:
            s = summary.get(f"{obj}/{level}/{strategy}")
            if s is None or not s.get("failures", {}).get("failed"):
                continue
            f = s["failures"]
            lines.append(
                f"| {obj} | {level} | {f['failed']}/{s['trials']} | {f['declared']} | "
                f"{f['no_grasp']} | {f['out_of_region']} | {f['not_held']} | "
                f"{f.get('fingers', 0)} | {f.get('required', 0)} |"
            )
    return "\n".join(lines) + "\n"


def markdown_table(summary: dict[str, dict], objects: list[str], levels: list[str]) -> str:
    """Success % per object × strategy × level with n and the 95 % interval, beside the paper."""
    lines = []
    for level in levels:
        lines += [
            f"**{level} uncertainty**",
            "",
            "| object | open-loop | RRG-Goal | RRG-Info (H=2) | RRG-Info, strict "
            "| RRG-Info, sensed-finger judge | paper RRG-Info | mean actions (Info) |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for obj in objects:
            cells = []
            for strat in ("open-loop", "rrg-goal", "rrg-info"):
                s = summary.get(f"{obj}/{level}/{strat}")
                cells.append(
                    "–"
                    if s is None
                    else f"{100 * s['success_rate']:.0f}% ({s['successes']}/{s['trials']}, "
                    f"{100 * s['ci95'][0]:.0f}–{100 * s['ci95'][1]:.0f})"
                )
            info = summary.get(f"{obj}/{level}/rrg-info")
            acts = f"{info['mean_actions']:.1f}" if info else "–"
            strict = (
                f"{100 * info['strict_rate']:.0f}% ({info['strict_successes']}/{info['trials']})"
                if info
                else "–"
            )
            sensed = f"{100 * info['sensed_judge_rate']:.0f}%" if info else "–"
            lines.append(
                f"| {obj} | "
                + " | ".join(cells)
                + f" | {strict} | {sensed} | {paper_rrg_info(obj, level)} | {acts} |"
            )
        lines.append("")
    return "\n".join(lines)


def bar_chart(
    summary: dict[str, dict], objects: list[str], level: str, path: Path, title: str
) -> None:
    """Fig. 7/8: success % per object for the strategies that ran, with 95 % intervals (a
    strategy with no cell at this level is left out, not drawn at 0 %)."""
    fig, ax = plt.subplots(figsize=(11, 4))
    width = 0.27
    x = np.arange(len(objects))
    for i, strat in enumerate(("open-loop", "rrg-goal", "rrg-info")):
        cells = [summary.get(f"{obj}/{level}/{strat}") for obj in objects]
        if not any(cells):
            continue
        rates = np.array([100 * s["success_rate"] if s else np.nan for s in cells])
        err = np.array(
            [  # ≥ 0 despite rounding
                [max(0.0, r - 100 * s["ci95"][0]), max(0.0, 100 * s["ci95"][1] - r)]
                if s
                else [np.nan, np.nan]
                for r, s in zip(rates, cells)
            ]
        ).T
        ax.bar(
            x + (i - 1) * width,
            rates,
            width,
            yerr=err,
            capsize=2,
            color=f"C{i}",  # one colour per strategy in every figure
            label=STRATEGY_LABELS[strat],
        )
    ax.axhline(95, color="k", lw=0.8, ls="--", label="95 % target")
    ax.set_xticks(x, objects, rotation=20)
    ax.set_ylabel("success (%)")
    ax.set_ylim(0, 105)
    ax.set_title(title)
    ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8)  # outside: bars reach 100 %
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def fig9_curves(
    summary: dict[str, dict], obj: str = "powerdrill", level: str = "high"
) -> dict[str, list[dict]]:
    """Fig. 9's curves: name (RRG-Goal, RRG-Info H=1…3) → its cells' summaries, by name."""
    curves: dict[str, list[dict]] = defaultdict(list)
    for s in summary.values():
        if s["object"] == obj and s["level"] == level and s["strategy"] != "open-loop":
            curves[
                "RRG-Goal" if s["strategy"] == "rrg-goal" else f"RRG-Info H={s['horizon']}"
            ].append(s)
    return dict(sorted(curves.items()))


def fig9(
    summary: dict[str, dict], path: Path, obj: str = "powerdrill", level: str = "high"
) -> None:
    """Fig. 9: success % against mean actions, δ swept, RRG-Goal and RRG-Info at H = 1, 2, 3."""
    fig, ax = plt.subplots(figsize=(6, 4.5))
    for name, cells in fig9_curves(summary, obj, level).items():
        pts = sorted((s["mean_actions"], 100 * s["success_rate"]) for s in cells)
        ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", label=name)
    ax.axhline(90, color="k", lw=0.8, ls="--")
    ax.set_xlabel("mean number of actions")
    ax.set_ylabel("success (%)")
    ax.set_title(f"{obj}, {level} uncertainty, δ swept")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def fig9_frontier(
    summary: dict[str, dict], obj: str = "powerdrill", level: str = "high", target: float = 0.9
) -> dict[str, dict | None]:
    """Per Fig. 9 curve (RRG-Goal, RRG-Info H=1…3): its point with the fewest mean actions at
    or above ``target`` success (the cell's summary), or None if no point reaches it."""
    return {
        name: min(
            (s for s in cells if s["success_rate"] >= target),
            key=lambda s: s["mean_actions"],
            default=None,
        )
        for name, cells in fig9_curves(summary, obj, level).items()
    }


def fig9_table(summary: dict[str, dict], target: float = 0.9) -> str:
    """Markdown: each Fig. 9 curve's fewest mean actions at ≥ target success (fig9_frontier)."""
    rows = [
        f"**Fig. 9: fewest mean actions at ≥ {target:.0%} success (powerdrill, high)**",
        "",
        "| curve | success | mean actions | δ |",
        "|---|---|---|---|",
    ]
    for name, s in fig9_frontier(summary, target=target).items():
        rows.append(
            f"| {name} | none reaches {target:.0%} | | |"
            if s is None
            else f"| {name} | {s['success_rate']:.0%} ({s['successes']}/{s['trials']}) | "
            f"{s['mean_actions']:.2f} | {s['delta']:g} |"
        )
    return "\n".join(rows) + "\n"


def campaign_header(campaign: dict) -> str:
    """Markdown: the code version, base seed and world profile the table comes from."""
    return (
        f"World profile **{campaign['world']}**; base seed {campaign['seed']} "
        f"({campaign['seed_source']}); code {campaign['commit']}.\n"
    )


def paired_difference(
    a: list[dict], b: list[dict], n_boot: int = 10_000, seed: int = 0
) -> dict | None:
    """Trials of two sets paired by object, level and trial index (the same true poses): the
    mean difference b − a in success and in the number of actions, each with a 95 % percentile
    bootstrap interval over the pairs (``n_boot`` resamples, seeded). None without common
    trials."""

    def key(r: dict) -> tuple:
        return r.get("object"), r.get("level"), r["trial"]

    by_trial = {key(r): r for r in a}
    pairs = [(by_trial[key(r)], r) for r in b if key(r) in by_trial]
    if not pairs:
        return None
    success = np.array([[ra["success"], rb["success"]] for ra, rb in pairs], dtype=float)
    actions = np.array([[ra["n_actions"], rb["n_actions"]] for ra, rb in pairs], dtype=float)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(pairs), (n_boot, len(pairs)))
    out = dict(pairs=len(pairs))
    for name, values in (("success", success), ("actions", actions)):
        diff = values[:, 1] - values[:, 0]
        boot = diff[idx].mean(axis=1)
        lo, hi = np.percentile(boot, [2.5, 97.5])
        out[name] = dict(a=float(values[:, 0].mean()), b=float(values[:, 1].mean()))
        out[name].update(diff=float(diff.mean()), ci95=[float(lo), float(hi)])
    return out


def fig9_paired(records: list[dict], obj: str = "powerdrill", level: str = "high") -> dict:
    """Fig. 9's H = 2 against H = 1 at every δ both ran (paired_difference), by δ."""
    cells: dict[tuple[int, float], list[dict]] = defaultdict(list)
    for r in records:
        if (r["object"], r["level"], r["strategy"]) == (obj, level, "rrg-info"):
            cells[r["horizon"], r["delta"]].append(r)
    out = {}
    for delta in sorted({d for _, d in cells}, reverse=True):
        if (1, delta) in cells and (2, delta) in cells:
            out[f"{delta:g}"] = paired_difference(cells[1, delta], cells[2, delta])
    return out


def fig9_paired_table(paired: dict) -> str:
    """Markdown: H = 2 − H = 1 per δ, success and actions, with the bootstrap intervals."""
    rows = [
        "**Fig. 9: H = 2 against H = 1 on the same trials (powerdrill, high)**: difference "
        "H = 2 − H = 1, 95 % paired bootstrap interval",
        "",
        "| δ | pairs | success H=1 → H=2 | Δ success | mean actions H=1 → H=2 | Δ actions |",
        "|---|---|---|---|---|---|",
    ]
    for delta, d in paired.items():
        s, a = d["success"], d["actions"]
        rows.append(
            f"| {delta} | {d['pairs']} | {s['a']:.0%} → {s['b']:.0%} | "
            f"{100 * s['diff']:+.1f} pts "
            f"({100 * s['ci95'][0]:+.1f} to {100 * s['ci95'][1]:+.1f}) | "
            f"{a['a']:.2f} → {a['b']:.2f} | {a['diff']:+.2f} ({a['ci95'][0]:+.2f} to "
            f"{a['ci95'][1]:+.2f}) |"
        )
    return "\n".join(rows) + "\n"


def ablation(records: list[dict]) -> dict:
    """Per level and switched-off capability: RRG-Info's main cells (every capability on)
    against the same trials without it (paired_difference), per object and over all objects
    that ran both. Empty without ablation cells."""
    full = main_rrg_info(records)
    out: dict = {}
    for r in records:
        if rrg_info_at_defaults(r) and len(r.get("without") or []) == 1:
            out.setdefault(r["level"], {}).setdefault(r["without"][0], {}).setdefault(
                r["object"], []
            ).append(r)
    result: dict = {}
    for level, by_capability in sorted(out.items()):
        for capability, by_object in sorted(by_capability.items()):
            row = {}
            for obj, off in sorted(by_object.items()):
                on = [r for r in full if (r["object"], r["level"]) == (obj, level)]
                row[obj] = paired_difference(on, off)
            both = [o for o, d in row.items() if d is not None]
            on = [r for r in full if r["level"] == level and r["object"] in both]
            off = [r for o in both for r in by_object[o]]
            row["all"] = paired_difference(on, off)
            result.setdefault(level, {})[capability] = row
    return result


def ablation_table(ab: dict) -> str:
    """Markdown: per level, RRG-Info's success with every capability on, and the change when
    each one is switched off (paired points, 95 % bootstrap interval), per object."""
    rows = []
    for level, by_capability in ab.items():
        capabilities = list(by_capability)
        objects = sorted({o for row in by_capability.values() for o in row if o != "all"})
        rows += [
            f"**Ablation, {level} uncertainty**: RRG-Info success with every capability on, and "
            "the change without each (paired by trial, 95 % bootstrap interval)",
            "",
            "| object | pairs | all on | "
            + " | ".join(f"without {c}" for c in capabilities)
            + " |",
            "|---|---|---|" + "---|" * len(capabilities),
        ]
        for obj in [*objects, "all"]:
            ds = [by_capability[c].get(obj) for c in capabilities]
            first = next((d for d in ds if d is not None), None)
            if first is None:
                continue
            cells = [
                "–"
                if d is None
                else f"{100 * d['success']['diff']:+.0f} ({100 * d['success']['ci95'][0]:+.0f} "
                f"to {100 * d['success']['ci95'][1]:+.0f})"
                for d in ds
            ]
            name = "**all**" if obj == "all" else obj
            rows.append(
                f"| {name} | {first['pairs']} | {first['success']['a']:.0%} | "
                + " | ".join(cells)
                + " |"
            )
        rows.append("")
    return "\n".join(rows)


def write_outputs(
    records: list[dict], out_dir: Path, objects: list[str], levels: list[str], campaign: dict
) -> dict:
    """summary.json ({"campaign": its stamp, "cells": per-cell summaries}), table.md and the
    figures that the records support; returns the summary."""
    out_dir.mkdir(parents=True, exist_ok=True)
    cells = summarize(records)
    paired = fig9_paired(records)
    info = main_rrg_info(records)
    cal = calibration(info) if info else None
    ab = ablation(records)
    summary = dict(
        campaign=dict(campaign, trials=len(records)),
        cells=cells,
        fig9_paired=paired,
        calibration=cal,
        ablation=ab,
    )
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=1))
    fig9_cells = any(
        s["delta"] != SEARCH.delta or s["horizon"] != SEARCH.horizon for s in cells.values()
    )
    (out_dir / "table.md").write_text(
        campaign_header(campaign)
        + "\n"
        + markdown_table(cells, objects, levels)
        + "\n"
        + failure_table(cells, objects, levels)
        + ("\n" + fig9_table(cells) if fig9_cells else "")
        + ("\n" + fig9_paired_table(paired) if paired else "")
        + ("\n" + calibration_table(cal) if cal else "")
        + ("\n" + ablation_table(ab) if ab else "")
    )
    if cal:
        reliability_diagram(
            cal, out_dir / "calibration.png", f"RRG-Info P(goal), {campaign['world']} world"
        )
    titles = {
        "low": "Fig. 7: simulation, low uncertainty (1 cm, 1 cm, 3°)",
        "high": "Fig. 8: simulation, high uncertainty (5 cm, 5 cm, 30°)",
    }
    for level, fig_name in (("low", "fig7_low.png"), ("high", "fig8_high.png")):
        if level in levels:
            bar_chart(
                cells, objects, level, out_dir / fig_name, f"{titles[level]}, {campaign['world']}"
            )
    if fig9_cells:
        fig9(cells, out_dir / "fig9_powerdrill.png")
    return summary
