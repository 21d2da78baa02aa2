"""Mount configs: a tilt servo's range is checked at load and its angle adds to the pitch."""

from __future__ import annotations

import math

import msgspec
import numpy as np
import pytest

from capsd.mounts import SonarMountConfig, SonarPanConfig, SonarTiltConfig


def test_a_servo_range_upside_down_is_refused_naming_the_fields() -> None:
    with pytest.raises(msgspec.ValidationError, match=r"min_deg.*max_deg"):
        msgspec.convert({"tilt": {"min_deg": 20.0, "max_deg": 10.0}}, SonarMountConfig)
    with pytest.raises(msgspec.ValidationError, match="rate_deg_s"):
        msgspec.convert({"tilt": {"rate_deg_s": 0.0}}, SonarMountConfig)


def test_the_servo_angle_adds_to_the_pitch_about_the_yawed_y_axis() -> None:
    mount = SonarMountConfig(pitch_deg=30.0, yaw_deg=20.0, roll_deg=1.0, tilt=SonarTiltConfig())
    tilted = mount.transform(tilt_rad=math.radians(12.0))
    steeper = msgspec.structs.replace(mount, pitch_deg=42.0).transform()
    assert np.allclose(tilted.rotation, steeper.rotation)
    assert np.allclose(tilted.translation, mount.transform().translation)
    assert SonarTiltConfig(min_deg=-5.0, max_deg=5.0).clamp_rad(1.0) == pytest.approx(
        math.radians(5.0)
    )


def test_the_pan_angle_adds_to_the_yaw_about_the_bodys_z_axis_through_the_mount() -> None:
    mount = SonarMountConfig(
        pitch_deg=30.0, yaw_deg=20.0, roll_deg=1.0, tilt=SonarTiltConfig(), pan=SonarPanConfig()
    )
    panned = mount.transform(tilt_rad=math.radians(12.0), pan_rad=math.radians(-35.0))
    turned = msgspec.structs.replace(mount, pitch_deg=42.0, yaw_deg=-15.0).transform()
    assert np.allclose(panned.rotation, turned.rotation)
    assert np.allclose(panned.translation, mount.transform().translation)  # where it sits
    assert SonarPanConfig().clamp_rad(-3.0) == pytest.approx(math.radians(-90.0))
    with pytest.raises(msgspec.ValidationError, match="`pan` needs `tilt`"):
        msgspec.convert({"pan": {}}, SonarMountConfig)
    with pytest.raises(msgspec.ValidationError, match=r"min_deg.*max_deg"):
        msgspec.convert({"tilt": {}, "pan": {"min_deg": 10.0, "max_deg": 0.0}}, SonarMountConfig)
