"""The one typed adapter around pymavlink: MAVLink 2 links, typed messages in, typed sends out.

Nothing else in the project imports pymavlink. Both sides of a link are here: the companion
side (the bridge: heartbeats, VISION_POSITION_ESTIMATE, GPS_INPUT, parameters, commands) and the
vehicle side used by the autopilot stand-in of tests and the demo (ATTITUDE, SCALED_PRESSURE2,
PARAM_VALUE, COMMAND_ACK...). Connection strings: `tcp:HOST:PORT`, `tcpin:HOST:PORT`,
`udpin:HOST:PORT`, `udpout:HOST:PORT`, `serial:DEVICE:BAUD`.
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import time
from dataclasses import dataclass
from typing import Any, Literal, Self

# MAVLink 2 (extension fields: covariance, reset_counter) must be chosen before the import.
os.environ["MAVLINK20"] = "1"

from pymavlink import mavutil

from capsd.errors import ConfigError

MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY = 197
MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_CMD_PREFLIGHT_CALIBRATION = 241
MAV_CMD_DO_SET_MODE = 176
MAV_CMD_DO_SET_REVERSE = 194
MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN = 246
MAV_CMD_REQUEST_MESSAGE = 512
# A gimbal's pitch and yaw (ArduPilot 4.3 on: its mount library, a servo mount included).
MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW = 1000
# GIMBAL_DEVICE_ATTITUDE_STATUS flags: pitch (roll) relative to the horizon, else to the
# vehicle. ArduPilot's mount library sets both always: its pitch is the horizon's.
GIMBAL_DEVICE_FLAGS_PITCH_LOCK = int(mavutil.mavlink.GIMBAL_DEVICE_FLAGS_PITCH_LOCK)
GIMBAL_DEVICE_FLAGS_ROLL_LOCK = int(mavutil.mavlink.GIMBAL_DEVICE_FLAGS_ROLL_LOCK)
# ... and its yaw: in the vehicle's frame (a pan on the hull) or the earth's (locked).
GIMBAL_DEVICE_FLAGS_YAW_LOCK = int(mavutil.mavlink.GIMBAL_DEVICE_FLAGS_YAW_LOCK)
GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME = int(
    mavutil.mavlink.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME
)
GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME = int(mavutil.mavlink.GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME)
# SYS_STATUS sensor bit of external position (ArduPilot: VISO_TYPE set; healthy once the
# visual-odometry backend made at boot has had an estimate within 300 ms).
MAV_SYS_STATUS_SENSOR_VISION_POSITION = int(mavutil.mavlink.MAV_SYS_STATUS_SENSOR_VISION_POSITION)
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_FRAME_LOCAL_NED = 1
# SET_POSITION_TARGET_LOCAL_NED type_mask: position only (velocity, acceleration, yaw and yaw
# rate ignored), the form ArduSub's GUIDED mode takes for a position target.
POSITION_ONLY_MASK = 0b0000_1101_1111_1000
# ... and with the yaw (bit 10 clear): ArduRover's GUIDED turns an omni or boat frame to it.
_YAW_IGNORE = 0b0100_0000_0000
POSITION_YAW_MASK = POSITION_ONLY_MASK & ~_YAW_IGNORE
# ... a heading alone (position, velocity, acceleration and yaw rate ignored): ArduRover's GUIDED
# ignores the yaw of a position target; this one turns the vehicle in place to the heading.
_POSITION_IGNORE = 0b0000_0000_0111
HEADING_ONLY_MASK = 0b1001_1111_1111
# Whose custom modes a HEARTBEAT carries: the ROV's ArduSub, the ASV's ArduRover (boat/omni).
Autopilot = Literal["ardusub", "ardurover"]
MAV_RESULT_ACCEPTED = 0
MAV_RESULT_DENIED = 2
MAV_RESULT_UNSUPPORTED = 3
MAV_SEVERITY = {"emergency": 0, "alert": 1, "critical": 2, "error": 3, "warning": 4,
                "notice": 5, "info": 6, "debug": 7}  # fmt: skip
_ARMED_FLAG = 128  # MAV_MODE_FLAG_SAFETY_ARMED
_CONNECTION = re.compile(r"^(tcp|tcpin|udpin|udpout):[^:]+:\d{1,5}$|^serial:[^:]+:\d+$")

# GPS_INPUT ignore flags: we send no velocity.
GPS_INPUT_IGNORE_VELOCITY = 8 | 16 | 32  # VEL_HORIZ | VEL_VERT | SPEED_ACCURACY


def check_connection(connection: str) -> str:
    """Validate a connection string, or raise ConfigError naming it."""
    if not _CONNECTION.fullmatch(connection):
        raise ConfigError(
            "mavlink",
            "connect",
            f"'{connection}' is not tcp:HOST:PORT, tcpin:, udpin:, udpout: or serial:DEVICE:BAUD",
        )
    return connection


# ------------------------------------------------------------------------- messages in


@dataclass(frozen=True)
class Heartbeat:
    system_id: int
    component_id: int
    mav_type: int
    autopilot: int
    base_mode: int
    custom_mode: int

    @property
    def armed(self) -> bool:
        return bool(self.base_mode & _ARMED_FLAG)


@dataclass(frozen=True)
class Attitude:
    """ATTITUDE: the vehicle's body FRD in local NED (rad, rad/s)."""

    time_boot_ms: int
    roll: float
    pitch: float
    yaw: float
    rollspeed: float
    pitchspeed: float
    yawspeed: float


@dataclass(frozen=True)
class ScaledPressure:
    """SCALED_PRESSUREn: `instance` 1, 2 or 3 (BlueROV2's Bar30 is 2); pressure in hPa."""

    instance: int
    time_boot_ms: int
    press_abs_hpa: float
    temperature_c: float


@dataclass(frozen=True)
class SystemTime:
    time_unix_usec: int
    time_boot_ms: int


@dataclass(frozen=True)
class EkfStatus:
    flags: int
    # EKF3's innovation test ratios (1.0: at its gate); pos_horiz is the one external position
    # feeds: ~0.1 in good flight, several when positions and the vehicle's motion disagree.
    pos_horiz_variance: float = 0.0
    velocity_variance: float = 0.0
    compass_variance: float = 0.0


@dataclass(frozen=True)
class SysStatus:
    """SYS_STATUS: which sensors the autopilot has (present), uses (enabled), trusts (health)."""

    present: int
    enabled: int
    health: int

    def sensor(self, bit: int) -> Literal["absent", "unhealthy", "healthy"]:
        if not self.present & bit:
            return "absent"
        return "healthy" if self.health & bit else "unhealthy"


@dataclass(frozen=True)
class ParamValue:
    name: str
    value: float
    index: int
    count: int


@dataclass(frozen=True)
class CommandAck:
    command: int
    result: int


@dataclass(frozen=True)
class CommandLong:
    command: int
    params: tuple[float, float, float, float, float, float, float]


@dataclass(frozen=True)
class StatusText:
    severity: int
    text: str


@dataclass(frozen=True)
class VisionPositionEstimate:
    usec: int
    x: float
    y: float
    z: float
    roll: float
    pitch: float
    yaw: float
    covariance: tuple[float, ...]
    reset_counter: int


@dataclass(frozen=True)
class GimbalAttitude:
    """GIMBAL_DEVICE_ATTITUDE_STATUS: a mount's pitch (rad, up +) and whether it is the horizon's.

    `horizon_relative`: the PITCH_LOCK flag (a stabilised gimbal); else relative to the vehicle.
    `yaw_rad`: its yaw in the vehicle's frame (right +, MAVLink's); None where the message puts
    it in the earth's frame (YAW_LOCK or YAW_IN_EARTH_FRAME), which a pan on the hull is not.
    """

    time_boot_ms: int
    pitch_rad: float
    horizon_relative: bool
    yaw_rad: float | None = 0.0


@dataclass(frozen=True)
class GpsInput:
    time_usec: int
    lat_e7: int
    lon_e7: int
    alt_m: float
    horiz_accuracy_m: float
    fix_type: int


@dataclass(frozen=True)
class GlobalOrigin:
    lat_e7: int
    lon_e7: int
    alt_mm: int


@dataclass(frozen=True)
class OriginReport:
    """GPS_GLOBAL_ORIGIN: the EKF origin the autopilot uses (it has one)."""

    lat_e7: int
    lon_e7: int
    alt_mm: int


@dataclass(frozen=True)
class ParamSet:
    name: str
    value: float


@dataclass(frozen=True)
class ParamRequest:
    """PARAM_REQUEST_READ (name) or PARAM_REQUEST_LIST (name None)."""

    name: str | None


@dataclass(frozen=True)
class PositionTarget:
    """SET_POSITION_TARGET_LOCAL_NED: where GUIDED should go (NED, metres)."""

    time_boot_ms: int
    frame: int
    type_mask: int
    north_m: float
    east_m: float
    down_m: float
    yaw_rad: float | None = None  # None when the type mask says to ignore it
    position_ignored: bool = False  # a heading-only target: north/east/down mean nothing


Message = (
    Heartbeat | Attitude | ScaledPressure | SystemTime | EkfStatus | SysStatus | ParamValue
    | CommandAck | CommandLong | StatusText | VisionPositionEstimate | GpsInput | GlobalOrigin
    | OriginReport | ParamSet | ParamRequest | PositionTarget | GimbalAttitude
)  # fmt: skip


@dataclass(frozen=True)
class Received:
    """A typed message and who sent it."""

    message: Message
    system_id: int
    component_id: int


def _text(value: Any) -> str:
    return value.decode(errors="replace") if isinstance(value, bytes) else str(value)


def _convert(msg: Any) -> Message | None:
    kind = msg.get_type()
    if kind == "HEARTBEAT":
        return Heartbeat(
            msg.get_srcSystem(),
            msg.get_srcComponent(),
            msg.type,
            msg.autopilot,
            msg.base_mode,
            msg.custom_mode,
        )
    if kind == "ATTITUDE":
        return Attitude(
            msg.time_boot_ms,
            msg.roll,
            msg.pitch,
            msg.yaw,
            msg.rollspeed,
            msg.pitchspeed,
            msg.yawspeed,
        )
    if kind in ("SCALED_PRESSURE", "SCALED_PRESSURE2", "SCALED_PRESSURE3"):
        instance = {"SCALED_PRESSURE": 1, "SCALED_PRESSURE2": 2, "SCALED_PRESSURE3": 3}[kind]
        return ScaledPressure(instance, msg.time_boot_ms, msg.press_abs, msg.temperature / 100.0)
    if kind == "SYSTEM_TIME":
        return SystemTime(msg.time_unix_usec, msg.time_boot_ms)
    if kind == "EKF_STATUS_REPORT":
        return EkfStatus(
            msg.flags,
            float(msg.pos_horiz_variance),
            float(msg.velocity_variance),
            float(msg.compass_variance),
        )
    if kind == "SYS_STATUS":
        return SysStatus(
            msg.onboard_control_sensors_present,
            msg.onboard_control_sensors_enabled,
            msg.onboard_control_sensors_health,
        )
    if kind == "PARAM_VALUE":
        return ParamValue(
            _text(msg.param_id).rstrip("\0"),
            float(msg.param_value),
            msg.param_index,
            msg.param_count,
        )
    if kind == "COMMAND_ACK":
        return CommandAck(msg.command, msg.result)
    if kind == "COMMAND_LONG":
        return CommandLong(
            msg.command,
            (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7),
        )
    if kind == "STATUSTEXT":
        return StatusText(msg.severity, _text(msg.text).rstrip("\0"))
    if kind == "VISION_POSITION_ESTIMATE":
        return VisionPositionEstimate(
            msg.usec,
            msg.x,
            msg.y,
            msg.z,
            msg.roll,
            msg.pitch,
            msg.yaw,
            tuple(float(c) for c in msg.covariance),
            msg.reset_counter,
        )
    if kind == "GIMBAL_DEVICE_ATTITUDE_STATUS":
        w, x, y, z = (float(c) for c in msg.q)
        pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
        locked = bool(msg.flags & GIMBAL_DEVICE_FLAGS_PITCH_LOCK)
        earth = GIMBAL_DEVICE_FLAGS_YAW_LOCK | GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME
        yaw = (
            None
            if msg.flags & earth
            else math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
        )
        return GimbalAttitude(msg.time_boot_ms, pitch, locked, yaw)
    if kind == "GPS_INPUT":
        return GpsInput(msg.time_usec, msg.lat, msg.lon, msg.alt, msg.horiz_accuracy, msg.fix_type)
    if kind == "SET_GPS_GLOBAL_ORIGIN":
        return GlobalOrigin(msg.latitude, msg.longitude, msg.altitude)
    if kind == "GPS_GLOBAL_ORIGIN":
        return OriginReport(msg.latitude, msg.longitude, msg.altitude)
    if kind == "PARAM_SET":
        return ParamSet(_text(msg.param_id).rstrip("\0"), float(msg.param_value))
    if kind == "PARAM_REQUEST_READ":
        return ParamRequest(_text(msg.param_id).rstrip("\0"))
    if kind == "PARAM_REQUEST_LIST":
        return ParamRequest(None)
    if kind == "SET_POSITION_TARGET_LOCAL_NED":
        yaw = None if msg.type_mask & _YAW_IGNORE else float(msg.yaw)
        ignored = msg.type_mask & _POSITION_IGNORE == _POSITION_IGNORE
        return PositionTarget(
            msg.time_boot_ms, msg.coordinate_frame, msg.type_mask, msg.x, msg.y, msg.z, yaw, ignored
        )
    return None


# ------------------------------------------------------------------------- the link


class MavLink:
    """One MAVLink 2 connection; a context manager; not thread-safe (callers hold a lock)."""

    def __init__(self, connection: str, *, system_id: int, component_id: int):
        self.connection = check_connection(connection)
        self.system_id = system_id
        self.component_id = component_id
        self._conn: Any = None

    def __enter__(self) -> Self:
        self.open()
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def open(self) -> None:
        kind, _, rest = self.connection.partition(":")
        kwargs: dict[str, Any] = {
            "source_system": self.system_id,
            "source_component": self.component_id,
            "dialect": "ardupilotmega",
        }
        if kind == "serial":
            device, baud = rest.rsplit(":", 1)
            self._conn = mavutil.mavlink_connection(device, baud=int(baud), **kwargs)
        elif kind == "tcp":
            # One attempt, no reconnecting inside pymavlink: the caller owns reconnection
            # (with back-off). pymavlink's TCP link otherwise prints on EOF, reconnects on its
            # own from recv/write, and swallows a failed write: all three become errors here.
            self._conn = mavutil.mavlink_connection(
                self.connection, autoreconnect=False, retries=0, **kwargs
            )
            self._raise_on_loss(self._conn)
        else:
            self._conn = mavutil.mavlink_connection(self.connection, **kwargs)
        self._conn.mav.srcSystem = self.system_id
        self._conn.mav.srcComponent = self.component_id

    def _raise_on_loss(self, conn: Any) -> None:
        """Make a pymavlink TCP link raise ConnectionError where it would print or reconnect."""
        where = self.connection

        def lost(*_args: object) -> None:
            raise ConnectionError(f"MAVLink link {where} closed by the other end")

        def write(buf: bytes) -> None:
            if conn.port is None:
                raise ConnectionError(f"MAVLink link {where} is closed")
            sent = conn.port.send(buf)  # OSError (EPIPE, ECONNRESET, EAGAIN) propagates
            if sent != len(buf):
                raise ConnectionError(f"MAVLink link {where}: {sent} of {len(buf)} bytes sent")

        conn.handle_eof = lost
        conn.handle_disconnect = lost
        conn.write = write

    def close(self) -> None:
        """Close the link; never raises (pymavlink's close can raise on a half-open link)."""
        conn, self._conn = self._conn, None
        if conn is not None:
            # pymavlink raises AttributeError closing a link whose socket it already dropped.
            with contextlib.suppress(OSError, AttributeError):
                conn.close()

    @property
    def is_open(self) -> bool:
        return self._conn is not None

    @property
    def _mav(self) -> Any:
        if self._conn is None:
            raise ConnectionError(f"MAVLink link {self.connection} is closed")
        return self._conn.mav

    def recv(self, *, timeout_s: float = 0.0) -> Received | None:
        """The next known message, or None if none came within `timeout_s`.

        Messages this adapter does not know are passed over, also past the deadline while
        more are already here: an autopilot streams many (SERVO_OUTPUT_RAW, RC_CHANNELS, ...),
        and a read that gave up at the first left the caller seconds behind the stream.
        """
        if self._conn is None:
            return None
        deadline = time.monotonic() + timeout_s
        while True:
            remaining = deadline - time.monotonic()
            # pymavlink checks a timeout before reading: a non-blocking read needs None.
            if remaining > 0:
                msg = self._conn.recv_match(blocking=True, timeout=remaining)
            else:
                msg = self._conn.recv_match(blocking=False, timeout=None)
            if msg is None:
                return None
            converted = _convert(msg) if msg.get_type() != "BAD_DATA" else None
            if converted is not None:
                return Received(converted, msg.get_srcSystem(), msg.get_srcComponent())

    # ------------------------------------------------------------ companion side

    def send_heartbeat_onboard(self) -> None:
        mav = mavutil.mavlink
        self._mav.heartbeat_send(
            mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE
        )

    def send_vision_position_estimate(
        self,
        *,
        usec: int,
        x: float,
        y: float,
        z: float,
        roll: float,
        pitch: float,
        yaw: float,
        covariance: tuple[float, ...],
        reset_counter: int,
    ) -> None:
        if len(covariance) != 21:
            raise ValueError("VISION_POSITION_ESTIMATE covariance has 21 entries")
        self._mav.vision_position_estimate_send(
            usec, x, y, z, roll, pitch, yaw, list(covariance), reset_counter % 256
        )

    def send_gps_input(
        self,
        *,
        time_usec: int,
        gps_week: int,
        gps_week_ms: int,
        lat_e7: int,
        lon_e7: int,
        alt_m: float,
        horiz_accuracy_m: float,
        vert_accuracy_m: float,
        yaw_cdeg: int = 0,
    ) -> None:
        self._mav.gps_input_send(
            time_usec,
            0,
            GPS_INPUT_IGNORE_VELOCITY,
            gps_week_ms,
            gps_week,
            3,
            lat_e7,
            lon_e7,
            alt_m,
            1.0,
            1.0,
            0.0,
            0.0,
            0.0,
            0.0,
            horiz_accuracy_m,
            vert_accuracy_m,
            10,
            yaw_cdeg,
        )

    def send_statustext(self, severity: str, text: str) -> None:
        self._mav.statustext_send(MAV_SEVERITY[severity], text.encode()[:50])

    def send_set_message_interval(
        self, *, target_system: int, message_id: int, rate_hz: float
    ) -> None:
        interval_us = -1 if rate_hz <= 0 else int(1e6 / rate_hz)
        self._mav.command_long_send(
            target_system,
            1,
            MAV_CMD_SET_MESSAGE_INTERVAL,
            0,
            message_id,
            interval_us,
            0,
            0,
            0,
            0,
            0,
        )

    def send_calibrate_surface_pressure(self, *, target_system: int) -> None:
        """MAV_CMD_PREFLIGHT_CALIBRATION, barometer: the pressure now becomes the surface's."""
        self._mav.command_long_send(
            target_system, 1, MAV_CMD_PREFLIGHT_CALIBRATION, 0, 0, 0, 1, 0, 0, 0, 0
        )

    def send_request_message(self, *, target_system: int, message_id: int) -> None:
        """MAV_CMD_REQUEST_MESSAGE: send `message_id` once now."""
        self._mav.command_long_send(
            target_system, 1, MAV_CMD_REQUEST_MESSAGE, 0, message_id, 0, 0, 0, 0, 0, 0
        )

    def send_origin_report(self, origin: OriginReport) -> None:
        self._mav.gps_global_origin_send(
            origin.lat_e7, origin.lon_e7, origin.alt_mm, int(time.time() * 1e6)
        )

    def send_reboot(self, *, target_system: int) -> None:
        """MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN: reboot the autopilot (ArduPilot: only disarmed)."""
        self._mav.command_long_send(
            target_system, 1, MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 0, 1, 0, 0, 0, 0, 0, 0
        )

    def send_set_mode(
        self, *, target_system: int, mode: str, autopilot: Autopilot = "ardusub"
    ) -> None:
        """MAV_CMD_DO_SET_MODE with the autopilot's custom mode `mode` (GUIDED, POSHOLD...)."""
        self._mav.command_long_send(
            target_system,
            1,
            MAV_CMD_DO_SET_MODE,
            0,
            MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
            mode_number(mode, autopilot),
            0,
            0,
            0,
            0,
            0,
        )

    def send_position_target(
        self,
        *,
        target_system: int,
        time_boot_ms: int,
        ned_m: tuple[float, float, float],
        yaw_rad: float | None = None,
    ) -> None:
        """SET_POSITION_TARGET_LOCAL_NED in the EKF's local NED frame: position (and yaw)."""
        self._mav.set_position_target_local_ned_send(
            time_boot_ms & 0xFFFFFFFF,
            target_system,
            1,
            MAV_FRAME_LOCAL_NED,
            POSITION_ONLY_MASK if yaw_rad is None else POSITION_YAW_MASK,
            float(ned_m[0]),
            float(ned_m[1]),
            float(ned_m[2]),
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0 if yaw_rad is None else float(yaw_rad),
            0.0,
        )

    def send_heading_target(self, *, target_system: int, time_boot_ms: int, yaw_rad: float) -> None:
        """SET_POSITION_TARGET_LOCAL_NED with a heading alone (NED yaw): turn in place to it."""
        self._mav.set_position_target_local_ned_send(
            time_boot_ms & 0xFFFFFFFF, target_system, 1, MAV_FRAME_LOCAL_NED, HEADING_ONLY_MASK,
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, float(yaw_rad), 0.0,
        )  # fmt: skip

    def send_set_reverse(
        self, *, target_system: int, direction: Literal["forward", "reverse"]
    ) -> None:
        """MAV_CMD_DO_SET_REVERSE: ArduRover drives its position targets backwards (or not)."""
        self._mav.command_long_send(
            target_system, 1, MAV_CMD_DO_SET_REVERSE, 0,
            1.0 if direction == "reverse" else 0.0, 0, 0, 0, 0, 0, 0,
        )  # fmt: skip

    def send_gimbal_pitch(
        self, *, target_system: int, pitch_deg: float, yaw_deg: float = 0.0
    ) -> None:
        """MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW: every gimbal to `pitch_deg` (up +), `yaw_deg`.

        The yaw in the vehicle's frame (right +; 0: ahead). No lock flag: the yaw follows the
        vehicle (ArduPilot takes the pitch against the horizon whatever the flags); the rates
        unused (NaN).
        """
        nan = float("nan")
        self._mav.command_long_send(
            target_system, 1, MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, 0,
            float(pitch_deg), float(yaw_deg), nan, nan, 0, 0, 0,
        )  # fmt: skip

    def send_set_gps_global_origin(
        self, *, target_system: int, lat_e7: int, lon_e7: int, alt_mm: int
    ) -> None:
        self._mav.set_gps_global_origin_send(
            target_system, lat_e7, lon_e7, alt_mm, int(time.time() * 1e6)
        )

    def send_param_request_read(self, *, target_system: int, name: str) -> None:
        self._mav.param_request_read_send(target_system, 1, name.encode(), -1)

    def send_param_set(self, *, target_system: int, name: str, value: float) -> None:
        self._mav.param_set_send(
            target_system, 1, name.encode(), float(value), mavutil.mavlink.MAV_PARAM_TYPE_REAL32
        )

    # ------------------------------------------------------------ vehicle side (stand-in)

    def send_heartbeat_vehicle(
        self, *, armed: bool, custom_mode: int, autopilot: Autopilot = "ardusub"
    ) -> None:
        mav = mavutil.mavlink
        base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (_ARMED_FLAG if armed else 0)
        self._mav.heartbeat_send(
            mav.MAV_TYPE_SUBMARINE if autopilot == "ardusub" else mav.MAV_TYPE_SURFACE_BOAT,
            mav.MAV_AUTOPILOT_ARDUPILOTMEGA,
            base,
            custom_mode,
            mav.MAV_STATE_ACTIVE,
        )

    def send_attitude(self, attitude: Attitude) -> None:
        a = attitude
        self._mav.attitude_send(
            a.time_boot_ms, a.roll, a.pitch, a.yaw, a.rollspeed, a.pitchspeed, a.yawspeed
        )

    def send_gimbal_attitude(
        self, *, time_boot_ms: int, pitch_rad: float, horizon_relative: bool, yaw_rad: float = 0.0
    ) -> None:
        """GIMBAL_DEVICE_ATTITUDE_STATUS of a mount pitched `pitch_rad` (up +), yawed `yaw_rad`.

        The pitch against the horizon (the lock flags, as ArduPilot's mount sends it) or the
        vehicle; the yaw in the vehicle's frame (right +).
        """
        cy, sy = math.cos(yaw_rad / 2.0), math.sin(yaw_rad / 2.0)
        cp, sp = math.cos(pitch_rad / 2.0), math.sin(pitch_rad / 2.0)
        q = (cy * cp, -sy * sp, cy * sp, sy * cp)  # w, x, y, z: the yaw, then the pitch
        flags = GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME
        flags |= GIMBAL_DEVICE_FLAGS_PITCH_LOCK | GIMBAL_DEVICE_FLAGS_ROLL_LOCK
        nan = float("nan")
        self._mav.gimbal_device_attitude_status_send(
            0,
            0,
            time_boot_ms,
            flags if horizon_relative else GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME,
            q,
            nan,
            nan,
            nan,
            0,
        )

    def send_scaled_pressure2(
        self, *, time_boot_ms: int, press_abs_hpa: float, temperature_c: float
    ) -> None:
        self._mav.scaled_pressure2_send(
            time_boot_ms, press_abs_hpa, 0.0, round(temperature_c * 100)
        )

    def send_system_time(self, *, time_unix_usec: int, time_boot_ms: int) -> None:
        self._mav.system_time_send(time_unix_usec, time_boot_ms)

    def send_ekf_status(self, status: EkfStatus) -> None:
        self._mav.ekf_status_report_send(
            status.flags,
            status.velocity_variance,
            status.pos_horiz_variance,
            0.0,  # pos_vert_variance
            status.compass_variance,
            0.0,  # terrain_alt_variance
        )

    def send_sys_status(self, status: SysStatus) -> None:
        self._mav.sys_status_send(
            status.present, status.enabled, status.health, 0, 16_000, -1, -1, 0, 0, 0, 0, 0, 0
        )

    def send_param_value(self, *, name: str, value: float, index: int, count: int) -> None:
        self._mav.param_value_send(
            name.encode(), float(value), mavutil.mavlink.MAV_PARAM_TYPE_REAL32, count, index
        )

    def send_command_ack(self, *, command: int, result: int) -> None:
        self._mav.command_ack_send(command, result)


def _modes(autopilot: Autopilot) -> dict[int, str]:
    table = mavutil.mode_mapping_sub if autopilot == "ardusub" else mavutil.mode_mapping_rover
    return {int(k): str(v) for k, v in table.items()}


def mode_name(custom_mode: int, autopilot: Autopilot = "ardusub") -> str:
    """The autopilot's name for a HEARTBEAT custom_mode (ArduSub 16: POSHOLD)."""
    return _modes(autopilot).get(custom_mode, f"MODE{custom_mode}")


def mode_number(name: str, autopilot: Autopilot = "ardusub") -> int:
    """The autopilot's custom_mode for a mode name (ArduSub POSHOLD -> 16)."""
    for number, known in _modes(autopilot).items():
        if known == name:
            return number
    raise KeyError(f"{autopilot} has no mode '{name}'")


def message_id(name: str) -> int:
    """The MAVLink message id of e.g. "ATTITUDE" (for SET_MESSAGE_INTERVAL)."""
    return int(getattr(mavutil.mavlink, f"MAVLINK_MSG_ID_{name}"))
