"""The follower service: fixes, the ASV's pose and the tank map in, the ASV's GUIDED targets out.

It runs beside the locator (topside namespace, where the site lets that computer write) and
puts signed `follow/command` goto commands (position and heading) that the ASV's bridge
(`role: asv`) passes to ArduRover while its pilot keeps it in GUIDED; it never changes the
ASV's mode. Where to go: capsd.services.asv_follow.station; when and how fast:
capsd.services.asv_follow.follower. It also hears the ROV mission's signed commands (where
the mission sends the ROV). Health counts stations chosen, commands put, mission commands
heard, and says when no station can see the ROV.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
import time
from typing import Annotated, Literal

import msgspec
import numpy as np

from capsd import topics
from capsd.config import ConfigSection, ServiceConfig
from capsd.geometry import quat_to_matrix
from capsd.keys import check_name
from capsd.mounts import AsvDrive, SonarMountConfig
from capsd.payloads import AsvPose, AutopilotStatus, RovFix, VehicleCommand
from capsd.runner import Publisher, ServiceRunner
from capsd.services.asv_follow.follower import Follower, FollowSettings, Target
from capsd.services.asv_follow.station import StationPlanner, StationSettings
from capsd.signing import site_key
from capsd.tank import TankBounds, TankFixture

logger = logging.getLogger(__name__)

Degrees = Annotated[float, msgspec.Meta(ge=0.0, le=90.0)]
Positive = Annotated[float, msgspec.Meta(gt=0.0, le=100.0)]


class StationConfig(ConfigSection, frozen=True, kw_only=True):
    """What a good station is (capsd.services.asv_follow.station)."""

    target_elevation_deg: Annotated[float, msgspec.Meta(ge=-45.0, le=45.0)] = 0.0
    elevation_margin_deg: Degrees = 3.0
    min_range_m: Positive = 2.0
    max_range_m: Positive = 15.0
    # Stations keep the ROV this far off where any can, `min_range_m` where none can (None:
    # `min_range_m` alone): a detector that misses a ROV nearer than about a metre (the mockup).
    preferred_min_range_m: Positive | None = None
    wall_clearance_m: Annotated[float, msgspec.Meta(ge=0.0, le=20.0)] = 1.0
    hull_radius_m: Annotated[float, msgspec.Meta(ge=0.0, le=10.0)] = 0.6
    tracking_margin_m: Annotated[float, msgspec.Meta(ge=0.0, le=10.0)] = 0.5
    max_conditioning: Positive = 2.0
    # How far beyond the aperture's nominal edge a fixture still masks the ROV (beam skirts).
    mask_skirt_deg: Annotated[float, msgspec.Meta(ge=0.0, le=30.0)] = 3.0
    # Per degree a point of the ROV's mission leg ahead would sit beyond the aperture's margin
    # (0: stations for where the ROV is alone).
    path_cost_per_deg: Annotated[float, msgspec.Meta(ge=0.0, le=100.0)] = 0.5
    # A point of that leg this far along it counts 1/e as much as its first (0: all alike).
    path_discount_m: Annotated[float, msgspec.Meta(ge=0.0, le=1000.0)] = 10.0
    # Where the ASV must not go, besides fixtures of the tank that reach the surface.
    keep_out: Annotated[tuple[TankFixture, ...], msgspec.Meta(max_length=100)] = ()

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.min_range_m >= self.max_range_m:
            raise ValueError("`min_range_m` must be below `max_range_m`")
        preferred = self.preferred_min_range_m
        if preferred is not None and not self.min_range_m <= preferred < self.max_range_m:
            raise ValueError(
                "`preferred_min_range_m` must be from `min_range_m` to below `max_range_m`"
            )

    def settings(self) -> StationSettings:
        return StationSettings(
            target_elevation_rad=math.radians(self.target_elevation_deg),
            elevation_margin_rad=math.radians(self.elevation_margin_deg),
            min_range_m=self.min_range_m,
            max_range_m=self.max_range_m,
            preferred_min_range_m=self.preferred_min_range_m,
            wall_clearance_m=self.wall_clearance_m,
            hull_radius_m=self.hull_radius_m,
            tracking_margin_m=self.tracking_margin_m,
            max_conditioning=self.max_conditioning,
            mask_skirt_rad=math.radians(self.mask_skirt_deg),
            path_cost_per_deg=self.path_cost_per_deg,
            path_discount_m=self.path_discount_m,
            keep_out=self.keep_out,
        )


# How much of the ROV's leg ahead a station is to see, by the drive: an ASV that crabs keeps
# pace with the ROV (the next 6 s at the plan's 0.25 m/s); a steered one turns after it from
# where it stands (a lane of the nfp plans is 16 m).
PATH_AHEAD_M: dict[AsvDrive, float] = {"lateral": 1.5, "steered": 20.0}


class MotionConfig(ConfigSection, frozen=True, kw_only=True):
    """Dead band and limits (capsd.services.asv_follow.follower)."""

    elevation_tolerance_deg: Degrees = 2.0
    azimuth_tolerance_deg: Degrees = 15.0
    replan_after_s: Positive = 1.0
    fix_timeout_s: Positive = 1.0
    lead_s: Annotated[float, msgspec.Meta(ge=0.0, le=30.0)] = 3.0
    # Stations are to see this much of the ROV's mission leg ahead of it too. None: by the
    # drive (PATH_AHEAD_M): a steered hull watches by turning where it stands, so its station
    # is to see the rest of the leg, where one can: a move after the ROV along its lane is
    # across the line of sight, blind (ArduRover SITL, docs/JOURNAL.md session 33).
    path_ahead_m: Annotated[float, msgspec.Meta(ge=0.0, le=50.0)] | None = None
    reacquire_after_s: Positive = 6.0
    max_speed_m_s: Annotated[float, msgspec.Meta(gt=0.0, le=2.0)] = 0.5
    max_accel_m_s2: Annotated[float, msgspec.Meta(gt=0.0, le=2.0)] = 0.25
    max_yaw_rate_deg_s: Annotated[float, msgspec.Meta(gt=0.0, le=90.0)] = 15.0
    # A station facing further than this from the hull is turned to, where the hull is, before
    # the ASV goes (ArduRover turns a hull only at its target). 180: never.
    turn_first_deg: Annotated[float, msgspec.Meta(gt=0.0, le=180.0)] = 30.0
    # A ROV that lost its fix is looked for this far along its track (its mission pauses).
    stop_within_s: Annotated[float, msgspec.Meta(ge=0.0, le=30.0)] = 1.0
    # How fast a ROV holding without positions may wander: looks search a growing circle.
    lost_drift_m_s: Annotated[float, msgspec.Meta(ge=0.0, le=1.0)] = 0.02
    # How the ASV's autopilot moves it to a position target. steered: ArduRover's GUIDED, a
    # boat or an omni frame alike (a forward speed and a turn rate: the hull turns to its
    # way); the ASV then watches by turning where it is and moves as little as it can.
    # lateral: any way with the heading kept (an omni frame on a controller of its own).
    drive: AsvDrive = "steered"
    # Steered: what a second of the sonar turned off the ROV on the way to a station costs
    # (in degrees of elevation off the target, the planner's unit). A blind second costs more
    # than itself: the ROV's mission pauses half a second after its last fix, and the ASV
    # then looks for it (`capsd bench follow`, nfp lawnmower, 10 seeds: median in view 80 %
    # at 2, 85 % at 4, 99 % at 8, 98.5 % at 16 and 32; the mockup 71-74 % at any of them).
    blind_cost_per_s: Annotated[float, msgspec.Meta(ge=0.0, le=100.0)] = 8.0
    # A sonar on a tilt servo is aimed where the ROV will be this far ahead (its tracked
    # velocity): the fix's age, the way through the bridge and autopilot, the servo's slew.
    tilt_lead_s: Annotated[float, msgspec.Meta(ge=0.0, le=5.0)] = 0.5
    # Without a fresh fix the tilt servo nods this far either side of where the ROV is looked
    # for (None: half the vertical aperture; 0: no nod), at this rate.
    nod_amplitude_deg: Annotated[float, msgspec.Meta(ge=0.0, le=45.0)] | None = None
    nod_rate_deg_s: Annotated[float, msgspec.Meta(gt=0.0, le=180.0)] = 15.0
    # The pan servo holds while the ROV's bearing stays this near its boresight (0: tracks it).
    pan_dead_band_deg: Annotated[float, msgspec.Meta(ge=0.0, le=60.0)] = 15.0
    # With a pan servo the hull at its station may turn this far off facing the ROV, the pan
    # facing it (the sonar, ahead of the hull's origin, kept off a near ROV); 0: it faces it.
    pan_abeam_deg: Annotated[float, msgspec.Meta(ge=0.0, le=90.0)] = 60.0

    def settings(self) -> FollowSettings:
        return FollowSettings(
            elevation_tolerance_rad=math.radians(self.elevation_tolerance_deg),
            azimuth_tolerance_rad=math.radians(self.azimuth_tolerance_deg),
            replan_after_s=self.replan_after_s,
            fix_timeout_s=self.fix_timeout_s,
            lead_s=self.lead_s,
            path_ahead_m=(
                PATH_AHEAD_M[self.drive] if self.path_ahead_m is None else self.path_ahead_m
            ),
            reacquire_after_s=self.reacquire_after_s,
            max_speed_m_s=self.max_speed_m_s,
            max_accel_m_s2=self.max_accel_m_s2,
            max_yaw_rate_rad_s=math.radians(self.max_yaw_rate_deg_s),
            turn_first_rad=math.radians(self.turn_first_deg),
            stop_within_s=self.stop_within_s,
            lost_drift_m_s=self.lost_drift_m_s,
            tilt_lead_s=self.tilt_lead_s,
            nod_amplitude_rad=(
                None if self.nod_amplitude_deg is None else math.radians(self.nod_amplitude_deg)
            ),
            nod_rate_rad_s=math.radians(self.nod_rate_deg_s),
            pan_abeam_rad=math.radians(self.pan_abeam_deg),
            pan_dead_band_rad=math.radians(self.pan_dead_band_deg),
        )

    def drive_settings(self, station: StationSettings) -> StationSettings:
        """The planner's settings with this vehicle's drive, speed and turn rate."""
        return dataclasses.replace(
            station,
            drive=self.drive,
            blind_cost_per_s=self.blind_cost_per_s,
            transit_speed_m_s=self.max_speed_m_s,
            turn_rate_rad_s=math.radians(self.max_yaw_rate_deg_s),
        )


class Config(ServiceConfig, frozen=True, kw_only=True):
    """Follower configuration: the sonar's mount and the tank as the locator has them."""

    vehicle: str = "topside"
    locator_vehicle: str = "topside"
    asv_vehicle: str = "asv"
    # Whose ROV mission commands say where the ROV is going (`mission/command`): the follower
    # does not lead the ROV past its waypoint.
    mission_vehicle: str = "topside"
    sonar: SonarMountConfig = SonarMountConfig()
    tank: TankBounds = TankBounds()
    station: StationConfig = StationConfig()
    motion: MotionConfig = MotionConfig()
    command_rate_hz: Annotated[float, msgspec.Meta(gt=0.0, le=20.0)] = 5.0
    # required: fixes must carry, and commands get, the site's fix key's tag.
    fix_auth: Literal["required", "off"] = "required"
    fix_key: str | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("locator_vehicle", "asv_vehicle", "mission_vehicle"):
            try:
                check_name("vehicle", getattr(self, name))
            except ValueError as exc:
                raise ValueError(f"`{name}`: {exc}") from None


def _heading(orientation_xyzw: tuple[float, float, float, float]) -> float:
    r = quat_to_matrix(np.array(orientation_xyzw))
    return math.atan2(float(r[1, 0]), float(r[0, 0]))


class FollowNode:
    """Bus in, follower, bus out; thread-safe (Zenoh calls back on its own threads)."""

    def __init__(self, config: Config, commands: Publisher[VehicleCommand]):
        planner = StationPlanner(
            config.sonar, config.tank, config.motion.drive_settings(config.station.settings())
        )
        self.follower = Follower(planner, config.motion.settings())
        self.commands = commands
        self.lock = threading.Lock()
        self.put_count = 0
        self.mission_commands = 0
        self.state: str | None = None  # the last one logged

    def on_mission(self, command: VehicleCommand) -> None:
        """A ROV mission's command: where it sends the ROV (engage, goto) or that it holds."""
        if command.kind in ("engage", "goto") and command.position_m is not None:
            # Where the leg ends, not where the ROV waits for the ASV meanwhile.
            position = np.array(command.leg_end_m or command.position_m)
            after = None if command.next_leg_end_m is None else np.array(command.next_leg_end_m)
        elif command.kind == "hold":
            position, after = None, None
        else:
            return
        with self.lock:
            self.mission_commands += 1
            self.follower.on_leg_end(time.monotonic(), position, after)

    def on_fix(self, fix: RovFix) -> None:
        if fix.quality != "good":
            return
        position = fix.position_m if fix.position_m is not None else fix.raw_position_m
        if position is None:
            return
        velocity = None if fix.velocity_m_s is None else np.array(fix.velocity_m_s)
        with self.lock:
            self.follower.on_fix(time.monotonic(), np.array(position), velocity)

    def on_pose(self, pose: AsvPose) -> None:
        if pose.status == "lost":
            return
        with self.lock:
            self.follower.on_pose(np.array(pose.position_m[:2]), _heading(pose.orientation_xyzw))

    def on_status(self, status: AutopilotStatus) -> None:
        with self.lock:
            self.follower.on_mode(status.mode if status.link == "ok" else None)

    def step(self) -> None:
        with self.lock:
            target = self.follower.step(time.monotonic())
            station = self.follower.station
        self._announce(target)
        if target is None:
            return
        self.commands.put(
            VehicleCommand(
                stamp_ns=time.time_ns(),
                seq=self.commands.next_seq(),
                mission="follow",
                kind="goto",
                position_m=(float(target.position_xy[0]), float(target.position_xy[1]), 0.0),
                heading_rad=float(target.heading_rad),
                reason="station" if target.replanned else "repeat",
                direction=target.direction,
                sonar_tilt_rad=target.sonar_tilt_rad,
                sonar_pan_rad=target.sonar_pan_rad,
            )
        )
        self.put_count += 1
        if target.replanned and station is not None:
            logger.info(
                "new station",
                extra={
                    "fields": {
                        "x_m": round(float(station.position_xy[0]), 2),
                        "y_m": round(float(station.position_xy[1]), 2),
                        "heading_deg": round(math.degrees(station.heading_rad), 1),
                        "range_m": round(station.view.range_m, 2),
                        "elevation_deg": round(math.degrees(station.view.elevation_rad), 1),
                    }
                },
            )

    def _announce(self, target: Target | None) -> None:
        state = "standby" if target is None else target.state
        if state != self.state:
            logger.info("follower", extra={"fields": {"state": state}})
            self.state = state

    def counters(self) -> dict[str, int]:
        return {
            "commands_put": self.put_count,
            "stations_chosen": self.follower.replans,
            "looks_for_a_lost_rov": self.follower.looks,
            "mission_commands": self.mission_commands,
        }


def main(config: Config) -> int:
    """Run the follower until stopped."""
    key = site_key(auth=config.fix_auth, path=config.fix_key, needed_for="the follower")
    with ServiceRunner("asv_follow", config) as runner:
        commands: Publisher[VehicleCommand] = runner.publisher(topics.ASV_COMMAND, signer=key)
        node = FollowNode(config, commands)
        runner.add_counters(node.counters)
        runner.subscribe(topics.ROV_FIX, node.on_fix, vehicle=config.locator_vehicle, verifier=key)
        runner.subscribe(topics.ASV_POSE, node.on_pose, vehicle=config.asv_vehicle)
        runner.subscribe(
            topics.ROV_COMMAND, node.on_mission, vehicle=config.mission_vehicle, verifier=key
        )
        runner.subscribe(topics.ASV_AUTOPILOT, node.on_status, vehicle=config.asv_vehicle)
        logger.info("follower ready")
        runner.run(node.step, period_s=1.0 / config.command_rate_hz)
    return 0
