"""Helpers the `capsd` verb groups share: failing with a message, signals, world and view flags."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path
from typing import Any, TypeAlias

from capsd.errors import BusError, ConfigError
from capsd.launch import (
    EXIT_CONFIG,
    EXIT_FAILURE,
    EXIT_OK,
    positive_float,
)
from capsd.stop_signal import set_after_handler

# What `add_subparsers` returns: each verb group's `register` adds its verbs to it.
Subcommands: TypeAlias = "argparse._SubParsersAction[argparse.ArgumentParser]"


def fail(message: str, code: int) -> int:
    """Print `capsd: MESSAGE` on stderr and return the exit code `code`."""
    print(f"capsd: {message}", file=sys.stderr)
    return code


def guarded(body: Any) -> int:
    """Run `body()`: config errors exit 2, bus errors 1, Ctrl-C is a clean stop (0)."""
    try:
        return int(body())
    except ConfigError as exc:
        return fail(str(exc), EXIT_CONFIG)
    except BusError as exc:
        return fail(str(exc), EXIT_FAILURE)
    except KeyboardInterrupt:
        return EXIT_OK


class StopOnSignal:
    """Turn SIGINT/SIGTERM into an Event for short-lived tools."""

    def __init__(self) -> None:
        self.event = threading.Event()

    def __enter__(self) -> threading.Event:
        self._old = {
            s: signal.signal(s, lambda *_: set_after_handler(self.event))
            for s in (signal.SIGINT, signal.SIGTERM)
        }
        return self.event

    def __exit__(self, *_exc: object) -> None:
        for signum, handler in self._old.items():
            signal.signal(signum, handler)


def add_world_flags(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", type=Path, help="simulator YAML config (defaults otherwise)")
    parser.add_argument("--tank", choices=["nfp", "mockup", "pond"], help="tank preset")
    parser.add_argument(
        "--trajectory",
        help="square, lawnmower, bouncing, random or two_floor",
        choices=["square", "lawnmower", "bouncing", "random", "two_floor"],
    )
    parser.add_argument("--seed", type=int, help="random seed (the same seed, the same run)")


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
