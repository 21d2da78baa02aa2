"""`capsd evaluate` on a simulated dive: a rotated, shifted, late reference is found again."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from capsd.bench.evaluate import bench
from tests.conftest import REPO


@pytest.fixture(scope="module")
def dive(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    out = tmp_path_factory.mktemp("bench-evaluate")
    result = bench(
        tank="nfp", trajectory="bouncing", seed=3, duration_s=40.0, out_dir=out, detector="truth"
    )
    return out, result


def test_the_alignment_and_the_figures_come_back(dive: tuple[Path, dict[str, Any]]) -> None:
    out, result = dive
    checks = result["checks"]
    alignment = result["evaluation"]["alignment"]
    # 40 s of bouncing: the errors stay within three of the sigmas the evaluation states.
    assert checks["rotation_error_deg"] <= 3 * alignment["rotation_sigma_deg"]
    assert checks["rotation_error_deg"] < 0.3
    assert abs(checks["offset_error_ms"]) <= 3 * alignment["offset_sigma_ms"]
    assert checks["translation_error_mm"] < 30.0
    # Each ping's error moves by at most how far the fitted transform misplaces its reference
    # point (triangle inequality), so the MEDs differ by no more than the worst such shift
    # (plus the reference's noise and interpolation).
    assert abs(checks["med_difference_mm"]) <= checks["translation_error_mm"] + 1.0
    assert result["evaluation"]["reference_spikes_dropped"] == result["mocap"]["swaps"]
    for png in ("trajectory_3d.png", "axes.png", "errors.png"):
        assert (out / png).stat().st_size > 10_000
    assert json.loads((out / "evaluation.json").read_text())["accuracy"]["med_mm"] > 0


def _evaluate(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "capsd", "evaluate", *args],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=REPO,
    )


def test_the_command_says_when_it_is_not_sure(dive: tuple[Path, dict[str, Any]]) -> None:
    out, _ = dive
    recording = str(out / "dive.mcap")
    proc = _evaluate(recording, "--clock-offset-ms", "150", "--out", str(out / "given"))
    figures = json.loads((out / "given" / "evaluation.json").read_text())
    assert figures["alignment"]["clock_offset_given"] is True
    assert figures["alignment"]["clock_offset_ms"] == 150.0
    # Exit 1 exactly when the evaluation names a reason not to trust its alignment.
    assert proc.returncode == (1 if figures["alignment"]["problems"] else 0), proc.stderr
    if figures["alignment"]["problems"]:
        assert "NOT TRUSTED" in proc.stdout
        assert "the alignment is not determined" in proc.stderr
    proc = _evaluate(recording, "--reference", "rov/nothing", "--out", str(out / "x"))
    assert proc.returncode == 2
    assert "no reference key matching 'rov/nothing'" in proc.stderr
