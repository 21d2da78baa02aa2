"""Tank frame to NED: positions, covariances and attitudes for several tank headings."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from capsd.geometry import euler_zyx_to_matrix
from capsd.ned import TankToNed, upper_triangle


@pytest.mark.parametrize(
    ("heading_deg", "p_w", "expected_ned"),
    [
        (0.0, (1.0, 2.0, -3.0), (1.0, -2.0, 3.0)),  # x north, y (left of x) west
        (90.0, (1.0, 2.0, -3.0), (2.0, 1.0, 3.0)),  # x east, y north
        (180.0, (1.0, 2.0, -3.0), (-1.0, 2.0, 3.0)),  # x south, y east
        (-90.0, (1.0, 2.0, -3.0), (-2.0, -1.0, 3.0)),  # x west, y south
        (30.0, (1.0, 0.0, 0.0), (math.cos(math.radians(30)), math.sin(math.radians(30)), 0.0)),
    ],
)
def test_positions(
    heading_deg: float, p_w: tuple[float, ...], expected_ned: tuple[float, ...]
) -> None:
    ned = TankToNed(math.radians(heading_deg), np.zeros(3))
    assert ned.position(np.array(p_w)) == pytest.approx(expected_ned, abs=1e-12)


def test_origin_offset() -> None:
    ned = TankToNed(0.0, np.array([10.0, -5.0, 0.5]))
    assert ned.position(np.zeros(3)) == pytest.approx([10.0, -5.0, 0.5])
    assert ned.position_to_tank(ned.position(np.array([1.0, 2.0, -3.0]))) == pytest.approx(
        [1.0, 2.0, -3.0]
    )


def test_covariance_rotates_with_the_axes() -> None:
    ned = TankToNed(math.radians(90.0), np.zeros(3))
    cov = ned.covariance(np.diag([0.01, 0.04, 0.09]))
    assert np.diag(cov) == pytest.approx([0.04, 0.01, 0.09])


def test_attitude_of_a_level_rov_facing_tank_x() -> None:
    # W's x at heading 30 deg: a ROV facing W's x has ArduPilot yaw 30 deg, level.
    ned = TankToNed(math.radians(30.0), np.zeros(3))
    roll, pitch, yaw = ned.attitude_to_ned(np.eye(3))
    assert (roll, pitch, yaw) == pytest.approx((0.0, 0.0, math.radians(30.0)), abs=1e-12)


def test_nose_down_is_negative_pitch_in_both() -> None:
    # Pitch +10 deg about FLU y (left) is nose DOWN; in FRD (y right) nose down is pitch -10 deg.
    ned = TankToNed(0.0, np.zeros(3))
    r_w_r = euler_zyx_to_matrix(0.0, math.radians(10.0), 0.0)
    nose = r_w_r @ np.array([1.0, 0.0, 0.0])
    assert nose[2] < 0.0
    roll, pitch, _ = ned.attitude_to_ned(r_w_r)
    assert pitch == pytest.approx(-math.radians(10.0))
    assert roll == pytest.approx(0.0, abs=1e-12)


angles = st.floats(min_value=-3.0, max_value=3.0)


@given(
    st.floats(min_value=-math.pi, max_value=math.pi),
    angles,
    st.floats(min_value=-1.4, max_value=1.4),
    angles,
)
def test_attitude_round_trip(heading: float, roll: float, pitch: float, yaw: float) -> None:
    ned = TankToNed(heading, np.zeros(3))
    r_w_r = ned.attitude_to_tank(roll, pitch, yaw)
    back = ned.attitude_to_ned(r_w_r)
    assert np.allclose(
        euler_zyx_to_matrix(back[2], back[1], back[0]),
        euler_zyx_to_matrix(yaw, pitch, roll),
        atol=1e-9,
    )


def test_upper_triangle_layout() -> None:
    m = np.arange(36, dtype=float).reshape(6, 6)
    tri = upper_triangle(m)
    assert len(tri) == 21
    # MAVLink: x var at 0, y var at 6, z var at 11, roll 15, pitch 18, yaw 20.
    assert [tri[i] for i in (0, 6, 11, 15, 18, 20)] == [m[k, k] for k in range(6)]
