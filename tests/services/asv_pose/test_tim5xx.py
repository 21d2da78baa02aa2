"""CoLa-A framing and LMDscandata parsing, and the TiM5xx client against a fake TiM."""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st

from capsd import topics
from capsd.codec import Codec
from capsd.health import query_health
from capsd.keys import is_concrete
from capsd.payloads import LidarScan
from capsd.protocols.cola import ColaError, ColaStream, format_scan, parse_scan, telegram
from capsd.simulator.tim_fake import SAMPLES, START_ANGLE_DEG, STEP_DEG, FakeTim
from tests.conftest import Proc, wait_for

RANGES_MM = [1000 + (k % 400) * 10 for k in range(SAMPLES)]
RANGES_MM[5] = 0  # no return


def _text(counter: int = 7) -> str:
    return format_scan(
        scan_counter=counter,
        time_us=123456,
        scan_frequency_hz=15.0,
        start_angle_deg=START_ANGLE_DEG,
        step_deg=STEP_DEG,
        ranges_mm=RANGES_MM,
        rssi=[200] * SAMPLES,
    )


def test_parse_scan_reads_every_field() -> None:
    scan = parse_scan(_text())
    assert scan.scan_counter == 7
    assert scan.time_since_startup_us == 123456
    assert scan.scan_frequency_hz == 15.0
    assert scan.start_angle_deg == pytest.approx(-45.0)
    assert scan.step_deg == pytest.approx(0.3333)
    assert len(scan.ranges_m) == SAMPLES
    assert scan.ranges_m[0] == pytest.approx(1.0)
    assert scan.ranges_m[5] == 0.0
    assert scan.intensities[0] == 200.0


def test_a_known_telegram_from_the_manual_layout() -> None:
    # Hand-written in the documented layout: -45 deg start, 1/3 deg, 3 samples, scale 1.0.
    text = (
        "sRA LMDscandata 1 1 89A27F 0 0 343 347 27477BA9 2747844D 0 0 7 0 0 1388 168 0 1 "
        "DIST1 3F800000 00000000 FFF92230 D05 3 3E8 0 1F4 0 0 0 0 0 0"
    )
    scan = parse_scan(text)
    assert scan.scan_counter == 0x347
    assert scan.scan_frequency_hz == 50.0
    assert scan.start_angle_deg == -45.0
    assert scan.ranges_m == (1.0, 0.0, 0.5)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("sRA LMDscandata 1 1", "ends before"),
        ("sFA 3", "not a scan telegram"),
        (_text().replace("DIST1 3F800000", "DIST1 ZZZZ"), "not hex"),
        (_text().replace(f" {SAMPLES:X} ", " FFFF ", 1), "count"),
        (_text().replace("DIST1", "DIST9"), "no DIST1"),
        # A 400-digit number where a 32-bit one belongs (it overflowed a float before).
        (_text().replace("DIST1 3F800000", "DIST1 " + "F" * 400), "wider than 32 bits"),
        (_text().replace(f" {SAMPLES:X} ", " " + "1" * 400 + " ", 1), "wider than 32 bits"),
    ],
)
def test_bad_telegrams_name_the_field(text: str, message: str) -> None:
    with pytest.raises(ColaError, match=message):
        parse_scan(text)


@settings(max_examples=150, deadline=None)
@given(cuts=st.lists(st.integers(1, 40_000), max_size=12), junk=st.binary(max_size=40))
def test_stream_split_anywhere_gives_the_same_telegrams(cuts: list[int], junk: bytes) -> None:
    junk = junk.replace(b"\x02", b"").replace(b"\x03", b"")
    data = junk + b"".join(telegram(_text(k)) for k in range(3))
    stream = ColaStream()
    texts: list[str] = []
    pos = 0
    for cut in [*sorted({c % (len(data) + 1) for c in cuts}), len(data)]:
        texts += [t for t in stream.feed(data[pos:cut]) if isinstance(t, str)]
        pos = cut
    assert [parse_scan(t).scan_counter for t in texts] == [0, 1, 2]


def test_a_cut_telegram_is_dropped_and_the_next_one_read() -> None:
    whole = telegram(_text(1))
    stream = ColaStream()
    items = list(stream.feed(whole[:500] + telegram(_text(2))))
    assert isinstance(items[0], ColaError)
    assert [parse_scan(t).scan_counter for t in items if isinstance(t, str)] == [2]


_FIELDS = _text().split(" ")


@settings(max_examples=300, deadline=None)
@given(
    data=st.binary(max_size=3000),
    token=st.text("0123456789ABCDEF", max_size=500),
    # Any field of an otherwise valid telegram, the header's (its first 40) drawn half the time:
    # one telegram per example, not one per field (that took 70 s for the same cover).
    field=st.one_of(st.integers(0, 40), st.integers(0, len(_FIELDS) - 1)),
)
def test_garbage_never_raises(data: bytes, token: str, field: int) -> None:
    texts = [t for t in ColaStream().feed(data) if isinstance(t, str)]
    texts.append(" ".join([*_FIELDS[:field], token, *_FIELDS[field + 1 :]]))
    for text in texts:
        with contextlib.suppress(ColaError):
            parse_scan(text)


# ------------------------------------------------------------------ the client process


def _tank_scan_mm(k: int) -> list[int]:
    """A square room 6 x 6 m around the scanner, as a TiM would see it (SICK angles)."""
    out = []
    for i in range(SAMPLES):
        sick_deg = START_ANGLE_DEG + i * STEP_DEG
        a = math.radians(sick_deg - 90.0)
        r = 3.0 / max(abs(math.cos(a)), abs(math.sin(a)))
        out.append(round(r * 1000))
    return out


@pytest.mark.integration
def test_client_streams_reconnects_after_a_cut_and_counts_garbage(
    spawn: Callable[..., Proc], router: Proc, endpoint: str, client: zenoh.Session, tmp_path: Path
) -> None:
    got: list[LidarScan] = []
    lock = threading.Lock()
    codec = Codec(LidarScan)

    def on_sample(sample: zenoh.Sample) -> None:
        if is_concrete(str(sample.key_expr)):
            scan = codec.decode(
                sample.payload.to_bytes(),
                encoding=str(sample.encoding),
                key_expr=str(sample.key_expr),
            )
            with lock:
                got.append(scan)

    sub = client.declare_subscriber(topics.ASV_SCAN.key("tank", "asv"), on_sample)
    with FakeTim(_tank_scan_mm, rate_hz=15.0, corrupt_every=7, cut_after=20) as tim:
        config = tmp_path / "tim.yaml"
        config.write_text(f"address: 127.0.0.1\nport: {tim.port}\nreconnect_s: 0.2\n")
        spawn("run", "tim5xx", "--config", str(config), "--connect", endpoint)
        wait_for(lambda: len(got) >= 30, timeout_s=30, what="30 scans across a reconnect")
        assert tim.connections >= 2  # the cut mid-telegram was survived by reconnecting
        assert "sEN LMDscandata 1" in tim.requests
    scan = got[0]
    assert len(scan.ranges_m) == SAMPLES
    assert scan.angle_min_rad == pytest.approx(math.radians(-135.0))
    # Straight ahead (angle 0) the wall is 3 m away; at 45 deg the corner is 4.24 m.
    angles = scan.angle_min_rad + scan.angle_increment_rad * np.arange(SAMPLES)
    ahead = int(np.argmin(np.abs(angles)))
    corner = int(np.argmin(np.abs(angles - math.pi / 4)))
    assert scan.ranges_m[ahead] == pytest.approx(3.0, abs=0.005)
    assert scan.ranges_m[corner] == pytest.approx(3.0 * math.sqrt(2), abs=0.02)
    health = query_health(client, site="tank", vehicle="asv", service="tim5xx", timeout_s=2)
    assert health is not None
    assert health.counters["bad_telegrams"] >= 1  # the garbled ones, counted not published
    assert health.counters["reconnects"] >= 1
    sub.undeclare()


@pytest.mark.integration
def test_hostile_bytes_cost_less_than_a_second_and_a_few_log_lines(
    spawn: Callable[..., Proc], router: Proc, endpoint: str, client: zenoh.Session, tmp_path: Path
) -> None:
    arrived: list[float] = []
    sub = client.declare_subscriber(
        topics.ASV_SCAN.key("tank", "asv"), lambda _s: arrived.append(time.monotonic())
    )
    # 64,000 telegram starts, then a telegram whose numbers are 400 hex digits wide.
    hostile = b"\x02" * 64_000 + telegram("sSN LMDscandata " + " ".join(["F" * 400] * 30))
    with FakeTim(_tank_scan_mm, rate_hz=15.0, prefix=hostile) as tim:
        config = tmp_path / "tim.yaml"
        config.write_text(f"address: 127.0.0.1\nport: {tim.port}\nreconnect_s: 0.2\n")
        proc = spawn("run", "tim5xx", "--config", str(config), "--connect", endpoint)
        wait_for(lambda: len(arrived) >= 15, timeout_s=30, what="15 scans after the hostile bytes")
        assert tim.prefix_sent_at is not None
        assert arrived[0] - tim.prefix_sent_at < 1.0
        assert tim.connections == 1
        health = query_health(client, site="tank", vehicle="asv", service="tim5xx", timeout_s=2)
    assert health is not None
    assert health.counters["bad_telegrams"] >= 1, health.counters
    errors = [
        line
        for line in proc.output().splitlines()
        if "level=error" in line or "level=warning" in line
    ]
    assert len(errors) <= 4, errors
    sub.undeclare()
