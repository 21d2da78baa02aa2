"""The commands behind `capsd sim` and `capsd render` (the CLI parses their arguments)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import msgspec
import numpy as np

from capsd.errors import CapsdError
from capsd.launch import EXIT_CONFIG, EXIT_FAILURE, EXIT_OK, service_config_from_args
from capsd.payloads import SonarDetections, SonarFrame, SonarLabel
from capsd.simulator import dataset, render
from capsd.simulator.config import Config
from capsd.simulator.sim import Simulation


def config_from_args(args: argparse.Namespace) -> Config:
    """The sim config from --config and the bus flags, then --tank/--trajectory/--seed."""
    config = service_config_from_args(Config, args)
    changes = {
        name: getattr(args, name)
        for name in ("tank", "trajectory", "seed")
        if getattr(args, name, None) is not None
    }
    return msgspec.structs.replace(config, **changes) if changes else config


def run_sim(args: argparse.Namespace, config: Config) -> int:
    if args.offline is not None:
        meta = dataset.write(Path(args.offline), config, duration_s=args.duration)
        counts = ", ".join(f"{s['subject']}@{s['vehicle']}: {s['count']}" for s in meta["streams"])
        print(
            f"wrote {args.offline}: {args.duration:g} s of {config.tank}/{config.trajectory}, "
            f"seed {config.seed} ({counts})"
        )
        return EXIT_OK
    from capsd.simulator.service import main

    return main(config)


def render_fan(args: argparse.Namespace) -> int:
    frame = label = detections = None
    try:
        for record in dataset.read(Path(args.dataset)):
            payload = record.payload
            if isinstance(payload, SonarFrame) and payload.ping_id == args.ping:
                frame = payload
            elif isinstance(payload, SonarLabel) and payload.ping_id == args.ping:
                label = payload
            elif isinstance(payload, SonarDetections) and payload.ping_id == args.ping:
                detections = payload
            if (
                frame is not None
                and label is not None
                and (detections is not None or getattr(payload, "ping_id", -1) > args.ping)
            ):
                break
    except CapsdError as exc:
        print(f"capsd: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    if frame is None:
        print(f"capsd: no sonar frame with ping id {args.ping} in {args.dataset}", file=sys.stderr)
        return EXIT_FAILURE
    render.draw_fan(frame, label, detections, Path(args.out))
    print(f"wrote {args.out}")
    return EXIT_OK


def render_top_view(args: argparse.Namespace, config: Config) -> int:
    sim = Simulation(config, horizon_s=args.duration + 5.0)
    times = np.arange(0.0, args.duration, 0.1)
    rov = np.array([sim.rov_state(t).position_m[:2] for t in times])
    asv = np.array([sim.asv_pose(t).translation[:2] for t in times])
    render.draw_top_view(sim.tank, rov, asv, Path(args.out))
    print(f"wrote {args.out}")
    return EXIT_OK
