#!/usr/bin/env bash
# Peer environments of bench/peers, idempotent (stamps = hash of the requirement files):
#   .venv-peers  tools/requirements-peers.txt (+ -lock as constraints): hpp-python, ompl, pin-pink,
#                and the project's algorithm dependencies (pin 4.1, coal 3.0.3, numpy, numba, ...)
#   .venv-placo  tools/requirements-peers-placo.txt (+ -lock): placo (pins pinocchio 3.8)
# Never part of make setup / make test. Usage: bench/peers/setup.sh [--force]
set -euo pipefail
cd "$(dirname "$0")/../.."
force=${1:-}
PY=${PYTHON:-$(command -v python3.11 || command -v python3)}
mkdir -p build
make_venv() {  # name requirements lock
  local venv=$1 req=$2 lock=$3
  local hash; hash=$(cat "$req" "$lock" | sha256sum | cut -c1-16)
  if [ "$force" != "--force" ] && [ -x "$venv/bin/python" ] && [ "$(cat "$venv/.stamp" 2>/dev/null)" = "$hash" ]; then
    return 0
  fi
  echo "bench-peers: installing $venv from $req (a few minutes the first time)"
  [ -x "$venv/bin/python" ] || "$PY" -m venv "$venv"
  echo '*' > "$venv/.gitignore"
  "$venv/bin/python" -m pip install --disable-pip-version-check -q -r "$req" -c "$lock" \
      > "build/pip-$(basename "$venv").log" 2>&1 \
      || { tail -20 "build/pip-$(basename "$venv").log" >&2; echo "bench-peers: pip failed for $venv" >&2; return 1; }
  echo "$hash" > "$venv/.stamp"
}
# a peer venv that cannot be built is reported by the bench as unavailable, the others still run
make_venv .venv-peers tools/requirements-peers.txt tools/requirements-peers-lock.txt || true
make_venv .venv-placo tools/requirements-peers-placo.txt tools/requirements-peers-placo-lock.txt || true
