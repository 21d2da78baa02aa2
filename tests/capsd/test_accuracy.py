"""Accuracy figures, live pairing, the offline pipeline and the demo command."""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
from pathlib import Path

import msgspec
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capsd.accuracy import Accuracy, LivePairing, Scored, bootstrap_med, common_pings
from capsd.bench.baseline import box_range_bias
from capsd.losses import load as load_losses
from capsd.offline_pipeline import (
    DETECTOR_BEARING_EXACT,
    DETECTOR_EXACT,
    DETECTOR_RANGE_EXACT,
    PERFECT_DETECTOR,
    Variant,
    ablations,
    run,
    with_exact,
)
from capsd.payloads import Detection, RovFix, SonarLabel
from capsd.recording import channel_counts
from capsd.services.locator.service import MethodConfig
from capsd.simulator.config import Config as SimConfig
from capsd.simulator.install_errors import InstallErrorsConfig
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


def _errors(values_mm: list[float | None]) -> Accuracy:
    """One ping per value: an x error of that many mm, or no good fix (None)."""
    acc = Accuracy()
    for k, v in enumerate(values_mm):
        estimate = None if v is None else (v / 1000, 0.0, 0.0)
        acc.add(Scored(k, estimate, estimate, (0.0, 0.0, 0.0)))
    return acc


def test_common_pings_keep_only_what_every_method_fixed() -> None:
    ours = _errors([10, None, 10, 10])
    other = _errors([50, 50, None, 50])
    a, b = common_pings([ours, other])
    assert [p.stamp_ns for p in a.pings] == [0, 3]
    assert a.summary()["med_mm"] == 10.0
    assert b.summary()["med_mm"] == 50.0
    # Scored on all of its own pings, the other method would look the same, ours too: the
    # point is that the set is the same for both.
    assert [p.stamp_ns for p in b.pings] == [0, 3]


@settings(max_examples=25, deadline=None)
@given(
    st.lists(st.floats(1.0, 100.0), min_size=5, max_size=200),
    st.floats(1.5, 5.0),
    st.integers(0, 1000),
)
def test_bootstrap_intervals_hold_the_estimate(
    ours_mm: list[float], factor: float, seed: int
) -> None:
    ours = _errors(list(ours_mm))
    other = _errors([v * factor for v in ours_mm])
    result = bootstrap_med(ours, other, seed=seed, resamples=200)
    assert result["common_pings"] == len(ours_mm)
    low, high = result["ratio_ci"]
    # The other method is exactly `factor` times worse on every ping: every resample agrees.
    assert low == pytest.approx(1 / factor, abs=2e-3)
    assert high == pytest.approx(1 / factor, abs=2e-3)
    lo_mm, hi_mm = result["ours_med_ci_mm"]
    # Resampled means lie between the smallest and the largest error (a percentile interval
    # need not hold the point estimate itself on a small, skewed sample).
    assert min(ours_mm) - 0.1 <= lo_mm <= hi_mm <= max(ours_mm) + 0.1


def test_bootstrap_of_methods_with_no_common_ping() -> None:
    assert bootstrap_med(_errors([10, None]), _errors([None, 10])) == {"common_pings": 0}


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


def test_the_calibrated_baseline_beats_the_published_one_on_the_same_pings() -> None:
    bias = box_range_bias(duration_s=4.0, sonar_hz=5.0)
    # The box frames the near side of the hull (about 0.6 m deep): short by some centimetres.
    assert bias.pings >= 50
    assert 0.03 < bias.mean_m < 0.2
    variants = ablations(box_range_bias_m=bias.mean_m)[:2]
    assert [v.box_range_bias_m for v in variants] == [0.0, bias.mean_m]
    results = run(
        SimConfig(tank="nfp", trajectory="random", seed=9), duration_s=5.0, variants=variants
    )
    published, calibrated = (results[v.name] for v in variants)
    result = bootstrap_med(calibrated, published)
    assert result["common_pings"] >= 50
    assert result["ratio_ci"][1] < 1.0


def test_a_perfect_detector_fixes_the_pings_in_view_closer_than_the_box() -> None:
    by_name = {v.name: v for v in ablations()}
    variants = [by_name["paper (baseline)"], by_name[PERFECT_DETECTOR]]
    config = SimConfig(
        tank="nfp", trajectory="square", seed=3, install_errors=InstallErrorsConfig(mode="off")
    )
    results = run(config, duration_s=6.0, variants=variants)
    paper, perfect = (results[v.name].summary() for v in variants)
    assert perfect["pings"] == paper["pings"] >= 100
    assert perfect["availability"] > 0.9
    # What is left without detector error: depth noise, the ASV's pose, the filter.
    assert perfect["med_mm"] < 30.0
    assert perfect["med_mm"] < paper["med_mm"] / 2


def _candidate(range_m: float, azimuth_rad: float) -> Detection:
    return Detection(
        range_m=range_m,
        azimuth_rad=azimuth_rad,
        range_sigma_m=0.02,
        azimuth_sigma_rad=0.003,
        confidence=0.9,
    )


@settings(max_examples=200, deadline=None)
@given(
    truth_range=st.floats(1.0, 20.0),
    truth_azimuth=st.floats(-1.1, 1.1),
    range_error=st.floats(-0.3, 0.3),
    cross_error=st.floats(-0.3, 0.3),
    alarm_range=st.floats(0.5, 30.0),
    axes=st.sampled_from(["range", "azimuth", "both"]),
)
def test_with_exact_moves_only_the_candidate_on_the_rov_along_its_axes(
    truth_range: float,
    truth_azimuth: float,
    range_error: float,
    cross_error: float,
    alarm_range: float,
    axes: str,
) -> None:
    label = SonarLabel(
        stamp_ns=1,
        seq=1,
        ping_id=1,
        visible=True,
        range_m=truth_range,
        azimuth_rad=truth_azimuth,
        elevation_rad=0.0,
        rov_position_m=(0.0, 0.0, 0.0),
    )
    on_rov = _candidate(truth_range + range_error, truth_azimuth + cross_error / truth_range)
    # A false alarm at least 2 m from the ROV (on the other side of the fan, or out along it).
    alarm = _candidate(max(alarm_range, truth_range + 2.0), -truth_azimuth - 0.2)
    out = with_exact([alarm, on_rov], label, axes=axes)  # type: ignore[arg-type]
    assert out[0] == alarm
    moved = out[1]
    assert moved.range_m == (on_rov.range_m if axes == "azimuth" else truth_range)
    assert moved.azimuth_rad == (on_rov.azimuth_rad if axes == "range" else truth_azimuth)
    assert (moved.range_sigma_m, moved.confidence) == (on_rov.range_sigma_m, on_rov.confidence)
    # No candidate on the ROV (a miss), or the ROV out of view: nothing moves.
    assert with_exact([alarm], label, axes=axes) == [alarm]  # type: ignore[arg-type]
    hidden = msgspec.structs.replace(label, visible=False)
    assert with_exact([alarm, on_rov], hidden, axes=axes) == [alarm, on_rov]  # type: ignore[arg-type]


def test_the_detectors_own_errors_cost_what_its_exact_variants_take_off() -> None:
    # The held-out pond, where the CNN's ranges run 1-2 cm short (docs/JOURNAL.md, the accuracy
    # bench's detector rows): taking its range and bearing error off lowers ours on the same pings.
    names = {"ours (CAP-SD)", DETECTOR_EXACT, DETECTOR_RANGE_EXACT, DETECTOR_BEARING_EXACT}
    variants = [v for v in ablations() if v.name in names]
    assert len(variants) == 4
    config = SimConfig(
        tank="pond", trajectory="random", seed=0, install_errors=InstallErrorsConfig(mode="off")
    )
    results = {k: a.summary() for k, a in run(config, duration_s=5.0, variants=variants).items()}
    assert len({s["pings"] for s in results.values()}) == 1
    ours = results["ours (CAP-SD)"]
    assert ours["good"] >= 30
    assert results[DETECTOR_EXACT]["med_mm"] < ours["med_mm"]
    assert results[DETECTOR_RANGE_EXACT]["med_mm"] < ours["med_mm"]


@pytest.mark.integration
def test_demo_runs_end_to_end_and_writes_its_report(tmp_path: Path) -> None:
    out = tmp_path / "report"
    recording = tmp_path / "demo.mcap"
    command = [sys.executable, "-m", "capsd", "demo", "--duration", "12", "--out", str(out),
               "--record", str(recording), "--record-view", "off"]  # fmt: skip
    proc = subprocess.run(
        command,
        capture_output=True,
        text=True,
        timeout=110,
        cwd=REPO,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    figures = json.loads((out / "figures.json").read_text())
    assert figures["accuracy"]["good"] > 20
    # The default installation is a tape-measured one, uncalibrated: about 0.1 m off (seed 0
    # draws 1.2 deg of sonar heading), never the metres of a broken pipeline.
    assert figures["accuracy"]["med_mm"] < 300.0
    assert figures["install_errors"]["sonar_yaw_deg"] != 0.0
    assert all(code == 0 for code in figures["exit_codes"].values())
    for name in ("summary.md", "trajectory_3d.png", "position_axes.png", "errors.png"):
        assert (out / name).stat().st_size > 0
    summary = (out / "summary.md").read_text()
    assert "VISION_POSITION_ESTIMATE" in summary
    assert "Installation errors: realistic (drawn from the seed" in summary
    # The recording holds the payloads without the operator's scene, and says per ping why
    # a fix was good or not.
    keys = channel_counts(recording)
    assert not [k for k in keys if k.startswith("/capsd/")]
    assert keys["cap/tank/sim/sim/label"] > 50
    losses = load_losses(recording)
    assert len(losses.pings) == keys["cap/tank/sim/sim/label"]
    assert sum(p.kind == "good" for p in losses.pings) > 20


def test_the_self_calibrated_report_states_its_targets() -> None:
    from capsd.bench.accuracy import OURS, OURS_SELF_CALIBRATED, self_calibrated_report

    figures = {
        "runs": {
            "nfp/square": {
                OURS: {"med_mm": 120.0},
                OURS_SELF_CALIBRATED: {"nees_mean": 2.9, "nees_within_95": 0.95},
            }
        },
        "self_calibration": {
            "nfp/square": {
                "yaw_deg": 0.5, "yaw_wanted_deg": 0.48, "roll_deg": -0.6,
                "roll_wanted_deg": -0.59, "y_mm": 10.0, "y_wanted_mm": 12.0,
                "depth_offset_mm": -20.0, "depth_offset_wanted_mm": -25.0,
                "range_offset_mm": 4.0, "range_offset_wanted_mm": 9.0, "forward_mm": None,
                "forward_wanted_mm": -12.0,
            }
        },
        "common_self_calibrated": {
            "nfp/square": {
                "common_pings": 100, "ours_med_mm": 30.0, "ours_med_ci_mm": [28.0, 33.0],
                "other_med_mm": 50.0, "other_med_ci_mm": [47.0, 52.0], "ratio": 0.6,
                "ratio_ci": [0.55, 0.66],
            }
        },
        "perfect_detector_self_calibrated": {
            "nfp/square": {
                "common_pings": 110, "ours_med_mm": 20.0, "ours_med_ci_mm": [19.0, 21.0],
                "other_med_mm": 50.0, "other_med_ci_mm": [47.0, 52.0], "ratio": 0.4,
                "ratio_ci": [0.37, 0.43],
            }
        },
    }  # fmt: skip
    text = "\n".join(self_calibrated_report(figures))
    assert "| nfp/square | 0.5 / 0.48 |" in text
    assert "| -20.0 / -25.0 | 4.0 / 9.0 | - / -12.0 | 120.0 |" in text
    assert (
        "| 120.0 | 30.0 [28, 33] | 50.0 [47, 52] | 0.6 [0.55, 0.66] | met | NOT met | 2.9, 0.95 "
        "| 0.4 [0.37, 0.43] |" in text
    )
    assert "All met: no" in text


def _processes_mentioning(text: str) -> list[str]:
    """Command lines of live processes that mention `text` (Linux /proc)."""
    found = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            args = cmdline.read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue  # gone meanwhile
        if text in args:
            found.append(args)
    return found


@pytest.mark.integration
def test_a_killed_demo_stops_its_children_and_still_reports(tmp_path: Path) -> None:
    """SIGTERM (a timeout, systemd, kill) ends the demo as Ctrl-C does: no orphans."""
    out = tmp_path / "killed"
    proc = subprocess.Popen(
        [sys.executable, "-m", "capsd", "demo", "--duration", "120", "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=REPO,
    )
    assert proc.stdout is not None
    for line in proc.stdout:  # until the first pings are counted
        if " pings " in line and " pings     0 " not in line:
            break
    assert _processes_mentioning(str(out)), "the demo's services run meanwhile"
    proc.send_signal(signal.SIGTERM)
    rest, _ = proc.communicate(timeout=60)
    assert proc.returncode == 0, rest[-3000:]
    assert "stopped by user" in rest
    assert (out / "summary.md").stat().st_size > 0
    assert _processes_mentioning(str(out)) == []
