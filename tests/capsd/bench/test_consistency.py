"""The covariance floor is derived, not chosen: the NEES arithmetic and the bench end to end."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from capsd.accuracy import CHI2_3_95, Scored, nees
from capsd.bench.consistency import floor_for
from tests.conftest import REPO


def _pings(errors_m: np.ndarray, sigma_m: float) -> list[Scored]:
    cov = tuple((np.eye(3) * sigma_m**2).ravel().tolist())
    return [
        Scored(k, (float(e[0]), float(e[1]), float(e[2])), None, (0.0, 0.0, 0.0), cov)
        for k, e in enumerate(errors_m)
    ]


def test_a_consistent_covariance_needs_no_floor_and_a_small_one_gets_one() -> None:
    rng = np.random.default_rng(0)
    errors = rng.normal(0.0, 0.02, (4000, 3))
    honest = _pings(errors, 0.02)
    assert np.mean(nees(honest)) == pytest.approx(3.0, abs=0.2)
    assert floor_for(honest) == 0.0
    # Reported 10 mm for errors of 20 mm: the floor must supply sqrt(20^2 - 10^2) = 17 mm.
    small = _pings(errors, 0.01)
    floor = floor_for(small)
    assert floor == pytest.approx(0.0173, abs=0.0015)
    assert np.mean(nees(small, floor_m=floor) <= CHI2_3_95) >= 0.95


def test_bench_consistency_writes_its_figures(tmp_path: Path) -> None:
    out = tmp_path / "consistency.json"
    proc = subprocess.run(
        [sys.executable, "-m", "capsd", "bench", "consistency", "--duration", "3",
         "--out", str(out)],
        capture_output=True, text=True, timeout=300, cwd=REPO,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    figures = json.loads(out.read_text())
    assert figures["derived_floor_mm"] >= 0.0
    assert {row["runs"] for row in figures["rows"]} == {"tuning", "held-out pond"}
