"""`capsd train range-bias`: the table from runs drawn as training runs are."""

from __future__ import annotations

from pathlib import Path

from capsd.cli import main
from capsd.services.sonar_detect.range_bias import load
from capsd.train.range_bias import SHARE_EDGES, WITHIN_M


def test_the_command_writes_a_table_that_says_how_it_was_measured(tmp_path: Path) -> None:
    out = tmp_path / "range_bias.json"
    assert main(["train", "range-bias", "--runs", "2", "--duration", "3", "--out", str(out)]) == 0
    table = load(out)
    assert table.share_edges == SHARE_EDGES
    assert table.within_m == WITHIN_M
    assert table.half_aperture_deg == 10.0
    assert sum(table.samples) > 0  # near ROVs matched
    # Too few in any bin for a median: every bias stays 0 rather than a guess.
    assert all(n < 30 for n in table.samples)
    assert table.bias_m == (0.0,) * len(table.bias_m)
    assert table.provenance["command"] == "capsd train range-bias --runs 2 --duration 3"
