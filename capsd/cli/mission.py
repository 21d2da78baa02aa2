"""`capsd mission run PLAN.yaml`: fly a plan of waypoints on CAP-SD fixes through the bridge."""

from __future__ import annotations

import argparse
import sys
from datetime import UTC, datetime
from pathlib import Path

from capsd.cli.common import Subcommands, fail, guarded
from capsd.errors import ConfigError
from capsd.launch import (
    EXIT_CONFIG,
    add_bus_flags,
    add_namespace_flags,
    service_config_from_args,
)

DEFAULT_LOCATOR_CONFIG = Path("deploy/config/locator.yaml")


def _cmd_mission_run(args: argparse.Namespace) -> int:
    from capsd.mission import node

    try:
        config = service_config_from_args(node.Config, args)
    except ConfigError as exc:
        return fail(str(exc), EXIT_CONFIG)
    out = args.out or Path("reports") / datetime.now(UTC).strftime("mission-%Y%m%d-%H%M%S")
    return guarded(
        lambda: node.main(
            config,
            plan_path=args.plan,
            locator_config=args.locator_config,
            out=out,
            stream=sys.stdout,
        )
    )


DEFAULT_FOLLOW_CONFIG = Path("deploy/config/asv_follow.yaml")


def _cmd_mission_check(args: argparse.Namespace) -> int:
    import msgspec

    from capsd.config import load_config
    from capsd.mission import check
    from capsd.services.asv_follow.service import Config as FollowConfig

    try:
        if args.tank is not None:
            from capsd.harness import SonarTilt, follow_config

            tilt: SonarTilt = args.sonar_tilt or "fixed"
            config = follow_config(args.tank, tilt=tilt)
            source = f"the demo's for the simulated {args.tank} tank"
            if tilt != "fixed":
                source += (
                    f", the sonar on {'a tilt servo' if tilt == 'servo' else 'pan-tilt servos'}"
                )
        elif args.sonar_tilt is not None:
            return fail(
                "--sonar-tilt goes with --tank (a site's follower config says its mount: `sonar`)",
                EXIT_CONFIG,
            )
        else:
            config = load_config(args.follow_config, FollowConfig)
            source = str(args.follow_config)
        if args.sonar_pitch is not None:
            sonar = msgspec.structs.replace(config.sonar, pitch_deg=args.sonar_pitch)
            config = msgspec.structs.replace(config, sonar=sonar)
            source += f", the sonar's pitch set to {args.sonar_pitch:g} deg"
    except ConfigError as exc:
        return fail(str(exc), EXIT_CONFIG)
    return guarded(
        lambda: check.main(
            config,
            plan_path=args.plan,
            png=args.png,
            stream=sys.stdout,
            source=source,
            json_out=args.json,
        )
    )


def _pitch_deg(text: str) -> float:
    value = float(text)
    if not 0.0 < value < 90.0:
        raise argparse.ArgumentTypeError(f"{text}: a pitch down between 0 and 90 deg")
    return value


def register(sub: Subcommands) -> None:
    """Add the mission verbs to the `capsd` parser's subcommands."""
    mission = sub.add_parser("mission", help="ROV missions on CAP-SD fixes (GUIDED via the bridge)")
    verbs = mission.add_subparsers(dest="mission_command", required=True, metavar="VERB")
    run = verbs.add_parser(
        "run",
        help="fly a plan (lawnmower or inspection points); Ctrl-C leaves the ROV holding",
        description="Read the fixes and the vehicle's mode from the bus and put signed "
        "commands for the ROV's bridge (which needs `mission_commands: accept`): GUIDED "
        "targets waypoint by waypoint, POSHOLD when the fix is lost or unsure (resumed once "
        "it is good again), a last POSHOLD on Ctrl-C; the pilot's mode change ends the "
        "mission. Writes mission.json and mission.png (planned against flown).",
    )
    run.add_argument("plan", type=Path, help="the plan (YAML: `lawnmower:` or `points:`)")
    run.add_argument("--config", type=Path, default=None, help="the mission's bus config (YAML)")
    run.add_argument(
        "--locator-config",
        type=Path,
        default=DEFAULT_LOCATOR_CONFIG,
        help="the site's locator config: the tank (geofence) and the fix key that signs commands",
    )
    run.add_argument("--out", type=Path, default=None, help="report folder (reports/mission-TIME)")
    add_namespace_flags(run)
    add_bus_flags(run)
    run.set_defaults(func=_cmd_mission_run)
    check = verbs.add_parser(
        "check",
        help="before a dive: can the follower keep the plan in view, with how many stops",
        description="For every point of the plan's path (sampled finely), the places the ASV "
        "may be (as far from walls and keep-out boxes as the follower's stations) whose view, "
        "the hull turned to face it, the follower calls good; per leg the share seen, and seen "
        "with no fixture, floor or wall in the ROV's range cell; what no place sees; and the "
        "fewest ASV stops that keep it in view by turning alone (each move between them is a "
        "move a steered hull may make blind). Exit 0 when every point is seen, 1 when not.",
    )
    check.add_argument("plan", type=Path, help="the plan (YAML: `lawnmower:` or `points:`)")
    where = check.add_mutually_exclusive_group()
    where.add_argument(
        "--follow-config",
        type=Path,
        default=DEFAULT_FOLLOW_CONFIG,
        help="the site's follower config: tank, sonar mount, station rules (default: %(default)s)",
    )
    where.add_argument(
        "--tank",
        choices=("nfp", "mockup", "pond"),
        default=None,
        help="instead: the demo's follower settings for a simulated tank",
    )
    check.add_argument(
        "--sonar-tilt",
        choices=("fixed", "servo", "pan-tilt"),
        default=None,
        help="with --tank: the demo's sonar fixed (default), on a tilt servo, or on pan-tilt "
        "servos (as `capsd demo --sonar-tilt`; a servo widens where the ASV can watch from)",
    )
    check.add_argument(
        "--sonar-pitch",
        type=_pitch_deg,
        default=None,
        metavar="DEG",
        help="try the sonar pitched this far down instead of the config's",
    )
    check.add_argument("--png", type=Path, default=None, help="also draw the check (PNG)")
    check.add_argument(
        "--json",
        type=Path,
        default=None,
        help="also write the check as JSON (the path, what sees each point, the stops, the "
        "least blind route's station for every point)",
    )
    check.set_defaults(func=_cmd_mission_check)
