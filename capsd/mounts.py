"""Vehicle mounting config shared by services and the simulator: sonar H_B_S, ROV lever arm."""

from __future__ import annotations

import math
from typing import Annotated, Literal

import msgspec

from capsd.config import ConfigSection
from capsd.geometry import Transform
from capsd.sonar_geometry import BeamModel

# How the ASV's autopilot moves it to a position target. steered: as ArduRover's GUIDED drives
# a boat or an omni frame (a forward speed and a turn rate: the hull turns to its way, and the
# sonar with it); lateral: any way with the heading kept (an omni frame on a controller that
# uses its lateral thrust, not ArduRover's GUIDED). The follower and the simulator's stand-in.
AsvDrive = Literal["steered", "lateral"]


class SonarTiltConfig(ConfigSection, frozen=True, kw_only=True):
    """A tilt servo under the sonar: the angle it adds to the mount's pitch (down +), its limits.

    The mount's `pitch_deg` is the pitch at the servo's zero (what `capsd calibrate` measures);
    the servo's reported angle is added to it ping by ping (docs/CONVENTIONS.md).
    """

    min_deg: Annotated[float, msgspec.Meta(ge=-90.0, le=90.0)] = -15.0
    max_deg: Annotated[float, msgspec.Meta(ge=-90.0, le=90.0)] = 40.0
    rate_deg_s: Annotated[float, msgspec.Meta(gt=0.0, le=720.0)] = 30.0
    # The locator fixes a ping only with a reported angle at most this old (the servo moves).
    max_age_s: Annotated[float, msgspec.Meta(gt=0.0, le=10.0)] = 0.5

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.min_deg >= self.max_deg:
            raise ValueError(f"`min_deg` ({self.min_deg}) must be below `max_deg` ({self.max_deg})")

    def clamp_rad(self, tilt_rad: float) -> float:
        """`tilt_rad` within the servo's range."""
        return min(max(tilt_rad, math.radians(self.min_deg)), math.radians(self.max_deg))


class SonarPanConfig(ConfigSection, frozen=True, kw_only=True):
    """A pan servo under the tilt servo: the angle it adds to the mount's yaw (left +), limits.

    A steered hull (ArduRover's GUIDED turns it to its way) takes a forward-looking sonar off
    the ROV whenever its way crosses the ROV's bearing; a pan keeps the sonar on it. The mount's
    `yaw_deg` is the yaw at the pan's zero; the reported angle is added ping by ping
    (docs/CONVENTIONS.md). Needs the tilt servo (an autopilot mount with both axes).
    """

    min_deg: Annotated[float, msgspec.Meta(ge=-180.0, le=180.0)] = -90.0
    max_deg: Annotated[float, msgspec.Meta(ge=-180.0, le=180.0)] = 90.0
    rate_deg_s: Annotated[float, msgspec.Meta(gt=0.0, le=720.0)] = 60.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.min_deg >= self.max_deg:
            raise ValueError(f"`min_deg` ({self.min_deg}) must be below `max_deg` ({self.max_deg})")

    def clamp_rad(self, pan_rad: float) -> float:
        """`pan_rad` within the servo's range."""
        return min(max(pan_rad, math.radians(self.min_deg)), math.radians(self.max_deg))


class SonarMountConfig(ConfigSection, frozen=True, kw_only=True):
    """H_B_S: where the sonar sits on the ASV, and its beam geometry."""

    position_m: tuple[float, float, float] = (0.3, 0.0, -0.2)
    yaw_deg: Annotated[float, msgspec.Meta(ge=-180.0, le=180.0)] = 0.0
    pitch_deg: Annotated[float, msgspec.Meta(ge=-90.0, le=90.0)] = 30.0
    roll_deg: Annotated[float, msgspec.Meta(ge=-180.0, le=180.0)] = 0.0
    vertical_aperture_deg: Annotated[float, msgspec.Meta(gt=0.0, le=90.0)] = 20.0
    beam_model: BeamModel = "conical"
    # Added to every detection's range before a fix (the locator's): where the echo's range
    # sits from the ROV's centre beyond what the detector allows for, and the sonar's own zero
    # (which bin edge a range stands for). `capsd calibrate --what range` measures it; the
    # simulator's sonar has none of its own (its range errors are the drawn sound speed's).
    range_offset_m: Annotated[float, msgspec.Meta(ge=-0.5, le=0.5)] = 0.0
    # None: the sonar is fixed to the hull. A servo: its angle is added to `pitch_deg`.
    tilt: SonarTiltConfig | None = None
    # None: no pan. A pan servo (with the tilt: one mount, both axes, one report whose age
    # `tilt.max_age_s` bounds): its angle is added to `yaw_deg`.
    pan: SonarPanConfig | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.pan is not None and self.tilt is None:
            raise ValueError("`pan` needs `tilt`: the pan servo is the tilt mount's second axis")

    def transform(self, *, tilt_rad: float = 0.0, pan_rad: float = 0.0) -> Transform:
        """H_B_S in radians (the one place its degrees are converted), the servos at their angles.

        The tilt turns the sonar about its own y axis (the pitch is the mount's plus the tilt),
        the pan about the body's z axis through the mount's position (the yaw is the mount's
        plus the pan).
        """
        return Transform.from_euler_zyx(
            self.position_m,
            yaw_rad=math.radians(self.yaw_deg) + pan_rad,
            pitch_rad=math.radians(self.pitch_deg) + tilt_rad,
            roll_rad=math.radians(self.roll_deg),
        )


class RovConfig(ConfigSection, frozen=True, kw_only=True):
    """The ROV's pressure sensor: its lever arm t_R_D in the ROV body frame, its offset."""

    pressure_sensor_m: tuple[float, float, float] = (-0.2, 0.0, 0.0)
    # The ROV origin's depth when it floats at rest at the surface, trimmed as it dives (a
    # BlueROV2's 0.25 m frame floats about 1-2 cm proud): what a surface check compares with.
    float_depth_m: Annotated[float, msgspec.Meta(ge=0.0, le=2.0)] = 0.11
    # Added to every depth reading before use (services only; the simulator's sensor has its
    # drawn bias instead): what `capsd calibrate` measured at the surface for this boot of the
    # autopilot (ArduSub zeroes its pressure at boot, so each boot has its own offset).
    depth_offset_m: Annotated[float, msgspec.Meta(ge=-1.0, le=1.0)] = 0.0
