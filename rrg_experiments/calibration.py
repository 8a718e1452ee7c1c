"""Does P(goal) tell the truth? The calibration of a campaign's RRG-Info trials: P(goal) at the
end of each run against the judge's verdict, as a reliability diagram with Wilson intervals,
the Brier score, and per object the share of declared grasps that succeed.

A run *declares* when its last goal grasp was believed to hold (P(goal) > 1 − δ). Its P(goal)
is the planner's: the belief's P_b(G) of that grasp, or 0 when the grasp's own observation
failed its check (rrg_planner.agent.RobustGraspAgent.verify_goal). A run that ran no goal grasp
(nothing feasible, or a crash) has no P(goal) and counts as not declared.
"""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from rrg_planner.config import SEARCH

#: Bin edges of P(goal) for the reliability diagram (chosen: the declared grasps split at the
#: audit's 0.95 and 0.99, the undeclared ones at 0.5).
BINS = (0.0, 0.5, 0.9, 0.95, 0.99, 1.0)


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score 95 % interval of a binomial proportion (it holds k/n: at k = n its upper
    end is exactly 1, not 1 less a round-off)."""
    if n == 0:
        return (0.0, 1.0)
    p = k / n
    den = 1 + z * z / n
    mid = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return (min(p, max(0.0, mid - half)), max(p, min(1.0, mid + half)))


def rrg_info_at_defaults(record: dict) -> bool:
    """Whether a record is RRG-Info at the default H and δ (not Fig. 9's sweep), with every
    capability on or some switched off (an ablation's cell)."""
    return (record["strategy"], record["horizon"], record["delta"]) == (
        "rrg-info",
        SEARCH.horizon,
        SEARCH.delta,
    )


def main_rrg_info(records: list[dict]) -> list[dict]:
    """The RRG-Info records of the main cells (H and δ the defaults, not Fig. 9's sweep, and
    every capability on, not an ablation's cell)."""
    return [r for r in records if rrg_info_at_defaults(r) and not r.get("without")]


def _judged(records: list[dict]) -> list[dict]:
    """The records whose run ended on a goal grasp with a P(goal)."""
    return [r for r in records if r.get("judge") and math.isfinite(r["p_goal"])]


def _share(k: int, n: int) -> dict:
    lo, hi = wilson(k, n)
    return dict(n=n, k=k, rate=k / n if n else float("nan"), ci95=[lo, hi])


def calibration(records: list[dict]) -> dict:
    """P(goal) against success over ``records`` (one strategy's trials, e.g. main_rrg_info):

    trials; declared (count, and the share that succeeded with its interval); undeclared_share;
    mean_p_declared; brier (over every run with a P(goal)) and brier_declared; bins (BINS: n,
    mean P(goal), successes with their interval, predicted failures Σ(1 − P), observed
    failures, their ratio); objects (per object: declared, the share that succeeded, mean
    P(goal) at declaration, undeclared).
    """
    judged = _judged(records)
    p = np.array([r["p_goal"] for r in judged], dtype=float)
    ok = np.array([bool(r["success"]) for r in judged], dtype=float)
    declared = [r for r in records if r["declared"]]
    pd = np.array([r["p_goal"] for r in declared], dtype=float)
    okd = np.array([bool(r["success"]) for r in declared], dtype=float)
    bins = []
    edges = np.asarray(BINS)
    which = np.clip(np.searchsorted(edges, p, side="right") - 1, 0, len(edges) - 2)
    for b in range(len(edges) - 1):
        sel = which == b
        n = int(sel.sum())
        if n == 0:
            continue
        predicted = float((1.0 - p[sel]).sum())
        observed = int(n - ok[sel].sum())
        ratio = observed / predicted if predicted > 0 else float("inf" if observed else "nan")
        bins.append(
            dict(
                lo=float(edges[b]),
                hi=float(edges[b + 1]),
                mean_p=float(p[sel].mean()),
                successes=_share(int(ok[sel].sum()), n),
                predicted_failures=predicted,
                observed_failures=observed,
                failure_ratio=ratio,
            )
        )
    by_object: dict[str, list[dict]] = defaultdict(list)
    for r in records:
        by_object[r["object"]].append(r)
    objects = {}
    for obj, rs in sorted(by_object.items()):
        dec = [r for r in rs if r["declared"]]
        objects[obj] = dict(
            trials=len(rs),
            declared=_share(sum(bool(r["success"]) for r in dec), len(dec)),
            mean_p_declared=float(np.mean([r["p_goal"] for r in dec])) if dec else float("nan"),
            undeclared=len(rs) - len(dec),
        )
    return dict(
        trials=len(records),
        declared=_share(int(okd.sum()), len(declared)),
        undeclared_share=(len(records) - len(declared)) / len(records) if records else float("nan"),
        undeclared_successes=sum(bool(r["success"]) for r in records if not r["declared"]),
        mean_p_declared=float(pd.mean()) if len(pd) else float("nan"),
        brier=float(np.mean((p - ok) ** 2)) if len(p) else float("nan"),
        brier_declared=float(np.mean((pd - okd) ** 2)) if len(pd) else float("nan"),
        bins=bins,
        objects=objects,
    )


def reliability_diagram(cal: dict, path: Path, title: str) -> None:
    """Observed success against mean P(goal) per bin, with Wilson intervals and counts."""
    fig, ax = plt.subplots(figsize=(5.5, 5))
    ax.plot([0, 1], [0, 1], color="0.6", lw=0.8, ls="--", label="perfect calibration")
    for b in cal["bins"]:
        s = b["successes"]
        ax.errorbar(
            b["mean_p"],
            s["rate"],
            yerr=[[s["rate"] - s["ci95"][0]], [s["ci95"][1] - s["rate"]]],
            fmt="o",
            color="C0",
            capsize=3,
        )
        ax.annotate(
            f"n={s['n']}",
            (b["mean_p"], s["rate"]),
            textcoords="offset points",
            xytext=(6, -12),
            fontsize=7,
        )
    ax.set_xlim(0, 1.02)
    ax.set_ylim(0, 1.05)
    ax.set_xlabel("P(goal) at the end of the run")
    ax.set_ylabel("judged success")
    ax.set_title(
        f"{title}\nBrier {cal['brier']:.3f}; declared: {cal['declared']['k']}/"
        f"{cal['declared']['n']} succeeded",
        fontsize=9,
    )
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def calibration_table(cal: dict, delta: float = SEARCH.delta) -> str:
    """Markdown: the calibration summary, its bins and its objects."""
    d = cal["declared"]
    lines = [
        "**Calibration of RRG-Info's P(goal)** (main cells; P(goal) at the end of each run)",
        "",
        f"- declared {d['n']} of {cal['trials']} runs at a mean P(goal) of "
        f"{cal['mean_p_declared']:.3f}; {d['k']} succeeded: {100 * d['rate']:.1f} % "
        f"({100 * d['ci95'][0]:.1f}–{100 * d['ci95'][1]:.1f}), target ≥ {100 * (1 - delta):.0f} %",
        f"- runs that ended without declaring: {100 * cal['undeclared_share']:.1f} % "
        f"({cal['undeclared_successes']} of them succeeded)",
        f"- Brier score {cal['brier']:.3f} (every run with a P(goal)), "
        f"{cal['brier_declared']:.3f} (declared runs)",
        "",
        "| P(goal) | runs | mean P(goal) | succeeded | failures observed / predicted |",
        "|---|---|---|---|---|",
    ]
    for b in cal["bins"]:
        s = b["successes"]
        lines.append(
            f"| {b['lo']:g}–{b['hi']:g} | {s['n']} | {b['mean_p']:.3f} | {100 * s['rate']:.0f} % "
            f"({100 * s['ci95'][0]:.0f}–{100 * s['ci95'][1]:.0f}) | {b['observed_failures']} / "
            f"{b['predicted_failures']:.1f} = {b['failure_ratio']:.2f} |"
        )
    lines += [
        "",
        "| object | declared | succeeded when declared | mean P(goal) declared | not declared |",
        "|---|---|---|---|---|",
    ]
    for obj, o in cal["objects"].items():
        s = o["declared"]
        rate = f"{100 * s['rate']:.0f} % ({s['k']}/{s['n']})" if s["n"] else "–"
        lines.append(
            f"| {obj} | {s['n']}/{o['trials']} | {rate} | {o['mean_p_declared']:.3f} | "
            f"{o['undeclared']} |"
        )
    return "\n".join(lines) + "\n"
