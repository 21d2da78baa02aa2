#!/usr/bin/env bash
# Install the topside role into .venv, then run the system on the simulated tank over Zenoh on
# loopback: a router, the simulator and the locator as separate processes; show live services
# and fixes for DURATION seconds (default 20), then stop everything cleanly.
set -euo pipefail
cd "$(dirname "$0")/.."
DURATION=${1:-20}
PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null 2>&1 || PY=python3
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install --quiet --disable-pip-version-check -e '.[topside]' 2> >(grep -v "^WARNING: Location" >&2)
PORT=${CAPSD_PORT:-7447}
EP=tcp/127.0.0.1:$PORT
LOGS=$(mktemp -d)
pids=()
cleanup() { for pid in "${pids[@]}"; do kill -TERM "$pid" 2>/dev/null || true; done; wait || true; }
trap cleanup EXIT INT TERM
.venv/bin/capsd router --listen "$EP" 2>"$LOGS/router.log" & pids+=($!)
sleep 1
.venv/bin/capsd run sim --config deploy/config/sim.yaml --connect "$EP" 2>"$LOGS/sim.log" & pids+=($!)
.venv/bin/capsd run locator --config deploy/config/locator.yaml --connect "$EP" 2>"$LOGS/locator.log" & pids+=($!)
sleep 3
.venv/bin/capsd list --connect "$EP"
echo "== fix accuracy against the simulator's truth, for ${DURATION} s (service logs: $LOGS)"
.venv/bin/python -m simulator.compare --connect "$EP" --duration "$DURATION"
.venv/bin/capsd list --connect "$EP"
