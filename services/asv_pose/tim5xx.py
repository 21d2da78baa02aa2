"""The SICK TiM5xx client: its own process, LiDAR scans from a TiM5xx onto the bus.

Connects to the scanner's CoLa-A port (2112), asks for the scan stream (`sEN LMDscandata 1`)
and publishes each `sSN LMDscandata` as a LidarScan in the scanner frame: SICK's angles (90 deg
straight ahead) turned by `angle_offset_deg` (-90: 0 rad ahead, counter-clockwise positive;
an inverted mount mirrors them). Ranges outside [range_min_m, range_max_m] become 0 (no
return). A telegram that does not parse is counted and skipped; a stream that ends, errs or
stalls for `stall_timeout_s` is reconnected; all of it shows in Health.

Stamps: the scan's first beam is taken to be one scan period plus `latency_offset_s` before the
telegram's arrival (the TiM sends a scan once it is complete).
"""

from __future__ import annotations

import logging
import math
import socket
import time
from collections import Counter
from typing import Annotated, Literal

import msgspec

from capsd import topics
from capsd.config import ServiceConfig
from capsd.payloads import LidarScan
from capsd.protocols.cola import (
    START_STREAM,
    ColaError,
    ColaStream,
    ScanTelegram,
    parse_scan,
)
from capsd.runner import Publisher, ServiceRunner

logger = logging.getLogger(__name__)
COLA_PORT = 2112


class Config(ServiceConfig, frozen=True, kw_only=True):
    """TiM5xx client configuration."""

    vehicle: str = "asv"
    address: str = "192.168.0.1"  # the TiM's factory address
    port: Annotated[int, msgspec.Meta(ge=1, le=65535)] = COLA_PORT
    angle_offset_deg: Annotated[float, msgspec.Meta(ge=-360.0, le=360.0)] = -90.0
    mount: Literal["upright", "inverted"] = "upright"
    range_min_m: Annotated[float, msgspec.Meta(ge=0.0, le=10.0)] = 0.05
    range_max_m: Annotated[float, msgspec.Meta(gt=0.0, le=100.0)] = 25.0
    latency_offset_s: Annotated[float, msgspec.Meta(ge=0.0, le=1.0)] = 0.0
    stall_timeout_s: Annotated[float, msgspec.Meta(gt=0.0, le=60.0)] = 2.0
    reconnect_s: Annotated[float, msgspec.Meta(gt=0.0, le=60.0)] = 1.0


def to_scan(item: ScanTelegram, *, config: Config, stamp_ns: int, seq: int) -> LidarScan:
    """The bus payload of one scan telegram."""
    sign = 1.0 if config.mount == "upright" else -1.0
    start = math.radians(item.start_angle_deg + config.angle_offset_deg) * sign
    step = math.radians(item.step_deg) * sign
    ranges = [r if config.range_min_m <= r <= config.range_max_m else 0.0 for r in item.ranges_m]
    intensities = list(item.intensities)
    if sign < 0:  # keep the increment positive: reverse the order
        start = start + step * (len(ranges) - 1)
        step = -step
        ranges.reverse()
        intensities.reverse()
    period = 1.0 / item.scan_frequency_hz if item.scan_frequency_hz > 0 else 0.0
    return LidarScan(
        stamp_ns=stamp_ns,
        seq=seq,
        angle_min_rad=start,
        angle_increment_rad=step,
        time_increment_s=period * (item.step_deg / 360.0),
        range_min_m=config.range_min_m,
        range_max_m=config.range_max_m,
        ranges_m=tuple(ranges),
        intensities=tuple(intensities),
    )


class Client:
    """Connection state and the telegram stream; `step()` does a bounded amount of work."""

    def __init__(self, config: Config, runner: ServiceRunner, scans: Publisher[LidarScan]):
        self.config = config
        self.runner = runner
        self.scans = scans
        self.counts: Counter[str] = Counter()
        self.sock: socket.socket | None = None
        self.stream = ColaStream()
        self._last_attempt = -math.inf
        self._last_scan = 0.0

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
        self.sock = None

    def step(self) -> None:
        now = time.monotonic()
        if self.sock is None:
            if now - self._last_attempt >= self.config.reconnect_s:
                self._last_attempt = now
                self._connect(now)
            return
        try:
            chunk = self.sock.recv(1 << 16)
        except TimeoutError:
            chunk = None
        except OSError as exc:
            self._drop(f"receive failed: {exc}")
            return
        if chunk == b"":
            self._drop("the scanner closed the connection")
            return
        if chunk:
            self._consume(chunk, time.time_ns(), now)
        if now - self._last_scan > self.config.stall_timeout_s:
            self._drop(f"no scan for {self.config.stall_timeout_s:g} s")

    def _consume(self, chunk: bytes, arrival_ns: int, now: float) -> None:
        for item in self.stream.feed(chunk):
            if isinstance(item, ColaError):
                self.counts["framing_errors"] += 1
                self.runner.report_error(
                    f"TiM stream: {item} (resynchronising)", kind="tim framing"
                )
                continue
            if not item.startswith(("sSN LMDscandata", "sRA LMDscandata")):
                self.counts["other_telegrams"] += 1
                continue
            try:
                scan = parse_scan(item)
            except ColaError as exc:
                self.counts["bad_telegrams"] += 1
                self.runner.report_error(f"TiM scan telegram dropped: {exc}", kind="tim telegram")
                continue
            period = 1.0 / scan.scan_frequency_hz if scan.scan_frequency_hz > 0 else 0.0
            stamp = arrival_ns - int((period + self.config.latency_offset_s) * 1e9)
            try:
                payload = to_scan(
                    scan, config=self.config, stamp_ns=stamp, seq=self.scans.next_seq()
                )
            except (ValueError, msgspec.ValidationError) as exc:
                self.counts["bad_telegrams"] += 1
                self.runner.report_error(f"TiM scan not publishable: {exc}", kind="tim scan")
                continue
            self.scans.put(payload)
            self._last_scan = now
            self.counts["scans"] += 1

    def _connect(self, now: float) -> None:
        address = (self.config.address, self.config.port)
        try:
            sock = socket.create_connection(address, timeout=2.0)
            sock.sendall(START_STREAM)
        except OSError as exc:
            self.counts["connect_failed"] += 1
            self.runner.set_state("degraded", f"no TiM at {address[0]}:{address[1]}: {exc}")
            return
        sock.settimeout(0.05)
        self.sock = sock
        self.stream = ColaStream()  # a fragment of the last connection is not continued
        self._last_scan = now
        self.runner.set_state("ok")
        logger.info("connected to the TiM", extra={"fields": {"address": address[0]}})

    def _drop(self, why: str) -> None:
        self.counts["reconnects"] += 1
        self.runner.set_state("degraded", why)
        logger.warning("TiM link lost", extra={"fields": {"reason": why}})
        self.close()

    def counters(self) -> dict[str, int]:
        return {**self.counts, "skipped_bytes": self.stream.skipped_bytes}


def main(config: Config) -> int:
    """Run the client until stopped."""
    with ServiceRunner("tim5xx", config) as runner:
        scans = runner.publisher(topics.ASV_SCAN)
        client = Client(config, runner, scans)
        runner.add_counters(client.counters)
        try:
            runner.run(client.step, period_s=0.001)
        finally:
            client.close()
    return 0
