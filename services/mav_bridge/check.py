"""`capsd mav check`: read ArduSub's parameters, say what is wrong for external position, fix it.

The values (FIELD-NOTES, ArduSub 4.5-4.7): VISO_TYPE=1 (MAVLink; takes effect after a reboot),
EK3_SRC1_POSXY=6 (ExternalNav), EK3_SRC1_VELXY=0, EK3_SRC1_POSZ=1 (baro: the Bar30),
EK3_SRC1_YAW=1 (compass) or 6 (the yaw we send), GPS1_TYPE=0 (GPS_TYPE before 4.6),
VISO_POS_M_NSE at most our position noise (it is a floor), VISO_DELAY_MS near our latency.
ArduRover (the ASV, `--role asv`) also: WP_RADIUS at most 0.2 m (GUIDED calls a position target
reached this near and stops steering for it: 2 m by default, so a follower's station ends up to
2 m off and the bridge's turn to the station's heading, within 0.3 m, never comes), LOIT_RADIUS
at most 0.3 m (a boat at its target drifts freely this far: 2 m by default), WP_SPEED at most
the follower's speed (2 m/s by default). Found with ArduRover SITL (README). With the sonar on a
tilt servo (the bridge's `sonar_tilt`): MNT1_TYPE=1 (servo; read at boot), MNT1_PITCH_MIN and
MNT1_PITCH_MAX wide enough for every angle the follower may ask (the servo's range about the
bridge's `zero_pitch_deg`), and one servo output driving the mount's tilt (SERVOn_FUNCTION=7).
Which output the servo is wired to, and the pitch limits (a servo mount maps them onto the
output's pulse range: they are the servo's measured calibration), are for a person to set:
this check says what they must allow and never --apply's them.

VISO_TYPE and GPS1_TYPE are read at boot only. Whether the running firmware uses what the
parameters say is the autopilot's own state: its SYS_STATUS reports external position healthy
only when the backend made at boot has an estimate within 300 ms. So a reboot is pending when
this run changed a boot parameter, or when the parameters are right and estimates are arriving
(the bridge says so) but the autopilot does not report them healthy. Exit codes: 0 all right,
1 wrong (or unreadable), 3 reboot pending (`--reboot` reboots a disarmed autopilot).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal, TextIO

from capsd.protocols.mavlink import (
    MAV_CMD_PREFLIGHT_CALIBRATION,
    MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN,
    MAV_RESULT_ACCEPTED,
    MAV_SYS_STATUS_SENSOR_VISION_POSITION,
    Autopilot,
    CommandAck,
    Heartbeat,
    MavLink,
    ParamValue,
    ScaledPressure,
    SysStatus,
    SystemTime,
    message_id,
)

YawSource = Literal["compass", "vision"]
RebootChoice = Literal["ask", "when_pending"]
# Parameters ArduPilot reads at boot only (RebootRequired in its parameter documentation).
BOOT_PARAMS = frozenset({"VISO_TYPE", "GPS1_TYPE", "GPS_TYPE", "MNT1_TYPE"})
# A boot parameter's family, which ArduPilot lists only once it is set (and booted).
_LISTED_AFTER = {"VISO_TYPE": "VISO_", "MNT1_TYPE": "MNT1_"}
Bound = Literal["equal", "at_most", "at_least", "any_equal"]
Fix = Literal["apply", "by_hand"]
EXIT_REBOOT_PENDING = 3

_GCS_SYSTEM = 255
_GCS_COMPONENT = 190  # MAV_COMP_ID_MISSIONPLANNER: a ground-station identity


@dataclass(frozen=True)
class Rule:
    """One parameter, the value it should have, and why; `tolerance` allows a band.

    `bound` at_most / at_least: the value may also be lower / higher; any_equal: one of
    `names` (all read) has the value, shown under `label`. `fix` by_hand: --apply leaves it
    to a person (a wiring or a calibration the check cannot know).
    """

    names: tuple[str, ...]  # the first one the vehicle has is used (renamed across versions)
    wanted: float
    why: str
    tolerance: float = 0.0
    bound: Bound = "equal"
    label: str | None = None  # any_equal: the name shown (e.g. SERVOn_FUNCTION)
    fix: Fix = "apply"


@dataclass(frozen=True)
class Finding:
    name: str
    current: float | None
    wanted: float
    ok: bool
    why: str
    bound: Bound = "equal"
    fix: Fix = "apply"

    @property
    def settable(self) -> bool:
        """Whether --apply may set it."""
        return self.fix == "apply"


@dataclass(frozen=True)
class MountRange:
    """The mount pitches (MAVLink's: up +, degrees) the follower's servo angles need.

    With a pan servo, the yaws too (MAVLink's: the vehicle's frame, right +, degrees: the pan
    is left +).
    """

    lowest_deg: float  # the servo's furthest tilt down: zero_pitch_deg - tilt max_deg
    highest_deg: float  # its furthest up: zero_pitch_deg - tilt min_deg
    yaws_deg: tuple[float, float] | None = None  # the pan's furthest right, left; None: no pan

    @staticmethod
    def of(
        *,
        zero_pitch_deg: float,
        tilt_min_deg: float,
        tilt_max_deg: float,
        pan_deg: tuple[float, float] | None = None,
    ) -> MountRange:
        """`pan_deg`: the pan servo's (min, max), left +; None without one."""
        yaws = None if pan_deg is None else (-pan_deg[1], -pan_deg[0])
        return MountRange(zero_pitch_deg - tilt_max_deg, zero_pitch_deg - tilt_min_deg, yaws)


MOUNT_TYPE_SERVO = 1  # MNT1_TYPE
SERVO_FUNCTION_MOUNT_TILT = 7  # SERVOn_FUNCTION: "Mount1Pitch" (mount tilt)
SERVO_FUNCTION_MOUNT_PAN = 6  # SERVOn_FUNCTION: "Mount1Yaw" (mount pan)
SERVO_OUTPUTS = 16


# ArduRover: GUIDED stops steering for a target this near (its WP_RADIUS), and the bridge turns
# the ASV to its station's heading once within 0.3 m (`heading_only_within_m`): below that.
ASV_ARRIVE_WITHIN_M = 0.2
# A boat at its GUIDED target drifts freely within LOIT_RADIUS before it drives back.
ASV_LOITER_WITHIN_M = 0.3


def _servo_axis_rules(
    axis: Literal["PITCH", "YAW"],
    limits_deg: tuple[float, float],
    function: int,
    *,
    what: tuple[str, str],
    reach: tuple[str, str],
    label: str,
) -> list[Rule]:
    """One axis of a servo mount: MNT1_<axis>_MIN at most, _MAX at least, and its output.

    A servo mount maps MNT1_<axis>_MIN..MAX onto its output's SERVOn_MIN..MAX pulses: they are
    the servo's calibration, which a person measures; and which output drives which axis only a
    person knows: never --apply'd.
    """
    angle, servo = what
    return [
        Rule(
            (f"MNT1_{axis}_MIN",),
            round(limits_deg[0], 2),
            f"the {angle} at its lowest pulse, as measured: it must reach {reach[0]}, or "
            f"narrow the {servo}",
            bound="at_most",
            fix="by_hand",
        ),
        Rule(
            (f"MNT1_{axis}_MAX",),
            round(limits_deg[1], 2),
            f"the {angle} at its highest pulse, as measured: it must reach {reach[1]}, or "
            f"narrow the {servo}",
            bound="at_least",
            fix="by_hand",
        ),
        Rule(
            tuple(f"SERVO{n}_FUNCTION" for n in range(1, SERVO_OUTPUTS + 1)),
            function,
            f"the output the {servo} servo is wired to drives the mount's {servo}",
            bound="any_equal",
            label=label,
            fix="by_hand",
        ),
    ]


def rules(
    *,
    yaw_source: YawSource,
    position_noise_m: float,
    delay_ms: float | None,
    autopilot: Autopilot = "ardusub",
    max_speed_m_s: float = 0.5,
    mount: MountRange | None = None,
) -> list[Rule]:
    """The parameter rules; VISO_DELAY_MS only when the delay is known (measured or given).

    `autopilot` ardurover (the ASV): also how GUIDED drives to the follower's stations, with
    `max_speed_m_s` the follower's speed, and with `mount` the sonar's tilt servo.
    """
    rov = autopilot == "ardusub"
    out = [
        Rule(("VISO_TYPE",), 1, "external position over MAVLink (reboot needed)"),
        Rule(("EK3_SRC1_POSXY",), 6, "horizontal position from ExternalNav (CAP-SD)"),
        Rule(("EK3_SRC1_VELXY",), 0, "no horizontal velocity source: CAP-SD sends positions"),
        Rule(
            ("EK3_SRC1_POSZ",),
            1,
            "depth from the barometer (the Bar30)" if rov else "height from the barometer",
        ),
        Rule(
            ("EK3_SRC1_YAW",),
            1 if yaw_source == "compass" else 6,
            "yaw from the compass" if yaw_source == "compass" else "yaw from the estimates",
        ),
        Rule(("GPS1_TYPE", "GPS_TYPE"), 0, "no GPS underwater" if rov else "no GPS indoors"),
        Rule(
            ("VISO_POS_M_NSE",),
            position_noise_m,
            "the EKF's floor on position noise: at most CAP-SD's",
            bound="at_most",
        ),
    ]
    if delay_ms is not None:
        out.append(Rule(("VISO_DELAY_MS",), delay_ms, "measured latency", tolerance=5.0))
    if not rov:
        out += [
            Rule(
                ("WP_RADIUS",),
                ASV_ARRIVE_WITHIN_M,
                "GUIDED stops this near a station (then the bridge turns it to its heading)",
                bound="at_most",
            ),
            Rule(
                ("LOIT_RADIUS",),
                ASV_LOITER_WITHIN_M,
                "a boat drifts this far from its station before it drives back",
                bound="at_most",
            ),
            Rule(("WP_SPEED",), max_speed_m_s, "GUIDED's speed: the follower's", bound="at_most"),
        ]
    if not rov and mount is not None:
        out += [
            Rule(("MNT1_TYPE",), MOUNT_TYPE_SERVO, "the sonar's tilt servo (reboot needed)"),
            *_servo_axis_rules(
                "PITCH",
                (mount.lowest_deg, mount.highest_deg),
                SERVO_FUNCTION_MOUNT_TILT,
                what=("servo's pitch", "tilt"),
                reach=(
                    "the follower's furthest tilt down (sonar_tilt zero less tilt max_deg)",
                    "the furthest tilt up (zero less tilt min_deg)",
                ),
                label="SERVOn_FUNCTION",
            ),
        ]
    if not rov and mount is not None and mount.yaws_deg is not None:
        out += _servo_axis_rules(
            "YAW",
            mount.yaws_deg,
            SERVO_FUNCTION_MOUNT_PAN,
            what=("pan servo's yaw", "pan"),
            reach=(
                "the follower's furthest pan right (less the pan's max_deg)",
                "the furthest pan left (less the pan's min_deg)",
            ),
            label="SERVOn_FUNCTION (pan)",
        )
    return out


def _read(
    link: MavLink, target: int, wanted: Sequence[tuple[str, ...]], timeout_s: float
) -> dict[str, float]:
    """Ask for each wanted parameter by name (twice at most); return those the vehicle answered.

    Each entry of `wanted` is one parameter under each firmware's name (GPS1_TYPE or GPS_TYPE),
    and an autopilot does not answer for a name it lacks: the read is complete once each entry
    has an answer, instead of waiting out the timeout for names this firmware does not have.
    """
    names = [n for group in wanted for n in group]
    values: dict[str, float] = {}

    def complete() -> bool:
        return all(any(n in values for n in group) for group in wanted)

    for _attempt in range(2):
        for name in names:
            if name not in values:
                link.send_param_request_read(target_system=target, name=name)
        deadline = time.monotonic() + timeout_s / 2
        while time.monotonic() < deadline and not complete():
            received = link.recv(timeout_s=0.1)
            if received is not None and isinstance(received.message, ParamValue):
                values[received.message.name] = received.message.value
        if complete():
            break
    return values


def _wait_heartbeat(link: MavLink, timeout_s: float) -> int | None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        received = link.recv(timeout_s=0.2)
        if (
            received is not None
            and isinstance(received.message, Heartbeat)
            and (received.component_id == 1)
        ):
            return received.system_id
    return None


class _Autopilot:
    """A ground-station link to the autopilot, and its system id once it has heartbeat."""

    def __init__(self, connection: str, *, timeout_s: float, out: TextIO):
        self.link = MavLink(connection, system_id=_GCS_SYSTEM, component_id=_GCS_COMPONENT)
        self.timeout_s = timeout_s
        self.out = out

    def __enter__(self) -> tuple[MavLink, int | None]:
        self.link.open()
        self.link.send_heartbeat_onboard()
        target = _wait_heartbeat(self.link, self.timeout_s)
        if target is None:
            print(
                f"no autopilot HEARTBEAT on {self.link.connection} within {self.timeout_s:.0f} s",
                file=self.out,
            )
        return self.link, target

    def __exit__(self, *_exc: object) -> None:
        self.link.close()


def evaluate(values: dict[str, float], checks: list[Rule]) -> list[Finding]:
    findings = []
    for rule in checks:
        if rule.bound == "any_equal":
            found = [n for n in rule.names if values.get(n) == rule.wanted]
            name = found[0] if found else (rule.label or rule.names[0])
            current = rule.wanted if found else None
            findings.append(
                Finding(name, current, rule.wanted, bool(found), rule.why, rule.bound, rule.fix)
            )
            continue
        name = next((n for n in rule.names if n in values), rule.names[0])
        current = values.get(name)
        if current is None:
            ok = False
        elif rule.bound == "at_most":
            ok = current <= rule.wanted + 1e-6
        elif rule.bound == "at_least":
            ok = current >= rule.wanted - 1e-6
        else:
            ok = abs(current - rule.wanted) <= rule.tolerance + 1e-6
        findings.append(Finding(name, current, rule.wanted, ok, rule.why, rule.bound, rule.fix))
    return findings


def _groups(checks: list[Rule]) -> list[tuple[str, ...]]:
    """What `_read` asks for: one group per rule, each name its own for an any_equal rule."""
    out: list[tuple[str, ...]] = []
    for rule in checks:
        out += [(n,) for n in rule.names] if rule.bound == "any_equal" else [rule.names]
    return out


def _names(findings: list[Finding]) -> str:
    return ", ".join(f.name for f in findings)


def run_check(
    connection: str,
    *,
    apply: bool,
    yaw_source: YawSource = "compass",
    position_noise_m: float = 0.05,
    delay_ms: float | None = 50.0,
    timeout_s: float = 5.0,
    estimates_arriving: Callable[[], bool | None] = lambda: None,
    reboot: RebootChoice = "ask",
    autopilot: Autopilot = "ardusub",
    max_speed_m_s: float = 0.5,
    mount: MountRange | None = None,
    out: TextIO = sys.stdout,
) -> int:
    """Print the findings (and fix them with `apply`); the exit code (module docstring).

    `estimates_arriving`: whether estimates reach the autopilot now (the bridge's word), None
    when unknown. `reboot`: when_pending reboots a disarmed autopilot whose reboot is pending.
    """
    checks = rules(
        yaw_source=yaw_source,
        position_noise_m=position_noise_m,
        delay_ms=delay_ms,
        autopilot=autopilot,
        max_speed_m_s=max_speed_m_s,
        mount=mount,
    )
    with _Autopilot(connection, timeout_s=timeout_s, out=out) as (link, target):
        if target is None:
            return 1
        values = _read(link, target, _groups(checks), timeout_s)
        findings = evaluate(values, checks)
        _print(findings, out)
        wrong = [f for f in findings if not f.ok]
        by_hand = [f for f in wrong if not f.settable]
        if wrong and not apply:
            print(
                f"{len(wrong)} parameter(s) to change; run again with --apply to set them"
                + (f" ({_names(by_hand)} by hand)." if by_hand else "."),
                file=out,
            )
            return 1
        changed_at_boot = sorted(f.name for f in wrong if f.name in BOOT_PARAMS)
        if any(f.settable for f in wrong):
            for finding in wrong:
                if finding.settable:
                    link.send_param_set(
                        target_system=target, name=finding.name, value=finding.wanted
                    )
            after = evaluate(_read(link, target, _groups(checks), timeout_s), checks)
            print("after --apply:", file=out)
            _print(after, out)
            # ArduPilot lists a family (the other VISO_*, MNT1_*) only once its type is set:
            # not in this read.
            prefixes = tuple(_LISTED_AFTER[p] for p in changed_at_boot if p in _LISTED_AFTER)
            waiting = [
                f
                for f in after
                if not f.ok and f.current is None and prefixes and f.name.startswith(prefixes)
            ]
            still = [f for f in after if not f.ok and f.settable and f not in waiting]
            by_hand = [f for f in after if not f.ok and not f.settable and f not in waiting]
            if still:
                print(f"{len(still)} parameter(s) could not be set.", file=out)
                return 1
            print("Parameters set.", file=out)
            if waiting:
                types = ", ".join(p for p in changed_at_boot if p in _LISTED_AFTER)
                print(
                    f"{_names(waiting)}: not listed yet (ArduPilot lists them once {types} is "
                    "set); run this check again, with --apply if it says CHANGE.",
                    file=out,
                )
        if by_hand:
            print(
                f"{_names(by_hand)}: only a person can set these (a wiring or a measured "
                "calibration: see WHY); set them, then run this check again"
                + (" (after the reboot a boot parameter needs)." if changed_at_boot else "."),
                file=out,
            )
            return 1
        pending = _reboot_pending(
            link, target, changed_at_boot, estimates_arriving, timeout_s=timeout_s, out=out
        )
        if not pending:
            return 0
        if reboot == "when_pending":
            return _reboot(link, target, timeout_s=timeout_s, out=out)
        print(
            "Reboot the autopilot (disarmed; `capsd mav check --reboot` does it), then run "
            "this check again.",
            file=out,
        )
        return EXIT_REBOOT_PENDING


def _reboot_pending(
    link: MavLink,
    target: int,
    changed_at_boot: list[str],
    estimates_arriving: Callable[[], bool | None],
    *,
    timeout_s: float,
    out: TextIO,
) -> bool:
    """Say whether the running firmware uses the parameters; True when a reboot is pending."""
    boot_names = ", ".join(sorted(BOOT_PARAMS - {"GPS_TYPE"}))
    if changed_at_boot:
        print(
            f"REBOOT PENDING: {', '.join(changed_at_boot)} changed now; the autopilot reads "
            f"{boot_names} at boot only.",
            file=out,
        )
        return True
    status, uptime_s = _status_and_uptime(link, target, timeout_s)
    vision = None if status is None else status.sensor(MAV_SYS_STATUS_SENSOR_VISION_POSITION)
    if vision == "healthy":
        print("External position in use: the autopilot takes CAP-SD's estimates.", file=out)
        return False
    arriving = estimates_arriving()
    since_boot = "" if uptime_s is None else f" (it booted {uptime_s / 60:.1f} min ago)"
    if arriving and status is not None:
        print(
            f"REBOOT PENDING: the parameters are right and estimates are arriving, but the "
            f"autopilot reports external position {vision}{since_boot}: it reads {boot_names} "
            "at boot only.",
            file=out,
        )
        return True
    why = (
        "no SYS_STATUS from the autopilot"
        if status is None
        else "no estimates arriving (is the bridge running?)"
    )
    print(
        f"Parameters right; not verified that the autopilot uses them: {why}. If {boot_names} "
        f"changed since the autopilot booted{since_boot}, reboot it.",
        file=out,
    )
    return False


def _status_and_uptime(
    link: MavLink, target: int, timeout_s: float
) -> tuple[SysStatus | None, float | None]:
    """The autopilot's SYS_STATUS and seconds since boot (SYSTEM_TIME), asked for at 2 Hz."""
    for name in ("SYS_STATUS", "SYSTEM_TIME"):
        link.send_set_message_interval(
            target_system=target, message_id=message_id(name), rate_hz=2.0
        )
    status: SysStatus | None = None
    uptime_s: float | None = None
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and (status is None or uptime_s is None):
        received = link.recv(timeout_s=0.2)
        message = None if received is None else received.message
        if isinstance(message, SysStatus):
            status = message
        elif isinstance(message, SystemTime):
            uptime_s = message.time_boot_ms / 1000.0
    return status, uptime_s


def _wait_ack(link: MavLink, command: int, timeout_s: float) -> int | None:
    """The result of the autopilot's COMMAND_ACK for `command`, None if none came in time."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        received = link.recv(timeout_s=0.2)
        ack = None if received is None else received.message
        if isinstance(ack, CommandAck) and ack.command == command:
            return ack.result
    return None


def _reboot(link: MavLink, target: int, *, timeout_s: float, out: TextIO) -> int:
    """Reboot the autopilot and wait for it to come back; 0 when it did."""
    _status, up_before_s = _status_and_uptime(link, target, timeout_s)
    link.send_reboot(target_system=target)
    result = _wait_ack(link, MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, timeout_s)
    if result != MAV_RESULT_ACCEPTED:
        print(
            f"the autopilot refused to reboot (result {result}; ArduPilot refuses when armed)",
            file=out,
        )
        return EXIT_REBOOT_PENDING
    print("rebooting the autopilot ...", file=out)
    back = _back_after_reboot(link, target, up_before_s, timeout_s=timeout_s * 6, out=out)
    return 0 if back else 1


def _back_after_reboot(
    link: MavLink, target: int, up_before_s: float | None, *, timeout_s: float, out: TextIO
) -> bool:
    """Reconnect until the autopilot answers again with a boot time later than before."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        time.sleep(0.5)
        try:
            link.close()
            link.open()
            link.send_heartbeat_onboard()
            _status, uptime_s = _status_and_uptime(link, target, 2.0)
        except OSError:
            continue
        if uptime_s is not None and (up_before_s is None or uptime_s < up_before_s):
            print(f"the autopilot is back (up {uptime_s:.1f} s); run this check again", file=out)
            return True
    print(f"the autopilot did not come back within {timeout_s:.0f} s", file=out)
    return False


_BOUND_MARK: dict[Bound, str] = {"equal": "", "at_most": "<=", "at_least": ">=", "any_equal": ""}


def _print(findings: list[Finding], out: TextIO) -> None:
    print(f"{'PARAMETER':<16} {'NOW':>8} {'WANTED':>8}  STATUS   WHY", file=out)
    for f in findings:
        now = "absent" if f.current is None else f"{f.current:g}"
        if f.bound == "any_equal" and f.current is None:
            now = "none"
        status = "ok" if f.ok else "CHANGE"
        wanted = f"{_BOUND_MARK[f.bound]}{f.wanted:g}"
        print(f"{f.name:<16} {now:>8} {wanted:>8}  {status:<7}  {f.why}", file=out)


RHO_G = 1000.0 * 9.80665  # fresh water; the depth shown uses BARO_SPEC_GRAV


def _pressure_now(link: MavLink, target: int, timeout_s: float) -> float | None:
    """The Bar30's absolute pressure (Pa) from SCALED_PRESSURE2, asked for at 5 Hz."""
    link.send_set_message_interval(
        target_system=target, message_id=message_id("SCALED_PRESSURE2"), rate_hz=5.0
    )
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        received = link.recv(timeout_s=0.2)
        message = None if received is None else received.message
        if isinstance(message, ScaledPressure) and message.instance == 2:
            return message.press_abs_hpa * 100.0
    return None


def run_zero_depth(
    connection: str, *, apply: bool, timeout_s: float = 5.0, out: TextIO = sys.stdout
) -> int:
    """Show the depth the vehicle reads now; with `apply` make the pressure now the surface's.

    Depth is measured from BARO2_GND_PRESS, the pressure at the autopilot's boot: a vehicle
    that booted under water reads shallow all dive. At the surface, `--apply` sends
    MAV_CMD_PREFLIGHT_CALIBRATION (barometer), after which depth reads 0 there.
    """
    with _Autopilot(connection, timeout_s=timeout_s, out=out) as (link, target):
        if target is None:
            return 1
        values = _read(link, target, [("BARO2_GND_PRESS",), ("BARO_SPEC_GRAV",)], timeout_s)
        pressure = _pressure_now(link, target, timeout_s)
        surface = values.get("BARO2_GND_PRESS")
        if pressure is None or surface is None:
            print("no SCALED_PRESSURE2 or BARO2_GND_PRESS from the autopilot", file=out)
            return 1
        rho_g = RHO_G * values.get("BARO_SPEC_GRAV", 1.0)
        print(
            f"surface pressure in use {surface:.0f} Pa, now {pressure:.0f} Pa: the vehicle reads "
            f"{(pressure - surface) / rho_g:+.3f} m deep",
            file=out,
        )
        if not apply:
            print("at the surface, run again with --apply to take this pressure as 0 m", file=out)
            return 0
        link.send_calibrate_surface_pressure(target_system=target)
        result = _wait_ack(link, MAV_CMD_PREFLIGHT_CALIBRATION, timeout_s)
        if result != MAV_RESULT_ACCEPTED:
            print(f"the autopilot did not accept the calibration (result {result})", file=out)
            return 1
        after = _read(link, target, [("BARO2_GND_PRESS",)], timeout_s).get("BARO2_GND_PRESS")
        if after is None:
            print("calibrated, but BARO2_GND_PRESS could not be read back", file=out)
            return 1
        print(
            f"surface pressure now {after:.0f} Pa: the vehicle reads "
            f"{(pressure - after) / rho_g:+.3f} m deep (the bridge picks it up within 10 s)",
            file=out,
        )
        return 0
