"""`capsd record`, `replay`, `replay-check`, `import-bag`, `live-view`, `evaluate`, `losses`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from capsd.cli.common import (
    StopOnSignal,
    Subcommands,
    add_view_flags,
    fail,
    view_from_args,
)
from capsd.config import BusConfig
from capsd.errors import BusError, CapsdError, ConfigError
from capsd.launch import (
    EXIT_CONFIG,
    EXIT_FAILURE,
    EXIT_OK,
    add_bus_flags,
    bus_from_args,
    positive_float,
)


def _cmd_record(args: argparse.Namespace) -> int:
    import zenoh

    from capsd.bus import open_session
    from capsd.recording import LOCATOR_CONFIG_ATTACHMENT, record

    attachments = {}
    try:
        bus = bus_from_args(args, BusConfig())
        for expr in (args.keyexpr, *args.exclude):
            zenoh.KeyExpr(expr)
        view = None
        if args.view == "on":
            from capsd.live_view import make_view

            view = make_view(view_from_args(args))
        if args.locator_config is not None:
            # What the site's locator runs with, kept in the file (capsd replay-check uses it).
            attachments[LOCATOR_CONFIG_ATTACHMENT] = args.locator_config.read_bytes()
    except (ConfigError, zenoh.ZError) as exc:
        return fail(f"record: {exc}", EXIT_CONFIG)
    except OSError as exc:
        return fail(f"record: --locator-config: {exc}", EXIT_CONFIG)

    def progress(n: int) -> None:
        print(f"record: {n} messages", file=sys.stderr, flush=True)

    try:
        with StopOnSignal() as stop, open_session(bus) as session:
            counts = record(
                session,
                args.keyexpr,
                args.output,
                stop=stop,
                duration_s=args.duration,
                exclude=tuple(args.exclude),
                view=view,
                logs="services/capsd-$*/log" if view is not None else None,
                on_progress=progress,
                attachments=attachments,
            )
    except KeyboardInterrupt:
        return EXIT_OK
    except (BusError, CapsdError, OSError) as exc:
        return fail(f"record: {exc}", EXIT_FAILURE)
    for key, n in sorted(counts.items()):
        print(f"{n:8d}  {key}")
    print(f"recorded {sum(counts.values())} messages into {args.output}")
    return EXIT_OK


def _cmd_replay(args: argparse.Namespace) -> int:
    from capsd.bus import open_session
    from capsd.recording import channel_counts, replay

    if args.info:
        try:
            counts = channel_counts(args.file)
        except CapsdError as exc:
            return fail(f"replay: {exc}", EXIT_CONFIG)
        for key, n in sorted(counts.items()):
            print(f"{n:8d}  {key}")
        return EXIT_OK
    if not args.speed > 0:
        return fail(f"replay: --speed must be positive, not {args.speed}", EXIT_CONFIG)
    try:
        bus = bus_from_args(args, BusConfig())
    except ConfigError as exc:
        return fail(str(exc), EXIT_CONFIG)
    try:
        channel_counts(args.file)  # a bad file fails before the first message
        with StopOnSignal() as stop, open_session(bus) as session:
            counts = replay(
                session,
                args.file,
                speed=args.speed,
                stop=stop,
                include=args.include,
                exclude=tuple(args.exclude),
            )
    except KeyboardInterrupt:
        return EXIT_OK
    except CapsdError as exc:
        return fail(f"replay: {exc}", EXIT_CONFIG)
    except BusError as exc:
        return fail(f"replay: {exc}", EXIT_FAILURE)
    print(f"replayed {sum(counts.values())} messages from {args.file}")
    return EXIT_OK


def _cmd_replay_check(args: argparse.Namespace) -> int:
    from capsd import replay_check

    if not args.speed > 0:
        return fail(f"replay-check: --speed must be positive, not {args.speed}", EXIT_CONFIG)
    try:
        result = replay_check.run(args.file, locator_config=args.locator_config, speed=args.speed)
    except CapsdError as exc:
        return fail(f"replay-check: {exc}", EXIT_CONFIG)
    return EXIT_OK if result.consistent else EXIT_FAILURE


def _cmd_import_bag(args: argparse.Namespace) -> int:
    from capsd.bag_import import import_bag

    try:
        result = import_bag(args.bag, args.mapping, args.output)
    except ConfigError as exc:
        return fail(str(exc), EXIT_CONFIG)
    except CapsdError as exc:
        return fail(f"import-bag: {exc}", EXIT_CONFIG)
    for key, n in sorted(result["written"].items()):
        print(f"{n:8d}  {key}")
    for what, n in sorted(result["rejected"].items()):
        print(f"rejected {n} messages of {what}", file=sys.stderr)
    if result["mapped_topics_missing"]:
        print(f"mapped but not in the bag: {result['mapped_topics_missing']}", file=sys.stderr)
    print(f"wrote {sum(result['written'].values())} messages to {args.output}")
    if result["empty_topics"]:
        return fail(
            f"import-bag: mapped topics gave no message: {result['empty_topics']} "
            "(the rejections above say why)",
            EXIT_CONFIG,
        )
    return EXIT_OK


def _cmd_live_view(args: argparse.Namespace) -> int:
    from capsd.bus import open_session
    from capsd.live_view import serve

    try:
        bus = bus_from_args(args, BusConfig())
        settings = view_from_args(args)
    except ConfigError as exc:
        return fail(str(exc), EXIT_CONFIG)
    print(f"live view on ws://{args.host}:{args.port} (open it in Foxglove)", flush=True)
    try:
        with StopOnSignal() as stop, open_session(bus) as session:
            serve(
                session,
                site=args.site,
                host=args.host,
                port=args.port,
                settings=settings,
                stop=stop,
                on_status=lambda counts: print(f"live view: {counts}", file=sys.stderr),
            )
    except KeyboardInterrupt:
        return EXIT_OK
    except BusError as exc:
        return fail(str(exc), EXIT_FAILURE)
    return EXIT_OK


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from capsd.evaluate import evaluate, load, report

    try:
        inputs = load(args.recording, reference=args.reference, fixes=args.fixes)
        evaluation = evaluate(
            inputs,
            with_scale=args.fit == "similarity",
            max_offset_s=args.max_clock_offset,
            offset_s=None if args.clock_offset_ms is None else args.clock_offset_ms / 1000,
            max_gap_s=args.max_gap,
        )
    except CapsdError as exc:
        return fail(f"evaluate: {exc}", EXIT_CONFIG)
    figures = report(evaluation, args.out, title=", ".join(p.name for p in args.recording))
    print((args.out / "evaluation.md").read_text())
    print(f"written: {args.out}/evaluation.md, evaluation.json and 3 PNGs")
    if figures["alignment"]["problems"]:
        return fail("evaluate: the alignment is not determined (see above)", EXIT_FAILURE)
    return EXIT_OK


def _cmd_losses(args: argparse.Namespace) -> int:
    import math

    from capsd.losses import Thresholds, load, plot, since, table, write_json

    if not 0.0 < args.vertical_aperture_deg < 180.0:
        return fail("losses: --vertical-aperture-deg must be in (0, 180)", EXIT_CONFIG)
    if args.since < 0.0:
        return fail("losses: --since must be >= 0 seconds", EXIT_CONFIG)
    thresholds = Thresholds(vertical_aperture_rad=math.radians(args.vertical_aperture_deg))
    try:
        losses = since(load(args.recording, thresholds=thresholds), args.since)
    except CapsdError as exc:
        return fail(f"losses: {exc}", EXIT_CONFIG)
    print(f"{args.recording}: {len(losses.pings)} labelled pings from {args.since:g} s")
    print(table(losses))
    if losses.undecodable:
        print(f"payloads that did not decode (not judged): {losses.undecodable}")
    if args.out is not None and losses.pings:
        write_json(losses, args.out / "losses.json")
        plot(losses, args.out / "losses.png", thresholds=thresholds)
        print(f"written: {args.out}/losses.json, losses.png")
    return EXIT_OK


def register(sub: Subcommands) -> None:
    """Add the recording verbs to the `capsd` parser's subcommands."""
    rec = sub.add_parser(
        "record",
        help="record key expressions into an MCAP file (JSON schemas; Foxglove reads it)",
        description="Subscribe to KEYEXPR and write every sample to an MCAP file until "
        "Ctrl-C/SIGTERM or --duration.",
    )
    rec.add_argument("keyexpr", help="key expression, e.g. 'cap/**'")
    rec.add_argument("-o", "--output", type=Path, required=True, help="the .mcap file")
    rec.add_argument("--duration", type=positive_float, default=None, help="seconds to record")
    rec.add_argument(
        "--exclude", action="append", default=[], help="skip keys intersecting this (repeatable)"
    )
    rec.add_argument(
        "--view",
        choices=("on", "off"),
        default="on",
        help="on: also the operator's scene (transforms, tank, trails, LiDAR, logs, fan "
        "images) as Foxglove channels /capsd/...; excluded keys still feed it",
    )
    add_view_flags(rec)
    add_bus_flags(rec)
    rec.set_defaults(func=_cmd_record)
    rep = sub.add_parser(
        "replay",
        help="republish an MCAP recording with its original timing (bytes and stamps kept)",
        description="Put every recorded sample again on its key, paced by --speed.",
    )
    rep.add_argument("file", type=Path, help="an .mcap file written by `capsd record`")
    rep.add_argument(
        "--speed", type=positive_float, default=1.0, help="1 = real time, 10 = ten times"
    )
    rep.add_argument("--include", default="**", help="only keys intersecting this expression")
    rep.add_argument("--exclude", action="append", default=[], help="skip these keys")
    rep.add_argument("--info", action="store_true", help="only print per-channel counts")
    add_bus_flags(rep)
    rep.set_defaults(func=_cmd_replay)
    rchk = sub.add_parser(
        "replay-check",
        help="replay a recording into a fresh locator and compare its fixes with the recorded",
        description="Start a router and a fresh locator on 127.0.0.1, replay the recording's "
        "inputs in recorded order, and compare every fix by ping stamp: input stamps, "
        "quality, single-ping and tracked positions bit for bit. Exit 0 when identical, or when "
        "every difference follows from an input the live locator did not have yet.",
    )
    rchk.add_argument("file", type=Path, help="an .mcap file (e.g. from `capsd demo --record`)")
    rchk.add_argument(
        "--locator-config",
        type=Path,
        default=None,
        help="the live locator's config (default: the one `capsd record --locator-config` kept "
        "in the recording, else deploy/config/locator.yaml)",
    )
    rchk.add_argument(
        "--speed", type=positive_float, default=1.0, help="replay speed (1 = real time)"
    )
    rchk.set_defaults(func=_cmd_replay_check)
    imp = sub.add_parser(
        "import-bag",
        help="a ROS 1/ROS 2 bag into a replayable MCAP recording, by a topic mapping file",
        description="Convert the mapped topics (LaserScan, Imu; PoseStamped, "
        "PoseWithCovarianceStamped, TransformStamped, /tf, Odometry as an input pose or as a "
        "reference for `capsd evaluate`) into CAP-SD payloads on their keys; `capsd replay` "
        "plays the result. Exit 2 when a topic's type does not fit its mapping or a mapped "
        "topic gives nothing.",
    )
    imp.add_argument("bag", type=Path, help="a ROS 1 .bag file or a ROS 2 bag directory")
    imp.add_argument("--mapping", type=Path, required=True, help="topic mapping YAML")
    imp.add_argument("-o", "--output", type=Path, required=True, help="the .mcap to write")
    imp.set_defaults(func=_cmd_import_bag)
    live = sub.add_parser(
        "live-view",
        help="a Foxglove WebSocket server: sonar fan with detections, tank map, every payload",
        description="Serve the site's keys to Foxglove (ws://HOST:PORT): JSON channels with "
        "schemas, /capsd/sonar_fan and /capsd/tank_map images.",
    )
    live.add_argument("--site", default="tank")
    live.add_argument("--host", default="127.0.0.1", help="address to serve on")
    live.add_argument("--port", type=int, default=8765)
    add_view_flags(live)
    add_bus_flags(live)
    live.set_defaults(func=_cmd_live_view)
    ev = sub.add_parser(
        "evaluate",
        help="score a recording's fixes against a reference system (motion capture)",
        description="Align the reference (ReferencePose on `ref/pose`: `capsd import-bag` with "
        "`as: reference`, or the ROS 2 input's reference_topic; or the simulator's truth) to "
        "the fixes: rigid transform (or similarity) by robust Umeyama and the clock offset by "
        "search; then the accuracy bench's report: MED, RMSE per axis, p95, availability, "
        "3D trajectory, per-axis plots, error histogram. Exit 1 when the alignment is not "
        "determined (a dive along a line, a vehicle that hardly moved).",
    )
    ev.add_argument("recording", type=Path, nargs="+", help="MCAP recordings (read together)")
    ev.add_argument("--reference", default=None, help="the reference's key, or its end "
                    "(default: the one `ref/pose` key)")  # fmt: skip
    ev.add_argument("--fixes", default=None, help="the fixes' key (default: the one "
                    "`locator/fix` key)")  # fmt: skip
    ev.add_argument("--fit", choices=("rigid", "similarity"), default="rigid",
                    help="similarity also fits a scale (a reference in other units)")  # fmt: skip
    ev.add_argument("--clock-offset-ms", type=float, default=None,
                    help="reference stamps minus fix stamps (default: estimated)")  # fmt: skip
    ev.add_argument("--max-clock-offset", type=positive_float, default=1.0,
                    help="seconds either way the offset search covers")  # fmt: skip
    ev.add_argument("--max-gap", type=positive_float, default=0.1,
                    help="seconds: no reference value across a longer gap")  # fmt: skip
    ev.add_argument("--out", type=Path, default=Path("reports/evaluate"), help="report folder")
    ev.set_defaults(func=_cmd_evaluate)
    los = sub.add_parser(
        "losses",
        help="where a simulated recording's pings lost their good fix: out of view, missed by "
        "the detector, refused by the locator (against the simulator's labels)",
        description="Join each labelled ping (sim/label) with its detections and fix by stamp "
        "and count the pings per class: out of view (above or below the aperture, outside the "
        "fan), no detections, missed, no fix, refused (by the locator's reason), good (on or "
        "off the ROV). Exit 2 when the recording has no labels (a field recording).",
    )
    los.add_argument("recording", type=Path, help="an .mcap from `capsd demo --record`")
    los.add_argument("--since", type=float, default=0.0,
                     help="seconds after the first labelled ping to start from")  # fmt: skip
    los.add_argument("--vertical-aperture-deg", type=float, default=20.0,
                     help="the simulated sonar's (splits the out-of-view pings)")  # fmt: skip
    los.add_argument("--out", type=Path, default=None,
                     help="also write losses.json and losses.png (per class)")  # fmt: skip
    los.set_defaults(func=_cmd_losses)
