"""Simulator configuration: tank, motion, sensors, noise, clocks, what to publish."""

from __future__ import annotations

import math
from typing import Annotated, Literal

import msgspec

from capsd.config import ConfigSection, ServiceConfig
from capsd.geometry import Transform
from capsd.mounts import AsvDrive, RovConfig, SonarMountConfig
from capsd.simulator import sonar_look
from capsd.simulator.clock import ClockModel
from capsd.simulator.imu import ImuModel
from capsd.simulator.install_errors import InstallErrorsConfig
from capsd.simulator.lidar import LidarModel
from capsd.simulator.sonar import SonarModel
from capsd.simulator.sonar_look import Look, OutsideKnob, Variety
from capsd.simulator.world import (
    RackHeights,
    Tank,
    TankName,
    TrajectoryName,
    Waves,
    make_tank,
)

Rate = Annotated[float, msgspec.Meta(gt=0.0, le=400.0)]
Sigma = Annotated[float, msgspec.Meta(ge=0.0, le=10.0)]
OnOff = Literal["on", "off"]
Vec3 = tuple[float, float, float]

# 2026-01-01T00:00:00Z: offline datasets are stamped from here, so they are reproducible.
OFFLINE_START_NS = 1_767_225_600_000_000_000


class WavesConfig(ConfigSection, frozen=True, kw_only=True):
    roll_deg: Annotated[float, msgspec.Meta(ge=0.0, le=20.0)] = 1.5
    pitch_deg: Annotated[float, msgspec.Meta(ge=0.0, le=20.0)] = 1.0
    heave_m: Annotated[float, msgspec.Meta(ge=0.0, le=1.0)] = 0.02
    roll_period_s: Annotated[float, msgspec.Meta(gt=0.5, le=60.0)] = 3.7
    pitch_period_s: Annotated[float, msgspec.Meta(gt=0.5, le=60.0)] = 4.3
    heave_period_s: Annotated[float, msgspec.Meta(gt=0.5, le=60.0)] = 5.1

    def waves(self) -> Waves:
        return Waves(
            self.roll_deg,
            self.pitch_deg,
            self.heave_m,
            self.roll_period_s,
            self.pitch_period_s,
            self.heave_period_s,
        )


class SonarImageConfig(ConfigSection, frozen=True, kw_only=True):
    """The imaging sonar (Oculus M3000d, 1.2 MHz mode) and its image formation."""

    n_beams: Annotated[int, msgspec.Meta(ge=16, le=1024)] = 512
    horizontal_fov_deg: Annotated[float, msgspec.Meta(gt=0.0, le=180.0)] = 130.0
    range_max_m: Annotated[float, msgspec.Meta(gt=0.5, le=120.0)] | None = None  # per tank
    n_ranges: Annotated[int, msgspec.Meta(ge=16, le=4000)] | None = None  # per tank
    elevation_rays: Annotated[int, msgspec.Meta(ge=1, le=128)] = 16
    gain_percent: Annotated[float, msgspec.Meta(ge=0.0, le=100.0)] = 50.0
    noise_level: Sigma = 0.0004
    ghost_gain: Annotated[float, msgspec.Meta(ge=0.0, le=1.0)] = 0.12
    # off: the fixed look; train / heldout: every knob of capsd.simulator.sonar_look drawn per seed
    # (sonar settings, image formation, ROV detail, floor, floating clutter, fish).
    variety: Variety = "off"
    # The look drawn from this seed instead of the run's: one site's sonar and tank (its
    # settings, floor and floating clutter) under other motions.
    look_seed: int | None = None
    # With variety: outside, the knobs drawn beyond the range trained on (null: all five with
    # an outside band; [] none: the others' whole ranges from the same draw).
    outside_knobs: tuple[OutsideKnob, ...] | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.outside_knobs is not None and self.variety != "outside":
            raise ValueError(
                f"`outside_knobs` needs `variety: outside` (variety is {self.variety!r})"
            )


class LidarConfig(ConfigSection, frozen=True, kw_only=True):
    position_m: Vec3 = (0.0, 0.0, 0.4)  # on a mast above the ASV's centre
    rate_hz: Rate = 15.0
    sigma_m: Sigma = 0.02
    dropout: Annotated[float, msgspec.Meta(ge=0.0, le=1.0)] = 0.01


class ImuConfig(ConfigSection, frozen=True, kw_only=True):
    rate_hz: Rate = 200.0
    mount_rpy_deg: Vec3 = (0.0, 0.0, 0.0)
    gyro_sigma_rad_s: Sigma = 0.002
    accel_sigma_m_s2: Sigma = 0.02
    gyro_bias_sigma_rad_s: Sigma = 0.001
    accel_bias_sigma_m_s2: Sigma = 0.02


class ClockConfig(ConfigSection, frozen=True, kw_only=True):
    offset_s: Annotated[float, msgspec.Meta(ge=-10.0, le=10.0)] = 0.0
    drift_ppm: Annotated[float, msgspec.Meta(ge=-1000.0, le=1000.0)] = 0.0
    jitter_s: Annotated[float, msgspec.Meta(ge=0.0, le=1.0)] = 0.0

    def model(self) -> ClockModel:
        return ClockModel(self.offset_s, self.drift_ppm, self.jitter_s)


class Clocks(ConfigSection, frozen=True, kw_only=True):
    asv: ClockConfig = ClockConfig()
    rov: ClockConfig = ClockConfig(offset_s=0.0, drift_ppm=0.0, jitter_s=0.0)


class Rates(ConfigSection, frozen=True, kw_only=True):
    sonar_hz: Annotated[float, msgspec.Meta(gt=0.0, le=40.0)] = 20.0
    asv_pose_hz: Rate = 50.0
    depth_hz: Rate = 10.0
    attitude_hz: Rate = 20.0
    # A DVL-like velocity of the ROV in W; 0 turns it off (a BlueROV2 often has none).
    velocity_hz: Annotated[float, msgspec.Meta(ge=0.0, le=200.0)] = 0.0


class Noise(ConfigSection, frozen=True, kw_only=True):
    pose_sigma_m: Sigma = 0.01
    range_sigma_m: Sigma = 0.02
    azimuth_sigma_deg: Sigma = 0.3
    depth_sigma_m: Sigma = 0.01  # a Bar30 is about 2 mm rms; a real tank adds waves and drift
    velocity_sigma_m_s: Sigma = 0.02


class Streams(ConfigSection, frozen=True, kw_only=True):
    """What to publish.

    The `*_truth_noise` streams are the truth plus the `noise` section's errors, shaped as an
    ASV pose and detections: off by default, and when on they go to the simulator's own
    `sim/asv_pose` and `sim/detections` keys, which no service subscribes to (a bench or a
    test may relay them on purpose).
    """

    sonar_frames: OnOff = "on"
    lidar: OnOff = "on"
    imu: OnOff = "on"
    asv_pose_truth_noise: OnOff = "off"
    detections_truth_noise: OnOff = "off"


class GuidedConfig(ConfigSection, frozen=True, kw_only=True):
    """The ROV flown by an ArduSub stand-in the simulator hosts (closed-loop missions).

    The stand-in listens for the bridge on tcpin:127.0.0.1:`port`; `ned_*` must be the bridge's
    `ned` settings (they turn its NED targets and estimates back into the tank frame).
    """

    port: Annotated[int, msgspec.Meta(ge=1, le=65535)]
    ned_heading_deg: Annotated[float, msgspec.Meta(ge=-360.0, le=360.0)] = 0.0
    ned_origin_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    start_m: tuple[float, float, float] | None = None  # None: the trajectory's first point
    max_speed_m_s: Annotated[float, msgspec.Meta(gt=0.0, le=2.0)] = 0.3


class AsvGuidedConfig(ConfigSection, frozen=True, kw_only=True):
    """The ASV driven by an ArduRover stand-in the simulator hosts (`asv_mode: guided`).

    It listens for the ASV's bridge (`role: asv`) on tcpin:127.0.0.1:`port`; `ned_*` must be
    that bridge's `ned` settings. `mode` is what the pilot left it in: GUIDED lets a follower
    drive it (nothing in CAP-SD ever switches the ASV to GUIDED), MANUAL keeps it still.
    """

    port: Annotated[int, msgspec.Meta(ge=1, le=65535)]
    ned_heading_deg: Annotated[float, msgspec.Meta(ge=-360.0, le=360.0)] = 0.0
    ned_origin_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    start_heading_deg: Annotated[float, msgspec.Meta(ge=-360.0, le=360.0)] | None = None
    mode: Literal["GUIDED", "MANUAL"] = "GUIDED"
    max_speed_m_s: Annotated[float, msgspec.Meta(gt=0.0, le=2.0)] = 0.3
    # steered: as ArduRover's GUIDED drives a boat or an omni frame, the hull turned towards
    # its way; lateral: an omni frame moving any way with its heading kept (a controller of
    # its own, not ArduRover's GUIDED). capsd.mounts.AsvDrive.
    drive: AsvDrive = "steered"


class Config(ServiceConfig, frozen=True, kw_only=True):
    """Simulator configuration."""

    vehicle: str = "sim"
    asv_vehicle: str = "asv"
    rov_vehicle: str = "rov"
    tank: TankName = "nfp"
    clutter: OnOff = "on"
    # per_seed: the preset's clutter laid out anew for every run (its racks, sandbags, fixtures
    # and pipes moved; capsd.simulator.world.drawn), from `layout_seed` or else the run's seed;
    # preset: the tank's one fixed layout.
    clutter_layout: Literal["per_seed", "preset"] = "per_seed"
    layout_seed: int | None = None
    # drawn: a per-seed layout's racks and skips of other heights too, some just under the
    # ROV's lower flight level (capsd.simulator.world.RackHeights; training runs, `capsd train
    # detector --rack-heights drawn`); preset: the preset's heights.
    rack_heights: RackHeights = "preset"
    trajectory: TrajectoryName = "square"
    rov_speed_m_s: Annotated[float, msgspec.Meta(gt=0.0, le=0.5)] = 0.3
    # surface: the ROV floats at the surface above its trajectory's start for the whole run
    # (a pre-dive surface check: `capsd calibrate` reads its depth offset from it), its origin
    # at rov.float_depth_m plus the installation's trim error, heaving with the waves.
    # parked: the ROV holds still where its trajectory starts (on the tank floor or a stand:
    # the range-offset manoeuvre, with asv_mode: orbit).
    # profile: the ROV holds its place in the plane where its trajectory starts and goes down
    # and up through the sonar's vertical aperture, 2 minutes a round trip (the pitch
    # manoeuvre, with asv_mode: follow, which then stands still facing it). With
    # asv_standoff_m, the ASV stands that far off and the ROV's depths span the aperture's
    # edges as seen from there (capsd.simulator.world.profile_span: a second distance
    # separates the sonar's pitch from its height).
    rov_mode: Literal["trajectory", "surface", "parked", "profile"] = "trajectory"
    profile_period_s: Annotated[float, msgspec.Meta(ge=10.0, le=3600.0)] = 120.0  # down and up
    seed: int = 0
    # spin: turns on the spot; guided: driven live by an ArduRover stand-in (`asv_guided`).
    asv_mode: Literal["follow", "stationary", "spin", "orbit", "guided"] = "follow"
    # How far behind the ROV (along W's x) the following ASV keeps; None puts the ROV on the
    # sonar's boresight at the upper flight level.
    asv_standoff_m: Annotated[float, msgspec.Meta(ge=0.0, le=50.0)] | None = None
    asv_start_xy: tuple[float, float] | None = None
    waves: WavesConfig = WavesConfig()
    sonar: SonarMountConfig = SonarMountConfig()
    sonar_image: SonarImageConfig = SonarImageConfig()
    lidar: LidarConfig = LidarConfig()
    imu: ImuConfig = ImuConfig()
    rov: RovConfig = RovConfig()
    rates: Rates = Rates()
    noise: Noise = Noise()
    clocks: Clocks = Clocks()
    streams: Streams = Streams()
    # What the installation gets wrong, unknown to the services (capsd.simulator.install_errors).
    install_errors: InstallErrorsConfig = InstallErrorsConfig()
    # The water: what the speed of sound truly is (capsd.sound_speed). The sonar assumes a
    # speed off by install_errors.sound_speed_sigma; the ROV's thermometer reads this
    # temperature plus its own bias.
    water_temperature_c: Annotated[float, msgspec.Meta(ge=0.0, le=40.0)] = 24.0
    water_salinity_ppt: Annotated[float, msgspec.Meta(ge=0.0, le=45.0)] = 0.0
    # Sim-time windows [start_s, end_s] in which the sonar sees nothing (the ROV out of view).
    sonar_dropouts_s: tuple[tuple[float, float], ...] = ()
    # Real-time runs precompute this much motion, then repeat it.
    motion_horizon_s: Annotated[float, msgspec.Meta(ge=10.0, le=86_400.0)] = 1800.0
    # Set: the ROV is not on `trajectory` but flown by an ArduSub stand-in that the simulator
    # hosts (GUIDED targets from the bridge, on its own estimates); the ASV must not follow.
    guided: GuidedConfig | None = None
    asv_guided: AsvGuidedConfig | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.guided is not None and self.asv_mode == "follow":
            raise ValueError(
                "`guided`: the ASV cannot follow a ROV flown live; use asv_mode: stationary"
                " or guided"
            )
        if self.guided is not None and self.rov_mode != "trajectory":
            raise ValueError(
                f"`rov_mode: {self.rov_mode}`: a ROV flown live (`guided`) flies its own way"
            )
        if (self.asv_mode == "guided") != (self.asv_guided is not None):
            raise ValueError("`asv_guided`: needed with `asv_mode: guided`, and only then")
        if self.rack_heights == "drawn" and (
            self.clutter_layout == "preset" or self.clutter == "off"
        ):
            raise ValueError(
                "`rack_heights: drawn` draws a per-seed layout's racks: it needs "
                "`clutter_layout: per_seed` and `clutter: on`"
            )
        for i, (start, end) in enumerate(self.sonar_dropouts_s):
            if not 0.0 <= start < end:
                raise ValueError(
                    f"`sonar_dropouts_s[{i}]` must be [start, end] with 0 <= start < end"
                )

    def world_tank(self) -> Tank:
        """The run's tank: the preset with this run's clutter layout."""
        seed = self.seed if self.layout_seed is None else self.layout_seed
        per_seed = self.clutter_layout == "per_seed"
        return make_tank(
            self.tank,
            clutter=self.clutter,
            layout_seed=seed if per_seed else None,
            rack_heights=self.rack_heights,
        )

    def look(self) -> Look | None:
        """The run's draw of the look knobs (None: the fixed look)."""
        variety = self.sonar_image.variety
        if variety == "off":
            return None
        tank = make_tank(self.tank, clutter="off")
        reach = math.hypot(tank.length_m, tank.width_m)
        seed = self.seed if self.sonar_image.look_seed is None else self.sonar_image.look_seed
        knobs = self.sonar_image.outside_knobs
        return sonar_look.draw(
            sonar_look.look_rng(seed),
            variety,
            tank_reach_m=reach,
            outside_knobs=None if knobs is None else frozenset(knobs),
        )

    def sonar_model(self) -> SonarModel:
        img = self.sonar_image
        range_max = img.range_max_m or (8.0 if self.tank == "mockup" else 20.0)
        n_ranges = img.n_ranges or (800 if self.tank == "mockup" else 1000)
        look = self.look()
        model = self._fixed_sonar_model(range_max, n_ranges)
        return model if look is None else model.with_look(look)

    def _fixed_sonar_model(self, range_max: float, n_ranges: int) -> SonarModel:
        img = self.sonar_image
        return SonarModel(
            n_beams=img.n_beams,
            half_fov_rad=math.radians(img.horizontal_fov_deg / 2),
            vertical_aperture_rad=math.radians(self.sonar.vertical_aperture_deg),
            beam_model=self.sonar.beam_model,
            range_max_m=range_max,
            n_ranges=n_ranges,
            elevation_rays=img.elevation_rays,
            gain_percent=img.gain_percent,
            noise_level=img.noise_level,
            ghost_gain=img.ghost_gain,
        )

    def lidar_model(self) -> LidarModel:
        return LidarModel(
            sigma_m=self.lidar.sigma_m,
            dropout=self.lidar.dropout,
            scan_time_s=1.0 / self.lidar.rate_hz,
        )

    def lidar_mount(self) -> Transform:
        return Transform.from_euler_zyx(
            self.lidar.position_m, yaw_rad=0.0, pitch_rad=0.0, roll_rad=0.0
        )

    def imu_model(self) -> ImuModel:
        i = self.imu
        return ImuModel(
            i.rate_hz,
            i.gyro_sigma_rad_s,
            i.accel_sigma_m_s2,
            i.gyro_bias_sigma_rad_s,
            i.accel_bias_sigma_m_s2,
        )

    def imu_mounting(self) -> Transform:
        """R_I_B as a Transform (the IMU's axes expressed from the body's)."""
        r, p, y = (math.radians(v) for v in self.imu.mount_rpy_deg)
        return Transform.from_euler_zyx(
            (0.0, 0.0, 0.0), yaw_rad=y, pitch_rad=p, roll_rad=r
        ).inverse()
