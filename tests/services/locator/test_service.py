"""The Locator class: input timing reasons, ghosts, association among several detections."""

from __future__ import annotations

import math
from typing import Literal

import msgspec
import numpy as np

from capsd.geometry import Transform
from capsd.mounts import SonarMountConfig
from capsd.payloads import (
    AsvPose,
    Detection,
    RovAttitude,
    RovDepth,
    RovFix,
    SonarDetections,
    SonarTilt,
)
from capsd.services.locator.service import (
    ClutterConfig,
    Config,
    InstallationConfig,
    Locator,
    MethodConfig,
    SoundSpeedConfig,
    TrackingConfig,
)
from capsd.sonar_geometry import to_polar
from capsd.sound_speed import speed_of_sound_m_s
from capsd.tank import TankBounds, TankFixture

SECOND = 1_000_000_000
IDENTITY_Q = (0.0, 0.0, 0.0, 1.0)
COV6 = tuple(float(i == j) * 1e-6 for i in range(6) for j in range(6))
ROV = np.array([8.0, 5.0, -2.0])
ASV = np.array([4.0, 5.0, 0.0])


def _feed_inputs(
    locator: Locator,
    *,
    until_s: float,
    depth_until_s: float | None = None,
    from_s: float = 0.0,
    temperature_c: float | None = None,
) -> None:
    steps = int(until_s * 50)
    depth_steps = steps if depth_until_s is None else int(depth_until_s * 50)
    for k in range(int(from_s * 50), steps + 1):
        stamp = k * SECOND // 50
        locator.on_pose(
            AsvPose(
                stamp_ns=stamp,
                seq=k,
                position_m=tuple(ASV),
                orientation_xyzw=IDENTITY_Q,
                covariance=COV6,
            )
        )
        locator.on_attitude(RovAttitude(stamp_ns=stamp, seq=k, orientation_xyzw=IDENTITY_Q))
        if k <= depth_steps:
            depth = RovDepth(
                stamp_ns=stamp,
                seq=k,
                depth_m=-float(ROV[2]),
                sigma_m=0.005,
                temperature_c=temperature_c,
            )
            locator.on_depth(depth)


def _detection_of(locator: Locator, point: np.ndarray, confidence: float = 0.9) -> Detection:
    sonar = Transform(np.eye(3), ASV).compose(locator.mount)
    r, azimuth, _ = to_polar(locator.config.sonar.beam_model, sonar.inverse().apply(point))
    return Detection(
        range_m=r,
        azimuth_rad=azimuth,
        range_sigma_m=0.01,
        azimuth_sigma_rad=math.radians(0.2),
        confidence=confidence,
    )


def _ping(
    stamp_ns: int, *detections: Detection, sound_speed_m_s: float | None = None
) -> SonarDetections:
    return SonarDetections(
        stamp_ns=stamp_ns,
        seq=0,
        ping_id=0,
        detector="t",
        detections=detections,
        sound_speed_m_s=sound_speed_m_s,
    )


def _locator(**changes: object) -> Locator:
    # Zero lever arm: the test's ROV is level, its depth is the centre's.
    config = Config(**changes)  # type: ignore[arg-type]
    return Locator(config)


def test_fix_at_the_true_position_good_once_the_track_is_confirmed() -> None:
    locator = _locator()
    _feed_inputs(locator, until_s=1.0)
    fix = locator.locate(_ping(SECOND // 2, _detection_of(locator, ROV)), seq=0)
    # One echo is not yet the ROV: a new track is tentative, its fixes unsure.
    assert (fix.quality, fix.track_state) == ("unsure", "tentative")
    assert fix.raw_position_m is not None
    assert np.allclose(fix.raw_position_m, ROV, atol=1e-6)
    assert fix.asv_pose_stamp_ns == SECOND // 2  # causal matching: the sample at the ping
    fix = locator.locate(_ping(SECOND // 2 + SECOND // 200, _detection_of(locator, ROV)), seq=1)
    assert fix.quality == "unsure"
    # Between samples, causal matching extrapolates from the two before the ping.
    fix = locator.locate(_ping(SECOND // 2 + SECOND // 100, _detection_of(locator, ROV)), seq=2)
    assert fix.asv_pose_stamp_ns == SECOND // 2
    assert (fix.quality, fix.track_state) == ("good", "tracking")
    interpolating = _locator(method=MethodConfig(preset="custom", matching="interpolate"))
    _feed_inputs(interpolating, until_s=1.0)
    ping = _ping(SECOND // 2 + SECOND // 100, _detection_of(interpolating, ROV))
    assert interpolating.locate(ping, seq=0).asv_pose_stamp_ns == SECOND // 2


def test_a_rov_in_the_beams_skirt_is_fixed_and_beyond_it_refused() -> None:
    """1.5 deg below the aperture's nominal edge: fixed with a 3 deg skirt, refused without."""
    mount = Config().sonar
    sonar_xy = ASV[:2] + np.array(mount.position_m[:2])
    drop = float(ASV[2] + mount.position_m[2] - ROV[2])
    half = mount.vertical_aperture_deg / 2.0

    def rov_at(elevation_deg: float) -> np.ndarray:
        depression = math.radians(mount.pitch_deg - elevation_deg)
        return np.array([sonar_xy[0] + drop / math.tan(depression), sonar_xy[1], ROV[2]])

    def fix_of(locator: Locator, point: np.ndarray) -> RovFix:
        _feed_inputs(locator, until_s=1.0)
        return locator.locate(_ping(SECOND // 2, _detection_of(locator, point)), seq=0)

    in_skirt = rov_at(-(half + 1.5))
    fix = fix_of(_locator(aperture_skirt_deg=3.0), in_skirt)
    assert fix.raw_position_m is not None
    assert np.allclose(fix.raw_position_m, in_skirt, atol=1e-6)
    assert fix_of(_locator(), in_skirt).no_fix_reason == "outside_aperture"
    beyond = rov_at(-(half + 4.0))
    assert fix_of(_locator(aperture_skirt_deg=3.0), beyond).no_fix_reason == "outside_aperture"


def test_an_extrapolated_depth_widens_the_vertical_uncertainty() -> None:
    """Depth readings stop at 0.5 s: a ping 0.1 s later uses one extrapolated 5 gaps on."""
    locator = _locator()
    _feed_inputs(locator, until_s=1.0)
    at_reading = locator.locate(_ping(SECOND // 2, _detection_of(locator, ROV)), seq=0)
    fresh = _locator()
    _feed_inputs(fresh, until_s=0.6, depth_until_s=0.5)  # pose and attitude go on
    late = fresh.locate(_ping(SECOND // 2 + SECOND // 10, _detection_of(fresh, ROV)), seq=0)
    assert at_reading.raw_covariance_m2 is not None
    assert late.raw_covariance_m2 is not None
    # z variance: the covariance floor plus the depth's 5 mm, then 5 mm x hypot(6, 5) = 39 mm.
    floor = Config().unmodelled_sigma_m ** 2
    assert math.isclose(at_reading.raw_covariance_m2[8] - floor, 0.005**2, rel_tol=0.05)
    assert math.isclose(
        late.raw_covariance_m2[8] - floor, (0.005 * math.hypot(6, 5)) ** 2, rel_tol=0.05
    )


def test_ranges_are_rescaled_to_the_water_the_rov_s_thermometer_reads() -> None:
    # The sonar assumed 1480 m/s; the water is at 28 degC (1503 m/s): every range it reports
    # is 1.5 % short, about 10 cm here. The ROV's thermometer puts the fix back on the ROV.
    water = speed_of_sound_m_s(28.0, salinity_ppt=0.0)

    def raw_fix(locator: Locator, *, temperature_c: float | None) -> RovFix:
        _feed_inputs(locator, until_s=1.0, temperature_c=temperature_c)
        true = _detection_of(locator, ROV)
        reported = msgspec.structs.replace(true, range_m=true.range_m * 1480.0 / water)
        return locator.locate(_ping(SECOND // 2, reported, sound_speed_m_s=1480.0), seq=0)

    corrected = _locator()
    fix = raw_fix(corrected, temperature_c=28.0)
    assert fix.raw_position_m is not None
    assert np.linalg.norm(np.subtract(fix.raw_position_m, ROV)) < 1e-6
    assert corrected.counters()["water_speed_pings"] == 1
    as_reported = _locator(sound_speed=SoundSpeedConfig(source="sonar"))
    fix = raw_fix(as_reported, temperature_c=28.0)
    assert fix.raw_position_m is not None
    assert np.linalg.norm(np.subtract(fix.raw_position_m, ROV)) > 0.05
    # No temperature with the depth: the sonar's ranges, counted.
    unknown = _locator()
    fix = raw_fix(unknown, temperature_c=None)
    assert fix.raw_position_m is not None
    assert np.linalg.norm(np.subtract(fix.raw_position_m, ROV)) > 0.05
    assert unknown.counters()["sonar_speed_pings"] == 1
    assert unknown.counters()["water_speed_pings"] == 0
    assert corrected.counters()["sonar_speed_pings"] == 0


def test_the_calibrated_range_offset_is_added_to_every_detection_s_range() -> None:
    # The detector's ranges 25 mm long (its echo's range bias): calibrated, the fix is the ROV.
    def miss_m(locator: Locator) -> float:
        _feed_inputs(locator, until_s=1.0)
        true = _detection_of(locator, ROV)
        long = msgspec.structs.replace(true, range_m=true.range_m + 0.025)
        fix = locator.locate(_ping(SECOND // 2, long), seq=0)
        assert fix.raw_position_m is not None
        return float(np.linalg.norm(np.subtract(fix.raw_position_m, ROV)))

    assert miss_m(_locator()) > 0.02
    assert miss_m(_locator(sonar=SonarMountConfig(range_offset_m=-0.025))) < 1e-6


def test_a_detection_unsure_of_its_range_gives_no_fix_and_is_counted() -> None:
    # The same echo four pings running: with a 1 cm range sigma the track is confirmed and
    # good; with 8 cm (the refiner's answer on a ROV over clutter) no fix is made at all.
    def fixes(range_sigma_m: float, **changes: object) -> tuple[list[RovFix], Locator]:
        locator = _locator(**changes)
        _feed_inputs(locator, until_s=1.0)
        echo = msgspec.structs.replace(_detection_of(locator, ROV), range_sigma_m=range_sigma_m)
        out = [
            locator.locate(_ping(SECOND // 2 + k * SECOND // 100, echo), seq=k) for k in range(4)
        ]
        return out, locator

    sure, locator = fixes(0.01)
    assert sure[-1].quality == "good"
    assert locator.counters()["uncertain_detections"] == 0
    unsure, locator = fixes(0.08)
    assert all(f.quality == "invalid" for f in unsure)
    assert {f.no_fix_reason for f in unsure} == {"detection_uncertain"}
    assert locator.counters()["uncertain_detections"] == 4
    # The limit is the config's: None uses every detection.
    allowed, _ = fixes(0.08, max_range_sigma_m=None)
    assert allowed[-1].quality == "good"


def test_the_thermometer_s_sigma_goes_into_the_covariance_in_place_of_the_range_scale() -> None:
    # Told the sonar's speed may be 1 % off, the fix's range variance is large; rescaled to the
    # water's speed, what is left is the thermometer's 0.5 degC (about 0.09 %).
    def range_variance(source: Literal["rov_thermometer", "sonar"]) -> float:
        locator = _locator(
            installation=InstallationConfig(range_scale=0.01),
            sound_speed=SoundSpeedConfig(source=source, thermometer_sigma_c=0.5),
            unmodelled_sigma_m=0.0,
        )
        _feed_inputs(locator, until_s=1.0, temperature_c=20.0)
        ping = _ping(SECOND // 2, _detection_of(locator, ROV), sound_speed_m_s=1482.0)
        fix = locator.locate(ping, seq=0)
        assert fix.raw_covariance_m2 is not None
        assert fix.raw_position_m is not None
        along = np.subtract(fix.raw_position_m, ASV)[:2]
        along = np.append(along / np.linalg.norm(along), 0.0)
        return float(along @ np.array(fix.raw_covariance_m2).reshape(3, 3) @ along)

    told_sonar, told_water = range_variance("sonar"), range_variance("rov_thermometer")
    # 1 % of about 4.5 m is 45 mm along the ground; the solver's own 10 mm stays in both.
    assert math.sqrt(told_sonar) > 0.04
    assert math.sqrt(told_water) < 0.015


def test_stale_and_missing_inputs_give_reasons_not_fixes() -> None:
    empty = _locator()
    fix = empty.locate(_ping(SECOND, _detection_of(empty, ROV)), seq=0)
    assert fix.quality == "invalid"
    assert fix.no_fix_reason is not None
    assert "asv_pose_no_samples" in fix.no_fix_reason

    locator = _locator()
    _feed_inputs(locator, until_s=1.0)
    late = locator.locate(_ping(2 * SECOND, _detection_of(locator, ROV)), seq=1)
    assert late.quality == "invalid"
    assert late.no_fix_reason is not None
    assert "asv_pose_too_new" in late.no_fix_reason
    early = locator.locate(_ping(-SECOND, _detection_of(locator, ROV)), seq=2)
    assert early.no_fix_reason is not None
    assert "too_old" in early.no_fix_reason


def test_ghost_outside_the_tank_is_dropped() -> None:
    locator = _locator(tank=TankBounds(length_m=6.0, width_m=16.0, depth_m=8.0, margin_m=0.1))
    _feed_inputs(locator, until_s=1.0)
    fix = locator.locate(_ping(SECOND // 2, _detection_of(locator, ROV)), seq=0)
    assert fix.quality == "invalid"
    assert fix.no_fix_reason == "outside_tank"


def test_association_prefers_the_track_over_a_more_confident_ghost() -> None:
    locator = _locator()
    _feed_inputs(locator, until_s=3.0)
    for k in range(10):
        locator.locate(_ping(k * SECOND // 10, _detection_of(locator, ROV)), seq=k)
    ghost = _detection_of(locator, ROV + np.array([2.5, 1.0, 0.0]), confidence=0.99)
    real = _detection_of(locator, ROV, confidence=0.6)
    fix = locator.locate(_ping(SECOND + SECOND // 10, ghost, real), seq=11)
    assert fix.candidates == 2
    assert fix.quality == "good"
    assert fix.raw_position_m is not None
    assert np.allclose(fix.raw_position_m, ROV, atol=1e-6)


def _ghost_then_loss(locator: Locator) -> list[str]:
    """8 s tracking the ROV with a static echo 1.6 m off in every ping, then only the echo."""
    ghost = ROV + np.array([0.5, 1.5, 0.0])
    qualities = []
    for k in range(140):  # 10 Hz
        stamp = k * SECOND // 10
        _feed_inputs(locator, from_s=k / 10, until_s=(k + 1) / 10)
        seen = [_detection_of(locator, ghost, confidence=0.8)]
        if k < 80:
            seen.append(_detection_of(locator, ROV))
        fix = locator.locate(_ping(stamp, *seen), seq=k)
        if k >= 80:
            qualities.append(f"{fix.quality}:{fix.no_fix_reason}")
    return qualities


def test_a_static_echo_learned_while_tracking_never_restarts_the_track() -> None:
    locator = _locator()
    after_loss = _ghost_then_loss(locator)
    assert not any(q.startswith("good") for q in after_loss)
    assert after_loss[-1] == "invalid:static_clutter"
    assert locator.clutter_refusals > 0
    # Without the clutter map the lost track restarts on the echo; 1.6 m off where the ROV was
    # lost 2 s before, it is an unproven relocation, unsure; with neither rule, called good.
    unmapped = _locator(clutter=ClutterConfig(mode="off"))
    assert not any(q.startswith("good") for q in _ghost_then_loss(unmapped))
    assert unmapped.relocation.started == 1
    blind = _locator(clutter=ClutterConfig(mode="off"), tracking=TrackingConfig(relocation="off"))
    assert any(q.startswith("good") for q in _ghost_then_loss(blind))


def _rov_stops_beside_a_sandbag(locator: Locator) -> list[tuple[float, str, float | None]]:
    """The ROV stops 0.6 m from a sandbag; its echo is missed for 1.5 s as it arrives.

    It flies 3 m along y at 0.25 m/s; the sandbag is seen from the second second on, its echo
    not missed; the ROV's is seen again, held, after the 1.5 s. Each ping from the arrival:
    (time, quality:reason, the fix's distance from the ROV).
    """
    stop = ROV
    sandbag = stop + np.array([0.25, 0.55, 0.0])
    out = []
    for k in range(250):  # 10 Hz, 25 s
        t = k / 10
        stamp = k * SECOND // 10
        rov = stop + np.array([0.0, -3.0 + min(0.25 * t, 3.0), 0.0])
        _feed_inputs(locator, from_s=t, until_s=t + 0.1)
        seen = [_detection_of(locator, sandbag, confidence=0.6)] if t >= 1.0 else []
        if not 12.0 <= t < 13.5:
            seen.append(_detection_of(locator, rov))
        fix = locator.locate(_ping(stamp, *seen), seq=k)
        if t >= 12.0:
            where = fix.position_m or fix.raw_position_m
            off = None if where is None else float(np.linalg.norm(np.array(where) - rov))
            out.append((t, f"{fix.quality}:{fix.no_fix_reason}", off))
    return out


def test_a_rov_held_beside_learned_clutter_is_not_taken_for_it_and_is_found_again() -> None:
    """Its mission pauses as the fix goes: the ROV holds just where the clutter hid it."""
    pings = _rov_stops_beside_a_sandbag(_locator())
    good = [(t, off) for t, q, off in pings if q.startswith("good")]
    # Never the sandbag's echo called the ROV while its own was missed ...
    assert all(off is not None and off < 0.1 for _, off in good), good
    # ... and its own echo, seen again beside the sandbag, is the ROV again within 1 s.
    assert good, pings[:40]
    assert good[0][0] <= 14.5, pings[:40]
    assert all(q.startswith("good") for t, q, _ in pings if t >= 14.5)


def test_an_echo_a_mapped_fixture_explains_never_starts_a_track() -> None:
    """A rack top in the echo's range cell (same range and bearing, lower): it may be the rack."""
    rack = TankFixture(name="rack", lo_m=(7.5, 4.5, -3.5), hi_m=(8.8, 5.5, -3.0))
    tank = TankBounds(fixtures=(rack,))
    modes = (("refuse_start", False), ("refuse_unless_moving", False), ("off", True))
    for mode, expect_start in modes:
        locator = _locator(tank=tank, clutter=ClutterConfig(map_explained=mode))  # type: ignore[arg-type]
        started = False
        for k in range(10):
            stamp = k * SECOND // 10
            _feed_inputs(locator, from_s=k / 10, until_s=(k + 1) / 10)
            fix = locator.locate(_ping(stamp, _detection_of(locator, ROV)), seq=k)
            started = started or fix.track_state in ("tentative", "tracking")
            if not expect_start:
                assert fix.no_fix_reason == "map_clutter", fix
        assert started == expect_start
    # The same echo with the rack elsewhere in the tank starts a track.
    elsewhere = TankFixture(name="rack", lo_m=(20.0, 10.0, -8.0), hi_m=(22.0, 12.0, -5.0))
    open_water = _locator(tank=TankBounds(fixtures=(elsewhere,)))
    _feed_inputs(open_water, until_s=1.0)
    assert (
        open_water.locate(_ping(SECOND // 2, _detection_of(open_water, ROV)), seq=0).track_state
        == "tentative"
    )


def test_an_echo_over_a_rack_that_moves_as_no_fixture_can_starts_a_track() -> None:
    """The ROV flies along a rack at 0.3 m/s: its echo shares the rack's cells all the way."""
    rack = TankFixture(name="rack", lo_m=(7.0, 3.0, -3.5), hi_m=(9.0, 8.0, -3.0))
    tank = TankBounds(fixtures=(rack,))
    outcomes = {}
    for mode in ("refuse_start", "refuse_unless_moving"):
        locator = _locator(tank=tank, clutter=ClutterConfig(map_explained=mode))
        states = []
        for k in range(40):  # 4 s at 10 Hz
            stamp = k * SECOND // 10
            _feed_inputs(locator, from_s=k / 10, until_s=(k + 1) / 10)
            rov = ROV + np.array([0.0, -1.0 + 0.3 * k / 10, 0.0])
            fix = locator.locate(_ping(stamp, _detection_of(locator, rov)), seq=k)
            states.append(f"{fix.track_state}:{fix.no_fix_reason}")
        outcomes[mode] = states
    assert set(outcomes["refuse_start"]) == {"none:map_clutter"}
    moving = outcomes["refuse_unless_moving"]
    first = next(k for k, s in enumerate(moving) if s != "none:map_clutter")
    assert 10 <= first <= 25, moving  # followed for 1 s, then 0.3 m from any static source
    assert moving[-1] == "tracking:None", moving


def _lost_then_over_the_rack(
    locator: Locator, *, hidden_s: float, seen_s: float = 1.0
) -> list[str]:
    """Tracked 1.5 m beside the rack for 2 s, unseen for `hidden_s`, then seen over the rack."""
    beside = ROV + np.array([0.0, 1.5, 0.0])
    states = []
    steps_before, hidden = 20, round(hidden_s * 10)
    for k in range(steps_before + hidden + round(seen_s * 10)):  # 10 Hz
        stamp = k * SECOND // 10
        _feed_inputs(locator, from_s=k / 10, until_s=(k + 1) / 10)
        if k < steps_before:
            seen = [_detection_of(locator, beside)]
        elif k < steps_before + hidden:
            seen = []
        else:
            seen = [_detection_of(locator, ROV)]
        fix = locator.locate(_ping(stamp, *seen), seq=k)
        if k >= steps_before + hidden:
            states.append(f"{fix.track_state}:{fix.no_fix_reason}")
    return states


def test_a_rov_lost_over_a_rack_is_found_again_where_it_was_last_confirmed() -> None:
    rack = TankFixture(name="rack", lo_m=(7.5, 4.5, -3.5), hi_m=(8.8, 5.5, -3.0))
    tank = TankBounds(fixtures=(rack,))
    # 6 s unseen: 1.5 m from the last confirmed fix of a ROV holding still is within where it
    # could be (0.5 m + 0.2 m/s x 6 s, `tracking.reach_*`).
    found = _lost_then_over_the_rack(_locator(tank=tank), hidden_s=6.0)
    assert found[-1].startswith("tracking"), found
    # Without the rule, or too long unseen to say it is the same ROV: the rack's echo, refused.
    never = _locator(tank=tank, clutter=ClutterConfig(reacquire_window_s=0.0))
    assert set(_lost_then_over_the_rack(never, hidden_s=6.0)) == {"lost:map_clutter"}
    stale = _locator(tank=tank, clutter=ClutterConfig(reacquire_window_s=5.0))
    assert set(_lost_then_over_the_rack(stale, hidden_s=6.0)) == {"lost:map_clutter"}
    # Too far for the time unseen (0.5 m + 0.2 m/s x 3 s = 1.1 m < 1.5 m): refused until the ROV
    # could have come that far (5 s after its last confirmed fix).
    fast = _lost_then_over_the_rack(_locator(tank=tank), hidden_s=3.0, seen_s=3.0)
    assert fast[:15] == ["lost:map_clutter"] * 15, fast
    assert fast[-1].startswith("tracking"), fast


def test_a_ping_past_the_newest_pose_is_one_to_wait_for() -> None:
    """pose_covers is what a ping waits on (services/locator/waiting.py)."""
    locator = _locator()
    assert not locator.pose_covers(SECOND)  # no pose at all yet
    _feed_inputs(locator, until_s=1.0)
    assert locator.pose_covers(SECOND)
    assert locator.pose_covers(SECOND + SECOND // 10)  # within the 0.15 s extrapolation
    assert not locator.pose_covers(2 * SECOND)  # the pose it needs is still on its way
    _feed_inputs(locator, from_s=1.0, until_s=2.0)
    assert locator.pose_covers(2 * SECOND)
    fix = locator.locate(_ping(2 * SECOND, _detection_of(locator, ROV)), seq=0)
    assert fix.no_fix_reason is None or "asv_pose" not in fix.no_fix_reason


def _lost_then_elsewhere(
    locator: Locator,
    *,
    echo_m: np.ndarray,
    echo_speed_m_s: float = 0.0,
    rov_back_after_s: float | None = None,
    seen_s: float = 8.0,
) -> list[RovFix]:
    """Tracked holding at ROV for 3 s, unseen 5 s, then an echo at `echo_m`, and the ROV again.

    The echo moves along x at `echo_speed_m_s`; the ROV is seen where it was lost from
    `rov_back_after_s` after the echo's first sighting.
    """
    fixes = []
    for k in range(80 + round(seen_s * 10)):  # 10 Hz
        stamp = k * SECOND // 10
        _feed_inputs(locator, from_s=k / 10, until_s=(k + 1) / 10)
        seen = []
        if k < 30:
            seen.append(_detection_of(locator, ROV))
        elif k >= 80:
            since_s = (k - 80) / 10
            echo = echo_m + np.array([echo_speed_m_s * since_s, 0.0, 0.0])
            seen.append(_detection_of(locator, echo))
            if rov_back_after_s is not None and since_s >= rov_back_after_s:
                seen.append(_detection_of(locator, ROV))
        fix = locator.locate(_ping(stamp, *seen), seq=k)
        if k >= 80:
            fixes.append(fix)
    return fixes


def test_a_track_far_from_where_the_rov_was_lost_is_unsure_until_it_persists() -> None:
    """An unmapped static echo 2.1 m from where the ROV was lost 5 s before.

    Session 34's demo: confirmed on 3 hits, good for 8 s, 2.2-4.5 m off; ArduSub flew 1.5 m
    off its lane.
    """
    echo = ROV + np.array([0.0, -2.1, 0.0])
    wary = _locator(tracking=TrackingConfig(relocate_confirm_s=4.0))
    fixes = _lost_then_elsewhere(wary, echo_m=echo)
    good = [k for k, f in enumerate(fixes) if f.quality == "good"]
    # 0.5 m + 0.2 m/s x 5 s = 1.5 m < 2.1 m: the ROV could not be there; good only after 4 s.
    assert good, [f"{f.quality}:{f.track_state}" for f in fixes]
    assert good[0] == 40, [f"{f.quality}:{f.track_state}" for f in fixes]
    assert {f.track_state for f in fixes[:40]} == {"tentative"}
    assert wary.counters()["relocations"] == 1
    assert wary.counters()["relocations_waited"] == 1
    # Hits alone: good on the third ping.
    trusting = _locator(tracking=TrackingConfig(relocation="off"))
    fixes = _lost_then_elsewhere(trusting, echo_m=echo)
    assert [f.quality for f in fixes[:3]] == ["unsure", "unsure", "good"]
    # Where the ROV could be (1.2 m off after 5 s): confirmed on hits as before.
    near = _lost_then_elsewhere(_locator(), echo_m=ROV + np.array([0.0, -1.2, 0.0]))
    assert [f.quality for f in near[:3]] == ["unsure", "unsure", "good"]


def test_the_rov_reappearing_where_it_was_lost_takes_over_a_far_track() -> None:
    echo = ROV + np.array([0.0, -2.1, 0.0])
    locator = _locator()
    fixes = _lost_then_elsewhere(locator, echo_m=echo, rov_back_after_s=2.0)
    assert all(f.quality != "good" for f in fixes[:20])
    back = fixes[20:]
    assert back[0].raw_position_m is not None
    assert np.allclose(back[0].raw_position_m, ROV, atol=0.05)  # taken over on its first ping
    assert back[2].quality == "good"  # then confirmed on hits
    assert all(
        f.quality != "good" or np.linalg.norm(np.array(f.position_m) - ROV) < 0.1 for f in fixes
    )
    assert locator.counters()["relocations_taken_over"] == 1


def test_a_far_track_whose_echo_moves_as_a_rov_is_proven_by_it() -> None:
    """The pilot flew the ROV 3 m off while it was unseen; it is seen moving at 0.3 m/s."""
    locator = _locator()
    fixes = _lost_then_elsewhere(
        locator, echo_m=ROV + np.array([-1.0, -3.0, 0.0]), echo_speed_m_s=0.3
    )
    good = [k for k, f in enumerate(fixes) if f.quality == "good"]
    # Followed at least 1 s and 10 sightings, then 0.3 m from where a static source would be.
    assert good, [f.quality for f in fixes]
    assert 10 <= good[0] <= 25, [f.quality for f in fixes]
    assert locator.counters()["relocations_moved"] == 1
    # Held still there, it would wait the full relocate_confirm_s (20 s).
    still = _lost_then_elsewhere(_locator(), echo_m=ROV + np.array([-1.0, -3.0, 0.0]))
    assert all(f.quality != "good" for f in still)


def test_a_sonar_on_a_tilt_servo_is_fixed_through_the_angle_reported_for_its_ping() -> None:
    """The ping's H_B_S has the servo's angle; without a fresh angle there is no fix."""
    servo = msgspec.convert({"pitch_deg": 20.0, "tilt": {"max_age_s": 0.5}}, SonarMountConfig)
    locator = _locator(sonar=servo)
    _feed_inputs(locator, until_s=2.0)
    # Tilted 12 deg down, the sonar saw the ROV where this echo says.
    tilt = math.radians(12.0)
    rov = np.array([7.0, 7.5, ROV[2]])  # off the boresight: there the pitch matters
    seen_by = Transform(np.eye(3), ASV).compose(servo.transform(tilt_rad=tilt))
    r, azimuth, elevation = to_polar(servo.beam_model, seen_by.inverse().apply(rov))
    echo = Detection(range_m=r, azimuth_rad=azimuth, range_sigma_m=0.01,
                     azimuth_sigma_rad=math.radians(0.2), confidence=0.9)  # fmt: skip
    assert abs(elevation) < math.radians(10.0)
    no_angle = locator.locate(_ping(SECOND // 2, echo), seq=0)
    assert no_angle.quality == "invalid"
    assert no_angle.no_fix_reason is not None
    assert "sonar_tilt_no_samples" in no_angle.no_fix_reason
    for k in range(0, 21):  # 10 reports a second from 0.5 s to 2.5 s
        locator.on_tilt(SonarTilt(stamp_ns=SECOND // 2 + k * SECOND // 10, seq=k, tilt_rad=tilt))
    fix = locator.locate(_ping(SECOND, echo), seq=1)
    assert fix.raw_position_m is not None
    assert np.allclose(fix.raw_position_m, rov, atol=1e-6)
    # The same echo through the servo's zero lands elsewhere (or nowhere): the angle mattered.
    fixed = _locator(sonar=msgspec.structs.replace(servo, tilt=None))
    _feed_inputs(fixed, until_s=2.0)
    other = fixed.locate(_ping(SECOND, echo), seq=0)
    assert other.raw_position_m is None or not np.allclose(other.raw_position_m, rov, atol=0.05)
    # Reports stopped at 2.5 s: a ping 0.6 s later has no angle young enough (max_age_s 0.5).
    _feed_inputs(locator, from_s=2.0, until_s=3.5)
    stale = locator.locate(_ping(3 * SECOND + SECOND // 10, echo), seq=2)
    assert stale.no_fix_reason is not None
    assert "sonar_tilt_too_new" in stale.no_fix_reason


def _seen_through_servos(
    servo: SonarMountConfig, tilt: float, pan: float, off_deg: float
) -> tuple[np.ndarray, Detection, float]:
    """A ROV 3 m off, `off_deg` beyond the panned boresight's bearing, at ROV's depth.

    Where it is, its echo through the servos at `tilt` and `pan` (a level ASV at ASV), and its
    elevation in the sonar.
    """
    seen_by = Transform(np.eye(3), ASV).compose(servo.transform(tilt_rad=tilt, pan_rad=pan))
    bearing = pan + math.radians(off_deg)
    rov = ASV + np.array([3.0 * math.cos(bearing), 3.0 * math.sin(bearing), 0.0])
    rov[2] = ROV[2]
    r, azimuth, elevation = to_polar(servo.beam_model, seen_by.inverse().apply(rov))
    echo = Detection(range_m=r, azimuth_rad=azimuth, range_sigma_m=0.01,
                     azimuth_sigma_rad=math.radians(0.2), confidence=0.9)  # fmt: skip
    return rov, echo, elevation


def test_a_sonar_on_a_pan_servo_is_fixed_through_the_pan_reported_for_its_ping() -> None:
    """A pan turns the sonar about the body's z through its mount: the fix follows the pan."""
    servo = msgspec.convert(
        {"pitch_deg": 20.0, "tilt": {"max_age_s": 0.5}, "pan": {}}, SonarMountConfig
    )
    locator = _locator(sonar=servo)
    _feed_inputs(locator, until_s=2.0)
    tilt, pan = math.radians(12.0), math.radians(50.0)
    rov, echo, elevation = _seen_through_servos(servo, tilt, pan, off_deg=6.0)
    assert abs(elevation) < math.radians(10.0)
    for k in range(0, 21):
        stamp = SECOND // 2 + k * SECOND // 10
        locator.on_tilt(SonarTilt(stamp_ns=stamp, seq=k, tilt_rad=tilt, pan_rad=pan))
    fix = locator.locate(_ping(SECOND, echo), seq=0)
    assert fix.raw_position_m is not None
    assert np.allclose(fix.raw_position_m, rov, atol=1e-6)
    # A mount without the pan takes the tilt alone (its reports' pan is not its own).
    tilt_only = _locator(sonar=msgspec.structs.replace(servo, pan=None))
    _feed_inputs(tilt_only, until_s=2.0)
    for k in range(0, 21):
        stamp = SECOND // 2 + k * SECOND // 10
        tilt_only.on_tilt(SonarTilt(stamp_ns=stamp, seq=k, tilt_rad=tilt, pan_rad=pan))
    other = tilt_only.locate(_ping(SECOND, echo), seq=0)
    assert other.raw_position_m is None or not np.allclose(other.raw_position_m, rov, atol=0.05)


def test_a_ping_while_the_pan_slews_is_fixed_through_where_the_pan_is_not_where_it_goes() -> None:
    """Told 50 deg after 0.9 s, reported at 1.0 s: a 60 deg/s pan is at 15 deg at 1.2 s.

    (The new angle is taken half way between the reports, 0.95 s; capsd.servo_motion.)
    """
    servo = msgspec.convert(
        {"pitch_deg": 20.0, "tilt": {"max_age_s": 0.5}, "pan": {"rate_deg_s": 60.0}},
        SonarMountConfig,
    )
    locator = _locator(sonar=servo)
    _feed_inputs(locator, until_s=2.0)
    tilt = math.radians(12.0)
    for k in range(0, 16):  # 10 reports a second from 0.5 s: 0 deg, then 50 deg from 1.0 s
        stamp = SECOND // 2 + k * SECOND // 10
        pan = 0.0 if stamp < SECOND else math.radians(50.0)
        locator.on_tilt(SonarTilt(stamp_ns=stamp, seq=k, tilt_rad=tilt, pan_rad=pan))
    at = math.radians(15.0)  # 0.25 s at 60 deg/s
    rov, echo, _ = _seen_through_servos(servo, tilt, at, off_deg=4.0)
    fix = locator.locate(_ping(SECOND + SECOND // 5, echo), seq=0)
    assert fix.raw_position_m is not None
    assert np.allclose(fix.raw_position_m, rov, atol=1e-6)
