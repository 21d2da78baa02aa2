"""Simulator configuration: tank, trajectory, sonar mount, rates, noise and dropouts."""

from __future__ import annotations

from typing import Annotated

import msgspec

from capsd.config import ConfigSection, ServiceConfig
from capsd.mounts import RovConfig, SonarMountConfig
from simulator.world import TankName, TrajectoryName

Rate = Annotated[float, msgspec.Meta(gt=0.0, le=200.0)]
Sigma = Annotated[float, msgspec.Meta(ge=0.0, le=10.0)]


class Rates(ConfigSection, frozen=True, kw_only=True):
    asv_pose_hz: Rate = 50.0
    sonar_hz: Rate = 10.0
    depth_hz: Rate = 10.0
    attitude_hz: Rate = 20.0
    # A DVL-like velocity of the ROV in W; 0 turns it off (a BlueROV2 often has none).
    velocity_hz: Annotated[float, msgspec.Meta(ge=0.0, le=200.0)] = 0.0


class Noise(ConfigSection, frozen=True, kw_only=True):
    pose_sigma_m: Sigma = 0.01
    range_sigma_m: Sigma = 0.02
    azimuth_sigma_deg: Sigma = 0.3
    depth_sigma_m: Sigma = 0.01
    velocity_sigma_m_s: Sigma = 0.02


class Config(ServiceConfig, frozen=True, kw_only=True):
    """Simulator configuration."""

    vehicle: str = "sim"
    asv_vehicle: str = "asv"
    rov_vehicle: str = "rov"
    tank: TankName = "nfp"
    trajectory: TrajectoryName = "square"
    rov_speed_m_s: Annotated[float, msgspec.Meta(gt=0.0, le=0.5)] = 0.3
    seed: int = 0
    sonar: SonarMountConfig = SonarMountConfig()
    rov: RovConfig = RovConfig()
    sonar_max_range_m: Annotated[float, msgspec.Meta(gt=0.1, le=120.0)] = 30.0
    sonar_half_fov_deg: Annotated[float, msgspec.Meta(gt=0.0, le=90.0)] = 65.0
    # The ASV keeps station so the ROV sits near the sonar's boresight (it "follows").
    asv_follow_lag_s: Annotated[float, msgspec.Meta(gt=0.0, le=60.0)] = 2.0
    rates: Rates = Rates()
    noise: Noise = Noise()
    # Sim-time windows [start_s, end_s] in which the sonar sees nothing (the ROV out of view).
    sonar_dropouts_s: tuple[tuple[float, float], ...] = ()

    def __post_init__(self) -> None:
        super().__post_init__()
        for i, (start, end) in enumerate(self.sonar_dropouts_s):
            if not 0.0 <= start < end:
                raise ValueError(
                    f"`sonar_dropouts_s[{i}]` must be [start, end] with 0 <= start < end"
                )
