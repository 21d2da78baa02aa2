"""`capsd bench finetune`'s options (the bench itself takes minutes: docs/JOURNAL.md)."""

from __future__ import annotations

from pathlib import Path

import pytest

from capsd.cli import main


@pytest.mark.parametrize("knobs", [["colour"], ["none", "gamma"], ["water_db", "speckle"]])
def test_outside_knobs_are_checked_before_the_dive(
    knobs: list[str], tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "finetune"
    assert main(["bench", "finetune", "--out", str(out), "--outside-knobs", *knobs]) == 2
    err = capfd.readouterr().err
    assert "bench finetune: --outside-knobs" in err
    assert not out.exists()  # nothing recorded, nothing trained
