"""README tables come from the benches' JSON: the README is in step, and the generator works."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from capsd.errors import CapsdError
from capsd.readme_figures import RENDERERS, blocks, finetune_table, render
from tests.conftest import REPO


def test_the_readme_is_up_to_date_with_its_figures() -> None:
    text = (REPO / "README.md").read_text()
    found = blocks(text)
    assert found  # the README quotes benches through the generator
    for name, source in found:
        assert name in RENDERERS
        assert (REPO / source).is_file(), source
    assert render(text, root=REPO) == text, "run `capsd docs figures`"


def _capsd(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "capsd", *args], capture_output=True,
                          text=True, timeout=300, cwd=REPO)  # fmt: skip


def test_a_short_bench_through_the_generator(tmp_path: Path) -> None:
    out = tmp_path / "bench"
    # The perfect detector: the generator is under test, not the fixes (a third of the time).
    _capsd("bench", "evaluate", "--duration", "20", "--trajectory", "bouncing",
           "--detector", "truth", "--out", str(out))  # fmt: skip
    figures = json.loads((out / "bench_evaluate.json").read_text())
    doc = tmp_path / "doc.md"
    doc.write_text(
        "# Figures\n\n<!-- figures: evaluate_checks bench/bench_evaluate.json -->\nstale\n"
        "<!-- /figures -->\n"
    )
    assert _capsd("docs", "figures", "--file", str(doc), "--check").returncode == 1
    written = _capsd("docs", "figures", "--file", str(doc))
    assert written.returncode == 0, written.stderr
    text = doc.read_text()
    assert "stale" not in text
    assert f"| rotation | {figures['checks']['rotation_error_deg']} deg |" in text
    assert "(`capsd bench evaluate`)" in text
    assert _capsd("docs", "figures", "--file", str(doc), "--check").returncode == 0
    # A table pointed at another bench's JSON is refused, naming the field it lacks.
    doc.write_text(
        "<!-- figures: accuracy_table bench/bench_evaluate.json -->\n<!-- /figures -->\n"
    )
    with pytest.raises(CapsdError, match="not `capsd bench accuracy`'s output"):
        render(doc.read_text(), root=tmp_path)
    refused = _capsd("docs", "figures", "--file", str(doc))
    assert refused.returncode == 2
    assert "field 'runs'" in refused.stderr


def test_the_detect_table_names_the_benchs_groups() -> None:
    from capsd import readme_figures
    from capsd.bench import detect

    assert readme_figures._BRIGHTEST == detect.BRIGHTEST
    assert tuple(f"{lo:g}-{hi:g} m" for lo, hi in detect.BANDS) == readme_figures._BANDS
    assert readme_figures._PLACES == detect.APERTURE_PLACES
    assert readme_figures._ALARM_KINDS == detect.ALARM_KINDS


def test_the_detector_budget_names_the_accuracy_benchs_variants() -> None:
    from capsd import offline_pipeline, readme_figures

    names = {v.name for v in offline_pipeline.ablations()}
    assert [variant for _, variant in readme_figures._EXACT] == [
        offline_pipeline.DETECTOR_EXACT,
        offline_pipeline.DETECTOR_RANGE_EXACT,
        offline_pipeline.DETECTOR_BEARING_EXACT,
    ]
    assert {readme_figures.OURS, readme_figures.PERFECT_DETECTOR} <= names
    run = {
        readme_figures.OURS: {"med_mm": 25.4, "availability": 0.5812},
        readme_figures.PERFECT_DETECTOR: {"med_mm": 12.1, "availability": 0.955},
        offline_pipeline.DETECTOR_RANGE_EXACT: {"med_mm": 23.2, "availability": 0.582},
    }
    lines = readme_figures.detector_budget({"runs": {"pond/lawnmower": run}})
    # A bench from before the variants: their cells say so rather than break the table.
    assert lines[2] == (
        "| pond lawnmower (held out) | 25.4 mm, 58.1 % | - | 23.2 mm, 58.2 % | - "
        "| 12.1 mm, 95.5 % |"
    )


def test_the_detect_table_gives_the_spread_over_runs() -> None:
    from capsd import readme_figures

    figures = json.loads((REPO / "docs/figures/detect.json").read_text())
    spread = figures["over_runs"]["cnn / heldout"]
    spread["detection_rate_by_run"] = [0.5, None, 0.25]
    spread["detection_rate_ci95"], spread["false_alarms_per_frame_ci95"] = [0.2, 0.6], [0.0, 0.1]
    rows = [line for line in readme_figures.detect_table(figures) if "run by run" in line]
    assert len(rows) == 2  # each look
    held_out = rows[1]
    assert "| 25.0 % to 50.0 %; 20.0 % to 60.0 % | 0.000 to 0.100 |" in held_out
    # A look whose runs never had the ROV in view says so rather than break the table.
    spread["detection_rate_by_run"] = [None, None, None]
    rows = [line for line in readme_figures.detect_table(figures) if "run by run" in line]
    assert "| - to -; " in rows[1]


def test_the_gated_detect_table_takes_only_the_gated_bench() -> None:
    from capsd import readme_figures

    figures = json.loads((REPO / "docs/figures/detect.json").read_text())
    assert figures["depth_gate"] == "off"
    with pytest.raises(KeyError, match="depth_gate"):
        readme_figures.detect_gated_table(figures)
    # With the classical detector run too, its rows through the gate after the CNN's, per look.
    figures["depth_gate"] = "truth"
    figures["groups"]["classical / off / all"] = figures["groups"]["classical / heldout / all"]
    gated = readme_figures.detect_gated_table(figures)
    fallback = [line for line in gated if "classical" in line]
    assert [line.split(" |")[0] for line in fallback] == [
        "| classical (CFAR) fallback, fixed look",
        "| classical (CFAR) fallback, held-out look",
    ]
    assert gated[-2:] == fallback
    # The CNN alone: no fallback row, the CNN's rows as the plain table's.
    figures["groups"] = {k: v for k, v in figures["groups"].items() if "classical" not in k}
    gated = readme_figures.detect_gated_table(figures)
    assert not any("classical" in line for line in gated)
    with pytest.raises(KeyError, match="classical"):
        readme_figures.detect_table(figures)
    assert gated[0].startswith("| look / pings |")
    assert any(line.startswith("| held-out look, all |") for line in gated)


def test_the_finetune_table_says_which_knobs_were_beyond_training() -> None:
    five = json.loads((REPO / "docs/figures/finetune.json").read_text())
    assert five.get("outside_knobs") is None  # all five (written as null since session 68)
    assert "in a look outside the training variety;" in finetune_table(five)[0]
    one = json.loads((REPO / "docs/figures/finetune_water_db.json").read_text())
    assert one["outside_knobs"] == ["water_db"]
    first = finetune_table(one)[0]
    assert "with water_db beyond the range trained on" in first
    assert "(`--outside-knobs water_db`)" in first
    assert "--outside-knobs none" in finetune_table({**one, "outside_knobs": []})[0]
