"""The polar network's inputs: the coarse grid pools right, crops land where they say."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capsd.payloads import SonarFrame
from capsd.services.sonar_detect.polar_input import (
    CROP_SIZE,
    CROP_STEP_M,
    NORM_HIGH,
    NORM_LOW,
    RANGE_PLANE_M,
    BeamTable,
    Grid,
    coarse_input,
    crop,
    range_value,
    row_medians,
    with_range_plane,
    with_range_rows,
)
from capsd.sonar_image import unit_image


def _frame(image: np.ndarray, *, resolution_m: float, half_fov_deg: float = 65.0) -> SonarFrame:
    n_ranges, n_beams = image.shape
    s = math.sin(math.radians(half_fov_deg))
    azimuths = tuple(float(a) for a in np.arcsin(np.linspace(-s, s, n_beams)))
    return SonarFrame(
        stamp_ns=1,
        seq=0,
        ping_id=0,
        n_ranges=n_ranges,
        n_beams=n_beams,
        sample_bits=8,
        image=memoryview(image.astype(np.uint8).tobytes()),
        azimuths_rad=azimuths,
        range_start_m=0.0,
        range_resolution_m=resolution_m,
        sound_speed_m_s=1480.0,
        gain_percent=50.0,
        frequency_hz=1.2e6,
        vertical_aperture_rad=math.radians(20.0),
    )


@settings(max_examples=200, deadline=None)
@given(
    rows=st.integers(1, 12),
    cols=st.integers(1, 140),
    bits=st.sampled_from([8, 16]),
    seed=st.integers(0, 2**32 - 1),
)
def test_row_medians_are_numpys_medians(rows: int, cols: int, bits: int, seed: int) -> None:
    # Samples as unit_image makes them (ties included), and any float32 besides.
    rng = np.random.default_rng(seed)
    top = 255 if bits == 8 else 65535
    samples = (rng.integers(0, top + 1, size=(rows, cols)) / np.float32(top)).astype(np.float32)
    floats = rng.standard_normal((rows, cols)).astype(np.float32)
    for a in (samples, floats, samples[:, ::3]):
        got = row_medians(a)
        assert got.dtype == np.float32
        assert np.array_equal(got, np.median(a, axis=1).astype(np.float32))


def test_coarse_grid_is_the_mean_and_max_of_each_cell() -> None:
    rng = np.random.default_rng(1)
    raw = rng.integers(0, 256, (1003, 512))
    frame = _frame(raw, resolution_m=0.02)
    grid = Grid.of(frame)
    assert (grid.range_factor, grid.beam_factor, grid.rows, grid.cols) == (4, 4, 250, 128)
    out = coarse_input(unit_image(frame), grid)
    cells = raw[:1000].reshape(250, 4, 128, 4) / 255.0
    np.testing.assert_allclose(out[0], cells.mean(axis=(1, 3)), atol=1e-5)
    np.testing.assert_allclose(out[1], cells.max(axis=(1, 3)), atol=1e-6)


def test_the_range_plane_gives_each_row_its_range() -> None:
    frame = _frame(np.zeros((1000, 512)), resolution_m=0.02)
    grid = Grid.of(frame)
    coarse = coarse_input(unit_image(frame), grid)
    out = with_range_rows(coarse, frame, grid)
    assert out.shape == (3, grid.rows, grid.cols)
    np.testing.assert_array_equal(out[:2], coarse)
    # Row i spans bins 4i .. 4i + 3 of 2 cm: its centre is (i + 0.5) x 8 cm.
    centres = (np.arange(grid.rows) + 0.5) * 0.08
    wanted = np.asarray(range_value(centres), dtype=np.float64)
    np.testing.assert_allclose(np.asarray(out[2, :, 0], dtype=np.float64), wanted, atol=1e-6)
    assert np.all(out[2] == out[2, :, :1])  # the same along a row
    assert np.all(np.diff(out[2, :, 0]) > 0)  # growing with range
    assert range_value(0.0) == NORM_LOW
    assert range_value(RANGE_PLANE_M) == NORM_HIGH
    assert range_value(2 * RANGE_PLANE_M) == NORM_HIGH  # beyond: the top, never outside
    crops = np.zeros((2, 96, 96), dtype=np.float32)
    ranged = with_range_plane(crops, 15.0)
    assert ranged.shape == (3, 96, 96)
    assert np.all(ranged[2] == range_value(15.0))
    assert float(range_value(15.0)) == pytest.approx((NORM_LOW + NORM_HIGH) / 2)


def test_grid_follows_the_sonar_settings() -> None:
    fine = _frame(np.zeros((800, 256)), resolution_m=0.01)
    grid = Grid.of(fine)
    assert (grid.range_factor, grid.beam_factor) == (8, 2)  # ~8 cm cells, 128 columns


def test_crop_centres_a_bright_spot_and_scales_metric() -> None:
    raw = np.zeros((1000, 512))
    frame = _frame(raw, resolution_m=0.02)
    table = BeamTable(frame.azimuths_rad)
    range_m, azimuth = 6.0, math.radians(12.0)
    row = int(range_m / 0.02)
    beam = round(float(table.index(azimuth)))
    raw[row - 1 : row + 2, beam - 1 : beam + 2] = 255
    frame = _frame(raw, resolution_m=0.02)
    image = unit_image(frame)
    centre = (CROP_SIZE - 1) / 2.0
    patch = crop(
        image, frame, table, range_m=row * 0.02 + 0.01, azimuth_rad=float(table.azimuths[beam])
    )
    i, j = np.unravel_index(int(np.argmax(patch)), patch.shape)
    assert abs(i - centre) <= 1.0
    assert abs(j - centre) <= 1.0
    # The same spot seen from a crop 0.2 m nearer and 0.1 m to port of it: 10 rows later,
    # 5 columns earlier (rows are range, columns cross-range, CROP_STEP_M apart).
    shifted = crop(
        image,
        frame,
        table,
        range_m=row * 0.02 + 0.01 - 0.2,
        azimuth_rad=float(table.azimuths[beam]) + 0.1 / (row * 0.02 - 0.19),
    )
    i2, j2 = np.unravel_index(int(np.argmax(shifted)), shifted.shape)
    assert abs((i2 - i) - 0.2 / CROP_STEP_M) <= 1.0
    assert abs((j2 - j) + 0.1 / CROP_STEP_M) <= 1.0


def test_crop_outside_the_fan_is_zero() -> None:
    frame = _frame(np.full((400, 128), 200), resolution_m=0.02)
    table = BeamTable(frame.azimuths_rad)
    patch = crop(unit_image(frame), frame, table, range_m=1.0, azimuth_rad=math.radians(64.0))
    assert patch[:, -1].max() == 0.0  # beyond +65 deg
    assert patch[:, 0].min() > 0.7  # inside the fan


@settings(max_examples=200, deadline=None)
@given(
    n_beams=st.integers(8, 1024),
    half_fov_deg=st.floats(5.0, 89.0),
    fraction=st.floats(0.0, 1.0),
    descending=st.booleans(),
)
def test_beam_table_index_and_azimuth_are_inverse(
    n_beams: int, half_fov_deg: float, fraction: float, descending: bool
) -> None:
    s = math.sin(math.radians(half_fov_deg))
    table_values = np.arcsin(np.linspace(-s, s, n_beams))
    if descending:  # some sonars list bearings starboard first
        table_values = table_values[::-1]
    table = BeamTable(table_values)
    index = fraction * (n_beams - 1)
    azimuth = float(table.azimuth(index))
    assert abs(float(table.index(azimuth)) - index) < 1e-6 * n_beams
