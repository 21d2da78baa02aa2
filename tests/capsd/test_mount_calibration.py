"""Sonar mount self-calibration from the tank walls, on synthetic frames with a known error."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import msgspec
import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from capsd import topics
from capsd.codec import Codec
from capsd.errors import CapsdError
from capsd.geometry import Transform, matrix_to_quat
from capsd.mount_calibration import (
    Observation,
    _beam_directions,
    _mount_with,
    fit_mount,
    predicted_edges,
)
from capsd.mounts import RovConfig, SonarMountConfig
from capsd.payloads import AsvPose, RovDepth, SonarFrame
from capsd.recording import McapRecorder, Sample
from capsd.tank import TankBounds
from tests.conftest import REPO

TANK = TankBounds(length_m=20.0, width_m=12.0, depth_m=6.0)
MOUNT = SonarMountConfig()
N_BEAMS, N_RANGES, RESOLUTION_M = 128, 800, 0.02
AZIMUTHS = np.linspace(-math.radians(60), math.radians(60), N_BEAMS)


def _asv(heading_rad: float) -> Transform:
    return Transform.from_euler_zyx((9.0, 6.5, 0.0), yaw_rad=heading_rad, pitch_rad=0, roll_rad=0)


def _frame(asv: Transform, true_sonar: Transform, rng: np.random.Generator, k: int) -> SonarFrame:
    """Water at ~20/255 with noise; each beam's wall band from where the true mount puts it."""
    spacing = float(AZIMUTHS[1] - AZIMUTHS[0])
    rays = _beam_directions(MOUNT, AZIMUTHS, math.radians(20.0), 0.0, spacing)
    edges = predicted_edges(asv, true_sonar, rays, TANK)
    ranges = (np.arange(N_RANGES) + 0.5) * RESOLUTION_M
    image = rng.normal(20.0, 6.0, (N_RANGES, N_BEAMS))
    for b, edge in enumerate(edges):
        if np.isfinite(edge):
            image[(ranges >= edge) & (ranges < edge + 0.6), b] += 150.0
    return SonarFrame(
        stamp_ns=1_800_000_000_000_000_000 + k * 500_000_000,
        seq=k,
        ping_id=k,
        n_ranges=N_RANGES,
        n_beams=N_BEAMS,
        sample_bits=8,
        image=memoryview(np.clip(image, 0, 255).astype(np.uint8).tobytes()),
        azimuths_rad=tuple(float(a) for a in AZIMUTHS),
        range_start_m=0.0,
        range_resolution_m=RESOLUTION_M,
        sound_speed_m_s=1500.0,
        gain_percent=50.0,
        frequency_hz=1.2e6,
        vertical_aperture_rad=math.radians(20.0),
    )


def _spin(true_sonar: Transform, frames: int = 48) -> list[Observation]:
    """The calibration manoeuvre: the ASV turning on the spot, one frame every 7.5 deg."""
    rng = np.random.default_rng(0)
    return [
        Observation(
            _frame(_asv(k * math.tau / frames), true_sonar, rng, k), _asv(k * math.tau / frames)
        )
        for k in range(frames)
    ]


@settings(max_examples=30, deadline=None)
@given(st.floats(0.5, 19.5), st.floats(0.5, 11.5), st.floats(-math.pi, math.pi))
def test_a_level_ray_meets_the_wall_it_points_at(x: float, y: float, heading: float) -> None:
    origin = Transform.from_euler_zyx((x, y, -1.0), yaw_rad=heading, pitch_rad=0.0, roll_rad=0.0)
    ray = np.array([[[1.0, 0.0, 0.0]]])  # along the sonar's x, level
    level = Transform.from_euler_zyx((0, 0, 0), yaw_rad=0.0, pitch_rad=0.0, roll_rad=0.0)
    (edge,) = predicted_edges(origin, level, ray, TANK)
    dx, dy = math.cos(heading), math.sin(heading)
    t = min(
        ((TANK.length_m - x) / dx) if dx > 1e-9 else (-x / dx) if dx < -1e-9 else math.inf,
        ((TANK.width_m - y) / dy) if dy > 1e-9 else (-y / dy) if dy < -1e-9 else math.inf,
    )
    assert edge == pytest.approx(t, rel=1e-9)


@pytest.mark.parametrize(("yaw_deg", "roll_deg"), [(0.6, 0.0), (-0.8, 0.5), (0.0, -0.7)])
def test_a_known_heading_and_roll_error_is_recovered(yaw_deg: float, roll_deg: float) -> None:
    true_sonar = _mount_with(MOUNT, math.radians(yaw_deg), math.radians(roll_deg), (0.0, 0.02))
    fit = fit_mount(_spin(true_sonar), mount=MOUNT, tank=TANK)
    assert fit.yaw_determined
    assert fit.yaw_deg == pytest.approx(yaw_deg, abs=0.05)
    assert fit.roll_deg == pytest.approx(roll_deg, abs=0.2)
    assert fit.shift_y_m == pytest.approx(0.02, abs=0.01)
    assert abs(fit.yaw_deg - yaw_deg) < 4 * fit.yaw_sigma_deg + 0.01  # an honest sigma


def test_from_one_heading_it_says_what_it_cannot_tell() -> None:
    # Without the turn, with one wall in view, heading, roll and position move its edge
    # nearly alike: their 1-sigma (what they trade against each other) is too wide to write.
    true_sonar = _mount_with(MOUNT, math.radians(0.6), math.radians(-0.5), (0.0, 0.02))
    rng = np.random.default_rng(3)
    asv = _asv(1.0)
    still = [Observation(_frame(asv, true_sonar, rng, k), asv) for k in range(24)]
    fit = fit_mount(still, mount=MOUNT, tank=TANK)
    assert not fit.yaw_determined
    assert not fit.roll_determined
    assert not fit.shift_determined
    turned = fit_mount(_spin(true_sonar), mount=MOUNT, tank=TANK)
    assert turned.yaw_determined
    assert turned.roll_determined
    assert turned.shift_determined


def test_without_walls_in_view_it_refuses() -> None:
    rng = np.random.default_rng(1)
    true_sonar = _mount_with(MOUNT, 0.0, 0.0)
    asv = _asv(0.0)
    blank = _frame(asv, true_sonar, rng, 0)
    quiet = SonarFrame(
        **{
            **{f: getattr(blank, f) for f in blank.__struct_fields__},
            "image": memoryview(bytes(N_RANGES * N_BEAMS)),
        }
    )
    with pytest.raises(CapsdError, match="clean wall edges"):
        fit_mount([Observation(quiet, asv)] * 5, mount=MOUNT, tank=TANK)


def _floating(start_ns: int, *, seconds: float, reading_bias_m: float) -> list[RovDepth]:
    """A ROV floating level at the default floating depth, heaving 2 cm, its reading biased."""
    out = []
    for k in range(int(seconds * 10)):
        heave = 0.02 * math.sin(2 * math.pi * k / 51)
        depth = RovConfig().float_depth_m + heave + reading_bias_m
        out.append(RovDepth(stamp_ns=start_ns + k * 100_000_000, seq=k, depth_m=depth))
    return out


def _record(
    path: Path, observations: list[Observation], depths: list[RovDepth] | None = None
) -> None:
    frame_codec, pose_codec, depth_codec = Codec(SonarFrame), Codec(AsvPose), Codec(RovDepth)
    recorder = McapRecorder(path)
    depth_key = topics.ROV_DEPTH.key("tank", "rov")
    for depth in depths or []:
        encoded = depth_codec.encode(depth)
        recorder.write(Sample(depth_key, depth_codec.encoding, encoded, depth.stamp_ns))
    for obs in observations:
        x, y, z = (float(v) for v in obs.asv.translation)
        qx, qy, qz, qw = (float(v) for v in matrix_to_quat(obs.asv.rotation))
        pose = AsvPose(
            stamp_ns=obs.frame.stamp_ns,
            seq=obs.frame.seq,
            position_m=(x, y, z),
            orientation_xyzw=(qx, qy, qz, qw),
            covariance=(0.0,) * 36,
        )
        pose_key, frame_key = (t.key("tank", "asv") for t in (topics.ASV_POSE, topics.SONAR_FRAME))
        recorder.write(
            Sample(pose_key, pose_codec.encoding, pose_codec.encode(pose), pose.stamp_ns)
        )
        recorder.write(
            Sample(
                frame_key, frame_codec.encoding, frame_codec.encode(obs.frame), obs.frame.stamp_ns
            )
        )
    recorder.close()


def test_capsd_calibrate_writes_the_corrected_config(tmp_path: Path) -> None:
    true_sonar = _mount_with(MOUNT, math.radians(0.7), 0.0)
    recording = tmp_path / "spin.mcap"
    spin = _spin(true_sonar)
    # The ROV floats at the surface meanwhile; this boot's depth reads 35 mm too deep.
    _record(recording, spin, _floating(spin[0].frame.stamp_ns, seconds=24, reading_bias_m=0.035))
    locator = tmp_path / "locator.yaml"
    locator.write_text(
        "site: tank\ntank: {length_m: 20.0, width_m: 12.0, depth_m: 6.0}\n"
        "sonar: {position_m: [0.3, 0.0, -0.2], pitch_deg: 30.0}\n"
    )
    # The detector's gate was told another pitch by hand: the copy sees the calibrated sonar.
    detector = tmp_path / "sonar_detect.yaml"
    detector.write_text(
        "site: tank\nmin_confidence: 0.6\n"
        "depth_gate: {tolerance_m: 0.25, sonar: {position_m: [0.3, 0.0, -0.2], pitch_deg: 28.0}}\n"
    )
    out, detector_out = tmp_path / "calibrated.yaml", tmp_path / "detect_calibrated.yaml"
    proc = subprocess.run(
        [sys.executable, "-m", "capsd", "calibrate", str(recording), "--locator-config",
         str(locator), "-o", str(out), "--detector-config", str(detector),
         "--detector-out", str(detector_out)],
        capture_output=True, text=True, timeout=120, cwd=REPO,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "sonar yaw correction" in proc.stdout
    assert "NOT determined" in proc.stdout  # pitch, at least, is said to be unknown
    written = yaml.safe_load(out.read_text())
    assert written["site"] == "tank"
    calibrated = msgspec.convert(written["sonar"], SonarMountConfig).transform()
    # The written mount is the true one (the angle between the two rotations), in the
    # config's own terms (yaw, pitch, roll of the ASV frame, not of the sonar's).
    between = calibrated.rotation.T @ true_sonar.rotation
    angle_deg = math.degrees(math.acos(min(1.0, (np.trace(between) - 1.0) / 2.0)))
    assert angle_deg < 0.1
    assert written["rov"]["depth_offset_m"] == pytest.approx(-0.035, abs=0.005)
    # What may still be wrong, for the locator's covariances: the fits' 1-sigma where they
    # determined a term (heading, depth offset), the config's prior (none here) elsewhere.
    left = written["installation"]
    assert 0.0 < left["sonar_angles_deg"][0] < 0.1
    assert left["sonar_angles_deg"][1] == 0.0
    assert 0.01 <= left["depth_offset_m"] < 0.015
    assert "depth offset" in proc.stdout
    assert "still allowed for in every fix's covariance" in proc.stdout
    assert out.read_text().startswith("# locator.yaml calibrated by `capsd calibrate spin.mcap`")
    gated = yaml.safe_load(detector_out.read_text())
    assert gated["depth_gate"]["sonar"] == written["sonar"]
    assert gated["depth_gate"]["tolerance_m"] == 0.25  # the rest of the file as it was
    assert gated["min_confidence"] == 0.6
    assert "it differed from" in proc.stdout


def test_capsd_calibrate_depth_alone_needs_no_frames(tmp_path: Path) -> None:
    recording = tmp_path / "float.mcap"
    _record(recording, [], _floating(1_800_000_000_000_000_000, seconds=30, reading_bias_m=-0.02))
    locator = tmp_path / "locator.yaml"
    locator.write_text("site: tank\nrov: {pressure_sensor_m: [-0.2, 0.0, 0.0]}\n")
    out = tmp_path / "calibrated.yaml"
    args = [sys.executable, "-m", "capsd", "calibrate", str(recording), "--what", "depth",
            "--locator-config", str(locator), "-o", str(out)]  # fmt: skip
    proc = subprocess.run(args, capture_output=True, text=True, timeout=60, cwd=REPO)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    written = yaml.safe_load(out.read_text())
    assert written["rov"]["depth_offset_m"] == pytest.approx(0.02, abs=0.005)
    assert written["rov"]["pressure_sensor_m"] == [-0.2, 0.0, 0.0]
    assert "sonar" not in written  # not asked for: left as it was
    # A float too short to trust: said, and no config written.
    short = tmp_path / "short.mcap"
    _record(short, [], _floating(1_800_000_000_000_000_000, seconds=4, reading_bias_m=0.0))
    args[4], out2 = str(short), tmp_path / "not_written.yaml"
    args[-1] = str(out2)
    proc = subprocess.run(args, capture_output=True, text=True, timeout=60, cwd=REPO)
    assert proc.returncode == 1
    assert "depth offset           NOT determined: the ROV floated" in proc.stdout
    assert not out2.exists()


def test_capsd_calibrate_names_what_is_missing(tmp_path: Path) -> None:
    recording = tmp_path / "frames_only.mcap"
    recorder = McapRecorder(recording)
    recorder.close()
    proc = subprocess.run(
        [sys.executable, "-m", "capsd", "calibrate", str(recording), "-o", str(tmp_path / "o")],
        capture_output=True, text=True, timeout=60, cwd=REPO,
    )  # fmt: skip
    assert proc.returncode == 2
    assert "no sonar frames" in proc.stderr
