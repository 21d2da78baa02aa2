"""`capsd bench calibrate` end to end on one short run: figures written, targets printed."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from tests.conftest import REPO


def test_bench_calibrate_writes_its_figures(tmp_path: Path) -> None:
    out = tmp_path / "calibrate.json"
    proc = subprocess.run(
        [sys.executable, "-m", "capsd", "bench", "calibrate", "--seeds", "1", "--duration", "30",
         "--out", str(out)],
        capture_output=True, text=True, timeout=300, cwd=REPO,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "mean |yaw error|" in proc.stdout
    figures = json.loads(out.read_text())
    (run,) = figures["runs"]
    # A third of a turn already pins the heading to a few tenths of a degree.
    assert abs(run["yaw_error_deg"]) < 0.3
    assert run["measurements"] > 1000
    # Then the parked ROV seen from the swinging ASV: a range offset fitted, against the truth,
    # and the forward position said determined or not.
    assert "mean |range offset error|" in proc.stdout
    assert "the forward position determined on" in proc.stdout
    assert run["orbit_fixes"] > 50
    assert abs(run["range_offset_error_mm"]) < 30.0
    assert run["look_spread_deg"] > 20.0  # the ASV looked to either side of the ROV
    # Then the ROV going down and up through the aperture, near and far (the pond is deep
    # enough for both): the elevation offset against the truth at the edges (half a minute
    # each: both edges crossed, not yet known to 0.15 deg).
    assert "mean |elevation offset error|" in proc.stdout
    near, far = run["profiles"]
    assert near["distance_m"] < 2.0 < 3.0 < far["distance_m"]
    assert near["height_gain_deg_per_cm"] > 1.5 * far["height_gain_deg_per_cm"]
    for profile in (near, far):
        above, below = profile["frames_above_below"]
        assert above > 10
        assert below > 10
    assert abs(run["elevation_offset_error_deg"]) <= 4.0 * run["elevation_offset_sigma_deg"]
    # The two tell the sonar's height (written only when known within 15 mm): said either way.
    assert "the sonar's height determined on" in proc.stdout
    if run["height_determined"]:
        assert abs(run["height_error_mm"]) <= 4.0 * run["height_sigma_mm"]
