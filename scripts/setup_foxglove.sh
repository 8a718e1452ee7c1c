#!/usr/bin/env bash
# What scripts/foxglove_screenshot.cjs needs (not part of scripts/setup.sh: only for taking the
# README's screenshot of docs/foxglove/rrg_layout.json, or serving a bag to a browser):
#   - Debian's Chromium (headless; WebGL through SwiftShader), only when missing;
#   - in .cache/foxglove/node_modules (npm, ~60 MB): the open-source Foxglove Studio's web build
#     (@foxglove/studio-base 1.48.0), React 17 for it, playwright-core to drive Chromium (it
#     downloads no browser), @mcap/core to find the bag's times.
# Idempotent: a stamp of the package list skips the npm step when nothing changed.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
DIR="$ROOT/.cache/foxglove"
log() { echo "[setup_foxglove] $*"; }

need_apt=()
command -v chromium >/dev/null || need_apt+=(chromium)
command -v npm >/dev/null || need_apt+=(nodejs npm)
fc-list 2>/dev/null | grep -qi dejavu || need_apt+=(fonts-dejavu-core)
if [ ${#need_apt[@]} -gt 0 ]; then
  log "installing ${need_apt[*]} (apt)"
  SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${need_apt[@]}" >/dev/null
fi

PACKAGES=(@foxglove/studio-base@1.48.0 react@17.0.2 react-dom@17.0.2 playwright-core@1.65.1 @mcap/core@2)
STAMP="$DIR/.rrg-foxglove-stamp"
SUM="$(printf '%s\n' "${PACKAGES[@]}" | sha256sum | cut -d' ' -f1)"
if [ ! -f "$STAMP" ] || [ "$(cat "$STAMP")" != "$SUM" ]; then
  log "installing Foxglove Studio's web build into $DIR"
  mkdir -p "$DIR"
  [ -f "$DIR/package.json" ] || echo '{"name": "rrg-foxglove-viewer", "private": true}' > "$DIR/package.json"
  PLAYWRIGHT_SKIP_BROWSER_DOWNLOAD=1 npm install --prefix "$DIR" --no-audit --no-fund --silent "${PACKAGES[@]}"
  echo "$SUM" > "$STAMP"
fi
log "ready: node scripts/foxglove_screenshot.cjs BAG"
