"""The detection bench: where in the runs' paths it scores, and its depth-aware search."""

from __future__ import annotations

import itertools
import json
import math
from collections import defaultdict
from pathlib import Path

import msgspec
import pytest

from capsd.bench.detect import (
    EXAMPLE_SPACING_S,
    EXAMPLES_PER_KIND,
    RUNS,
    Detector,
    Examples,
    Tally,
    aperture_place,
    azimuth_band,
    band_of,
    evaluate,
    over_runs,
    run_group,
    run_name,
    score,
    sonar_only,
    truth_gate,
)
from capsd.cli import main
from capsd.payloads import Detection, SonarFrame, SonarLabel
from capsd.simulator.config import OFFLINE_START_NS
from capsd.simulator.sim import Simulation


def _label(range_m: float, elevation_deg: float) -> SonarLabel:
    return SonarLabel(
        stamp_ns=1, seq=0, ping_id=0, visible=True, range_m=range_m, azimuth_rad=0.1,
        elevation_rad=math.radians(elevation_deg), rov_position_m=(1.0, 2.0, -1.0),
    )  # fmt: skip


def _at(range_m: float) -> list[Detection]:
    return [Detection(range_m=range_m, azimuth_rad=0.1, range_sigma_m=0.01,
                      azimuth_sigma_rad=0.01, confidence=0.9)]  # fmt: skip


def test_a_near_rov_is_scored_by_its_place_in_the_aperture_with_a_signed_range_bias() -> None:
    half = math.radians(10.0)
    assert [aperture_place(math.radians(e), half) for e in (-9.0, -2.0, 4.0, 10.5, -11.0)] == [
        "lower third", "middle third", "upper third", "beyond an edge", "beyond an edge",
    ]  # fmt: skip
    tallies: dict[str, Tally] = defaultdict(Tally)
    score(tallies, "d", _label(2.0, -8.0), _at(2.03), half_aperture_rad=half)
    score(tallies, "d", _label(2.0, -7.0), _at(2.05), half_aperture_rad=half)
    score(tallies, "d", _label(3.0, 6.0), _at(2.98), half_aperture_rad=half)
    score(tallies, "d", _label(6.0, -8.0), _at(6.1), half_aperture_rad=half)  # too far off
    lower = tallies["d / under 4 m, lower third"].summary()
    assert lower["visible"] == 2
    assert lower["range_bias_cm_median"] == pytest.approx(4.0)
    assert tallies["d / under 4 m, upper third"].summary()["range_bias_cm_median"] == (
        pytest.approx(-2.0)
    )
    assert tallies["d / all"].summary()["range_err_cm_median"] == pytest.approx(4.0)  # unsigned
    assert not any("middle" in name or "beyond" in name for name in tallies)
    # Without the aperture, no place groups.
    bare: dict[str, Tally] = defaultdict(Tally)
    score(bare, "d", _label(2.0, -8.0), _at(2.03))
    assert sorted(bare) == ["d / 1.5-4 m", "d / all", "d / clear"]


def _alarm(range_m: float, azimuth_rad: float) -> Detection:
    return Detection(range_m=range_m, azimuth_rad=azimuth_rad, range_sigma_m=0.01,
                     azimuth_sigma_rad=0.01, confidence=0.8)  # fmt: skip


def test_false_alarms_are_told_by_what_the_ping_held_and_whether_on_the_rov_s_bearing() -> None:
    tallies: dict[str, Tally] = defaultdict(Tally)
    # The ROV found at 8 m (azimuth 0.1), with an echo 3 m nearer in its beams.
    score(tallies, "d", _label(8.0, 0.0), [*_at(8.02), _alarm(5.0, 0.1)])
    # The ROV missed: one alarm 0.4 m across its bearing at 12 m (0.033 rad), one far off it.
    score(tallies, "d", _label(8.0, 0.0), [_alarm(12.0, 0.1 + 0.4 / 12.0), _alarm(6.0, -0.3)])
    out_of_view = msgspec.structs.replace(_label(8.0, 14.0), visible=False)
    score(tallies, "d", out_of_view, [_alarm(9.0, 0.1)])
    score(tallies, "d", _label(8.0, 0.0), _at(8.0))  # nothing else
    s = tallies["d / all"].summary()
    assert s["frames"] == 4
    assert s["false_alarms_per_frame"] == 4 / 4
    assert s["false_alarms_per_frame_rov_found"] == 1 / 4
    assert s["false_alarms_per_frame_rov_missed"] == 2 / 4
    assert s["false_alarms_per_frame_rov_out_of_view"] == 1 / 4
    assert s["false_alarms_per_frame_on_rov_bearing"] == 3 / 4  # not the one at -0.3 rad


class _Stamps:
    """Finds nothing; notes each frame's stamp."""

    def __init__(self) -> None:
        self.stamps: list[int] = []
        self.windows: list[tuple[float, float] | None] = []

    def __call__(
        self, frame: SonarFrame, *, range_window: tuple[float, float] | None = None
    ) -> list[Detection]:
        self.stamps.append(frame.stamp_ns)
        self.windows.append(range_window)
        return []


def test_a_later_start_scores_that_stretch_of_every_run() -> None:
    first, later = _Stamps(), _Stamps()
    from_start = evaluate({"none": first}, duration_s=1.0, runs=RUNS[:1], looks=("off",))
    from_40 = evaluate(
        {"none": later}, duration_s=1.0, runs=RUNS[:1], looks=("off",), starts_s=(40.0,)
    )
    assert from_start["none / off / all"].frames == len(first.stamps) > 0
    assert from_40["none / off / all"].frames == len(later.stamps) == len(first.stamps)
    # Sim time in the stamps (the sonar's clock may be off by less than a second).
    assert max(first.stamps) - OFFLINE_START_NS < 2e9
    assert min(later.stamps) - OFFLINE_START_NS > 39e9


def test_several_starts_score_each_stretch_of_every_run() -> None:
    one, both = _Stamps(), _Stamps()
    evaluate({"none": one}, duration_s=1.0, runs=RUNS[:1], looks=("off",), starts_s=(30.0,))
    tallies = evaluate(
        {"none": both}, duration_s=1.0, runs=RUNS[:1], looks=("off",), starts_s=(0.0, 30.0)
    )
    assert tallies["none / off / all"].frames == len(both.stamps) > len(one.stamps) > 0
    seconds = sorted((s - OFFLINE_START_NS) / 1e9 for s in both.stamps)
    assert seconds[0] < 2.0
    assert seconds[-1] > 29.0
    # Nothing between the stretches: each is its own 1 s of the paths.
    assert not any(3.0 < s < 29.0 for s in seconds)
    # The later stretch is the same pings whether scored alone or after another.
    assert sorted(both.stamps)[-len(one.stamps) :] == sorted(one.stamps)


def test_every_run_is_tallied_apart_and_together() -> None:
    stamps = _Stamps()
    tallies = evaluate({"none": stamps}, duration_s=1.0, runs=RUNS[:2], looks=("off",))
    apart = [tallies[run_group("none / off", run)] for run in RUNS[:2]]
    assert all(t.frames > 0 for t in apart)
    assert sum(t.frames for t in apart) == tallies["none / off / all"].frames
    assert over_runs(tallies, "none / off", RUNS[:2]) is not None
    assert over_runs(tallies, "none / off", RUNS[:3]) is None  # a run it never scored


def _run_tally(hits: int, visible: int, false_alarms: int, frames: int) -> Tally:
    return Tally(frames=frames, visible=visible, hits=hits, false_alarms=false_alarms)


def test_the_interval_over_runs_resamples_runs_not_pings() -> None:
    runs = RUNS[:3]
    # One run found the ROV on every ping, two on none: 1000 pings each, but three samples.
    tallies = {
        run_group("cnn / heldout", runs[0]): _run_tally(1000, 1000, 0, 1000),
        run_group("cnn / heldout", runs[1]): _run_tally(0, 1000, 30, 1000),
        run_group("cnn / heldout", runs[2]): _run_tally(0, 1000, 30, 1000),
    }
    spread = over_runs(tallies, "cnn / heldout", runs)
    assert spread is not None
    assert spread["runs"] == 3
    assert spread["detection_rate_by_run"] == [1.0, 0.0, 0.0]
    assert spread["false_alarms_per_frame_by_run"] == [0.0, 0.03, 0.03]
    low, high = spread["detection_rate_ci95"]
    # Pooled 1/3; with runs resampled, three draws of the first run alone (1/27 of draws, more
    # than 2.5 %) give 1, of the others alone 0: the interval spans both, where pings
    # resampled one by one would give about +-3 points.
    assert (low, high) == (0.0, 1.0)
    assert spread["false_alarms_per_frame_ci95"] == [0.0, 0.03]
    # Every run alike: the interval is the one value.
    same = {run_group("cnn / heldout", r): _run_tally(800, 1000, 20, 1000) for r in runs}
    again = over_runs(same, "cnn / heldout", runs)
    assert again is not None
    assert again["detection_rate_ci95"] == [0.8, 0.8]


@pytest.mark.parametrize(
    "starts", [["-1"], ["nan"], ["2000"], ["0", "0"], ["0", "3"], ["60", "0", "62"]]
)
def test_a_start_outside_the_paths_or_overlapping_is_refused(
    starts: list[str], capfd: pytest.CaptureFixture[str]
) -> None:
    assert main(["bench", "detect", "--duration", "5", "--start", *starts]) == 2
    assert "--start" in capfd.readouterr().err


@pytest.mark.parametrize("throughput", [[], ["--throughput"]])
def test_missing_weights_are_named_before_any_frame(
    throughput: list[str], tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    missing = tmp_path / "none" / "polar_net.pt"
    assert main(["bench", "detect", *throughput, "--weights", str(missing)]) == 2
    assert f"--weights {missing}: no such file" in capfd.readouterr().err


@pytest.mark.parametrize("threshold", ["0", "1", "-0.1", "nan"])
def test_a_proposal_threshold_outside_0_to_1_is_refused(
    threshold: str, capfd: pytest.CaptureFixture[str]
) -> None:
    assert main(["bench", "detect", "--proposal-threshold", threshold]) == 2
    assert "--proposal-threshold" in capfd.readouterr().err


@pytest.mark.parametrize("threshold", ["0", "1", "nan", "none"])
def test_a_track_proposal_threshold_is_a_number_from_0_to_1_or_off(
    threshold: str, capfd: pytest.CaptureFixture[str]
) -> None:
    assert main(["bench", "detect", "--track-proposal-threshold", threshold]) == 2
    assert f"--track-proposal-threshold {threshold}: between 0 and 1, or off" in (
        capfd.readouterr().err
    )


def test_range_bands_start_close_for_small_tanks_and_end_at_20_m() -> None:
    assert band_of(0.4) is None
    assert band_of(1.2) == "0.5-1.5 m"  # the mockup's follower keeps the ROV about here
    assert band_of(1.5) == "1.5-4 m"
    assert band_of(19.99) == "14-20 m"
    assert band_of(20.0) is None


def test_the_truth_gate_keeps_the_rov_and_bounds_the_search() -> None:
    tank, trajectory, mode, seed = RUNS[1]
    sim = Simulation(sonar_only(tank, trajectory, mode, seed), horizon_s=10.0)
    visible = 0
    for t_s, frame, label in sim.labelled_pings(start_ns=OFFLINE_START_NS, duration_s=3.0):
        if not label.visible:
            continue
        visible += 1
        gate = truth_gate(sim, t_s, label)
        assert gate.plausible(label.range_m, label.azimuth_rad)
        window = gate.range_window(max(abs(a) for a in frame.azimuths_rad))
        assert window is not None
        near, far = window
        assert near <= label.range_m <= far
        # Where the ROV's plane cannot be (well short of the window): rejected.
        assert not gate.plausible(0.5 * near, label.azimuth_rad)
    assert visible > 10


def test_the_bench_hands_the_service_search_window_only_with_the_gate() -> None:
    alone, gated = _Stamps(), _Stamps()
    evaluate({"none": alone}, duration_s=1.0, runs=RUNS[:1], looks=("off",))
    evaluate({"none": gated}, duration_s=1.0, runs=RUNS[:1], looks=("off",), depth_gate="truth")
    assert alone.stamps == gated.stamps
    assert all(w is None for w in alone.windows)
    assert all(w is not None and 0.0 <= w[0] < w[1] for w in gated.windows)


def test_the_looks_rendered_are_the_ones_asked_for(tmp_path: Path) -> None:
    out = tmp_path / "detect.json"
    args = ["bench", "detect", "--detector", "classical", "--looks", "outside"]
    assert main([*args, "--duration", "0.5", "--start", "0", "--json", str(out)]) == 0
    figures = json.loads(out.read_text())
    assert figures["looks"] == ["outside"]
    looks = {name.split(" / ")[1] for name in figures["groups"]}
    assert looks == {"outside"}


def _band_frame(patches: list[tuple[int, int, int]]) -> SonarFrame:
    """100 bins x 64 beams of speckle-free water (level 20), bright patches (bin, beam, level)."""
    import numpy as np

    image = np.full((100, 64), 20, dtype=np.uint8)
    for row, beam, level in patches:
        image[row : row + 6, beam : beam + 4] = level
    return SonarFrame(
        stamp_ns=1, seq=0, ping_id=0, n_ranges=100, n_beams=64, sample_bits=8,
        image=memoryview(image.tobytes()),
        azimuths_rad=tuple(float(a) for a in np.linspace(-0.5, 0.5, 64)),
        range_start_m=0.0, range_resolution_m=0.05, sound_speed_m_s=1480.0, gain_percent=50.0,
        frequency_hz=1.2e6, vertical_aperture_rad=math.radians(20.0),
    )  # fmt: skip


def _footprint(frame: SonarFrame) -> SonarLabel:
    """The ROV over bins 40-46, beams 30-34."""
    az = frame.azimuths_rad
    return SonarLabel(
        stamp_ns=1, seq=0, ping_id=0, visible=True, range_m=2.15, azimuth_rad=az[32],
        elevation_rad=0.0, range_min_m=2.0, range_max_m=2.3, azimuth_min_rad=az[30],
        azimuth_max_rad=az[33], rov_position_m=(1.0, 2.0, -1.0),
    )  # fmt: skip


def test_the_rov_is_the_brightest_of_its_band_unless_something_there_outshines_it() -> None:
    from capsd.bench.detect import brightest_in_band

    alone = _band_frame([(40, 30, 120)])
    assert brightest_in_band(alone, _footprint(alone))
    # Brighter, but at other ranges: still the brightest of its band.
    floor = _band_frame([(40, 30, 120), (80, 5, 250), (10, 50, 250)])
    assert brightest_in_band(floor, _footprint(floor))
    # A wall at its ranges, brighter: a detector must tell the ROV by shape.
    wall = _band_frame([(40, 30, 120), (40, 5, 160)])
    assert not brightest_in_band(wall, _footprint(wall))
    hidden = msgspec.structs.replace(_footprint(alone), visible=False)
    assert not brightest_in_band(alone, hidden)


@pytest.mark.parametrize(
    "extra", [["--detector", "classical"], ["--throughput"], ["--prior-sweep", "1"]]
)
def test_examples_are_refused_where_no_cnn_is_scored(
    extra: list[str], tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    assert main(["bench", "detect", "--examples", str(tmp_path), *extra]) == 2
    assert "--examples" in capfd.readouterr().err
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize(
    "extra",
    [
        ["--outside-knobs", "gamma"],  # without the outside look
        ["--looks", "outside", "--outside-knobs", "colour"],
        ["--looks", "outside", "--outside-knobs", "none", "gamma"],
    ],
)
def test_outside_knobs_are_checked_before_any_frame(
    extra: list[str], capfd: pytest.CaptureFixture[str]
) -> None:
    assert main(["bench", "detect", "--detector", "classical", *extra]) == 2
    assert "--outside-knobs" in capfd.readouterr().err


def test_one_knob_outside_is_rendered_and_recorded(tmp_path: Path) -> None:
    out = tmp_path / "detect.json"
    args = ["bench", "detect", "--detector", "classical", "--looks", "outside"]
    args += ["--outside-knobs", "water_db", "--duration", "0.5", "--start", "0"]
    assert main([*args, "--json", str(out)]) == 0
    figures = json.loads(out.read_text())
    assert figures["outside_knobs"] == ["water_db"]
    brightest = figures["groups"]["(no detector) the ROV brightest in its band / outside / all"]
    assert brightest["false_alarms_per_frame"] == 0.0


def test_the_near_runs_score_a_rov_in_the_near_band(tmp_path: Path) -> None:
    """`--runs near`: the near runs alone, the ROV 0.5-1.5 m off where it is seen."""
    config = sonar_only("mockup", "lawnmower", "follow_near", 108)
    assert config.sonar.pitch_deg == 60.0
    assert config.asv_standoff_m == 0.6
    out = tmp_path / "detect.json"
    args = ["bench", "detect", "--detector", "classical", "--runs", "near", "--looks", "off"]
    assert main([*args, "--duration", "4", "--start", "0", "--json", str(out)]) == 0
    figures = json.loads(out.read_text())
    assert [run[2] for run in figures["runs"]] == [
        "follow_near", "follow_near", "follow_near_side", "follow_near_edge",
    ]  # fmt: skip
    groups = figures["groups"]
    assert groups["classical / off / 0.5-1.5 m"]["visible"] > 0
    # The side run puts the ROV well off the boresight: scored in its own azimuth band.
    assert groups["classical / off / under 4 m, 30-45 deg off the boresight"]["visible"] > 0


def test_the_side_run_turns_the_sonar_off_the_rov() -> None:
    config = sonar_only("mockup", "lawnmower", "follow_near_side", 110)
    assert (config.sonar.pitch_deg, config.sonar.yaw_deg) == (40.0, 70.0)
    assert config.asv_standoff_m == 1.4
    edge = sonar_only("mockup", "random", "follow_near_edge", 111)
    assert (edge.sonar.pitch_deg, edge.sonar.yaw_deg) == (40.0, 85.0)
    assert edge.asv_standoff_m == 1.4


def test_a_near_rov_is_scored_by_how_far_off_the_boresight_it_is() -> None:
    assert [azimuth_band(math.radians(a)) for a in (3.0, -20.0, 44.9, -50.0, 66.0)] == [
        "0-15 deg off the boresight", "15-30 deg off the boresight",
        "30-45 deg off the boresight", "45-65 deg off the boresight", None,
    ]  # fmt: skip
    tallies: dict[str, Tally] = defaultdict(Tally)
    score(tallies, "d", _label(2.0, -8.0), _at(2.03), half_aperture_rad=math.radians(10.0))
    score(tallies, "d", _label(6.0, -8.0), _at(6.1), half_aperture_rad=math.radians(10.0))
    near = [name for name in tallies if "boresight" in name]
    assert near == ["d / under 4 m, 0-15 deg off the boresight"]  # 0.1 rad; the 6 m ROV: none
    assert tallies[near[0]].summary()["visible"] == 1


def test_the_close_runs_put_the_rov_across_the_aperture_of_a_sonar_30_deg_down() -> None:
    """`--runs close`: the ROV 1.2-2 m off at every elevation, the sonar mounted as usual."""
    profile = sonar_only("pond", "lawnmower", "profile_close", 113)
    assert (profile.sonar.pitch_deg, profile.asv_standoff_m) == (30.0, 1.5)
    assert (profile.rov_mode, profile.profile_period_s) == ("profile", 45.0)
    follow = sonar_only("nfp", "bouncing", "follow_close", 115)
    assert (follow.rov_mode, follow.asv_standoff_m) == ("trajectory", 1.5)
    sim = Simulation(profile, horizon_s=50.0)
    seen = [
        label
        for _, _, label in sim.labelled_pings(start_ns=OFFLINE_START_NS, duration_s=45.0)
        if label.visible and abs(label.elevation_rad) <= math.radians(10.0)
    ]
    assert len(seen) >= 20
    assert all(1.2 <= label.range_m <= 2.0 for label in seen)
    elevations = [math.degrees(label.elevation_rad) for label in seen]
    assert min(elevations) < -6.0
    assert max(elevations) > 6.0


class _Twins:
    """Two equally sure echoes off the ROV on every ping."""

    def __call__(
        self, frame: SonarFrame, *, range_window: tuple[float, float] | None = None
    ) -> list[Detection]:
        return [
            Detection(range_m=r, azimuth_rad=a, range_sigma_m=0.01, azimuth_sigma_rad=0.01,
                      confidence=0.9)
            for r, a in ((0.4, -0.5), (0.5, 0.5))
        ]  # fmt: skip


def test_candidates_are_scored_as_the_one_rov_but_the_classical_detector_s_alone() -> None:
    # Any detector but the classical one (the fine-tune bench names its CNNs by their weights).
    detectors: dict[str, Detector] = {"fine-tuned": _Twins(), "classical": _Twins()}
    one_rov = evaluate(detectors, duration_s=1.0, runs=RUNS[:1], looks=("off",))
    alone = evaluate(
        detectors, duration_s=1.0, runs=RUNS[:1], looks=("off",), confidence="independent"
    )
    # Two at 0.9 are each 0.47 as the one ROV: neither is sure, neither a false alarm.
    assert one_rov["fine-tuned / off / all"].summary()["false_alarms_per_frame"] == 0.0
    assert alone["fine-tuned / off / all"].summary()["false_alarms_per_frame"] == 2.0
    assert one_rov["classical / off / all"].summary()["false_alarms_per_frame"] == 2.0


def test_the_bench_s_cnn_settings_reach_both_of_its_cnns() -> None:
    from capsd.bench.detect import CnnOptions, _detectors

    # Neither value the service's default, so a setting not handed on is seen.
    detectors = _detectors("cnn", options=CnnOptions(max_candidates=4, proposal_threshold=0.2))
    assert set(detectors) == {"cnn", "cnn, every frame alone"}
    for detect in detectors.values():
        settings = detect.__self__.settings  # type: ignore[attr-defined]
        assert settings.max_candidates == 4
        assert settings.proposal_threshold == 0.2
    assert detectors["cnn, every frame alone"].__self__.settings.search_every_s == 0.0  # type: ignore[attr-defined]


def test_the_bench_s_cnn_defaults_are_the_service_s() -> None:
    # The bench's options and its command line repeat the service's defaults (the CLI does not
    # import the service, for start-up time): what the bench measures is what ships.
    from capsd.bench.detect import CnnOptions
    from capsd.cli import build_parser
    from capsd.services.sonar_detect.cnn import CnnSettings
    from capsd.services.sonar_detect.service import CnnConfig

    options, config, settings = CnnOptions(), CnnConfig(), CnnSettings()
    for key in ("max_candidates", "proposal_threshold", "track_proposal_threshold",
                "track_hold_s", "search_refines"):  # fmt: skip
        assert getattr(options, key) == getattr(config, key) == getattr(settings, key), key
    args = build_parser().parse_args(["bench", "detect"])
    assert args.max_candidates == options.max_candidates
    assert args.proposal_threshold == options.proposal_threshold
    assert float(args.track_proposal_threshold) == options.track_proposal_threshold
    assert args.track_hold == options.track_hold_s
    assert args.search_refines == options.search_refines


def test_examples_keep_misses_and_false_alarms_spaced_and_few(tmp_path: Path) -> None:
    from capsd.plots import example_sheets

    frame = _band_frame([(40, 30, 200), (70, 10, 200)])
    label = _footprint(frame)
    rov, clutter = _at(2.15)[0], _alarm(3.6, frame.azimuths_rad[12])
    examples = Examples()
    run, other = RUNS[0], RUNS[1]
    pings = [(k * 0.25, found) for k in range(40) for found in ([rov, clutter], [])]
    for t_s, found in pings:  # every 0.25 s the ROV found beside a false alarm, then missed
        examples.note("heldout", run, t_s, frame, label, found)
    kept = examples.found[("heldout", run_name(run))]
    assert [e.kind for e in kept].count("missed") == EXAMPLES_PER_KIND
    assert [e.kind for e in kept].count("false alarm") == EXAMPLES_PER_KIND
    # At most one of a kind per EXAMPLE_SPACING_S of the run: not its first consecutive pings.
    times = [e.t_s for e in kept if e.kind == "missed"]
    assert all(b - a >= EXAMPLE_SPACING_S for a, b in itertools.pairwise(times))
    assert next(e for e in kept if e.kind == "missed").title.startswith(
        f"missed {label.range_m:.1f} m, nothing sure"
    )
    alarm = next(e for e in kept if e.kind == "false alarm")
    assert alarm.title.startswith("alarm 3.6 m, 0.80")
    # Centred on the place: the clutter patch in the middle of its crop, brighter than water.
    c = alarm.crop.shape[0] // 2
    assert alarm.crop[c - 2 : c + 3, c - 2 : c + 3].mean() > alarm.crop[:5, :5].mean()
    # A ping without the ROV in view is no miss; the surest candidate is named in a miss.
    examples.note("heldout", other, 0.0, frame, msgspec.structs.replace(label, visible=False), [])
    assert ("heldout", run_name(other)) in examples.found
    assert not examples.found[("heldout", run_name(other))]
    examples.note("off", other, 0.0, frame, label, [clutter])
    miss, alarm_off = examples.found[("off", run_name(other))]
    assert miss.title.startswith(f"missed {label.range_m:.1f} m, 0.80 elsewhere")
    assert (miss.kind, alarm_off.kind) == ("missed", "false alarm")
    # Gathered as they came (the sheet draws a run's misses first).
    assert [e.kind for e in kept[:2]] == ["false alarm", "missed"]
    paths = example_sheets(examples.found, tmp_path, detector="cnn")
    assert [p.name for p in paths] == ["examples_heldout.png", "examples_off.png"]
    assert all(p.stat().st_size > 1000 for p in paths)
