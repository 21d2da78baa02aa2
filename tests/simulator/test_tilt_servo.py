"""The simulated tilt servo: reports where it is driven at once, gets there at its rate."""

from __future__ import annotations

import math

import pytest

from capsd.mounts import SonarPanConfig, SonarTiltConfig
from capsd.simulator.tilt_servo import TiltServo


def test_the_report_runs_ahead_of_the_servo_which_slews_at_its_rate() -> None:
    servo = TiltServo(SonarTiltConfig(rate_deg_s=30.0), zero_pitch_deg=-45.0)
    assert servo.tilt_rad(5.0) == 0.0
    assert servo.reported_pitch_rad() == pytest.approx(math.radians(-45.0))
    servo.command(10.0, -60.0)  # 15 deg down from the zero
    assert servo.reported_pitch_rad() == pytest.approx(math.radians(-60.0))  # at once
    assert servo.tilt_rad(10.0) == pytest.approx(0.0)
    assert servo.tilt_rad(10.25) == pytest.approx(math.radians(7.5))  # half way
    assert servo.tilt_rad(11.0) == pytest.approx(math.radians(15.0))  # there, and stays
    # Told back up half way through: from where it is, not from where it was told.
    servo.command(11.25, -45.0)
    assert servo.tilt_rad(11.25) == pytest.approx(math.radians(15.0))
    assert servo.tilt_rad(11.5) == pytest.approx(math.radians(7.5))


def test_beyond_its_range_it_stops_at_the_limit_and_says_so() -> None:
    servo = TiltServo(SonarTiltConfig(min_deg=-15.0, max_deg=40.0), zero_pitch_deg=-45.0)
    servo.command(0.0, -120.0)  # 75 deg down asked, 40 possible
    assert servo.reported_pitch_rad() == pytest.approx(math.radians(-85.0))
    assert servo.tilt_rad(100.0) == pytest.approx(math.radians(40.0))
    servo.command(100.0, float("nan"))  # not a command: nothing changes
    assert servo.commands == 1
    assert servo.tilt_rad(200.0) == pytest.approx(math.radians(40.0))


def test_it_holds_its_angle_against_the_horizon_taking_the_hull_s_pitch_out() -> None:
    servo = TiltServo(SonarTiltConfig(), zero_pitch_deg=-45.0)
    servo.command(0.0, -55.0)  # 10 deg down from the zero, against the horizon
    hull_nose_down = math.radians(1.0)
    assert servo.tilt_rad(5.0, hull_pitch_rad=hull_nose_down) == pytest.approx(math.radians(9.0))


def test_a_pan_servo_takes_the_yaw_right_positive_and_turns_left_positive_at_its_rate() -> None:
    servo = TiltServo(SonarTiltConfig(), zero_pitch_deg=-45.0, pan=SonarPanConfig(rate_deg_s=60.0))
    servo.command(0.0, -45.0, -30.0)  # MAVLink: 30 deg to the left
    assert servo.reported_yaw_rad() == pytest.approx(math.radians(-30.0))  # at once
    assert servo.pan_rad(0.25) == pytest.approx(math.radians(15.0))  # 60 deg/s
    assert servo.pan_rad(1.0) == pytest.approx(math.radians(30.0))
    servo.command(2.0, float("nan"), 120.0)  # past the right limit (90); the pitch kept
    assert servo.pan_rad(10.0) == pytest.approx(math.radians(-90.0))
    assert servo.tilt_rad(10.0) == pytest.approx(0.0)
    # Without a pan servo a yaw is nobody's.
    plain = TiltServo(SonarTiltConfig(), zero_pitch_deg=-45.0)
    plain.command(0.0, -45.0, 40.0)
    assert plain.pan_rad(5.0) == 0.0
    assert plain.reported_yaw_rad() == 0.0
