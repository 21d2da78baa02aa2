"""The view guard's geometry: the ROV's elevation margin in the sonar, now and ahead."""

from __future__ import annotations

import math

import msgspec
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from capsd.geometry import Transform
from capsd.mission.view_guard import elevation_margin_rad, view_margin_rad
from capsd.mounts import SonarMountConfig, SonarPanConfig, SonarTiltConfig

# A level ASV at the origin facing +x; the sonar at its origin, pitched 45 deg down.
MOUNT = SonarMountConfig(position_m=(0.0, 0.0, 0.0), pitch_deg=45.0, vertical_aperture_deg=20.0)
ASV = Transform.from_euler_zyx((0.0, 0.0, 0.0), yaw_rad=0.0, pitch_rad=0.0, roll_rad=0.0)
HALF = math.radians(10.0)


@given(
    distance=st.floats(0.3, 20.0),
    depression_deg=st.floats(20.0, 70.0),
    heading=st.floats(-math.pi, math.pi),
)
def test_the_margin_is_the_half_aperture_less_the_elevation_off_the_boresight(
    distance: float, depression_deg: float, heading: float
) -> None:
    # The ASV turned to face the ROV: only the depression matters.
    asv = Transform.from_euler_zyx((1.0, 2.0, 0.0), yaw_rad=heading, pitch_rad=0.0, roll_rad=0.0)
    d = math.radians(depression_deg)
    rov = np.array([1.0, 2.0, 0.0]) + distance * np.array(
        [math.cos(d) * math.cos(heading), math.cos(d) * math.sin(heading), -math.sin(d)]
    )
    margin = elevation_margin_rad(asv=asv, mount=MOUNT, rov_m=rov)
    assert margin == pytest.approx(HALF - abs(d - math.radians(45.0)), abs=1e-9)


def test_a_rov_under_the_hull_or_at_the_sonar_is_far_outside() -> None:
    below = elevation_margin_rad(asv=ASV, mount=MOUNT, rov_m=np.array([0.0, 0.0, -1.0]))
    assert below == pytest.approx(HALF - math.radians(45.0))
    assert elevation_margin_rad(asv=ASV, mount=MOUNT, rov_m=np.zeros(3)) == -math.pi


def test_the_margin_ahead_counts_when_the_rov_flies_towards_the_sonar() -> None:
    rov = np.array([1.0, 0.0, -1.0])  # on the boresight
    towards = np.array([-0.2, 0.0, 0.0])
    now = view_margin_rad(asv=ASV, mount=MOUNT, rov_m=rov, velocity_m_s=None, lookahead_s=1.5)
    ahead = view_margin_rad(asv=ASV, mount=MOUNT, rov_m=rov, velocity_m_s=towards, lookahead_s=1.5)
    assert now == pytest.approx(HALF)
    # 0.3 m nearer: the depression is atan(1 / 0.7) = 55 deg, 10 deg off the boresight.
    assert ahead == pytest.approx(HALF - (math.atan2(1.0, 0.7) - math.radians(45.0)))
    assert ahead < 0.01


def test_a_sonar_on_a_tilt_servo_is_judged_at_the_servo_s_zero() -> None:
    """As the fixed sonar: the ROV keeps to the stations' geometry, the servo covers lags."""
    servo = msgspec.structs.replace(MOUNT, tilt=SonarTiltConfig())
    d = math.radians(60.0)  # 15 deg below the boresight at the zero: outside
    rov = 3.0 * np.array([math.cos(d), 0.0, -math.sin(d)])
    assert elevation_margin_rad(asv=ASV, mount=servo, rov_m=rov) == pytest.approx(
        elevation_margin_rad(asv=ASV, mount=MOUNT, rov_m=rov)
    )
    assert elevation_margin_rad(asv=ASV, mount=servo, rov_m=rov) < 0.0


def test_a_sonar_on_a_pan_servo_is_judged_where_the_pan_is() -> None:
    """A ROV abeam, 45 deg down: outside the fan's view ahead, mid aperture panned to it."""
    servos = msgspec.structs.replace(MOUNT, tilt=SonarTiltConfig(), pan=SonarPanConfig())
    rov = np.array([0.0, 3.0, -3.0])  # to port
    ahead = elevation_margin_rad(asv=ASV, mount=servos, rov_m=rov)
    panned = elevation_margin_rad(asv=ASV, mount=servos, rov_m=rov, pan_rad=math.pi / 2)
    assert ahead < 0.0
    assert panned == pytest.approx(HALF, abs=1e-9)
