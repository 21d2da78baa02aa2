"""One way to start anything on the bus: shared flags, config loading, overrides, exit codes.

systemd units, tests and people all go through here, so a service starts the same way for each.
Exit codes: 0 clean stop, 1 runtime failure, 2 bad configuration or usage (systemd units set
RestartPreventExitStatus=2 so a bad config never becomes a restart loop).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import TypeVar

import msgspec

from capsd.config import BusConfig, ServiceConfig, load_config
from capsd.errors import ConfigError, KeyExprError

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_CONFIG = 2

S = TypeVar("S", bound=ServiceConfig)


def positive_float(text: str) -> float:
    """An argparse type: a finite number > 0 (durations, timeouts, speeds)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a number") from None
    if not (math.isfinite(value) and value > 0.0):
        raise argparse.ArgumentTypeError(f"{text} must be a positive number")
    return value


def non_negative_float(text: str) -> float:
    """An argparse type: a finite number >= 0 (0 meaning "no limit" where a flag says so)."""
    if text.strip() in ("0", "0.0"):
        return 0.0
    return positive_float(text)


def non_negative_int(text: str) -> int:
    """An argparse type: a whole number >= 0 (counts; 0 meaning "no limit" where said)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a whole number") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text} must not be negative")
    return value


def positive_int(text: str) -> int:
    """An argparse type: a whole number > 0 (runs, frames)."""
    value = non_negative_int(text)
    if value == 0:
        raise argparse.ArgumentTypeError("0 is not allowed here")
    return value


def add_bus_flags(parser: argparse.ArgumentParser) -> None:
    """Flags that override the `bus` section of a config (or the defaults, for tools)."""
    group = parser.add_argument_group("bus (override the config's `bus` section)")
    group.add_argument("--mode", choices=["client", "peer", "router"], help="Zenoh mode")
    group.add_argument(
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help="endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable; replaces the config's)",
    )
    group.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help="endpoint to listen on (repeatable; replaces the config's)",
    )
    group.add_argument(
        "--multicast-scouting", choices=["off", "on"], help="Zenoh multicast scouting"
    )
    group.add_argument(
        "--tls",
        nargs=3,
        metavar=("CA", "CERT", "KEY"),
        help="mutual TLS to a secure site router (tls/ endpoints): the site's CA, this "
        "identity's certificate and key (a laptop: capsd-laptop.pem/.key, read-only)",
    )


def add_namespace_flags(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("namespace (override the config)")
    group.add_argument("--site", help="site name in keys cap/<site>/...")
    group.add_argument("--vehicle", help="vehicle name in keys cap/<site>/<vehicle>/...")


def bus_from_args(args: argparse.Namespace, base: BusConfig) -> BusConfig:
    """`base` with the bus flags applied; re-validated, so a bad flag is a ConfigError."""
    changes: dict[str, object] = {}
    if args.mode is not None:
        changes["mode"] = args.mode
    if args.connect is not None:
        changes["connect"] = tuple(args.connect)
    if args.listen is not None:
        changes["listen"] = tuple(args.listen)
    if args.multicast_scouting is not None:
        changes["multicast_scouting"] = args.multicast_scouting
    if args.mode == "router" and args.connect is None:
        changes.setdefault("connect", ())
    if getattr(args, "tls", None) is not None:
        ca, cert, key = args.tls
        changes["tls"] = {"ca_certificate": ca, "certificate": cert, "private_key": key}
    data = msgspec.to_builtins(base)
    data.update(changes)
    try:
        return msgspec.convert(data, BusConfig, strict=False)
    except msgspec.ValidationError as exc:
        raise ConfigError("command line", "bus", str(exc)) from None


def service_config_from_args(
    cls: type[S], args: argparse.Namespace, *, default: S | None = None
) -> S:
    """Load `--config` (or the defaults) into `cls`, then apply namespace and bus flags."""
    config_path: Path | None = getattr(args, "config", None)
    config = load_config(config_path, cls) if config_path is not None else (default or cls())
    changes: dict[str, object] = {"bus": bus_from_args(args, config.bus)}
    for name in ("site", "vehicle"):
        value = getattr(args, name, None)
        if value is not None:
            changes[name] = value
    try:
        return msgspec.structs.replace(config, **changes)
    except (ValueError, KeyExprError) as exc:
        raise ConfigError("command line", "", str(exc)) from None
