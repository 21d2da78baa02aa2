from __future__ import annotations

import itertools
import math

import msgspec
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capsd.geometry import Transform
from capsd.payloads import AsvPose, Detection, RovDepth, SonarFrame, SonarTilt
from capsd.services.sonar_detect.depth_gate import DepthGate
from capsd.services.sonar_detect.service import DepthGateConfig, GateInputs, detect_gated
from capsd.sonar_geometry import BeamModel, beam_direction, to_polar
from tests.capsd.samples import SAMPLES

HALF_APERTURE = math.radians(10.0)
SAMPLES_FRAME = next(p for p in SAMPLES if isinstance(p, SonarFrame))


def _sonar(pitch_deg: float, yaw_deg: float, roll_deg: float) -> Transform:
    # A sonar 0.2 m under the surface, pitched down (positive pitch about y tips x down in
    # Z-Y-X with z up: the mount's pitch_deg convention of capsd.mounts).
    return Transform.from_euler_zyx(
        (3.0, 2.0, -0.2),
        yaw_rad=math.radians(yaw_deg),
        pitch_rad=math.radians(pitch_deg),
        roll_rad=math.radians(roll_deg),
    )


@settings(max_examples=200, deadline=None)
@given(
    pitch=st.floats(10.0, 50.0),
    yaw=st.floats(-180.0, 180.0),
    roll=st.floats(-5.0, 5.0),
    range_m=st.floats(1.5, 20.0),
    azimuth_deg=st.floats(-60.0, 60.0),
    elevation_deg=st.floats(-9.5, 9.5),
    model=st.sampled_from(["planar", "conical"]),
)
def test_the_rov_where_it_is_passes_off_its_plane_does_not_and_its_elevation_is_found(
    pitch: float,
    yaw: float,
    roll: float,
    range_m: float,
    azimuth_deg: float,
    elevation_deg: float,
    model: BeamModel,
) -> None:
    sonar = _sonar(pitch, yaw, roll)
    azimuth = math.radians(azimuth_deg)
    p_s = range_m * beam_direction(model, azimuth, math.radians(elevation_deg))
    rov = sonar.apply(p_s)
    gate = DepthGate(sonar, float(rov[2]), 0.3, HALF_APERTURE, model)
    r, theta, elevation = to_polar(model, p_s)
    assert gate.plausible(r, theta)
    # The gate puts the point on the ROV's plane at its own elevation.
    found = gate.elevation_at(r, theta)
    assert found is not None
    assert math.degrees(found) == pytest.approx(math.degrees(elevation), abs=1e-6)
    window = gate.range_window(math.radians(65.0))
    assert window is not None
    assert window[0] - 1e-6 <= r <= window[1] + 1e-6
    # The same echo with the ROV's plane far above or below: not the ROV.
    for shift in (-1.0, 1.0):
        vertical_reach = range_m * 2 * math.sin(HALF_APERTURE) + 0.3
        other = DepthGate(
            sonar, float(rov[2]) + shift * (vertical_reach + 0.1), 0.3, HALF_APERTURE, model
        )
        assert not other.plausible(r, theta)
    # A plane deeper than the range reaches: at no elevation.
    assert (
        DepthGate(sonar, -0.2 - 2.0 * range_m, 0.3, HALF_APERTURE, model).elevation_at(r, theta)
        is None
    )


def test_a_plane_the_fan_never_reaches_has_no_window() -> None:
    # Sonar looking up 30 deg (pitch -30): rays go up, the ROV is 5 m below.
    sonar = _sonar(-30.0, 0.0, 0.0)
    gate = DepthGate(sonar, -5.2, 0.3, HALF_APERTURE, "conical")
    assert gate.range_window(math.radians(65.0)) is None
    assert not gate.plausible(8.0, 0.0)


def test_window_spans_near_and_far_edges_of_the_aperture() -> None:
    sonar = _sonar(30.0, 0.0, 0.0)
    depth_below = 3.0
    gate = DepthGate(sonar, -0.2 - depth_below, 0.0, HALF_APERTURE, "planar")
    window = gate.range_window(0.0 + 1e-9)
    assert window is not None
    # On the boresight: the steepest ray (40 deg down) is nearest, the shallowest (20) furthest.
    near = depth_below / math.sin(math.radians(40.0))
    far = depth_below / math.sin(math.radians(20.0))
    assert np.isclose(window[0], near, rtol=1e-3)
    assert np.isclose(window[1], far, rtol=1e-3)


class _Fixed:
    """A detector that finds the same candidates in every frame and notes the window asked."""

    def __init__(self, found: list[Detection]):
        self.found = found
        self.windows: list[tuple[float, float] | None] = []

    def detect(
        self, frame: SonarFrame, *, range_window: tuple[float, float] | None = None
    ) -> list[Detection]:
        self.windows.append(range_window)
        return list(self.found)


def _candidate(range_m: float, confidence: float = 0.9) -> Detection:
    return Detection(
        range_m=range_m,
        azimuth_rad=0.0,
        range_sigma_m=0.02,
        azimuth_sigma_rad=0.003,
        confidence=confidence,
    )


def _gate_30_deg_down() -> DepthGate:
    """Sonar 0.2 m under the surface, 30 deg down; ROV 4.5 m deep."""
    return DepthGate(
        sonar_in_world=_sonar(30.0, 0.0, 0.0),
        rov_z_m=-4.5,
        tolerance_m=0.6,
        half_aperture_rad=math.radians(15.0),
        beam_model="conical",
    )


def test_detect_gated_searches_the_window_and_rejects_what_is_off_the_rov_plane() -> None:
    # Sonar 0.2 m under the surface, 30 deg down; ROV 4.5 m deep: on the boresight at about
    # 8.6 m; at 3 m the aperture (+-15 deg with the skirts) reaches 1.5-2.4 m deep only.
    gate = _gate_30_deg_down()
    frame = SAMPLES_FRAME
    on_plane, near, faint = _candidate(8.6), _candidate(3.0), _candidate(8.6, confidence=0.3)
    detector = _Fixed([on_plane, near, faint])
    kept, rejected, _ = detect_gated(
        detector, frame, gate, min_confidence=0.5, confidence="independent"
    )
    assert kept == [on_plane]
    assert rejected == 1  # the faint one is below the confidence, not rejected by depth
    window = detector.windows[-1]
    assert window is not None
    assert 3.0 < window[0] < 8.6 < window[1]
    kept, rejected, _ = detect_gated(
        detector, frame, None, min_confidence=0.5, confidence="independent"
    )
    assert kept == [on_plane, near]
    assert rejected == 0
    assert detector.windows[-1] is None


def test_a_sonar_on_a_servo_is_gated_through_its_reported_angle_or_not_at_all() -> None:
    """The gate's sonar pose has the servo's angle; no fresh angle, no gate (nothing refused)."""
    servo = msgspec.convert({"sonar": {"pitch_deg": 30.0, "tilt": {}}}, DepthGateConfig)
    inputs = GateInputs(servo)
    stamp = 10_000_000_000
    cov = tuple(float(i == j) * 1e-4 for i in range(6) for j in range(6))
    inputs.pose = AsvPose(stamp_ns=stamp, seq=0, position_m=(0.0, 0.0, 0.0),
                          orientation_xyzw=(0.0, 0.0, 0.0, 1.0), covariance=cov)  # fmt: skip
    inputs.depth = RovDepth(stamp_ns=stamp, seq=0, depth_m=3.0, sigma_m=0.01)
    assert inputs.gate(stamp) is None  # no angle yet
    inputs.tilt = SonarTilt(stamp_ns=stamp - 2_000_000_000, seq=0, tilt_rad=0.3)
    assert inputs.gate(stamp) is None  # 2 s old
    inputs.tilt = SonarTilt(stamp_ns=stamp, seq=1, tilt_rad=0.3)
    gate = inputs.gate(stamp)
    assert gate is not None
    tilted = servo.sonar.transform(tilt_rad=0.3)
    assert np.allclose(gate.sonar_in_world.rotation, tilted.rotation)
    # A pan in the report: taken where the mount has the pan servo, not elsewhere.
    inputs.tilt = SonarTilt(stamp_ns=stamp, seq=2, tilt_rad=0.3, pan_rad=0.8)
    gate = inputs.gate(stamp)
    assert gate is not None
    assert np.allclose(gate.sonar_in_world.rotation, tilted.rotation)
    panning = msgspec.convert({"sonar": {"tilt": {}, "pan": {}}}, DepthGateConfig)
    inputs = GateInputs(panning)
    inputs.pose = AsvPose(stamp_ns=stamp, seq=0, position_m=(0.0, 0.0, 0.0),
                          orientation_xyzw=(0.0, 0.0, 0.0, 1.0), covariance=cov)  # fmt: skip
    inputs.depth = RovDepth(stamp_ns=stamp, seq=0, depth_m=3.0, sigma_m=0.01)
    inputs.tilt = SonarTilt(stamp_ns=stamp, seq=0, tilt_rad=0.3, pan_rad=0.8)
    gate = inputs.gate(stamp)
    assert gate is not None
    panned = panning.sonar.transform(tilt_rad=0.3, pan_rad=0.8)
    assert np.allclose(gate.sonar_in_world.rotation, panned.rotation)
    assert np.allclose(gate.sonar_in_world.translation, panned.translation)


def test_what_the_gate_rules_out_takes_nothing_from_the_one_rov() -> None:
    # The same gate: a ROV at 0.95 and clutter at 0.6 on its plane, a 0.9 echo off it at 3 m.
    gate = _gate_30_deg_down()
    rov, clutter, off_plane = _candidate(8.6, 0.95), _candidate(8.9, 0.6), _candidate(3.0)
    detector = _Fixed([rov, clutter, off_plane])
    kept, rejected, ambiguous = detect_gated(
        detector, SAMPLES_FRAME, gate, min_confidence=0.5, confidence="exclusive"
    )
    # The ROV as the one among the two on the plane: 0.95 x 0.4 / (0.05 x 0.4 + 0.38 + 0.03).
    assert [d.range_m for d in kept] == [8.6]
    assert kept[0].confidence == pytest.approx(0.38 / 0.43)
    assert (rejected, ambiguous) == (1, 1)
    # Without the gate the 0.9 echo off the plane shares the frame too: the ROV less sure,
    # 19 x 0.002 against 0.002 (none) + 0.038 + 0.003 (the clutter) + 0.018 (the 0.9 echo).
    kept, rejected, ambiguous = detect_gated(
        detector, SAMPLES_FRAME, None, min_confidence=0.5, confidence="exclusive"
    )
    assert [d.range_m for d in kept] == [8.6]
    assert kept[0].confidence == pytest.approx(0.038 / 0.061)
    assert (rejected, ambiguous) == (0, 2)


@settings(max_examples=100, deadline=None)
@given(
    pitch=st.floats(15.0, 45.0),
    range_m=st.floats(0.5, 20.0),
    azimuth_deg=st.floats(-60.0, 60.0),
)
def test_the_default_gate_keeps_a_rov_within_its_error_budget(
    pitch: float, range_m: float, azimuth_deg: float
) -> None:
    # The worst corners of the budget: the sonar truly pitched and rolled 2 deg off what the
    # gate is told, the ROV's echo at the nominal aperture's edge and 0.3 m off the plane the
    # depth reading gives, each either way.
    told = DepthGateConfig()
    for pitch_error, roll_error, elevation_deg, off_plane_m in itertools.product(
        (-2.0, 2.0), (-2.0, 2.0), (-10.0, 10.0), (-0.3, 0.3)
    ):
        true_sonar = _sonar(pitch + pitch_error, 0.0, roll_error)
        p_s = range_m * beam_direction(
            "conical", math.radians(azimuth_deg), math.radians(elevation_deg)
        )
        rov_z = float(true_sonar.apply(p_s)[2]) + off_plane_m
        r, theta, _ = to_polar("conical", p_s)
        gate = told.gate_at(_sonar(pitch, 0.0, 0.0), rov_z)
        assert gate.plausible(r, theta), (pitch_error, roll_error, elevation_deg, off_plane_m)


def test_the_default_gate_rejects_clutter_over_a_near_rov() -> None:
    # Session 66's run 121 (mockup, the ASV still): the sonar 0.19 m deep, 31 deg down, the
    # ROV's centre 1.14 m deep 1.42 m off; a box 0.83 m off on the boresight reaches 0.81 m
    # deep at most within the aperture and its margin (48 deg down): 0.33 m above the ROV's
    # plane. The 0.6 m tolerance before session 66 let it through.
    sonar = Transform.from_euler_zyx(
        (0.0, 0.0, -0.19), yaw_rad=0.0, pitch_rad=math.radians(31.0), roll_rad=0.0
    )
    gate = DepthGateConfig().gate_at(sonar, -1.14)
    assert not gate.plausible(0.83, 0.0)
    assert DepthGateConfig(tolerance_m=0.6).gate_at(sonar, -1.14).plausible(0.83, 0.0)
    # The ROV itself, 1.42 m off and 11 deg under the boresight, passes.
    assert gate.plausible(1.42, 0.0)
