"""`capsd mav check|zero-depth`: the autopilot's side of the bridge."""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from capsd.cli.common import Subcommands, fail
from capsd.config import BusConfig
from capsd.errors import BusError, ConfigError
from capsd.launch import (
    EXIT_CONFIG,
    EXIT_FAILURE,
    positive_float,
)

if TYPE_CHECKING:  # the check needs the rov extra (pymavlink): imported where it runs
    from capsd.services.mav_bridge.check import MountRange


def _mav_tool(args: argparse.Namespace, tool: Callable[[Any], int]) -> int:
    """Run a `capsd mav` tool with the checks they share: the extra, the connection string."""
    try:
        from capsd.protocols.mavlink import check_connection
        from capsd.services.mav_bridge import check
    except ImportError as exc:  # the base install has no pymavlink: it comes with [rov]
        return fail(
            f"`capsd mav` needs the rov extra (pip install 'capsd[rov]'): {exc}", EXIT_FAILURE
        )
    try:
        check_connection(args.connect)
    except ConfigError as exc:
        return fail(str(exc), EXIT_CONFIG)
    try:
        return tool(check)
    except OSError as exc:
        return fail(f"MAVLink link {args.connect}: {exc}", EXIT_FAILURE)


def _delay_ms(text: str) -> float | str:
    return "auto" if text == "auto" else positive_float(text)


def _measured_delay_ms(args: argparse.Namespace) -> float | None:
    """The bridge's measured ping-to-autopilot median (its Health), rounded to 5 ms."""
    from capsd.bus import open_session
    from capsd.health import query_health
    from capsd.latency import percentile_ms

    try:
        with open_session(BusConfig(connect=(args.bus,), connect_timeout_s=2.0)) as session:
            health = query_health(
                session, site=args.site, vehicle=args.vehicle, service="mav_bridge"
            )
    except (BusError, ConfigError) as exc:
        print(f"VISO_DELAY_MS: no bus at {args.bus} ({exc})")
        return None
    stats = next((s for s in (health.latencies if health else ()) if s.name == "end to end"), None)
    median = percentile_ms(stats, 50) if stats is not None else None
    if median is None:
        print(f"VISO_DELAY_MS: no measured delay from the bridge on {args.bus}: not checked")
        return None
    wanted = max(5.0, 5.0 * round(median / 5.0))
    print(f"VISO_DELAY_MS: the bridge measures {median:.1f} ms ping to autopilot (median)")
    return wanted


def _estimates_arriving(args: argparse.Namespace) -> bool | None:
    """Whether the bridge on the bus is sending estimates now (its gate_sent counter grows)."""
    from capsd.bus import open_session
    from capsd.health import query_health

    try:
        with open_session(BusConfig(connect=(args.bus,), connect_timeout_s=2.0)) as session:
            sent = []
            for attempt in range(2):
                if attempt:
                    time.sleep(1.0)
                health = query_health(
                    session, site=args.site, vehicle=args.vehicle, service="mav_bridge"
                )
                if health is None:
                    return None
                sent.append(health.counters.get("gate_sent", 0))
    except (BusError, ConfigError):
        return None
    return sent[1] > sent[0]


# What each role's autopilot is, and the yaw its EKF should use by default: the ROV's compass;
# the ASV's scan-matched heading (a compass beside a steel tank wall is off).
_ROLE_AUTOPILOT: dict[str, Literal["ardusub", "ardurover"]] = {"rov": "ardusub", "asv": "ardurover"}
_ROLE_YAW: dict[str, Literal["compass", "vision"]] = {"rov": "compass", "asv": "vision"}


def _mount_range(args: argparse.Namespace) -> MountRange | None:
    """The mount pitches the follower's servo angles need, or None without a servo.

    From the ASV bridge's config (`sonar_tilt.zero_pitch_deg`) and the follower's (its sonar's
    `tilt` range): the files the ASV runs with, so the check and the services cannot disagree.
    A ConfigError names what is missing or wrong.
    """
    if args.bridge_config is None:
        if args.follow_config is not None:
            raise ConfigError(
                "--follow-config", "", "give the bridge's config too (--bridge-config)"
            )
        return None
    from capsd.config import load_config
    from capsd.services.asv_follow.service import Config as FollowConfig
    from capsd.services.mav_bridge.check import MountRange
    from capsd.services.mav_bridge.service import Config as BridgeConfig

    bridge = load_config(args.bridge_config, BridgeConfig)
    if bridge.sonar_tilt is None:
        return None  # a fixed sonar: no mount to check
    if args.follow_config is None:
        raise ConfigError(
            str(args.bridge_config),
            "sonar_tilt",
            "set: give the follower's config too (--follow-config): its sonar's `tilt` range "
            "is what the mount must allow",
        )
    follow = load_config(args.follow_config, FollowConfig)
    tilt = follow.sonar.tilt
    if tilt is None:
        raise ConfigError(
            str(args.follow_config),
            "sonar.tilt",
            f"not set, but {args.bridge_config} drives a tilt servo (`sonar_tilt`): the "
            "follower would never move it",
        )
    pan = follow.sonar.pan
    if (pan is not None) != (bridge.sonar_tilt.pan == "servo"):
        raise ConfigError(
            str(args.bridge_config),
            "sonar_tilt.pan",
            f"{bridge.sonar_tilt.pan!r}, but {args.follow_config}'s `sonar.pan` is "
            f"{'set' if pan is not None else 'not set'}: the bridge drives a pan servo exactly "
            "when the follower aims one",
        )
    return MountRange.of(
        zero_pitch_deg=bridge.sonar_tilt.zero_pitch_deg,
        tilt_min_deg=tilt.min_deg,
        tilt_max_deg=tilt.max_deg,
        pan_deg=None if pan is None else (pan.min_deg, pan.max_deg),
    )


def _cmd_mav_check(args: argparse.Namespace) -> int:
    if args.vehicle is None:
        args.vehicle = args.role
    if args.role != "asv" and (args.bridge_config or args.follow_config):
        return fail(
            "--bridge-config/--follow-config: the sonar's servo is on the ASV (--role asv)",
            EXIT_CONFIG,
        )
    try:
        mount = _mount_range(args)
    except ConfigError as exc:
        return fail(str(exc), EXIT_CONFIG)
    delay = _measured_delay_ms(args) if args.delay_ms == "auto" else float(args.delay_ms)
    return _mav_tool(
        args,
        lambda check: check.run_check(
            args.connect,
            apply=args.apply,
            yaw_source=args.yaw_source or _ROLE_YAW[args.role],
            autopilot=_ROLE_AUTOPILOT[args.role],
            max_speed_m_s=args.max_speed_m_s,
            position_noise_m=args.position_noise_m,
            delay_ms=delay,
            timeout_s=args.timeout,
            estimates_arriving=lambda: _estimates_arriving(args),
            reboot="when_pending" if args.reboot else "ask",
            mount=mount,
        ),
    )


def _cmd_mav_zero_depth(args: argparse.Namespace) -> int:
    return _mav_tool(
        args,
        lambda check: check.run_zero_depth(args.connect, apply=args.apply, timeout_s=args.timeout),
    )


def register(sub: Subcommands) -> None:
    """Add the mav verbs to the `capsd` parser's subcommands."""
    mav = sub.add_parser(
        "mav",
        help="ArduSub / ArduRover set-up tools",
        description="Tools that talk to the autopilot over MAVLink.",
    )
    mav_sub = mav.add_subparsers(dest="mav_command", required=True, metavar="TOOL")
    check = mav_sub.add_parser(
        "check",
        help="check (and --apply) ArduSub's (ArduRover's) parameters for external position",
        description="Read the autopilot's parameters, print what is wrong for CAP-SD's "
        "external position and the values to set; --apply sets them. Exit 0: all right; 1: "
        "parameters wrong; 3: a reboot is pending (a boot-time parameter changed, or estimates "
        "arrive and the autopilot does not use them).",
    )
    check.add_argument(
        "--connect",
        default="tcp:127.0.0.1:5777",
        help="MAVLink connection (default: BlueOS's tcp:127.0.0.1:5777)",
    )
    check.add_argument("--apply", action="store_true", help="set the wrong parameters")
    check.add_argument(
        "--reboot",
        action="store_true",
        help="reboot the autopilot (disarmed only) when a reboot is pending",
    )
    check.add_argument(
        "--role",
        choices=["rov", "asv"],
        default="rov",
        help="rov (default): ArduSub on the ROV; asv: ArduRover on the ASV, also how GUIDED "
        "drives to the follower's stations (WP_RADIUS, LOIT_RADIUS, WP_SPEED)",
    )
    check.add_argument(
        "--bridge-config",
        type=Path,
        default=None,
        help="--role asv: the ASV bridge's config; with its `sonar_tilt` set, also the "
        "mount (MNT1_TYPE servo, MNT1_PITCH_MIN/MAX wide enough, a SERVOn_FUNCTION 7)",
    )
    check.add_argument(
        "--follow-config",
        type=Path,
        default=None,
        help="--role asv with a tilt servo: the follower's config (its sonar's `tilt` range)",
    )
    check.add_argument(
        "--yaw-source",
        choices=["compass", "vision"],
        default=None,
        help="EK3 yaw source: the compass (1) or the yaw CAP-SD sends (6); default: compass "
        "for the rov, vision for the asv",
    )
    check.add_argument(
        "--max-speed-m-s",
        type=positive_float,
        default=0.5,
        help="--role asv: WP_SPEED at most this (the follower's motion.max_speed_m_s)",
    )
    check.add_argument(
        "--position-noise-m",
        type=float,
        default=0.05,
        help="VISO_POS_M_NSE should be at most this (metres)",
    )
    check.add_argument(
        "--delay-ms",
        type=_delay_ms,
        default="auto",
        help="wanted VISO_DELAY_MS, or 'auto' (default): the bridge's measured ping-to-"
        "autopilot median from its Health on the bus (--bus), rounded to 5 ms",
    )
    check.add_argument(
        "--bus",
        default="tcp/127.0.0.1:7447",
        help="Zenoh endpoint where the bridge's Health is (--delay-ms auto; whether "
        "estimates are arriving)",
    )
    check.add_argument("--site", default="tank", help="site of the bridge (--delay-ms auto)")
    check.add_argument(
        "--vehicle", default=None, help="vehicle of the bridge (--delay-ms auto): the role's name"
    )
    check.add_argument(
        "--timeout", type=positive_float, default=5.0, help="seconds to wait for answers"
    )
    check.set_defaults(func=_cmd_mav_check)
    zero = mav_sub.add_parser(
        "zero-depth",
        help="show the depth the vehicle reads; at the surface, --apply makes it 0",
        description="Depth is measured from the pressure at the autopilot's boot "
        "(BARO2_GND_PRESS): a vehicle booted under water reads shallow. At the surface, "
        "--apply asks the autopilot to take the pressure now as the surface's "
        "(MAV_CMD_PREFLIGHT_CALIBRATION, barometer); the bridge picks it up within 10 s.",
    )
    zero.add_argument(
        "--connect",
        default="tcp:127.0.0.1:5777",
        help="MAVLink connection (default: BlueOS's tcp:127.0.0.1:5777)",
    )
    zero.add_argument("--apply", action="store_true", help="take the pressure now as 0 m")
    zero.add_argument(
        "--timeout", type=positive_float, default=5.0, help="seconds to wait for answers"
    )
    zero.set_defaults(func=_cmd_mav_zero_depth)
