"""`capsd train range-bias`: the table from runs drawn as training runs are."""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from pathlib import Path

import pytest

from capsd.cli import main
from capsd.services.sonar_detect.range_bias import RangeBias, load, save
from capsd.train.range_bias import DEPRESSION_EDGES_DEG, SHARE_EDGES, WITHIN_M, Sample, filled


def test_the_command_writes_a_table_that_says_how_it_was_measured(tmp_path: Path) -> None:
    out = tmp_path / "range_bias.json"
    argv = ["train", "range-bias", "--runs", "2", "--steep-runs", "2", "--duration", "3"]
    assert main([*argv, "--out", str(out)]) == 0
    table = load(out)
    assert table.share_edges == SHARE_EDGES
    assert table.depression_edges_deg == DEPRESSION_EDGES_DEG
    assert table.within_m == WITHIN_M
    assert table.half_aperture_deg == 10.0
    # The shipped weights' near refiner: its detections counted in a grid of their own.
    assert table.near_within_m == 1.5
    assert len(table.near_bias_m) == len(table.near_samples) == len(table.bias_m)
    assert sum(table.samples) + sum(table.near_samples) > 0  # near ROVs matched
    # Too few in any cell for a median: every bias stays 0 rather than a guess.
    assert all(n < 30 for n in table.samples + table.near_samples)
    assert table.bias_m + table.near_bias_m == (0.0,) * 2 * len(table.bias_m)
    assert table.provenance["command"] == (
        "capsd train range-bias --runs 2 --steep-runs 2 --duration 3 --pitch-deg 40 85"
    )


def test_a_cell_without_a_median_takes_its_bands_nearest() -> None:
    """Gaps filled within their band; a band with none takes the nearest band's; ties: centre."""
    medians: list[float | None] = [None, 0.02, None, 0.06, None, None, None, None]
    assert filled(medians, 4) == [0.02, 0.02, 0.02, 0.06] * 2
    three: list[float | None] = [0.01, None, None, None, None, None, None, None, 0.05]
    assert filled(three, 3) == [0.01] * 3 + [0.01] * 3 + [0.05] * 3  # a tie: the shallower
    # Bin 1 is as near bin 0 as bin 2; bin 2 is nearer the centre (1.5).
    assert filled([0.01, None, 0.03, None], 4) == [0.01, 0.03, 0.03, 0.03]
    assert filled([None] * 4, 2) == [0.0] * 4


def test_the_command_refuses_a_pitch_range_out_of_order(tmp_path: Path) -> None:
    out = tmp_path / "range_bias.json"
    assert main(["train", "range-bias", "--runs", "1", "--duration", "1",
                 "--pitch-deg", "60", "20", "--out", str(out)]) != 0  # fmt: skip
    assert not out.exists()


def test_evaluate_scores_tables_on_the_same_detections(tmp_path: Path) -> None:
    """A table of 1 cm everywhere moves every near ROV's error by 1 cm, and finds the same."""
    constant = tmp_path / "one_cm.json"
    bins = len(SHARE_EDGES) - 1
    cells = bins * (len(DEPRESSION_EDGES_DEG) - 1)
    save(
        RangeBias(share_edges=SHARE_EDGES, depression_edges_deg=DEPRESSION_EDGES_DEG,
                  bias_m=(0.01,) * cells, samples=(30,) * cells, within_m=WITHIN_M,
                  half_aperture_deg=10.0),
        constant,
    )  # fmt: skip
    out = tmp_path / "evaluate.json"
    argv = ["train", "range-bias", "--evaluate", "none", str(constant), "--runs", "2",
            "--duration", "3", "--pitch-deg", "30", "40", "--json", str(out)]  # fmt: skip
    assert main(argv) == 0
    figures = json.loads(out.read_text())["tables"]
    plain, moved = figures["none"]["all"], figures[str(constant)]["all"]
    assert plain["detections"] == moved["detections"] > 0
    assert plain["in_view"] >= plain["detections"]
    assert plain["found_pct"] == round(100.0 * plain["detections"] / plain["in_view"], 1)
    assert moved["signed_median_cm"] == pytest.approx(plain["signed_median_cm"] - 1.0, abs=0.011)
    assert not (tmp_path / "range_bias.json").exists()  # evaluating writes no table


def test_under_the_trained_depression_only_training_runs_count(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Training-like runs make the shallow band, steep runs the steep ones; never the other way."""
    from capsd.train import range_bias

    def fake(plans: list[object], *, duration_s: float, label: str) -> Iterator[Sample]:
        # Training runs: 2 cm long wherever; steep runs: 7 cm long wherever.
        error = 0.02 if "training" in label else 0.07
        for depression in (20.0, 55.0):
            for _ in range(40):
                yield Sample(elevation_rad=0.01, depression_rad=math.radians(depression),
                             range_m=1.5, error_m=error)  # fmt: skip
                # A ROV in view not detected: no error to take a median of.
                yield Sample(elevation_rad=0.01, depression_rad=math.radians(depression),
                             range_m=1.5, error_m=None)  # fmt: skip

    monkeypatch.setattr(range_bias, "samples", fake)
    table = range_bias.measure(runs=1, steep_runs=1, duration_s=1.0)
    assert table.at(0.01, 1.5, math.radians(20.0)) == 0.02
    assert table.at(0.01, 1.5, math.radians(55.0)) == 0.07
    assert table.at(0.01, 1.5, math.radians(45.0)) == 0.02  # empty, between two: the shallower
