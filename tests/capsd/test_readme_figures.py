"""README tables come from the benches' JSON: the README is in step, and the generator works."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from capsd.errors import CapsdError
from capsd.readme_figures import RENDERERS, blocks, render
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
