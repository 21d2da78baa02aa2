"""The `capsd` command: run a service, run a router, tap key expressions, list live services."""

from __future__ import annotations

import argparse
import faulthandler
import json
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from capsd.config import BusConfig, ServiceConfig, dump_config
from capsd.errors import BusError, CapsdError, ConfigError, PayloadError
from capsd.launch import (
    EXIT_CONFIG,
    EXIT_FAILURE,
    EXIT_OK,
    add_bus_flags,
    add_namespace_flags,
    bus_from_args,
    non_negative_float,
    non_negative_int,
    positive_float,
    positive_int,
    service_config_from_args,
)
from capsd.logs import setup_stderr_logging
from capsd.registry import SERVICES


class RouterConfig(ServiceConfig, frozen=True, kw_only=True):
    """A Zenoh router (topside or a dev laptop); it reports health like any service."""

    bus: BusConfig = BusConfig(mode="router", connect=(), listen=("tcp/127.0.0.1:7447",))


def _fail(message: str, code: int) -> int:
    print(f"capsd: {message}", file=sys.stderr)
    return code


# ---------------------------------------------------------------------------- run / router


def _cmd_run(args: argparse.Namespace) -> int:
    entry = SERVICES[args.service]
    config_cls, service_main = entry.load()
    try:
        config = service_config_from_args(config_cls, args)
    except ConfigError as exc:
        return _fail(str(exc), EXIT_CONFIG)
    if args.print_config:
        print(dump_config(config), end="")
        return EXIT_OK
    setup_stderr_logging(entry.name, config.log_level)
    return _guarded(lambda: service_main(config))


def _cmd_router(args: argparse.Namespace) -> int:
    try:
        config = service_config_from_args(RouterConfig, args)
    except ConfigError as exc:
        return _fail(str(exc), EXIT_CONFIG)
    if config.bus.mode != "router":
        return _fail("config error: `bus.mode` must be 'router' for `capsd router`", EXIT_CONFIG)
    setup_stderr_logging("router", config.log_level)
    from capsd.runner import ServiceRunner

    def router_main() -> int:
        with ServiceRunner("router", config) as runner:
            runner.run()
        return EXIT_OK

    return _guarded(router_main)


def _guarded(body: Any) -> int:
    try:
        return int(body())
    except ConfigError as exc:
        return _fail(str(exc), EXIT_CONFIG)
    except BusError as exc:
        return _fail(str(exc), EXIT_FAILURE)
    except KeyboardInterrupt:
        return EXIT_OK


# ---------------------------------------------------------------------------- tap


class _StopOnSignal:
    """Turn SIGINT/SIGTERM into an Event for short-lived tools."""

    def __init__(self) -> None:
        self.event = threading.Event()

    def __enter__(self) -> threading.Event:
        self._old = {
            s: signal.signal(s, lambda *_: self.event.set())
            for s in (signal.SIGINT, signal.SIGTERM)
        }
        return self.event

    def __exit__(self, *_exc: object) -> None:
        for signum, handler in self._old.items():
            signal.signal(signum, handler)


def _cmd_tap(args: argparse.Namespace) -> int:
    from capsd.bus import open_session
    from capsd.codec import decode_any, split_encoding, to_builtins

    try:
        bus = bus_from_args(args, BusConfig())
    except ConfigError as exc:
        return _fail(str(exc), EXIT_CONFIG)
    lock = threading.Lock()
    printed = 0
    done = threading.Event()

    def on_sample(sample: Any) -> None:
        nonlocal printed
        key, encoding = str(sample.key_expr), str(sample.encoding)
        line: dict[str, Any] = {
            "key": key,
            "encoding": encoding,
            "schema": split_encoding(encoding)[1],
        }
        try:
            payload = decode_any(sample.payload.to_bytes(), encoding=encoding, key_expr=key)
            line["payload"] = to_builtins(payload, bytes_as=args.bytes)
        except PayloadError as exc:
            line["error"] = exc.reason
        with lock:
            if done.is_set():
                return
            try:
                print(json.dumps(line, separators=(",", ":")), flush=True)
            except BrokenPipeError:  # the reader went away (`| head`): stop quietly
                done.set()
                return
            printed += 1
            if args.count and printed >= args.count:
                done.set()

    try:
        with _StopOnSignal() as stop, open_session(bus) as session:
            subscriber = session.declare_subscriber(args.keyexpr, on_sample)
            deadline = time.monotonic() + args.duration if args.duration else None
            while not (stop.is_set() or done.is_set()):
                if deadline is not None and time.monotonic() >= deadline:
                    break
                stop.wait(0.05)
            done.set()
            subscriber.undeclare()
    except BusError as exc:
        return _fail(str(exc), EXIT_FAILURE)
    except Exception as exc:
        return _fail(f"tap failed on '{args.keyexpr}': {exc}", EXIT_CONFIG)
    return EXIT_OK


# ---------------------------------------------------------------------------- list


def _cmd_list(args: argparse.Namespace) -> int:
    from capsd.bus import open_session
    from capsd.codec import Codec
    from capsd.keys import all_alive, all_health, parse_service_key
    from capsd.payloads import Health

    try:
        bus = bus_from_args(args, BusConfig())
    except ConfigError as exc:
        return _fail(str(exc), EXIT_CONFIG)
    codec = Codec(Health)
    rows: dict[tuple[str, str, str], dict[str, Any]] = {}
    try:
        with open_session(bus) as session:
            for reply in session.liveliness().get(all_alive(args.site), timeout=args.timeout):
                if reply.ok is not None:
                    site, vehicle, service = parse_service_key(str(reply.ok.key_expr))
                    rows[(site, vehicle, service)] = {
                        "site": site,
                        "vehicle": vehicle,
                        "service": service,
                    }
            asked_ns = time.time_ns()
            for reply in session.get(all_health(args.site), timeout=args.timeout):
                received_ns = time.time_ns()
                if reply.ok is None:
                    continue
                key = str(reply.ok.key_expr)
                try:
                    reported = codec.decode(
                        reply.ok.payload.to_bytes(), encoding=str(reply.ok.encoding), key_expr=key
                    )
                except PayloadError as exc:
                    print(f"capsd: {exc}", file=sys.stderr)
                    continue
                ident = parse_service_key(key)
                if ident in rows:  # only live services (a stale health reply is not a live service)
                    rows[ident]["health"] = reported
                    # The service stamped its reply between our query and the reply's arrival:
                    # its clock minus ours, +- half the round trip (NTP's estimate).
                    rows[ident]["clock_offset_ms"] = round(
                        (reported.stamp_ns - (asked_ns + received_ns) / 2) / 1e6, 1
                    )
                    rows[ident]["clock_uncertainty_ms"] = round((received_ns - asked_ns) / 2e6, 1)
    except (BusError, CapsdError) as exc:
        return _fail(str(exc), EXIT_FAILURE)
    ordered = [rows[k] for k in sorted(rows)]
    if args.json:
        from capsd.codec import to_builtins

        for row in ordered:
            out = {k: v for k, v in row.items() if k != "health"}
            if "health" in row:
                out["health"] = to_builtins(row["health"])
            print(json.dumps(out, separators=(",", ":")))
        return EXIT_OK
    print(
        f"{'SITE':<10} {'VEHICLE':<10} {'SERVICE':<14} {'STATE':<9} {'UPTIME':>8} "
        f"{'IN/s':>7} {'OUT/s':>7} {'ERRORS':>7} {'CLOCK ms':>9}  LAST ERROR"
    )
    skewed = []
    for row in ordered:
        health: Health | None = row.get("health")
        if health is None:
            print(f"{row['site']:<10} {row['vehicle']:<10} {row['service']:<14} {'?':<9}")
            continue
        rate_in = sum(s.rate_hz for s in health.inputs)
        rate_out = sum(s.rate_hz for s in health.outputs)
        offset = row["clock_offset_ms"]
        if abs(offset) > args.clock_warn_ms + row["clock_uncertainty_ms"]:
            skewed.append(f"{row['vehicle']}/{row['service']} ({offset:+.1f} ms)")
        print(
            f"{row['site']:<10} {row['vehicle']:<10} {row['service']:<14} {health.state:<9} "
            f"{health.uptime_s:>7.0f}s {rate_in:>7.1f} {rate_out:>7.1f} {health.decode_errors:>7} "
            f"{offset:>+9.1f}  {health.last_error or ''}"
        )
    if not ordered:
        print("(no live services)")
    if skewed:
        print(
            f"WARNING: clock offset above {args.clock_warn_ms:g} ms against this computer: "
            + ", ".join(skewed)
            + " (fixes combine stamps from several computers: check chrony)"
        )
    return EXIT_OK


# ---------------------------------------------------------------------------- mav


def _mav_tool(args: argparse.Namespace, tool: Callable[[Any], int]) -> int:
    """Run a `capsd mav` tool with the checks they share: the extra, the connection string."""
    try:
        from capsd.protocols.mavlink import check_connection
        from capsd.services.mav_bridge import check
    except ImportError as exc:  # the base install has no pymavlink: it comes with [rov]
        return _fail(
            f"`capsd mav` needs the rov extra (pip install 'capsd[rov]'): {exc}", EXIT_FAILURE
        )
    try:
        check_connection(args.connect)
    except ConfigError as exc:
        return _fail(str(exc), EXIT_CONFIG)
    try:
        return tool(check)
    except OSError as exc:
        return _fail(f"MAVLink link {args.connect}: {exc}", EXIT_FAILURE)


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


def _cmd_mav_check(args: argparse.Namespace) -> int:
    delay = _measured_delay_ms(args) if args.delay_ms == "auto" else float(args.delay_ms)
    return _mav_tool(
        args,
        lambda check: check.run_check(
            args.connect,
            apply=args.apply,
            yaw_source=args.yaw_source,
            position_noise_m=args.position_noise_m,
            delay_ms=delay,
            timeout_s=args.timeout,
        ),
    )


def _cmd_mav_zero_depth(args: argparse.Namespace) -> int:
    return _mav_tool(
        args,
        lambda check: check.run_zero_depth(args.connect, apply=args.apply, timeout_s=args.timeout),
    )


# ---------------------------------------------------------------------------- sim / render


def _sim_config(args: argparse.Namespace) -> Any:
    from capsd.simulator.commands import config_from_args

    return config_from_args(args)


def _cmd_sim(args: argparse.Namespace) -> int:
    from capsd.simulator.commands import run_sim

    try:
        config = _sim_config(args)
    except ConfigError as exc:
        return _fail(str(exc), EXIT_CONFIG)
    setup_stderr_logging("sim", config.log_level)
    return _guarded(lambda: run_sim(args, config))


def _cmd_render_fan(args: argparse.Namespace) -> int:
    from capsd.simulator.commands import render_fan

    return render_fan(args)


def _cmd_render_view(args: argparse.Namespace) -> int:
    from capsd.view_preview import render

    try:
        used = render(args.recording, args.out)
    except CapsdError as exc:
        return _fail(f"render view: {exc}", EXIT_CONFIG)
    print(f"wrote {args.out} from {sum(used.values())} view messages: {used}")
    return EXIT_OK


def _cmd_render_top_view(args: argparse.Namespace) -> int:
    from capsd.simulator.commands import render_top_view

    try:
        config = _sim_config(args)
    except ConfigError as exc:
        return _fail(str(exc), EXIT_CONFIG)
    return render_top_view(args, config)


def _add_world_flags(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", type=Path, help="simulator YAML config (defaults otherwise)")
    parser.add_argument("--tank", choices=["nfp", "mockup", "pond"], help="tank preset")
    parser.add_argument(
        "--trajectory",
        help="square, lawnmower, bouncing, random or two_floor",
        choices=["square", "lawnmower", "bouncing", "random", "two_floor"],
    )
    parser.add_argument("--seed", type=int, help="random seed (the same seed, the same run)")


# ---------------------------------------------------------------------------- bench


def _cmd_bench_sim(args: argparse.Namespace) -> int:
    from capsd.bench import sim

    return sim.run(
        tank=args.tank, trajectory=args.trajectory, duration_s=args.duration, warmup_s=args.warmup
    )


def _cmd_bench_finetune(args: argparse.Namespace) -> int:
    from capsd.bench import finetune

    if not (args.duration > 0 and args.eval_duration > 0):
        return _fail("bench finetune: durations must be positive", EXIT_CONFIG)
    return finetune.run(out=args.out, duration_s=args.duration, eval_duration_s=args.eval_duration)


def _cmd_bench_detect(args: argparse.Namespace) -> int:
    from capsd.bench import detect

    if args.throughput:
        return detect.run_throughput(frames=args.frames, which=args.detector)
    if args.prior_sweep:
        return detect.sweep_prior(args.prior_sweep, duration_s=args.duration)
    for weights in args.weights or []:
        if not weights.is_file():
            return _fail(f"bench detect: --weights {weights}: no such file", EXIT_CONFIG)
    return detect.run(
        duration_s=args.duration,
        which=args.detector,
        fixtures=args.fixtures,
        weights=args.weights,
        json_out=args.json,
    )


def _cmd_record(args: argparse.Namespace) -> int:
    import zenoh

    from capsd.bus import open_session
    from capsd.recording import record

    try:
        bus = bus_from_args(args, BusConfig())
        for expr in (args.keyexpr, *args.exclude):
            zenoh.KeyExpr(expr)
        view = None
        if args.view == "on":
            from capsd.live_view import make_view

            view = make_view(view_from_args(args))
    except (ConfigError, zenoh.ZError) as exc:
        return _fail(f"record: {exc}", EXIT_CONFIG)

    def progress(n: int) -> None:
        print(f"record: {n} messages", file=sys.stderr, flush=True)

    try:
        with _StopOnSignal() as stop, open_session(bus) as session:
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
            )
    except KeyboardInterrupt:
        return EXIT_OK
    except (BusError, CapsdError, OSError) as exc:
        return _fail(f"record: {exc}", EXIT_FAILURE)
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
            return _fail(f"replay: {exc}", EXIT_CONFIG)
        for key, n in sorted(counts.items()):
            print(f"{n:8d}  {key}")
        return EXIT_OK
    if not args.speed > 0:
        return _fail(f"replay: --speed must be positive, not {args.speed}", EXIT_CONFIG)
    try:
        bus = bus_from_args(args, BusConfig())
    except ConfigError as exc:
        return _fail(str(exc), EXIT_CONFIG)
    try:
        channel_counts(args.file)  # a bad file fails before the first message
        with _StopOnSignal() as stop, open_session(bus) as session:
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
        return _fail(f"replay: {exc}", EXIT_CONFIG)
    except BusError as exc:
        return _fail(f"replay: {exc}", EXIT_FAILURE)
    print(f"replayed {sum(counts.values())} messages from {args.file}")
    return EXIT_OK


def _cmd_replay_check(args: argparse.Namespace) -> int:
    from capsd import replay_check

    if not args.speed > 0:
        return _fail(f"replay-check: --speed must be positive, not {args.speed}", EXIT_CONFIG)
    try:
        result = replay_check.run(args.file, locator_config=args.locator_config, speed=args.speed)
    except CapsdError as exc:
        return _fail(f"replay-check: {exc}", EXIT_CONFIG)
    return EXIT_OK if result.consistent else EXIT_FAILURE


def _cmd_import_bag(args: argparse.Namespace) -> int:
    from capsd.bag_import import import_bag

    try:
        result = import_bag(args.bag, args.mapping, args.output)
    except ConfigError as exc:
        return _fail(str(exc), EXIT_CONFIG)
    except CapsdError as exc:
        return _fail(f"import-bag: {exc}", EXIT_CONFIG)
    for key, n in sorted(result["written"].items()):
        print(f"{n:8d}  {key}")
    for what, n in sorted(result["rejected"].items()):
        print(f"rejected {n} messages of {what}", file=sys.stderr)
    if result["mapped_topics_missing"]:
        print(f"mapped but not in the bag: {result['mapped_topics_missing']}", file=sys.stderr)
    print(f"wrote {sum(result['written'].values())} messages to {args.output}")
    if result["empty_topics"]:
        return _fail(
            f"import-bag: mapped topics gave no message: {result['empty_topics']} "
            "(the rejections above say why)",
            EXIT_CONFIG,
        )
    return EXIT_OK


def add_view_flags(parser: argparse.ArgumentParser) -> None:
    """What the operator's view draws from: the services' configs; how images are sent."""
    parser.add_argument(
        "--locator-config",
        type=Path,
        default=None,
        help="the tank (box, fixtures) and sonar mount the services use (default: "
        "deploy/config/locator.yaml where present)",
    )
    parser.add_argument(
        "--asv-pose-config", type=Path, default=None, help="the LiDAR's place on the ASV"
    )
    parser.add_argument(
        "--images", choices=("jpeg", "png", "off"), default="jpeg", help="sonar fan images"
    )
    parser.add_argument("--jpeg-quality", type=int, default=75, choices=range(1, 101),
                        metavar="1-100", help="JPEG quality of the fan images")  # fmt: skip
    parser.add_argument("--fan-hz", type=positive_float, default=2.0, help="fan images per second")


def view_from_args(args: argparse.Namespace) -> Any:
    """The view's settings from `add_view_flags`' flags (ConfigError names a bad config)."""
    from capsd.live_view import view_settings

    locator = args.locator_config
    if locator is None and Path("deploy/config/locator.yaml").is_file():
        locator = Path("deploy/config/locator.yaml")
    return view_settings(
        locator,
        asv_pose_config=args.asv_pose_config,
        images=args.images,
        jpeg_quality=args.jpeg_quality,
        fan_hz=args.fan_hz,
    )


def _cmd_live_view(args: argparse.Namespace) -> int:
    from capsd.bus import open_session
    from capsd.live_view import serve

    try:
        bus = bus_from_args(args, BusConfig())
        settings = view_from_args(args)
    except ConfigError as exc:
        return _fail(str(exc), EXIT_CONFIG)
    print(f"live view on ws://{args.host}:{args.port} (open it in Foxglove)", flush=True)
    try:
        with _StopOnSignal() as stop, open_session(bus) as session:
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
        return _fail(str(exc), EXIT_FAILURE)
    return EXIT_OK


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
    )


def _cmd_bench_calibrate(args: argparse.Namespace) -> int:
    from capsd.bench import calibrate

    calibrate.bench(
        seeds=args.seeds,
        duration_s=args.duration,
        tank=args.tank,
        trajectory="square",
        out=args.out,
    )
    return EXIT_OK


def _cmd_bench_evaluate(args: argparse.Namespace) -> int:
    from capsd.bench import evaluate

    result = evaluate.bench(
        tank=args.tank,
        trajectory=args.trajectory,
        seed=args.seed,
        duration_s=args.duration,
        out_dir=args.out,
    )
    return EXIT_OK if all(result["verdicts"].values()) else EXIT_FAILURE


def _cmd_bench_consistency(args: argparse.Namespace) -> int:
    from capsd.bench import consistency

    consistency.bench(duration_s=args.duration, out=args.out)
    return EXIT_OK


def _cmd_bench_accuracy(args: argparse.Namespace) -> int:
    from capsd.bench import accuracy

    accuracy.bench(
        duration_s=args.duration,
        seed=args.seed,
        out_dir=args.out,
        install_errors=args.install_errors,
    )
    return 0


def _cmd_train_calibrate(args: argparse.Namespace) -> int:
    from capsd.train.detector import recalibrate

    try:
        recalibrate(args.weights, duration_s=args.duration)
    except CapsdError as exc:
        return _fail(f"calibrate: {exc}", EXIT_CONFIG)
    return EXIT_OK


def _cmd_label(args: argparse.Namespace) -> int:
    from capsd.config import load_config
    from capsd.services.locator.service import Config as LocatorConfig
    from capsd.train.labelling import label_recording, write_labels

    if not 0.0 < args.max_sigma <= 1.0:
        return _fail(f"label: --max-sigma must be in (0, 1] m, not {args.max_sigma}", EXIT_CONFIG)
    try:
        locator = load_config(args.locator_config, LocatorConfig)
        labels, summary = label_recording(
            args.recording, sonar=locator.sonar, max_sigma_m=args.max_sigma
        )
    except CapsdError as exc:
        return _fail(f"label: {exc}", EXIT_CONFIG)
    print(
        f"{summary.frames} frames, {summary.fixes} fixes, {summary.confident} confident and "
        f"tracked with a pose, {summary.labelled} labelled ({summary.outside_fan} outside the "
        f"fan, {summary.unreadable} unreadable messages)"
    )
    if not labels:
        return _fail("label: no frame could be labelled (no confident tracked fix)", EXIT_FAILURE)
    sheets = write_labels(labels, args.out)
    print(f"labels in {args.out}: {len(sheets)} contact sheets; reject crops in rejected.txt")
    return EXIT_OK


def _cmd_docs_figures(args: argparse.Namespace) -> int:
    from capsd.readme_figures import blocks, render

    try:
        text = args.file.read_text()
        new = render(text, root=args.file.resolve().parent)
    except OSError as exc:
        return _fail(f"docs figures: {args.file}: {exc}", EXIT_CONFIG)
    except CapsdError as exc:
        return _fail(f"docs figures: {args.file}: {exc}", EXIT_CONFIG)
    found = blocks(text)
    if args.check:
        if new != text:
            return _fail(
                f"docs figures: {args.file} is not up to date with its figures' JSON "
                "(run `capsd docs figures`)",
                EXIT_FAILURE,
            )
        print(f"{args.file}: {len(found)} figure blocks up to date")
        return EXIT_OK
    args.file.write_text(new)
    print(f"{args.file}: {len(found)} figure blocks written ({', '.join(n for n, _ in found)})")
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
        return _fail(f"evaluate: {exc}", EXIT_CONFIG)
    figures = report(evaluation, args.out, title=", ".join(p.name for p in args.recording))
    print((args.out / "evaluation.md").read_text())
    print(f"written: {args.out}/evaluation.md, evaluation.json and 3 PNGs")
    if figures["alignment"]["problems"]:
        return _fail("evaluate: the alignment is not determined (see above)", EXIT_FAILURE)
    return EXIT_OK


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from capsd.calibrate import calibrate, write_config
    from capsd.config import load_config
    from capsd.services.locator.service import Config as LocatorConfig

    try:
        locator = load_config(args.locator_config, LocatorConfig)
        if locator.tank is None:
            return _fail(
                f"calibrate: {args.locator_config} has no `tank` section: the walls are needed",
                EXIT_CONFIG,
            )
        fit, mount = calibrate(args.recording, mount=locator.sonar, tank=locator.tank)
    except CapsdError as exc:
        return _fail(f"calibrate: {exc}", EXIT_CONFIG)
    for line in fit.lines():
        print(line)
    write_config(args.locator_config, args.out, mount, fit, args.recording)
    print(
        f"wrote {args.out}: sonar yaw {mount.yaw_deg:g} deg, pitch {mount.pitch_deg:g} deg, "
        f"roll {mount.roll_deg:g} deg, position {list(mount.position_m)} m"
    )
    if not (fit.yaw_determined or fit.roll_determined or fit.shift_determined):
        return _fail("calibrate: nothing was determined; the config is unchanged", EXIT_FAILURE)
    return EXIT_OK


def _cmd_train_detector(args: argparse.Namespace) -> int:
    from capsd.train.detector import TrainConfig, train

    if args.finetune is not None:
        from capsd.train.finetune import FinetuneConfig, finetune

        try:
            finetune(
                args.weights,
                args.finetune,
                args.out,
                FinetuneConfig(seed=args.seed, workers=args.workers, threads=args.threads),
            )
        except CapsdError as exc:
            return _fail(f"finetune: {exc}", EXIT_CONFIG)
        return EXIT_OK

    config = TrainConfig(
        seed=args.seed,
        runs=args.runs,
        duration_s=args.run_duration,
        workers=args.workers,
        threads=args.threads,
        proposal_epochs=args.proposal_epochs,
        refine_epochs=args.refine_epochs,
        mining_runs=args.mining_runs,
        hard_runs=args.hard_runs,
        hard_rounds=args.hard_rounds,
        hard_epochs=args.hard_epochs,
        eval_duration_s=args.eval_duration,
        device=args.device,
        evaluate=args.evaluate,
    )
    try:
        train(config, args.out)
    except CapsdError as exc:
        return _fail(str(exc), EXIT_CONFIG)
    return EXIT_OK


def _cmd_bench_faults(args: argparse.Namespace) -> int:
    from capsd.bench import faults

    return faults.bench(out=args.out, baseline_s=args.baseline, skew_s=args.skew_duration)


def _cmd_bench_latency(args: argparse.Namespace) -> int:
    from capsd.bench import latency

    return latency.run(
        rates_hz=tuple(args.rates),
        duration_s=args.duration,
        warmup_s=args.warmup,
        out=args.out,
        busy_cores=args.busy_cores,
    )


def _cmd_bench_asv_pose(args: argparse.Namespace) -> int:
    from capsd.bench import asv_pose

    return asv_pose.run(seconds=args.duration)


def _cmd_bench_footprint(args: argparse.Namespace) -> int:
    from capsd.bench import footprint

    return footprint.bridge(runs=args.runs, settle_s=args.settle)


# ---------------------------------------------------------------------------- parser


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="capsd",
        description="CAP-SD: ROV positioning from an ASV's sonar and the ROV's depth, over Zenoh.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    run = sub.add_parser(
        "run", help="run one service", description="Run one service until SIGTERM/SIGINT."
    )
    run.add_argument(
        "service",
        choices=sorted(SERVICES),
        help="; ".join(f"{e.name}: {e.summary}" for e in SERVICES.values()),
    )
    run.add_argument("--config", type=Path, help="YAML config file (defaults apply when omitted)")
    run.add_argument(
        "--print-config", action="store_true", help="print the effective config as YAML and exit"
    )
    add_namespace_flags(run)
    add_bus_flags(run)
    run.set_defaults(func=_cmd_run)

    router = sub.add_parser(
        "router",
        help="run a Zenoh router",
        description="A Zenoh router for topside or a dev laptop (default listen "
        "tcp/127.0.0.1:7447). On a BlueOS ROV, join its router instead.",
    )
    router.add_argument("--config", type=Path, help="YAML config file")
    add_namespace_flags(router)
    add_bus_flags(router)
    router.set_defaults(func=_cmd_router)

    tap = sub.add_parser(
        "tap",
        help="print live payloads as JSON lines",
        description="Decode every payload on KEYEXPR and print one JSON line each.",
    )
    tap.add_argument("keyexpr", help="key expression, e.g. 'cap/**'")
    tap.add_argument(
        "--count", type=non_negative_int, default=0, help="stop after N payloads (0: no limit)"
    )
    tap.add_argument(
        "--duration",
        type=non_negative_float,
        default=0.0,
        help="stop after S seconds (0: no limit)",
    )
    tap.add_argument(
        "--bytes",
        choices=["summary", "full"],
        default="summary",
        help="print bulky byte fields as a size summary (default) or in full (base64)",
    )
    add_bus_flags(tap)
    tap.set_defaults(func=_cmd_tap)

    lst = sub.add_parser(
        "list",
        help="list live services and their health",
        description="Live services from their liveliness tokens, with their latest health.",
    )
    lst.add_argument("--site", help="only this site")
    lst.add_argument("--timeout", type=positive_float, default=1.0, help="query timeout in seconds")
    lst.add_argument("--json", action="store_true", help="one JSON object per service")
    lst.add_argument(
        "--clock-warn-ms",
        type=float,
        default=20.0,
        help="warn when a service's clock is off ours by more than this",
    )
    add_bus_flags(lst)
    lst.set_defaults(func=_cmd_list)

    mav = sub.add_parser(
        "mav",
        help="ArduSub set-up tools",
        description="Tools that talk to the autopilot over MAVLink.",
    )
    mav_sub = mav.add_subparsers(dest="mav_command", required=True, metavar="TOOL")
    check = mav_sub.add_parser(
        "check",
        help="check (and --apply) ArduSub parameters for external position",
        description="Read the autopilot's parameters, print what is wrong for CAP-SD's "
        "external position and the values to set; --apply sets them.",
    )
    check.add_argument(
        "--connect",
        default="tcp:127.0.0.1:5777",
        help="MAVLink connection (default: BlueOS's tcp:127.0.0.1:5777)",
    )
    check.add_argument("--apply", action="store_true", help="set the wrong parameters")
    check.add_argument(
        "--yaw-source",
        choices=["compass", "vision"],
        default="compass",
        help="EK3 yaw source: the compass (1) or the yaw CAP-SD sends (6)",
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
        help="Zenoh endpoint where the bridge's Health is (with --delay-ms auto)",
    )
    check.add_argument("--site", default="tank", help="site of the bridge (--delay-ms auto)")
    check.add_argument("--vehicle", default="rov", help="vehicle of the bridge (--delay-ms auto)")
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

    sim = sub.add_parser(
        "sim",
        help="the simulated tank: real time on the bus, or an offline dataset",
        description="Simulate the tank, both vehicles and every sensor. Without --offline it "
        "publishes in real time on the same keys the real drivers use; with "
        "--offline DIR it writes a dataset (format in simulator/dataset.py).",
    )
    _add_world_flags(sim)
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
    _add_world_flags(top)
    top.add_argument(
        "--duration", type=positive_float, default=120.0, help="seconds of track to draw"
    )
    top.add_argument("--out", "-o", required=True, help="PNG file to write")
    add_namespace_flags(top)
    add_bus_flags(top)
    top.set_defaults(func=_cmd_render_top_view)

    bench = sub.add_parser(
        "bench",
        help="benchmarks that print measured figures",
        description="Benchmarks: each prints figures measured in one run.",
    )
    bench_sub = bench.add_subparsers(dest="bench_command", required=True, metavar="BENCH")
    foot = bench_sub.add_parser(
        "footprint",
        help="start-up time and resident memory of the MAVLink bridge",
        description="Start the bridge against a local router and the autopilot stand-in; "
        "print start-up time to READY=1, resident memory and heavy libraries.",
    )
    foot.add_argument("--runs", type=positive_int, default=5, help="repetitions (median reported)")
    foot.add_argument("--settle", type=float, default=3.0, help="seconds running before RSS")
    foot.set_defaults(func=_cmd_bench_footprint)
    bsim = bench_sub.add_parser(
        "sim",
        help="achieved rate and CPU per stream of the real-time simulator",
        description="Run `capsd sim` as its own process; print each stream's achieved rate and "
        "CPU share next to its target, and the process's total CPU.",
    )
    bsim.add_argument("--tank", choices=["nfp", "mockup", "pond"], default="nfp")
    bsim.add_argument(
        "--trajectory",
        default="lawnmower",
        choices=["square", "lawnmower", "bouncing", "random", "two_floor"],
    )
    bsim.add_argument("--duration", type=positive_float, default=20.0, help="seconds measured")
    bsim.add_argument("--warmup", type=positive_float, default=4.0, help="seconds before measuring")
    bsim.set_defaults(func=_cmd_bench_sim)
    bdet = bench_sub.add_parser(
        "detect",
        help="detectors on held-out simulated frames against the labels",
        description="Detection rate, false alarms per frame, range/azimuth errors (median, "
        "p90) in the simulator's fixed look and in held-out look settings (docs/SONAR-"
        "VARIETY.md), with and without clutter overlapping the ROV and by range band; the "
        "paper's box-centre pipeline as the baseline; detections on real Oculus pings (none "
        "allowed); or time per frame.",
    )
    bdet.add_argument("--duration", type=positive_float, default=15.0, help="seconds per run")
    bdet.add_argument("--json", type=Path, default=None, help="also write the figures as JSON")
    bdet.add_argument(
        "--fixtures",
        type=Path,
        default=Path("tests/fixtures/oculus"),
        help="folder of raw Oculus captures without an ROV (skipped if absent)",
    )
    bdet.add_argument(
        "--detector", choices=["all", "classical", "cnn"], default="all", help="which to run"
    )
    bdet.add_argument(
        "--throughput",
        action="store_true",
        help="instead: per-frame latency on 512 x 1000 frames on one CPU core",
    )
    bdet.add_argument(
        "--frames", type=positive_int, default=300, help="frames timed (--throughput)"
    )
    bdet.add_argument(
        "--prior-sweep",
        type=float,
        nargs="+",
        metavar="LOGIT",
        help="instead: the CNN's hysteresis prior on the validation runs (e.g. 0 1 2)",
    )
    bdet.add_argument(
        "--weights",
        type=Path,
        nargs="+",
        metavar="PT",
        help="CNN weights to compare in one run (default: the shipped ones), each named by "
        "its folder",
    )
    bdet.set_defaults(func=_cmd_bench_detect)
    bft = bench_sub.add_parser(
        "finetune",
        help="the fine-tune path on a sonar look outside the training variety, before/after",
        description="A simulated first dive in a look never trained on, recorded; `capsd "
        "label` on it; `capsd train detector --finetune`; both weights on held-out runs.",
    )
    bft.add_argument("--out", type=Path, default=Path("reports/finetune"), help="report folder")
    bft.add_argument(
        "--duration", type=positive_float, default=60.0, help="first dive, simulated s"
    )
    bft.add_argument(
        "--eval-duration", type=positive_float, default=15.0, help="seconds per held-out run"
    )
    bft.set_defaults(func=_cmd_bench_finetune)
    bcal = bench_sub.add_parser(
        "calibrate",
        help="how well `capsd calibrate` recovers the simulator's hidden mount errors",
        description="Per seed, a simulated run of the calibration manoeuvre (the ASV turning "
        "on the spot) with realistic installation errors, through the services' own pose "
        "estimate; the fitted corrections against those the hidden errors call for.",
    )
    bcal.add_argument("--seeds", type=positive_int, default=5, help="runs (seeds 500, 501, ...)")
    bcal.add_argument(
        "--duration", type=positive_float, default=120.0, help="simulated seconds per run"
    )
    bcal.add_argument(
        "--tank",
        choices=["nfp", "mockup", "pond"],
        default="pond",
        help="pond: the tank held out of training and tuning",
    )
    bcal.add_argument(
        "--out", type=Path, default=Path("reports/calibrate.json"), help="figures as JSON"
    )
    bcal.set_defaults(func=_cmd_bench_calibrate)
    beval = bench_sub.add_parser(
        "evaluate",
        help="`capsd evaluate` on a simulated dive with a rotated, shifted, late reference",
        description="The offline pipeline's fixes and a motion-capture stand-in (the tank "
        "frame rotated 30 deg and shifted 2 m, stamps 150 ms late, 100 Hz, 0.5 mm noise, "
        "marker swaps, an occlusion) in one recording; `capsd evaluate`'s recovered transform, "
        "clock offset and MED against the known answer and the accuracy bench's MED.",
    )
    beval.add_argument("--tank", choices=["nfp", "mockup", "pond"], default="nfp")
    beval.add_argument(
        "--trajectory",
        choices=["square", "lawnmower", "bouncing", "random", "two_floor"],
        default="square",
    )
    beval.add_argument("--seed", type=int, default=0, help="simulator seed")
    beval.add_argument("--duration", type=positive_float, default=300.0, help="simulated seconds")
    beval.add_argument(
        "--out", type=Path, default=Path("reports/bench-evaluate"), help="report folder"
    )
    beval.set_defaults(func=_cmd_bench_evaluate)
    bcons = bench_sub.add_parser(
        "consistency",
        help="the locator's covariance floor derived on tuning runs, NEES on held-out ones",
        description="The smallest covariance floor with which 95 %% of fixes' NEES fall under "
        "the chi-square bound on tuning runs; the NEES on the held-out pond with it, with the "
        "configured floor and with none.",
    )
    bcons.add_argument("--duration", type=positive_float, default=60.0, help="seconds per run")
    bcons.add_argument(
        "--out", type=Path, default=Path("reports/consistency.json"), help="figures as JSON"
    )
    bcons.set_defaults(func=_cmd_bench_consistency)
    bacc = bench_sub.add_parser(
        "accuracy",
        help="the paper's results table: its method vs ours on the same runs, and an ablation",
        description="Five trajectories in the nfp tank, one in the mockup and two in the held-out "
        "pond through the "
        "offline pipeline; x/y/z RMSE, MED, p95, availability; targets; ablation; PNGs.",
    )
    bacc.add_argument(
        "--duration", type=positive_float, default=60.0, help="simulated seconds per run"
    )
    bacc.add_argument("--seed", type=int, default=0, help="simulator seed")
    bacc.add_argument("--out", type=Path, default=Path("reports/accuracy"), help="report folder")
    bacc.add_argument(
        "--install-errors",
        choices=("off", "realistic"),
        default="off",
        help="realistic: mount, sound-speed, depth and attitude errors drawn per run and "
        "unknown to the services (docs/INSTALL-ERRORS.md); the services stay uncalibrated",
    )
    bacc.set_defaults(func=_cmd_bench_accuracy)
    bpose = bench_sub.add_parser(
        "asv_pose",
        help="ASV pose error against the simulator's truth (both tanks, both modes)",
        description="Run the pose estimator on simulated IMU and LiDAR (waves on), ASV stationary "
        "and following; print RMS position, yaw, roll and pitch error and the targets.",
    )
    bpose.add_argument("--duration", type=positive_float, default=60.0, help="seconds per run")
    bpose.set_defaults(func=_cmd_bench_asv_pose)
    blat = bench_sub.add_parser(
        "latency",
        help="ping to autopilot latency per stage at 10/20/40 Hz, Zenoh floor, CPU and RSS",
        description="Run the whole pipeline (as `capsd demo`) once per sonar rate; print the "
        "latency of each stage and end to end (median, p99), the bare Zenoh floor for the "
        "same payload sizes, frames dropped, CPU share and resident memory per service, and "
        "the 40 Hz targets next to the measured values.",
    )
    blat.add_argument(
        "--rates", type=float, nargs="+", default=[10.0, 20.0, 40.0], help="sonar rates, Hz"
    )
    blat.add_argument(
        "--duration", type=positive_float, default=30.0, help="seconds measured per rate"
    )
    blat.add_argument(
        "--warmup", type=positive_float, default=5.0, help="seconds after the first VPE"
    )
    blat.add_argument(
        "--busy-cores",
        type=non_negative_int,
        default=0,
        help="other processes that each keep a core busy during the run (a loaded computer)",
    )
    blat.add_argument("--out", type=Path, default=Path("reports/latency"), help="report folder")
    blat.set_defaults(func=_cmd_bench_latency)
    bfault = bench_sub.add_parser(
        "faults",
        help="inject faults (kill -9, router restart, dropouts, clock skew); judge ArduSub input",
        description="Run the demo pipeline and inject one fault at a time; print per fault the "
        "recovery time, good fixes lost, and the estimates the autopilot received that were "
        "stale, invalid or wrong by more than 3 sigma against the simulator's truth.",
    )
    bfault.add_argument("--baseline", type=float, default=10.0, help="seconds without a fault")
    bfault.add_argument(
        "--skew-duration", type=float, default=25.0, help="seconds per clock-skew run"
    )
    bfault.add_argument("--out", type=Path, default=Path("reports/faults"), help="report folder")
    bfault.set_defaults(func=_cmd_bench_faults)
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
        default=Path("deploy/config/locator.yaml"),
        help="the live locator's config (the demo writes it to its logs folder)",
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
    dem.set_defaults(func=_cmd_demo)
    train = sub.add_parser("train", help="train a model").add_subparsers(
        dest="train_command", required=True
    )
    tdet = train.add_parser(
        "detector",
        help="train the polar CNN detector on simulated runs",
        description="Render simulator runs, train the proposal and refinement networks "
        "(deterministic for a seed), evaluate on held-out runs, write polar_net.pt and "
        "polar_net.json into --out. Defaults: about 29 minutes on 2 CPU cores.",
    )
    tdet.add_argument("--out", type=Path, default=Path("services/sonar_detect/weights"))
    tdet.add_argument("--seed", type=int, default=0)
    tdet.add_argument("--runs", type=positive_int, default=64, help="simulated training runs")
    tdet.add_argument("--run-duration", type=positive_float, default=60.0, help="seconds per run")
    tdet.add_argument("--workers", type=int, default=2, help="rendering processes")
    tdet.add_argument("--threads", type=int, default=2, help="torch threads for training")
    tdet.add_argument("--proposal-epochs", type=int, default=6)
    tdet.add_argument("--refine-epochs", type=int, default=6)
    tdet.add_argument("--mining-runs", type=int, default=24, help="runs for hard negatives")
    tdet.add_argument("--hard-runs", type=int, default=32, help="runs per hard-example round")
    tdet.add_argument("--hard-rounds", type=int, default=1, help="hard-example rounds")
    tdet.add_argument("--hard-epochs", type=int, default=2)
    tdet.add_argument(
        "--eval-duration", type=positive_float, default=20.0, help="seconds per held-out run"
    )
    tdet.add_argument(
        "--device",
        choices=("cpu", "cuda"),
        default="cpu",
        help="where the networks train (cuda: a GPU; rendering and calibration stay on the CPU)",
    )
    tdet.add_argument(
        "--evaluate",
        choices=("heldout", "none"),
        default="heldout",
        help="none: skip the held-out evaluation (run `capsd bench detect` after)",
    )
    tdet.add_argument(
        "--finetune",
        type=Path,
        metavar="LABELS",
        help="instead: adapt --weights to a `capsd label` folder (minutes on 2 cores)",
    )
    tdet.add_argument(
        "--weights",
        type=Path,
        default=Path("services/sonar_detect/weights/polar_net.pt"),
        help="the weights to fine-tune (--finetune)",
    )
    tdet.set_defaults(func=_cmd_train_detector)
    lab = sub.add_parser(
        "label",
        help="labelled sonar frames from a recording's confident tracked fixes",
        description="Project each good, tracked fix of a recording (sonar frames, ASV poses "
        "and fixes: `capsd record 'cap/**'`) back into its sonar frame; write labels.msgpack, "
        "numbered PNG contact sheets to check, and rejected.txt for the crops to leave out. "
        "`capsd train detector --finetune OUT` then adapts the detector.",
    )
    lab.add_argument("recording", type=Path, help="an MCAP recording")
    lab.add_argument("-o", "--out", type=Path, required=True, help="labels folder")
    lab.add_argument(
        "--locator-config",
        type=Path,
        default=Path("deploy/config/locator.yaml"),
        help="the locator's config during the dive (its sonar mount)",
    )
    lab.add_argument(
        "--max-sigma", type=float, default=0.05, help="largest horizontal fix sigma kept (m)"
    )
    lab.set_defaults(func=_cmd_label)
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
    docs = sub.add_parser(
        "docs",
        help="the README's figures: tables written from the benches' JSON",
        description="Documentation written by commands, never by hand.",
    )
    docs_sub = docs.add_subparsers(dest="docs_command", required=True, metavar="WHAT")
    dfig = docs_sub.add_parser(
        "figures",
        help="rewrite the tables between `<!-- figures: NAME JSON -->` markers",
        description="Each block names a table and the bench JSON it comes from (docs/figures/); "
        "the block is rewritten from that JSON with a line naming the bench's command. "
        "--check: exit 1 when the file is not up to date.",
    )
    dfig.add_argument("--file", type=Path, default=Path("README.md"), help="Markdown file")
    dfig.add_argument("--check", action="store_true", help="only say whether it is up to date")
    dfig.set_defaults(func=_cmd_docs_figures)
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
    tcal = train.add_parser(
        "calibrate",
        help="set the polar CNN's operating point on validation runs (part of `detector`)",
        description="Choose the confidence offset that keeps false alarms <= 0.005 per frame "
        "on validation runs (seeds used neither in training nor in the bench), save it in the "
        "weights and refresh their evaluation.",
    )
    tcal.add_argument(
        "--weights", type=Path, default=Path("services/sonar_detect/weights/polar_net.pt")
    )
    tcal.add_argument(
        "--duration", type=positive_float, default=10.0, help="seconds per validation run"
    )
    tcal.set_defaults(func=_cmd_train_calibrate)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    # `kill -USR1 <pid>` dumps every thread's stack to stderr: how a wedged service is diagnosed.
    faulthandler.register(signal.SIGUSR1, all_threads=True)
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except BrokenPipeError:
        # The reader went away (`capsd list --json | head`): not an error of ours. Point
        # stdout at nothing so the interpreter's final flush does not complain either.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK
    except ModuleNotFoundError as exc:
        extra = _EXTRA_OF.get((exc.name or "").split(".")[0])
        if extra is None:
            raise
        return _fail(
            f"`capsd {args.command}` needs {exc.name}: install the extra, "
            f"pip install 'capsd[{extra}]'",
            EXIT_CONFIG,
        )


# Which extra brings a module a command may need (pyproject.toml's optional dependencies).
_EXTRA_OF = {
    "torch": "detect",
    "scipy": "asv",
    "cv2": "asv",
    "matplotlib": "topside",
    "mcap": "topside",
    "foxglove": "topside",
    "pymavlink": "rov",
    "rosbags": "ros",
}


if __name__ == "__main__":
    sys.exit(main())
