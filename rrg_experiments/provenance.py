"""Which code a campaign ran, and the base seed it draws from that code.

A reported campaign takes its base seed from the code version (``campaign_seed``), so no
version of the code can be tuned on the trials that will judge it: changing the code changes
the trials. Development probes use DEV_SEED instead (``rrg-experiment --dev``), whose trials
are never reported.

The code version is the last git commit that changed the code (the packages and
``pyproject.toml``) in the checkout the packages were imported from, with ``+dirty.<hash>``
when a tracked source file differs from it (the hash is of that diff, so each edit is its own
version), or ``src.<hash>`` of the package sources outside a git checkout. Results and docs,
written or committed during a campaign, do not change its version, so it resumes.
"""

from __future__ import annotations

import functools
import hashlib
import subprocess
from pathlib import Path

#: The base seed of development probes (the trials earlier versions of RRG were tuned on);
#: never the seed of a reported campaign.
DEV_SEED = 0

#: What defines the code's behaviour, relative to the repository root.
CODE_PATHS = (
    "rrg_models",
    "rrg_common",
    "rrg_sim",
    "rrg_estimator",
    "rrg_planner",
    "rrg_hw_bridge",
    "rrg_fake_hw",
    "rrg_experiments",
    "rrg_bags",
    "rrg_onboarding",
    "rrg_bringup",
    "rrg_msgs",
    "pyproject.toml",
)

REPO_ROOT = Path(__file__).resolve().parents[1]


def _git(*args: str) -> bytes:
    return subprocess.run(
        ["git", "-C", str(REPO_ROOT), *args], capture_output=True, check=True, timeout=30
    ).stdout


def _short_hash(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()[:12]


def _source_hash() -> str:
    """Hash of every file under CODE_PATHS (sorted by path), caches excluded."""
    h = hashlib.sha256()
    for rel in CODE_PATHS:
        root = REPO_ROOT / rel
        files = [root] if root.is_file() else sorted(p for p in root.rglob("*") if p.is_file())
        for p in files:
            if "__pycache__" in p.parts or p.suffix == ".pyc":
                continue
            h.update(str(p.relative_to(REPO_ROOT)).encode() + b"\0" + p.read_bytes() + b"\0")
    return h.hexdigest()[:12]


@functools.cache
def code_version() -> str:
    """'<commit>', '<commit>+dirty.<diff hash>' or 'src.<source hash>' (see the module doc):
    the commit is the last one that changed the code."""
    try:
        commit = _git("log", "-1", "--format=%H", "HEAD", "--", *CODE_PATHS).decode().strip()
        diff = _git("diff", "HEAD", "--binary", "--", *CODE_PATHS)
    except (OSError, subprocess.SubprocessError):
        return f"src.{_source_hash()}"
    return f"{commit}+dirty.{_short_hash(diff)}" if diff else commit


def campaign_seed(version: str) -> int:
    """The base seed (32 bits) a campaign of code ``version`` draws its trials from."""
    return int.from_bytes(hashlib.sha256(f"rrg-campaign/{version}".encode()).digest()[:4], "big")
