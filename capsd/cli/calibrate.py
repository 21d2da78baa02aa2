"""`capsd calibrate RECORDING`: the sonar mount from a recording."""

from __future__ import annotations

import argparse
from pathlib import Path

from capsd.cli.common import Subcommands, fail
from capsd.errors import CapsdError
from capsd.launch import (
    EXIT_CONFIG,
    EXIT_FAILURE,
    EXIT_OK,
)


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from capsd.calibrate import calibrate, write_config
    from capsd.config import load_config
    from capsd.services.locator.service import Config as LocatorConfig

    try:
        locator = load_config(args.locator_config, LocatorConfig)
        if locator.tank is None:
            return fail(
                f"calibrate: {args.locator_config} has no `tank` section: the walls are needed",
                EXIT_CONFIG,
            )
        fit, mount = calibrate(args.recording, mount=locator.sonar, tank=locator.tank)
    except CapsdError as exc:
        return fail(f"calibrate: {exc}", EXIT_CONFIG)
    for line in fit.lines():
        print(line)
    write_config(args.locator_config, args.out, mount, fit, args.recording)
    print(
        f"wrote {args.out}: sonar yaw {mount.yaw_deg:g} deg, pitch {mount.pitch_deg:g} deg, "
        f"roll {mount.roll_deg:g} deg, position {list(mount.position_m)} m"
    )
    if not (fit.yaw_determined or fit.roll_determined or fit.shift_determined):
        return fail("calibrate: nothing was determined; the config is unchanged", EXIT_FAILURE)
    return EXIT_OK


def register(sub: Subcommands) -> None:
    """Add the calibrate verbs to the `capsd` parser's subcommands."""
    cal = sub.add_parser(
        "calibrate",
        help="the sonar mount (heading, roll, position) from a recording of the ASV turning",
        description="Fit the sonar's heading, roll and horizontal position against the ASV's "
        "LiDAR-derived frame to the tank walls in a recording's sonar frames (`capsd record "
        "'cap/**'` while the ASV turns on the spot, about two minutes); print each estimate "
        "with its uncertainty and whether the data determined it; write a copy of the locator "
        "config with what was determined (docs/INSTALL-ERRORS.md).",
    )
    cal.add_argument("recording", type=Path, help="an MCAP recording with frames and ASV poses")
    cal.add_argument(
        "--locator-config",
        type=Path,
        default=Path("deploy/config/locator.yaml"),
        help="the locator's config during the recording (its sonar mount and tank)",
    )
    cal.add_argument("-o", "--out", type=Path, required=True, help="the calibrated config")
    cal.set_defaults(func=_cmd_calibrate)
