"""Vehicle mounting config shared by services and the simulator: sonar H_B_S, ROV lever arm."""

from __future__ import annotations

import math
from typing import Annotated

import msgspec

from capsd.config import ConfigSection
from capsd.geometry import Transform
from capsd.sonar_geometry import BeamModel


class SonarMountConfig(ConfigSection, frozen=True, kw_only=True):
    """H_B_S: where the sonar sits on the ASV, and its beam geometry."""

    position_m: tuple[float, float, float] = (0.3, 0.0, -0.2)
    yaw_deg: Annotated[float, msgspec.Meta(ge=-180.0, le=180.0)] = 0.0
    pitch_deg: Annotated[float, msgspec.Meta(ge=-90.0, le=90.0)] = 30.0
    roll_deg: Annotated[float, msgspec.Meta(ge=-180.0, le=180.0)] = 0.0
    vertical_aperture_deg: Annotated[float, msgspec.Meta(gt=0.0, le=90.0)] = 20.0
    beam_model: BeamModel = "conical"

    def transform(self) -> Transform:
        """H_B_S in radians (the one place its degrees are converted)."""
        return Transform.from_euler_zyx(
            self.position_m,
            yaw_rad=math.radians(self.yaw_deg),
            pitch_rad=math.radians(self.pitch_deg),
            roll_rad=math.radians(self.roll_deg),
        )


class RovConfig(ConfigSection, frozen=True, kw_only=True):
    """The ROV's pressure sensor lever arm t_R_D in the ROV body frame."""

    pressure_sensor_m: tuple[float, float, float] = (-0.2, 0.0, 0.0)
