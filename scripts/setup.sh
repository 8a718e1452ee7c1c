#!/usr/bin/env bash
# Set up RRG's environment in .venv/ (idempotent; fast when nothing changed).
#   - Debian packages the build needs (python3-venv, cmake, g++), only when missing;
#   - the Python virtual environment with the core dependencies;
#   - RRG itself, installed editable, with its command-line tools and the test and ray extras.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv"
PY="${RRG_PYTHON:-python3}"

log() { printf '\033[1;34m[setup]\033[0m %s\n' "$*"; }

need_apt=()
command -v cmake >/dev/null || need_apt+=(cmake)
command -v g++ >/dev/null || need_apt+=(g++)
"$PY" -c "import ensurepip, venv" 2>/dev/null || need_apt+=(python3-venv)
"$PY" -c "import sysconfig, os, sys; sys.exit(0 if os.path.exists(os.path.join(sysconfig.get_paths()['include'], 'Python.h')) else 1)" \
  || need_apt+=(python3-dev)
if [ ${#need_apt[@]} -gt 0 ]; then
  log "installing Debian packages: ${need_apt[*]}"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${need_apt[@]}"
fi

if [ ! -x "$VENV/bin/python" ]; then
  log "creating $VENV"
  "$PY" -m venv "$VENV"
fi
VPY="$VENV/bin/python"

# Re-install only when pyproject.toml or the pinned versions changed since the last install.
STAMP="$VENV/.rrg-core-stamp"
SUM="$(cat "$ROOT/pyproject.toml" "$ROOT/scripts/constraints.txt" | sha256sum | cut -d' ' -f1)"
if [ ! -f "$STAMP" ] || [ "$(cat "$STAMP")" != "$SUM" ]; then
  log "installing Python dependencies (scripts/constraints.txt) and RRG (editable)"
  "$VPY" -m pip install -q --upgrade pip
  "$VPY" -m pip install -q -c "$ROOT/scripts/constraints.txt" -e "$ROOT[test,ray]"
  echo "$SUM" > "$STAMP"
fi

# ROS 2 Jazzy wheels and the rrg_msgs build (added by the ROS graph work), when present.
if [ -x "$ROOT/scripts/setup_ros.sh" ] && [ "${RRG_SKIP_ROS:-0}" != "1" ]; then
  "$ROOT/scripts/setup_ros.sh"
fi
log "environment ready: $VENV"
