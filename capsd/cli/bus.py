"""`capsd run`, `router`, `tap`, `list`: services and the bus."""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from pathlib import Path
from typing import Any

from capsd.cli.common import (
    StopOnSignal,
    Subcommands,
    fail,
    guarded,
)
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
    service_config_from_args,
)
from capsd.logs import setup_stderr_logging
from capsd.registry import SERVICES


class RouterConfig(ServiceConfig, frozen=True, kw_only=True):
    """A Zenoh router (topside or a dev laptop); it reports health like any service."""

    bus: BusConfig = BusConfig(mode="router", connect=(), listen=("tcp/127.0.0.1:7447",))


def _cmd_run(args: argparse.Namespace) -> int:
    entry = SERVICES[args.service]
    config_cls, service_main = entry.load()
    try:
        config = service_config_from_args(config_cls, args)
    except ConfigError as exc:
        return fail(str(exc), EXIT_CONFIG)
    if args.print_config:
        print(dump_config(config), end="")
        return EXIT_OK
    setup_stderr_logging(entry.name, config.log_level)
    return guarded(lambda: service_main(config))


def _cmd_router(args: argparse.Namespace) -> int:
    try:
        config = service_config_from_args(RouterConfig, args)
    except ConfigError as exc:
        return fail(str(exc), EXIT_CONFIG)
    if config.bus.mode != "router":
        return fail("config error: `bus.mode` must be 'router' for `capsd router`", EXIT_CONFIG)
    setup_stderr_logging("router", config.log_level)
    from capsd.runner import ServiceRunner

    def router_main() -> int:
        with ServiceRunner("router", config) as runner:
            runner.run()
        return EXIT_OK

    return guarded(router_main)


def _cmd_tap(args: argparse.Namespace) -> int:
    from capsd.bus import open_session
    from capsd.codec import decode_any, split_encoding, to_builtins

    try:
        bus = bus_from_args(args, BusConfig())
    except ConfigError as exc:
        return fail(str(exc), EXIT_CONFIG)
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
        with StopOnSignal() as stop, open_session(bus) as session:
            subscriber = session.declare_subscriber(args.keyexpr, on_sample)
            deadline = time.monotonic() + args.duration if args.duration else None
            while not (stop.is_set() or done.is_set()):
                if deadline is not None and time.monotonic() >= deadline:
                    break
                stop.wait(0.05)
            done.set()
            subscriber.undeclare()
    except BusError as exc:
        return fail(str(exc), EXIT_FAILURE)
    except Exception as exc:
        return fail(f"tap failed on '{args.keyexpr}': {exc}", EXIT_CONFIG)
    return EXIT_OK


def _cmd_list(args: argparse.Namespace) -> int:
    from capsd.bus import open_session
    from capsd.codec import Codec
    from capsd.keys import all_alive, all_health, parse_service_key
    from capsd.payloads import Health

    try:
        bus = bus_from_args(args, BusConfig())
    except ConfigError as exc:
        return fail(str(exc), EXIT_CONFIG)
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
        return fail(str(exc), EXIT_FAILURE)
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


def register(sub: Subcommands) -> None:
    """Add the bus verbs to the `capsd` parser's subcommands."""
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
