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


def _cmd_render_screenshot(args: argparse.Namespace) -> int:
    from capsd.progress import Progress
    from capsd.recording import time_span_ns
    from capsd.viewer_screenshot import (
        Served,
        find_browser,
        screenshot,
        serving,
        viewer_url,
    )

    if (args.viewer_dir is None) == (args.viewer_url is None):
        return fail("render screenshot: give one of --viewer-dir and --viewer-url", EXIT_CONFIG)
    try:
        width, height = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        return fail(f"render screenshot: --size {args.size!r}: expected WIDTHxHEIGHT", EXIT_CONFIG)
    if not (320 <= width <= 7680 and 240 <= height <= 4320):
        return fail(f"render screenshot: --size {args.size}: 320x240 to 7680x4320", EXIT_CONFIG)
    live = args.source if args.source.startswith(("ws://", "wss://")) else None
    recording = None if live else Path(args.source)
    try:
        browser = find_browser(args.browser)
        at_ns: int | None = None
        first_ns = 0
        if recording is not None:
            first_ns, last_ns = time_span_ns(recording)
            at_ns = last_ns if args.at_s is None else min(first_ns + int(args.at_s * 1e9), last_ns)
        served = Served(recording, args.layout, args.viewer_dir)
        with serving(served) as base:
            url = viewer_url(args.viewer_url or base, base, time_ns=at_ns, live=live)
            print(f"opening {url}")
            bar = Progress(args.wait_s, label="viewer loading", unit=" s")
            try:
                screenshot(
                    url,
                    args.out,
                    browser=browser,
                    width=width,
                    height=height,
                    wait_s=args.wait_s,
                    progress=bar.update,
                )
            finally:
                bar.close()
    except CapsdError as exc:
        return fail(f"render screenshot: {exc}", EXIT_CONFIG)
    where = live if at_ns is None else f"{(at_ns - first_ns) / 1e9:.1f} s into the recording"
    print(f"wrote {args.out} ({width}x{height}, {where})")
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
        help="PNG pictures: a sonar fan, a tank top view, the viewer's layout",
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
    shot = rend_sub.add_parser(
        "screenshot",
        help="a real viewer's (Lichtblick's) picture of a recording or a live view in the layout",
        description="Serves the recording and the layout on 127.0.0.1 (and a viewer's web "
        "build with --viewer-dir), opens them in the viewer in headless Chromium and saves "
        "what it shows. Needs Chromium and a web build of Lichtblick (or a URL serving one).",
    )
    shot.add_argument(
        "source",
        help="an .mcap (capsd record, capsd demo --record), or a capsd live-view's ws://HOST:PORT",
    )
    shot.add_argument("--out", "-o", type=Path, required=True, help="PNG file to write")
    shot.add_argument(
        "--layout",
        type=Path,
        default=Path(__file__).resolve().parents[2] / "deploy" / "foxglove" / "capsd-layout.json",
        help="the layout to open (default: deploy/foxglove/capsd-layout.json)",
    )
    shot.add_argument("--viewer-dir", type=Path, help="a viewer's web build (its index.html)")
    shot.add_argument("--viewer-url", help="or: where a viewer's web build is served")
    shot.add_argument("--browser", help="the Chromium to run (default: chromium on PATH)")
    shot.add_argument(
        "--at-s", type=float, default=None, help="seconds into the recording (default: its end)"
    )
    shot.add_argument("--size", default="1600x1000", help="window WIDTHxHEIGHT (default 1600x1000)")
    shot.add_argument(
        "--wait-s",
        type=positive_float,
        default=30.0,
        help="seconds the viewer loads and draws before the picture (default 30)",
    )
    shot.set_defaults(func=_cmd_render_screenshot)
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
