"""An ArduSub (or ArduRover) stand-in on a loopback link: telemetry, parameters, a recorder.

It listens (`tcpin:`), sends HEARTBEAT (1 Hz), ATTITUDE, SCALED_PRESSURE2, SYSTEM_TIME,
SYS_STATUS and EKF_STATUS_REPORT (a model of EKF3's position test ratio, see `pos_horiz_ratio`)
at the rates the bridge asks for (MAV_CMD_SET_MESSAGE_INTERVAL, acknowledged), serves
parameters (PARAM_REQUEST_READ/LIST, PARAM_SET echoes PARAM_VALUE), reboots when disarmed
(MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN) and records what it receives: VISION_POSITION_ESTIMATE,
GPS_INPUT, STATUSTEXT, SET_GPS_GLOBAL_ORIGIN. As ArduPilot does, it takes external position
only when VISO_TYPE was set at its last boot (the backend is made then); SYS_STATUS says so.
The vehicle's attitude and depth come from a callable, so a simulator can drive it. For tests
and the demo only.
"""

from __future__ import annotations

import json
import math
import socket
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Self

from capsd.errors import CapsdError
from capsd.payloads import DriveDirection
from capsd.protocols.mavlink import (
    MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW,
    MAV_CMD_DO_SET_MODE,
    MAV_CMD_DO_SET_REVERSE,
    MAV_CMD_PREFLIGHT_CALIBRATION,
    MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN,
    MAV_CMD_REQUEST_MESSAGE,
    MAV_CMD_SET_MESSAGE_INTERVAL,
    MAV_RESULT_ACCEPTED,
    MAV_RESULT_DENIED,
    MAV_RESULT_UNSUPPORTED,
    MAV_SYS_STATUS_SENSOR_VISION_POSITION,
    Attitude,
    Autopilot,
    CommandLong,
    EkfStatus,
    GlobalOrigin,
    GpsInput,
    Heartbeat,
    MavLink,
    OriginReport,
    ParamRequest,
    ParamSet,
    PositionTarget,
    StatusText,
    SysStatus,
    VisionPositionEstimate,
    message_id,
    mode_name,
    mode_number,
)
from capsd.simulator.guided import WP_RADIUS_M
from capsd.stop_signal import set_after_handler

# A fresh ArduSub as far as external position is concerned (what `capsd mav check` fixes).
DEFAULT_PARAMS: dict[str, float] = {
    "VISO_TYPE": 0.0,
    "EK3_SRC1_POSXY": 3.0,
    "EK3_SRC1_VELXY": 3.0,
    "EK3_SRC1_POSZ": 1.0,
    "EK3_SRC1_YAW": 1.0,
    "GPS1_TYPE": 1.0,
    "VISO_POS_M_NSE": 0.2,
    "VISO_DELAY_MS": 10.0,
    "BARO2_GND_PRESS": 101_325.0,
    "BARO_SPEC_GRAV": 1.0,
}

# ... and one `capsd mav check --apply` and a reboot later.
CONFIGURED_PARAMS: dict[str, float] = DEFAULT_PARAMS | {
    "VISO_TYPE": 1.0,
    "EK3_SRC1_POSXY": 6.0,
    "EK3_SRC1_VELXY": 0.0,
    "GPS1_TYPE": 0.0,
    "VISO_POS_M_NSE": 0.05,
}
# A fresh ArduRover (the ASV) adds how GUIDED drives to a target (AR_WPNav's and Rover's
# defaults): it stops steering 2 m from it, a boat then drifts 2 m before it drives back.
# Its outputs: steering and throttle (ArduRover's defaults), the rest unassigned, no mount.
ROVER_DEFAULT_PARAMS: dict[str, float] = (
    DEFAULT_PARAMS
    | {"WP_RADIUS": 2.0, "LOIT_RADIUS": 2.0, "WP_SPEED": 2.0, "MNT1_TYPE": 0.0}
    | {f"SERVO{n}_FUNCTION": 0.0 for n in range(1, 17)}
    | {"SERVO1_FUNCTION": 26.0, "SERVO3_FUNCTION": 70.0}
)
# ArduPilot lists a mount's parameters once MNT1_TYPE is set (its defaults then).
MOUNT_LISTED_PARAMS: dict[str, float] = {
    "MNT1_PITCH_MIN": -90.0,
    "MNT1_PITCH_MAX": 20.0,
    "MNT1_YAW_MIN": -180.0,
    "MNT1_YAW_MAX": 180.0,
}
# ... after `capsd mav check --role asv --apply` and a reboot (the ASV's yaw: its pose's).
# The sonar's tilt servo on output 9 (`capsd mav check --role asv --bridge-config ...`).
ROVER_CONFIGURED_PARAMS: dict[str, float] = (
    ROVER_DEFAULT_PARAMS
    | CONFIGURED_PARAMS
    | MOUNT_LISTED_PARAMS
    | {
        "EK3_SRC1_YAW": 6.0,
        "WP_RADIUS": WP_RADIUS_M,  # the simulated ASV stops steering this near its target
        "LOIT_RADIUS": 0.3,
        "WP_SPEED": 0.5,
        "MNT1_TYPE": 1.0,
        "SERVO9_FUNCTION": 7.0,
        "SERVO10_FUNCTION": 6.0,  # a pan servo (where the mount has one)
    }
)
# Read by ArduPilot at boot only (its parameter documentation: RebootRequired).
BOOT_PARAMS = ("VISO_TYPE", "GPS1_TYPE", "MNT1_TYPE")
REBOOT_S = 1.0  # how long a reboot keeps the link down
# ArduPilot drops an EKF origin sent before its EKF has started (this long after boot here).
EKF_START_S = 1.5
VISO_TIMEOUT_S = 0.3  # AP_VisualOdom: healthy with an estimate this recent

RHO_G = 1000.0 * 9.80665
EKF_WINDOW_S = 3.0
EKF_GATE_M = 0.3
EKF_HEALTHY_FLAGS = 0x1FF  # attitude, velocities, positions, const-pos: what a good EKF says
# Modes the autopilot refuses without an EKF position (external positions arriving).
POSITION_MODES: dict[Autopilot, tuple[str, ...]] = {
    "ardusub": ("GUIDED", "POSHOLD"),
    "ardurover": ("GUIDED", "LOITER"),
}


@dataclass(frozen=True)
class VehicleState:
    """What the stand-in reports: FRD attitude in NED (rad) and the Bar30's depth (m)."""

    roll: float = 0.0
    pitch: float = 0.0
    yaw: float = 0.0
    depth_m: float = 1.0
    # Where the vehicle truly is (NED from the EKF origin), for the EKF model: None = unknown.
    north_m: float | None = None
    east_m: float | None = None


@dataclass
class Recorded:
    """Everything the stand-in received that a test may check, with arrival times."""

    estimates: list[tuple[float, VisionPositionEstimate]] = field(default_factory=list)
    gps_inputs: list[tuple[float, GpsInput]] = field(default_factory=list)
    statustexts: list[StatusText] = field(default_factory=list)
    origins: list[GlobalOrigin] = field(default_factory=list)
    heartbeats: int = 0
    position_targets: list[tuple[float, PositionTarget]] = field(default_factory=list)
    targets_refused: int = 0  # position targets while not in GUIDED (ArduSub ignores them)
    targets_without_origin: int = 0  # ArduRover ignores GUIDED targets without an EKF origin
    modes: list[tuple[float, str, bool]] = field(default_factory=list)  # (when, asked, taken)


def _check_bindable(port: int) -> None:
    """OSError if pymavlink's listener could not bind the port (it leaks its socket then)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as pymavlink's does
        probe.bind(("127.0.0.1", port))


class AutopilotStandIn:
    """Run with `with AutopilotStandIn(port) as ap:`; `restart()` cuts and restores the link."""

    def __init__(
        self,
        port: int,
        *,
        state: Callable[[float], VehicleState] = lambda _t: VehicleState(),
        params: dict[str, float] | None = None,
        armed: bool = True,
        mode: str = "POSHOLD",
        autopilot: Autopilot = "ardusub",
        boot_depth_m: float = 0.0,
        water_temperature_c: float = 18.0,
        on_mode: Callable[[str], None] | None = None,
        on_target: Callable[[PositionTarget], None] | None = None,
        on_estimate: Callable[[VisionPositionEstimate], None] | None = None,
        on_direction: Callable[[DriveDirection], None] | None = None,
        on_gimbal_pitch: Callable[[float, float], None] | None = None,
        gimbal_pitch_rad: Callable[[], float] | None = None,
        gimbal_yaw_rad: Callable[[], float] | None = None,
        gcs_port: int | None = None,
    ):
        self.port = port
        # A second client (a ground station beside the bridge), as BlueOS's router allows.
        self.gcs_port = gcs_port
        # A simulator flying the vehicle hears what the autopilot is told (its own thread).
        self.on_mode = on_mode
        self.on_target = on_target
        self.on_estimate = on_estimate
        self.on_direction = on_direction  # ArduRover's MAV_CMD_DO_SET_REVERSE
        # A mount (the sonar's tilt servo, a pan servo too): told a pitch and a yaw (deg, up
        # +, right +; NaN: unchanged), reporting them (rad; the yaw 0 without a pan).
        self.on_gimbal_pitch = on_gimbal_pitch
        self.gimbal_pitch_rad = gimbal_pitch_rad
        self.gimbal_yaw_rad = gimbal_yaw_rad
        self.state = state
        self.heartbeat_sent_s = -math.inf
        self.params = dict(DEFAULT_PARAMS if params is None else params)
        # The air's pressure; the surface reference is what the autopilot measured at boot
        # (BARO2_GND_PRESS), `boot_depth_m` under water if it booted there.
        self.air_pressure_pa = self.params["BARO2_GND_PRESS"]
        self.params["BARO2_GND_PRESS"] += boot_depth_m * RHO_G * self.params["BARO_SPEC_GRAV"]
        self.water_temperature_c = water_temperature_c  # what its Bar30 reads besides pressure
        self.armed = armed
        self.autopilot: Autopilot = autopilot
        mode_number(mode, autopilot)  # a mode this autopilot has, or KeyError now
        self.mode = mode
        self.recorded = Recorded()
        self.lock = threading.Lock()
        # (arrival, estimate north, east, true north, east) of the last EKF_WINDOW_S.
        self._innovations: deque[tuple[float, float, float, float, float]] = deque()
        self._rates_hz = {
            message_id("ATTITUDE"): 10.0,
            message_id("SCALED_PRESSURE2"): 5.0,
            message_id("SYSTEM_TIME"): 1.0,
            message_id("SYS_STATUS"): 1.0,
        }
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._booted = time.monotonic()
        self._paused = threading.Event()
        self._reboot_due = threading.Event()
        self.origin: OriginReport | None = None  # the EKF origin, once one was taken
        self.boots = 1
        # What the running firmware read at boot: parameters changed since wait for a reboot.
        self.boot_params = self._read_at_boot()

    def __enter__(self) -> Self:
        """Listening on every port when this returns (a client may connect at once)."""
        ports = [self.port] + ([] if self.gcs_port is None else [self.gcs_port])
        listening = [threading.Event() for _ in ports]
        for k, port in enumerate(ports):
            thread = threading.Thread(
                target=self._run,
                args=(port, k == 0, listening[k]),
                name=f"autopilot-{port}",
                daemon=True,
            )
            thread.start()
            self._threads.append(thread)
        deadline = time.monotonic() + 10.0
        for port, ready, thread in zip(ports, listening, self._threads, strict=True):
            while not ready.wait(timeout=0.02):
                if not thread.is_alive() or time.monotonic() > deadline:
                    self.__exit__()
                    raise CapsdError(f"the autopilot stand-in could not listen on 127.0.0.1:{port}")
        return self

    def __exit__(self, *_exc: object) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=5)

    def restart(self, *, down_s: float) -> None:
        """Close the link for `down_s` seconds (the bridge sees the autopilot vanish)."""
        self._paused.set()
        time.sleep(down_s)
        self._paused.clear()

    def rates_hz(self) -> dict[int, float]:
        """The stream rates now in force, by message id (as set by SET_MESSAGE_INTERVAL)."""
        return dict(self._rates_hz)

    def time_boot_ms(self) -> int:
        return int((time.monotonic() - self._booted) * 1000)

    @property
    def takes_estimates(self) -> bool:
        """Whether the firmware has an external-position backend (VISO_TYPE at boot)."""
        return self.boot_params.get("VISO_TYPE", 0.0) != 0.0

    def _read_at_boot(self) -> dict[str, float]:
        return {name: self.params[name] for name in BOOT_PARAMS if name in self.params}

    def _boot(self) -> None:
        self._booted = time.monotonic()
        self.origin = None
        self.boots += 1
        self.boot_params = self._read_at_boot()
        with self.lock:
            self._innovations.clear()

    # ------------------------------------------------------------------ loop

    def _run(self, port: int, primary: bool, listening: threading.Event) -> None:
        while not self._stop.is_set():
            try:
                _check_bindable(port)
            except OSError:
                if not listening.is_set():
                    return  # never listened: __enter__ says so
                time.sleep(0.1)  # the port taken between two clients: try again
                continue
            with MavLink(f"tcpin:127.0.0.1:{port}", system_id=1, component_id=1) as link:
                listening.set()
                self._serve(link)
            if self._reboot_due.is_set():
                if primary:  # one thread boots the firmware; the others wait for it
                    self._stop.wait(REBOOT_S)
                    self._boot()
                    self._reboot_due.clear()
                else:
                    while self._reboot_due.is_set() and not self._stop.is_set():
                        time.sleep(0.02)
            while self._paused.is_set() and not self._stop.is_set():
                time.sleep(0.02)

    def _serve(self, link: MavLink) -> None:
        next_due: dict[int | str, float] = {"heartbeat": 0.0}
        while not (self._stop.is_set() or self._paused.is_set() or self._reboot_due.is_set()):
            received = link.recv(timeout_s=0.005)
            if received is not None:
                self._handle(link, received.message)
            now = time.monotonic()
            try:
                if now >= next_due["heartbeat"]:
                    next_due["heartbeat"] = now + 1.0
                    self.heartbeat_sent_s = now  # monotonic: tests time a change between two
                    link.send_heartbeat_vehicle(
                        armed=self.armed,
                        custom_mode=mode_number(self.mode, self.autopilot),
                        autopilot=self.autopilot,
                    )
                for msg, hz in list(self._rates_hz.items()):
                    if hz > 0 and now >= next_due.get(msg, 0.0):
                        next_due[msg] = now + 1.0 / hz
                        self._send_stream(link, msg)
            except OSError:
                return  # the client went away; listen again

    def _send_stream(self, link: MavLink, msg: int) -> None:
        boot_ms = self.time_boot_ms()
        state = self.state(time.time())
        if msg == message_id("ATTITUDE"):
            link.send_attitude(Attitude(boot_ms, state.roll, state.pitch, state.yaw, 0.0, 0.0, 0.0))
        elif msg == message_id("SCALED_PRESSURE2"):
            pressure_pa = self.pressure_pa(state)
            link.send_scaled_pressure2(
                time_boot_ms=boot_ms,
                press_abs_hpa=pressure_pa / 100.0,
                temperature_c=self.water_temperature_c,
            )
        elif msg == message_id("SYSTEM_TIME"):
            link.send_system_time(time_unix_usec=0, time_boot_ms=boot_ms)
        elif msg == message_id("GIMBAL_DEVICE_ATTITUDE_STATUS") and self.gimbal_pitch_rad:
            # As ArduPilot's mount library: the pitch against the horizon, the lock flags set.
            link.send_gimbal_attitude(
                time_boot_ms=boot_ms,
                pitch_rad=self.gimbal_pitch_rad(),
                horizon_relative=True,
                yaw_rad=0.0 if self.gimbal_yaw_rad is None else self.gimbal_yaw_rad(),
            )
        elif msg == message_id("SYS_STATUS"):
            link.send_sys_status(self.sys_status())
        elif msg == message_id("EKF_STATUS_REPORT"):
            link.send_ekf_status(
                EkfStatus(
                    EKF_HEALTHY_FLAGS,
                    pos_horiz_variance=self.pos_horiz_ratio(),
                    velocity_variance=0.05,
                    compass_variance=0.05,
                )
            )

    def sys_status(self) -> SysStatus:
        """External position: present once VISO_TYPE is set, healthy once it is in use."""
        vision = MAV_SYS_STATUS_SENSOR_VISION_POSITION
        present = vision if self.params.get("VISO_TYPE", 0.0) != 0.0 else 0
        with self.lock:
            last = self.recorded.estimates[-1][0] if self.recorded.estimates else None
        used = self.takes_estimates and last is not None and time.time() - last < VISO_TIMEOUT_S
        healthy = present if used else 0
        return SysStatus(present=present, enabled=present, health=healthy)

    def pressure_pa(self, state: VehicleState) -> float:
        """The Bar30's absolute pressure at the vehicle's true depth."""
        return self.air_pressure_pa + state.depth_m * RHO_G * self.params["BARO_SPEC_GRAV"]

    def pos_horiz_ratio(self) -> float:
        """The EKF's horizontal position test ratio, modelled (units of EKF_GATE_M squared).

        How far the estimates' motion strays from the vehicle's own over the last EKF_WINDOW_S.
        A constant offset is forgiven (the EKF takes it as the origin); a rotation (a wrong
        heading) or a scale error grows with the distance travelled, as EKF3's ratio does.
        """
        with self.lock:
            now = time.time()
            while self._innovations and now - self._innovations[0][0] > EKF_WINDOW_S:
                self._innovations.popleft()
            rows = list(self._innovations)
        if len(rows) < 5:
            return 0.05
        first = rows[0]
        squares = [
            ((n - first[1]) - (tn - first[3])) ** 2 + ((e - first[2]) - (te - first[4])) ** 2
            for _, n, e, tn, te in rows
        ]
        return max(0.05, (sum(squares) / len(squares)) / EKF_GATE_M**2)

    def _handle(self, link: MavLink, message: object) -> None:
        now = time.time()
        taken: PositionTarget | None = None  # ArduSub ignores targets outside GUIDED
        with self.lock:
            if isinstance(message, VisionPositionEstimate):
                self.recorded.estimates.append((now, message))
                truth = self.state(now)
                used = self.takes_estimates
                if used and truth.north_m is not None and truth.east_m is not None:
                    self._innovations.append(
                        (now, message.x, message.y, truth.north_m, truth.east_m)
                    )
            elif isinstance(message, GpsInput):
                self.recorded.gps_inputs.append((now, message))
            elif isinstance(message, StatusText):
                self.recorded.statustexts.append(message)
            elif isinstance(message, GlobalOrigin):
                self.recorded.origins.append(message)
                if self.origin is None and time.monotonic() - self._booted >= EKF_START_S:
                    self.origin = OriginReport(message.lat_e7, message.lon_e7, message.alt_mm)
            elif isinstance(message, Heartbeat):
                self.recorded.heartbeats += 1
            elif isinstance(message, PositionTarget):
                if self.autopilot == "ardurover" and self.origin is None:
                    self.recorded.targets_without_origin += 1
                elif self.mode == "GUIDED":
                    self.recorded.position_targets.append((now, message))
                    taken = message
                else:
                    self.recorded.targets_refused += 1
        if (
            isinstance(message, VisionPositionEstimate)
            and self.on_estimate is not None
            and self.takes_estimates
        ):
            self.on_estimate(message)
        if taken is not None and self.on_target is not None:
            self.on_target(taken)
        command = message.command if isinstance(message, CommandLong) else None
        if isinstance(message, CommandLong) and command == MAV_CMD_DO_SET_MODE:
            link.send_command_ack(command=message.command, result=self._set_mode(message, now))
        elif isinstance(message, CommandLong) and command == MAV_CMD_DO_SET_REVERSE:
            # ArduRover takes it in any mode (its GUIDED position targets then drive astern).
            rover = self.autopilot == "ardurover"
            if rover and self.on_direction is not None:
                self.on_direction("reverse" if message.params[0] == 1 else "forward")
            link.send_command_ack(
                command=message.command,
                result=MAV_RESULT_ACCEPTED if rover else MAV_RESULT_UNSUPPORTED,
            )
        elif isinstance(message, CommandLong) and command == MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW:
            # ArduPilot's mount takes it in any mode (the bridge sends it in GUIDED only).
            mounted = self.on_gimbal_pitch is not None
            if self.on_gimbal_pitch is not None:
                self.on_gimbal_pitch(message.params[0], message.params[1])
            link.send_command_ack(
                command=message.command,
                result=MAV_RESULT_ACCEPTED if mounted else MAV_RESULT_UNSUPPORTED,
            )
        elif isinstance(message, CommandLong) and command == MAV_CMD_REQUEST_MESSAGE:
            if int(message.params[0]) == message_id("GPS_GLOBAL_ORIGIN") and self.origin:
                link.send_origin_report(self.origin)
        elif isinstance(message, CommandLong) and command == MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN:
            # ArduPilot refuses to reboot an armed vehicle.
            rebooting = message.params[0] == 1 and not self.armed
            link.send_command_ack(
                command=message.command,
                result=MAV_RESULT_ACCEPTED if rebooting else MAV_RESULT_DENIED,
            )
            if rebooting:
                self._reboot_due.set()
        elif isinstance(message, CommandLong) and message.command == MAV_CMD_PREFLIGHT_CALIBRATION:
            if message.params[2] == 1:  # barometer: the pressure now becomes the surface's
                self.params["BARO2_GND_PRESS"] = self.pressure_pa(self.state(time.time()))
            link.send_command_ack(command=message.command, result=MAV_RESULT_ACCEPTED)
        elif isinstance(message, CommandLong) and message.command == MAV_CMD_SET_MESSAGE_INTERVAL:
            interval_us = message.params[1]
            self._rates_hz[int(message.params[0])] = (
                0.0 if interval_us < 0 else 1e6 / max(interval_us, 1.0)
            )
            link.send_command_ack(command=message.command, result=MAV_RESULT_ACCEPTED)
        elif isinstance(message, ParamRequest):
            names = sorted(self.params) if message.name is None else [message.name]
            for name in names:
                if name in self.params:
                    link.send_param_value(
                        name=name,
                        value=self.params[name],
                        index=sorted(self.params).index(name),
                        count=len(self.params),
                    )
        elif isinstance(message, ParamSet) and message.name in self.params:
            if math.isfinite(message.value):
                self.params[message.name] = message.value
            if message.name == "MNT1_TYPE" and message.value != 0.0:
                self.params = MOUNT_LISTED_PARAMS | self.params
            link.send_param_value(
                name=message.name,
                value=self.params[message.name],
                index=sorted(self.params).index(message.name),
                count=len(self.params),
            )

    def _set_mode(self, command: CommandLong, now: float) -> int:
        """MAV_CMD_DO_SET_MODE: position modes only with external positions arriving."""
        try:
            asked = mode_name(int(command.params[1]), self.autopilot)
        except (ValueError, OverflowError):
            return MAV_RESULT_DENIED
        if asked.startswith("MODE"):  # a number the autopilot has no mode for
            return MAV_RESULT_DENIED
        with self.lock:
            fresh = (
                self.takes_estimates
                and bool(self.recorded.estimates)
                and now - self.recorded.estimates[-1][0] < 1.0
            )
            taken = asked not in POSITION_MODES[self.autopilot] or fresh
            if taken:
                self.mode = asked
            self.recorded.modes.append((now, asked, taken))
        if taken and self.on_mode is not None:
            self.on_mode(asked)
        return MAV_RESULT_ACCEPTED if taken else MAV_RESULT_DENIED


def main(argv: list[str] | None = None) -> int:
    """`python -m capsd.simulator.autopilot --port P`: serve until SIGINT/SIGTERM, then report."""
    import argparse
    import signal

    parser = argparse.ArgumentParser(
        prog="python -m capsd.simulator.autopilot",
        description="An ArduSub stand-in on tcpin:127.0.0.1:PORT.",
    )
    parser.add_argument("--port", type=int, default=5777)
    parser.add_argument(
        "--setup",
        choices=["configured", "fresh"],
        default="configured",
        help="configured: set up for external position and rebooted (default); fresh: as "
        "delivered, what `capsd mav check --apply` fixes",
    )
    parser.add_argument(
        "--estimates-out",
        type=Path,
        default=None,
        help="write every VISION_POSITION_ESTIMATE received as a JSON line here on exit",
    )
    args = parser.parse_args(argv)
    stop = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: set_after_handler(stop))
    started = time.monotonic()
    params = CONFIGURED_PARAMS if args.setup == "configured" else DEFAULT_PARAMS
    with AutopilotStandIn(args.port, params=params) as autopilot:
        stop.wait()
        elapsed = time.monotonic() - started
        with autopilot.lock:
            estimates = list(autopilot.recorded.estimates)
            texts = [s.text for s in autopilot.recorded.statustexts]
    if args.estimates_out is not None:
        with args.estimates_out.open("w") as out:
            for arrival_s, e in estimates:
                out.write(json.dumps({"arrival_s": arrival_s, **asdict(e)}) + "\n")
    rate = len(estimates) / elapsed if elapsed > 0 else 0.0
    print(
        f"autopilot stand-in: {len(estimates)} VISION_POSITION_ESTIMATE in {elapsed:.0f} s "
        f"({rate:.1f}/s); STATUSTEXT: {texts}",
        flush=True,
    )
    if estimates:
        last = estimates[-1][1]
        print(
            f"  last: NED ({last.x:.3f}, {last.y:.3f}, {last.z:.3f}) m, "
            f"reset_counter {last.reset_counter}",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    import sys

    sys.exit(main())
