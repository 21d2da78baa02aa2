"""Reference-to-tank alignment: Umeyama, its robust refit, the track, the clock offset search."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from capsd.alignment import Similarity, Track, align, robust_fit, spikes, umeyama
from capsd.geometry import euler_zyx_to_matrix

ANGLE = st.floats(-math.pi, math.pi, allow_nan=False)
SHIFT = st.floats(-50.0, 50.0, allow_nan=False)


def _rotation_error_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(max(-1.0, min(1.0, (float(np.trace(a @ b.T)) - 1.0) / 2.0))))


@settings(max_examples=60, deadline=None)
@given(
    yaw=ANGLE,
    pitch=st.floats(-1.5, 1.5),
    roll=ANGLE,
    x=SHIFT,
    y=SHIFT,
    z=SHIFT,
    scale=st.floats(0.5, 2.0),
    seed=st.integers(0, 2**16),
    planar=st.booleans(),
)
def test_umeyama_recovers_any_similarity(
    yaw: float, pitch: float, roll: float, x: float, y: float, z: float, scale: float,
    seed: int, planar: bool,
) -> None:  # fmt: skip
    rng = np.random.default_rng(seed)
    points = rng.uniform(-5.0, 5.0, (40, 3))
    if planar:  # a dive at one depth: still determined (not a line)
        points[:, 2] = -2.0
    truth = Similarity(euler_zyx_to_matrix(yaw, pitch, roll), np.array([x, y, z]), scale)
    got = umeyama(points, truth.apply(points), with_scale=True)
    assert np.allclose(got.rotation, truth.rotation, atol=1e-9)
    assert np.allclose(got.translation_m, truth.translation_m, atol=1e-6)
    assert abs(got.scale - scale) < 1e-9
    assert np.linalg.det(got.rotation) > 0.0  # a rotation, never a reflection
    back = got.inverse().apply(got.apply(points))
    assert np.allclose(back, points, atol=1e-9)


def test_the_robust_fit_ignores_outliers() -> None:
    rng = np.random.default_rng(1)
    points = rng.uniform(-5.0, 5.0, (500, 3))
    truth = Similarity(euler_zyx_to_matrix(0.5, 0.02, -0.01), np.array([2.0, -1.0, 0.3]))
    target = truth.apply(points) + rng.normal(0.0, 0.01, points.shape)
    bad = rng.choice(500, 25, replace=False)
    target[bad] += rng.uniform(0.3, 2.0, (25, 3))
    plain = umeyama(points, target)
    fit = robust_fit(points, target)
    assert _rotation_error_deg(plain.rotation, truth.rotation) > 0.1  # the outliers pull it
    assert _rotation_error_deg(fit.transform.rotation, truth.rotation) < 0.05
    assert set(np.flatnonzero(~fit.inliers)) == set(bad)
    assert 0.008 < fit.sigma_m < 0.012  # the per-axis scatter


def test_the_track_interpolates_but_not_across_gaps_and_drops_spikes() -> None:
    stamps = np.arange(0, 100, dtype=np.int64) * 10_000_000  # 100 Hz
    positions = np.column_stack([stamps / 1e9, np.zeros(100), np.zeros(100)])
    positions[40] += (0.0, 0.3, 0.0)  # a marker swap
    keep = (stamps < 600_000_000) | (stamps > 800_000_000)  # a 0.2 s occlusion
    assert list(np.flatnonzero(spikes(positions[keep]))) == [40]
    track = Track.of(stamps[keep], positions[keep], max_gap_s=0.1)
    assert track.spikes == 1
    got, valid = track.at(np.array([405_000_000, 700_000_000, 990_000_000, 2_000_000_000]))
    assert list(valid) == [True, False, True, False]
    assert np.allclose(got[0], (0.405, 0.0, 0.0))  # across the dropped spike


def _helix(t: np.ndarray) -> np.ndarray:
    return np.column_stack(
        [5 + 4 * np.cos(0.1 * t), 3 + 2 * np.sin(0.13 * t), -2 + 0.5 * np.sin(0.05 * t)]
    )


def test_align_finds_frame_and_clock_offset() -> None:
    rng = np.random.default_rng(2)
    t_fix = np.arange(0.0, 200.0, 0.05)
    fixes = _helix(t_fix) + rng.normal(0.0, 0.01, (len(t_fix), 3))
    t_ref = np.arange(-1.0, 201.0, 0.01)
    to_ref = Similarity(euler_zyx_to_matrix(math.radians(30), 0.0, 0.0), np.array([2.0, 0, 0]))
    late_s = 0.15
    reference = Track.of(
        np.round((t_ref + late_s) * 1e9).astype(np.int64),
        to_ref.apply(_helix(t_ref)),
        max_gap_s=0.1,
    )
    found = align(np.round(t_fix * 1e9).astype(np.int64), fixes, reference)
    assert abs(found.offset_ns / 1e6 - 150.0) < 3 * found.offset_sigma_ms() + 0.5
    assert found.offset_sigma_ms() < 2.0
    wanted = to_ref.inverse()
    assert _rotation_error_deg(found.transform.rotation, wanted.rotation) < 0.02
    assert np.allclose(found.transform.translation_m, wanted.translation_m, atol=0.005)
    assert found.problems() == []


def test_a_dive_along_a_line_is_not_trusted() -> None:
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 60.0, 0.05)
    line = np.column_stack([0.3 * t, np.zeros_like(t), np.full_like(t, -2.0)])
    reference = Track.of(np.round(t * 1e9).astype(np.int64), line, max_gap_s=0.1)
    found = align(
        np.round(t * 1e9).astype(np.int64), line + rng.normal(0.0, 0.01, line.shape), reference
    )
    assert any(p.startswith("rotation not determined") for p in found.problems())
    still = np.tile([[1.0, 2.0, -2.0]], (len(t), 1))
    found = align(
        np.round(t * 1e9).astype(np.int64),
        still + rng.normal(0.0, 0.01, still.shape),
        Track.of(np.round(t * 1e9).astype(np.int64), still, max_gap_s=0.1),
    )
    assert any(p.startswith("clock offset not determined") for p in found.problems())
