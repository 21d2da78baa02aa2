"""`capsd replay-check`: replay a recording into a fresh locator and compare its fixes.

A router and a locator (the given config) are started on 127.0.0.1; the recording is replayed
without its fixes, health and logs, in recorded order; every fix the fresh locator puts is
matched by stamp with the recorded one and compared: input stamps, quality, the single-ping
position and the tracked position, bit for bit. The recording should start before the live
locator did (`capsd demo --record`), or the tracker's history differs at the start.
"""

from __future__ import annotations

import math
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

import zenoh

from capsd.bus import open_session
from capsd.codec import Codec
from capsd.config import BusConfig
from capsd.errors import CapsdError, PayloadError
from capsd.harness import Processes, free_port
from capsd.health import query_health
from capsd.keys import all_health, is_concrete
from capsd.payloads import RovFix
from capsd.recording import LOCATOR_CONFIG_ATTACHMENT, attachment, channel_counts, read, replay

_FIX_SUFFIX = "/locator/fix"


@dataclass(frozen=True)
class Comparison:
    recorded: int
    replayed: int
    matched: int
    same_inputs: int
    same_quality: int
    raw_identical: int
    tracked_identical: int
    # Same input stamps and the same track so far, yet a different quality or single-ping fix:
    # must never happen. (Once the tracks differ, the gate may take or refuse another echo.)
    unexplained: int
    # Tracked estimates all identical up to the first fix whose inputs differ.
    tracked_identical_until_inputs_differ: bool
    max_raw_difference_m: float
    max_tracked_difference_m: float
    first_difference: str | None
    # Good fixes among the matched pings: what another locator config would have made of the
    # same inputs (availability, open loop: the vehicles flew as they did live).
    recorded_good: int = 0
    replayed_good: int = 0

    @property
    def identical(self) -> bool:
        n = self.recorded
        return n > 0 and self.replayed == n and self.matched == n and self.first_difference is None

    @property
    def consistent(self) -> bool:
        """Every fix replayed, and each difference explained by an input the live one lacked."""
        n = self.recorded
        return (
            n > 0
            and self.replayed == n
            and self.matched == n
            and self.unexplained == 0
            and self.tracked_identical_until_inputs_differ
        )


def _distance(a: tuple[float, ...] | None, b: tuple[float, ...] | None) -> float:
    if a is None and b is None:
        return 0.0
    if a is None or b is None:
        return math.inf
    return math.dist(a, b)


def _inputs(fix: RovFix) -> tuple[int | None, ...]:
    return (fix.asv_pose_stamp_ns, fix.depth_stamp_ns, fix.attitude_stamp_ns)


def compare(recorded: dict[int, RovFix], replayed: dict[int, RovFix]) -> Comparison:
    """Fixes matched by stamp; counts of what is the same and the largest differences.

    A live locator solves a ping with the inputs in by then; one stamped before the ping but
    late on the bus (the fix names the inputs it used) makes that fix, and the track after
    it, differ from the replay's; after it the track gate may take or refuse an echo the other
    did not, so quality and single-ping fix may differ for the same inputs. Any difference
    before the first input difference is a determinism bug: `unexplained`.
    """
    # Pings after the recording's last fix were still in flight when it stopped: not compared.
    end = max(recorded, default=-1)
    replayed = {stamp: fix for stamp, fix in replayed.items() if stamp <= end}
    common = sorted(set(recorded) & set(replayed))
    same_inputs = same_quality = raw_same = tracked_same = unexplained = 0
    max_raw = max_tracked = 0.0
    first: str | None = None
    inputs_differed = False
    tracked_until = True
    for stamp in common:
        a, b = recorded[stamp], replayed[stamp]
        inputs_ok = _inputs(a) == _inputs(b)
        quality_ok = a.quality == b.quality
        raw_ok = a.raw_position_m == b.raw_position_m and a.raw_covariance_m2 == b.raw_covariance_m2
        tracked_ok = a.position_m == b.position_m and a.covariance_m2 == b.covariance_m2
        inputs_differed = inputs_differed or not inputs_ok
        if not inputs_differed and not tracked_ok:
            tracked_until = False
        same_inputs += inputs_ok
        same_quality += quality_ok
        raw_same += raw_ok
        tracked_same += tracked_ok
        unexplained += not inputs_differed and not (quality_ok and raw_ok)
        max_raw = max(max_raw, _distance(a.raw_position_m, b.raw_position_m))
        max_tracked = max(max_tracked, _distance(a.position_m, b.position_m))
        if first is None and not (inputs_ok and quality_ok and raw_ok and tracked_ok):
            first = (
                f"ping {stamp}: inputs {_inputs(a)} vs {_inputs(b)}, quality {a.quality} vs "
                f"{b.quality}, raw {a.raw_position_m} vs {b.raw_position_m}, tracked "
                f"{a.position_m} vs {b.position_m}"
            )
    missing = sorted(set(recorded) ^ set(replayed))
    if first is None and missing:
        side = "replay" if missing[0] in recorded else "recording"
        first = f"ping {missing[0]}: no fix in the {side}"
    return Comparison(
        recorded=len(recorded),
        replayed=len(replayed),
        matched=len(common),
        same_inputs=same_inputs,
        same_quality=same_quality,
        raw_identical=raw_same,
        tracked_identical=tracked_same,
        unexplained=unexplained,
        tracked_identical_until_inputs_differ=tracked_until,
        max_raw_difference_m=max_raw,
        max_tracked_difference_m=max_tracked,
        first_difference=first,
        recorded_good=sum(recorded[s].quality == "good" for s in common),
        replayed_good=sum(replayed[s].quality == "good" for s in common),
    )


def recorded_fixes(path: Path) -> tuple[str, dict[int, RovFix]]:
    """The recording's fix key and its fixes by stamp."""
    keys = [k for k in channel_counts(path) if k.endswith(_FIX_SUFFIX)]
    if len(keys) != 1:
        raise CapsdError(f"{path}: expected the fixes of one locator, found keys {keys}")
    codec = Codec(RovFix)
    fixes = {}
    for item in read(path):
        if item.key == keys[0]:
            fix = codec.decode(item.data, encoding=item.encoding, key_expr=item.key)
            fixes[fix.stamp_ns] = fix
    return keys[0], fixes


def run(
    recording: Path,
    *,
    locator_config: Path | None,
    speed: float,
    stream: TextIO = sys.stdout,
) -> Comparison:
    """Replay into a fresh locator on a private router; the comparison (also printed).

    `locator_config` None: the config the recording carries (LOCATOR_CONFIG_ATTACHMENT), else
    the shipped deploy/config/locator.yaml; which one is printed.
    """
    fix_key, recorded = recorded_fixes(recording)
    attached = attachment(recording, LOCATOR_CONFIG_ATTACHMENT) if locator_config is None else None
    site, vehicle = fix_key.split("/")[1:3]
    got: dict[int, RovFix] = {}
    lock = threading.Lock()
    codec = Codec(RovFix)

    def on_fix(sample: zenoh.Sample) -> None:
        if not is_concrete(str(sample.key_expr)):
            return
        try:
            fix = codec.decode(
                sample.payload.to_bytes(), encoding=str(sample.encoding), key_expr=fix_key
            )
        except PayloadError:
            return
        with lock:
            got[fix.stamp_ns] = fix

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with tempfile.TemporaryDirectory(prefix="capsd-replay-check-") as tmp:
        procs = Processes(Path(tmp))
        if locator_config is not None:
            config, origin = locator_config, str(locator_config)
        elif attached is not None:
            config, origin = Path(tmp) / "locator.yaml", "the recording's, attached by capsd record"
            config.write_bytes(attached)
        else:
            config = Path("deploy/config/locator.yaml")
            origin = f"{config}: the recording carries none"
        try:
            procs.start("router", ["-m", "capsd", "router", "--listen", endpoint])
            time.sleep(1.0)
            args = ["run", "locator", "--config", str(config), "--connect", endpoint]
            locator = procs.start("locator", ["-m", "capsd", *args])
            with open_session(BusConfig(connect=(endpoint,))) as session:
                sub = session.declare_subscriber(fix_key, on_fix)
                deadline = time.monotonic() + 30.0
                while (
                    query_health(
                        session, site=site, vehicle=vehicle, service="locator", timeout_s=0.5
                    )
                    is None
                ):
                    if time.monotonic() > deadline or locator.popen.poll() is not None:
                        raise CapsdError(
                            f"the fresh locator did not start: {locator.log.read_text()[-2000:]}"
                        )
                print(
                    f"replaying {recording} into a fresh locator (config: {origin}) at {speed:g}x",
                    file=stream,
                    flush=True,
                )
                replay(
                    session,
                    recording,
                    speed=speed,
                    stop=threading.Event(),
                    # Inputs only: not the fixes, not Health (nor BlueOS-style logs, not
                    # under cap/), or the fresh locator would compete with its own past.
                    exclude=(fix_key, all_health(site), "services/**"),
                )
                # Until the last ping's fix is in (or nothing new for 2 s).
                last, quiet_since = -1, time.monotonic()
                while time.monotonic() - quiet_since < 2.0:
                    time.sleep(0.1)
                    with lock:
                        n = len(got)
                    if n != last:
                        last, quiet_since = n, time.monotonic()
                    if n >= len(recorded):
                        break
                sub.undeclare()
        finally:
            procs.stop()
    with lock:
        result = compare(recorded, dict(got))
    print(report(result), file=stream, flush=True)
    return result


def report(c: Comparison) -> str:
    n = max(c.matched, 1)
    lines = [
        f"fixes: recorded {c.recorded}, replayed {c.replayed}, matched by ping stamp {c.matched}",
        f"  same input stamps   {c.same_inputs:6d}  ({100 * c.same_inputs / n:.1f}%)",
        f"  same quality        {c.same_quality:6d}  ({100 * c.same_quality / n:.1f}%)",
        f"  raw fix identical   {c.raw_identical:6d}  ({100 * c.raw_identical / n:.1f}%), "
        f"largest difference {c.max_raw_difference_m:.6f} m",
        f"  tracked identical   {c.tracked_identical:6d}  ({100 * c.tracked_identical / n:.1f}%), "
        f"largest difference {c.max_tracked_difference_m:.6f} m",
        f"  a different fix before any input differed (must be 0): {c.unexplained}",
        f"  good fixes          recorded {c.recorded_good} ({100 * c.recorded_good / n:.1f}%), "
        f"replayed {c.replayed_good} ({100 * c.replayed_good / n:.1f}%)",
    ]
    if c.identical:
        lines.append("  IDENTICAL")
    else:
        lines.append(f"  first difference: {c.first_difference}")
        if c.consistent:
            lines.append(
                "  CONSISTENT: every difference is a fix whose live inputs lacked one stamped "
                "before its ping (late on the bus; see the locator's late_inputs count), or "
                "the track after it"
            )
        else:
            lines.append("  NOT CONSISTENT")
    return "\n".join(lines)
