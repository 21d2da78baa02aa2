"""`capsd sim` and `capsd render`: the simulated tank and its pictures."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from capsd.cli.common import (
    Subcommands,
    add_world_flags,
    fail,
    guarded,
)
from capsd.errors import CapsdError, ConfigError
from capsd.launch import (
    EXIT_CONFIG,
    EXIT_OK,
    add_bus_flags,
    add_namespace_flags,
    positive_float,
)
from capsd.logs import setup_stderr_logging


def _sim_config(args: argparse.Namespace) -> Any:
    from capsd.simulator.commands import config_from_args

    return config_from_args(args)


def _cmd_sim(args: argparse.Namespace) -> int:
    from capsd.simulator.commands import run_sim

    try:
        config = _sim_config(args)
    except ConfigError as exc:
        return fail(str(exc), EXIT_CONFIG)
    setup_stderr_logging("sim", config.log_level)
    return guarded(lambda: run_sim(args, config))


def _cmd_render_fan(args: argparse.Namespace) -> int:
    from capsd.simulator.commands import render_fan

    return render_fan(args)


def _cmd_render_view(args: argparse.Namespace) -> int:
    from capsd.view_preview import render

    try:
        used = render(args.recording, args.out)
    except CapsdError as exc:
        return fail(f"render view: {exc}", EXIT_CONFIG)
    print(f"wrote {args.out} from {sum(used.values())} view messages: {used}")
    return EXIT_OK


def _cmd_render_top_view(args: argparse.Namespace) -> int:
    from capsd.simulator.commands import render_top_view

    try:
        config = _sim_config(args)
    except ConfigError as exc:
        return fail(str(exc), EXIT_CONFIG)
    return render_top_view(args, config)


def register(sub: Subcommands) -> None:
    """Add the sim verbs to the `capsd` parser's subcommands."""
    sim = sub.add_parser(
        "sim",
        help="the simulated tank: real time on the bus, or an offline dataset",
        description="Simulate the tank, both vehicles and every sensor. Without --offline it "
        "publishes in real time on the same keys the real drivers use; with "
        "--offline DIR it writes a dataset (format in simulator/dataset.py).",
    )
    add_world_flags(sim)
    sim.add_argument("--offline", metavar="DIR", help="write a dataset here instead")
    sim.add_argument(
        "--duration",
        type=positive_float,
        default=60.0,
        help="seconds to simulate with --offline (default 60)",
    )
    add_namespace_flags(sim)
    add_bus_flags(sim)
    sim.set_defaults(func=_cmd_sim)
    rend = sub.add_parser(
        "render",
        help="PNG pictures: a sonar fan, a tank top view",
        description="Render pictures a person can look at.",
    )
    rend_sub = rend.add_subparsers(dest="render_command", required=True, metavar="WHAT")
    fan = rend_sub.add_parser(
        "fan",
        help="one sonar frame of a dataset as a fan, with its truth",
        description="The frame as a Cartesian fan PNG; truth (green), "
        "ghosts (yellow) and detections (red) drawn on it.",
    )
    fan.add_argument("dataset", help="dataset directory (capsd sim --offline)")
    fan.add_argument("--ping", type=int, default=0, help="ping id")
    fan.add_argument("--out", "-o", required=True, help="PNG file to write")
    fan.set_defaults(func=_cmd_render_fan)
    rview = rend_sub.add_parser(
        "view",
        help="the Foxglove layout's panels drawn from a recording's /capsd/... messages",
        description="A PNG of what deploy/foxglove/capsd-layout.json shows (3D scene through "
        "its transforms, fan image, fix x/y/z), drawn by capsd from a `capsd record` (or "
        "`capsd demo --record`) file: a preview, not a viewer's screenshot.",
    )
    rview.add_argument("recording", type=Path, help="an .mcap with the view's channels")
    rview.add_argument("--out", "-o", type=Path, required=True, help="PNG file to write")
    rview.set_defaults(func=_cmd_render_view)
    top = rend_sub.add_parser(
        "topview",
        help="the tank, its clutter and the vehicles' tracks",
        description="A top-view PNG of the tank with both tracks.",
    )
    add_world_flags(top)
    top.add_argument(
        "--duration", type=positive_float, default=120.0, help="seconds of track to draw"
    )
    top.add_argument("--out", "-o", required=True, help="PNG file to write")
    add_namespace_flags(top)
    add_bus_flags(top)
    top.set_defaults(func=_cmd_render_top_view)
