"""The repository's documents: the README is a user's manual of at most about 12 KB with the two
commands, every "design §N", "algorithm §N" and "operations §N" the code cites is a section of
docs/design.md, docs/algorithm.md or docs/operations.md, and the history of how the code was
made (sessions, campaign hashes, trial ids) stays in CHANGELOG.md."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from repo_layout import PACKAGES

ROOT = Path(__file__).resolve().parents[2]
README_MAX_BYTES = 12 * 1024
TEXT_SUFFIXES = {".py", ".md", ".msg", ".srv", ".action", ".sh", ".toml", ".txt", ".cjs"}
#: The trial-id format is the experiment runner's own interface: its usage text and its tests
#: may show examples.
TRIAL_ID_EXAMPLES = {
    "rrg_experiments/experiment_cli.py",
    "tests/rrg_experiments/test_experiment.py",
    "tests/repo/test_docs.py",
}


def _text_files() -> list[Path]:
    roots = [*PACKAGES, "rrg_msgs", "tests", "scripts", "docs"]
    files = [p for r in roots for p in (ROOT / r).rglob("*") if p.suffix in TEXT_SUFFIXES]
    return files + [ROOT / "README.md", ROOT / "CONTRIBUTING.md", ROOT / "pyproject.toml"]


FILES = sorted(p for p in _text_files() if p.is_file() and "__pycache__" not in p.parts)
HISTORY = {
    "a session number": re.compile(r"\bsessions? ?-?\d+", re.I),
    "a session in time": re.compile(r"\b(this|last|next|earlier|previous) session\b", re.I),
    "a campaign hash": re.compile(r"\bcampaigns? (at )?[0-9a-f]{7}\b"),
}
TRIAL_ID = re.compile(r"\b[a-z_]+/(high|mid|low)/(rrg-info|rrg-goal|open-loop)\S*#\d+")
#: The manual's pages and the sections each holds; the code cites them as "design §7",
#: "algorithm §3" or "operations §8" (also "docs/algorithm.md §3", "[algorithm.md](...) §3").
MANUAL = {"design": {1, 7, 9}, "algorithm": {2, 3, 4, 5, 6}, "operations": {8}}
SECTION_REF = re.compile(
    r"\b(design|algorithm|operations)(?:\.md(?:\]\([\w./]*\))?)? (?:§|sections? )(\d+)"
    r"(?:\s*[-–,]\s*(?:and )?§?(\d+))?"
)


def test_the_readme_is_a_short_manual_with_the_two_commands():
    text = (ROOT / "README.md").read_text()
    assert len(text.encode()) <= README_MAX_BYTES
    assert "./scripts/run.sh" in text and "./scripts/test.sh" in text
    assert all(f"docs/{page}.md" in text for page in MANUAL) and "CHANGELOG.md" in text


def _sections(page: str) -> set[int]:
    text = (ROOT / "docs" / f"{page}.md").read_text()
    return {int(n) for n in re.findall(r"^## (\d+)\. ", text, re.M)}


def test_the_manual_keeps_its_section_numbers():
    assert {page: _sections(page) for page in MANUAL} == MANUAL


def test_every_section_reference_names_a_section_of_its_page():
    cited = {}
    for path in FILES:
        for m in SECTION_REF.finditer(path.read_text(errors="replace")):
            page, *numbers = m.groups()
            for n in numbers:
                if n is not None:
                    cited.setdefault((page, int(n)), path.relative_to(ROOT).as_posix())
    for page in MANUAL:  # the code does cite each page
        assert len([n for p, n in cited if p == page]) >= len(MANUAL[page]) // 2 + 1, page
    assert {ref: f for ref, f in cited.items() if ref[1] not in MANUAL[ref[0]]} == {}


def test_the_section_pattern_finds_citations():
    """Every form the code, the docs and the interfaces use (the section sign and word are
    spliced in, so that this file cites nothing)."""
    s, w = "§", "sections"
    text = (
        f"(design {s}7) docs/algorithm.md {s}3, [operations.md](operations.md) {s}8;"
        f" (algorithm {s}2, {s}4) design {w} 6-7 (algorithm {s}6, design {s}7)"
    )
    assert [m.groups() for m in SECTION_REF.finditer(text)] == [
        ("design", "7", None),
        ("algorithm", "3", None),
        ("operations", "8", None),
        ("algorithm", "2", "4"),
        ("design", "6", "7"),
        ("algorithm", "6", None),
        ("design", "7", None),
    ]


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_history_stays_in_the_changelog(path):
    text = path.read_text(errors="replace")
    found = [f"{what}: {m.group(0)!r}" for what, rx in HISTORY.items() for m in rx.finditer(text)]
    if path.relative_to(ROOT).as_posix() not in TRIAL_ID_EXAMPLES:
        found += [f"a trial id: {m.group(0)!r}" for m in TRIAL_ID.finditer(text)]
    assert found == []


def test_the_history_patterns_find_history():
    """The patterns are not vacuous: each finds the kind of line the CHANGELOG holds."""
    session, campaign = "sess" + "ion", "camp" + "aign"  # (so that this file holds no history)
    assert HISTORY["a session number"].search(f"Changes in {session} 12")
    assert HISTORY["a campaign hash"].search(f"{campaign} 4282222: 26 of 1,000")
    assert TRIAL_ID.search("powerdrill/high/rrg-info/H2/d0.3#5") and TRIAL_ID.search(
        "cup/low/rrg-goal#8"
    )
