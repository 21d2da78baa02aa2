"""The footprint bench's library detection sees what a process really loaded."""

from __future__ import annotations

import subprocess
import sys
import time

from capsd.bench.footprint import _heavy_mapped, status_kb


def test_detects_scipy_in_a_process_that_loads_it() -> None:
    code = "import scipy.linalg, sys; print('ready', flush=True); sys.stdin.read()"
    with subprocess.Popen(
        [sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    ) as proc:
        try:
            assert proc.stdout is not None
            assert proc.stdout.readline().strip() == "ready"
            assert "scipy" in _heavy_mapped(proc.pid)
            assert status_kb(proc.pid, "VmRSS") > 1000
        finally:
            proc.kill()


def test_a_plain_python_process_maps_none() -> None:
    with subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"]) as proc:
        try:
            time.sleep(0.3)
            assert _heavy_mapped(proc.pid) == ()
        finally:
            proc.kill()
