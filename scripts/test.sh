#!/usr/bin/env bash
# Install everything from nothing into .venv, then lint, type-check and run the test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null 2>&1 || PY=python3
[ -x .venv/bin/python ] || "$PY" -m venv .venv
# torch is pinned to the CPU wheel (torch==2.13.0); pip's quiet mode keeps the log readable.
echo "== install (.venv; a few minutes the first time)"
.venv/bin/python -m pip install --progress-bar off --disable-pip-version-check -e '.[all,dev]' 2> >(grep -v "^WARNING: Location" >&2) | { grep -E '^(Collecting|Successfully installed)' || true; }
echo "== ruff (${SECONDS} s in)"; .venv/bin/ruff check .
echo "== ruff format"; .venv/bin/ruff format --check .
# The ROV role's check (a venv of its own: pip, mostly waiting) runs beside mypy.
rov_role() {
  rm -rf .venv-rov && "$PY" -m venv .venv-rov
  .venv-rov/bin/python -m pip install --quiet --disable-pip-version-check '.[rov]' 2> >(grep -v "^WARNING: Location" >&2)
  .venv-rov/bin/python - <<'PY'
import contextlib, importlib.util, io
for heavy in ("torch", "scipy", "cv2"):
    assert importlib.util.find_spec(heavy) is None, f"{heavy} is installed in the rov role"
import capsd.services.mav_bridge.service  # noqa: F401
from capsd.cli import main
with contextlib.redirect_stdout(io.StringIO()):
    assert main(["run", "mav_bridge", "--print-config"]) == 0
print("rov role: bridge imports and configures without torch, scipy or OpenCV")
PY
  rm -rf .venv-rov
}
echo "== mypy (${SECONDS} s in), and beside it the rov role: install capsd[rov] alone and start the bridge's code without torch/scipy/cv2"
rov_role > .venv/rov-role.log 2>&1 &
rov_pid=$!
.venv/bin/mypy
rov_rc=0
wait "$rov_pid" || rov_rc=$?
cat .venv/rov-role.log
[ "$rov_rc" -eq 0 ] || { echo "rov role check failed ($rov_rc)"; exit "$rov_rc"; }
# Two phases. Tests that start real processes and Zenoh sessions (marked integration) measure
# rates and delays, so they run one at a time; the rest (in-process, or a CLI's figures, and
# integration tests marked shares_cpu: nothing timed) run on every core (pytest-xdist): the
# suite took 17 min in one process on a 2-core machine.
# Exit 5 is "no test selected" (arguments that pick tests of one kind only).
failed=0
phase() {
  local rc=0
  .venv/bin/pytest "$@" || rc=$?
  if [ "$rc" -ne 0 ] && [ "$rc" -ne 5 ]; then failed=$rc; fi
}
echo "== (${SECONDS} s in) pytest: in-process tests, ${CAPSD_TEST_WORKERS:-auto} workers"
phase -n "${CAPSD_TEST_WORKERS:-auto}" --durations=15 -m "not integration or shares_cpu" "$@"
echo "== (${SECONDS} s in) pytest: integration tests (real processes on 127.0.0.1), one at a time"
phase --durations=15 -m "integration and not shares_cpu" "$@"
echo "== done in ${SECONDS} s"
exit "$failed"
