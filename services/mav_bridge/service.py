"""The MAVLink bridge: autopilot telemetry onto the bus, gated estimates into the autopilot.

Two roles. `rov` (the default): ArduSub on the ROV, fed the locator's fixes, as below. `asv`:
ArduRover (boat or omni frame) on the ASV, fed the ASV's own pose (asv_pose: the tank is
GPS-denied for the ASV too) as VISION_POSITION_ESTIMATE with the pose's attitude, its state
published on `asv/autopilot`, and the follower's GUIDED targets (`follow/command`, with a
heading) passed on while the pilot keeps it in GUIDED; the ASV's bridge never switches to
GUIDED itself, and it has no depth.

Vehicle to bus (stamps from the autopilot's boot clock mapped to Unix time):
- depth from SCALED_PRESSURE2, the Bar30's raw absolute pressure (baro instance 1 on a
  BlueROV2): depth = (p - p_surface) / (rho g). Raw pressure, not VFR_HUD.alt or the EKF's
  LOCAL_POSITION_NED.z, because those are filtered by the EKF that our own positions feed (a
  loop) and VFR_HUD.alt needs an origin. p_surface is the vehicle's BARO2_GND_PRESS unless
  configured; rho is 1000 kg/m^3 x the vehicle's BARO_SPEC_GRAV unless configured.
- attitude from ATTITUDE (FRD in NED, converted to FLU in the tank frame W);
- armed state and mode from HEARTBEAT, EKF flags from EKF_STATUS_REPORT.
Bus to vehicle: RovFix estimates through the safety gate (capsd.services.mav_bridge.gate), converted
to NED, as VISION_POSITION_ESTIMATE (or GPS_INPUT), usec = the estimate's measurement time.
Mission commands (VehicleCommand, signed like fixes; only with `mission_commands: accept`): fresh,
inside the tank's geofence, then MAV_CMD_DO_SET_MODE (GUIDED to engage, POSHOLD to hold, the
latter only from GUIDED or again to a vehicle holding; ALT_HOLD when the autopilot refuses
POSHOLD for want of a position) and SET_POSITION_TARGET_LOCAL_NED, each logged and counted.
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from collections import Counter
from typing import Annotated, Literal

import msgspec
import numpy as np

from capsd import topics
from capsd.config import ConfigSection, ServiceConfig
from capsd.errors import ConfigError
from capsd.geometry import Array, euler_zyx_to_matrix, matrix_to_quat, quat_to_matrix
from capsd.keys import check_name
from capsd.mailbox import Mailbox
from capsd.ned import TankToNed, upper_triangle
from capsd.payloads import (
    AutopilotStatus,
    DriveDirection,
    RovAttitude,
    RovDepth,
    SonarTilt,
    VehicleCommand,
)
from capsd.protocols.mavlink import (
    MAV_CMD_DO_SET_MODE,
    MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY,
    MAV_RESULT_ACCEPTED,
    MAV_SYS_STATUS_SENSOR_VISION_POSITION,
    Attitude,
    Autopilot,
    CommandAck,
    EkfStatus,
    GimbalAttitude,
    Heartbeat,
    MavLink,
    OriginReport,
    ParamValue,
    ScaledPressure,
    SysStatus,
    SystemTime,
    check_connection,
    message_id,
    mode_name,
)
from capsd.runner import Publisher, ServiceRunner, StreamCounter
from capsd.services.mav_bridge.clock import BootClock
from capsd.services.mav_bridge.gate import Estimate, GateSettings, Passed, SafetyGate
from capsd.services.mav_bridge.uptake import EstimateUptake
from capsd.signing import SiteKey, site_key
from capsd.tank import TankBounds

logger = logging.getLogger(__name__)

G = 9.80665
_AUTOPILOT_COMPONENT = 1
_REOPEN_FIRST_S = 0.25
_REOPEN_MAX_S = 2.0
# With the link up, depth or attitude missing for this long makes Health degraded (why).
_INPUT_GRACE_S = 1.0
# A depth this far above the surface (negative) is no real reading: the reference is wrong.
_ABOVE_SURFACE_M = -0.1


class MavlinkConfig(ConfigSection, frozen=True, kw_only=True):
    """The link to the autopilot."""

    connect: str = "tcp:127.0.0.1:5777"  # BlueOS's MAVLink router, internal TCP
    system_id: Annotated[int, msgspec.Meta(ge=1, le=255)] = 1
    component_id: Annotated[int, msgspec.Meta(ge=1, le=255)] = MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY
    target_system: Annotated[int, msgspec.Meta(ge=1, le=255)] = 1
    # No HEARTBEAT from the autopilot for this long: the link is reopened.
    link_timeout_s: Annotated[float, msgspec.Meta(gt=0.0, le=60.0)] = 2.0

    def __post_init__(self) -> None:
        super().__post_init__()
        try:
            check_connection(self.connect)
        except ConfigError as exc:
            raise ValueError(f"`connect`: {exc.reason}") from None


class NedConfig(ConfigSection, frozen=True, kw_only=True):
    """Where the tank frame W sits in the EKF's local NED frame."""

    heading_deg: Annotated[float, msgspec.Meta(ge=-360.0, le=360.0)] = 0.0  # W's x, cw from north
    origin_ned_m: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def tank_to_ned(self) -> TankToNed:
        return TankToNed(math.radians(self.heading_deg), np.array(self.origin_ned_m))


class OriginConfig(ConfigSection, frozen=True, kw_only=True):
    """The EKF origin (SET_GPS_GLOBAL_ORIGIN, once per boot); needed for GPS_INPUT."""

    lat_deg: Annotated[float, msgspec.Meta(ge=-90.0, le=90.0)]
    lon_deg: Annotated[float, msgspec.Meta(ge=-180.0, le=180.0)]
    alt_m: float = 0.0


class DepthConfig(ConfigSection, frozen=True, kw_only=True):
    """How pressure becomes depth; None means "read it from the vehicle"."""

    surface_pressure_pa: Annotated[float, msgspec.Meta(gt=50_000.0, lt=150_000.0)] | None = None
    water_density_kg_m3: Annotated[float, msgspec.Meta(gt=900.0, lt=1100.0)] | None = None
    sigma_m: Annotated[float, msgspec.Meta(gt=0.0, le=1.0)] = 0.01


class GateConfig(ConfigSection, frozen=True, kw_only=True):
    """The safety gate (capsd.services.mav_bridge.gate)."""

    max_age_s: Annotated[float, msgspec.Meta(gt=0.0, le=0.5)] = 0.3
    max_sigma_m: Annotated[float, msgspec.Meta(gt=0.0, le=5.0)] = 0.5
    # EKF3 drops samples measured closer than 20 ms: more than 50 Hz is waste (by stamps).
    max_rate_hz: Annotated[float, msgspec.Meta(gt=0.0, le=50.0)] = 50.0


class EkfCheckConfig(ConfigSection, frozen=True, kw_only=True):
    """When ArduSub's EKF and our positions disagree (a wrong heading or origin)."""

    # EKF_STATUS_REPORT's horizontal position test ratio: ~0.1 in good flight (SITL p95),
    # 5.8 with the tank frame 90 deg off; above this for `sustained_s` while estimates go out
    # is an episode: the pilot is told once, Health says why.
    max_pos_ratio: Annotated[float, msgspec.Meta(gt=0.0, le=100.0)] = 1.0
    sustained_s: Annotated[float, msgspec.Meta(gt=0.0, le=60.0)] = 3.0


class RatesConfig(ConfigSection, frozen=True, kw_only=True):
    """Message rates requested with MAV_CMD_SET_MESSAGE_INTERVAL."""

    attitude_hz: Annotated[float, msgspec.Meta(gt=0.0, le=100.0)] = 20.0
    pressure_hz: Annotated[float, msgspec.Meta(gt=0.0, le=100.0)] = 20.0
    ekf_status_hz: Annotated[float, msgspec.Meta(gt=0.0, le=10.0)] = 2.0
    system_time_hz: Annotated[float, msgspec.Meta(gt=0.0, le=10.0)] = 1.0
    sys_status_hz: Annotated[float, msgspec.Meta(gt=0.0, le=10.0)] = 1.0


class SonarTiltBridgeConfig(ConfigSection, frozen=True, kw_only=True):
    """Role asv: the sonar's tilt servo on the autopilot's mount (ArduPilot MNT1_*, a servo).

    The follower's angle goes out as MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW (in GUIDED only, with
    its goto), and each GIMBAL_DEVICE_ATTITUDE_STATUS comes back as a `sonar/tilt` payload.
    """

    # The mount pitch the autopilot reports (MAVLink's: up +, degrees) with the sonar at the
    # servo's zero: where the sonar mount's `pitch_deg` was measured. The tilt is the angle
    # down from there.
    zero_pitch_deg: Annotated[float, msgspec.Meta(ge=-180.0, le=180.0)]
    # servo: the mount has a pan servo too (the sonar mount's `pan`; ArduPilot's mount yaw):
    # the follower's pan goes out as the yaw (the vehicle's frame), the reported yaw comes back
    # as `pan_rad`. none: the yaw is sent ahead (0) and the pan reported as 0.
    pan: Literal["none", "servo"] = "none"
    status_hz: Annotated[float, msgspec.Meta(gt=0.0, le=100.0)] = 20.0
    # A new angle goes out when it moved this far from the last sent, or after resend_s.
    deadband_deg: Annotated[float, msgspec.Meta(ge=0.0, le=10.0)] = 0.25
    resend_s: Annotated[float, msgspec.Meta(gt=0.0, le=60.0)] = 1.0


Role = Literal["rov", "asv"]
_AUTOPILOT: dict[Role, Autopilot] = {"rov": "ardusub", "asv": "ardurover"}
# The autopilot's own position hold, which a "hold" command switches to (from GUIDED only).
_HOLD_MODE: dict[Role, str] = {"rov": "POSHOLD", "asv": "LOITER"}
# What a hold becomes when the autopilot refuses its position hold (no position left: the fixes
# stopped before the hold came): ArduSub holds depth and attitude, ArduRover stops.
_HOLD_FALLBACK: dict[Role, str] = {"rov": "ALT_HOLD", "asv": "HOLD"}
# A refusal (COMMAND_ACK) this long after our position hold is taken as its answer.
_HOLD_ANSWER_S = 3.0


class Config(ServiceConfig, frozen=True, kw_only=True):
    """MAVLink bridge configuration."""

    vehicle: str = "rov"
    # rov: ArduSub fed the locator's fixes; asv: ArduRover fed this vehicle's own pose.
    role: Role = "rov"
    locator_vehicle: str = "topside"
    mavlink: MavlinkConfig = MavlinkConfig()
    ned: NedConfig = NedConfig()
    output: Literal["vision_position_estimate", "gps_input", "off"] = "vision_position_estimate"
    gate: GateConfig = GateConfig()
    ekf_origin: OriginConfig | None = None
    depth: DepthConfig = DepthConfig()
    rates: RatesConfig = RatesConfig()
    ekf_check: EkfCheckConfig = EkfCheckConfig()
    # required: only fixes tagged with the site's fix key reach the autopilot, whatever router
    # carried them (BlueOS's has no access control); off: a bench without keys, never a site.
    fix_auth: Literal["required", "off"] = "required"
    fix_key: str | None = None  # the site's fix key file (make-site-certs.sh writes fix.key)
    # Estimates outside the tank (plus its margin) are refused; without it only absurd ones.
    tank: TankBounds | None = None
    attitude_sigma_deg: Annotated[float, msgspec.Meta(gt=0.0, le=90.0)] = 3.0
    # After this long without a sendable estimate, the pilot is told (STATUSTEXT).
    outage_warning_s: Annotated[float, msgspec.Meta(gt=0.0, le=60.0)] = 1.0
    statustext_interval_s: Annotated[float, msgspec.Meta(ge=1.0, le=600.0)] = 5.0
    # accept: signed mission commands (capsd mission run) may switch ArduSub to GUIDED, move
    # its target and hold; refuse (the default): they are counted and dropped.
    mission_commands: Literal["accept", "refuse"] = "refuse"
    # Targets closer than this to a wall, the floor or the surface are refused (the geofence).
    geofence_clearance_m: Annotated[float, msgspec.Meta(ge=0.0, le=100.0)] = 0.5
    # Role asv: within this of a goto's position (by the last pose sent) the heading goes
    # alone, as ArduRover's GUIDED ignores the yaw of a position target; but only once that
    # position went out as the autopilot's target (within a third of this): a station moved
    # a little is driven to, not turned at where the old one was.
    heading_only_within_m: Annotated[float, msgspec.Meta(ge=0.0, le=10.0)] = 0.3
    # A command older than this on arrival is refused (a stalled link replays nothing).
    max_command_age_s: Annotated[float, msgspec.Meta(gt=0.0, le=10.0)] = 1.0
    # Role asv: the sonar on a tilt servo the autopilot drives (None: the sonar is fixed).
    sonar_tilt: SonarTiltBridgeConfig | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        try:
            check_name("vehicle", self.locator_vehicle)
        except ValueError as exc:
            raise ValueError(f"`locator_vehicle`: {exc}") from None
        if self.output == "gps_input" and self.ekf_origin is None:
            raise ValueError("`ekf_origin`: GPS_INPUT output needs the EKF origin (lat/lon)")
        if self.role == "asv" and self.ekf_origin is None:
            raise ValueError(
                "`ekf_origin`: role asv needs the EKF origin (lat/lon): ArduRover's GUIDED "
                "ignores every target until its EKF has one"
            )
        if self.mission_commands == "accept" and self.tank is None:
            raise ValueError("`mission_commands: accept` needs `tank`: the geofence for targets")
        if self.sonar_tilt is not None and self.role != "asv":
            raise ValueError("`sonar_tilt`: the sonar's servo is on the ASV (role asv)")
        if self.role == "asv" and self.output == "gps_input":
            raise ValueError("`output`: the ASV's bridge sends VISION_POSITION_ESTIMATE (its pose)")


class Bridge:
    """Link state, telemetry conversion and the estimate path; MAVLink I/O under one lock."""

    def __init__(self, config: Config, runner: ServiceRunner):
        self.config = config
        self.runner = runner
        self.ned = config.ned.tank_to_ned()
        self.autopilot: Autopilot = _AUTOPILOT[config.role]
        self.gate = SafetyGate(
            GateSettings(config.gate.max_age_s, config.gate.max_sigma_m, config.gate.max_rate_hz),
            tank=config.tank,
        )
        # Fixes wait here for the sender: the newest only, so a flood cannot age good ones.
        self.fixes: Mailbox[tuple[Estimate, int]] = Mailbox()
        # Mission commands: the newest only (a hold replaces a pending target and vice versa).
        self.commands: Mailbox[VehicleCommand] = Mailbox()
        self.command_stream: StreamCounter | None = None
        self.mode: str | None = None
        self._hold_sent_at = -math.inf  # when our last position hold went out
        self.fix_stream: StreamCounter | None = None
        self._unauthenticated_seen = 0
        self.link = MavLink(
            config.mavlink.connect,
            system_id=config.mavlink.system_id,
            component_id=config.mavlink.component_id,
        )
        self.lock = threading.Lock()
        self._last_counts: dict[str, int] = {}
        self.clock = BootClock()
        self.counts: Counter[str] = Counter()
        self.attitude: Attitude | None = None
        self.ekf_flags = 0
        self.surface_pressure_pa = config.depth.surface_pressure_pa
        self.density = config.depth.water_density_kg_m3
        self._last_vehicle_heartbeat = 0.0
        self._last_heartbeat_sent = 0.0
        self._last_open_attempt = -math.inf
        self._open_failures = 0
        self._last_open_warning = -math.inf
        self._link_opened = 0.0
        self._last_depth = -math.inf
        self._last_attitude = -math.inf
        self._missing: str | None = None
        self._last_reference_read = 0.0
        self._above_surface_since: float | None = None
        self._reference_suspect: float | None = None
        self.ekf_pos_ratio = 0.0
        self._ekf_high_since: float | None = None
        self._ekf_low_since: float | None = None
        self._ekf_disagrees = False
        self._configured_boot = 0
        self.origin_set = False  # the autopilot reported an EKF origin (this boot)
        self._origin_sent = -math.inf
        self._last_param_request = 0.0
        self._last_sent_mono: float | None = None
        self.uptake = EstimateUptake()
        self._ignored_told = False
        self._asv_at: Array | None = None  # role asv: where the last pose sent put the ASV (W)
        # Role asv: the last position target sent (W), None once the autopilot left GUIDED or
        # the link was lost (its target is gone with it).
        self._asv_target_xy: Array | None = None
        # The drive direction ArduRover was last told (None: not since it took GUIDED, whose
        # entry sets forward, or since the link came back).
        self._asv_direction: DriveDirection | None = None
        # Role asv with a tilt servo: the last pitch and yaw sent (deg, MAVLink's) and when.
        self._tilt_sent: tuple[float, float, float] | None = None
        self._outage_reasons: Counter[str] = Counter()
        self._announced: str | None = None
        self._last_statustext: dict[str, float] = {}
        rov = config.vehicle
        self.depth_pub: Publisher[RovDepth] | None = None
        self.attitude_pub: Publisher[RovAttitude] | None = None
        if config.role == "rov":
            self.depth_pub = runner.publisher(topics.ROV_DEPTH, vehicle=rov)
            self.attitude_pub = runner.publisher(topics.ROV_ATTITUDE, vehicle=rov)
        self.tilt_pub: Publisher[SonarTilt] | None = None
        if config.sonar_tilt is not None:
            self.tilt_pub = runner.publisher(topics.SONAR_TILT, vehicle=rov)
        status = topics.ROV_STATUS if config.role == "rov" else topics.ASV_AUTOPILOT
        self.status_pub: Publisher[AutopilotStatus] = runner.publisher(status, vehicle=rov)
        # Fix arrival to the estimate leaving the socket; and the ping (the fix's stamp) to it.
        self.stage_latency = runner.latency("bridge")
        self.end_to_end_latency = runner.latency("end to end")

    # ------------------------------------------------------------------ link upkeep

    def step(self) -> None:
        """One pass of the main loop: keep the link, drain messages, heartbeat, announce."""
        now = time.monotonic()
        with self.lock:
            if not self.link.is_open:
                # Back-off: 0.25 s after a loss, doubling to 2 s while the autopilot is away.
                delay = min(_REOPEN_MAX_S, _REOPEN_FIRST_S * 2.0**self._open_failures)
                if now - self._last_open_attempt < delay:
                    return
                self._last_open_attempt = now
                try:
                    self.link.open()
                    self._last_vehicle_heartbeat = now
                    self._link_opened = now
                    self._open_failures = 0
                    logger.info(
                        "MAVLink link open", extra={"fields": {"connect": self.link.connection}}
                    )
                except OSError as exc:
                    self.counts["link_open_failed"] += 1
                    self._open_failures += 1
                    self.runner.set_state("degraded", f"no MAVLink link: {exc}")
                    if now - self._last_open_warning >= 10.0:
                        self._last_open_warning = now
                        logger.warning(
                            "no MAVLink link yet",
                            extra={"fields": {"error": str(exc), "failed": self._open_failures}},
                        )
                    return
            try:
                for _ in range(200):
                    received = self.link.recv(timeout_s=0.0)
                    if received is None:
                        break
                    self._handle(received.message, received.component_id)
                if now - self._last_heartbeat_sent >= 1.0:
                    self._last_heartbeat_sent = now
                    self.link.send_heartbeat_onboard()
            except OSError as exc:
                self._drop_link(f"MAVLink I/O error: {exc}")
                return
            if now - self._last_vehicle_heartbeat > self.config.mavlink.link_timeout_s:
                self._drop_link("no HEARTBEAT from the autopilot")
                return
            self._configure_vehicle(now)
            self._check_inputs(now)
            try:
                self._act_on_commands()
            except OSError as exc:
                self._drop_link(f"MAVLink I/O error: {exc}")
                return
        self._announce(now)

    def _observe_ekf(self, ratio: float, now: float) -> None:
        """Track the EKF's position test ratio: a sustained high one while we send is wrong."""
        c = self.config.ekf_check
        sending = self._last_sent_mono is not None and now - self._last_sent_mono < 1.0
        high = ratio > c.max_pos_ratio and sending
        self.ekf_pos_ratio = ratio
        if high:
            self._ekf_high_since = self._ekf_high_since or now
            self._ekf_low_since = None
        else:
            self._ekf_low_since = self._ekf_low_since or now
            self._ekf_high_since = None
        if (
            not self._ekf_disagrees
            and self._ekf_high_since is not None
            and now - self._ekf_high_since >= c.sustained_s
        ):
            self._ekf_disagrees = True
            self.counts["ekf_disagreement_episodes"] += 1
            heading = self.config.ned.heading_deg
            logger.warning(
                "the EKF rejects our positions",
                extra={"fields": {"pos_ratio": round(ratio, 2), "heading_deg": heading}},
            )
            # Once per episode (the caller holds the link's lock).
            try:
                self.link.send_statustext(
                    "warning", f"CAP-SD: EKF rejects fixes: heading {heading:g}/origin?"
                )
                self.counts["statustext_ekf"] += 1
            except OSError:
                pass
        elif (
            self._ekf_disagrees
            and self._ekf_low_since is not None
            and now - self._ekf_low_since >= c.sustained_s
        ):
            self._ekf_disagrees = False
            logger.info("the EKF accepts our positions again")

    def _watch_reference(self, depth_m: float, now: float) -> None:
        """Depth above the surface for a while: the reference was taken under water."""
        if depth_m >= _ABOVE_SURFACE_M:
            self._above_surface_since = None
            self._reference_suspect = (
                None if depth_m > _ABOVE_SURFACE_M / 2 else (self._reference_suspect)
            )
            return
        self._above_surface_since = self._above_surface_since or now
        if self._reference_suspect is None and now - self._above_surface_since >= 2.0:
            self._reference_suspect = depth_m
            self.counts["surface_reference_suspect"] += 1
            logger.warning(
                "depth reads above the surface: the autopilot booted under water",
                extra={"fields": {"depth_m": round(depth_m, 3)}},
            )
            with contextlib.suppress(OSError):  # the link's loss is handled where it is read
                self.link.send_statustext(
                    "warning", f"CAP-SD: depth {depth_m:+.2f} m at surface? zero-depth"
                )

    def _check_inputs(self, now: float) -> None:
        """Health says what is wrong: depth or attitude missing, the EKF disagreeing."""
        if self.clock.boots == 0 or now - self._link_opened < _INPUT_GRACE_S:
            return
        inputs = [("attitude", self._last_attitude)]
        if self.config.role == "rov":
            inputs.insert(0, ("depth", self._last_depth))
        missing = [name for name, last in inputs if now - last > _INPUT_GRACE_S]
        reasons = []
        if missing:
            reasons.append("no " + " and no ".join(missing) + " from the autopilot")
        if self._reference_suspect is not None:
            reasons.append(
                f"depth reads {self._reference_suspect:+.2f} m, above the surface: the surface "
                "pressure was taken under water (at the surface: capsd mav zero-depth --apply)"
            )
        ignored = self.uptake.ignored(now)
        if ignored:
            reasons.append(
                f"the autopilot does not use our estimates (SYS_STATUS external position "
                f"{self.uptake.state}): VISO_TYPE 0, or set since its last boot (capsd mav check)"
            )
            if not self._ignored_told:  # the pilot hears it once per episode
                self.counts["estimates_ignored_episodes"] += 1
                with contextlib.suppress(OSError):
                    self.link.send_statustext("warning", "CAP-SD: autopilot ignores fixes: reboot?")
        self._ignored_told = ignored
        if self._ekf_disagrees:
            reasons.append(
                f"the EKF rejects our positions (test ratio {self.ekf_pos_ratio:.1f}): "
                f"heading ({self.config.ned.heading_deg:g} deg) or origin wrong?"
            )
        why = "; ".join(reasons) or None
        if why is not None:
            if self._missing != why:
                logger.warning("autopilot check", extra={"fields": {"reason": why}})
            self.runner.set_state("degraded", why)
        elif self._missing is not None:
            self.runner.set_state("ok")
        self._missing = why

    def _drop_link(self, why: str) -> None:
        """Close the link and forget everything it told us (published as unknown)."""
        self.counts["link_lost"] += 1
        self.runner.set_state("degraded", why)
        logger.warning("MAVLink link lost, reopening", extra={"fields": {"reason": why}})
        self.link.close()
        self._last_open_attempt = time.monotonic()
        self._open_failures = 0
        # An old attitude must not go out with a new position; the surface pressure and
        # density may change with a reboot: read again.
        self.attitude = None
        self.mode = None  # a mission's hold must never act on a mode from before the loss
        self._asv_target_xy = None
        self._asv_direction = None
        self.ekf_flags = 0
        self.uptake.reset()
        self.surface_pressure_pa = self.config.depth.surface_pressure_pa
        self.density = self.config.depth.water_density_kg_m3
        self._last_depth = self._last_attitude = -math.inf
        self.status_pub.put(
            AutopilotStatus(
                stamp_ns=time.time_ns(),
                seq=self.status_pub.next_seq(),
                armed=False,
                mode="unknown",
                link="lost",
            )
        )

    def _configure_vehicle(self, now: float) -> None:
        """Once per autopilot boot: message rates, EKF origin; depth references until known."""
        if self.clock.boots == 0:
            return
        cfg, target = self.config, self.config.mavlink.target_system
        if self._configured_boot != self.clock.boots:
            self._configured_boot = self.clock.boots
            rates = [
                ("ATTITUDE", cfg.rates.attitude_hz),
                ("SCALED_PRESSURE2", cfg.rates.pressure_hz),
                ("EKF_STATUS_REPORT", cfg.rates.ekf_status_hz),
                ("SYSTEM_TIME", cfg.rates.system_time_hz),
                ("SYS_STATUS", cfg.rates.sys_status_hz),
            ]
            if cfg.role == "asv":  # no depth on the surface vehicle
                rates = [(name, hz) for name, hz in rates if name != "SCALED_PRESSURE2"]
            if cfg.sonar_tilt is not None:
                rates.append(("GIMBAL_DEVICE_ATTITUDE_STATUS", cfg.sonar_tilt.status_hz))
            for name, hz in rates:
                self.link.send_set_message_interval(
                    target_system=target, message_id=message_id(name), rate_hz=hz
                )
            self.origin_set = False
            self.runner.set_state("ok")
            logger.info("autopilot configured", extra={"fields": {"boot": self.clock.boots}})
        # ArduPilot drops an origin sent before its EKF has started (and ArduRover's GUIDED then
        # ignores every target): send it until the autopilot reports one.
        if cfg.ekf_origin is not None and not self.origin_set and now - self._origin_sent >= 2.0:
            self._origin_sent = now
            o = cfg.ekf_origin
            self.link.send_set_gps_global_origin(
                target_system=target,
                lat_e7=round(o.lat_deg * 1e7),
                lon_e7=round(o.lon_deg * 1e7),
                alt_mm=round(o.alt_m * 1000),
            )
            self.link.send_request_message(
                target_system=target, message_id=message_id("GPS_GLOBAL_ORIGIN")
            )
            self.counts["origin_sent"] += 1
        if cfg.role == "asv":
            return
        missing = [
            name
            for name, value in (
                ("BARO2_GND_PRESS", self.surface_pressure_pa),
                ("BARO_SPEC_GRAV", self.density),
            )
            if value is None
        ]
        # The surface reference is read again every 10 s: `capsd mav zero-depth --apply`
        # (or a ground station's baro calibration) changes it without a reboot.
        if cfg.depth.surface_pressure_pa is None and now - self._last_reference_read > 10.0:
            self._last_reference_read = now
            missing = sorted({*missing, "BARO2_GND_PRESS"})
        if missing and now - self._last_param_request > 2.0:
            self._last_param_request = now
            for name in missing:
                self.link.send_param_request_read(target_system=target, name=name)

    # ------------------------------------------------------------------ vehicle to bus

    def _handle(self, message: object, component_id: int) -> None:
        if component_id != _AUTOPILOT_COMPONENT:
            return
        arrival_ns = time.time_ns()
        if isinstance(message, Heartbeat):
            self._last_vehicle_heartbeat = time.monotonic()
            self.status_pub.put(
                AutopilotStatus(
                    stamp_ns=arrival_ns,
                    seq=self.status_pub.next_seq(),
                    armed=message.armed,
                    mode=mode_name(message.custom_mode, self.autopilot),
                    ekf_flags=self.ekf_flags,
                )
            )
            self.mode = mode_name(message.custom_mode, self.autopilot)
            if self.mode != "GUIDED":
                self._asv_target_xy = None
                self._asv_direction = None
        elif isinstance(message, CommandAck) and message.command == MAV_CMD_DO_SET_MODE:
            self._on_mode_answer(message.result)
        elif isinstance(message, Attitude):
            if not self._observe(message.time_boot_ms, arrival_ns):
                return
            self.attitude = message
            self._last_attitude = time.monotonic()
            if self.attitude_pub is None:
                return
            r_w_r = self.ned.attitude_to_tank(message.roll, message.pitch, message.yaw)
            q = matrix_to_quat(r_w_r)
            rates = self.ned.body_rates_to_flu(
                message.rollspeed, message.pitchspeed, message.yawspeed
            )
            self.attitude_pub.put(
                RovAttitude(
                    stamp_ns=self.clock.to_unix_ns(message.time_boot_ms),
                    seq=self.attitude_pub.next_seq(),
                    orientation_xyzw=(float(q[0]), float(q[1]), float(q[2]), float(q[3])),
                    angular_velocity_rad_s=rates,
                )
            )
        elif (
            isinstance(message, ScaledPressure)
            and message.instance == 2
            and self.depth_pub is not None
        ):
            if not self._observe(message.time_boot_ms, arrival_ns):
                return
            self._publish_depth(message)
        elif isinstance(message, SystemTime):
            self._observe(message.time_boot_ms, arrival_ns)
        elif isinstance(message, GimbalAttitude) and self.tilt_pub is not None:
            if not self._observe(message.time_boot_ms, arrival_ns):
                return
            self._publish_tilt(message)
        elif isinstance(message, OriginReport):
            if not self.origin_set:
                self.origin_set = True
                logger.info(
                    "EKF origin set",
                    extra={"fields": {"lat_e7": message.lat_e7, "lon_e7": message.lon_e7}},
                )
        elif isinstance(message, SysStatus):
            self.uptake.status(
                message.sensor(MAV_SYS_STATUS_SENSOR_VISION_POSITION), time.monotonic()
            )
        elif isinstance(message, EkfStatus):
            self.ekf_flags = message.flags
            self._observe_ekf(message.pos_horiz_variance, time.monotonic())
        elif isinstance(message, ParamValue):
            if message.name == "BARO2_GND_PRESS" and self.config.depth.surface_pressure_pa is None:
                if (
                    self.surface_pressure_pa is not None
                    and abs(message.value - self.surface_pressure_pa) > 1.0
                ):
                    logger.info(
                        "surface pressure reference changed",
                        extra={
                            "fields": {"from_pa": self.surface_pressure_pa, "to_pa": message.value}
                        },
                    )
                self.surface_pressure_pa = message.value
            elif message.name == "BARO_SPEC_GRAV" and self.density is None:
                self.density = 1000.0 * message.value

    def _observe(self, time_boot_ms: int, arrival_ns: int) -> bool:
        """Feed the boot clock; a message from before a detected reboot is dropped."""
        if self.clock.observe(time_boot_ms, arrival_ns):
            self.counts["vehicle_reboots"] += 1
            logger.warning("autopilot rebooted", extra={"fields": {"boots": self.clock.boots}})
        return self.clock.ready

    def _publish_tilt(self, message: GimbalAttitude) -> None:
        """The mount's reported pitch as the servo's tilt on the hull (down + from its zero).

        ArduPilot's mount reports (and holds) its pitch against the horizon (the PITCH_LOCK
        flag, always set by its mount library): on the hull that is the reported pitch less
        the vehicle's own (the newest ATTITUDE; a forward-looking mount). A mount reporting
        against the vehicle is taken as it is.
        """
        assert self.tilt_pub is not None
        assert self.config.sonar_tilt is not None
        pitch_on_hull = message.pitch_rad
        if message.horizon_relative:
            if self.attitude is None:
                self.counts["tilt_waiting_attitude"] += 1
                return
            pitch_on_hull -= self.attitude.pitch
        zero = math.radians(self.config.sonar_tilt.zero_pitch_deg)
        tilt = zero - pitch_on_hull
        if not -math.pi / 2 <= tilt <= math.pi / 2:
            self.counts["tilt_refused_out_of_range"] += 1
            return
        pan = 0.0
        if self.config.sonar_tilt.pan == "servo":
            if message.yaw_rad is None:
                # Against north: the pan on the hull would need the heading at that instant.
                self.counts["tilt_refused_yaw_earth_frame"] += 1
                return
            pan = -message.yaw_rad  # MAVLink's yaw is right +, the pan left +
        self.counts["tilt_reports"] += 1
        self.tilt_pub.put(
            SonarTilt(
                stamp_ns=self.clock.to_unix_ns(message.time_boot_ms),
                seq=self.tilt_pub.next_seq(),
                tilt_rad=tilt,
                pan_rad=pan,
            )
        )

    def _send_tilt(self, tilt_rad: float, pan_rad: float | None) -> None:
        """The follower's angles to the mount (the caller holds the lock; GUIDED only).

        ArduPilot holds a mount's pitch against the horizon: the follower's angle is the one
        for a level ASV, so it is the horizon's too, and the servo keeps it through the waves.
        The pan (a mount with one; None: ahead) goes out as the yaw in the vehicle's frame.
        """
        servo = self.config.sonar_tilt
        if servo is None:
            self.counts["commands_tilt_no_servo"] += 1
            return
        pitch_deg = servo.zero_pitch_deg - math.degrees(tilt_rad)
        yaw_deg = 0.0
        if servo.pan == "servo" and pan_rad is not None:
            yaw_deg = -math.degrees(pan_rad)
        now = time.monotonic()
        if self._tilt_sent is not None:
            last_pitch, last_yaw, at = self._tilt_sent
            moved = max(abs(pitch_deg - last_pitch), abs(yaw_deg - last_yaw))
            if moved < servo.deadband_deg and now - at < servo.resend_s:
                return
        self.link.send_gimbal_pitch(
            target_system=self.config.mavlink.target_system, pitch_deg=pitch_deg, yaw_deg=yaw_deg
        )
        self._tilt_sent = (pitch_deg, yaw_deg, now)
        self.counts["commands_sent_tilt"] += 1

    def _publish_depth(self, message: ScaledPressure) -> None:
        assert self.depth_pub is not None  # the ROV's bridge only
        if self.surface_pressure_pa is None or self.density is None:
            self.counts["depth_waiting_reference"] += 1
            return
        pressure_pa = message.press_abs_hpa * 100.0
        if not math.isfinite(pressure_pa) or pressure_pa <= 0.0:
            self.counts["depth_bad_pressure"] += 1
            return
        depth = (pressure_pa - self.surface_pressure_pa) / (self.density * G)
        now = time.monotonic()
        self._last_depth = now
        self._watch_reference(depth, now)
        self.depth_pub.put(
            RovDepth(
                stamp_ns=self.clock.to_unix_ns(message.time_boot_ms),
                seq=self.depth_pub.next_seq(),
                depth_m=depth,
                pressure_pa=pressure_pa,
                temperature_c=message.temperature_c,
                sigma_m=self.config.depth.sigma_m,
            )
        )

    # ------------------------------------------------------------------ bus to vehicle

    def on_fix(self, fix: Estimate) -> None:
        """Take a fix (or the ASV's pose) off the bus (Zenoh's thread); refuse a future one."""
        if self.config.output == "off":
            return
        received_ns = self.runner.received_ns()
        with self.lock:
            if self.gate.from_future(fix, now_ns=received_ns):
                self._outage_reasons["from_future"] += 1
                return
        self.fixes.put((fix, received_ns))

    def on_command(self, command: VehicleCommand) -> None:
        """Take a mission command off the bus (Zenoh's thread), refused or kept for `step`.

        Refusals are counted at arrival; an acceptable command waits (the newest only).
        """
        if self.config.mission_commands == "refuse":
            refused: str | None = "disabled"
        elif command.kind == "engage" and self.config.role == "asv":
            refused = "engage_is_the_pilots"  # the ASV's pilot puts it in GUIDED, never we
        else:
            refused = self._refusal(command, self.runner.received_ns())
        if refused is None:
            self.commands.put(command)
            return
        with self.lock:
            self.counts[f"commands_refused_{refused}"] += 1
        logger.warning(
            "mission command refused",
            extra={"fields": {"kind": command.kind, "mission": command.mission, "why": refused}},
        )

    def _on_mode_answer(self, result: int) -> None:
        """A refused position hold (no position left) becomes the autopilot's plain hold.

        Left in GUIDED, the vehicle would fly on to its last target on a coasting estimate.
        """
        if result == MAV_RESULT_ACCEPTED or time.monotonic() - self._hold_sent_at > _HOLD_ANSWER_S:
            return
        self._hold_sent_at = -math.inf  # one fallback per hold
        fallback = _HOLD_FALLBACK[self.config.role]
        self.link.send_set_mode(
            target_system=self.config.mavlink.target_system, mode=fallback, autopilot=self.autopilot
        )
        self.mode = fallback
        self.counts[f"commands_sent_{fallback.lower()}"] += 1
        logger.warning(
            f"mission: {_HOLD_MODE[self.config.role]} refused, {fallback} instead",
            extra={"fields": {"why": "the autopilot has no position to hold (fixes stopped)"}},
        )

    def _act_on_commands(self) -> None:
        """The newest mission command to MAVLink (the caller holds the lock, the link is open)."""
        command = self.commands.take(0.0)
        if command is None:
            return
        fields = {"kind": command.kind, "waypoint": command.waypoint, "mission": command.mission}
        target = self.config.mavlink.target_system
        if command.kind == "hold":
            hold = _HOLD_MODE[self.config.role]
            # The pilot's mode is never overridden. Already holding, the hold is sent again:
            # a HEARTBEAT sent before the autopilot took our GUIDED can arrive after it and
            # say the old hold, and a hold then dropped would leave the vehicle in GUIDED.
            if self.mode not in ("GUIDED", hold):
                self.counts["commands_hold_not_guided"] += 1
                return
            self.link.send_set_mode(target_system=target, mode=hold, autopilot=self.autopilot)
            self.mode = hold  # ours until a HEARTBEAT says otherwise (1 Hz)
            self._hold_sent_at = time.monotonic()
            self.counts[f"commands_sent_{hold.lower()}"] += 1
            logger.info(f"mission: {hold}", extra={"fields": {**fields, "why": command.reason}})
            return
        if command.kind == "goto" and self.mode != "GUIDED":
            self.counts["commands_goto_not_guided"] += 1
            return
        if command.kind == "engage":
            # Always asked, whatever the last HEARTBEAT said: at 1 Hz it can be older than the
            # hold this bridge sent since (ArduSub SITL: a resume 2 s after a pause found
            # "GUIDED", sent no mode, and the mission saw POSHOLD and ended). An autopilot
            # already in GUIDED takes it as it is.
            self.link.send_set_mode(target_system=target, mode="GUIDED")
            self._hold_sent_at = -math.inf  # a refusal now answers this, not a hold
            # Ours until a HEARTBEAT says otherwise: a hold right after an engage must not be
            # taken for a pilot's mode (the HEARTBEAT comes at 1 Hz).
            self.mode = "GUIDED"
            self.counts["commands_sent_guided"] += 1
            logger.info("mission: GUIDED", extra={"fields": {**fields, "why": command.reason}})
        assert command.position_m is not None  # the payload refuses engage/goto without one
        ned = self.ned.position(np.array(command.position_m))
        yaw_ned = None
        if command.heading_rad is not None:
            heading = euler_zyx_to_matrix(command.heading_rad, 0.0, 0.0)
            yaw_ned = self.ned.attitude_to_ned(heading)[2]
        goal_xy = np.array(command.position_m[:2])
        radius = self.config.heading_only_within_m
        arrived = (
            self._asv_at is not None
            and float(np.linalg.norm(self._asv_at[:2] - goal_xy)) <= radius
            and self._asv_target_xy is not None
            and float(np.linalg.norm(self._asv_target_xy - goal_xy)) <= radius / 3.0
        )
        if self.config.role == "asv" and yaw_ned is not None and arrived:
            # ArduRover's GUIDED ignores a position target's yaw: at the station, turn to it.
            self.link.send_heading_target(
                target_system=target, time_boot_ms=self.clock.last_boot_ms(), yaw_rad=yaw_ned
            )
            self.counts["commands_sent_heading"] += 1
        else:
            if self.config.role == "asv" and command.direction != self._asv_direction:
                # Before the target it is for: ArduRover drives its stern to it, or its bow.
                self.link.send_set_reverse(target_system=target, direction=command.direction)
                self.counts[f"commands_sent_{command.direction}"] += 1
                self._asv_direction = command.direction
            self.link.send_position_target(
                target_system=target,
                time_boot_ms=self.clock.last_boot_ms(),
                ned_m=(float(ned[0]), float(ned[1]), float(ned[2])),
                yaw_rad=yaw_ned,
            )
            self.counts["commands_sent_target"] += 1
            self._asv_target_xy = goal_xy
        if self.config.role == "asv" and command.sonar_tilt_rad is not None:
            self._send_tilt(command.sonar_tilt_rad, command.sonar_pan_rad)
        # Every command is logged; the mission's twice-a-second repeats at debug level.
        logger.log(
            logging.DEBUG if command.reason == "repeat" else logging.INFO,
            "mission: target",
            extra={"fields": {**fields, "tank_m": list(command.position_m)}},
        )

    def _refusal(self, command: VehicleCommand, received_ns: int) -> str | None:
        """Why a command must not reach the autopilot (None: it may)."""
        if received_ns - command.stamp_ns > self.config.max_command_age_s * 1e9:
            return "stale"
        if command.stamp_ns - received_ns > self.config.max_command_age_s * 1e9:
            return "from_future"
        if command.position_m is not None:
            tank = self.config.tank
            assert tank is not None  # Config requires it with mission_commands: accept
            x, y, z = command.position_m
            if self.config.role == "asv":
                z = -tank.depth_m / 2.0  # a surface vehicle: only the walls fence it
            if not tank.clear_of_walls((x, y, z), self.config.geofence_clearance_m):
                return "outside_geofence"
        return None

    def send_loop(self) -> None:
        """The sender thread: the newest estimate through the gate (again) to the autopilot."""
        while not self.runner.stop_event.is_set():
            item = self.fixes.take(0.1)
            if item is not None:
                self._gate_and_send(*item)

    def _gate_and_send(self, fix: Estimate, received_ns: int) -> None:
        with self.lock:
            attitude = self.attitude
            if (attitude is None and self.config.role == "rov") or not self.link.is_open:
                self.counts["no_link_or_attitude"] += 1
                self._outage_reasons["no_link_or_attitude"] += 1
                return
            decision = self.gate.check(fix, now_ns=time.time_ns())
            if not isinstance(decision, Passed):
                self._outage_reasons[decision] += 1
                return
            try:
                self._send(decision, attitude)
            except OSError as exc:
                self.counts["send_failed"] += 1
                logger.warning("estimate not sent", extra={"fields": {"error": str(exc)}})
                return
            sent_ns = time.time_ns()
            self.stage_latency.record_ns(sent_ns - received_ns)
            self.end_to_end_latency.record_ns(sent_ns - fix.stamp_ns)
            self._last_sent_mono = time.monotonic()
            self.uptake.sent(self._last_sent_mono)
            self._asv_at = decision.position_w if self.config.role == "asv" else None
            self._outage_reasons.clear()

    def _send(self, passed: Passed, attitude: Attitude | None) -> None:
        p = self.ned.position(passed.position_w)
        if passed.orientation_xyzw is not None:  # the ASV's pose carries its own attitude
            roll, pitch, yaw = self.ned.attitude_to_ned(
                quat_to_matrix(np.array(passed.orientation_xyzw))
            )
        else:
            assert attitude is not None  # _gate_and_send waits for one in the ROV's role
            roll, pitch, yaw = attitude.roll, attitude.pitch, attitude.yaw
        cov6 = np.zeros((6, 6))
        cov6[:3, :3] = self.ned.covariance(passed.covariance_w)
        att_var = math.radians(self.config.attitude_sigma_deg) ** 2
        cov6[3, 3] = cov6[4, 4] = cov6[5, 5] = att_var
        if self.config.output == "vision_position_estimate":
            self.link.send_vision_position_estimate(
                usec=passed.usec,
                x=float(p[0]),
                y=float(p[1]),
                z=float(p[2]),
                roll=roll,
                pitch=pitch,
                yaw=yaw,
                covariance=upper_triangle(cov6),
                reset_counter=passed.reset_counter,
            )
        else:
            self._send_gps_input(passed, p, cov6)

    def _send_gps_input(self, passed: Passed, p_ned: np.ndarray, cov6: np.ndarray) -> None:
        origin = self.config.ekf_origin
        assert origin is not None  # Config refuses gps_input without it
        earth_radius = 6_378_137.0
        lat = origin.lat_deg + math.degrees(float(p_ned[0]) / earth_radius)
        lon = origin.lon_deg + math.degrees(
            float(p_ned[1]) / (earth_radius * math.cos(math.radians(origin.lat_deg)))
        )
        # GPS time: weeks since 1980-01-06, 18 leap seconds ahead of Unix time.
        gps_s = passed.usec / 1e6 - 315_964_800 + 18
        week = int(gps_s // 604_800)
        self.link.send_gps_input(
            time_usec=passed.usec,
            gps_week=week,
            gps_week_ms=int((gps_s - week * 604_800) * 1000),
            lat_e7=round(lat * 1e7),
            lon_e7=round(lon * 1e7),
            alt_m=origin.alt_m - float(p_ned[2]),
            horiz_accuracy_m=math.sqrt(max(cov6[0, 0], cov6[1, 1])),
            vert_accuracy_m=math.sqrt(cov6[2, 2]),
        )

    # ------------------------------------------------------------------ the pilot

    def _announce(self, now: float) -> None:
        """STATUSTEXT on a change the pilot must know: positioning OK, or lost (and why)."""
        if self.config.output == "off":
            return
        self._warn_unauthenticated()
        if (
            self._last_sent_mono is not None
            and now - self._last_sent_mono <= self.config.outage_warning_s
        ):
            self._say("ok", "info", "CAP-SD: position OK")
        elif self._announced == "ok":
            reason = (
                self._outage_reasons.most_common(1)[0][0] if self._outage_reasons else "no input"
            )
            self._say("lost", "warning", f"CAP-SD: position lost ({reason})")

    def _say(self, state: str, severity: str, text: str) -> None:
        now = time.monotonic()
        if self._announced == state:
            return
        if now - self._last_statustext.get(state, -math.inf) < self.config.statustext_interval_s:
            return
        with self.lock:
            if not self.link.is_open:
                return
            try:
                self.link.send_statustext(severity, text)
            except OSError:
                return
        self._announced = state
        self._last_statustext[state] = now
        self.counts[f"statustext_{state}"] += 1
        logger.info("told the pilot", extra={"fields": {"text": text}})

    def _warn_unauthenticated(self) -> None:
        """Tell the pilot (once a minute at most) that fixes without the site's tag came."""
        stream = self.fix_stream
        if stream is None or stream.unauthenticated == self._unauthenticated_seen:
            return
        self._unauthenticated_seen = stream.unauthenticated
        now = time.monotonic()
        if now - self._last_statustext.get("unauthenticated", -math.inf) < 60.0:
            return
        with self.lock:
            if not self.link.is_open:
                return
            try:
                self.link.send_statustext("warning", "CAP-SD: unsigned fixes refused")
            except OSError:
                return
        self._last_statustext["unauthenticated"] = now
        self.counts["statustext_unauthenticated"] += 1
        logger.warning(
            "fixes without the site's tag refused",
            extra={"fields": {"count": stream.unauthenticated}},
        )

    def counters(self) -> dict[str, int]:
        # Health is answered on Zenoh's thread: it never waits long behind the main loop's
        # MAVLink I/O (which holds the lock); if busy, the last counts go out.
        if self.lock.acquire(timeout=0.2):
            try:
                merged = {f"gate_{k}": v for k, v in self.gate.counts.items()}
                merged.update(self.counts)
                self._last_counts = dict(merged)
            finally:
                self.lock.release()
        else:
            merged = dict(self._last_counts)
        merged["fixes_dropped_for_newer"] = self.fixes.dropped
        if self.fix_stream is not None:
            merged["fixes_unauthenticated"] = self.fix_stream.unauthenticated
        if self.command_stream is not None:
            merged["commands_unauthenticated"] = self.command_stream.unauthenticated
        return merged


def fix_verifier(config: Config) -> SiteKey | None:
    """The key fixes must be tagged with; a config error if required and not given."""
    what = "the ROV's bridge (acting on fixes)" if config.role == "rov" else "the ASV's bridge"
    return site_key(auth=config.fix_auth, path=config.fix_key, needed_for=what)


def main(config: Config) -> int:
    """Run the bridge until stopped."""
    verifier = fix_verifier(config)
    with ServiceRunner("mav_bridge", config) as runner:
        bridge = Bridge(config, runner)
        runner.add_counters(bridge.counters)
        if config.role == "rov":
            bridge.fix_stream = runner.subscribe(
                topics.ROV_FIX, bridge.on_fix, vehicle=config.locator_vehicle, verifier=verifier
            )
        else:
            # The ASV's own pose, from asv_pose on this computer's namespace.
            runner.subscribe(topics.ASV_POSE, bridge.on_fix, vehicle=config.vehicle)
        bridge.command_stream = runner.subscribe(
            topics.ROV_COMMAND if config.role == "rov" else topics.ASV_COMMAND,
            bridge.on_command,
            vehicle=config.locator_vehicle,
            verifier=verifier,
        )
        sender = threading.Thread(target=bridge.send_loop, name="mav-bridge-send", daemon=True)
        sender.start()
        try:
            runner.run(bridge.step, period_s=0.01)
        finally:
            runner.stop_event.set()
            sender.join(timeout=2.0)
            with bridge.lock:
                bridge.link.close()
    return 0
