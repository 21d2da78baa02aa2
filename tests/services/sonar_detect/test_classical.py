"""The classical detector finds a simulated ROV where it is, and stays quiet on empty water."""

from __future__ import annotations

import math

import numpy as np
import pytest

from capsd.geometry import Transform, euler_zyx_to_matrix
from capsd.payloads import SonarFrame
from capsd.services.sonar_detect.classical import ClassicalDetector
from capsd.simulator.scene import BLUEROV2_SEMI_AXES, Ellipsoid
from capsd.simulator.sonar import SonarModel, SonarRenderer
from capsd.simulator.world import make_tank


def _frame(
    renderer: SonarRenderer, sonar: Transform, rov: Ellipsoid | None, seed: int
) -> SonarFrame:
    ping = renderer.render(sonar, rov, np.random.default_rng(seed))
    return renderer.frame(ping, stamp_ns=seed, seq=seed, ping_id=seed)


@pytest.mark.parametrize(("range_m", "azimuth_deg"), [(4.0, 0.0), (6.0, 25.0), (8.0, -40.0)])
def test_finds_the_rov_centre(range_m: float, azimuth_deg: float) -> None:
    tank = make_tank("nfp", clutter="off")
    renderer = SonarRenderer(SonarModel(range_max_m=12.0, n_ranges=600), tank)
    sonar = Transform(euler_zyx_to_matrix(0.0, math.radians(30.0), 0.0), np.array([6.0, 8.0, -0.2]))
    az = math.radians(azimuth_deg)
    rov = Ellipsoid(
        sonar.apply(range_m * np.array([math.cos(az), math.sin(az), 0.0])),
        euler_zyx_to_matrix(az, 0.0, 0.0),
        BLUEROV2_SEMI_AXES,
    )
    detector = ClassicalDetector()
    errors_r, errors_a = [], []
    for seed in range(5):
        found = detector.detect(_frame(renderer, sonar, rov, seed))
        assert found, "the ROV must be detected"
        best = found[0]
        errors_r.append(best.range_m - range_m)
        errors_a.append(math.degrees(best.azimuth_rad - az))
    # The range-bias correction puts the echo (the near side) back at the centre.
    assert abs(float(np.median(errors_r))) < 0.06
    assert abs(float(np.median(errors_a))) < 0.5


def test_quiet_on_an_empty_fan() -> None:
    tank = make_tank("nfp", clutter="off")
    renderer = SonarRenderer(SonarModel(range_max_m=12.0, n_ranges=600), tank)
    # Looking level along the tank's long axis: water, then the far wall beyond range.
    sonar = Transform(np.eye(3), np.array([2.0, 8.0, -4.0]))
    detector = ClassicalDetector()
    alarms = sum(len(detector.detect(_frame(renderer, sonar, None, seed))) for seed in range(10))
    assert alarms / 10 <= 0.2
