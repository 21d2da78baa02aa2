"""SICK CoLa-A over TCP (port 2112): telegram framing and LMDscandata parsing (TiM5xx).

A telegram is STX (0x02), ASCII tokens separated by single spaces, ETX (0x03). Numbers are
upper-case hex (signed where the field is). The scan telegram, `sRA LMDscandata` (polled) or
`sSN LMDscandata` (streamed after `sEN LMDscandata 1`), holds in order: version, device number,
serial number, two status bytes, telegram and scan counters, time since start-up and time of
transmission (us), digital inputs (2) and outputs (2), a reserved field, scan frequency
(1/100 Hz), measurement frequency, the encoder count (and 2 fields per encoder), then the 16-bit
channel count and per channel: name (DIST1...), scale factor and offset (IEEE-754 float as
hex), start angle (1/10000 deg, signed), angular step (1/10000 deg), sample count, samples.
Distances are millimetres times the scale factor; 0 means no return. The 8-bit channels
(RSSI) follow the same way and are read when present.

Angles are SICK's: 90 deg is straight ahead. Everything here is bytes in, typed values or a
`ColaError` out; the stream resynchronises on the next STX after garbage.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterator
from dataclasses import dataclass

from capsd.errors import CapsdError

STX = 0x02
ETX = 0x03
MAX_TELEGRAM_BYTES = 64 * 1024  # a TiM5xx scan is ~5 KB; anything far larger is garbage


class ColaError(CapsdError):
    """A telegram that is not what it says it is."""


def telegram(text: str) -> bytes:
    """Frame a command: `telegram("sEN LMDscandata 1")`."""
    return bytes([STX]) + text.encode("ascii") + bytes([ETX])


START_STREAM = telegram("sEN LMDscandata 1")
STOP_STREAM = telegram("sEN LMDscandata 0")
POLL_SCAN = telegram("sRN LMDscandata")


@dataclass(frozen=True)
class ScanTelegram:
    """One decoded LMDscandata."""

    scan_counter: int
    telegram_counter: int
    time_since_startup_us: int
    scan_frequency_hz: float
    start_angle_deg: float  # SICK's angle: 90 is straight ahead
    step_deg: float
    ranges_m: tuple[float, ...]  # 0.0: no return
    intensities: tuple[float, ...]  # empty without an RSSI channel


class ColaStream:
    """Feed TCP chunks; get telegram texts (or a ColaError for broken framing) out."""

    def __init__(self) -> None:
        self._buffer = bytearray()
        self.skipped_bytes = 0

    def feed(self, chunk: bytes) -> Iterator[str | ColaError]:
        self._buffer.extend(chunk)
        while True:
            start = self._buffer.find(STX)
            if start < 0:
                self.skipped_bytes += len(self._buffer)
                self._buffer.clear()
                return
            if start > 0:
                self.skipped_bytes += start
                yield ColaError(f"{start} bytes outside a telegram skipped")
                del self._buffer[:start]
            end = self._buffer.find(ETX, 1)
            nested = self._buffer.find(STX, 1)
            if 0 < nested < (end if end > 0 else len(self._buffer)):
                # A new STX before this telegram's ETX: the telegram was cut (a reconnect or a
                # dropped segment); drop the fragment and resynchronise on the new start.
                self.skipped_bytes += nested
                yield ColaError(f"telegram cut after {nested} bytes")
                del self._buffer[:nested]
                continue
            if end < 0:
                if len(self._buffer) > MAX_TELEGRAM_BYTES:
                    self.skipped_bytes += len(self._buffer)
                    self._buffer.clear()
                    yield ColaError(f"no ETX within {MAX_TELEGRAM_BYTES} bytes")
                return
            body = bytes(self._buffer[1:end])
            del self._buffer[: end + 1]
            try:
                yield body.decode("ascii")
            except UnicodeDecodeError:
                yield ColaError("telegram is not ASCII")


MAX_HEX_DIGITS = 8  # every CoLa-A number is at most 32 bits


def _hex(token: str, field: str, *, signed_bits: int | None = None) -> int:
    if len(token) > MAX_HEX_DIGITS:
        raise ColaError(f"field {field}: {len(token)} hex digits, wider than 32 bits")
    try:
        value = int(token, 16)
    except ValueError:
        raise ColaError(f"field {field}: {token[:16]!r} is not hex") from None
    if value < 0:
        raise ColaError(f"field {field}: {token!r} is negative hex")
    if signed_bits is not None and value >= 1 << (signed_bits - 1):
        value -= 1 << signed_bits
    return value


def _float(token: str, field: str) -> float:
    raw = _hex(token, field)
    if raw >= 1 << 32:
        raise ColaError(f"field {field}: {token!r} is wider than a float32")
    value = float(struct.unpack(">f", raw.to_bytes(4, "big"))[0])
    if not math.isfinite(value):
        raise ColaError(f"field {field}: {token!r} is not a finite float")
    return value


def parse_scan(text: str) -> ScanTelegram:
    """Decode an `sRA`/`sSN LMDscandata` telegram (the text between STX and ETX)."""
    tokens = text.split(" ")
    if len(tokens) < 2 or tokens[0] not in ("sRA", "sSN") or tokens[1] != "LMDscandata":
        raise ColaError(f"not a scan telegram: {text[:40]!r}")
    pos = 2

    def take(field: str) -> str:
        nonlocal pos
        if pos >= len(tokens):
            raise ColaError(f"telegram ends before field {field} (token {pos})")
        pos += 1
        return tokens[pos - 1]

    for field in ("version", "device_number", "serial_number", "status_1", "status_2"):
        take(field)
    telegram_counter = _hex(take("telegram_counter"), "telegram_counter")
    scan_counter = _hex(take("scan_counter"), "scan_counter")
    time_us = _hex(take("time_since_startup"), "time_since_startup")
    for field in ("time_of_transmission", "inputs_1", "inputs_2", "outputs_1", "outputs_2"):
        take(field)
    take("reserved")
    scan_frequency = _hex(take("scan_frequency"), "scan_frequency") / 100.0
    take("measurement_frequency")
    encoders = _hex(take("encoders"), "encoders")
    if encoders > 16:
        raise ColaError(f"field encoders: {encoders} is implausible")
    for k in range(2 * encoders):
        take(f"encoder_{k}")
    channels_16 = _hex(take("channels_16bit"), "channels_16bit")
    ranges: tuple[float, ...] | None = None
    start_deg = step_deg = 0.0
    count = 0
    for _ in range(channels_16):
        name = take("channel_name")
        scale = _float(take(f"{name}.scale"), f"{name}.scale")
        offset = _float(take(f"{name}.offset"), f"{name}.offset")
        start = _hex(take(f"{name}.start_angle"), f"{name}.start_angle", signed_bits=32) / 1e4
        step = _hex(take(f"{name}.step"), f"{name}.step") / 1e4
        n = _hex(take(f"{name}.count"), f"{name}.count")
        if n > 10_000 or pos + n > len(tokens):
            raise ColaError(f"field {name}.count: {n} samples, {len(tokens) - pos} tokens left")
        values = [_hex(t, f"{name}[{k}]") for k, t in enumerate(tokens[pos : pos + n])]
        pos += n
        if name == "DIST1":
            if step <= 0.0:
                raise ColaError(f"field DIST1.step: {step} deg is not positive")
            # 0 is "no return" and stays 0, whatever the offset.
            ranges = tuple((v * scale + offset) / 1000.0 if v > 0 else 0.0 for v in values)
            start_deg, step_deg, count = start, step, n
    if ranges is None:
        raise ColaError("no DIST1 channel in the scan telegram")
    intensities: tuple[float, ...] = ()
    if pos < len(tokens):
        channels_8 = _hex(take("channels_8bit"), "channels_8bit")
        for _ in range(channels_8):
            name = take("channel_name")
            for field in ("scale", "offset", "start_angle", "step"):
                take(f"{name}.{field}")
            n = _hex(take(f"{name}.count"), f"{name}.count")
            if pos + n > len(tokens):
                raise ColaError(f"field {name}.count: {n} samples, {len(tokens) - pos} left")
            if name == "RSSI1" and n == count:
                intensities = tuple(float(_hex(t, "RSSI1")) for t in tokens[pos : pos + n])
            pos += n
    return ScanTelegram(
        scan_counter=scan_counter,
        telegram_counter=telegram_counter,
        time_since_startup_us=time_us,
        scan_frequency_hz=scan_frequency,
        start_angle_deg=start_deg,
        step_deg=step_deg,
        ranges_m=ranges,
        intensities=intensities,
    )


def format_scan(
    *,
    scan_counter: int,
    time_us: int,
    scan_frequency_hz: float,
    start_angle_deg: float,
    step_deg: float,
    ranges_mm: list[int],
    rssi: list[int] | None = None,
    command: str = "sSN",
) -> str:
    """The telegram text a TiM5xx sends for one scan (used by the fake device and tests)."""

    def h(v: int) -> str:
        return f"{v & 0xFFFFFFFF:X}"

    fields = [
        command,
        "LMDscandata",
        "1",
        "1",
        "B0D4F2",
        "0",
        "0",
        h(scan_counter),
        h(scan_counter),
        h(time_us),
        h(time_us + 300),
        "0",
        "0",
        "0",
        "0",
        "0",
        h(round(scan_frequency_hz * 100)),
        "0",
        "0",
        "1",
        "DIST1",
        "3F800000",
        "00000000",
        h(round(start_angle_deg * 1e4)),
        h(round(step_deg * 1e4)),
        h(len(ranges_mm)),
        *(h(v) for v in ranges_mm),
    ]
    if rssi is not None:
        fields += ["1", "RSSI1", "3F800000", "00000000", h(round(start_angle_deg * 1e4))]
        fields += [h(round(step_deg * 1e4)), h(len(rssi)), *(h(v) for v in rssi)]
    else:
        fields.append("0")
    fields += ["0", "0", "0", "0", "0"]  # position, name, comment, time, event: absent
    return " ".join(fields)
