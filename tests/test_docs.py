"""The repository's documents: the README is a user's manual of at most about 12 KB with the two
commands, every "design §N" the code cites is a section of docs/design.md, and the history of
how the code was made (sessions, campaign hashes, trial ids) stays in CHANGELOG.md."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from repo_layout import PACKAGES

ROOT = Path(__file__).resolve().parents[1]
README_MAX_BYTES = 12 * 1024
TEXT_SUFFIXES = {".py", ".md", ".msg", ".srv", ".action", ".sh", ".toml", ".txt", ".cjs"}
#: The trial-id format is the experiment runner's own interface: its usage text and its tests
#: may show examples.
TRIAL_ID_EXAMPLES = {
    "rrg_experiments/experiment_cli.py",
    "tests/test_experiment.py",
    "tests/test_docs.py",
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
DESIGN_REF = re.compile(r"design (?:§|sections? )(\d+)(?:\s*[-–,]\s*(?:and )?(\d+))?")


def test_the_readme_is_a_short_manual_with_the_two_commands():
    text = (ROOT / "README.md").read_text()
    assert len(text.encode()) <= README_MAX_BYTES
    assert "./scripts/run.sh" in text and "./scripts/test.sh" in text
    assert "docs/design.md" in text and "CHANGELOG.md" in text


def test_every_design_reference_names_a_section_of_the_design():
    sections = {
        int(n) for n in re.findall(r"^## (\d+)\. ", (ROOT / "docs/design.md").read_text(), re.M)
    }
    assert sections == set(range(1, 10))
    cited = {}
    for path in FILES:
        for m in DESIGN_REF.finditer(path.read_text(errors="replace")):
            for n in m.groups():
                if n is not None:
                    cited.setdefault(int(n), path.relative_to(ROOT).as_posix())
    assert len(cited) >= 5  # the code does cite it
    assert {n: f for n, f in cited.items() if n not in sections} == {}


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
