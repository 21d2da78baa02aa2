"""The near ROV's range corrected for where it lies in the vertical aperture."""

from __future__ import annotations

import math
from pathlib import Path

import msgspec
import pytest

from capsd.errors import CapsdError, ConfigError
from capsd.geometry import Transform
from capsd.payloads import Detection
from capsd.services.sonar_detect.depth_gate import DepthGate
from capsd.services.sonar_detect.range_bias import (
    DEFAULT_TABLE,
    RangeBias,
    depression_rad,
    load,
    save,
)
from capsd.services.sonar_detect.service import CnnConfig, detect_gated
from capsd.sonar_geometry import beam_direction, to_polar
from tests.services.sonar_detect.test_depth_gate import SAMPLES_FRAME

SONAR = Transform.from_euler_zyx((0.0, 0.0, -0.2), yaw_rad=0.0, pitch_rad=math.radians(30.0),
                                 roll_rad=0.0)  # fmt: skip
TABLE = RangeBias(
    share_edges=(-1.0, -0.5, 0.0, 0.5, 1.0),
    bias_m=(0.04, 0.02, 0.0, -0.01),
    samples=(50, 60, 70, 10),
    within_m=4.0,
    half_aperture_deg=10.0,
)


def _at(elevation_deg: float, range_m: float) -> tuple[Detection, DepthGate]:
    """A detection of a ROV at this elevation and range, and the gate of its depth plane."""
    p_s = range_m * beam_direction("conical", 0.1, math.radians(elevation_deg))
    r, azimuth, _ = to_polar("conical", p_s)
    gate = DepthGate(SONAR, float(SONAR.apply(p_s)[2]), 0.6, math.radians(15.0), "conical")
    detection = Detection(range_m=r, azimuth_rad=azimuth, range_sigma_m=0.02,
                          azimuth_sigma_rad=0.005, confidence=0.9)  # fmt: skip
    return detection, gate


def test_a_near_rov_low_in_the_aperture_has_its_range_shortened_by_its_bin() -> None:
    for elevation, bias in ((-8.0, 0.04), (-3.0, 0.02), (2.0, 0.0), (7.0, -0.01)):
        detection, gate = _at(elevation, 2.5)
        assert TABLE.corrected(detection, gate).range_m == pytest.approx(detection.range_m - bias)
    # Beyond the table's elevations, or further than within_m: as detected.
    for elevation, range_m in ((-12.0, 2.5), (-8.0, 5.0)):
        detection, gate = _at(elevation, range_m)
        assert TABLE.corrected(detection, gate) == detection


def test_the_same_place_in_the_aperture_seen_more_steeply_takes_its_band() -> None:
    """A sonar looking down steeply sees the ROV's top first: the band by depression decides.

    The test's sonar is pitched 30 deg: a ROV 8 deg below the boresight is seen 38 deg down
    (band 30-50), one 8 deg above 22 deg down (band 0-30).
    """
    table = RangeBias(
        share_edges=(-1.0, 0.0, 1.0),
        depression_edges_deg=(-90.0, 30.0, 50.0, 90.0),
        bias_m=(0.01, -0.01, 0.05, 0.03, 0.09, 0.07),
        samples=(40,) * 6,
        within_m=4.0,
        half_aperture_deg=10.0,
    )
    for elevation, bias in ((-8.0, 0.05), (8.0, -0.01)):
        detection, gate = _at(elevation, 2.5)
        assert table.corrected(detection, gate).range_m == pytest.approx(detection.range_m - bias)
    # The depression is the height between the sonar and the ROV's plane over the range.
    detection, gate = _at(-8.0, 2.5)
    assert math.degrees(depression_rad(gate, detection.range_m)) == pytest.approx(38.0, abs=0.3)
    # A table from before the bands (one band for every depression) reads as before.
    old = msgspec.json.decode(
        b'{"share_edges": [-1.0, 0.0, 1.0], "bias_m": [0.04, 0.0], "samples": [50, 50],'
        b' "within_m": 4.0, "half_aperture_deg": 10.0}',
        type=RangeBias,
    )
    assert old.at(math.radians(-5.0), 2.0, math.radians(70.0)) == 0.04
    with pytest.raises(ValueError, match="6 cells"):
        RangeBias(share_edges=(-1.0, 0.0, 1.0), depression_edges_deg=(-90.0, 30.0, 50.0, 90.0),
                  bias_m=(0.0,) * 2, samples=(1,) * 2, within_m=4.0,
                  half_aperture_deg=10.0)  # fmt: skip


def test_detect_gated_corrects_only_with_a_gate_and_a_table() -> None:
    detection, gate = _at(-8.0, 2.5)

    class _One:
        def detect(
            self, frame: object, *, range_window: tuple[float, float] | None = None
        ) -> list[Detection]:
            return [detection]

    kept, rejected, _ = detect_gated(_One(), SAMPLES_FRAME, gate, min_confidence=0.5,
                                     confidence="exclusive", range_bias=TABLE)  # fmt: skip
    assert rejected == 0
    assert kept[0].range_m == pytest.approx(detection.range_m - 0.04)
    assert detect_gated(_One(), SAMPLES_FRAME, gate, min_confidence=0.5,
                        confidence="exclusive").detections == [detection]  # fmt: skip
    ungated = detect_gated(_One(), SAMPLES_FRAME, None, min_confidence=0.5,
                           confidence="exclusive", range_bias=TABLE)  # fmt: skip
    assert ungated.detections == [detection]


def test_a_near_refiner_s_detections_take_the_near_grid() -> None:
    table = msgspec.structs.replace(
        TABLE, near_within_m=1.5, near_bias_m=(-0.03, 0.01, 0.05, 0.02), near_samples=(40,) * 4
    )
    for elevation, near_bias, bias in ((-8.0, -0.03, 0.04), (2.0, 0.05, 0.0)):
        for range_m, wanted in ((1.2, near_bias), (2.5, bias)):
            detection, gate = _at(elevation, range_m)
            corrected = table.corrected(detection, gate).range_m
            assert corrected == pytest.approx(detection.range_m - wanted)
    # Without a near grid the one grid serves every range (tables written before session 55).
    detection, gate = _at(-8.0, 1.2)
    assert TABLE.corrected(detection, gate).range_m == pytest.approx(detection.range_m - 0.04)
    with pytest.raises(ValueError, match="near biases"):
        msgspec.structs.replace(TABLE, near_within_m=1.5)
    with pytest.raises(ValueError, match="near biases"):
        msgspec.structs.replace(TABLE, near_bias_m=(0.0,) * 4, near_samples=(1,) * 4)
    with pytest.raises(ValueError, match="must not exceed"):
        msgspec.structs.replace(table, near_within_m=5.0)


def test_a_table_round_trips_and_a_bad_one_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "bias.json"
    save(TABLE, path)
    assert load(path) == TABLE
    with pytest.raises(ValueError, match="cells"):
        RangeBias(share_edges=(0.0, 1.0), bias_m=(0.0, 0.1), samples=(1,), within_m=4.0,
                  half_aperture_deg=10.0)  # fmt: skip
    (tmp_path / "bad.json").write_text('{"share_edges": [1.0, 0.0], "bias_m": [0.0]}')
    with pytest.raises(CapsdError, match=r"bad\.json: not a range bias table"):
        load(tmp_path / "bad.json")
    with pytest.raises(CapsdError, match="no range bias table"):
        load(tmp_path / "none.json")
    config = msgspec.convert(
        {"range_bias": "by_elevation", "range_bias_table": str(tmp_path / "none.json")}, CnnConfig
    )
    with pytest.raises(ConfigError, match=r"cnn\.range_bias_table"):
        config.range_bias_correction()
    assert CnnConfig(range_bias="off").range_bias_correction() is None
    # The shipped table is for the shipped weights: other weights need their own.
    assert CnnConfig(weights=str(tmp_path / "mine.pt")).range_bias_correction() is None
    save(TABLE, tmp_path / "mine.json")
    assert (
        CnnConfig(
            weights="mine.pt", range_bias_table=str(tmp_path / "mine.json")
        ).range_bias_correction()
        == TABLE
    )
    assert CnnConfig().range_bias_correction() == load(DEFAULT_TABLE)


def test_the_shipped_table_loads_and_says_how_it_was_measured() -> None:
    table = load(DEFAULT_TABLE)
    assert str(table.provenance["command"]).startswith("capsd train range-bias")
    assert table.within_m == 4.0
    assert sum(table.samples) > 0
    assert len(table.depression_edges_deg) > 2  # by depression too (session 43)
    # The shipped weights have a near refiner: its detections have a grid of their own.
    assert table.near_within_m == 1.5
    assert sum(table.near_samples) > 0
