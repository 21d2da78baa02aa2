"""The Oculus driver process against a fake sonar on loopback, with a real router."""

from __future__ import annotations

import math
import os
import signal
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import zenoh

from capsd import topics
from capsd.codec import Codec
from capsd.health import query_health
from capsd.payloads import Health, SonarFrame
from capsd.protocols.oculus import HEADER, MSG_SIMPLE_PING_RESULT, OCULUS_ID, parse_ping
from capsd.simulator.oculus_fake import FakeOculus
from tests.conftest import OCULUS_FIXTURES, Proc, free_port, wait_for

pytestmark = pytest.mark.integration

ONE = (OCULUS_FIXTURES / "one_ping_8bit.raw").read_bytes()
THREE = (OCULUS_FIXTURES / "three_pings_8bit.raw").read_bytes()
PINGS = [THREE[i * len(ONE) : (i + 1) * len(ONE)] for i in range(3)]


class Frames:
    def __init__(self, client: zenoh.Session):
        self.codec = Codec(SonarFrame)
        self.got: list[SonarFrame] = []
        self.arrived: list[float] = []  # time.monotonic() of each
        self.sub = client.declare_subscriber(topics.SONAR_FRAME.key("tank", "asv"), self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        self.arrived.append(time.monotonic())
        self.got.append(
            self.codec.decode(
                sample.payload.to_bytes(),
                encoding=str(sample.encoding),
                key_expr=str(sample.key_expr),
            )
        )


def _health(client: zenoh.Session) -> Health:
    health = query_health(client, site="tank", vehicle="asv", service="oculus")
    assert health is not None, "no health from the oculus"
    return health


def _driver(
    spawn: Callable[..., Proc],
    tmp_path: Path,
    endpoint: str,
    *,
    address: str,
    port: int,
    status_port: int = 52102,
) -> Proc:
    config = tmp_path / "oculus.yaml"
    config.write_text(
        f"site: tank\nvehicle: asv\nbus:\n  connect: [{endpoint}]\n"
        f"address: '{address}'\nport: {port}\nstatus_port: {status_port}\n"
        "status_bind: 127.0.0.1\nstall_timeout_s: 1.0\nreconnect_s: 0.2\n"
        "fire:\n  range_m: 2.0\n  gain_percent: 40.0\n"
    )
    return spawn("run", "oculus", "--config", str(config))


def test_frames_from_a_split_and_corrupted_stream(
    spawn: Callable[..., Proc], client: zenoh.Session, endpoint: str, tmp_path: Path
) -> None:
    frames = Frames(client)
    with FakeOculus(PINGS, rate_hz=20.0, split=True, corrupt_every=5) as sonar:
        driver = _driver(spawn, tmp_path, endpoint, address="127.0.0.1", port=sonar.port)
        wait_for(lambda: len(frames.got) >= 12, timeout_s=20, what="12 frames")
        assert sonar.fires, "the driver sent a SimpleFire"
        assert len(sonar.fires[0]) == 89  # v2 by default
        health = _health(client)
    frame = frames.got[0]
    truth = parse_ping(ONE)
    assert (frame.n_ranges, frame.n_beams, frame.sample_bits) == (703, 256, 8)
    # Upright mount: theta = -bearing, so the first beam (-30 deg, to port) is +30 deg theta.
    assert math.degrees(frame.azimuths_rad[0]) == pytest.approx(30.0)
    assert math.degrees(frame.azimuths_rad[-1]) == pytest.approx(-30.0)
    assert frame.range_resolution_m == pytest.approx(truth.range_resolution_m)
    image = np.frombuffer(frame.image, dtype=np.uint8).reshape(703, 256)
    known = {p.ping_id: p for p in (parse_ping(m) for m in PINGS)}
    for f in frames.got:
        assert np.array_equal(
            np.frombuffer(f.image, dtype=np.uint8).reshape(703, 256), known[f.ping_id].image
        )
    # Every 5th message was corrupted: skipped, counted, never published.
    assert health.counters.get("protocol_errors", 0) >= 1
    assert health.counters.get("resyncs", 0) >= 1
    assert driver.popen.poll() is None
    assert image.shape == (703, 256)
    stamps = [f.stamp_ns for f in frames.got]
    assert stamps == sorted(stamps)
    frames.sub.undeclare()


def _hostile_prefix() -> list[bytes]:
    """What a hostile peer on the sonar's link sends before the real pings resume."""
    rng = np.random.default_rng(7)
    # A ping-result header announcing 10 bytes: the ping's structs would read past it.
    short = HEADER.pack(OCULUS_ID, 0, 0, MSG_SIMPLE_PING_RESULT, 0, 10, 0) + bytes(10)
    # 100 KB of headers: the Oculus id every 16 bytes, any message id, any payload size.
    headers = b"".join(
        HEADER.pack(OCULUS_ID, 0, 0, int(rng.integers(0, 2**16)), 0, int(rng.integers(0, 2**32)), 0)
        for _ in range(6400)
    )
    # Ping-result headers with sizes a ping could have: each must not swallow good pings.
    plausible = b"".join(
        HEADER.pack(OCULUS_ID, 0, 0, MSG_SIMPLE_PING_RESULT, int(v), int(size), 0)
        for v, size in zip(rng.integers(0, 3, 500), rng.integers(200, 8_000_000, 500), strict=True)
    )
    return [short, headers, plausible]


def test_hostile_bytes_cost_less_than_a_second_and_a_few_log_lines(
    spawn: Callable[..., Proc], client: zenoh.Session, endpoint: str, tmp_path: Path
) -> None:
    frames = Frames(client)
    with FakeOculus(PINGS, rate_hz=40.0, split=True, prefix=_hostile_prefix()) as sonar:
        driver = _driver(spawn, tmp_path, endpoint, address="127.0.0.1", port=sonar.port)
        wait_for(lambda: len(frames.got) >= 40, timeout_s=20, what="40 frames")
        health = _health(client)
        assert sonar.prefix_sent_at is not None
        # Valid pings resume right after the prefix: the first frame within 1 s of them.
        assert frames.arrived[0] - sonar.prefix_sent_at < 1.0
        assert sonar.connections == 1  # no stall, no reconnect
    assert health.counters.get("protocol_errors", 0) >= 6000
    errors = [line for line in driver.output().splitlines() if "level=error" in line]
    assert len(errors) <= 3, errors  # rate-limited: one line a second per kind at most
    assert all(f.ping_id in {parse_ping(m).ping_id for m in PINGS} for f in frames.got)
    frames.sub.undeclare()


def test_pings_held_up_by_a_stalled_driver_keep_the_time_they_were_taken(
    spawn: Callable[..., Proc], client: zenoh.Session, endpoint: str, tmp_path: Path
) -> None:
    frames = Frames(client)
    with FakeOculus(PINGS, rate_hz=20.0, split=False, live_clock=True) as sonar:
        driver = _driver(spawn, tmp_path, endpoint, address="127.0.0.1", port=sonar.port)
        # 5 s of pings: the driver learns the sonar's counter (3 s of pings that came alone).
        wait_for(lambda: len(frames.got) >= 100, timeout_s=30, what="100 frames")
        os.kill(driver.popen.pid, signal.SIGSTOP)  # the driver starved: 2 s of pings queue up
        time.sleep(2.0)
        os.kill(driver.popen.pid, signal.SIGCONT)
        before = len(frames.got)
        wait_for(lambda: len(frames.got) >= before + 40, timeout_s=20, what="frames after")
        health = _health(client)
    travel_ns = int(2.0 * 2.0 / 1480.0 * 1e9)  # 2 m range
    after = frames.got[before:]
    errors_s = [(f.stamp_ns + travel_ns - sonar.taken_ns[f.ping_id]) / 1e9 for f in after]
    # On arrival the first frames after the stall would be stamped up to 2 s late.
    assert max(abs(e) for e in errors_s) < 0.05, errors_s[:10]
    assert health.counters.get("late_pings", 0) >= 1
    assert health.counters.get("sonar_clock_learnt") == 1
    assert health.counters.get("reconnects", 0) == 0
    frames.sub.undeclare()


def test_reconnects_when_the_sonar_drops_the_link(
    spawn: Callable[..., Proc], client: zenoh.Session, endpoint: str, tmp_path: Path
) -> None:
    frames = Frames(client)
    with FakeOculus(PINGS, rate_hz=20.0, split=False, drop_after=4) as sonar:
        driver = _driver(spawn, tmp_path, endpoint, address="127.0.0.1", port=sonar.port)
        wait_for(
            lambda: sonar.connections >= 3 and len(frames.got) >= 10,
            timeout_s=20,
            what="frames over three connections",
        )
    assert _health(client).counters.get("reconnects", 0) >= 2
    assert driver.popen.poll() is None
    frames.sub.undeclare()


def test_finds_the_sonar_by_its_status_broadcast(
    spawn: Callable[..., Proc], client: zenoh.Session, endpoint: str, tmp_path: Path
) -> None:
    frames = Frames(client)
    status_port = free_port()
    with FakeOculus(PINGS, rate_hz=20.0, split=False) as sonar:
        _driver(spawn, tmp_path, endpoint, address="auto", port=sonar.port, status_port=status_port)

        def found() -> bool:
            sonar.send_status(status_port)
            time.sleep(0.1)
            return len(frames.got) > 0

        wait_for(found, timeout_s=20, what="a frame after discovery")
    frames.sub.undeclare()


def test_detection_service_keeps_up_and_never_processes_stale_frames(
    spawn: Callable[..., Proc], client: zenoh.Session, endpoint: str
) -> None:
    from capsd.payloads import SonarDetections

    got: list[SonarDetections] = []
    codec = Codec(SonarDetections)
    sub = client.declare_subscriber(
        topics.SONAR_DETECTIONS.key("tank", "asv"),
        lambda s: got.append(
            codec.decode(s.payload.to_bytes(), encoding=str(s.encoding), key_expr="d")
        ),
    )
    spawn("run", "sonar_detect", "--connect", endpoint)
    frame_codec = Codec(SonarFrame)
    publisher = client.declare_publisher(
        topics.SONAR_FRAME.key("tank", "asv"), encoding=zenoh.Encoding(frame_codec.encoding)
    )
    base = parse_ping(ONE)
    from capsd.services.sonar_detect.driver import Config as DriverConfig
    from capsd.services.sonar_detect.driver import to_frame

    def frame(i: int) -> bytes:
        return frame_codec.encode(to_frame(base, config=DriverConfig(), stamp_ns=1_000 + i, seq=i))

    def answered() -> bool:
        publisher.put(frame(0))
        time.sleep(0.2)
        return len(got) > 0

    wait_for(answered, timeout_s=20, what="the detector answering")
    before = len(got)
    for i in range(1, 60):  # a burst far faster than a ping rate
        publisher.put(frame(i))
    time.sleep(1.5)
    burst = got[before:]
    assert burst, "the newest frame is processed"
    assert burst[-1].stamp_ns == 1_000 + 59  # ... and it is the newest
    assert [d.stamp_ns for d in burst] == sorted(d.stamp_ns for d in burst)
    health = query_health(client, site="tank", vehicle="asv", service="sonar_detect")
    assert health is not None
    assert health.counters["dropped_stale_frames"] + health.counters["frames"] >= 60
    assert health.counters["dropped_stale_frames"] > 0
    sub.undeclare()


def test_fire_config_names_each_flag() -> None:
    from capsd.protocols.oculus import FireFlag
    from capsd.services.sonar_detect.driver import FireConfig

    # An M3000d as deployed: metres, simple return, 512 beams, fixed gain, 8 bits.
    assert FireConfig().flags() == 0x49
    assert FireConfig(beams=256).flags() == 0x09
    assert FireConfig(gain_assist="on").flags() & FireFlag.GAIN_ASSIST
    assert FireConfig(sample_bits=16).flags() & FireFlag.DATA_16BIT
    assert FireConfig(row_gains="on").flags() & FireFlag.SEND_GAINS
    assert FireConfig().settings().flags == FireConfig().flags()


def test_a_frame_carries_the_speed_of_sound_the_ping_used_and_never_a_guess() -> None:
    from capsd.protocols.oculus import build_ping_result
    from capsd.services.sonar_detect.driver import Config as DriverConfig
    from capsd.services.sonar_detect.driver import FireConfig, to_frame

    def frame(*, reported_m_s: float, told_m_s: float) -> SonarFrame:
        ping = parse_ping(
            build_ping_result(
                version=2,
                ping_id=1,
                bearings_cdeg=np.linspace(-6500, 6500, 8).astype(np.int16),
                image=np.zeros((16, 8), dtype=np.uint8),
                sound_speed_m_s=reported_m_s,
            )
        )
        config = DriverConfig(fire=FireConfig(sound_speed_m_s=told_m_s))
        return to_frame(ping, config=config, stamp_ns=1, seq=1)

    assert frame(reported_m_s=1493.5, told_m_s=0.0).sound_speed_m_s == 1493.5
    # A ping that does not say: the speed it was told to use, else unknown (the locator then
    # keeps the sonar's ranges and counts the ping), never an assumed 1480.
    assert frame(reported_m_s=0.0, told_m_s=1500.0).sound_speed_m_s == 1500.0
    assert frame(reported_m_s=0.0, told_m_s=0.0).sound_speed_m_s is None
    with pytest.raises(ValueError, match="sound_speed_m_s"):
        FireConfig(sound_speed_m_s=500.0)
