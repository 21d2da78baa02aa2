"""The sonar's pitch from a ROV going down and up through the vertical aperture (synthetic)."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from capsd import topics
from capsd.calibrate import applied
from capsd.codec import Codec
from capsd.errors import CapsdError
from capsd.geometry import Transform, matrix_to_quat
from capsd.mount_calibration import Observation
from capsd.mounts import RovConfig, SonarMountConfig
from capsd.payloads import AsvPose, RovDepth, RovFix, SonarFrame
from capsd.pitch_calibration import EchoSamples, echo_samples, fit_pitch, rov_places
from capsd.recording import McapRecorder, Sample
from capsd.services.locator.service import InstallationConfig
from capsd.sonar_geometry import to_polar
from tests.conftest import REPO

START_NS = 1_800_000_000_000_000_000
NOMINAL = SonarMountConfig()  # pitched 30 deg down
N_BEAMS, N_RANGES, RESOLUTION_M = 64, 240, 0.025
AZIMUTHS = tuple(float(a) for a in np.linspace(-0.5, 0.5, N_BEAMS))
ASV = Transform(np.eye(3), np.zeros(3))  # level at the tank's origin, facing +x


def _frame(
    k: int, echo: tuple[float, float] | None, level: float, rng: np.random.Generator
) -> SonarFrame:
    """A speckled frame with the ROV's echo (range, azimuth) `level` bright, if any."""
    image = rng.normal(40.0, 8.0, (N_RANGES, N_BEAMS))
    if echo is not None:
        # A ROV 0.5 m across and 0.1 m deep in range: as many beams as it spans there.
        i = int(echo[0] / RESOLUTION_M)
        spacing = AZIMUTHS[1] - AZIMUTHS[0]
        half = max(round(0.25 / (echo[0] * spacing)), 1)
        j = int(np.argmin(np.abs(np.array(AZIMUTHS) - echo[1])))
        image[max(i - 3, 0) : i + 1, max(j - half, 0) : j + half + 1] += level * rng.uniform(
            0.8, 1.2
        )
    return SonarFrame(
        stamp_ns=START_NS + k * 200_000_000,
        seq=k,
        ping_id=k,
        n_ranges=N_RANGES,
        n_beams=N_BEAMS,
        sample_bits=8,
        image=memoryview(np.clip(image, 0, 255).astype(np.uint8).tobytes()),
        azimuths_rad=AZIMUTHS,
        range_start_m=0.0,
        range_resolution_m=RESOLUTION_M,
        sound_speed_m_s=1480.0,
        gain_percent=50.0,
        frequency_hz=1.2e6,
        vertical_aperture_rad=math.radians(20.0),
    )


def _profile(
    *, pitch_error_deg: float, bottom_z: float = -3.4, frames: int = 600, seed: int = 0
) -> tuple[list[SonarFrame], list[RovFix], list[RovDepth]]:
    """The ROV 3 m ahead going from 0.4 m deep to `bottom_z` and back.

    Seen by a sonar pitched `pitch_error_deg` further down than configured: its echo fades 10
    deg either side of the true boresight.
    """
    rng = np.random.default_rng(seed)
    true = SonarMountConfig(pitch_deg=NOMINAL.pitch_deg + pitch_error_deg).transform()
    out_frames, fixes, depths = [], [], []
    for k in range(frames):
        t = k / 5.0
        z = 0.5 * (-0.4 + bottom_z) + 0.5 * (-0.4 - bottom_z) * math.cos(2 * math.pi * t / 120.0)
        rov = np.array([3.0, 0.05, z])
        range_m, azimuth, elevation = to_polar("conical", ASV.compose(true).inverse().apply(rov))
        weight = 1.0 / (1.0 + math.exp((abs(math.degrees(elevation)) - 10.0) / 0.7))
        frame = _frame(k, (range_m, azimuth) if weight > 0.01 else None, 150.0 * weight, rng)
        out_frames.append(frame)
        stamp = frame.stamp_ns
        depths.append(RovDepth(stamp_ns=stamp, seq=k, depth_m=float(-z)))
        if weight > 0.5:  # the locator fixes a ROV it sees
            seen = rov + rng.normal(0.0, 0.01, 3)
            fixes.append(
                RovFix(stamp_ns=stamp, seq=k, method="capsd", quality="good",
                       position_m=(float(seen[0]), float(seen[1]), float(z)))
            )  # fmt: skip
    return out_frames, fixes, depths


def _samples(frames: list[SonarFrame], fixes: list[RovFix], depths: list[RovDepth],
             mount: SonarMountConfig) -> EchoSamples:  # fmt: skip
    places = rov_places(fixes, depths, [f.stamp_ns for f in frames])
    observations = [Observation(f, ASV) for f in frames]
    return echo_samples(observations, places, mount=mount.transform(), beam_model="conical")


def test_the_pitch_is_found_and_applied_as_a_pitch_correction() -> None:
    frames, fixes, depths = _profile(pitch_error_deg=1.0)
    fit = fit_pitch(_samples(frames, fixes, depths, NOMINAL))
    # Configured 1 deg too high, the boresight puts the ROV 1 deg higher in it than it is
    # (elevation is positive up).
    assert fit.offset_deg == pytest.approx(-1.0, abs=0.15)
    assert fit.determined
    assert fit.above >= 10
    assert fit.below >= 10
    assert fit.half_width_deg == pytest.approx(10.0, abs=1.0)
    cal = applied(NOMINAL, RovConfig(), InstallationConfig(), None, None, None, fit)
    assert cal.mount.pitch_deg == pytest.approx(30.0 - fit.offset_deg, abs=1e-3)
    assert cal.installation.sonar_angles_deg[1] == pytest.approx(fit.offset_sigma_deg, abs=1e-4)
    # Told the corrected mount, the same frames show no offset left.
    again = fit_pitch(_samples(frames, fixes, depths, cal.mount))
    assert abs(again.offset_deg) < 0.02


def test_a_profile_that_never_leaves_the_bottom_edge_determines_nothing() -> None:
    # Only down to 1.6 m: the ROV never goes below the aperture, so one edge is all there is.
    frames, fixes, depths = _profile(pitch_error_deg=0.5, bottom_z=-1.6)
    fit = fit_pitch(_samples(frames, fixes, depths, NOMINAL))
    assert fit.below < 10
    assert not fit.determined
    assert "NOT determined" in fit.lines()[0]
    cal = applied(NOMINAL, RovConfig(), InstallationConfig(), None, None, None, fit)
    assert cal.mount.pitch_deg == NOMINAL.pitch_deg
    assert not cal.determined_anything


def test_no_tracked_rov_is_an_error_that_says_so() -> None:
    frames, fixes, depths = _profile(pitch_error_deg=0.0, frames=300)
    with pytest.raises(CapsdError, match="ROV tracked"):
        rov_places(fixes[:1], depths, [f.stamp_ns for f in frames])
    # Four seconds of it: nowhere near both edges.
    with pytest.raises(CapsdError, match="going down and up"):
        fit_pitch(_samples(frames[200:220], fixes, depths, NOMINAL))


@settings(max_examples=30, deadline=None)
@given(
    centre_deg=st.floats(-3.0, 3.0),
    half_deg=st.floats(9.0, 16.0),
    soft_deg=st.floats(0.3, 1.5),
    noise=st.floats(0.0, 0.04),
    seed=st.integers(0, 1000),
)
def test_the_plateau_centre_is_recovered_within_its_sigma(
    centre_deg: float, half_deg: float, soft_deg: float, noise: float, seed: int
) -> None:
    # Any symmetric plateau with soft edges, sampled from well above to well below it.
    rng = np.random.default_rng(seed)
    n = 600
    e = np.radians(rng.uniform(centre_deg - half_deg - 10.0, centre_deg + half_deg + 10.0, n))
    c, w, k = (math.radians(v) for v in (centre_deg, half_deg, soft_deg))
    inside = 1.0 / (1.0 + np.exp((np.abs(e - c) - w) / k))
    strength = 0.3 + 0.6 * inside + rng.normal(0.0, noise, n)
    stamps = START_NS + np.arange(n, dtype=np.int64) * 200_000_000
    fit = fit_pitch(EchoSamples(stamps, e, np.full(n, 3.0), strength))
    assert fit.offset_deg == pytest.approx(centre_deg, abs=0.2)
    assert fit.determined


def test_capsd_calibrate_pitch_writes_the_pitch(tmp_path: Path) -> None:
    frames, fixes, depths = _profile(pitch_error_deg=-0.8)
    recording = tmp_path / "profile.mcap"
    recorder = McapRecorder(recording)
    frame_codec, pose_codec = Codec(SonarFrame), Codec(AsvPose)
    fix_codec, depth_codec = Codec(RovFix), Codec(RovDepth)
    frame_key = topics.SONAR_FRAME.key("tank", "asv")
    pose_key = topics.ASV_POSE.key("tank", "asv")
    fix_key = topics.ROV_FIX.key("tank", "topside")
    depth_key = topics.ROV_DEPTH.key("tank", "rov")
    qx, qy, qz, qw = (float(v) for v in matrix_to_quat(ASV.rotation))
    fixes_at = {f.stamp_ns: f for f in fixes}
    for k, (frame, depth) in enumerate(zip(frames, depths, strict=True)):
        for dt in (-100_000_000, 0):  # poses around each frame's stamp
            pose = AsvPose(stamp_ns=frame.stamp_ns + dt, seq=2 * k, position_m=(0.0, 0.0, 0.0),
                           orientation_xyzw=(qx, qy, qz, qw), covariance=(0.0,) * 36)  # fmt: skip
            recorder.write(
                Sample(pose_key, pose_codec.encoding, pose_codec.encode(pose), pose.stamp_ns)
            )
        recorder.write(
            Sample(frame_key, frame_codec.encoding, frame_codec.encode(frame), frame.stamp_ns)
        )
        recorder.write(
            Sample(depth_key, depth_codec.encoding, depth_codec.encode(depth), depth.stamp_ns)
        )
        if (fix := fixes_at.get(frame.stamp_ns)) is not None:
            recorder.write(Sample(fix_key, fix_codec.encoding, fix_codec.encode(fix), fix.stamp_ns))
    recorder.close()
    locator = tmp_path / "locator.yaml"
    locator.write_text(
        "site: tank\nsonar: {position_m: [0.3, 0.0, -0.2], pitch_deg: 30.0}\n"
        "installation: {sonar_angles_deg: [1.0, 1.0, 1.0]}\n"
    )
    out = tmp_path / "calibrated.yaml"
    proc = subprocess.run(
        [sys.executable, "-m", "capsd", "calibrate", str(recording), "--what", "pitch",
         "--locator-config", str(locator), "-o", str(out)],
        capture_output=True, text=True, timeout=60, cwd=REPO,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "determined: the sonar's pitch moves by -0." in proc.stdout
    written = yaml.safe_load(out.read_text())
    assert written["sonar"]["pitch_deg"] == pytest.approx(29.2, abs=0.3)
    assert written["sonar"]["position_m"] == [0.3, 0.0, -0.2]
    yaw, pitch, roll = written["installation"]["sonar_angles_deg"]
    assert (yaw, roll) == (1.0, 1.0)  # not asked for: the tape's
    assert pitch < 0.3  # the fit's 1-sigma in place of the tape's
