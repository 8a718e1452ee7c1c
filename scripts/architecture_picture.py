"""Draw RRG's package layers from the code's own imports, and write them into
docs/architecture.md.

    .venv/bin/python scripts/architecture_picture.py          # the picture and the doc's table
    .venv/bin/python scripts/architecture_picture.py --check  # status 1 if the table is stale

The packages are pyproject.toml's (``[tool.setuptools.packages.find]``). A package's floor is
one above the highest package it imports (floor 1 imports no other); an arrow A → B, labelled
with the number of A's modules that import B, says that A imports B. Imports are read with
``ast`` (lazy ones too); nothing is imported.
"""

from __future__ import annotations

import argparse
import ast
import sys
import tomllib
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "architecture.md"
PICTURE = ROOT / "docs" / "img" / "architecture.png"
BEGIN, END = "<!-- layers: begin -->", "<!-- layers: end -->"


def packages() -> list[str]:
    """The Python packages, as pyproject.toml lists them."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    return [
        p.removesuffix("*") for p in project["tool"]["setuptools"]["packages"]["find"]["include"]
    ]


def _modules(pkg: str) -> list[Path]:
    return [
        p
        for p in sorted((ROOT / pkg).rglob("*.py"))
        if p != ROOT / pkg / "setup.py" and "interfaces" not in p.relative_to(ROOT / pkg).parts
    ]


def _imported_packages(path: Path, pkgs: list[str]) -> set[str]:
    """The packages of ``pkgs`` that the module at ``path`` imports (absolute imports)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            out.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            out.add(node.module.split(".")[0])
    return out & set(pkgs)


def package_graph() -> tuple[dict[str, Counter], dict[str, int]]:
    """(A → Counter{B: modules of A that import B}, A → lines of code)."""
    pkgs = packages()
    edges: dict[str, Counter] = {p: Counter() for p in pkgs}
    lines = {}
    for pkg in pkgs:
        mods = _modules(pkg)
        lines[pkg] = sum(len(m.read_text().splitlines()) for m in mods)
        for m in mods:
            edges[pkg].update(_imported_packages(m, pkgs) - {pkg})
    return edges, lines


def floors(edges: dict[str, Counter]) -> dict[str, int]:
    """Each package's floor: 1 + the highest floor it imports (1 for none). ValueError on a
    cycle."""
    out: dict[str, int] = {}

    def floor(p: str, path: tuple[str, ...] = ()) -> int:
        if p in path:
            raise ValueError(f"import cycle: {' → '.join((*path, p))}")
        if p not in out:
            out[p] = 1 + max((floor(d, (*path, p)) for d in edges[p]), default=0)
        return out[p]

    for p in edges:
        floor(p)
    return out


def role(pkg: str) -> str:
    """The first paragraph of the package's docstring, on one line, in Markdown's code quotes."""
    doc = ast.get_docstring(ast.parse((ROOT / pkg / "__init__.py").read_text())) or pkg
    return " ".join(doc.split("\n\n")[0].split()).replace("``", "`").rstrip(".")


def layers_table(edges: dict[str, Counter]) -> str:
    """The doc's table: floor, package, its role, the packages it imports."""
    fl = floors(edges)
    rows = ["| floor | package | role | imports |", "|---|---|---|---|"]
    for p in sorted(edges, key=lambda p: (-fl[p], p)):
        deps = ", ".join(f"`{d}`" for d in sorted(edges[p])) or "none"
        rows.append(f"| {fl[p]} | `{p}` | {role(p)} | {deps} |")
    return "\n".join(rows)


def draw(edges: dict[str, Counter], lines: dict[str, int], path: Path) -> None:
    """The layers as boxes, floor 1 at the bottom, with an arrow per imported package."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fl = floors(edges)
    top = max(fl.values())
    by_floor = {f: sorted(p for p in fl if fl[p] == f) for f in range(1, top + 1)}
    pos: dict[str, tuple[float, float]] = {}
    for f in range(1, top + 1):  # order each floor by where its imports stand (fewer crossings)
        row = by_floor[f]
        if f > 1:
            row.sort(key=lambda p: sum(pos[d][0] for d in edges[p]) / max(len(edges[p]), 1))
        for i, p in enumerate(row):
            pos[p] = ((i + 1) / (len(row) + 1), f)
    fig, ax = plt.subplots(figsize=(11, 1.6 * top + 1))
    w, h = 0.17, 0.42
    for p, (x, y) in pos.items():
        for d, n in edges[p].items():
            dx, dy = pos[d]
            near = y - dy == 1  # to the floor below: dark; past it: light
            colour = "0.3" if near else "0.72"
            ax.annotate(
                "",
                xy=(dx, dy + h / 2),
                xytext=(x, y - h / 2),
                arrowprops=dict(arrowstyle="-|>", color=colour, lw=0.6 + 0.25 * n**0.5),
            )
            lx, ly = x + 0.3 * (dx - x), (y - h / 2) + 0.3 * ((dy + h / 2) - (y - h / 2))
            ax.text(lx, ly, str(n), fontsize=7, color=colour, ha="center", va="center")
        ax.add_patch(
            plt.Rectangle((x - w / 2, y - h / 2), w, h, fc="#dbe7f3", ec="#33557a", lw=1.0)
        )
        ax.text(x, y + 0.08, p, ha="center", va="center", fontsize=9, weight="bold")
        ax.text(x, y - 0.1, f"{lines[p]:,} lines", ha="center", va="center", fontsize=7)
    for f in range(1, top + 1):
        ax.text(0.0, f, f"floor {f}", va="center", fontsize=8, color="0.4")
    ax.set_xlim(-0.05, 1.05)
    ax.set_ylim(0.5, top + 0.5)
    ax.axis("off")
    ax.set_title("RRG's packages: an arrow A → B says A imports B (label: A's modules that do)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="only check the doc's table")
    args = ap.parse_args(argv)
    edges, lines = package_graph()
    table = layers_table(edges)
    doc = DOC.read_text()
    head, _, rest = doc.partition(BEGIN)
    _, _, tail = rest.partition(END)
    current = f"{head}{BEGIN}\n{table}\n{END}{tail}"
    if args.check:
        if current != doc:
            print(f"{DOC.relative_to(ROOT)}: the layers table is stale; run {__file__}")
            return 1
        return 0
    DOC.write_text(current)
    draw(edges, lines, PICTURE)
    print(f"wrote {PICTURE.relative_to(ROOT)} and the table in {DOC.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
