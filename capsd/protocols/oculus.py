"""Blueprint Subsea Oculus protocol: SimpleFire out, SimplePingResult in (little-endian, packed).

Every message starts with a 16-byte header: oculusId 0x4f53, srcDeviceId, dstDeviceId, msgId,
msgVersion, payloadSize (u32), spare. SimpleFire (0x15) v1 is 53 bytes, v2 89 bytes.
SimplePingResult (0x23): msgVersion 0 and 1 use the v1 layout (122-byte header), 2 the v2
layout (202 bytes); then nBeams int16 bearings (0.01 deg, NOT evenly spaced in angle), and at
imageOffset the image, nRanges rows of nBeams samples, optionally each row prefixed by 4 gain
bytes. The sample size (1, 2 or 4 bytes) and the gain prefix are inferred from imageSize /
nRanges: the flags are not trusted (FIELD-NOTES). The status broadcast (UDP 52102) is 142
bytes; its first fields give the sonar's address.

`PingStream` takes bytes in any chunking (a TCP stream), yields pings and reports problems; on
a broken message it resynchronises on the next header.
"""

from __future__ import annotations

import enum
import math
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

OCULUS_ID = 0x4F53
MSG_SIMPLE_FIRE = 0x15
MSG_SIMPLE_PING_RESULT = 0x23
DATA_PORT = 52100
STATUS_PORT = 52102

HEADER = struct.Struct("<HHHHHIH")  # 16 bytes
FIRE_V1 = struct.Struct("<BBBBBdddd")  # 37 bytes after the header: 53 in all
FIRE_V2 = struct.Struct("<BBBBBdddd I 8I")  # 73 after the header: 89 in all
RESULT_V1 = struct.Struct("<IIddddIBdHHIII")  # after a v1 fire: 122 in all
RESULT_V2 = struct.Struct("<IIddddddddBdHH4IIII")  # after a v2 fire: 202 in all
STATUS = struct.Struct("<HHHHHIH I I I I")  # header + deviceId, deviceType, partNumber, status

MAX_PAYLOAD = 16 * 1024 * 1024  # a 512 x 4000 x 4-byte ping is 8 MB: anything larger is noise
# Other messages an Oculus may put on the data link (user config, logs, dummy) are small; a
# header announcing more is taken for noise, so that it cannot swallow the pings behind it.
MAX_OTHER_PAYLOAD = 64 * 1024

PingRate = Literal["normal", "high", "highest", "low", "lowest", "standby"]
_PING_RATE = {"normal": 0, "high": 1, "highest": 2, "low": 3, "lowest": 4, "standby": 5}
MasterMode = Literal["lf", "hf"]  # 1: low frequency (1.2 MHz on an M3000d), 2: high


class FireFlag(enum.IntFlag):
    """SimpleFire's flag bits, as the vendor's SDK names them (FIELD-NOTES; drivers built on it)."""

    RANGE_IN_METRES = 0x01  # `range` is metres (else a percentage of the maximum)
    DATA_16BIT = 0x02  # 16-bit samples (else 8-bit)
    SEND_GAINS = 0x04  # each image row prefixed by its 4-byte gain
    SIMPLE_RETURN = 0x08  # reply with SimplePingResult
    GAIN_ASSIST = 0x10  # the sonar changes its gain ping to ping
    BEAMS_512 = 0x40  # 512 beams (else 256)


# An M3000d as CAP-SD wants it: metres, simple return, fixed gain (intensities comparable ping
# to ping), 512 beams, 8-bit data, no per-row gains.
DEFAULT_FLAGS = FireFlag.RANGE_IN_METRES | FireFlag.SIMPLE_RETURN | FireFlag.BEAMS_512


@dataclass(frozen=True)
class FireSettings:
    """What a SimpleFire asks of the sonar."""

    master_mode: MasterMode = "lf"
    ping_rate: PingRate = "high"
    network_speed: int = 255
    gamma: int = 127
    range_m: float = 20.0
    gain_percent: float = 50.0
    sound_speed_m_s: float = 0.0  # 0: the sonar computes it
    salinity_ppt: float = 0.0  # fresh water (fuel ponds)
    flags: FireFlag = DEFAULT_FLAGS


def simple_fire(settings: FireSettings, *, version: Literal[1, 2]) -> bytes:
    """The SimpleFire message bytes (v1: 53, v2: 89)."""
    mode = 1 if settings.master_mode == "lf" else 2
    body_args = (
        mode,
        _PING_RATE[settings.ping_rate],
        settings.network_speed,
        settings.gamma,
        int(settings.flags),
        settings.range_m,
        settings.gain_percent,
        settings.sound_speed_m_s,
        settings.salinity_ppt,
    )
    body = FIRE_V1.pack(*body_args) if version == 1 else FIRE_V2.pack(*body_args, 0, *([0] * 8))
    header = HEADER.pack(
        OCULUS_ID, 0, 0, MSG_SIMPLE_FIRE, version if version == 2 else 0, len(body), 0
    )
    return header + body


@dataclass(frozen=True)
class Ping:
    """One parsed SimplePingResult."""

    version: Literal[1, 2]
    ping_id: int
    master_mode: int
    range_m: float
    gain_percent: float
    frequency_hz: float
    sound_speed_m_s: float
    range_resolution_m: float
    bearings_deg: npt.NDArray[np.float64]  # as the sonar reports them: starboard positive
    image: npt.NDArray[np.uint8] | npt.NDArray[np.uint16] | npt.NDArray[np.uint32]
    row_gains: npt.NDArray[np.uint32] | None
    ping_start_time: float

    @property
    def n_ranges(self) -> int:
        return int(self.image.shape[0])

    @property
    def n_beams(self) -> int:
        return int(self.image.shape[1])


class ProtocolError(ValueError):
    """A message that cannot be a valid SimplePingResult (the stream then resynchronises)."""


# What a real Oculus can report; anything else is a corrupt or hostile header.
MAX_RANGE_M = 150.0
MAX_RANGE_RESOLUTION_M = 0.5
SOUND_SPEED_M_S = (1300.0, 1800.0)  # or 0: not reported
DATA_SIZE_32BIT = 3  # dataSize: 0 8-bit, 1 16-bit, 2 24-bit, 3 32-bit


def parse_ping(message: bytes) -> Ping:
    """Parse one whole SimplePingResult message (header included).

    Every way a message can be wrong is a ProtocolError (never another exception), so a stream
    resynchronises past it: lengths are checked before each struct is read, and header fields
    are checked against what an Oculus can report.
    """
    try:
        return _parse_ping(message)
    except (struct.error, IndexError, OverflowError) as exc:
        raise ProtocolError(f"malformed SimplePingResult: {exc}") from None


def _parse_ping(message: bytes) -> Ping:
    if len(message) < HEADER.size:
        raise ProtocolError("shorter than a message header")
    oculus_id, _src, _dst, msg_id, msg_version, payload_size, _spare = HEADER.unpack_from(message)
    if oculus_id != OCULUS_ID or msg_id != MSG_SIMPLE_PING_RESULT:
        raise ProtocolError(f"not a SimplePingResult (id {oculus_id:#x}, msg {msg_id:#x})")
    if HEADER.size + payload_size != len(message):
        raise ProtocolError(f"payload size {payload_size} does not match {len(message)} bytes")
    if msg_version in (0, 1) and len(message) < HEADER.size + FIRE_V1.size + RESULT_V1.size:
        raise ProtocolError(f"{len(message)} bytes: shorter than a v1 SimplePingResult header")
    if msg_version == 2 and len(message) < HEADER.size + FIRE_V2.size + RESULT_V2.size:
        raise ProtocolError(f"{len(message)} bytes: shorter than a v2 SimplePingResult header")
    if msg_version in (0, 1):
        version: Literal[1, 2] = 1
        fire = FIRE_V1.unpack_from(message, HEADER.size)
        fields = RESULT_V1.unpack_from(message, HEADER.size + FIRE_V1.size)
        (
            ping_id,
            _status,
            frequency,
            _temp,
            _press,
            sound_speed,
            start_time,
            data_size,
            range_res,
            n_ranges,
            n_beams,
            image_offset,
            image_size,
            message_size,
        ) = fields
        header_size = HEADER.size + FIRE_V1.size + RESULT_V1.size
    elif msg_version == 2:
        version = 2
        fire = FIRE_V2.unpack_from(message, HEADER.size)[:9]
        fields = RESULT_V2.unpack_from(message, HEADER.size + FIRE_V2.size)
        (
            ping_id,
            _status,
            frequency,
            _temp,
            _press,
            _heading,
            _pitch,
            _roll,
            sound_speed,
            start_time,
            data_size,
            range_res,
            n_ranges,
            n_beams,
            _s0,
            _s1,
            _s2,
            _s3,
            image_offset,
            image_size,
            message_size,
        ) = fields
        header_size = HEADER.size + FIRE_V2.size + RESULT_V2.size
    else:
        raise ProtocolError(f"SimplePingResult version {msg_version} is unknown")
    if n_ranges == 0 or n_beams == 0 or n_beams > 1024:
        raise ProtocolError(f"implausible image shape {n_ranges} x {n_beams}")
    range_m = fire[5]
    if not (math.isfinite(range_m) and 0.0 < range_m <= MAX_RANGE_M):
        raise ProtocolError(f"range {range_m} m is not one an Oculus fires")
    if not (math.isfinite(range_res) and 0.0 < range_res <= MAX_RANGE_RESOLUTION_M):
        raise ProtocolError(f"range resolution {range_res} m is implausible")
    if not (
        sound_speed == 0.0
        or (math.isfinite(sound_speed) and SOUND_SPEED_M_S[0] <= sound_speed <= SOUND_SPEED_M_S[1])
    ):
        raise ProtocolError(f"speed of sound {sound_speed} m/s is implausible")
    if not (math.isfinite(frequency) and frequency >= 0.0) or not math.isfinite(fire[6]):
        raise ProtocolError("frequency or gain is not a number")
    if header_size + 2 * n_beams > image_offset or image_offset + image_size > len(message):
        raise ProtocolError("bearing table or image outside the message")
    if message_size not in (0, len(message)):
        raise ProtocolError(f"messageSize {message_size} disagrees with {len(message)} bytes")
    row_bytes, remainder = divmod(image_size, n_ranges)
    if remainder:
        raise ProtocolError(f"imageSize {image_size} is not a whole number of {n_ranges} rows")
    layout = _row_layout(row_bytes, n_beams)
    if layout[0] == 4 and data_size != DATA_SIZE_32BIT:
        # 4 bytes a beam is also 4 x the beams of a 8-bit row: only dataSize tells them apart.
        raise ProtocolError(f"{row_bytes}-byte rows of {n_beams} beams but dataSize {data_size}")
    bearings = np.frombuffer(message, dtype="<i2", count=n_beams, offset=header_size) / 100.0
    steps = np.diff(bearings)
    if np.abs(bearings).max() > 90.0 or not ((steps > 0).all() or (steps < 0).all()):
        raise ProtocolError("bearing table is not a monotonic fan within +-90 deg")
    raw = np.frombuffer(message, dtype=np.uint8, count=image_size, offset=image_offset)
    rows = raw.reshape(n_ranges, row_bytes)
    gains = None
    sample_bytes, has_gain = layout
    if has_gain:
        gains = rows[:, :4].copy().view("<u4").reshape(n_ranges)
        rows = rows[:, 4:]
    dtype = {1: "<u1", 2: "<u2", 4: "<u4"}[sample_bytes]
    image = np.ascontiguousarray(rows).view(dtype).reshape(n_ranges, n_beams)
    return Ping(
        version,
        ping_id,
        fire[0],
        fire[5],
        fire[6],
        frequency,
        sound_speed,
        range_res,
        bearings.astype(np.float64),
        image,
        gains,
        float(start_time),
    )


def _row_layout(row_bytes: int, n_beams: int) -> tuple[int, bool]:
    """(bytes per sample, gain prefix?) from the bytes in one image row."""
    for sample_bytes in (1, 2, 4):
        if row_bytes == n_beams * sample_bytes:
            return sample_bytes, False
        if row_bytes == n_beams * sample_bytes + 4:
            return sample_bytes, True
    raise ProtocolError(f"{row_bytes} bytes a row fit no sample size for {n_beams} beams")


class PingStream:
    """Reassembles messages from a byte stream; `feed(chunk)` yields pings and problems."""

    def __init__(self) -> None:
        self._buffer = bytearray()
        self.resyncs = 0
        self.skipped_bytes = 0
        self.other_messages = 0

    def feed(self, chunk: bytes) -> Iterator[Ping | ProtocolError]:
        self._buffer += chunk
        while True:
            start = self._buffer.find(b"\x53\x4f")  # 0x4f53 little-endian
            if start < 0:
                keep = 1 if self._buffer.endswith(b"\x53") else 0
                self.skipped_bytes += len(self._buffer) - keep
                del self._buffer[: len(self._buffer) - keep]
                return
            if start > 0:
                self.skipped_bytes += start
                del self._buffer[:start]
            if len(self._buffer) < HEADER.size:
                return
            _id, _src, _dst, msg_id, _ver, payload_size, _spare = HEADER.unpack_from(self._buffer)
            if payload_size > MAX_PAYLOAD:
                yield self._resync(f"payload size {payload_size} is implausible")
                continue
            if msg_id != MSG_SIMPLE_PING_RESULT and payload_size > MAX_OTHER_PAYLOAD:
                yield self._resync(f"message {msg_id:#x} of {payload_size} bytes is implausible")
                continue
            total = HEADER.size + payload_size
            if msg_id == MSG_SIMPLE_PING_RESULT:
                # Check the ping's own header as soon as it is here, before waiting for the
                # rest: a bogus header must not make the stream wait for (and then discard)
                # megabytes of good pings.
                problem = _ping_head_problem(self._buffer, total)
                if problem is None and len(self._buffer) < total:
                    return  # the head is not here yet, or it is sound and the rest is coming
                if problem:
                    yield self._resync(problem)
                    continue
            if len(self._buffer) < total:
                return
            if msg_id != MSG_SIMPLE_PING_RESULT:
                # A header found inside noise (its id bytes, then whatever follows) may announce
                # a small message that would swallow the ping behind it: a sound ping header
                # inside says it is noise.
                if _holds_a_ping(self._buffer, total):
                    yield self._resync(f"message {msg_id:#x} of {payload_size} bytes holds a ping")
                    continue
                self.other_messages += 1
                del self._buffer[:total]
                continue
            message = bytes(self._buffer[:total])
            try:
                ping = parse_ping(message)
            except ProtocolError as exc:
                yield self._resync(str(exc))
                continue
            del self._buffer[:total]
            yield ping

    def _resync(self, reason: str) -> ProtocolError:
        # Drop the two id bytes and look for the next header.
        self.resyncs += 1
        self.skipped_bytes += 2
        del self._buffer[:2]
        return ProtocolError(reason)


def _holds_a_ping(buffer: bytearray, total: int) -> bool:
    """Whether a sound SimplePingResult header starts within `buffer[1:total]`."""
    head_max = HEADER.size + FIRE_V2.size + RESULT_V2.size
    at = buffer.find(b"\x53\x4f", 1, total)
    while at >= 0:
        if len(buffer) - at >= HEADER.size:
            fields = HEADER.unpack_from(buffer, at)
            msg_id, payload_size = fields[3], fields[5]
            if (
                msg_id == MSG_SIMPLE_PING_RESULT
                and payload_size <= MAX_PAYLOAD
                and _ping_head_problem(buffer[at : at + head_max], HEADER.size + payload_size)
                is None
            ):
                return True
        at = buffer.find(b"\x53\x4f", at + 1, total)
    return False


def _ping_head_problem(buffer: bytearray, total: int) -> str | None:
    """Why a SimplePingResult whose header is at the start of `buffer` cannot be one.

    None when it may be one, or when its fixed header has not all arrived yet. Only the
    sizes are checked here; `parse_ping` checks the rest once the whole message is in.
    """
    msg_version = HEADER.unpack_from(buffer)[4]
    if msg_version in (0, 1):
        head, result, beams_field = HEADER.size + FIRE_V1.size, RESULT_V1, 10
    elif msg_version == 2:
        head, result, beams_field = HEADER.size + FIRE_V2.size, RESULT_V2, 13
    else:
        return f"SimplePingResult version {msg_version} is unknown"
    version = 2 if msg_version == 2 else 1
    if total < head + result.size:
        return f"{total} bytes: shorter than a v{version} SimplePingResult header"
    if len(buffer) < head + result.size:
        return None
    fields = result.unpack_from(buffer, head)
    n_beams = fields[beams_field]
    image_offset, image_size, message_size = fields[-3:]
    if message_size not in (0, total):
        return f"messageSize {message_size} disagrees with the header's {total} bytes"
    if image_offset + image_size > total or image_offset < head + result.size + 2 * n_beams:
        return "bearing table or image outside the message"
    return None


def parse_status(datagram: bytes) -> tuple[int, int] | None:
    """(device id, device type) from a status broadcast, or None if it is not one."""
    if len(datagram) < STATUS.size:
        return None
    fields = STATUS.unpack_from(datagram)
    if fields[0] != OCULUS_ID:
        return None
    return fields[7], fields[8]


def build_ping_result(
    *,
    version: Literal[1, 2],
    ping_id: int,
    bearings_cdeg: npt.NDArray[np.int16],
    image: npt.NDArray[np.uint8] | npt.NDArray[np.uint16] | npt.NDArray[np.uint32],
    row_gains: npt.NDArray[np.uint32] | None = None,
    range_m: float = 20.0,
    range_resolution_m: float = 0.02,
    frequency_hz: float = 1.2e6,
    sound_speed_m_s: float = 1480.0,
    gain_percent: float = 50.0,
) -> bytes:
    """A SimplePingResult as a sonar sends it (for the fake sonar of tests and for replays)."""
    n_ranges, n_beams = image.shape
    data_size = {1: 0, 2: 1, 4: DATA_SIZE_32BIT}[image.dtype.itemsize]
    body = np.ascontiguousarray(image.astype(image.dtype.newbyteorder("<"))).view(np.uint8)
    rows = body.reshape(n_ranges, -1)
    if row_gains is not None:
        gains = np.asarray(row_gains, dtype="<u4").view(np.uint8).reshape(n_ranges, 4)
        rows = np.hstack([gains, rows])
    image_bytes = rows.tobytes()
    bearings = np.asarray(bearings_cdeg, dtype="<i2").tobytes()
    if version == 1:
        fire = FIRE_V1.pack(1, 1, 255, 127, 0x19, range_m, gain_percent, sound_speed_m_s, 0.0)
        head_size = HEADER.size + FIRE_V1.size + RESULT_V1.size
    else:
        fire = FIRE_V2.pack(
            1, 1, 255, 127, 0x19, range_m, gain_percent, sound_speed_m_s, 0.0, 0, *([0] * 8)
        )
        head_size = HEADER.size + FIRE_V2.size + RESULT_V2.size
    image_offset = head_size + len(bearings)
    total = image_offset + len(image_bytes)
    if version == 1:
        result = RESULT_V1.pack(
            ping_id,
            0,
            frequency_hz,
            20.0,
            0.0,
            sound_speed_m_s,
            0,
            data_size,
            range_resolution_m,
            n_ranges,
            n_beams,
            image_offset,
            len(image_bytes),
            total,
        )
    else:
        result = RESULT_V2.pack(
            ping_id,
            0,
            frequency_hz,
            20.0,
            0.0,
            0.0,
            0.0,
            0.0,
            sound_speed_m_s,
            0.0,
            data_size,
            range_resolution_m,
            n_ranges,
            n_beams,
            0,
            0,
            0,
            0,
            image_offset,
            len(image_bytes),
            total,
        )
    header = HEADER.pack(
        OCULUS_ID, 7892, 0, MSG_SIMPLE_PING_RESULT, version, total - HEADER.size, 0
    )
    return header + fire + result + bearings + image_bytes
