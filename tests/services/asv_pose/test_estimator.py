"""The pose estimator on simulated IMU and LiDAR against the simulator's truth."""

from __future__ import annotations

from typing import Literal

import pytest

from capsd.bench.asv_pose import rms_errors
from capsd.simulator.world import TankName


def _rms_errors(
    tank: TankName, mode: Literal["follow", "stationary"], seconds: float
) -> tuple[float, float, float, float, str]:
    r = rms_errors(tank, mode, seconds)
    return (
        float(r["position_mm"]) / 1000,
        float(r["yaw_deg"]),
        float(r["roll_deg"]),
        float(r["pitch_deg"]),
        str(r["status"]),
    )


@pytest.mark.parametrize("mode", ["stationary", "follow"])
@pytest.mark.parametrize("tank", ["nfp", "mockup"])
def test_meets_the_pose_targets(tank: TankName, mode: Literal["follow", "stationary"]) -> None:
    # Issue 9's targets: position <= 20 mm, yaw <= 0.3 deg, roll/pitch <= 0.2 deg, also while
    # the ASV manoeuvres (following the ROV).
    pos, yaw, roll, pitch, status = _rms_errors(tank, mode, 30.0)
    assert status == "ok"
    assert pos < 0.020
    assert yaw < 0.3
    assert roll < 0.2
    assert pitch < 0.2
