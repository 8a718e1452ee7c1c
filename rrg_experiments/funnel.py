"""Does one information grasp funnel another, and can the search see it? (paper, Fig. 9).

The paper explains Fig. 9's H = 2 gain on the drill by a funnel: "infograsp 2 ... acts as a
'funnel' for infograsp 1, enabling it to succeed more often". Two views of it:

* **The model's** (``model_funnel``), what the forward search sees from the initial belief:
  the expected best goal probability v after each information WRT alone, E[v(b_a)], and after
  each ordered pair, E[v(b_ab)], over the observation branches the search expands; the gain
  of b after a, E[v(b_ab)] − E[v(b_a)], against its gain first, E[v(b_b)] − v(b_0) (a funnel:
  b gains more after a than first); and the search's action values Q_1 and Q_2 at the root,
  which say whether a horizon of 2 prefers the funnel's first grasp where 1 does not.
* **The trials'** (``trial_funnel``), what physics did: per Fig. 9 cell, how often each pair
  of first two actions ran, and the success and mean actions of the trials that began with it.

``python -m rrg_experiments.funnel [--records results/realistic/trials.jsonl]`` prints
both as markdown (``--out FILE`` also writes it).
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import numpy as np

from rrg_estimator.belief import Belief
from rrg_estimator.config import LEVELS
from rrg_experiments.trials import load_records, model_levels
from rrg_models.config import WORLD
from rrg_planner.planning_model import PlanningModel
from rrg_planner.search import ForwardSearch, SparseBelief


def _expected_value(search: ForwardSearch, sb: SparseBelief, sequence: tuple[int, ...]) -> float:
    """E[v(b)] after running ``sequence`` from sb, over the search's observation branches (an
    infeasible action ends its branch where it stands)."""
    if not sequence:
        return search.static_value(sb)
    a, rest = sequence[0], sequence[1:]
    if not search.feasible(a, sb.w_star):
        return search.static_value(sb)
    branches = search.expand(sb, a)
    if not branches:
        return search.static_value(sb)
    total = sum(p for p, _ in branches)
    return sum(p * _expected_value(search, child, rest) for p, child in branches) / total


def model_funnel(
    model: PlanningModel, level: str = "high", deltas: tuple[float, ...] = (0.3, 0.1)
) -> dict:
    """The model's view from the level's initial belief at the nominal pose (module doc):
    v0, single[a], pair[a][b], and per δ the root's Q_1 and Q_2 of every action."""
    search = ForwardSearch(model)
    belief = Belief.for_level(LEVELS[level], np.asarray(WORLD.nominal_pose))
    sb = SparseBelief.from_belief(belief, level)
    info = [i for i, a in enumerate(model.actions) if a.kind == "info"]
    names = model.names
    single = {names[a]: _expected_value(search, sb, (a,)) for a in info}
    pair = {names[a]: {names[b]: _expected_value(search, sb, (a, b)) for b in info} for a in info}
    q = {}
    for delta in deltas:
        q[f"{delta:g}"] = {
            f"H{h}": dict(zip(names, search.action_values(sb, h, delta).tolist())) for h in (1, 2)
        }
    return dict(v0=search.static_value(sb), single=single, pair=pair, q=q)


def funnels(view: dict, margin: float = 0.0) -> list[tuple[str, str, float, float]]:
    """(a, b, gain of b after a, gain of b first) for every ordered pair where b gains more
    after a than first, by more than ``margin``; the largest excess first."""
    out = []
    for a, row in view["pair"].items():
        for b, v_ab in row.items():
            if a == b:
                continue
            after = v_ab - view["single"][a]
            first = view["single"][b] - view["v0"]
            if after > first + margin:
                out.append((a, b, after, first))
    return sorted(out, key=lambda f: f[3] - f[2])


def trial_funnel(
    records: list[dict], obj: str = "powerdrill", level: str = "high"
) -> dict[str, dict[str, dict]]:
    """Per Fig. 9 RRG-Info cell (key): per first-two-actions pair 'a→b', its count, successes
    and mean actions."""
    cells: dict[str, dict[str, list[dict]]] = defaultdict(lambda: defaultdict(list))
    for r in records:
        if (r["object"], r["level"], r["strategy"]) != (obj, level, "rrg-info"):
            continue
        first = "→".join(r["actions"][:2]) if r["actions"] else "(none)"
        cells[r["cell"]][first].append(r)
    return {
        cell: {
            pair: dict(
                trials=len(rs),
                successes=sum(bool(r["success"]) for r in rs),
                mean_actions=float(np.mean([r["n_actions"] for r in rs])),
            )
            for pair, rs in sorted(by_pair.items(), key=lambda kv: -len(kv[1]))
        }
        for cell, by_pair in sorted(cells.items())
    }


def markdown(view: dict, trials: dict | None, obj: str, level: str) -> str:
    """Both views as markdown."""
    names = list(view["single"])
    lines = [
        f"**The model's view** ({obj}, {level}, from the initial belief): expected best goal "
        "probability after each information WRT (row) and then each (column); v(b0) = "
        f"{view['v0']:.3f}",
        "",
        "| first \\ then | alone | " + " | ".join(names) + " |",
        "|---|---|" + "---|" * len(names),
    ]
    for a in names:
        lines.append(
            f"| {a} | {view['single'][a]:.3f} | "
            + " | ".join(f"{view['pair'][a][b]:.3f}" for b in names)
            + " |"
        )
    found = funnels(view)
    lines += ["", "Funnels (b gains more after a than first):", ""]
    lines += [
        f"- {a} funnels {b}: {b} gains {after:+.3f} after {a}, {first:+.3f} first"
        for a, b, after, first in found
    ] or ["- none"]
    for delta, by_h in view["q"].items():
        lines += ["", f"Root action values at δ = {delta}:", ""]
        acts = list(by_h["H1"])
        lines += ["| H | " + " | ".join(acts) + " | chosen |", "|---|" + "---|" * (len(acts) + 1)]
        for h, q in by_h.items():
            best = max(q, key=q.get)
            row = " | ".join("–" if not np.isfinite(v) else f"{v:.3f}" for v in q.values())
            lines.append(f"| {h[1:]} | {row} | {best} |")
    if trials:
        lines += ["", f"**The trials' view** ({obj}, {level}): the first two actions per cell", ""]
        lines += ["| cell | first two actions | trials | success | mean actions |"]
        lines += ["|---|---|---|---|---|"]
        for cell, pairs in trials.items():
            for pair, s in pairs.items():
                lines.append(
                    f"| {cell} | {pair} | {s['trials']} | {s['successes']}/{s['trials']} | "
                    f"{s['mean_actions']:.2f} |"
                )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m rrg_experiments.funnel", description=__doc__)
    ap.add_argument("--object", default="powerdrill")
    ap.add_argument("--level", default="high", choices=sorted(LEVELS))
    ap.add_argument("--records", type=Path, help="a campaign's trials.jsonl (the trials' view)")
    ap.add_argument("--out", type=Path, help="also write the markdown here")
    ap.add_argument("--json", action="store_true", help="print both views as JSON instead")
    args = ap.parse_args(argv)
    model = PlanningModel(args.object, levels=model_levels(args.level), progress=True)
    view = model_funnel(model, args.level)
    trials = (
        trial_funnel(load_records(args.records), args.object, args.level) if args.records else None
    )
    if args.json:
        print(json.dumps(dict(model=view, trials=trials)))
        return 0
    text = markdown(view, trials, args.object, args.level)
    print(text)
    if args.out:
        args.out.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
