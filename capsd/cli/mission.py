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
