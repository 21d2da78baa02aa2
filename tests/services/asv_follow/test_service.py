"""The follower's config: the path cost's knobs and the drive reach the planner and the follower."""

from __future__ import annotations

import math

import msgspec
import pytest

from capsd.services.asv_follow.service import MotionConfig, StationConfig


def test_the_path_cost_is_configured_and_bounded() -> None:
    assert StationConfig().settings().path_cost_per_deg == pytest.approx(0.5)
    assert StationConfig(path_cost_per_deg=0.0).settings().path_cost_per_deg == 0.0
    assert MotionConfig(path_ahead_m=3.0).settings().path_ahead_m == pytest.approx(3.0)
    with pytest.raises(msgspec.ValidationError, match="path_cost_per_deg"):
        msgspec.convert({"path_cost_per_deg": -1.0}, StationConfig)
    with pytest.raises(msgspec.ValidationError, match="path_ahead_m"):
        msgspec.convert({"path_ahead_m": -1.0}, MotionConfig)


def test_the_drive_reaches_the_planner_with_the_vehicles_speed_and_turn_rate() -> None:
    """Steered (ArduRover's GUIDED) by default; a drive the follower does not know is refused."""
    motion = MotionConfig(max_speed_m_s=0.4, max_yaw_rate_deg_s=10.0)
    settings = motion.drive_settings(StationConfig().settings())
    assert settings.drive == "steered"
    assert settings.transit_speed_m_s == pytest.approx(0.4)
    assert settings.turn_rate_rad_s == pytest.approx(math.radians(10.0))
    assert settings.blind_cost_per_s == pytest.approx(8.0)
    lateral = msgspec.convert({"drive": "lateral"}, MotionConfig)
    assert lateral.drive_settings(StationConfig().settings()).drive == "lateral"
    with pytest.raises(msgspec.ValidationError, match="drive"):
        msgspec.convert({"drive": "sideways"}, MotionConfig)
    with pytest.raises(msgspec.ValidationError, match="blind_cost_per_s"):
        msgspec.convert({"blind_cost_per_s": -1.0}, MotionConfig)
