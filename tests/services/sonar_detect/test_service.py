"""The detection service and the replay source as real processes on 127.0.0.1."""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import zenoh

from capsd import topics
from capsd.codec import Codec
from capsd.health import query_health
from capsd.keys import is_concrete
from capsd.payloads import SonarDetections, SonarFrame, SonarLabel
from tests.conftest import OCULUS_FIXTURES, Proc, relay, wait_for

pytestmark = pytest.mark.integration


def _collect(client: zenoh.Session, key: str, codec: Codec[Any], into: list[Any]) -> Any:
    lock = threading.Lock()

    def on_sample(sample: zenoh.Sample) -> None:
        if not is_concrete(str(sample.key_expr)):
            return
        payload = codec.decode(
            sample.payload.to_bytes(), encoding=str(sample.encoding), key_expr=str(sample.key_expr)
        )
        with lock:
            into.append(payload)

    return client.declare_subscriber(key, on_sample)


def test_cnn_service_detects_the_simulated_rov_stamped_at_the_ping(
    spawn: Callable[..., Proc], router: Proc, endpoint: str, client: zenoh.Session, tmp_path: Path
) -> None:
    frames: list[object] = []
    labels: list[object] = []
    found: list[object] = []
    subs = [
        _collect(client, topics.SONAR_FRAME.key("tank", "asv"), Codec(SonarFrame), frames),
        _collect(client, topics.SIM_LABEL.key("tank", "sim"), Codec(SonarLabel), labels),
        _collect(client, topics.SONAR_DETECTIONS.key("tank", "asv"), Codec(SonarDetections), found),
    ]
    # The simulator's noisy ASV pose (on its own sim/ key; the test relays it, playing the
    # asv_pose service) and the ROV's depth feed the detector's depth-aware search.
    subs.append(
        relay(client, topics.SIM_ASV_POSE.key("tank", "sim"), topics.ASV_POSE.key("tank", "asv"))
    )
    sim_config = _write(
        tmp_path,
        "sim.yaml",
        "streams:\n  lidar: 'off'\n  imu: 'off'\n  asv_pose_truth_noise: 'on'\n"
        "  detections_truth_noise: 'off'\nrates:\n  sonar_hz: 10.0\n",
    )
    spawn(
        "run", "sonar_detect", "--config", "deploy/config/sonar_detect.yaml", "--connect", endpoint
    )
    spawn("run", "sim", "--config", str(sim_config), "--connect", endpoint)
    wait_for(lambda: len(found) >= 40, timeout_s=60, what="40 detection messages")
    by_ping = {lab.ping_id: lab for lab in labels if isinstance(lab, SonarLabel)}
    stamps = {f.ping_id: f.stamp_ns for f in frames if isinstance(f, SonarFrame)}
    errors_m = []
    for det in found:
        assert isinstance(det, SonarDetections)
        assert det.detector == "cnn"
        if det.ping_id in stamps:
            assert det.stamp_ns == stamps[det.ping_id]  # the ping's stamp, not the detector's
        label = by_ping.get(det.ping_id)
        if label is None or not label.visible or not det.detections:
            continue
        best = det.detections[0]
        dx = best.range_m * math.cos(best.azimuth_rad) - label.range_m * math.cos(label.azimuth_rad)
        dy = best.range_m * math.sin(best.azimuth_rad) - label.range_m * math.sin(label.azimuth_rad)
        errors_m.append(math.hypot(dx, dy))
    assert len(errors_m) >= 20
    errors_m.sort()
    assert errors_m[len(errors_m) // 2] < 0.05
    health = query_health(client, site="tank", vehicle="asv", service="sonar_detect", timeout_s=2)
    assert health is not None
    assert health.counters["frames"] >= 40
    assert "dropped_stale_frames" in health.counters
    # The gate ran on (nearly) every ping and kept the ROV (the median error above).
    assert health.counters["depth_gated_frames"] >= 30
    assert "rejected_by_depth" in health.counters
    assert "ambiguous_candidates" in health.counters
    for sub in subs:
        sub.undeclare()


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_replay_of_real_oculus_bytes_reaches_the_bus(
    spawn: Callable[..., Proc], router: Proc, endpoint: str, client: zenoh.Session, tmp_path: Path
) -> None:
    frames: list[object] = []
    sub = _collect(client, topics.SONAR_FRAME.key("tank", "asv"), Codec(SonarFrame), frames)
    config = _write(
        tmp_path,
        "replay.yaml",
        f"path: {OCULUS_FIXTURES / 'three_pings_8bit.raw'}\nformat: oculus\nping_rate_hz: 20\n",
    )
    spawn("run", "sonar_replay", "--config", str(config), "--connect", endpoint)
    wait_for(lambda: len(frames) >= 6, timeout_s=20, what="6 replayed frames (two passes)")
    frame = frames[0]
    assert isinstance(frame, SonarFrame)
    assert (frame.n_ranges, frame.n_beams) == (703, 256)
    degrees = sorted(math.degrees(a) for a in frame.azimuths_rad)
    assert -31.0 < degrees[0] < -29.0
    assert 29.0 < degrees[-1] < 31.0
    sub.undeclare()


@pytest.mark.shares_cpu  # the process exits on its config: nothing timed
@pytest.mark.parametrize(
    ("service", "text", "where"),
    [
        ("sonar_replay", "path: /nonexistent/recording.raw\n", "'path'"),
        ("sonar_replay", "path: {junk}\n", "no sonar frame"),
        ("sonar_detect", "detector: cnn\ncnn:\n  weights: /nonexistent/net.pt\n", "'cnn.weights'"),
        ("sonar_detect", "detector: cnn\ncnn:\n  weights: {junk}\n", "not a weights file"),
    ],
)
def test_bad_recording_or_weights_is_a_config_error(
    spawn: Callable[..., Proc], endpoint: str, tmp_path: Path, service: str, text: str, where: str
) -> None:
    junk = _write(tmp_path, "junk.bin", "not a recording, not weights\n" * 10)
    config = _write(tmp_path, "bad.yaml", text.format(junk=junk))
    proc = spawn("run", service, "--config", str(config), "--connect", endpoint)
    assert proc.popen.wait(timeout=30) == 2
    assert where in proc.output()


def test_cadence_refuses_a_frame_older_than_the_ping_period() -> None:
    from capsd.services.sonar_detect.service import Cadence

    cadence = Cadence()
    period, ms = 25_000_000, 1_000_000  # 40 Hz
    t0 = 10**18

    def old(k: int, *, waited_ms: float) -> bool:
        stamp = t0 + k * period
        received = stamp + 3 * ms
        return cadence.too_old(stamp, received_ns=received, now_ns=received + int(waited_ms * ms))

    for k in range(5):
        assert not old(k, waited_ms=1)
    assert not old(5, waited_ms=20)  # 23 ms after its ping
    assert old(6, waited_ms=23)  # 26 ms after its ping: a newer one is on its way
    assert old(8, waited_ms=23)  # a dropped frame (one long gap) does not change the period
    # Stamps from another clock (or a replay): ages mean nothing, only the mailbox rule holds.
    skewed = Cadence()
    for k in range(6):
        stamp = t0 + k * period
        assert not skewed.too_old(stamp, received_ns=stamp + 900 * ms, now_ns=stamp + 990 * ms)
