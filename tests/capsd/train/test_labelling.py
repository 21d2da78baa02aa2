from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from capsd import topics
from capsd.codec import Codec
from capsd.errors import CapsdError
from capsd.geometry import matrix_to_quat
from capsd.payloads import AsvPose, RovFix, SonarFrame, SonarLabel
from capsd.recording import McapRecorder, Sample
from capsd.simulator.config import OFFLINE_START_NS, Config, Rates, Streams
from capsd.simulator.install_errors import InstallErrorsConfig
from capsd.simulator.sim import Simulation
from capsd.train.labelling import (
    REJECTED_FILE,
    label_recording,
    read_labels,
    write_labels,
)

COV = tuple(float(v) for v in (np.eye(3) * 0.01**2).ravel())


def _dive(path: Path) -> list[tuple[SonarFrame, SonarLabel]]:
    """A short simulated dive recorded as the live system would: frames, poses, fixes.

    The fixes and poses are the simulator's truth, so the labels must land on its labels.
    """
    config = Config(
        tank="nfp",
        seed=7,
        rates=Rates(sonar_hz=5.0),
        install_errors=InstallErrorsConfig(mode="off"),  # the nominal mount is the true one
        streams=Streams(
            lidar="off", imu="off", asv_pose_truth_noise="off", detections_truth_noise="off"
        ),
    )
    sim = Simulation(config, horizon_s=10.0)
    recorder = McapRecorder(path)
    frame_codec, pose_codec, fix_codec = Codec(SonarFrame), Codec(AsvPose), Codec(RovFix)
    pings = []
    for k, (t_s, frame, label) in enumerate(
        sim.labelled_pings(start_ns=OFFLINE_START_NS, duration_s=2.0)
    ):
        pose = sim.asv_pose(t_s)
        q = matrix_to_quat(pose.rotation)
        asv = AsvPose(
            stamp_ns=frame.stamp_ns,
            seq=k,
            position_m=tuple(float(v) for v in pose.translation),  # type: ignore[arg-type]
            orientation_xyzw=tuple(float(v) for v in q),  # type: ignore[arg-type]
            covariance=tuple([1e-6] * 36),
        )
        fix = RovFix(
            stamp_ns=frame.stamp_ns,
            seq=k,
            method="capsd",
            quality="good",
            position_m=label.rov_position_m,
            covariance_m2=COV,
            track_state="tracking",
        )
        for key, data, encoding in (
            (
                topics.SONAR_FRAME.key("tank", "asv"),
                frame_codec.encode(frame),
                frame_codec.encoding,
            ),
            (topics.ASV_POSE.key("tank", "asv"), pose_codec.encode(asv), pose_codec.encoding),
            (topics.ROV_FIX.key("tank", "topside"), fix_codec.encode(fix), fix_codec.encoding),
        ):
            recorder.write(Sample(key, encoding, data, frame.stamp_ns))
        pings.append((frame, label))
    recorder.close()
    return pings


def test_labels_land_where_the_simulator_says_the_rov_is(tmp_path: Path) -> None:
    recording = tmp_path / "dive.mcap"
    pings = _dive(recording)
    labels, summary = label_recording(recording, sonar=Config().sonar)
    truth = {frame.stamp_ns: label for frame, label in pings}
    assert summary.frames == len(pings)
    assert summary.labelled == len(labels) >= len(pings) - summary.outside_fan
    assert len(labels) >= 5
    for label in labels:
        frame = Codec(SonarFrame).decode(label.frame, encoding=None, key_expr="test")
        expected = truth[frame.stamp_ns]
        assert label.range_m == pytest.approx(expected.range_m, abs=1e-6)
        assert label.azimuth_rad == pytest.approx(expected.azimuth_rad, abs=1e-6)


def test_rejected_crops_are_left_out_and_bad_lines_named(tmp_path: Path) -> None:
    recording = tmp_path / "dive.mcap"
    _dive(recording)
    labels, _ = label_recording(recording, sonar=Config().sonar)
    folder = tmp_path / "labels"
    sheets = write_labels(labels, folder)
    assert sheets
    assert all(p.stat().st_size > 1000 for p in sheets)
    assert len(read_labels(folder)) == len(labels)
    (folder / REJECTED_FILE).write_text("# checked by a person\n0\n2  # a wall, not the ROV\n")
    kept = read_labels(folder)
    assert len(kept) == len(labels) - 2
    assert kept[0] == labels[1]
    (folder / REJECTED_FILE).write_text("999\n")
    with pytest.raises(CapsdError, match=r"rejected\.txt:1"):
        read_labels(folder)


def test_a_recording_without_frames_is_a_clear_error(tmp_path: Path) -> None:
    path = tmp_path / "empty.mcap"
    McapRecorder(path).close()
    with pytest.raises(CapsdError, match="no sonar frames"):
        label_recording(path, sonar=Config().sonar)


def test_finetune_adapts_the_weights_to_the_labels(tmp_path: Path) -> None:
    import torch

    from capsd.services.sonar_detect.cnn import DEFAULT_WEIGHTS
    from capsd.services.sonar_detect.polar_net import load
    from capsd.train.finetune import FinetuneConfig, finetune

    recording = tmp_path / "dive.mcap"
    _dive(recording)
    labels, _ = label_recording(recording, sonar=Config().sonar)
    write_labels(labels, tmp_path / "labels")
    config = FinetuneConfig(
        proposal_epochs=1, refine_epochs=1, replay_runs=1, replay_duration_s=2.0, workers=1
    )
    meta = finetune(DEFAULT_WEIGHTS, tmp_path / "labels", tmp_path / "out", config)
    assert meta["samples"]["labelled_pings"] == len(labels)
    assert meta["samples"]["site_crops"] >= len(labels)
    before, after = load(DEFAULT_WEIGHTS), load(tmp_path / "out" / "polar_net.pt")
    changed = [
        name
        for name, value in after.refine.state_dict().items()
        if not torch.equal(value, before.refine.state_dict()[name])
    ]
    assert changed
    # The operating point is set on the site's frames, never below the shipped one.
    assert float(after.logit_offset) >= float(before.logit_offset)
    assert meta["operating_point"]["offset"] == pytest.approx(float(after.logit_offset))
