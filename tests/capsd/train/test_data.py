"""The training plan: far, near and close runs, later starts, other rack heights on request."""

from __future__ import annotations

import dataclasses
import math

from capsd.bench.detect import band_of
from capsd.payloads import SonarLabel
from capsd.services.sonar_detect.polar_input import DEFAULT_INPUTS
from capsd.simulator.config import OFFLINE_START_NS
from capsd.simulator.sim import Simulation
from capsd.train.data import (
    CLOSE_PITCH_DEG,
    CLOSE_PROFILE_PERIOD_S,
    CLOSE_STANDOFF_M,
    FAR_PITCH_DEG,
    FAR_STANDOFF_M,
    NEAR_PITCH_DEG,
    NEAR_STANDOFF_M,
    NEAR_YAW_DEG,
    RunPlan,
    plan_runs,
    render_run,
)


def test_far_runs_replace_a_share_and_leave_the_rest_as_planned() -> None:
    plain = plan_runs(runs=40, seed=3, duration_s=10.0, sonar_hz=2.0)
    assert plain == plan_runs(runs=40, seed=3, duration_s=10.0, sonar_hz=2.0, far_share=0.0)
    assert all(p.sonar_pitch_deg is None for p in plain)
    mixed = plan_runs(runs=40, seed=3, duration_s=10.0, sonar_hz=2.0, far_share=0.5)
    far = [k for k, p in enumerate(mixed) if p.sonar_pitch_deg is not None]
    assert 10 <= len(far) <= 30
    for k, (p, q) in enumerate(zip(plain, mixed, strict=True)):
        if k not in far:
            assert p == q
            continue
        assert (q.tank, q.asv_mode) == ("nfp", "follow")
        assert q.standoff_m is not None
        assert q.sonar_pitch_deg is not None
        assert FAR_STANDOFF_M[0] <= q.standoff_m <= FAR_STANDOFF_M[1]
        assert FAR_PITCH_DEG[0] <= q.sonar_pitch_deg <= FAR_PITCH_DEG[1]
        # The rest of the run (its seed, look, gains) as planned.
        assert (
            dataclasses.replace(
                q, tank=p.tank, asv_mode=p.asv_mode, standoff_m=p.standoff_m, sonar_pitch_deg=None
            )
            == p
        )


def _in_the_aperture(plan: RunPlan, *, duration_s: float) -> list[SonarLabel]:
    """The labels of the run's first `duration_s` with the ROV's centre inside the aperture."""
    sim = Simulation(plan.config(), horizon_s=duration_s + 5.0)
    return [
        label
        for _, _, label in sim.labelled_pings(start_ns=OFFLINE_START_NS, duration_s=duration_s)
        if label.visible and abs(label.elevation_rad) <= math.radians(10.0)
    ]


def test_a_far_run_puts_the_rov_far_inside_the_aperture() -> None:
    plan = dataclasses.replace(
        plan_runs(runs=1, seed=5, duration_s=4.0, sonar_hz=5.0, far_share=1.0)[0],
        trajectory="lawnmower",
        standoff_m=16.0,
        sonar_pitch_deg=12.0,
    )
    assert plan.config().sonar.pitch_deg == 12.0
    far = _in_the_aperture(plan, duration_s=4.0)
    assert far
    assert all(band_of(label.range_m) == "14-20 m" for label in far)


def test_near_runs_replace_a_share_of_the_runs_that_are_not_far() -> None:
    far = plan_runs(runs=40, seed=3, duration_s=10.0, sonar_hz=2.0, far_share=0.3)
    both = plan_runs(runs=40, seed=3, duration_s=10.0, sonar_hz=2.0, far_share=0.3, near_share=0.5)
    near = [k for k, (p, q) in enumerate(zip(far, both, strict=True)) if p != q]
    assert 5 <= len(near) <= 25
    for k in near:
        p, q = far[k], both[k]
        assert p.sonar_pitch_deg is None  # a far run stays far
        assert (q.tank, q.asv_mode) == ("mockup", "follow")
        assert q.standoff_m is not None
        assert q.sonar_pitch_deg is not None
        assert NEAR_STANDOFF_M[0] <= q.standoff_m <= NEAR_STANDOFF_M[1]
        assert NEAR_PITCH_DEG[0] <= q.sonar_pitch_deg <= NEAR_PITCH_DEG[1]
        assert abs(q.sonar_yaw_deg) <= NEAR_YAW_DEG
        assert (q.seed, q.variety) == (p.seed, p.variety)
    # Turned either way, some of them far off the ROV; far and other runs face it.
    yaws = [both[k].sonar_yaw_deg for k in near]
    assert min(yaws) < -20.0
    assert max(yaws) > 20.0
    assert all(p.sonar_yaw_deg == 0.0 for k, p in enumerate(both) if k not in near)
    assert both[near[0]].config().sonar.yaw_deg == yaws[0]


def test_the_near_refiner_places_its_near_runs_further_off_and_turned_further() -> None:
    """Its own standoff and turn (the fan's edge at 1-2 m); the same runs otherwise."""
    default = plan_runs(runs=40, seed=3, duration_s=10.0, sonar_hz=2.0, near_share=1.0)
    wide = plan_runs(
        runs=40, seed=3, duration_s=10.0, sonar_hz=2.0, near_share=1.0,
        near_standoff_m=(0.3, 1.6), near_yaw_deg=85.0,
    )  # fmt: skip
    assert [p.seed for p in wide] == [p.seed for p in default]
    assert all(0.3 <= p.standoff_m <= 1.6 for p in wide if p.standoff_m is not None)
    assert max(p.standoff_m or 0.0 for p in wide) > NEAR_STANDOFF_M[1]
    assert all(abs(p.sonar_yaw_deg) <= 85.0 for p in wide)
    assert max(abs(p.sonar_yaw_deg) for p in wide) > NEAR_YAW_DEG


def test_a_near_run_puts_the_rov_near_the_sonar() -> None:
    plan = dataclasses.replace(
        plan_runs(runs=1, seed=5, duration_s=20.0, sonar_hz=5.0, near_share=1.0)[0],
        trajectory="lawnmower",
        standoff_m=0.6,
        sonar_pitch_deg=60.0,
    )
    seen = _in_the_aperture(plan, duration_s=20.0)
    assert len(seen) >= 20
    assert all(band_of(label.range_m) == "0.5-1.5 m" for label in seen)


def test_close_runs_replace_a_share_of_the_runs_that_are_not_far_half_of_them_profiling() -> None:
    far = plan_runs(runs=60, seed=3, duration_s=10.0, sonar_hz=2.0, far_share=0.3)
    both = plan_runs(runs=60, seed=3, duration_s=10.0, sonar_hz=2.0, far_share=0.3, close_share=0.5)
    close = [k for k, (p, q) in enumerate(zip(far, both, strict=True)) if p != q]
    assert 8 <= len(close) <= 30
    for k in close:
        p, q = far[k], both[k]
        assert p.sonar_pitch_deg is None  # a far run stays far
        assert (q.tank, q.asv_mode, q.seed, q.variety) == (p.tank, "follow", p.seed, p.variety)
        assert q.standoff_m is not None
        assert q.sonar_pitch_deg is not None
        assert CLOSE_STANDOFF_M[0] <= q.standoff_m <= CLOSE_STANDOFF_M[1]
        assert CLOSE_PITCH_DEG[0] <= q.sonar_pitch_deg <= CLOSE_PITCH_DEG[1]
        if q.rov_mode == "profile":
            assert CLOSE_PROFILE_PERIOD_S[0] <= q.profile_period_s <= CLOSE_PROFILE_PERIOD_S[1]
            assert q.config().rov_mode == "profile"
            assert q.config().profile_period_s == q.profile_period_s
    profiling = sum(both[k].rov_mode == "profile" for k in close)
    assert 0 < profiling < len(close)
    assert all(p.rov_mode == "trajectory" for k, p in enumerate(both) if k not in close)


def test_a_close_profile_puts_the_rov_near_a_sonar_30_deg_down_across_the_aperture() -> None:
    """What the proposal network had seen almost none of before session 59."""
    plan = dataclasses.replace(
        plan_runs(runs=1, seed=5, duration_s=30.0, sonar_hz=2.0)[0],
        tank="nfp",
        asv_mode="follow",
        standoff_m=1.5,
        sonar_pitch_deg=30.0,
        rov_mode="profile",
        profile_period_s=30.0,
    )
    seen = _in_the_aperture(plan, duration_s=30.0)
    assert len(seen) >= 10
    assert all(1.0 <= label.range_m <= 2.5 for label in seen)
    elevations = [math.degrees(label.elevation_rad) for label in seen]
    assert min(elevations) < -5.0
    assert max(elevations) > 5.0


def test_a_start_spread_moves_each_run_into_its_paths_and_leaves_the_rest_as_planned() -> None:
    plain = plan_runs(runs=30, seed=4, duration_s=10.0, sonar_hz=2.0, far_share=0.2)
    assert all(p.start_s == 0.0 for p in plain)
    spread = plan_runs(
        runs=30, seed=4, duration_s=10.0, sonar_hz=2.0, far_share=0.2, start_spread_s=300.0
    )
    starts = [q.start_s for q in spread]
    assert all(0.0 <= s <= 300.0 for s in starts)
    assert len(set(starts)) == len(starts)
    assert max(starts) > 150.0
    assert [dataclasses.replace(q, start_s=0.0) for q in spread] == plain


def test_drawn_rack_heights_reach_every_runs_tank_and_change_nothing_else() -> None:
    plain = plan_runs(runs=10, seed=4, duration_s=10.0, sonar_hz=2.0, far_share=0.2)
    racks = plan_runs(
        runs=10, seed=4, duration_s=10.0, sonar_hz=2.0, far_share=0.2, rack_heights="drawn"
    )
    assert [dataclasses.replace(q, rack_heights="preset") for q in racks] == plain
    tanks = [
        (p.config().world_tank(), q.config().world_tank())
        for p, q in zip(plain, racks, strict=True)
    ]
    # Each rack at even odds: a mockup with its two racks keeps both a quarter of the time.
    assert sum(a.boxes != b.boxes for a, b in tanks) >= 8
    assert all(a.cylinders == b.cylinders for a, b in tanks)


def test_pings_from_a_later_time_are_that_time_s_pings() -> None:
    plan = dataclasses.replace(
        plan_runs(runs=1, seed=6, duration_s=3.0, sonar_hz=2.0)[0], start_s=40.25
    )
    horizon = plan.start_s + plan.duration_s + 5.0
    whole = {
        round(t, 6): label
        for t, _, label in Simulation(plan.config(), horizon_s=horizon).labelled_pings(
            start_ns=OFFLINE_START_NS, duration_s=plan.start_s + plan.duration_s
        )
    }
    later = list(
        Simulation(plan.config(), horizon_s=horizon).labelled_pings(
            start_ns=OFFLINE_START_NS, duration_s=plan.duration_s, from_s=plan.start_s
        )
    )
    end_s = plan.start_s + plan.duration_s
    assert [round(t, 6) for t, _, _ in later] == [t for t in whole if plan.start_s <= t <= end_s]
    for t, frame, label in later:
        assert frame.stamp_ns == label.stamp_ns
        same = whole[round(t, 6)]
        assert label.rov_position_m == same.rov_position_m
        assert label.range_m == same.range_m
        assert label.azimuth_rad == same.azimuth_rad


def test_each_crop_knows_its_centre_s_range_and_the_near_ones_can_be_kept() -> None:
    plan = dataclasses.replace(
        plan_runs(runs=1, seed=5, duration_s=4.0, sonar_hz=5.0, near_share=1.0)[0],
        trajectory="lawnmower",
        standoff_m=0.6,
        sonar_pitch_deg=60.0,
    )
    samples = render_run((plan, None, DEFAULT_INPUTS, None))
    assert len(samples.crop_ranges_m) == len(samples.crops) == len(samples.crop_targets) > 0
    near = samples.crops_within(1.5)
    assert render_run((plan, None, DEFAULT_INPUTS, 1.5)).crop_ranges_m == near.crop_ranges_m
    assert all(r < 1.5 for r in near.crop_ranges_m)
    assert len(near.crops) == len(near.crop_targets) == len(near.crop_ranges_m)
    assert 0 < len(near.crops) < len(samples.crops)
    assert sum(t[0] for t in near.crop_targets) > 0  # the near ROV's own crops are kept
    assert not near.grids
    # Each kept crop is the one at its place in the whole set.
    kept = [k for k, r in enumerate(samples.crop_ranges_m) if r < 1.5]
    assert all((samples.crops[k] == c).all() for k, c in zip(kept, near.crops, strict=True))
