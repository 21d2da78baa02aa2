"""The Oculus driver: its own process, sonar frames from a real Oculus onto the bus.

Finds the sonar by its UDP status broadcast (or uses a fixed address), connects to its data
port, sends SimpleFire with the configured range/gain/rate, and publishes every
SimplePingResult as a SonarFrame: azimuths from the sonar's own bearing table, turned into
theta (port positive) by the mount (upright: theta = -bearing). A stream that ends, errs or
stalls is reconnected; every problem is counted in Health.

Stamps: a ping's instant is when it would have arrived over a link that keeps up (the
sonar's own pingStartTime mapped onto our clock by `sonar_clock.SonarClock`, which learns the
counter's unknown unit and wrap from the stream; arrival time until it has), minus the two-way
travel time to the configured range (the sonar can send only after that) minus a calibrated
`latency_offset_s` (processing and transfer). A ping that arrives late (a stall) keeps the
time it was taken and is counted (`late_pings`). When several pings arrive in one read (a
backlog: the driver was slow), only the newest is published.
With `address: auto`, the first status broadcast's sender is pinned for the process's life.
32-bit samples are scaled to 16 bits (the top 16); per-row gain prefixes are dropped.
"""

from __future__ import annotations

import logging
import socket
import time
from collections import Counter
from typing import Annotated, Literal

import msgspec
import numpy as np

from capsd import topics
from capsd.config import ConfigSection, ServiceConfig
from capsd.payloads import SonarFrame
from capsd.protocols.oculus import (
    DATA_PORT,
    STATUS_PORT,
    FireFlag,
    FireSettings,
    MasterMode,
    Ping,
    PingRate,
    PingStream,
    ProtocolError,
    parse_status,
    simple_fire,
)
from capsd.runner import Publisher, ServiceRunner
from capsd.services.sonar_detect.sonar_clock import LATE_S, SonarClock

logger = logging.getLogger(__name__)


class FireConfig(ConfigSection, frozen=True, kw_only=True):
    """SimpleFire settings."""

    version: Literal[1, 2] = 2
    master_mode: MasterMode = "lf"  # 1.2 MHz on an M3000d: 130 x 20 deg
    ping_rate: PingRate = "high"
    range_m: Annotated[float, msgspec.Meta(ge=0.1, le=120.0)] = 20.0
    gain_percent: Annotated[float, msgspec.Meta(ge=0.0, le=100.0)] = 50.0
    gamma: Annotated[int, msgspec.Meta(ge=0, le=255)] = 127
    sound_speed_m_s: Annotated[float, msgspec.Meta(ge=0.0, le=1700.0)] = 0.0  # 0: the sonar's
    salinity_ppt: Annotated[float, msgspec.Meta(ge=0.0, le=50.0)] = 0.0
    beams: Literal[256, 512] = 512  # an M3000d gives 512; an M1200d 256 whatever is asked
    # off: the configured gain every ping, so intensities compare ping to ping (the detector's
    # training assumes nothing about it, but a steady image tracks better).
    gain_assist: Literal["on", "off"] = "off"
    sample_bits: Literal[8, 16] = 8
    row_gains: Literal["on", "off"] = "off"  # per-row gain prefixes (the driver drops them)

    def __post_init__(self) -> None:
        super().__post_init__()
        if 0.0 < self.sound_speed_m_s < 1300.0:
            raise ValueError(
                "`sound_speed_m_s` must be 0 (the sonar computes it) or 1300-1700 m/s, "
                f"not {self.sound_speed_m_s:g}"
            )

    def flags(self) -> FireFlag:
        flags = FireFlag.RANGE_IN_METRES | FireFlag.SIMPLE_RETURN
        if self.beams == 512:
            flags |= FireFlag.BEAMS_512
        if self.gain_assist == "on":
            flags |= FireFlag.GAIN_ASSIST
        if self.sample_bits == 16:
            flags |= FireFlag.DATA_16BIT
        if self.row_gains == "on":
            flags |= FireFlag.SEND_GAINS
        return flags

    def settings(self) -> FireSettings:
        return FireSettings(
            flags=self.flags(),
            master_mode=self.master_mode,
            ping_rate=self.ping_rate,
            gamma=self.gamma,
            range_m=self.range_m,
            gain_percent=self.gain_percent,
            sound_speed_m_s=self.sound_speed_m_s,
            salinity_ppt=self.salinity_ppt,
        )


class Config(ServiceConfig, frozen=True, kw_only=True):
    """Oculus driver configuration."""

    vehicle: str = "asv"
    address: str = "auto"  # an IP or host name, or "auto": the first status broadcast heard
    port: Annotated[int, msgspec.Meta(ge=1, le=65535)] = DATA_PORT
    status_port: Annotated[int, msgspec.Meta(ge=1, le=65535)] = STATUS_PORT
    status_bind: str = "0.0.0.0"  # where to listen for status broadcasts
    fire: FireConfig = FireConfig()
    mount: Literal["upright", "inverted"] = "upright"
    vertical_aperture_deg: Annotated[float, msgspec.Meta(gt=0.0, le=90.0)] = 20.0
    latency_offset_s: Annotated[float, msgspec.Meta(ge=0.0, le=1.0)] = 0.0
    # Without a ping for this long the link is reopened.
    stall_timeout_s: Annotated[float, msgspec.Meta(gt=0.0, le=60.0)] = 3.0
    reconnect_s: Annotated[float, msgspec.Meta(gt=0.0, le=60.0)] = 1.0
    keepalive_s: Annotated[float, msgspec.Meta(gt=0.0, le=60.0)] = 2.0


def to_frame(ping: Ping, *, config: Config, stamp_ns: int, seq: int) -> SonarFrame:
    """The bus payload of one ping."""
    sign = -1.0 if config.mount == "upright" else 1.0
    azimuths = np.radians(ping.bearings_deg) * sign
    image = ping.image
    bits: Literal[8, 16]
    if image.dtype.itemsize == 1:
        bits = 8
    elif image.dtype.itemsize == 2:
        bits = 16
    else:
        image = (image >> 16).astype("<u2")
        bits = 16
    # One copy: astype is a no-op for little-endian data, tobytes writes C order.
    raw = image.astype(image.dtype.newbyteorder("<"), copy=False).tobytes()
    return SonarFrame(
        stamp_ns=stamp_ns,
        seq=seq,
        ping_id=ping.ping_id,
        n_ranges=ping.n_ranges,
        n_beams=ping.n_beams,
        sample_bits=bits,
        image=memoryview(raw),
        azimuths_rad=tuple(float(a) for a in azimuths),
        range_start_m=0.0,
        range_resolution_m=ping.range_resolution_m,
        # What the ping says it used; else what it was told to use; else unknown (never a
        # guess: the locator rescales ranges by it).
        sound_speed_m_s=(
            ping.sound_speed_m_s
            if ping.sound_speed_m_s > 0
            else (config.fire.sound_speed_m_s or None)
        ),
        gain_percent=min(max(ping.gain_percent, 0.0), 100.0),
        frequency_hz=ping.frequency_hz if ping.frequency_hz > 0 else 1.2e6,
        vertical_aperture_rad=float(np.radians(config.vertical_aperture_deg)),
    )


class Driver:
    """Connection state and the byte stream; `step()` does a bounded amount of work."""

    def __init__(self, config: Config, runner: ServiceRunner, frames: Publisher[SonarFrame]):
        self.config = config
        self.runner = runner
        self.frames = frames
        self.counts: Counter[str] = Counter()
        self.sock: socket.socket | None = None
        self.stream = PingStream()
        self.clock: SonarClock | None = None  # per connection, made by the first ping's version
        self.address: str | None = None if config.address == "auto" else config.address
        self._last_attempt = 0.0
        self._last_ping = 0.0
        self._last_fire = 0.0
        self._status: socket.socket | None = None

    def close(self) -> None:
        for sock in (self.sock, self._status):
            if sock is not None:
                sock.close()
        self.sock = self._status = None

    def step(self) -> None:
        now = time.monotonic()
        if self.address is None:
            self._discover()
            return
        if self.sock is None:
            if now - self._last_attempt >= self.config.reconnect_s:
                self._last_attempt = now
                self._connect(now)
            return
        if now - self._last_fire >= self.config.keepalive_s:
            self._fire(now)
        try:
            chunk = self.sock.recv(1 << 20)
        except TimeoutError:
            chunk = None
        except OSError as exc:
            self._drop(f"receive failed: {exc}")
            return
        if chunk == b"":
            self._drop("the sonar closed the connection")
            return
        if chunk:
            arrival = time.time_ns()
            newest: Ping | None = None
            in_this_read = 0
            for item in self.stream.feed(chunk):
                if isinstance(item, ProtocolError):
                    self.counts["protocol_errors"] += 1
                    self.runner.report_error(
                        f"Oculus stream: {item} (resynchronising)", kind="oculus protocol"
                    )
                    continue
                if newest is not None:
                    # A backlog (pings queued while we were slow): only the newest is stamped
                    # with this arrival; older ones would be stamped later than they were taken.
                    self.counts["backlog_dropped"] += 1
                newest = item
                in_this_read += 1
            if newest is not None:
                self._last_ping = now
                taken_ns = self._taken_ns(newest, arrival, alone=in_this_read == 1)
                travel = 2.0 * newest.range_m / (newest.sound_speed_m_s or 1480.0)
                stamp = taken_ns - int((travel + self.config.latency_offset_s) * 1e9)
                self.frames.put(
                    to_frame(newest, config=self.config, stamp_ns=stamp, seq=self.frames.next_seq())
                )
                self.counts["pings"] += 1
        if now - self._last_ping > self.config.stall_timeout_s:
            self._drop(f"no ping for {self.config.stall_timeout_s:g} s")

    def _taken_ns(self, ping: Ping, arrival_ns: int, *, alone: bool) -> int:
        """When the ping would have arrived over a link that keeps up (our clock)."""
        if self.clock is None:
            # v1 sends a 32-bit counter (it wraps); v2 a double.
            self.clock = SonarClock(modulus=2.0**32 if ping.version == 1 else None)
        stamp = self.clock.stamp(ping.ping_start_time, arrival_ns, alone=alone)
        if stamp.late_s > LATE_S:
            self.counts["late_pings"] += 1
        return stamp.taken_ns

    def _discover(self) -> None:
        if self._status is None:
            self._status = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self._status.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._status.bind((self.config.status_bind, self.config.status_port))
            self._status.settimeout(0.1)
            logger.info(
                "listening for Oculus status broadcasts",
                extra={"fields": {"port": self.config.status_port}},
            )
        try:
            datagram, (host, _port) = self._status.recvfrom(4096)
        except TimeoutError:
            return
        if parse_status(datagram) is None:
            self.counts["bad_status_datagrams"] += 1
            return
        # Pinned from now on (a reconnect goes back here, never to whoever broadcasts next).
        self.address = host
        self._status.close()
        self._status = None
        logger.info("Oculus found", extra={"fields": {"address": host}})

    def _connect(self, now: float) -> None:
        assert self.address is not None
        try:
            sock = socket.create_connection((self.address, self.config.port), timeout=2.0)
        except OSError as exc:
            self.counts["connect_failed"] += 1
            self.runner.set_state("degraded", f"no Oculus at {self.address}: {exc}")
            return
        sock.settimeout(0.05)
        self.sock = sock
        self.stream = PingStream()
        self.clock = None  # the sonar may have restarted: its counter is learnt again
        self._last_ping = now
        self._fire(now)
        self.runner.set_state("ok")
        logger.info("connected to the Oculus", extra={"fields": {"address": self.address}})

    def _fire(self, now: float) -> None:
        assert self.sock is not None
        try:
            self.sock.sendall(
                simple_fire(self.config.fire.settings(), version=self.config.fire.version)
            )
            self._last_fire = now
        except OSError as exc:
            self._drop(f"SimpleFire not sent: {exc}")

    def _drop(self, why: str) -> None:
        self.counts["reconnects"] += 1
        self.runner.set_state("degraded", why)
        logger.warning("Oculus link lost", extra={"fields": {"reason": why}})
        if self.sock is not None:
            self.sock.close()
        self.sock = None

    def counters(self) -> dict[str, int]:
        merged = dict(self.counts)
        merged["resyncs"] = self.stream.resyncs
        merged["skipped_bytes"] = self.stream.skipped_bytes
        if self.clock is not None:
            merged["sonar_clock_learnt"] = int(self.clock.learnt)
            merged["sonar_clock_resets"] = self.clock.resets
        return merged


def main(config: Config) -> int:
    """Run the driver until stopped."""
    with ServiceRunner("oculus", config) as runner:
        frames = runner.publisher(topics.SONAR_FRAME)
        driver = Driver(config, runner, frames)
        runner.add_counters(driver.counters)
        try:
            runner.run(driver.step, period_s=0.001)
        finally:
            driver.close()
    return 0
