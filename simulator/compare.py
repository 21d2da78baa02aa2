"""Live accuracy of fixes against the simulator's ground truth (for the demo and dry runs)."""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import zenoh

from capsd import topics
from capsd.bus import open_session
from capsd.codec import Codec
from capsd.config import BusConfig
from capsd.errors import BusError, ConfigError, PayloadError
from capsd.keys import is_concrete
from capsd.launch import add_bus_flags, bus_from_args
from capsd.payloads import RovFix, SonarLabel


class Comparison:
    """Pairs each fix with the label of the same ping (same stamp) and keeps the errors."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.truth: dict[int, SonarLabel] = {}
        self.pending: dict[int, RovFix] = {}
        self.errors_m: list[float] = []  # tracked estimate (what goes to the autopilot)
        self.raw_errors_m: list[float] = []  # single-ping fix
        self.fixes = 0
        self.good = 0

    def add_label(self, truth: SonarLabel) -> None:
        with self.lock:
            self.truth[truth.stamp_ns] = truth
            fix = self.pending.pop(truth.stamp_ns, None)
            if fix is not None:
                self._score(fix, truth)
            if len(self.truth) > 1000:
                del self.truth[min(self.truth)]

    def add_fix(self, fix: RovFix) -> None:
        with self.lock:
            self.fixes += 1
            truth = self.truth.get(fix.stamp_ns)
            if truth is None:
                self.pending[fix.stamp_ns] = fix
            else:
                self._score(fix, truth)

    def _score(self, fix: RovFix, truth: SonarLabel) -> None:
        if fix.quality != "good":
            return
        self.good += 1
        if fix.raw_position_m is not None:
            self.raw_errors_m.append(math.dist(fix.raw_position_m, truth.rov_position_m))
        estimate = fix.position_m or fix.raw_position_m  # per-frame methods have no track
        if estimate is not None:
            self.errors_m.append(math.dist(estimate, truth.rov_position_m))

    def line(self) -> str:
        with self.lock:
            errors, raw = list(self.errors_m), list(self.raw_errors_m)
            fixes, good = self.fixes, self.good
        if not errors:
            return f"fixes {fixes:5d}  good {good:5d}"
        ordered = sorted(errors)
        p95 = ordered[min(len(ordered) - 1, int(0.95 * len(ordered)))]
        return (
            f"fixes {fixes:5d}  good {good:5d} ({100.0 * good / max(fixes, 1):5.1f}%)  "
            f"error vs truth: mean {1000 * statistics.fmean(errors):6.1f} mm  "
            f"median {1000 * statistics.median(errors):6.1f} mm  p95 {1000 * p95:6.1f} mm"
            + (f"  (single-ping mean {1000 * statistics.fmean(raw):6.1f} mm)" if raw else "")
        )


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m simulator.compare",
        description="Print live fix accuracy against the simulator's ground truth.",
    )
    parser.add_argument("--site", default="tank")
    parser.add_argument("--locator-vehicle", default="topside")
    parser.add_argument("--sim-vehicle", default="sim")
    parser.add_argument("--duration", type=float, default=20.0, help="seconds to watch")
    add_bus_flags(parser)
    args = parser.parse_args(argv)
    try:
        bus = bus_from_args(args, BusConfig())
    except ConfigError as exc:
        print(f"compare: {exc}", file=sys.stderr)
        return 2
    comparison = Comparison()
    fix_codec, truth_codec = Codec(RovFix), Codec(SonarLabel)

    def decoding(codec: Codec[Any], sink: Callable[[Any], None]) -> Callable[[zenoh.Sample], None]:
        def on_sample(sample: zenoh.Sample) -> None:
            key = str(sample.key_expr)
            if not is_concrete(key):
                return
            try:
                sink(
                    codec.decode(
                        sample.payload.to_bytes(), encoding=str(sample.encoding), key_expr=key
                    )
                )
            except PayloadError as exc:
                print(f"compare: {exc}", file=sys.stderr)

        return on_sample

    try:
        with open_session(bus) as session:
            fix_sub = session.declare_subscriber(
                topics.ROV_FIX.key(args.site, args.locator_vehicle),
                decoding(fix_codec, comparison.add_fix),
            )
            truth_sub = session.declare_subscriber(
                topics.SIM_LABEL.key(args.site, args.sim_vehicle),
                decoding(truth_codec, comparison.add_label),
            )
            end = time.monotonic() + args.duration
            try:
                while time.monotonic() < end:
                    time.sleep(min(2.0, max(0.0, end - time.monotonic())))
                    print(comparison.line(), flush=True)
            except KeyboardInterrupt:
                pass
            fix_sub.undeclare()
            truth_sub.undeclare()
    except BusError as exc:
        print(f"compare: {exc}", file=sys.stderr)
        return 1
    print("final: " + comparison.line())
    return 0


if __name__ == "__main__":
    sys.exit(main())
