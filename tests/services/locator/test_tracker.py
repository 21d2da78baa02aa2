"""Tracker: consistency (NEES), gating, association, coasting, loss, relocalisation."""

from __future__ import annotations

import numpy as np
import pytest

from capsd.services.locator.tracker import Tracker, TrackerSettings
from tests.services.locator.nees import mean_nees_bounds

SECOND = 1_000_000_000


def _simulate(
    rng: np.random.Generator, settings: TrackerSettings, steps: int, dt: float, r_sigma: float
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Truth from the filter's own motion model, so NEES tests the filter, not the model."""
    q = np.array([settings.accel_density_xy, settings.accel_density_xy, settings.accel_density_z])
    cov_block = np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    x = np.concatenate([rng.normal(0, 5, 3), rng.normal(0, 0.3, 3)])
    truths, meas = [], []
    for _ in range(steps):
        for axis in range(3):
            w = rng.multivariate_normal(np.zeros(2), q[axis] * cov_block)
            x[axis] += dt * x[axis + 3] + w[0]
            x[axis + 3] += w[1]
        truths.append(x.copy())
        meas.append(x[:3] + rng.normal(0, r_sigma, 3))
    return truths, meas


def test_filter_nees_within_95_percent_chi_square_bounds() -> None:
    settings = TrackerSettings(initial_speed_sigma_m_s=0.5)
    rng = np.random.default_rng(11)
    runs, steps, dt, r_sigma = 50, 60, 0.1, 0.03
    r = np.eye(3) * r_sigma**2
    nees = np.zeros(steps)
    for _ in range(runs):
        truths, meas = _simulate(rng, settings, steps, dt, r_sigma)
        tracker = Tracker(settings)
        for k, (truth, z) in enumerate(zip(truths, meas, strict=True)):
            tracker.update(int(k * dt * SECOND), [(z, r)])
            est = tracker.estimate()
            assert est.position_m is not None
            assert est.covariance_m2 is not None
            err = est.position_m - truth[:3]
            nees[k] += float(err @ np.linalg.solve(est.covariance_m2, err))
    lo, hi = mean_nees_bounds(dim=3, count=runs)
    inside = np.mean((nees / runs >= lo) & (nees / runs <= hi))
    assert inside >= 0.9, f"only {inside:.0%} of steps inside [{lo:.2f}, {hi:.2f}]"
    overall = nees[5:].sum() / (runs * (steps - 5))
    total_lo, total_hi = mean_nees_bounds(dim=3, count=runs * (steps - 5))
    assert total_lo <= overall <= total_hi


def test_filter_beats_raw_measurements() -> None:
    settings = TrackerSettings()
    rng = np.random.default_rng(3)
    truths, meas = _simulate(rng, settings, 200, 0.1, 0.05)
    tracker = Tracker(settings)
    raw_err, filt_err = [], []
    for k, (truth, z) in enumerate(zip(truths, meas, strict=True)):
        tracker.update(int(k * 0.1 * SECOND), [(z, np.eye(3) * 0.05**2)])
        est = tracker.estimate()
        assert est.position_m is not None
        if k >= 10:
            raw_err.append(np.linalg.norm(z - truth[:3]))
            filt_err.append(np.linalg.norm(est.position_m - truth[:3]))
    assert np.mean(filt_err) < 0.8 * np.mean(raw_err)


def _tracking(at: np.ndarray) -> Tracker:
    tracker = Tracker(TrackerSettings())
    for k in range(10):
        tracker.update(k * SECOND // 10, [(at, np.eye(3) * 1e-4)])
    return tracker


def test_picks_the_candidate_consistent_with_the_track() -> None:
    tracker = _tracking(np.array([5.0, 5.0, -2.0]))
    ghost = (np.array([8.0, 5.0, -2.0]), np.eye(3) * 1e-4)
    real = (np.array([5.01, 5.0, -2.0]), np.eye(3) * 1e-4)
    association = tracker.update(SECOND, [ghost, real])
    assert association.index == 1
    assert association.distance2 is not None
    assert association.distance2 < tracker.settings.gate_chi2


def test_outlier_is_gated_and_coasting_grows_covariance() -> None:
    tracker = _tracking(np.array([5.0, 5.0, -2.0]))
    before = tracker.estimate().covariance_m2
    association = tracker.update(SECOND, [(np.array([9.0, 5.0, -2.0]), np.eye(3) * 1e-4)])
    assert association.index is None
    after = tracker.estimate()
    assert after.state == "coasting"
    assert before is not None
    assert after.covariance_m2 is not None
    assert np.trace(after.covariance_m2) > np.trace(before)
    tracker.coast(SECOND + SECOND // 2)
    later = tracker.estimate().covariance_m2
    assert later is not None
    assert np.trace(later) > np.trace(after.covariance_m2)


def test_lost_after_the_configured_time_then_restarts() -> None:
    tracker = _tracking(np.array([5.0, 5.0, -2.0]))
    last = int(0.9 * SECOND)
    tracker.coast(last + int(1.9 * SECOND))
    assert tracker.estimate().state == "coasting"
    tracker.coast(last + int(2.1 * SECOND))
    lost = tracker.estimate()
    assert lost.state == "lost"
    assert lost.position_m is None
    restart = np.array([1.0, 1.0, -1.0])
    for k in range(3):
        tracker.update(last + 3 * SECOND + k * SECOND // 20, [(restart, np.eye(3) * 1e-4)])
        assert tracker.estimate().state == ("tracking" if k == 2 else "tentative")


def test_a_new_track_is_tentative_until_confirmed_and_a_lone_echo_never_confirms() -> None:
    tracker = Tracker(TrackerSettings(confirm_after=3))
    echo = (np.array([3.0, 2.0, -1.0]), np.eye(3) * 1e-4)
    tracker.update(0, [echo])
    assert tracker.estimate().state == "tentative"
    for k in range(1, 45):  # 2.2 s of nothing: the tentative track coasts, then is lost
        tracker.update(k * SECOND // 20, [])
        assert tracker.estimate().state in ("tentative", "lost")
    assert tracker.estimate().state == "lost"


def test_candidates_that_may_not_start_are_still_associated() -> None:
    clutter = (np.array([7.0, 5.0, -2.0]), np.eye(3) * 1e-4)
    tracker = Tracker(TrackerSettings())
    association = tracker.update(0, [clutter], may_start=[False])
    assert association.index is None
    assert tracker.estimate().state == "none"
    # Out of the gate of a confirmed track, repeatedly: no relocalisation onto it either.
    tracker = _tracking(np.array([5.0, 5.0, -2.0]))
    for k in range(10):
        tracker.update(SECOND + k * SECOND // 10, [clutter], may_start=[False])
    assert tracker.estimate().resets == 0
    # Inside the gate it updates the track like any fix.
    near = (np.array([5.02, 5.0, -2.0]), np.eye(3) * 1e-4)
    assert tracker.update(2 * SECOND, [near], may_start=[False]).index == 0


def test_a_track_that_coasted_takes_no_static_clutter_echo() -> None:
    """The ROV's echo missed for a while: the sandbag in the growing gate does not take it."""
    sandbag = (np.array([5.15, 5.0, -2.0]), np.eye(3) * 1e-4)
    for static, taken in ((True, False), (False, True)):
        tracker = _tracking(np.array([5.0, 5.0, -2.0]))
        start = SECOND
        for k in range(1, 11):  # 0.5 s with nothing: coasting
            tracker.update(start + k * SECOND // 20, [])
        for k in range(11, 40):
            association = tracker.update(start + k * SECOND // 20, [sandbag], static=[static])
            if association.index is not None:
                break
        assert (association.index is not None) == taken
    # A track fused on the ping before still follows an echo inside a static cell.
    tracker = _tracking(np.array([5.0, 5.0, -2.0]))
    near = (np.array([5.02, 5.0, -2.0]), np.eye(3) * 1e-4)
    assert tracker.update(SECOND + SECOND // 20, [near], static=[True]).index == 0


def test_only_fixes_that_could_start_a_track_confirm_a_tentative_one() -> None:
    """Mapped clutter after one stray start moves the tentative track but never confirms it."""
    tracker = Tracker(TrackerSettings(confirm_after=3))
    rack = np.array([9.4, 12.0, -4.0])
    tracker.update(0, [(rack, np.eye(3) * 1e-4)], may_start=[True])  # the one "moved" sighting
    for k in range(1, 40):  # 2 s of the same echo, each one refused as a start
        jitter = np.array([0.02 * (-1) ** k, 0.0, 0.0])
        association = tracker.update(
            k * SECOND // 20, [(rack + jitter, np.eye(3) * 1e-4)], may_start=[False]
        )
        assert association.index == 0  # associated: the track follows it
        assert tracker.estimate().state == "tentative"
    # Two more that could each start a track (with the first): confirmed.
    for k in range(40, 42):
        tracker.update(k * SECOND // 20, [(rack, np.eye(3) * 1e-4)], may_start=[True])
    assert tracker.estimate().state == "tracking"


def test_consistent_jump_reinitialises_and_counts_a_reset() -> None:
    settings = TrackerSettings(reinit_after=3)
    tracker = Tracker(settings)
    for k in range(10):
        tracker.update(k * SECOND // 10, [(np.array([5.0, 5.0, -2.0]), np.eye(3) * 1e-4)])
    moved = np.array([7.0, 5.0, -2.0])
    for k in range(10, 13):
        tracker.update(k * SECOND // 10, [(moved, np.eye(3) * 1e-4)])
    est = tracker.estimate()
    assert est.resets == 1
    assert est.position_m is not None
    assert np.allclose(est.position_m, moved)


def test_velocity_input_sharpens_the_velocity() -> None:
    with_velocity, without = _tracking(np.zeros(3)), _tracking(np.zeros(3))
    with_velocity.update_velocity(SECOND, np.array([0.2, 0.0, 0.0]), np.eye(3) * 1e-4)
    without.coast(SECOND)
    assert with_velocity.x[3] == pytest.approx(0.2, abs=0.01)
    assert np.trace(with_velocity.P[3:, 3:]) < np.trace(without.P[3:, 3:])


def _leg_start(settings: TrackerSettings) -> tuple[int, Tracker, float]:
    """A ROV holding 10 s, then off at 1 m/s^2 (ArduSub's default WPNAV_ACCEL) to 1 m/s.

    Fixes at 5 Hz with 20 mm noise. Returns the fixes refused, the tracker, the worst error.
    """
    rng = np.random.default_rng(0)
    tracker = Tracker(settings)
    sigma, hz, x, v = 0.02, 5.0, 0.0, 0.0
    refused, worst = 0, 0.0
    for k in range(int(30 * hz)):
        t = k / hz
        if t >= 10.0:
            v = min(1.0, v + 1.0 / hz)
        x += v / hz
        truth = np.array([x, 0.0, -3.0])
        fix = truth + rng.normal(0.0, sigma, 3)
        refused += tracker.update(int(t * SECOND), [(fix, np.eye(3) * sigma**2)]).index is None
        estimate = tracker.estimate().position_m
        assert estimate is not None
        worst = max(worst, float(np.linalg.norm(estimate - truth)))
    return refused, tracker, worst


def test_a_rov_starting_a_leg_is_followed_through_the_manoeuvre_gate() -> None:
    refused, tracker, worst = _leg_start(TrackerSettings())
    assert refused == 0
    assert tracker.resets == 0
    assert tracker.manoeuvres >= 1
    assert worst < 0.1
    # Without the manoeuvre gate the same fixes lag out of the gate: refused, relocalised.
    refused, tracker, worst = _leg_start(TrackerSettings(manoeuvre_accel_density_xy=0.0))
    assert refused > 0
    assert tracker.resets >= 1
    assert worst > 0.3


def test_the_manoeuvre_gate_takes_no_jump_and_no_clutter() -> None:
    # A holding ROV: an echo 0.5 m off one ping later is no manoeuvre a ROV makes in 0.1 s.
    tracker = _tracking(np.array([5.0, 5.0, -2.0]))
    jump = (np.array([5.5, 5.0, -2.0]), np.eye(3) * 4e-4)
    assert tracker.update(SECOND, [jump]).index is None
    assert tracker.manoeuvres == 0
    # A lagging track: the fix it refuses is taken through the manoeuvre gate only if it may
    # start a track (never static or mapped clutter), and only soon after the last fused fix.
    lagging = (np.array([5.15, 5.0, -2.0]), np.eye(3) * 1e-4)
    clutter = _tracking(np.array([5.0, 5.0, -2.0]))
    assert clutter.update(SECOND + SECOND // 10, [lagging], may_start=[False]).index is None
    assert clutter.manoeuvres == 0
    tracker = _tracking(np.array([5.0, 5.0, -2.0]))
    assert tracker.update(SECOND + SECOND // 10, [lagging]).index == 0
    assert tracker.manoeuvres == 1
    tracker = _tracking(np.array([5.0, 5.0, -2.0]))
    tracker.coast(2 * SECOND)
    assert tracker.update(2 * SECOND, [(lagging[0] + 0.5, lagging[1])]).index is None
