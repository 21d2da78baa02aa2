"""Codec: round trips, malformed payloads, versions, unknown fields, encodings."""

from __future__ import annotations

import contextlib
import math

import msgspec
import pytest
from hypothesis import given
from hypothesis import strategies as st

from capsd.codec import SCHEMAS, Codec, decode_any, encoding_of, to_builtins
from capsd.errors import PayloadError
from capsd.payloads import ALL_PAYLOADS, Detection, Payload, RovDepth, SonarDetections, SonarFrame
from tests.capsd.samples import SAMPLES


def test_every_payload_type_has_a_sample() -> None:
    assert {type(s) for s in SAMPLES} == set(ALL_PAYLOADS)


def test_every_payload_type_is_known_to_tools() -> None:
    """A payload class missing from ALL_PAYLOADS would not decode in `capsd tap` or replays."""

    def leaves(cls: type[Payload]) -> set[type[Payload]]:
        subs = cls.__subclasses__()
        return {cls} if not subs else set().union(*(leaves(c) for c in subs))

    assert leaves(Payload) == set(ALL_PAYLOADS)


@pytest.mark.parametrize("payload", SAMPLES, ids=lambda p: type(p).__name__)
def test_round_trip_in_memory(payload: Payload) -> None:
    codec = Codec(type(payload))
    data = codec.encode(payload)
    assert codec.decode(data, encoding=codec.encoding, key_expr="k") == payload


def test_encodings_name_the_schema() -> None:
    assert encoding_of(RovDepth) == "application/json;RovDepth"
    assert encoding_of(SonarFrame) == "application/msgpack;SonarFrame"
    assert "foxglove.Log" in SCHEMAS


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (b"\x00\xff garbage", "malformed"),
        (b'{"stamp_ns": "yesterday", "seq": 0, "depth_m": 1.0}', "Expected `int`"),
        (b'{"stamp_ns": 1, "seq": 0, "depth_m": NaN}', "malformed"),
        (b'{"stamp_ns": 1, "seq": 0}', "missing required field `depth_m`"),
        (b'{"stamp_ns": -5, "seq": 0, "depth_m": 1.0}', ">= 0"),
        (b"[]", "Expected `object`"),
    ],
)
def test_malformed_json_is_rejected_with_reason(data: bytes, reason: str) -> None:
    codec = Codec(RovDepth)
    with pytest.raises(PayloadError) as info:
        codec.decode(data, encoding=codec.encoding, key_expr="cap/t/rov/rov/depth")
    assert reason in str(info.value)
    assert "cap/t/rov/rov/depth" in str(info.value)
    assert "RovDepth" in str(info.value)


def test_nan_in_msgpack_is_rejected() -> None:
    codec = Codec(SonarFrame)
    raw = msgspec.msgpack.encode(
        {
            **msgspec.structs.asdict(SAMPLES_BY_TYPE[SonarFrame]),
            "sound_speed_m_s": math.nan,
        }
    )
    with pytest.raises(PayloadError, match=r"finite|>"):
        codec.decode(raw, encoding=codec.encoding, key_expr="k")


def test_nan_inside_a_tuple_is_rejected() -> None:
    frame = SAMPLES_BY_TYPE[SonarFrame]
    raw = msgspec.msgpack.encode(
        {**msgspec.structs.asdict(frame), "azimuths_rad": [0.0, math.nan, 0.1, 0.2]}
    )
    with pytest.raises(PayloadError, match="finite"):
        Codec(SonarFrame).decode(raw, encoding=None, key_expr="k")


def test_image_size_must_match_shape() -> None:
    frame = SAMPLES_BY_TYPE[SonarFrame]
    raw = msgspec.msgpack.encode({**msgspec.structs.asdict(frame), "image": b"\x00" * 7})
    with pytest.raises(PayloadError, match="expected 16"):
        Codec(SonarFrame).decode(raw, encoding=None, key_expr="k")


def test_unknown_fields_are_tolerated() -> None:
    codec = Codec(RovDepth)
    data = b'{"stamp_ns": 1, "seq": 2, "depth_m": 1.5, "added_in_a_later_minor": [1, 2]}'
    assert codec.decode(data, encoding=codec.encoding, key_expr="k").depth_m == 1.5


def test_other_schema_version_is_rejected() -> None:
    codec = Codec(RovDepth)
    data = b'{"stamp_ns": 1, "seq": 2, "depth_m": 1.5, "schema_version": 2}'
    with pytest.raises(PayloadError, match="schema version 2 is not readable"):
        codec.decode(data, encoding=codec.encoding, key_expr="k")


def test_wrong_encoding_is_rejected() -> None:
    codec = Codec(RovDepth)
    data = codec.encode(RovDepth(stamp_ns=1, seq=0, depth_m=1.0))
    with pytest.raises(PayloadError, match="expected 'application/json;RovDepth'"):
        codec.decode(data, encoding="application/json;RovAttitude", key_expr="k")


def test_decode_any_and_unknown_schema() -> None:
    payload = RovDepth(stamp_ns=1, seq=0, depth_m=1.0)
    data = Codec(RovDepth).encode(payload)
    assert decode_any(data, encoding="application/json;RovDepth", key_expr="k") == payload
    with pytest.raises(PayloadError, match="unknown schema"):
        decode_any(data, encoding="application/json;Nope", key_expr="k")


def test_to_builtins_summarises_bytes() -> None:
    out = to_builtins(SAMPLES_BY_TYPE[SonarFrame])
    assert out["image"] == "<16 bytes>"


finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@given(
    stamp=st.integers(min_value=0, max_value=2**63 - 1),
    seq=st.integers(min_value=0, max_value=2**63 - 1),
    ping=st.integers(min_value=0, max_value=2**32),
    dets=st.lists(
        st.builds(
            Detection,
            range_m=st.floats(min_value=1e-3, max_value=200.0),
            azimuth_rad=st.floats(min_value=-math.pi, max_value=math.pi),
            range_sigma_m=st.floats(min_value=0.0, max_value=10.0),
            azimuth_sigma_rad=st.floats(min_value=0.0, max_value=1.0),
            confidence=st.floats(min_value=0.0, max_value=1.0),
        ),
        max_size=5,
    ),
)
def test_detections_round_trip_property(
    stamp: int, seq: int, ping: int, dets: list[Detection]
) -> None:
    payload = SonarDetections(
        stamp_ns=stamp, seq=seq, ping_id=ping, detector="d", detections=tuple(dets)
    )
    codec = Codec(SonarDetections)
    assert codec.decode(codec.encode(payload), encoding=codec.encoding, key_expr="k") == payload


@given(st.binary(max_size=300))
def test_arbitrary_bytes_never_escape_as_anything_but_payload_error(data: bytes) -> None:
    for cls in ALL_PAYLOADS:
        codec = Codec(cls)
        with contextlib.suppress(PayloadError):
            codec.decode(data, encoding=None, key_expr="k")


SAMPLES_BY_TYPE = {type(s): s for s in SAMPLES}
