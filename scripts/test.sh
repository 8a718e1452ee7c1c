#!/usr/bin/env bash
# Run RRG's whole test suite (sets the environment up first when needed).
# Extra arguments go to pytest, e.g. scripts/test.sh -k search -x
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$ROOT/scripts/setup.sh"
cd "$ROOT"
exec "$ROOT/.venv/bin/python" -m pytest "$@"
