#!/usr/bin/env bash
# Install the topside role into .venv, then run the whole system on the simulated tank, each
# part its own process talking over Zenoh on loopback:
#   router -> simulator (512-beam sonar images, LiDAR, IMU, ROV depth/attitude)
#          -> asv_pose (tilt filter + scan matching) and sonar_detect (ROV candidates)
#          -> locator (fixes, tracked)
#          -> mav_bridge -> an ArduSub stand-in (VISION_POSITION_ESTIMATE)
# It prints the live services, the fix error against the simulator's truth for DURATION
# seconds (default 30), what reached the autopilot, and stops everything cleanly.
# TRAJECTORY=lawnmower shows the hard case: clutter under the ROV (see the README).
set -euo pipefail
cd "$(dirname "$0")/.."
DURATION=${1:-30}
PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null 2>&1 || PY=python3
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install --quiet --disable-pip-version-check -e '.[topside,rov]' 2> >(grep -v "^WARNING: Location" >&2)
PORT=${CAPSD_PORT:-7447}
MAV_PORT=${CAPSD_MAV_PORT:-5777}
EP=tcp/127.0.0.1:$PORT
LOGS=$(mktemp -d)
pids=()
cleanup() {
  for pid in "${pids[@]}"; do kill -TERM "$pid" 2>/dev/null || true; done
  for pid in "${pids[@]}"; do wait "$pid" 2>/dev/null || true; done
}
trap cleanup EXIT INT TERM
cat > "$LOGS/sim.yaml" <<YAML
bus: {connect: [$EP]}
trajectory: ${TRAJECTORY:-square}
streams: {detections_truth_noise: "off", asv_pose_truth_noise: "off"}
YAML
# asv_pose needs to know roughly where the ASV was put in the water (its heading prior).
HEADING_DEG=$(.venv/bin/python -c "
import math, sys
from capsd.config import load_config
from simulator.config import Config
from simulator.sim import Simulation
from capsd.geometry import matrix_to_euler_zyx
pose = Simulation(load_config(sys.argv[1], Config), horizon_s=10).asv_pose(0.0)
yaw = math.degrees(matrix_to_euler_zyx(pose.rotation)[0])
print(f'{yaw:.0f}')
" "$LOGS/sim.yaml")
cat > "$LOGS/asv_pose.yaml" <<YAML
bus: {connect: [$EP]}
heading_prior_deg: $HEADING_DEG
YAML
# The simulator already publishes the ROV's depth and attitude under "rov"; the stand-in's
# telemetry goes under its own name so the two never mix on one key.
cat > "$LOGS/bridge.yaml" <<YAML
vehicle: rov_ap
bus: {connect: [$EP]}
mavlink: {connect: "tcp:127.0.0.1:$MAV_PORT"}
YAML
.venv/bin/capsd router --listen "$EP" 2>"$LOGS/router.log" & pids+=($!)
.venv/bin/python -m simulator.autopilot --port "$MAV_PORT" >"$LOGS/autopilot.out" 2>&1 & AP=$!
sleep 1
.venv/bin/capsd run sim --config "$LOGS/sim.yaml" 2>"$LOGS/sim.log" & pids+=($!)
.venv/bin/capsd run asv_pose --config "$LOGS/asv_pose.yaml" 2>"$LOGS/asv_pose.log" & pids+=($!)
.venv/bin/capsd run sonar_detect --config deploy/config/sonar_detect.yaml --connect "$EP" 2>"$LOGS/sonar_detect.log" & pids+=($!)
.venv/bin/capsd run locator --config deploy/config/locator.yaml --connect "$EP" 2>"$LOGS/locator.log" & pids+=($!)
.venv/bin/capsd run mav_bridge --config "$LOGS/bridge.yaml" 2>"$LOGS/mav_bridge.log" & pids+=($!)
sleep 4
.venv/bin/capsd list --connect "$EP"
echo "== fix error against the simulator's truth for ${DURATION} s (logs: $LOGS)"
.venv/bin/python -m simulator.compare --connect "$EP" --duration "$DURATION"
.venv/bin/capsd list --connect "$EP"
cleanup
pids=("$AP")
kill -TERM "$AP" 2>/dev/null || true
wait "$AP" 2>/dev/null || true
cat "$LOGS/autopilot.out"
