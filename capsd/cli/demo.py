"""`capsd demo`: the whole system on the simulated tank."""

from __future__ import annotations

import argparse
from pathlib import Path

from capsd.cli.common import Subcommands
from capsd.launch import positive_float


def _cmd_demo(args: argparse.Namespace) -> int:
    from datetime import UTC, datetime

    from capsd import demo

    out = args.out or Path("reports") / datetime.now(UTC).strftime("demo-%Y%m%d-%H%M%S")
    return demo.main(
        duration_s=args.duration,
        out=out,
        trajectory=args.trajectory,
        tank=args.tank,
        seed=args.seed,
        port=args.port,
        record=args.record,
        record_view=args.record_view,
        mission=args.mission,
        asv=args.asv,
        asv_drive=args.asv_drive,
        sonar_tilt=args.sonar_tilt,
        install_errors=args.install_errors,
        calibration=args.calibration,
        detector_config=args.detector_config,
    )


def register(sub: Subcommands) -> None:
    """Add the demo verbs to the `capsd` parser's subcommands."""
    dem = sub.add_parser(
        "demo",
        help="the whole system on the simulated tank, live, with a report folder",
        description="Router, simulator, asv_pose, sonar_detect, locator, mav_bridge and an "
        "ArduSub stand-in as separate processes on 127.0.0.1; live fix error vs truth, rates "
        "and health; stops after --duration or Ctrl-C; writes summary.md, figures.json, PNGs.",
    )
    dem.add_argument("--duration", type=positive_float, default=60.0, help="seconds to run")
    dem.add_argument("--out", type=Path, default=None, help="report folder (reports/demo-TIME)")
    dem.add_argument(
        "--trajectory",
        default="square",
        choices=["square", "lawnmower", "bouncing", "random", "two_floor"],
    )
    dem.add_argument("--tank", default="nfp", choices=["nfp", "mockup", "pond"])
    dem.add_argument("--seed", type=int, default=0)
    dem.add_argument("--port", type=int, default=None, help="router port (a free one if unset)")
    dem.add_argument(
        "--record",
        type=Path,
        default=None,
        help="also record every key but the sonar images into this .mcap, from before the "
        "services start (`capsd replay-check` replays it into a fresh locator)",
    )
    dem.add_argument(
        "--record-view",
        default="on",
        choices=["on", "off"],
        help="with --record: on, also the operator's scene for Foxglove (capsd record --view); "
        "off: the payloads alone (deriving the scene takes most of a core: on a 2-core machine "
        "it starves the services whose figures a run measures)",
    )
    dem.add_argument(
        "--mission",
        type=Path,
        default=None,
        help="close the loop: fly this plan (capsd mission run) with the simulated ROV flown "
        "by the ArduSub stand-in; the demo ends with the mission",
    )
    dem.add_argument(
        "--asv",
        default="station",
        choices=["station", "follow"],
        help="with --mission: the ASV keeps its station, or follows (asv_follow and the "
        "ASV's bridge drive the ArduRover stand-in the simulator hosts)",
    )
    dem.add_argument(
        "--asv-drive",
        default="steered",
        choices=["steered", "lateral"],
        help="with --asv follow, how the simulated ASV moves to a position target: steered "
        "(default), as ArduRover's GUIDED drives a boat or an omni frame, the hull turned "
        "towards its way; lateral: an omni frame moving any way with its heading kept (a "
        "controller that uses its lateral thrust, not ArduRover's GUIDED)",
    )
    dem.add_argument(
        "--sonar-tilt",
        default="fixed",
        choices=["fixed", "servo", "pan-tilt"],
        help="with --asv follow: the sonar fixed to the hull (default) or on a tilt servo "
        "(-15 to +40 deg about its pitch, 30 deg/s) the follower drives through the ASV's "
        "autopilot mount; the services take its reported angle ping by ping; pan-tilt: that "
        "servo on a pan servo too (+-90 deg, 60 deg/s), which keeps the sonar on the ROV while "
        "a steered hull's way crosses its bearing",
    )
    dem.add_argument(
        "--install-errors",
        default="realistic",
        choices=["realistic", "off"],
        help="realistic (default): the simulated installation has what a tape gets wrong "
        "(docs/INSTALL-ERRORS.md), unknown to the services, uncalibrated; off: a perfect one",
    )
    dem.add_argument(
        "--calibration",
        default="off",
        choices=["off", "dive"],
        help="dive: before the services start, calibrate the realistic installation as a "
        "field team does (a simulated 2-minute calibration dive of it, offline, fitted by "
        "capsd calibrate's code; the services get the calibrated mount); off (default): "
        "the tape's",
    )
    dem.add_argument(
        "--detector-config",
        type=Path,
        default=None,
        help="a sonar_detect config (e.g. a copy of deploy/config/sonar_detect.yaml) whose "
        "detector settings (detector, cnn, classical, min_confidence, and the depth gate's "
        "mode, tolerance, margin and age) the detection service runs with; its bus, names and "
        "sonar mount stay the demo's (default: the service's defaults)",
    )
    dem.set_defaults(func=_cmd_demo)
