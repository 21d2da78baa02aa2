"""Accuracy figures, live pairing, the offline pipeline and the demo command."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capsd.accuracy import Accuracy, LivePairing, Scored
from capsd.offline_pipeline import Variant, ablations, run
from capsd.payloads import RovFix, SonarLabel
from services.locator.service import MethodConfig
from simulator.config import Config as SimConfig
from tests.conftest import REPO


def test_summary_is_the_papers_figures() -> None:
    acc = Accuracy()
    acc.add(Scored(1, (1.0, 0.0, 0.0), (1.0, 0.0, 0.0), (1.0, 0.0, 0.03)))  # 30 mm in z
    acc.add(Scored(2, (0.0, 0.04, 0.0), None, (0.0, 0.0, 0.0)))  # 40 mm in y
    acc.add(Scored(3, None, None, (0.0, 0.0, 0.0)))  # no good fix
    s = acc.summary()
    assert s["pings"] == 3
    assert s["good"] == 2
    assert s["availability"] == pytest.approx(2 / 3, abs=1e-4)
    assert s["med_mm"] == pytest.approx(35.0)
    assert s["rmse_z_mm"] == pytest.approx(math.sqrt(0.03**2 / 2) * 1000, abs=0.1)
    assert s["rmse_x_mm"] == 0.0


def _fix(stamp: int) -> RovFix:
    return RovFix(
        stamp_ns=stamp,
        seq=stamp,
        method="capsd",
        quality="good",
        raw_position_m=(1.0, 2.0, -3.0),
        position_m=(1.0, 2.0, -3.0),
    )


def _label(stamp: int) -> SonarLabel:
    return SonarLabel(
        stamp_ns=stamp,
        seq=stamp,
        ping_id=stamp,
        visible=True,
        range_m=5.0,
        azimuth_rad=0.0,
        elevation_rad=0.0,
        rov_position_m=(1.0, 2.0, -3.01),
    )


@settings(max_examples=50, deadline=None)
@given(order=st.permutations(list(range(20))))
def test_live_pairing_is_order_independent(order: list[int]) -> None:
    acc = Accuracy()
    pairing = LivePairing(acc)
    for k in order:  # fixes 0..9 and labels 10..19 of the same ten pings, any order
        if k < 10:
            pairing.add_fix(_fix(k))
        else:
            pairing.add_label(_label(k - 10))
    assert acc.summary()["good"] == 10
    assert acc.summary()["med_mm"] == pytest.approx(10.0)


def test_offline_pipeline_scores_every_variant_on_the_same_pings() -> None:
    variants = [v for v in ablations() if v.detector == "box_centre"]
    variants.append(
        Variant(
            "per frame",
            detector="box_centre",
            method=MethodConfig(preset="custom", tracking="per_frame"),
        )
    )
    results = run(
        SimConfig(tank="nfp", trajectory="square", seed=3), duration_s=6.0, variants=variants
    )
    pings = {name: acc.summary()["pings"] for name, acc in results.items()}
    assert len(set(pings.values())) == 1  # the very same pings
    assert next(iter(pings.values())) >= 100
    for acc in results.values():
        s = acc.summary()
        assert s["availability"] > 0.9
        assert s["med_mm"] < 200.0


@pytest.mark.integration
def test_demo_runs_end_to_end_and_writes_its_report(tmp_path: Path) -> None:
    out = tmp_path / "report"
    proc = subprocess.run(
        [sys.executable, "-m", "capsd", "demo", "--duration", "12", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=110,
        cwd=REPO,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    figures = json.loads((out / "figures.json").read_text())
    assert figures["accuracy"]["good"] > 20
    assert figures["accuracy"]["med_mm"] < 100.0
    assert all(code == 0 for code in figures["exit_codes"].values())
    for name in ("summary.md", "trajectory_3d.png", "position_axes.png", "errors.png"):
        assert (out / name).stat().st_size > 0
    assert "VISION_POSITION_ESTIMATE" in (out / "summary.md").read_text()
