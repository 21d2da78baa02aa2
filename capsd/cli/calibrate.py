"""`capsd calibrate RECORDING`: the sonar mount and the depth offset from a recording."""

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
    from capsd.calibrate import calibrate, write_config, write_detector_config
    from capsd.config import load_config
    from capsd.services.locator.service import Config as LocatorConfig
    from capsd.services.sonar_detect.service import Config as DetectorConfig

    if (args.detector_config is None) != (args.detector_out is None):
        return fail("calibrate: --detector-config and --detector-out go together", EXIT_CONFIG)
    for flag, out in (("-o", args.out), ("--detector-out", args.detector_out)):
        if out is not None and not out.parent.is_dir():  # said before minutes of fitting
            return fail(f"calibrate: {flag} {out}: no folder {out.parent}", EXIT_CONFIG)
    try:
        locator = load_config(args.locator_config, LocatorConfig)
        detector = (
            None
            if args.detector_config is None
            else load_config(args.detector_config, DetectorConfig)
        )
        if locator.tank is None:
            return fail(
                f"calibrate: {args.locator_config} has no `tank` section: the walls are needed",
                EXIT_CONFIG,
            )
        result = calibrate(
            args.recording,
            mount=locator.sonar,
            rov=locator.rov,
            tank=locator.tank,
            prior=locator.installation,
            what=args.what,
            orbit=args.orbit,
        )
    except CapsdError as exc:
        return fail(f"calibrate: {exc}", EXIT_CONFIG)
    for line in result.lines():
        print(line)
    if not result.determined_anything:
        return fail("calibrate: nothing was determined; no config written", EXIT_FAILURE)
    written = write_config(args.locator_config, args.out, result, args.recording)
    mount, rov = result.mount, result.rov
    print(
        f"wrote {args.out}: sonar yaw {mount.yaw_deg:g} deg, pitch {mount.pitch_deg:g} deg, "
        f"roll {mount.roll_deg:g} deg, position {list(mount.position_m)} m; "
        f"depth offset {rov.depth_offset_m:+g} m"
    )
    if detector is not None:
        write_detector_config(
            args.detector_config,
            args.detector_out,
            result,
            args.recording,
            locator_sonar=written.get("sonar") or {},
        )
        before = (
            ""
            if detector.depth_gate.sonar == locator.sonar
            else f" (before, it differed from {args.locator_config}'s `sonar`)"
        )
        print(f"wrote {args.detector_out}: its depth_gate.sonar is {args.out}'s `sonar`{before}")
    left = result.installation
    print(
        "still allowed for in every fix's covariance (1 sigma): range scale "
        f"{left.range_scale:g}, sonar position {list(left.sonar_position_m)} m, angles "
        f"{list(left.sonar_angles_deg)} deg, depth offset {left.depth_offset_m:g} m"
    )
    return EXIT_OK


def register(sub: Subcommands) -> None:
    """Add the calibrate verbs to the `capsd` parser's subcommands."""
    cal = sub.add_parser(
        "calibrate",
        help="the sonar mount and the depth offset from a recording of the calibration dive",
        description="Fit the sonar's heading, roll and horizontal position against the ASV's "
        "LiDAR-derived frame to the tank walls in a recording's sonar frames (`capsd record "
        "'cap/**'` while the ASV turns on the spot, about two minutes), and the offset of the "
        "ROV's depth readings from a stretch of it floating at the surface (each boot of the "
        "autopilot zeroes its depth anew: redo `--what depth` after each); print each "
        "estimate with its uncertainty and whether the data determined it; write a copy of "
        "the locator config with what was determined (docs/INSTALL-ERRORS.md). Then, with "
        "that config, `--what range` on a recording of the ROV parked while the ASV swings "
        "round it, facing it and looking up to 25 deg to either side of it: the range offset "
        "added to every detection's range from the fixes' offset along the line of sight, "
        "and the sonar's forward position from their offset along the ASV's axis. And "
        "`--what pitch` on a recording (the same config) of the ASV still and "
        "the ROV in front of it going slowly down and up through the sonar's vertical aperture, "
        "beyond both its edges: the sonar's pitch from where the ROV's echo fades; flown from two "
        "distances (about 1.5 m and as far as the floor allows), with --orbit, its height too.",
    )
    cal.add_argument("recording", type=Path, help="an MCAP recording with frames and ASV poses")
    cal.add_argument(
        "--locator-config",
        type=Path,
        default=Path("deploy/config/locator.yaml"),
        help="the locator's config during the recording (its sonar mount and tank)",
    )
    cal.add_argument("-o", "--out", type=Path, required=True, help="the calibrated config")
    cal.add_argument(
        "--detector-config",
        type=Path,
        default=None,
        help="the sonar_detect config (e.g. deploy/config/sonar_detect.yaml): a copy whose "
        "depth gate sees the calibrated sonar is written to --detector-out",
    )
    cal.add_argument(
        "--detector-out",
        type=Path,
        default=None,
        help="with --detector-config: the copy, its `depth_gate.sonar` the calibrated "
        "locator config's `sonar`",
    )
    cal.add_argument(
        "--what",
        choices=("all", "mount", "depth", "range", "pitch"),  # capsd.calibrate.What
        default="all",
        help="mount: the sonar mount only; depth: the depth offset only (no sonar frames "
        "needed); all (default): both; range: the range offset and the sonar's forward "
        "position from the fixes of a parked ROV (a recording made with the calibrated "
        "config, the locator running); "
        "pitch: the sonar's pitch from the ROV going down and up in front of the still ASV (the "
        "same)",
    )
    cal.add_argument(
        "--orbit",
        type=Path,
        default=None,
        help="with --what pitch: the range manoeuvre's recording (the parked ROV); from two "
        "profiles at different distances the sonar's height is then written too, and the "
        "range offset gives back what it took of it",
    )
    cal.set_defaults(func=_cmd_calibrate)
