"""The follower's config: the path cost's two knobs reach the planner and the follower."""

from __future__ import annotations

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
