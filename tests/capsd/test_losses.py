"""capsd.losses: each labelled ping of a recording lands in the class its payloads say."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from capsd import topics
from capsd.cli import main
from capsd.codec import Codec
from capsd.errors import CapsdError
from capsd.losses import load, since
from capsd.payloads import Detection, Payload, RovFix, SonarDetections, SonarLabel
from capsd.recording import McapRecorder, Sample

ROV = (4.0, 1.0, -3.0)
COV = tuple([1e-4, 0.0, 0.0, 0.0, 1e-4, 0.0, 0.0, 0.0, 1e-4])
SECOND = 1_000_000_000


def _label(k: int, *, visible: bool = True, elevation_deg: float = 0.0) -> SonarLabel:
    return SonarLabel(
        stamp_ns=k * SECOND, seq=k, ping_id=k, visible=visible, range_m=5.0,
        azimuth_rad=0.1, elevation_rad=math.radians(elevation_deg), rov_position_m=ROV,
    )  # fmt: skip


def _detections(k: int, *at: tuple[float, float, float]) -> SonarDetections:
    found = tuple(
        Detection(
            range_m=r, azimuth_rad=a, range_sigma_m=0.02, azimuth_sigma_rad=0.01, confidence=c
        )
        for r, a, c in at
    )
    return SonarDetections(stamp_ns=k * SECOND, seq=k, ping_id=k, detector="cnn", detections=found)


def _fix(k: int, quality: str, *, reason: str | None = None, dx: float = 0.0) -> RovFix:
    good = quality == "good"
    return RovFix(
        stamp_ns=k * SECOND, seq=k, method="capsd", quality=quality,  # type: ignore[arg-type]
        no_fix_reason=reason, track_state="tracking" if good else "lost",
        position_m=(ROV[0] + dx, ROV[1], ROV[2]) if good else None,
        covariance_m2=COV if good else None,
    )  # fmt: skip


ON_ROV = (5.1, 0.1, 0.9)  # within 0.5 m of the label
ELSEWHERE = (7.0, 0.1, 0.9)
FAINT = (5.0, 0.1, 0.3)  # on the ROV, under the service's 0.5 threshold

# ping: (label, detections or None, fix or None), and the class and detail it must get
PINGS: list[tuple[SonarLabel, SonarDetections | None, RovFix | None, str, str]] = [
    (_label(0, visible=False, elevation_deg=12.0), _detections(0), _fix(0, "invalid"),
     "out_of_view", "above the aperture"),
    (_label(1, visible=False, elevation_deg=-11.0), _detections(1), _fix(1, "invalid"),
     "out_of_view", "below the aperture"),
    (_label(2, visible=False), _detections(2), _fix(2, "invalid"),
     "out_of_view", "outside the fan (bearing, range) or hidden"),
    (_label(3), None, _fix(3, "invalid"), "no_detections", ""),
    (_label(4), _detections(4, FAINT), _fix(4, "invalid"), "missed", "no candidate"),
    (_label(5), _detections(5, ELSEWHERE), _fix(5, "invalid", reason="outside_gate"),
     "missed", "candidates elsewhere"),
    (_label(6), _detections(6, ON_ROV), None, "no_fix", ""),
    (_label(7), _detections(7, ON_ROV), _fix(7, "invalid", reason="map_clutter"),
     "refused", "map_clutter"),
    (_label(8), _detections(8, ON_ROV), _fix(8, "good"), "good", "on the ROV"),
    (_label(9), _detections(9, ELSEWHERE, ON_ROV), _fix(9, "good", dx=0.5),
     "good", "off the ROV"),
    # a good fix on clutter while the ROV was out of view: counted as such
    (_label(10, visible=False, elevation_deg=15.0), _detections(10, ELSEWHERE), _fix(10, "good"),
     "out_of_view", "above the aperture"),
    # in view by a part of it, its centre 12 deg below the boresight
    (_label(11, elevation_deg=-12.0), _detections(11, FAINT), None,
     "missed", "no candidate, centre in the skirt"),
]  # fmt: skip


def _write(path: Path) -> None:
    recorder = McapRecorder(path)
    try:
        for label, detections, fix in ((p[0], p[1], p[2]) for p in PINGS):
            payloads: list[tuple[str, Payload | None]] = [
                (topics.SIM_LABEL.key("tank", "sim"), label),
                (topics.SONAR_DETECTIONS.key("tank", "asv"), detections),
                (topics.ROV_FIX.key("tank", "topside"), fix),
            ]
            for key, payload in payloads:
                if payload is None:
                    continue
                codec = Codec(type(payload))
                recorder.write(Sample(key, codec.encoding, codec.encode(payload), label.stamp_ns))
        # A payload that does not decode is counted, not judged.
        recorder.write(Sample(topics.ROV_FIX.key("tank", "topside"),
                              Codec(RovFix).encoding, b"{not json", 99 * SECOND))  # fmt: skip
    finally:
        recorder.close()


def test_each_ping_lands_in_its_class(tmp_path: Path) -> None:
    recording = tmp_path / "run.mcap"
    _write(recording)
    losses = load(recording)
    assert [(p.kind, p.detail) for p in losses.pings] == [(p[3], p[4]) for p in PINGS]
    assert losses.undecodable == 1
    assert losses.good_without_rov() == 1
    assert [p.fix_error_m for p in losses.pings if p.kind == "good"] == [
        0.0, pytest.approx(0.5)
    ]  # fmt: skip
    assert len(since(losses, 5.0).pings) == 7


def test_the_command_prints_and_writes_the_classes(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    recording = tmp_path / "run.mcap"
    _write(recording)
    assert main(["losses", str(recording), "--out", str(tmp_path / "out")]) == 0
    printed = capfd.readouterr().out
    assert "12 labelled pings" in printed
    assert "map_clutter" in printed
    summary = json.loads((tmp_path / "out" / "losses.json").read_text())
    assert summary["classes"]["out_of_view"]["pings"] == 4
    assert summary["classes"]["refused"]["details"] == {"map_clutter": 1}
    assert summary["good_without_rov"] == 1
    assert (tmp_path / "out" / "losses.png").stat().st_size > 0


def test_a_recording_without_labels_is_a_clear_error(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "field.mcap"
    McapRecorder(path).close()
    with pytest.raises(CapsdError, match="no label key"):
        load(path)
    assert main(["losses", str(path)]) == 2
    assert "no label key" in capfd.readouterr().err
