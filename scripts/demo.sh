#!/usr/bin/env bash
# Install what the demo needs into .venv, then run the whole system on the simulated tank
# (`capsd demo`): a router, the simulator, asv_pose, sonar_detect (polar CNN), locator,
# mav_bridge and an ArduSub stand-in, each its own process over Zenoh on 127.0.0.1. Live fix
# error against the simulator's truth; a report folder at the end (summary.md, figures.json,
# PNGs, logs). Usage: scripts/demo.sh [DURATION_S] [extra capsd demo flags...]
set -euo pipefail
cd "$(dirname "$0")/.."
DURATION=${1:-60}
shift || true
PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null 2>&1 || PY=python3
[ -x .venv/bin/python ] || "$PY" -m venv .venv
echo "installing CAP-SD and its dependencies into .venv (a few minutes the first time: torch is ~200 MB)..."
.venv/bin/python -m pip install --progress-bar off --disable-pip-version-check -e '.[topside,rov,asv,detect]' 2> >(grep -v "^WARNING: Location" >&2) | { grep -E '^(Collecting|Successfully installed)' || true; }
echo "installed; starting the demo"
exec .venv/bin/capsd demo --duration "$DURATION" "$@"
