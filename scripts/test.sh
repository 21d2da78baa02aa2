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
# The project's modules compiled once, here: where PYTHONDONTWRITEBYTECODE is set (as on some CI
# images) every process a test starts would compile them again (about 0.2 s of CPU each).
# compileall does not follow the links capsd/services and capsd/simulator: named on their own.
.venv/bin/python -m compileall -q capsd services simulator >/dev/null
echo "== ruff (${SECONDS} s in)"; .venv/bin/ruff check .
echo "== ruff format"; .venv/bin/ruff format --check .
# mypy runs in the background beside the in-process tests (nothing there is timed); its log
# is shown after them. The ROV role's install (capsd[rov] alone: no torch, scipy or OpenCV) is
# checked by tests/deploy/test_systemd.py through deploy/install.sh.
echo "== (${SECONDS} s in) mypy in the background"
.venv/bin/mypy > .venv/mypy.log 2>&1 &
mypy_pid=$!
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
mypy_rc=0
wait "$mypy_pid" || mypy_rc=$?
echo "== (${SECONDS} s in) mypy"; cat .venv/mypy.log
[ "$mypy_rc" -eq 0 ] || { echo "mypy failed ($mypy_rc)"; exit "$mypy_rc"; }
echo "== (${SECONDS} s in) pytest: integration tests (real processes on 127.0.0.1), one at a time"
phase --durations=15 -m "integration and not shares_cpu" "$@"
echo "== done in ${SECONDS} s"
exit "$failed"
