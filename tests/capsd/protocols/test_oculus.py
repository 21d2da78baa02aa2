"""The Oculus protocol on real bytes, on every layout, split anywhere and corrupted."""

from __future__ import annotations

import contextlib
import itertools
from typing import Literal

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from capsd.protocols.oculus import (
    FIRE_V1,
    HEADER,
    RESULT_V1,
    FireFlag,
    FireSettings,
    Ping,
    PingStream,
    ProtocolError,
    build_ping_result,
    parse_ping,
    simple_fire,
)
from tests.conftest import OCULUS_FIXTURES

ONE = (OCULUS_FIXTURES / "one_ping_8bit.raw").read_bytes()
THREE = (OCULUS_FIXTURES / "three_pings_8bit.raw").read_bytes()


def _pings(stream: PingStream, chunks: list[bytes]) -> tuple[list[Ping], list[ProtocolError]]:
    pings: list[Ping] = []
    errors: list[ProtocolError] = []
    for chunk in chunks:
        for item in stream.feed(chunk):
            if isinstance(item, Ping):
                pings.append(item)
            else:
                errors.append(item)
    return pings, errors


def test_real_ping() -> None:
    ping = parse_ping(ONE)
    assert ping.version == 1  # msgVersion 0 is read as v1
    assert (ping.n_ranges, ping.n_beams) == (703, 256)
    assert ping.image.dtype == np.uint8
    assert ping.row_gains is None
    assert ping.bearings_deg[0] == pytest.approx(-30.0)
    assert ping.bearings_deg[-1] == pytest.approx(30.0)
    steps = np.diff(ping.bearings_deg)
    assert steps.min() == pytest.approx(0.22, abs=0.011)  # centre
    assert steps.max() == pytest.approx(0.26, abs=0.011)  # edges: not even in angle
    assert ping.range_m == pytest.approx(2.0)
    assert ping.image.max() > 200


def test_three_real_pings_in_a_stream() -> None:
    pings, errors = _pings(PingStream(), [THREE])
    assert errors == []
    assert [p.ping_id for p in pings] == [pings[0].ping_id + i for i in range(3)]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(min_value=1, max_value=len(THREE) - 1), max_size=40))
def test_any_split_gives_the_same_pings(cuts: list[int]) -> None:
    points = sorted(set(cuts))
    chunks = [THREE[a:b] for a, b in zip([0, *points], [*points, len(THREE)], strict=True)]
    pings, errors = _pings(PingStream(), chunks)
    assert errors == []
    assert len(pings) == 3
    assert np.array_equal(pings[1].image, parse_ping(THREE[len(ONE) : 2 * len(ONE)]).image)


def test_corrupted_message_in_the_middle_is_skipped() -> None:
    middle = len(ONE)
    broken = bytearray(THREE)
    broken[middle + 200 : middle + 260] = b"\xff" * 60  # the second ping's bearing table
    stream = PingStream()
    chunks = [bytes(broken[i : i + 997]) for i in range(0, len(broken), 997)]
    pings, errors = _pings(stream, chunks)
    first = parse_ping(ONE).ping_id
    assert [p.ping_id for p in pings] == [first, first + 2]
    assert any("bearing table" in str(e) for e in errors)
    assert stream.resyncs >= 1
    # A wrong nRanges (the image no longer a whole number of rows) is refused too.
    bad_rows = bytearray(THREE)
    n_ranges_at = middle + 16 + 37 + 53  # header, v1 fire, then 53 bytes into the result
    bad_rows[n_ranges_at : n_ranges_at + 2] = (701).to_bytes(2, "little")
    pings, errors = _pings(PingStream(), [bytes(bad_rows)])
    assert len(pings) == 2
    assert any("whole number of" in str(e) for e in errors)


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=3000))
def test_garbage_never_raises(data: bytes) -> None:
    stream = PingStream()
    for item in stream.feed(data + ONE):
        assert isinstance(item, Ping | ProtocolError)


@pytest.mark.parametrize("version", [1, 2])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.uint32])
@pytest.mark.parametrize("gains", [False, True])
def test_every_layout_round_trips(version: Literal[1, 2], dtype: type, gains: bool) -> None:
    rng = np.random.default_rng(3)
    image = rng.integers(0, np.iinfo(dtype).max, size=(50, 64), dtype=dtype)
    bearings = np.round(np.degrees(np.arcsin(np.linspace(-0.9, 0.9, 64))) * 100).astype(np.int16)
    row_gains = rng.integers(1, 1000, size=50, dtype=np.uint32) if gains else None
    message = build_ping_result(
        version=version,
        ping_id=7,
        bearings_cdeg=bearings,
        image=image,  # type: ignore[arg-type]
        row_gains=row_gains,
    )
    ping = parse_ping(message)
    assert ping.version == version
    assert ping.image.dtype == np.dtype(dtype)
    assert np.array_equal(ping.image, image)
    assert np.allclose(ping.bearings_deg, bearings / 100.0)
    if gains:
        assert ping.row_gains is not None
        assert row_gains is not None
        assert np.array_equal(ping.row_gains, row_gains)
    else:
        assert ping.row_gains is None


def test_simple_fire_sizes_and_fields() -> None:
    v1 = simple_fire(FireSettings(range_m=12.5, gain_percent=40.0), version=1)
    v2 = simple_fire(FireSettings(), version=2)
    assert len(v1) == 53
    assert len(v2) == 89
    assert v1[:2] == b"\x53\x4f"
    assert v1[6] == 0x15
    import struct

    assert struct.unpack_from("<dd", v1, 21) == (12.5, 40.0)


def test_fire_flag_bits_are_the_sdk_ones() -> None:
    # The bit values drivers built on the vendor's SDK send (FIELD-NOTES).
    assert int(FireFlag.RANGE_IN_METRES) == 0x01
    assert int(FireFlag.DATA_16BIT) == 0x02
    assert int(FireFlag.SEND_GAINS) == 0x04
    assert int(FireFlag.SIMPLE_RETURN) == 0x08
    assert int(FireFlag.GAIN_ASSIST) == 0x10
    assert int(FireFlag.BEAMS_512) == 0x40
    # The captures were fired with 0x19: metres, simple return, gain assist, 256 beams.
    assert FireFlag(0x19) == (
        FireFlag.RANGE_IN_METRES | FireFlag.SIMPLE_RETURN | FireFlag.GAIN_ASSIST
    )


@pytest.mark.parametrize("version", [1, 2])
def test_simple_fire_carries_the_flags_byte(version: Literal[1, 2]) -> None:
    fired = simple_fire(
        FireSettings(flags=FireFlag.BEAMS_512 | FireFlag.DATA_16BIT), version=version
    )
    # 16-byte header, then masterMode, pingRate, networkSpeed, gamma, flags.
    assert fired[20] == 0x42
    assert simple_fire(FireSettings(), version=version)[20] == 0x49


def test_range_lines_tile_the_fired_range() -> None:
    # Line i stands for [i, i + 1) x resolution: n lines cover the range the sonar was fired
    # with (2.0 m here) within one line, so the project's bin centre is (i + 0.5) x resolution.
    ping = parse_ping(ONE)
    covered = ping.n_ranges * ping.range_resolution_m
    assert abs(covered - 2.0) < ping.range_resolution_m
    assert abs((ping.n_ranges - 1) * ping.range_resolution_m - 2.0) > 0.5 * ping.range_resolution_m


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=400))
def test_any_bytes_parse_or_raise_a_protocol_error(data: bytes) -> None:
    for message in (data, HEADER.pack(0x4F53, 0, 0, 0x23, 0, len(data), 0) + data):
        with contextlib.suppress(ProtocolError):
            parse_ping(message)


def test_a_short_ping_result_does_not_wedge_the_stream() -> None:
    # A 26-byte message with the ping-result id (10 bytes of payload): the parser's structs
    # would read past it. The stream skips it and the next real ping comes through.
    short = HEADER.pack(0x4F53, 0, 0, 0x23, 0, 10, 0) + bytes(10)
    pings, errors = _pings(PingStream(), [short + ONE])
    assert [p.ping_id for p in pings] == [parse_ping(ONE).ping_id]
    assert errors


_BOGUS_HEADERS = st.lists(
    st.one_of(
        # a ping result of any version and size: its own header gives it away at once
        st.tuples(st.just(0x23), st.integers(0, 3), st.integers(0, 2**32 - 1)),
        # any other message announcing more than the small ones an Oculus sends
        st.tuples(st.integers(0, 2**16 - 1), st.integers(0, 3), st.integers(65_537, 2**32 - 1)),
    ),
    max_size=40,
)


@settings(max_examples=200, deadline=None)
@given(_BOGUS_HEADERS, st.lists(st.integers(1, len(THREE)), max_size=6))
# Found by CI (session 35): the id bytes of the first header's message id start a header,
# misaligned, that announces a small message of another kind, 20307 bytes: the first ping.
@example(headers=[(0x4F53, 0, 65_537), (0x23, 0, 0)], cuts=[])
def test_bogus_headers_never_swallow_the_pings_behind_them(
    headers: list[tuple[int, int, int]], cuts: list[int]
) -> None:
    junk = b"".join(HEADER.pack(0x4F53, 0, 0, m, v, size, 0) for m, v, size in headers)
    stream = junk + THREE
    bounds = [0, *sorted(len(junk) + c for c in cuts), len(stream)]
    pings, errors = _pings(PingStream(), [stream[a:b] for a, b in itertools.pairwise(bounds)])
    assert [p.ping_id for p in pings] == [parse_ping(m).ping_id for m in _split_three()]
    assert len(errors) >= len(headers)


def _split_three() -> list[bytes]:
    return [THREE[i * len(ONE) : (i + 1) * len(ONE)] for i in range(3)]


def _patched(**fields: float) -> bytes:
    """ONE with v1 header fields replaced (by name) and nothing else changed."""
    names = [
        "ping_id",
        "status",
        "frequency",
        "temperature",
        "pressure",
        "sound_speed",
        "start_time",
        "data_size",
        "range_resolution",
        "n_ranges",
        "n_beams",
        "image_offset",
        "image_size",
        "message_size",
    ]
    offset = HEADER.size + FIRE_V1.size
    values = dict(zip(names, RESULT_V1.unpack_from(ONE, offset), strict=True))
    values.update(fields)
    out = bytearray(ONE)
    RESULT_V1.pack_into(out, offset, *(values[n] for n in names))
    return bytes(out)


@pytest.mark.parametrize(
    ("fields", "reason"),
    [
        ({"range_resolution": 0.0}, "range resolution"),
        ({"range_resolution": -0.01}, "range resolution"),
        ({"sound_speed": 150.0}, "speed of sound"),
        ({"n_beams": 64}, "dataSize"),  # a 256-byte row read as 64 beams of 32 bits
    ],
)
def test_implausible_header_fields_are_refused(fields: dict[str, float], reason: str) -> None:
    with pytest.raises(ProtocolError, match=reason):
        parse_ping(_patched(**fields))


def test_a_negative_range_is_refused() -> None:
    out = bytearray(ONE)
    fire = list(FIRE_V1.unpack_from(ONE, HEADER.size))
    fire[5] = -20.0
    FIRE_V1.pack_into(out, HEADER.size, *fire)
    with pytest.raises(ProtocolError, match="range"):
        parse_ping(bytes(out))
