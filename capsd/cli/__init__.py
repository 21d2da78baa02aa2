"""The `capsd` command: one module per verb group, assembled here."""

from __future__ import annotations

import argparse
import faulthandler
import os
import signal
import sys
from collections.abc import Sequence

from capsd.cli import bench, bus, calibrate, demo, docs, mav, mission, recording, sim, train
from capsd.cli.bus import RouterConfig
from capsd.cli.common import fail
from capsd.errors import CapsdError, ConfigError
from capsd.launch import EXIT_CONFIG, EXIT_FAILURE, EXIT_OK

__all__ = ["RouterConfig", "build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    """The whole `capsd` argument parser, verbs in the order `capsd --help` lists them."""
    parser = argparse.ArgumentParser(
        prog="capsd",
        description="CAP-SD: ROV positioning from an ASV's sonar and the ROV's depth, over Zenoh.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for group in (bus, mav, mission, sim, bench, recording, demo, train, calibrate, docs):
        group.register(sub)
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
    except ConfigError as exc:
        return fail(f"capsd {args.command}: {exc}", EXIT_CONFIG)
    except CapsdError as exc:
        # What a verb did not catch itself: still a message, never a traceback.
        return fail(f"capsd {args.command}: {exc}", EXIT_FAILURE)
    except ModuleNotFoundError as exc:
        extra = _EXTRA_OF.get((exc.name or "").split(".")[0])
        if extra is None:
            raise
        return fail(
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
