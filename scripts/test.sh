#!/usr/bin/env bash
# Install everything from nothing into .venv, then lint, type-check and run the test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null 2>&1 || PY=python3
[ -x .venv/bin/python ] || "$PY" -m venv .venv
# torch is pinned to the CPU wheel (torch==2.13.0); pip's quiet mode keeps the log readable.
.venv/bin/python -m pip install --quiet --disable-pip-version-check -e '.[all,dev]' 2> >(grep -v "^WARNING: Location" >&2)
echo "== ruff"; .venv/bin/ruff check .
echo "== ruff format"; .venv/bin/ruff format --check .
echo "== mypy"; .venv/bin/mypy
echo "== pytest"; .venv/bin/pytest "$@"
