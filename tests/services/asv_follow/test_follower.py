"""Follower: nothing outside GUIDED, no jump at hand-over, dead band, holding, limits."""

from __future__ import annotations

import math
from collections.abc import Callable

import msgspec
import numpy as np
import pytest

from capsd.bench import search
from capsd.geometry import wrap_angle
from capsd.mounts import SonarMountConfig
from capsd.services.asv_follow import follower as follower_module
from capsd.services.asv_follow.follower import Follower, FollowSettings, Target
from capsd.services.asv_follow.station import STAY_M, Station, StationPlanner, StationSettings
from capsd.tank import TankBounds

START = np.array([10.0, 8.0])


def _follower(**changes: object) -> Follower:
    planner = StationPlanner(SonarMountConfig(), TankBounds(), StationSettings())
    follower = Follower(planner, FollowSettings(**changes))  # type: ignore[arg-type]
    follower.on_pose(START, 0.0)
    return follower


def test_nothing_is_commanded_unless_the_pilot_chose_guided() -> None:
    follower = _follower()
    follower.on_fix(0.0, np.array([20.0, 8.0, -3.5]))
    for mode in (None, "MANUAL", "HOLD", "LOITER"):
        follower.on_mode(mode)
        assert follower.step(0.0) is None


def test_hand_over_starts_where_the_asv_is_and_moves_within_the_limits() -> None:
    follower = _follower(max_speed_m_s=0.3, max_accel_m_s2=0.1, max_yaw_rate_rad_s=0.2)
    follower.on_mode("GUIDED")
    rov = np.array([20.0, 6.0, -3.5])
    follower.on_fix(0.0, rov)
    first = follower.step(0.0)
    assert first is not None
    assert np.allclose(first.position_xy, START)
    assert first.heading_rad == 0.0
    assert first.replanned
    assert first.state == "following"
    previous, speed = first, 0.0
    for k in range(1, 400):  # 40 s at 10 Hz
        now = k * 0.1
        follower.on_fix(now, rov)
        target = follower.step(now)
        assert target is not None
        step = float(np.linalg.norm(target.position_xy - previous.position_xy))
        assert step <= 0.3 * 0.1 + 1e-9
        station = follower.station
        assert station is not None
        if not np.allclose(target.position_xy, station.position_xy):  # (the last step stops)
            assert abs((step / 0.1) - speed) <= 0.1 * 0.1 + 1e-9  # acceleration limit
        assert abs(target.heading_rad - previous.heading_rad) <= 0.2 * 0.1 + 1e-9
        previous, speed = target, step / 0.1
    station = follower.station
    assert station is not None
    assert np.allclose(previous.position_xy, station.position_xy)  # arrived
    view = follower.planner.view(station.position_xy, station.heading_rad, rov)
    assert abs(view.elevation_rad) < math.radians(0.5)


def test_small_rov_motion_does_not_move_the_station_and_large_motion_does() -> None:
    follower = _follower()
    follower.on_mode("GUIDED")
    rov = np.array([16.0, 8.0, -3.5])
    follower.on_fix(0.0, rov)
    follower.step(0.0)
    chosen = follower.replans
    rng = np.random.default_rng(1)
    for k in range(1, 200):  # 20 s of fixes jittering by 5 cm and drifting 0.3 m
        now = k * 0.1
        follower.on_fix(now, rov + np.array([0.3 * k / 200, 0.0, 0.0]) + rng.normal(0, 0.05, 3))
        follower.step(now)
    assert follower.replans == chosen
    follower.on_fix(21.0, rov + np.array([0.0, 4.0, 0.0]))  # well off the boresight
    follower.step(21.0)
    assert follower.replans == chosen + 1


def test_a_station_chosen_off_the_target_elevation_is_kept() -> None:
    """The dead band is round the station's own view: no new station every replan period."""
    rov = np.array([16.0, 8.0, -3.5])
    # The target's view is not feasible (the target beyond the aperture): the planner can only
    # choose views well off it, as where a rack masks the ROV at the target elevation.
    planner = StationPlanner(
        SonarMountConfig(),
        TankBounds(),
        StationSettings(target_elevation_rad=math.radians(-12.0)),
    )
    follower = Follower(planner, FollowSettings(elevation_tolerance_rad=math.radians(2.0)))
    follower.on_pose(START, 0.0)
    follower.on_mode("GUIDED")
    follower.on_fix(0.0, rov)
    follower.step(0.0)
    assert follower.station is not None
    assert abs(follower.station.view.elevation_rad - math.radians(-12.0)) > math.radians(2.0)
    chosen = follower.replans
    for k in range(1, 100):  # 10 s of the ROV hovering where it was
        follower.on_fix(k * 0.1, rov)
        follower.step(k * 0.1)
    assert follower.replans == chosen


def test_without_a_fix_it_holds_then_looks_again_from_another_bearing() -> None:
    follower = _follower(fix_timeout_s=1.0, reacquire_after_s=6.0)
    follower.on_mode("GUIDED")
    follower.on_fix(0.0, np.array([20.0, 6.0, -3.5]))
    follower.step(0.0)
    first = follower.station
    assert first is not None
    held = [follower.step(k * 0.1) for k in range(11, 60)]  # 1.1 s to 5.9 s: holding
    assert all(t is not None and t.state == "holding" for t in held)
    assert follower.station is first
    assert follower.replans == 1
    # Lost for 6 s, but the hull is still on its way to the station chosen to see the ROV.
    follower.step(6.0)
    assert follower.station is first
    assert follower.looks == 0
    # Once there and watched for 2 s (SEARCH_DWELL_S), it looks again.
    k, arrived_s = 61, None
    while follower.looks == 0 and k < 600:
        target = follower.step(k * 0.1)
        assert target is not None
        follower.on_pose(target.position_xy, target.heading_rad)  # an ASV on its target
        there = np.allclose(target.position_xy, first.position_xy, atol=0.05)
        if arrived_s is None and there and abs(target.heading_rad - first.heading_rad) < 0.08:
            arrived_s = k * 0.1
        k += 1
    looked_s = (k - 1) * 0.1
    assert arrived_s is not None
    assert arrived_s + 2.0 - 1e-9 <= looked_s <= arrived_s + 2.2
    second = follower.station
    assert second is not None
    assert second is not first
    assert follower.looks == 1
    turned = math.atan2(
        math.sin(second.heading_rad - first.heading_rad),
        math.cos(second.heading_rad - first.heading_rad),
    )
    assert abs(turned) >= math.radians(40.0) - 1e-9
    view = follower.planner.view(
        second.position_xy, second.heading_rad, np.array([20.0, 6.0, -3.5])
    )
    assert follower.planner.view_is_good(view)
    follower.step(looked_s + 3.0)
    assert follower.looks == 1  # not again before another 6 s
    # A pilot's mode change forgets the hand-over: back in GUIDED it starts where the ASV is.
    follower.on_mode("MANUAL")
    follower.on_pose(np.array([12.0, 9.0]), 0.5)
    follower.on_mode("GUIDED")
    target = follower.step(looked_s + 25.0)
    assert target is not None
    assert np.allclose(target.position_xy, [12.0, 9.0])
    assert target.heading_rad == 0.5


def test_a_rov_lost_out_of_the_stations_view_is_looked_for_at_once() -> None:
    """The ROV ran under the ASV (too steep for the aperture) and was lost: no 6 s wait."""
    follower = _follower(fix_timeout_s=1.0, reacquire_after_s=6.0, replan_after_s=1.0)
    follower.on_mode("GUIDED")
    follower.on_fix(0.0, np.array([20.0, 6.0, -3.5]))
    follower.step(0.0)
    first = follower.station
    assert first is not None
    # The last good fix: 1.5 m nearer the station than the ROV was, then nothing.
    toward = (first.position_xy - np.array([20.0, 6.0])) / np.linalg.norm(
        first.position_xy - np.array([20.0, 6.0])
    )
    last = np.array([*(np.array([20.0, 6.0]) + 1.5 * toward), -3.5])
    assert not follower._in_view_of_station(last)
    follower.on_fix(0.5, last)
    follower.step(0.5)  # within the replan interval: the station stays
    assert follower.station is first
    follower.step(1.6)  # the fix timed out and a second passed since the last plan
    second = follower.station
    assert second is not None
    assert second is not first
    assert follower.looks == 1
    view = follower.planner.view(second.position_xy, second.heading_rad, last)
    assert follower.planner.view_is_good(view)


def test_a_moving_rov_that_lost_its_fix_is_looked_for_where_it_stops() -> None:
    """Lost while flying towards the ASV: it holds nearer, too steep for the aperture."""
    follower = _follower(fix_timeout_s=0.5, replan_after_s=1.0, lead_s=0.0, stop_within_s=6.0)
    follower.on_mode("GUIDED")
    follower.on_fix(0.0, np.array([20.0, 6.0, -3.5]))
    follower.step(0.0)
    first = follower.station
    assert first is not None
    toward = first.position_xy - np.array([20.0, 6.0])
    toward = toward / np.linalg.norm(toward)
    velocity = np.array([*(0.5 * toward), 0.0])
    follower.on_fix(0.2, np.array([20.0, 6.0, -3.5]), velocity)  # its last good fix
    held = np.array([*(np.array([20.0, 6.0]) + 3.0 * toward), -3.5])  # 6 s on at 0.5 m/s
    assert follower._in_view_of_station(np.array([20.0, 6.0, -3.5]))
    assert not follower._in_view_of_station(held)
    for k in range(1, 40):
        follower.step(0.2 + 0.2 * k)
    second = follower.station
    assert second is not None
    assert follower.looks >= 1
    view = follower.planner.view(second.position_xy, second.heading_rad, held)
    assert follower.planner.view_is_good(view)


def test_a_lost_rov_drifting_any_way_is_mostly_looked_at_within_150_s() -> None:
    """The looks cover the disc where a ROV holding without positions may have wandered.

    Mockup (`capsd bench search`'s geometry and loss model), 16 losses (8 directions, the ROV
    0.3 or 0.6 m off its last fix, drifting 1 cm/s): this search sees it in 14 (the earlier
    one, a point on a growing circle a sixth of a turn further each look, in 11). Some places
    the mockup's ASV cannot see at all (under the box it keeps to, no station 0.9 m off).
    """
    stations = search.planner()
    found = [
        search.seen_after(stations, np.array([3.0, 1.8, -1.0]), math.radians(a), offset)
        for a in range(0, 360, 45)
        for offset in (0.3, 0.6)
    ]
    assert sum(t is not None for t in found) >= 14


def test_the_search_disc_grows_and_looks_go_elsewhere() -> None:
    follower = _follower(fix_timeout_s=0.5, reacquire_after_s=6.0, lost_drift_m_s=0.02)
    follower.on_mode("GUIDED")
    stop = np.array([20.0, 6.0, -3.5])
    follower.on_fix(0.0, stop)
    follower.step(0.0)
    radii = [follower._search_disc(t)[1] for t in (0.0, 30.0, 60.0)]
    assert radii[0] == pytest.approx(0.3)  # at least SEARCH_MIN_RADIUS_M
    assert radii[2] == pytest.approx(0.02 * (60.0 - follower.settings.stop_within_s))
    aims = []
    for k in range(1, 600):  # 2 min at 5 Hz, the ASV where it is told to be
        t = 0.2 * k
        looks = follower.looks
        target = follower.step(t)
        assert target is not None
        follower.on_pose(target.position_xy, target.heading_rad)
        if follower.looks > looks:
            assert follower._aim is not None
            aims.append(follower._aim.copy())
    # A look each time the last one's station was reached and watched (at least every 30 s).
    assert len(aims) >= 6
    # The looks do not all aim at one point: they go round the disc.
    assert len({(round(a[0], 1), round(a[1], 1)) for a in aims}) >= 4


def test_the_hull_turns_to_face_the_rov_before_the_asv_goes() -> None:
    """Hull at 0 deg, the ROV behind it: the carrot turns where the hull is, then walks."""
    rov = np.array([2.0, 9.0, -3.5])  # behind the ASV at START
    bearing = math.atan2(rov[1] - START[1], rov[0] - START[0])

    def left_start(follower: Follower) -> tuple[int, float]:
        """The step at which the carrot first leaves START, and the heading it then has."""
        follower.on_mode("GUIDED")
        heading = 0.0
        for k in range(300):  # 30 s at 10 Hz; the hull turns as told, where it is
            now = k * 0.1
            follower.on_fix(now, rov)
            follower.on_pose(START, heading)
            target = follower.step(now)
            assert target is not None
            if not np.allclose(target.position_xy, START):
                return k, heading
            heading = target.heading_rad
        raise AssertionError("the carrot never left")

    k, heading = left_start(_follower(max_yaw_rate_rad_s=math.radians(15.0)))
    off = abs(math.atan2(math.sin(bearing - heading), math.cos(bearing - heading)))
    assert off <= math.radians(30.0) + 1e-9  # turned to face the ROV first
    assert k >= 60  # ~150 deg at 15 deg/s, less the 30 deg allowed: 8 s
    # Without the rule the carrot walks at once, the hull still facing away.
    k, heading = left_start(_follower(turn_first_rad=math.pi))
    assert k <= 2
    assert abs(heading) < math.radians(5.0)


Fix = Callable[[float], tuple[np.ndarray, np.ndarray | None]]


def _drive(
    planner: StationPlanner,
    start: np.ndarray,
    hull_rad: float,
    station_xy: np.ndarray,
    heading_rad: float,
    *,
    steps: int,
    fix: Fix,
) -> list[tuple[np.ndarray, float, np.ndarray]]:
    """A follower handed a station (never replanned), the hull obeying its targets at 10 Hz.

    `fix(now)`: the ROV's fix and tracked velocity. Each step's target and heading, and the ROV.
    """
    follower = Follower(planner, FollowSettings())
    follower.on_pose(start, hull_rad)
    follower.on_mode("GUIDED")
    rov, velocity = fix(0.0)
    follower.on_fix(0.0, rov, velocity)
    assert follower.step(0.0) is not None
    view = planner.view(station_xy, heading_rad, rov)
    follower.station = Station(position_xy=station_xy, heading_rad=heading_rad, view=view)
    follower._last_plan_s = math.inf  # keep this station
    xy, hull = start.copy(), hull_rad
    out = []
    for k in range(1, steps):
        now = k * 0.1
        rov, velocity = fix(now)
        follower.on_fix(now, rov, velocity)
        follower.on_pose(xy, hull)
        target = follower.step(now)
        assert target is not None
        xy, hull = target.position_xy, target.heading_rad
        out.append((xy, hull, rov))
    return out


def _fly_to_station(
    planner: StationPlanner,
    start: np.ndarray,
    rov: np.ndarray,
    station_xy: np.ndarray,
    heading_rad: float,
    *,
    steps: int,
) -> list[np.ndarray]:
    """The carrot's 10 Hz positions to a station handed over, the ROV still."""
    steps_ = _drive(
        planner, start, 0.0, station_xy, heading_rad, steps=steps, fix=lambda now: (rov, None)
    )
    return [xy for xy, _, _ in steps_]


def test_the_way_to_a_station_beyond_the_rov_goes_round_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A station on the ROV's far side: the carrot keeps its distance instead of passing over."""
    rov = np.array([16.0, 8.0, -3.5])  # 6 m ahead of the ASV at START, which faces it
    # A tank wide enough that no wall narrows the way round.
    planner = StationPlanner(
        SonarMountConfig(), TankBounds(length_m=40.0, width_m=30.0), StationSettings()
    )
    far_side = rov[:2] + np.array([6.0, 0.5])
    heading = math.atan2(rov[1] - far_side[1], rov[0] - far_side[0])

    def nearest_on_the_way() -> float:
        way = _fly_to_station(planner, START, rov, far_side, heading, steps=1200)  # 120 s
        assert float(np.linalg.norm(way[-1] - far_side)) < 0.05  # arrived
        return min(float(np.linalg.norm(xy - rov[:2])) for xy in way)

    assert nearest_on_the_way() > 0.8 * 6.0 - 0.2
    monkeypatch.setattr(follower_module, "AROUND_WITHIN", 0.0)  # straight through
    monkeypatch.setattr(Follower, "_keep_off", lambda self: None)  # (its own test below)
    assert nearest_on_the_way() < 1.0


def test_the_way_round_a_close_rov_widens_to_where_the_sonar_sees_it() -> None:
    """Starting too close (the ROV under the aperture), the way round widens to see it."""
    rov = np.array([14.0, 8.0, -3.5])  # 4 m ahead of the ASV at START: under the aperture
    planner = StationPlanner(
        SonarMountConfig(), TankBounds(length_m=40.0, width_m=30.0), StationSettings()
    )
    far_side = rov[:2] + np.array([4.0, 0.3])
    heading = math.atan2(rov[1] - far_side[1], rov[0] - far_side[0])
    way = _fly_to_station(planner, START, rov, far_side, heading, steps=1500)
    arrived = next(k for k, xy in enumerate(way) if float(np.linalg.norm(xy - far_side)) < 1.0)
    half = math.radians(SonarMountConfig().vertical_aperture_deg) / 2.0
    below = [
        planner.view(xy, math.atan2(rov[1] - xy[1], rov[0] - xy[0]), rov).elevation_rad < -half
        for xy in way[:arrived]
    ]
    # The spiral from 4 m to 4 m alone keeps it under the aperture the whole way.
    assert sum(below) < 0.5 * len(below)


def test_going_round_the_rov_keeps_the_hull_clear_of_the_walls() -> None:
    """In a narrow tank the way round is kept inside the walls' clearance box (or straight)."""
    tank = TankBounds(length_m=30.0, width_m=11.0)
    planner = StationPlanner(SonarMountConfig(), tank, StationSettings())
    rov = np.array([16.0, 7.5, -3.5])  # 3.5 m from the far wall: no room round that side
    far_side = rov[:2] + np.array([6.0, 0.0])
    for start in (np.array([10.0, 7.0]), np.array([10.0, 8.0])):
        way = _fly_to_station(planner, start, rov, far_side, math.pi, steps=1500)
        for k, xy in enumerate(way):
            assert planner.clear(xy), (start, k, xy)
        assert float(np.linalg.norm(way[-1] - far_side)) < 0.05


def test_in_a_small_tank_the_search_goes_on_after_its_circle_outgrows_the_tank() -> None:
    """A mockup-sized tank: every look's aim stays in the tank, so stations keep being found."""
    tank = TankBounds(length_m=4.8, width_m=3.6, depth_m=2.0)
    settings = StationSettings(
        min_range_m=1.0, max_range_m=6.0, hull_radius_m=0.3, tracking_margin_m=0.2
    )
    planner = StationPlanner(SonarMountConfig(pitch_deg=45.0), tank, settings)
    follower = Follower(planner, FollowSettings(fix_timeout_s=0.5, reacquire_after_s=6.0))
    follower.on_pose(np.array([1.6, 1.6]), 0.0)
    follower.on_mode("GUIDED")
    follower.on_fix(0.0, np.array([2.84, 1.53, -1.0]))  # its last good fix
    looked_at: list[float] = []
    for k in range(1, 1500):  # 300 s lost, the ASV where it is told to be
        t = 0.2 * k
        looks = follower.looks
        target = follower.step(t)
        assert target is not None
        follower.on_pose(target.position_xy, target.heading_rad)
        if follower.looks > looks:
            looked_at.append(t)
            aim = follower._aim
            assert aim is not None
            assert 0.0 < aim[0] < tank.length_m
            assert 0.0 < aim[1] < tank.width_m
    # Long after the disc (growing 2 cm/s) is wider than the tank: looks still come.
    assert sum(1 for t in looked_at if t > 200.0) >= 4


def test_the_rov_is_not_led_past_the_waypoint_its_mission_sent_it_to() -> None:
    """3 s of lead at 0.25 m/s is 0.75 m: a leg ending 0.5 m ahead caps it there."""
    follower = _follower(lead_s=3.0)
    follower.on_mode("GUIDED")
    rov = np.array([16.0, 8.0, -3.5])
    velocity = np.array([0.25, 0.0, 0.0])
    follower.on_fix(0.0, rov, velocity)
    assert np.allclose(follower._ahead(), [16.75, 8.0, -3.5])  # no mission heard
    follower.on_leg_end(0.0, np.array([16.5, 8.0, -3.5]))
    assert np.allclose(follower._ahead(), [16.5, 8.0, -3.5])
    follower.on_leg_end(0.0, np.array([20.0, 8.0, -3.5]))  # far ahead: the full lead
    assert np.allclose(follower._ahead(), [16.75, 8.0, -3.5])
    # Behind it (turning back, along the sight): led back at the plan's speed, 1 m there.
    follower.on_leg_end(0.0, np.array([15.0, 8.0, -3.5]))
    assert np.allclose(follower._ahead(), [15.25, 8.0, -3.5])
    follower.on_leg_end(0.0, None)  # the mission holds it: the leg is paused, not ended
    assert np.allclose(follower._ahead(), [15.25, 8.0, -3.5])
    # A waypoint not repeated for 5 s (the mission ended) is forgotten.
    follower.on_leg_end(0.0, np.array([16.5, 8.0, -3.5]))
    follower.step(6.0)
    follower.on_fix(6.0, rov, velocity)
    assert follower.leg_end is None
    assert np.allclose(follower._ahead(), [16.75, 8.0, -3.5])


def test_the_carrot_keeps_off_a_rov_flying_at_the_sonar(monkeypatch: pytest.MonkeyPatch) -> None:
    """A ROV flying at a station ahead of it: the ASV backs off as it comes.

    Never nearer than where the ROV sinks below the aperture (the station kept, as in a dead
    band or a wait); without the rule the ROV comes to 0.8 of that distance or nearer.
    """

    def nearest_seen() -> float:
        planner = StationPlanner(SonarMountConfig(), TankBounds(), StationSettings())
        rov = np.array([8.0, 8.0, -3.5])

        def fix(now: float) -> tuple[np.ndarray, np.ndarray | None]:
            # 40 s to reach the station, then the ROV comes 2 m at 0.1 m/s.
            coming = now > 40.0
            at = rov + np.array([0.1 * max(0.0, now - 40.0), 0.0, 0.0])
            return at, np.array([0.1 if coming else 0.0, 0.0, 0.0])

        station_xy = rov[:2] + np.array([6.5, 0.0])
        way = _drive(planner, START, math.pi, station_xy, math.pi, steps=600, fix=fix)
        return min(
            float(np.linalg.norm(planner.sonar_xy(xy, hull) - at[:2]))
            / planner.nearest_distance(at)
            for xy, hull, at in way
        )

    assert nearest_seen() > 0.98
    monkeypatch.setattr(Follower, "_keep_off", lambda self: None)
    assert nearest_seen() < 0.8


def test_at_its_station_the_hull_keeps_facing_the_rov() -> None:
    """A ROV moving across the boresight inside the dead band: the hull turns after it.

    (A conical beam sees a ROV off its boresight lower.) It does not chase the fixes' jitter.
    """
    planner = StationPlanner(SonarMountConfig(), TankBounds(), StationSettings())
    rov = np.array([16.0, 8.0, -3.5])
    station_xy = np.array([10.0, 8.0])
    rng = np.random.default_rng(3)

    def fix(now: float) -> tuple[np.ndarray, np.ndarray | None]:
        # 30 s: the ROV 1.5 m across, then still, its fixes jittering 2 cm.
        across = np.array([0.0, 1.5 * min(now, 15.0) / 15.0, 0.0])
        return rov + across + rng.normal(0, 0.02, 3), None

    way = _drive(planner, station_xy, 0.0, station_xy, 0.0, steps=300, fix=fix)
    xy, hull, _ = way[-1]
    headings = [h for _, h, _ in way]
    sonar = planner.sonar_xy(xy, hull)
    bearing = math.atan2(rov[1] + 1.5 - sonar[1], rov[0] - sonar[0])
    assert abs(wrap_angle(hull - bearing)) < math.radians(3.5)
    assert hull > math.radians(10.0)  # not the station's heading (0)
    assert float(np.linalg.norm(xy - station_xy)) < 0.05  # turned where it stands
    # Still, the hull does not follow the jitter (0.2 deg at 6 m).
    assert len({round(h, 9) for h in headings[-100:]}) == 1


def test_on_the_way_to_the_far_side_of_a_near_rov_the_hull_keeps_facing_it() -> None:
    """A small tank: the ROV 0.9 m ahead of the ASV, its station on the far side, facing back.

    The hull faces the ROV on the way (before, within 1 m of it, it turned to the station's
    heading where it stood, the sonar facing away from the ROV).
    """
    planner = StationPlanner(
        SonarMountConfig(pitch_deg=45.0),
        TankBounds(),
        StationSettings(min_range_m=1.0, hull_radius_m=0.3, tracking_margin_m=0.2),
    )
    rov = np.array([16.0, 8.0, -1.0])
    start = np.array([15.1, 8.0])  # the sonar 0.3 m ahead of the origin
    station_xy = np.array([16.9, 8.0])
    way = _drive(planner, start, 0.0, station_xy, math.pi, steps=50, fix=lambda now: (rov, None))
    for xy, hull, _ in way:
        sonar = planner.sonar_xy(xy, hull)
        bearing = math.atan2(rov[1] - sonar[1], rov[0] - sonar[0])
        assert abs(wrap_angle(hull - bearing)) < math.radians(30.0)


def test_stations_are_chosen_for_the_next_metre_and_a_half_of_the_rovs_leg() -> None:
    follower = _follower()
    rov = np.array([16.0, 8.0, -3.5])
    follower.on_fix(0.0, rov)
    assert follower._leg_path() is None  # no mission
    follower.on_leg_end(0.0, rov + np.array([0.0, 4.0, 1.0]))
    path = follower._leg_path()
    assert path is not None
    assert len(path) == 6
    assert np.allclose(path[0][:2], [16.0, 8.25])
    assert np.allclose(path[-1][:2], [16.0, 9.5])
    assert path[-1][2] == pytest.approx(-3.5 + 1.5 / 4.0)  # climbing along the leg
    follower.on_leg_end(0.1, rov + np.array([0.0, 0.2, 0.0]))
    assert follower._leg_path() is None  # at its end
    follower.on_leg_end(0.1, rov + np.array([0.0, 4.0, 1.0]))
    follower.on_leg_end(0.2, None)  # it holds: the leg is paused, not ended
    held = follower._leg_path()
    assert held is not None
    assert np.allclose(held, path)
    follower.step(5.3)  # nothing from the mission for 5 s: it ended
    assert follower._leg_path() is None


def test_near_the_lead_is_a_quarter_of_the_distance_the_rov_is_watched_from() -> None:
    """The mockup's scale: 3 s at 0.25 m/s would lead 0.75 m, as far as the ROV is watched."""
    planner = StationPlanner(
        SonarMountConfig(pitch_deg=45.0),
        TankBounds(),
        StationSettings(min_range_m=1.0, hull_radius_m=0.3, tracking_margin_m=0.2),
    )
    follower = Follower(planner, FollowSettings(lead_s=3.0))
    rov = np.array([16.0, 8.0, -1.0])
    follower.on_fix(0.0, rov, np.array([0.0, 0.25, 0.0]))
    ideal = planner.ideal_distance(rov)
    assert ideal == pytest.approx(0.8)
    assert np.allclose(follower._ahead(), rov + np.array([0.0, 0.25 * ideal, 0.0]))


def _watch_a_passing_rov(drive: str) -> list[Target]:
    """A ROV passing 6 m ahead of its station, 3.5 m across in 30 s; the hull obeys its targets."""
    planner = StationPlanner(SonarMountConfig(), TankBounds(), StationSettings(drive=drive))  # type: ignore[arg-type]
    follower = Follower(planner, FollowSettings())
    rov = np.array([16.0, 5.5, -3.5])
    velocity = np.array([0.0, 3.5 / 30.0, 0.0])
    first = planner.choose(rov, np.array([10.0, 5.5]), 0.0)
    assert first is not None
    xy, hull = first.position_xy, first.heading_rad
    follower.on_pose(xy, hull)
    follower.on_mode("GUIDED")
    targets = []
    for k in range(300):
        now = k * 0.1
        follower.on_fix(now, rov + velocity * now, velocity)
        follower.on_pose(xy, hull)
        target = follower.step(now)
        assert target is not None
        targets.append(target)
        xy, hull = target.position_xy, target.heading_rad
    return targets


def test_a_steered_follower_watches_a_passing_rov_by_turning_where_it_is() -> None:
    """ArduRover's GUIDED turns the hull to its way: the ASV turns where it is instead.

    The lateral follower moves along with the ROV once it is 15 deg off the boresight; the
    steered one stays (within the autopilot's arrival), its hull turned to face the ROV (30
    deg off the first boresight at the end; further, the ROV's elevation drops with its
    distance, and the steered follower moves too, driving at the ROV).
    """
    steered = _watch_a_passing_rov("steered")
    start = steered[0].position_xy
    assert max(float(np.linalg.norm(t.position_xy - start)) for t in steered) < 0.06
    planner = StationPlanner(SonarMountConfig(), TankBounds(), StationSettings())
    end = np.array([16.0, 5.5 + 29.9 * 3.5 / 30.0, -3.5])
    last = steered[-1]
    assert abs(planner.view(last.position_xy, last.heading_rad, end).azimuth_rad) < math.radians(4)
    lateral = _watch_a_passing_rov("lateral")
    assert max(float(np.linalg.norm(t.position_xy - start)) for t in lateral) > 1.0


def test_on_its_way_a_steered_follower_asks_for_the_ways_heading_then_faces_the_rov() -> None:
    """What ArduRover does on its way anyway (so that turning first is turning to the way)."""
    planner = StationPlanner(SonarMountConfig(), TankBounds(), StationSettings(drive="steered"))
    rov = np.array([16.0, 8.0, -3.5])
    start = np.array([10.0, 8.0])
    station_xy = np.array([10.0, 10.0])  # 2 m to the left: the way is abeam of the ROV
    way = _drive(planner, start, 0.0, station_xy, 0.0, steps=400, fix=lambda now: (rov, None))
    walking = [(xy, hull) for xy, hull, _ in way if 0.5 < float(np.linalg.norm(xy - start)) < 1.8]
    assert walking
    for _, hull in walking:
        assert abs(wrap_angle(hull - math.pi / 2)) < math.radians(5.0)  # not the ROV's (90 off)
    xy, hull, _ = way[-1]
    assert float(np.linalg.norm(xy - station_xy)) < 0.01
    sonar = planner.sonar_xy(xy, hull)
    assert abs(wrap_angle(hull - math.atan2(rov[1] - sonar[1], rov[0] - sonar[0]))) < 0.06


def test_the_heading_asked_for_stays_wrapped_however_often_the_hull_turns() -> None:
    """A ROV circling the station three times: headings stay within +-pi.

    (Unwrapped, the carrot's heading wound past the +-7 rad a command may carry, and the bridge
    refused every command from then on: a mockup run.)
    """
    planner = StationPlanner(SonarMountConfig(), TankBounds(), StationSettings(drive="steered"))
    station_xy = np.array([14.0, 8.0])

    def circling(now: float) -> tuple[np.ndarray, np.ndarray | None]:
        angle = 3.0 * math.tau * now / 90.0
        return np.array([14.0 + 6.0 * math.cos(angle), 8.0 + 6.0 * math.sin(angle), -3.5]), None

    way = _drive(planner, station_xy, 0.0, station_xy, 0.0, steps=900, fix=circling)
    headings = np.array([hull for _, hull, _ in way])
    assert np.all(np.abs(headings) <= math.pi + 1e-9)
    assert np.ptp(headings) > 6.0  # it did turn all round


def test_a_steered_follower_backs_off_a_rov_astern_facing_it() -> None:
    """A station straight behind the hull, away from the ROV: astern, the sonar on the ROV."""
    planner = StationPlanner(SonarMountConfig(), TankBounds(), StationSettings(drive="steered"))
    follower = Follower(planner, FollowSettings())
    rov = np.array([16.0, 8.0, -3.5])
    xy, hull = np.array([11.0, 8.0]), 0.0
    follower.on_pose(xy, hull)
    follower.on_mode("GUIDED")
    follower.on_fix(0.0, rov, None)
    assert follower.step(0.0) is not None
    station_xy = np.array([9.0, 8.0])
    view = planner.view(station_xy, 0.0, rov)
    follower.station = Station(position_xy=station_xy, heading_rad=0.0, view=view)
    follower._last_plan_s = math.inf  # keep this station
    targets = []
    for k in range(1, 200):
        now = k * 0.1
        follower.on_fix(now, rov, None)
        follower.on_pose(xy, hull)
        target = follower.step(now)
        assert target is not None
        targets.append(target)
        xy, hull = target.position_xy, target.heading_rad
    assert float(np.linalg.norm(xy - station_xy)) < 0.01
    assert all(t.direction == "reverse" for t in targets)
    assert max(abs(wrap_angle(t.heading_rad)) for t in targets) < math.radians(1.0)


def test_a_station_just_behind_the_hull_is_backed_to_even_with_the_carrot_past_it() -> None:
    """The drive direction is judged from the hull, not from where the carrot was left.

    The carrot walks ahead of the hull; a new station chosen between the two (just behind the
    hull, the carrot past it) was driven to "ahead" from the carrot's side: the autopilot then
    turned the hull half round to drive its bow there, the sonar off the ROV (`capsd bench
    follow`, nfp: a 30 s loss, the ROV's mission paused).
    """
    planner = StationPlanner(SonarMountConfig(), TankBounds(), StationSettings(drive="steered"))
    follower = Follower(planner, FollowSettings())
    rov = np.array([16.0, 8.0, -3.5])
    xy, hull = np.array([10.0, 8.0]), 0.0
    follower.on_pose(xy, hull)
    follower.on_mode("GUIDED")
    follower.on_fix(0.0, rov, None)
    assert follower.step(0.0) is not None
    follower._carrot = np.array([9.2, 8.0])  # on its way west (astern), past the new station
    follower._direction = "forward"  # the way before ran towards the ROV
    station_xy = np.array([9.8, 8.0])
    view = planner.view(station_xy, 0.0, rov)
    follower.station = Station(position_xy=station_xy, heading_rad=0.0, view=view)
    follower._last_plan_s = math.inf  # keep this station
    follower.on_fix(0.1, rov, None)
    target = follower.step(0.1)
    assert target is not None
    assert target.direction == "reverse"
    assert abs(wrap_angle(target.heading_rad)) < math.radians(20.0)  # still facing the ROV


def test_a_rov_lost_where_no_station_sees_it_is_still_searched_for() -> None:
    """Its last fix by a wall, no station sees where it holds: the search starts all the same.

    (The look "where it holds, at once" took every turn, found no station, and the search never
    started: a mockup run's ASV held 280 s.)
    """
    follower = _follower()
    follower.on_mode("GUIDED")
    rov = np.array([45.0, 8.0, -3.5])  # a wrong last fix, beyond the tank: no station sees it
    follower.on_fix(0.0, np.array([16.0, 8.0, -3.5]), None)
    follower.step(0.0)
    assert follower.station is not None
    follower.on_fix(0.5, rov, np.array([0.2, 0.0, 0.0]))
    assert follower.planner.choose(follower._held_at(5.0), START, 0.0) is None
    for k in range(1, 300):
        follower.step(0.5 + k * 0.1)
    assert follower.looks >= 1


def test_a_small_move_of_a_steered_hull_goes_along_the_line_of_sight_only() -> None:
    """A station 0.3 m across and 0.5 m back: astern along the sight, the sonar on the ROV.

    (ArduRover turns the hull to its way: a 0.2 m move turned the sonar 68 deg off the ROV in
    an nfp run.)
    """
    planner = StationPlanner(SonarMountConfig(), TankBounds(), StationSettings(drive="steered"))
    rov = np.array([16.0, 8.0, -3.5])
    start = np.array([10.0, 8.0])
    station_xy = np.array([9.5, 8.3])
    way = _drive(planner, start, 0.0, station_xy, 0.0, steps=150, fix=lambda now: (rov, None))
    for xy, hull, _ in way:
        sonar = planner.sonar_xy(xy, hull)
        assert abs(wrap_angle(hull - math.atan2(rov[1] - sonar[1], rov[0] - sonar[0]))) < 0.03
    xy, _, _ = way[-1]
    assert xy == pytest.approx([9.5, 8.0], abs=0.02)  # the station's distance, on the sight


def test_a_move_along_the_line_of_sight_keeps_the_hulls_wall_clearance() -> None:
    """Along the sight, astern towards a wall: no nearer than a station may be."""
    planner = StationPlanner(SonarMountConfig(), TankBounds(), StationSettings(drive="steered"))
    rov = np.array([6.0, 8.0, -3.5])
    start = np.array([2.3, 8.0])
    clearance = 1.0 + 0.6 + 0.5  # the wall, the hull's radius, the tracking margin
    way = _drive(
        planner, start, 0.0, np.array([1.9, 8.3]), 0.0, steps=150, fix=lambda now: (rov, None)
    )
    assert min(float(xy[0]) for xy, _, _ in way) >= clearance - 1e-9


def test_a_rov_holding_on_a_leg_along_the_sight_is_led_at_the_plans_speed() -> None:
    """A ROV waiting for the ASV on a leg at it goes on as soon as it may: its station leads it."""
    follower = _follower(lead_s=3.0)
    follower.on_mode("GUIDED")
    rov = np.array([16.0, 8.0, -3.5])  # the ASV at (10, 8): the leg at it runs along the sight
    follower.on_fix(0.0, rov, np.zeros(3))
    assert np.allclose(follower._ahead(), rov)  # no mission heard: as it is
    follower.on_leg_end(0.0, np.array([12.0, 8.0, -3.5]))
    lead = follower_module.LEG_SPEED_M_S * 3.0
    assert np.allclose(follower._ahead(), rov - np.array([lead, 0.0, 0.0]))
    follower.on_fix(0.1, rov, np.array([-0.05, 0.0, 0.0]))  # creeping: the plan's speed still
    assert np.allclose(follower._ahead(), rov - np.array([lead, 0.0, 0.0]))
    # A leg across the sight changes its elevation little: as it is.
    follower.on_leg_end(0.2, np.array([16.0, 12.0, -3.5]))
    follower.on_fix(0.2, rov, np.zeros(3))
    assert np.allclose(follower._ahead(), rov)


def test_the_path_a_station_is_to_see_runs_on_into_the_next_leg() -> None:
    """The rest of the leg, then the next leg's start within `path_ahead_m`.

    docs/JOURNAL.md, session 38.

    A station that sees a lane to its end but not the turn after it is driven into a wall
    there: `capsd bench follow` (nfp) lost the ROV at the lanes' west ends without it.
    """
    follower = _follower(path_ahead_m=3.0)
    rov = np.array([10.0, 8.0, -3.5])
    follower.on_fix(0.0, rov, np.array([0.25, 0.0, 0.0]))
    end, after = np.array([12.0, 8.0, -3.5]), np.array([12.0, 10.0, -3.5])
    follower.on_leg_end(0.0, end)
    alone = follower._leg_path()
    assert alone is not None
    assert len(alone) == 8  # 2 m at 0.25 m
    assert np.allclose(alone[-1], end)
    follower.on_leg_end(0.0, end, after)
    path = follower._leg_path()
    assert path is not None
    assert len(path) == 12  # and 1 m of the next leg
    assert np.allclose(path[:8], alone)
    assert np.allclose(path[-1], [12.0, 9.0, -3.5])
    # At the leg's end the path is the next leg's; a hold keeps both.
    follower.on_fix(0.1, end)
    follower.on_leg_end(0.1, None)
    at_end = follower._leg_path()
    assert at_end is not None
    assert np.allclose(at_end[0], [12.0, 8.25, -3.5])
    assert np.allclose(at_end[-1], [12.0, 10.0, -3.5])
    # The next waypoint is told with each leg: a leg without one has none.
    follower.on_leg_end(0.2, after)
    follower.on_fix(0.2, rov)
    tail = follower._leg_path()
    assert tail is not None
    assert len(tail) == 11  # 2.83 m to it, nothing after
    assert float(np.linalg.norm(tail[-1] - after)) < 0.25


def test_a_holding_rov_out_of_the_margin_seen_from_where_the_hull_settled_gets_a_station() -> None:
    """ArduRover stops short of a target (WP_RADIUS 0.2 m): the view is judged from the hull.

    A station whose view keeps the ROV just inside the aperture's margin, the hull settled
    0.3 m nearer the ROV, from where it is beyond the margin: while the ROV holds still (the
    mission's view guard waits for the ASV) a new station is chosen; while the ROV flies on,
    or with the hull at its station, the dead band rules as before (ArduRover SITL, docs/JOURNAL.md
    session 38: 130 s of waiting without it).
    """
    planner = StationPlanner(SonarMountConfig(), TankBounds(), StationSettings(drive="steered"))
    follower = Follower(planner, FollowSettings())
    rov = np.array([20.0, 8.0, -3.5])
    limit = planner.half_aperture - planner.settings.elevation_margin_rad

    def west(distance: float) -> np.ndarray:
        return np.array([rov[0] - distance, rov[1]])

    def elevation(xy: np.ndarray) -> float:
        return planner.view(xy, planner.facing(xy, rov), rov).elevation_rad

    # The station: the ROV 0.2 deg inside the margin's lower edge.
    distance = next(
        d for d in np.arange(3.0, 12.0, 0.01) if elevation(west(d)) > -limit + math.radians(0.2)
    )
    station_xy = west(float(distance))
    view = planner.view(station_xy, 0.0, rov)
    follower.station = Station(station_xy, 0.0, view)
    settled = west(float(distance) - 0.3)
    assert not planner.view_is_good(planner.view(settled, planner.facing(settled, rov), rov))
    follower.on_fix(0.0, rov, np.zeros(3))
    follower.on_pose(station_xy, 0.0)
    assert not follower._needs_station()
    follower.on_pose(settled, 0.0)
    assert follower._needs_station()
    follower.on_fix(0.0, rov, np.array([0.0, 0.25, 0.0]))  # flying on: the dead band decides
    assert not follower._needs_station()


def test_a_hull_past_its_station_closes_the_rest_with_the_end_that_faces_it() -> None:
    """Backing off the ROV, the hull overshot its station (chosen where it then was, 0.6 m).

    The carrot waits at the station, the way done; "astern" kept from the way before had the
    autopilot turn the stern to the station ahead of the bow: half round, the sonar off the
    ROV for 20 s (nfp demo, session 38, at the first lane's start).
    """
    planner = StationPlanner(SonarMountConfig(), TankBounds(), StationSettings(drive="steered"))
    follower = Follower(planner, FollowSettings())
    rov = np.array([16.0, 8.0, -3.5])
    station_xy = np.array([10.0, 8.0])
    follower.on_pose(station_xy, 0.0)
    follower.on_mode("GUIDED")
    follower.on_fix(0.0, rov, None)
    assert follower.step(0.0) is not None
    view = planner.view(station_xy, 0.0, rov)
    follower.station = Station(position_xy=station_xy, heading_rad=0.0, view=view)
    follower._last_plan_s = math.inf  # keep this station
    follower._carrot = station_xy.copy()
    follower._direction = "reverse"  # the way here backed off the ROV
    follower._direction_for = station_xy.copy()
    for k in range(1, 4):
        now = 0.1 * k
        follower.on_pose(np.array([9.4, 8.0]), 0.0)  # 0.6 m past it, facing the ROV
        follower.on_fix(now, rov, None)
        target = follower.step(now)
        assert target is not None
        assert target.direction == "forward", k
        assert float(np.linalg.norm(target.position_xy - station_xy)) < 0.05
        assert abs(wrap_angle(target.heading_rad)) < math.radians(5.0)
    # Past it the other way (nearer the ROV than its station): astern.
    follower.on_pose(np.array([10.6, 8.0]), 0.0)
    follower.on_fix(0.4, rov, None)
    target = follower.step(0.4)
    assert target is not None
    assert target.direction == "reverse"


def test_a_servo_is_told_the_angle_for_the_rov_half_a_second_on_from_where_the_asv_is() -> None:
    """Not the station's, nor its 3 s lead: the fix 0.5 s on, from the hull's pose now."""
    servo = msgspec.convert({"tilt": {}}, SonarMountConfig)
    planner = StationPlanner(servo, TankBounds(), StationSettings())
    follower = Follower(planner, FollowSettings())
    follower.on_pose(START, 0.3)
    follower.on_mode("GUIDED")
    rov, velocity = np.array([14.0, 9.0, -3.5]), np.array([-0.2, 0.0, 0.0])
    follower.on_fix(0.0, rov, velocity)
    target = follower.step(0.0)
    assert target is not None
    assert target.sonar_tilt_rad is not None
    ahead = planner.tilt_rad(START, 0.3, rov + 0.5 * velocity)
    assert target.sonar_tilt_rad == pytest.approx(ahead)
    assert ahead > planner.tilt_rad(START, 0.3, rov)  # nearer: steeper
    assert target.sonar_tilt_rad != pytest.approx(0.0, abs=1e-3)  # 4.5 m off: steeper than 30
    # Without a servo: nothing to tell.
    plain = _follower()
    plain.on_mode("GUIDED")
    plain.on_fix(0.0, rov)
    told = plain.step(0.0)
    assert told is not None
    assert told.sonar_tilt_rad is None


def test_a_servo_looks_where_a_rov_that_lost_its_fix_holds_not_at_the_stations_lead() -> None:
    """The station was chosen for the ROV 0.75 m on; lost, the ROV stops 0.25 m on.

    (The look's centre: without the nod about it.)
    """
    servo = msgspec.convert({"tilt": {}}, SonarMountConfig)
    planner = StationPlanner(servo, TankBounds(), StationSettings())
    follower = Follower(
        planner, FollowSettings(lead_s=3.0, stop_within_s=1.0, nod_amplitude_rad=0.0)
    )
    follower.on_pose(START, 0.0)
    follower.on_mode("GUIDED")
    rov, velocity = np.array([16.0, 8.0, -3.5]), np.array([0.25, 0.0, 0.0])
    follower.on_leg_end(0.0, np.array([22.0, 8.0, -3.5]))
    follower.on_fix(0.0, rov, velocity)
    assert follower.step(0.0) is not None
    lead = follower._ahead()
    assert lead[0] == pytest.approx(16.75)
    follower.on_leg_end(1.5, None)  # the mission holds it
    lost = follower.step(1.5)  # 1.5 s without a fix: no search yet
    assert lost is not None
    assert lost.state == "holding"
    held = rov + velocity * 1.0
    assert lost.sonar_tilt_rad == pytest.approx(planner.tilt_rad(START, 0.0, held))
    assert lost.sonar_tilt_rad != pytest.approx(planner.tilt_rad(START, 0.0, lead), abs=1e-3)


def test_a_servo_nods_about_the_look_while_the_fix_is_lost_first_the_way_the_rov_went() -> None:
    """Lost, the tilt nods about the look, first the way the ROV went (down: it closed in).

    Out to the look's tilt plus the half aperture, over to minus it and back, at the nod's
    rate; a fresh fix ends it.
    """
    servo = msgspec.convert({"tilt": {}}, SonarMountConfig)
    planner = StationPlanner(servo, TankBounds(), StationSettings())
    settings = FollowSettings(
        stop_within_s=0.0, nod_rate_rad_s=math.radians(10.0), reacquire_after_s=30.0
    )
    follower = Follower(planner, settings)
    follower.on_pose(START, 0.0)
    follower.on_mode("GUIDED")
    t = 0.0
    for x in np.arange(16.0, 15.0, -0.05):  # coming at the ASV: ever steeper
        follower.on_fix(t, np.array([x, 8.0, -3.5]))
        assert follower.step(t) is not None
        t += 0.1
    last_fix_s = t - 0.1
    held = follower.rov_m
    assert held is not None
    look = planner.tilt_rad(START, 0.0, held)
    amplitude = planner.half_aperture
    quarter_s = amplitude / settings.nod_rate_rad_s  # 1 s
    told = {}
    for after in (0.5, 1.0, 2.0, 3.0, 4.0, 5.0):
        now = last_fix_s + settings.fix_timeout_s + after * quarter_s
        target = follower.step(now)
        assert target is not None
        assert target.sonar_tilt_rad is not None
        told[after] = target.sonar_tilt_rad
    assert told[0.5] == pytest.approx(look + 0.5 * amplitude, abs=1e-6)  # down first
    assert told[1.0] == pytest.approx(look + amplitude, abs=1e-6)
    assert told[2.0] == pytest.approx(look, abs=1e-6)
    assert told[3.0] == pytest.approx(look - amplitude, abs=1e-6)
    assert told[4.0] == pytest.approx(look, abs=1e-6)
    assert told[5.0] == pytest.approx(look + amplitude, abs=1e-6)
    # Found again: the look itself.
    now = last_fix_s + 10.0
    follower.on_fix(now, held)
    found = follower.step(now)
    assert found is not None
    assert found.sonar_tilt_rad == pytest.approx(planner.tilt_rad(START, 0.0, held))


def test_a_nod_starts_up_where_the_rov_was_going_up_the_aperture() -> None:
    """The ROV going away (the tilt shallower): the nod's first half goes up."""
    servo = msgspec.convert({"tilt": {}}, SonarMountConfig)
    planner = StationPlanner(servo, TankBounds(), StationSettings())
    settings = FollowSettings(stop_within_s=0.0)
    follower = Follower(planner, settings)
    follower.on_pose(START, 0.0)
    follower.on_mode("GUIDED")
    t = 0.0
    for x in np.arange(14.0, 15.0, 0.05):
        follower.on_fix(t, np.array([x, 8.0, -3.5]))
        assert follower.step(t) is not None
        t += 0.1
    assert follower.rov_m is not None
    look = planner.tilt_rad(START, 0.0, follower.rov_m)
    target = follower.step(t - 0.1 + settings.fix_timeout_s + 0.2)
    assert target is not None
    assert target.sonar_tilt_rad is not None
    assert target.sonar_tilt_rad == pytest.approx(look - 0.2 * settings.nod_rate_rad_s, abs=1e-6)


def test_with_a_pan_the_hull_at_its_station_turns_off_the_rov_and_the_pan_faces_it() -> None:
    """At its station the hull settles 60 deg off facing the ROV, the pan 60 deg the other way.

    (The sonar ahead of the origin kept off the ROV.) A hull already 50 deg off stays.
    """
    servos = msgspec.convert({"tilt": {}, "pan": {}}, SonarMountConfig)
    planner = StationPlanner(servos, TankBounds(), StationSettings())
    rov = np.array([14.0, 8.0, -3.5])
    abeam = FollowSettings(pan_abeam_rad=math.radians(60.0))
    follower = Follower(planner, abeam)
    follower.on_pose(START, 0.0)
    follower.on_mode("GUIDED")
    follower.on_fix(0.0, rov)
    assert follower.step(0.0) is not None
    station = follower.station
    assert station is not None
    facing = planner.facing(station.position_xy, rov)
    heading, t = station.heading_rad, 0.0
    target = None
    for _ in range(150):  # 15 s: the hull follows its target's heading at once
        t += 0.1
        follower.on_pose(station.position_xy, heading)
        follower.on_fix(t, rov)
        target = follower.step(t)
        assert target is not None
        heading = target.heading_rad
    assert target is not None
    assert target.sonar_pan_rad is not None
    off = wrap_angle(facing - target.heading_rad)
    assert math.degrees(abs(off)) == pytest.approx(60.0, abs=0.5)
    pan, _ = planner.pan_tilt_rad(station.position_xy, target.heading_rad, rov)
    assert target.sonar_pan_rad == pytest.approx(pan, abs=1e-6)
    assert math.degrees(abs(pan)) > 55.0
    # A hull 50 deg off (within the 20 deg slack of 60): kept, no turn.
    kept = Follower(planner, abeam)
    kept.on_pose(station.position_xy, wrap_angle(facing - math.radians(50.0)))
    kept.on_mode("GUIDED")
    kept.station = station
    kept.on_fix(0.0, rov)
    told = kept.step(0.0)
    assert told is not None
    assert told.heading_rad == pytest.approx(wrap_angle(facing - math.radians(50.0)))
    # Without the pan servo the hull faces the ROV.
    tilt_only = Follower(
        StationPlanner(
            msgspec.convert({"tilt": {}}, SonarMountConfig), TankBounds(), StationSettings()
        ),
        FollowSettings(),
    )
    tilt_only.on_pose(station.position_xy, facing)
    tilt_only.on_mode("GUIDED")
    tilt_only.station = station
    tilt_only.on_fix(0.0, rov)
    faced = tilt_only.step(0.0)
    assert faced is not None
    assert faced.heading_rad == pytest.approx(facing, abs=math.radians(3.0))


def test_a_pan_is_held_while_the_rov_stays_within_its_dead_band_then_turned_onto_it() -> None:
    """The ROV's bearing 10 deg off the pan: held; 20 deg off: turned onto it, at its rate."""
    servos = msgspec.convert({"tilt": {}, "pan": {}}, SonarMountConfig)
    planner = StationPlanner(servos, TankBounds(), StationSettings())
    settings = FollowSettings(pan_dead_band_rad=math.radians(15.0))
    follower = Follower(planner, settings)
    follower.on_pose(START, 0.0)
    follower.on_mode("GUIDED")

    def told_pan(t: float, bearing_deg: float, distance_m: float = 4.0) -> float:
        b = math.radians(bearing_deg)
        sonar = planner.sonar_xy(START, 0.0)
        rov = np.array(
            [sonar[0] + distance_m * math.cos(b), sonar[1] + distance_m * math.sin(b), -3.5]
        )
        follower.on_pose(START, 0.0)  # the hull kept where it is, facing +x
        follower.on_fix(t, rov)
        target = follower.step(t)
        assert target is not None
        assert target.sonar_pan_rad is not None
        return math.degrees(target.sonar_pan_rad)

    t = 0.0
    for _ in range(30):  # 3 s: the pan turns onto the ROV 40 deg to port
        t += 0.1
        first = told_pan(t, 40.0)
    assert first == pytest.approx(40.0, abs=1.0)
    t += 0.1
    assert told_pan(t, 50.0) == pytest.approx(first)  # 10 deg off: held
    t += 0.1
    turning = told_pan(t, 60.0)  # 20 deg off: on its way, no faster than 60 deg/s
    assert first < turning <= first + 6.0 + 1e-6
    for _ in range(10):
        t += 0.1
        turning = told_pan(t, 60.0)
    assert turning == pytest.approx(60.0, abs=1.0)
    # Without the dead band it follows every degree.
    tracking = Follower(planner, FollowSettings(pan_dead_band_rad=0.0))
    tracking.on_pose(START, 0.0)
    tracking.on_mode("GUIDED")
    follower = tracking
    t = 10.0
    for _ in range(30):
        t += 0.1
        told_pan(t, 40.0)
    t += 0.1
    assert told_pan(t, 45.0) == pytest.approx(45.0, abs=1.0)


def test_a_pan_servo_is_told_the_pan_that_faces_the_rov_and_the_tilt_for_it() -> None:
    """The ROV abeam of the hull: the pan turns to it; without a pan servo none is told."""
    servos = msgspec.convert({"tilt": {}, "pan": {}}, SonarMountConfig)
    planner = StationPlanner(servos, TankBounds(), StationSettings())
    follower = Follower(planner, FollowSettings())
    follower.on_pose(START, 0.0)
    follower.on_mode("GUIDED")
    rov = np.array([10.3, 12.0, -3.5])  # 4 m to port
    follower.on_fix(0.0, rov)
    target = follower.step(0.0)
    assert target is not None
    assert target.sonar_pan_rad is not None
    assert target.sonar_tilt_rad is not None
    pan, tilt = planner.pan_tilt_rad(START, 0.0, rov)
    assert target.sonar_pan_rad == pytest.approx(pan)
    assert math.degrees(pan) == pytest.approx(90.0, abs=1.0)
    assert target.sonar_tilt_rad == pytest.approx(tilt)
    told = _follower()
    told.on_mode("GUIDED")
    told.on_fix(0.0, rov)
    plain = told.step(0.0)
    assert plain is not None
    assert plain.sonar_pan_rad is None


def test_a_way_round_the_rov_keeps_its_side_while_the_fix_jitters_across_the_way(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A station right behind the ROV: fixes a few cm either side of the way do not swap sides.

    A steered hull turns to its way before it goes; each swap was a half turn, and it never went.
    """
    planner = StationPlanner(
        SonarMountConfig(),
        TankBounds(length_m=40.0, width_m=30.0),
        StationSettings(drive="steered"),
    )
    rov = np.array([16.0, 8.0, -3.5])
    far_side = rov[:2] + np.array([6.0, 0.0])

    def jittering(now: float) -> tuple[np.ndarray, None]:
        return rov + np.array([0.0, 0.05 if int(now) % 2 else -0.05, 0.0]), None

    def arrived() -> bool:
        way = _drive(planner, START, 0.0, far_side, math.pi, steps=1500, fix=jittering)
        return any(float(np.linalg.norm(xy - far_side)) < 0.05 for xy, _, _ in way)

    assert arrived()  # within 150 s
    monkeypatch.setattr(follower_module, "ROUND_KEEP_MAX_RAD", 0.0)  # each step chooses anew
    assert not arrived()


def test_a_station_on_the_other_side_is_kept_to_that_side_for_a_while() -> None:
    """The ROV back where it was within `side_commit_s`: not seen from the side it was left for."""
    planner = StationPlanner(SonarMountConfig(), TankBounds(), StationSettings())
    east, west = np.array([16.0, 8.0, -3.5]), np.array([4.0, 8.0, -3.5])

    def bearings(commit_s: float) -> list[float]:
        settings = FollowSettings(side_commit_s=commit_s, side_switch_rad=math.radians(60.0))
        follower = Follower(planner, settings)
        follower.on_pose(START, 0.0)
        follower.on_mode("GUIDED")
        out = []
        for now, rov in ((0.0, east), (2.5, west), (5.0, east)):
            follower.on_fix(now, rov)
            follower.step(now)
            assert follower.station is not None
            out.append(math.degrees(abs(planner.bearing(follower.station))))
        return out

    first, switched, back = bearings(10.0)
    assert first < 60.0 < switched  # the side switched (the bearing turned more than 60 deg)
    assert back > 60.0  # not back to the side it left
    first, switched, back = bearings(0.0)
    assert first < 60.0 < switched
    assert back < 60.0  # without the commitment: the side it left, the nearer


def test_a_steered_hull_too_near_the_rov_leaves_by_the_end_it_turns_to_least() -> None:
    """Nearer than stations keep it, neither end sees the ROV: the nearer end, not a half turn."""
    planner = StationPlanner(
        SonarMountConfig(),
        TankBounds(length_m=40.0, width_m=30.0),
        StationSettings(drive="steered"),
    )
    station_xy = START + np.array([3.0, 1.0])  # ahead, a little left: the bow's way

    def first_direction(rov: np.ndarray) -> str:
        follower = Follower(planner, FollowSettings())
        follower.on_pose(START, 0.0)
        follower.on_mode("GUIDED")
        follower.on_fix(0.0, rov)
        follower.step(0.0)
        view = planner.view(station_xy, planner.facing(station_xy, rov), rov)
        follower.station = Station(position_xy=station_xy, heading_rad=0.0, view=view)
        follower._last_plan_s = math.inf  # keep this station
        follower.on_fix(0.1, rov)
        target = follower.step(0.1)
        assert target is not None
        return target.direction

    near = np.array([START[0] - 0.3, START[1] - 1.0, -1.5])  # 1.75 m from the sonar
    assert planner.view(START, 0.0, near).range_m < 2.0
    assert first_direction(near) == "forward"
    # Off by as much, far enough to be seen: the stern to the way, the sonar facing it.
    far = np.array([START[0] - 1.0, START[1] - 4.0, -3.5])
    assert first_direction(far) == "reverse"


def test_the_end_chosen_for_a_too_near_rov_is_kept_until_it_is_clearly_further() -> None:
    """A ROV about `min_range_m` off: new stations a second apart do not swap the end each time.

    (Each swap a half turn first: a mockup demo's hull never went, 150 s 0.5 m off the ROV.)
    """
    planner = StationPlanner(
        SonarMountConfig(),
        TankBounds(length_m=40.0, width_m=30.0),
        StationSettings(drive="steered"),
    )
    follower = Follower(planner, FollowSettings())
    follower.on_pose(START, 0.0)
    follower.on_mode("GUIDED")
    behind = np.array([-0.3, -1.0]) / math.hypot(0.3, 1.0)  # behind on the right

    def rov_at(range_m: float) -> np.ndarray:
        """The ROV behind the hull at this range from its sonar (heading 0)."""
        distances = np.linspace(0.0, 3.0, 3001)
        ranges = [
            planner.view(START, 0.0, np.array([*(START + d * behind), -1.5])).range_m
            for d in distances
        ]
        d = float(np.interp(range_m, ranges, distances))
        return np.array([*(START + d * behind), -1.5])

    def direction(rov: np.ndarray, station_xy: np.ndarray, now: float) -> str:
        follower.on_fix(now, rov)
        view = planner.view(station_xy, planner.facing(station_xy, rov), rov)
        follower.station = Station(position_xy=station_xy, heading_rad=0.0, view=view)
        follower._last_plan_s = math.inf  # keep this station
        follower.on_pose(START, 0.0)
        target = follower.step(now)
        assert target is not None
        return target.direction

    limit = planner.settings.min_range_m
    ahead = START + np.array([3.0, 1.0])
    follower.on_fix(0.0, rov_at(limit - 0.05))
    follower.step(0.0)
    assert direction(rov_at(limit - 0.05), ahead, 0.1) == "forward"  # too near: turn least
    # A new station (its way chosen again) with the ROV just past `min_range_m`: kept.
    assert direction(rov_at(limit + 0.07), ahead + np.array([0.0, 0.6]), 0.2) == "forward"
    # Clearly further: the stern to the way, the sonar facing the ROV.
    assert direction(rov_at(limit + 0.4), ahead + np.array([0.0, 1.2]), 0.3) == "reverse"


def test_a_station_moved_a_little_on_the_way_keeps_the_end_the_hull_drives(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A station re-chosen a few dm off: no half turn half way (the way's end chosen again)."""
    planner = StationPlanner(
        SonarMountConfig(),
        TankBounds(length_m=40.0, width_m=30.0),
        StationSettings(drive="steered"),
    )
    rov = np.array([START[0] + 3.0, START[1] + 4.0, -3.5])  # ahead on the left, then behind

    def directions() -> tuple[str, str]:
        follower = Follower(planner, FollowSettings())
        follower.on_pose(START, 0.0)
        follower.on_mode("GUIDED")
        follower.on_fix(0.0, rov)
        follower.step(0.0)
        station_xy = START + np.array([8.0, 0.0])
        view = planner.view(station_xy, planner.facing(station_xy, rov), rov)
        follower.station = Station(position_xy=station_xy, heading_rad=0.0, view=view)
        follower._last_plan_s = math.inf  # keep this station
        xy, hull, now = START.copy(), 0.0, 0.0
        while xy[0] < START[0] + 5.0:  # past the ROV: now the stern faces it better
            now += 0.1
            follower.on_fix(now, rov)
            follower.on_pose(xy, hull)
            target = follower.step(now)
            assert target is not None
            assert now < 60.0
            xy, hull, before = target.position_xy, target.heading_rad, target.direction
        moved = station_xy + np.array([0.0, 0.3])
        follower.station = Station(position_xy=moved, heading_rad=0.0, view=view)
        follower.on_fix(now + 0.1, rov)
        follower.on_pose(xy, hull)
        target = follower.step(now + 0.1)
        assert target is not None
        return before, target.direction

    assert directions() == ("forward", "forward")
    monkeypatch.setattr(follower_module, "DIRECTION_KEEP_M", STAY_M)
    assert directions() == ("forward", "reverse")


def _facing_at_start(planner: StationPlanner, rov_m: np.ndarray) -> Follower:
    """A follower (`pan_abeam_rad` 0) handed a station where the hull is, heading 0, kept."""
    follower = Follower(planner, FollowSettings(pan_abeam_rad=0.0))
    follower.on_pose(START, 0.0)
    follower.on_mode("GUIDED")
    follower.on_fix(0.0, rov_m)
    follower.step(0.0)
    view = planner.view(START, 0.0, rov_m)
    follower.station = Station(position_xy=START.copy(), heading_rad=0.0, view=view)
    follower._last_plan_s = math.inf  # keep this station, no search
    return follower


def test_without_a_fix_a_hull_at_its_station_turns_to_where_the_pan_reaches_the_held_rov() -> None:
    """The ROV held 130 deg off the station's heading (the pan turns 90): the hull turns.

    Held 60 deg off, within the pan's reach: the station's heading is kept.
    """
    servos = msgspec.convert({"tilt": {}, "pan": {}}, SonarMountConfig)
    planner = StationPlanner(servos, TankBounds(), StationSettings())

    def heading_without_fix(off_bow_deg: float) -> float:
        bearing = math.radians(off_bow_deg)
        rov = np.array([START[0] + 3.0 * math.cos(bearing), START[1] + 3.0 * math.sin(bearing)])
        rov_m = np.array([rov[0], rov[1], -2.0])
        follower = _facing_at_start(planner, rov_m)
        target = None
        for k in range(1, 101):  # 10 s without a fix (stale after fix_timeout_s)
            follower.on_pose(START, 0.0)
            target = follower.step(k * 0.1)
        assert target is not None
        assert target.state == "holding"
        return target.heading_rad

    assert heading_without_fix(60.0) == pytest.approx(0.0, abs=1e-9)
    turned = heading_without_fix(130.0)
    assert math.degrees(abs(wrap_angle(turned - math.radians(130.0)))) < 45.0
    assert heading_without_fix(-130.0) < 0.0


def test_a_pan_tilt_hull_too_near_the_rov_at_its_station_turns_it_abeam() -> None:
    """Facing the ROV would put the sonar nearer than `min_range_m`: the hull turns 75 deg off.

    (The pan's 90 deg less its margin; the sonar ahead of the origin goes aside, not nearer.)
    Further off, the hull faces the ROV.
    """
    servos = msgspec.convert({"tilt": {}, "pan": {}}, SonarMountConfig)
    planner = StationPlanner(servos, TankBounds(), StationSettings())

    def settled_off_facing(distance_m: float) -> float:
        rov = np.array([START[0] + distance_m, START[1], -1.0])
        follower = _facing_at_start(planner, rov)
        heading, target = 0.0, None
        for k in range(1, 101):  # 10 s, the hull following its target's heading at once
            follower.on_pose(START, heading)
            follower.on_fix(k * 0.1, rov)
            target = follower.step(k * 0.1)
            assert target is not None
            heading = target.heading_rad
        return math.degrees(abs(wrap_angle(heading - planner.facing(START, rov))))

    near = 1.5  # the sonar 1.2 m off horizontally facing it, under 2 m slant
    rov_near = np.array([START[0] + near, START[1], -1.0])
    assert planner.view(START, 0.0, rov_near).range_m < planner.settings.min_range_m
    assert settled_off_facing(near) == pytest.approx(75.0, abs=1.0)
    assert settled_off_facing(4.0) < 3.0


def test_a_way_round_the_rov_that_the_walls_stop_goes_straight() -> None:
    """At a corner of the mockup's box the way round's next point is where the carrot is.

    (`capsd bench follow`, mockup pan-tilt, seed 9: the carrot held there 28 s.) The carrot
    goes on towards the station instead.
    """
    from capsd.harness import follow_config

    config = follow_config("mockup", drive="steered", tilt="pan-tilt")
    planner = StationPlanner(
        config.sonar, config.tank, config.motion.drive_settings(config.station.settings())
    )
    corner = np.array([1.57, 2.10])
    rov = np.array([2.16, 1.96, -1.01])
    station_xy = np.array([3.29, 2.04])  # on the ROV's far side
    follower = Follower(planner, config.motion.settings())
    follower.on_pose(corner, math.radians(-15.0))
    follower.on_mode("GUIDED")
    follower.on_fix(0.0, rov)
    follower.step(0.0)
    view = planner.view(station_xy, planner.facing(station_xy, rov), rov)
    follower.station = Station(position_xy=station_xy, heading_rad=math.pi, view=view)
    follower._last_plan_s = math.inf  # keep this station
    # The carrot at the box's north edge: north of it is outside the box.
    assert planner.within_walls(corner + np.array([0.0, 0.3]))[1] == pytest.approx(
        corner[1], abs=0.05
    )
    xy, hull = corner.copy(), math.radians(-15.0)
    for k in range(1, 200):  # 20 s, the hull obeying its targets
        follower.on_fix(k * 0.1, rov)
        follower.on_pose(xy, hull)
        target = follower.step(k * 0.1)
        assert target is not None
        xy, hull = target.position_xy, target.heading_rad
    assert float(np.linalg.norm(xy - corner)) > 0.5


def _mockup_pan_tilt_planner() -> StationPlanner:
    """A steered pan-tilt hull as the mockup demo has it (sonar 0.3 m ahead, 45 deg down)."""
    mount = msgspec.convert(
        {"position_m": [0.3, 0.0, -0.2], "pitch_deg": 45.0, "tilt": {}, "pan": {}},
        SonarMountConfig,
    )
    settings = StationSettings(drive="steered", min_range_m=1.1, hull_radius_m=0.3)
    return StationPlanner(mount, TankBounds(length_m=40.0, width_m=30.0), settings)


def _way_started(
    planner: StationPlanner, rov: np.ndarray, station_xy: np.ndarray
) -> tuple[Follower, Target]:
    """A follower at START (heading 0) with a fresh fix, its way to `station_xy` just started."""
    follower = Follower(planner, FollowSettings(pan_abeam_rad=0.0))
    follower.on_pose(START, 0.0)
    follower.on_mode("GUIDED")
    follower.on_fix(0.0, rov)
    follower.step(0.0)
    view = planner.view(station_xy, planner.facing(station_xy, rov), rov)
    follower.station = Station(position_xy=station_xy, heading_rad=0.0, view=view)
    follower._last_plan_s = math.inf  # keep this station
    follower._direction_for = None  # the way starts now
    follower.on_fix(0.1, rov)
    target = follower.step(0.1)
    assert target is not None
    return follower, target


@pytest.mark.parametrize("near", [True, False])
def test_a_pan_tilt_hull_passing_a_rov_abeam_drives_the_end_that_keeps_it_in_reach(
    monkeypatch: pytest.MonkeyPatch, near: bool
) -> None:
    """A way past a ROV abeam: astern, so that the pan reaches it at the way's end too.

    (Ahead, the bow's way, it ends 150 deg off the bow, 60 deg past the pan's limit: mockup
    demos, seeds 4-6.) Whether or not the ROV is nearer than stations keep it.
    """
    planner = _mockup_pan_tilt_planner()
    side = 0.6 if near else 1.0
    rov = np.array([START[0] + 0.2, START[1] + side, -1.0])
    assert (planner.view(START, 0.0, rov).range_m < 1.1) == near
    station_xy = START + np.array([1.3, -0.2])

    def first_direction() -> str:
        return _way_started(planner, rov, station_xy)[1].direction

    ahead = planner.way_past_pan_rad(START, 0.0, station_xy, rov, direction="forward")
    astern = planner.way_past_pan_rad(START, 0.0, station_xy, rov, direction="reverse")
    assert math.degrees(astern) < 30.0
    assert math.degrees(ahead) > 50.0
    assert first_direction() == "reverse"
    monkeypatch.setattr(follower_module, "PAST_PAN_SEEN_RAD", math.pi)  # the rules before
    assert first_direction() == "forward"


def test_the_end_that_keeps_the_rov_in_reach_is_kept_through_its_turn_fix_or_not() -> None:
    """Chosen with a fresh fix, the end stays while the fix is stale (the rules before swapped it).

    Judged again at each step of the half turn, a hull whose fix went stale as it turned took
    the other end back, then this one with the next fix: to and fro (`capsd bench follow`).
    """
    planner = _mockup_pan_tilt_planner()
    rov = np.array([START[0] + 0.2, START[1] + 0.6, -1.0])
    follower, target = _way_started(planner, rov, START + np.array([1.3, -0.2]))
    assert target.direction == "reverse"
    directions = []
    for k in range(2, 40):  # the fix stale from 1.1 s on; the hull turning where it is
        now = 0.1 * k
        follower.on_pose(START, target.heading_rad)
        follower._direction_for = None  # as the hull turning first leaves it
        stepped = follower.step(now)
        assert stepped is not None
        target = stepped
        directions.append(target.direction)
    assert now - follower.fix_s > follower.settings.fix_timeout_s
    assert set(directions) == {"reverse"}


def test_a_short_step_is_driven_by_the_end_the_rules_before_choose() -> None:
    """A way of 0.5 m or less (a station re-chosen nearby) is not judged for the pan's reach.

    (Kept backing on such steps, a hull turned half round for each: `capsd bench follow`,
    mockup pan-tilt, seed 25, 67 % in view.) Behind on the left, too near: the end turned to
    least, ahead, though it leaves the ROV 60 deg past the pan; a longer way, astern.
    """
    planner = _mockup_pan_tilt_planner()
    rov = np.array([START[0] - 0.3, START[1] + 0.4, -1.0])
    short_xy = START + np.array([0.45, 0.0])
    ahead = planner.way_past_pan_rad(START, 0.0, short_xy, rov, direction="forward")
    assert math.degrees(ahead) > 55.0
    assert _way_started(planner, rov, short_xy)[1].direction == "forward"
    assert _way_started(planner, rov, START + np.array([1.3, 0.0]))[1].direction == "reverse"
