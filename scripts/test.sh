#!/usr/bin/env bash
# Run RRG's whole test suite (sets the environment up first when needed, with Foxglove Studio's
# web build and a headless Chromium for tests/repo/test_foxglove_layout.py).
# Extra arguments go to pytest, e.g. scripts/test.sh -k search -x
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$ROOT/scripts/setup.sh"
"$ROOT/scripts/setup_foxglove.sh"  # Foxglove Studio and Chromium for the layout test
cd "$ROOT"
exec "$ROOT/.venv/bin/python" -m pytest "$@"
