"""Station planner: the view matches the sonar's geometry; chosen stations are safe and good."""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

import msgspec
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capsd.geometry import Transform, wrap_angle
from capsd.mounts import SonarMountConfig
from capsd.services.asv_follow.station import StationPlanner, StationSettings
from capsd.sonar_geometry import to_polar
from capsd.tank import TankBounds, TankFixture

TANK = TankBounds(length_m=28.0, width_m=16.0, depth_m=8.0)
MOUNT = SonarMountConfig()


def _planner(**changes: object) -> StationPlanner:
    return StationPlanner(MOUNT, TANK, StationSettings(**changes))  # type: ignore[arg-type]


@given(
    asv=st.tuples(st.floats(2.0, 26.0), st.floats(2.0, 14.0)),
    heading=st.floats(-math.pi, math.pi),
    rov=st.tuples(st.floats(1.0, 27.0), st.floats(1.0, 15.0), st.floats(-7.5, -1.0)),
)
def test_the_view_range_is_the_sonar_geometry(
    asv: tuple[float, float], heading: float, rov: tuple[float, float, float]
) -> None:
    """The range as the locator's beam model computes it (level ASV), anywhere."""
    planner = _planner()
    view = planner.view(np.array(asv), heading, np.array(rov))
    body = Transform.from_euler_zyx(
        (asv[0], asv[1], 0.0), yaw_rad=heading, pitch_rad=0.0, roll_rad=0.0
    )
    sonar = body.compose(MOUNT.transform())
    r, _, _ = to_polar("planar", sonar.inverse().apply(np.array(rov)))
    assert math.isclose(view.range_m, r, rel_tol=1e-9)
    # Off the boresight a pitched sonar's azimuth and elevation mix: checked on it (below).


@settings(max_examples=40, deadline=None)
@given(
    rov=st.tuples(st.floats(0.5, 27.5), st.floats(0.5, 15.5), st.floats(-7.8, -1.0)),
    asv=st.tuples(st.floats(2.0, 26.0), st.floats(2.0, 14.0)),
)
def test_a_chosen_station_is_clear_of_walls_and_sees_the_rov_well(
    rov: tuple[float, float, float], asv: tuple[float, float]
) -> None:
    planner = _planner(wall_clearance_m=1.0, hull_radius_m=0.6)
    station = planner.choose(np.array(rov), np.array(asv), 0.0)
    if station is None:
        return
    x, y = station.position_xy
    assert 2.1 - 1e-9 <= x <= 28.0 - 2.1 + 1e-9
    assert 2.1 - 1e-9 <= y <= 16.0 - 2.1 + 1e-9
    view = planner.view(station.position_xy, station.heading_rad, np.array(rov))
    assert planner.view_is_good(view)
    assert abs(view.azimuth_rad) < math.radians(0.5)


def test_the_ideal_station_when_nothing_is_in_the_way() -> None:
    """Mid-tank, the ROV 3.5 m deep: the sonar's pitch (30 deg) puts it on the boresight."""
    planner = _planner()
    rov = np.array([16.0, 8.0, -3.5])
    station = planner.choose(rov, np.array([10.0, 8.0]), 0.0)
    assert station is not None
    assert abs(station.view.elevation_rad) < math.radians(0.5)
    drop = 3.5 - 0.2
    assert math.isclose(station.view.range_m, drop / math.sin(math.radians(30.0)), rel_tol=0.01)
    # The nearest such station to the ASV: on its side of the ROV, facing +x.
    assert station.position_xy[0] < rov[0]
    assert abs(station.heading_rad) < math.radians(5.0)


@settings(max_examples=30, deadline=None)
@given(direction=st.floats(-math.pi, math.pi), speed=st.floats(0.1, 0.5))
def test_a_moving_rov_is_watched_from_abeam(direction: float, speed: float) -> None:
    """Seen from ahead or behind, its depression changes as it flies; from abeam it hardly does."""
    planner = _planner()
    rov = np.array([14.0, 8.0, -3.0])
    velocity = speed * np.array([math.cos(direction), math.sin(direction), 0.0])
    station = planner.choose(rov, np.array([14.0, 8.0]), 0.0, rov_velocity_m_s=velocity)
    assert station is not None
    across = abs(wrap_angle(planner.bearing(station) - direction))
    assert abs(across - math.pi / 2) < math.radians(20.0)
    # Without its velocity the planner has no reason to prefer any side (the ASV is over it).
    still = planner.choose(rov, np.array([14.0, 8.0]), 0.0)
    assert still is not None


def test_two_equal_stations_do_not_take_turns() -> None:
    """A ROV midway between two equally good sides keeps the side it is watched from."""
    planner = _planner()
    rov = np.array([14.0, 8.0, -3.0])
    asv = np.array([14.0, 8.0])  # over the ROV: every bearing as near as the others
    for side in (math.pi / 2, -math.pi / 2):
        station = planner.choose(rov, asv, 0.0, current_bearing_rad=side)
        assert station is not None
        assert abs(wrap_angle(planner.bearing(station) - side)) < math.radians(10.0)


def test_keep_out_boxes_and_surface_fixtures_are_avoided() -> None:
    rov = np.array([16.0, 8.0, -3.5])
    free = _planner().choose(rov, np.array([10.0, 8.0]), 0.0)
    assert free is not None
    fx, fy = free.position_xy
    box = TankFixture(name="crane", lo_m=(fx - 1.0, fy - 1.0, -1.0), hi_m=(fx + 1.0, fy + 1.0, 2.0))
    blocked = _planner(keep_out=(box,)).choose(rov, np.array([10.0, 8.0]), 0.0)
    assert blocked is not None
    bx, by = blocked.position_xy
    assert not (fx - 2.1 <= bx <= fx + 2.1 and fy - 2.1 <= by <= fy + 2.1)
    with_post = StationPlanner(MOUNT, TankBounds(fixtures=(box,)), StationSettings()).choose(
        rov, np.array([10.0, 8.0]), 0.0
    )
    assert with_post is not None
    assert np.allclose(with_post.position_xy, blocked.position_xy)


def test_no_station_for_a_rov_at_the_surface() -> None:
    assert _planner().choose(np.array([16.0, 8.0, 0.0]), np.array([10.0, 8.0]), 0.0) is None


@given(
    asv=st.tuples(st.floats(2.0, 26.0), st.floats(2.0, 14.0)),
    heading=st.floats(-math.pi, math.pi),
    distance=st.floats(0.5, 20.0),
    depth=st.floats(0.5, 8.0),
)
def test_on_the_boresight_the_elevation_is_the_beam_models(
    asv: tuple[float, float], heading: float, distance: float, depth: float
) -> None:
    planner = _planner()
    sonar_xy = planner.sonar_xy(np.array(asv), heading)
    rov = np.array(
        [
            sonar_xy[0] + distance * math.cos(heading),
            sonar_xy[1] + distance * math.sin(heading),
            -depth,
        ]
    )
    view = planner.view(np.array(asv), heading, rov)
    body = Transform.from_euler_zyx(
        (asv[0], asv[1], 0.0), yaw_rad=heading, pitch_rad=0.0, roll_rad=0.0
    )
    r, azimuth, elevation = to_polar(
        "conical", body.compose(MOUNT.transform()).inverse().apply(rov)
    )
    assert abs(view.azimuth_rad) < 1e-9
    assert abs(azimuth) < 1e-6
    assert math.isclose(view.range_m, r, rel_tol=1e-9)
    assert math.isclose(view.elevation_rad, elevation, abs_tol=1e-6)


@given(
    asv=st.tuples(st.floats(2.0, 26.0), st.floats(2.0, 14.0)),
    heading=st.floats(-math.pi, math.pi),
    off=st.floats(-1.2, 1.2),
    distance=st.floats(0.5, 20.0),
    depth=st.floats(0.5, 8.0),
    model=st.sampled_from(["conical", "planar"]),
    pitch_deg=st.floats(0.0, 60.0),
)
def test_off_the_boresight_the_elevation_is_the_beam_models(
    asv: tuple[float, float],
    heading: float,
    off: float,
    distance: float,
    depth: float,
    model: Literal["conical", "planar"],
    pitch_deg: float,
) -> None:
    """A ROV up to 69 deg off the boresight (the hull not facing it): the beam model's elevation.

    (A conical beam puts such a ROV lower than the planar one: the follower's dead band and
    the path cost see it where the sonar does.)
    """
    mount = SonarMountConfig(pitch_deg=pitch_deg, beam_model=model)
    planner = StationPlanner(mount, TANK, StationSettings())
    sonar_xy = planner.sonar_xy(np.array(asv), heading)
    rov = np.array(
        [
            sonar_xy[0] + distance * math.cos(heading + off),
            sonar_xy[1] + distance * math.sin(heading + off),
            -depth,
        ]
    )
    view = planner.view(np.array(asv), heading, rov)
    body = Transform.from_euler_zyx(
        (asv[0], asv[1], 0.0), yaw_rad=heading, pitch_rad=0.0, roll_rad=0.0
    )
    r, _, elevation = to_polar(model, body.compose(mount.transform()).inverse().apply(rov))
    assert math.isclose(view.azimuth_rad, off, abs_tol=1e-9)
    assert math.isclose(view.range_m, r, rel_tol=1e-9)
    assert math.isclose(view.elevation_rad, elevation, abs_tol=1e-6)


def test_a_view_where_a_rack_shares_the_rovs_range_cell_is_avoided() -> None:
    """Seen along a rack's top, the ROV's echo merges with it: another bearing is chosen."""
    rov = np.array([16.0, 8.0, -3.5])
    free = _planner().choose(rov, np.array([10.0, 8.0]), 0.0)
    assert free is not None
    # A rack top 1.2 m under the ROV's level, along the free view's line of sight.
    rack = TankFixture(name="rack", lo_m=(14.0, 7.0, -8.0), hi_m=(16.5, 9.0, -4.7))
    planner = StationPlanner(MOUNT, TankBounds(fixtures=(rack,)), StationSettings())
    assert planner.masked(free.position_xy, free.heading_rad, rov)
    chosen = planner.choose(rov, np.array([10.0, 8.0]), 0.0)
    assert chosen is not None
    assert not planner.masked(chosen.position_xy, chosen.heading_rad, rov)
    assert planner.view_is_good(chosen.view)
    # Open water: the same view is not masked.
    assert not _planner().masked(free.position_xy, free.heading_rad, rov)


def test_a_rack_just_beyond_the_apertures_edge_masks_the_rov() -> None:
    """A fixture in the beam pattern's skirt at the ROV's range masks it; without a skirt not."""
    rov = np.array([16.0, 8.0, -3.5])
    planner = _planner()
    # The sonar looking along +x at the ROV from where it sits mid aperture.
    free = planner.choose(rov, np.array([10.0, 8.0]), 0.0)
    assert free is not None
    sonar = Transform.from_euler_zyx(
        (float(free.position_xy[0]), float(free.position_xy[1]), 0.0),
        yaw_rad=free.heading_rad,
        pitch_rad=0.0,
        roll_rad=0.0,
    ).compose(MOUNT.transform())
    r = free.view.range_m
    half = math.radians(MOUNT.vertical_aperture_deg) / 2.0
    # A small box at the ROV's range, 1.5 deg below the aperture's lower edge.
    local = np.array(
        [r * math.cos(half + math.radians(1.5)), 0.0, r * math.sin(half + math.radians(1.5))]
    )
    centre = sonar.apply(local)
    box = TankFixture(
        name="rack",
        lo_m=(float(centre[0]) - 0.05, float(centre[1]) - 0.05, float(centre[2]) - 0.05),
        hi_m=(float(centre[0]) + 0.05, float(centre[1]) + 0.05, float(centre[2]) + 0.05),
    )
    skirted = StationPlanner(MOUNT, TankBounds(fixtures=(box,)), StationSettings(mask_margin_m=0.0))
    nominal = StationPlanner(
        MOUNT, TankBounds(fixtures=(box,)), StationSettings(mask_margin_m=0.0, mask_skirt_rad=0.0)
    )
    assert skirted.masked(free.position_xy, free.heading_rad, rov)
    assert not nominal.masked(free.position_xy, free.heading_rad, rov)


def test_within_walls_moves_a_point_the_least_into_the_clearance_box() -> None:
    planner = StationPlanner(
        SonarMountConfig(), TankBounds(length_m=20.0, width_m=10.0), StationSettings()
    )
    s = planner.settings
    c = s.wall_clearance_m + s.hull_radius_m + s.tracking_margin_m
    inside = np.array([8.0, 5.0])
    assert np.allclose(planner.within_walls(inside), inside)
    assert np.allclose(planner.within_walls(np.array([-3.0, 5.0])), [c, 5.0])
    assert np.allclose(planner.within_walls(np.array([25.0, 12.0])), [20.0 - c, 10.0 - c])
    assert planner.clear(planner.within_walls(np.array([19.9, 0.1])))


def test_a_station_sees_the_rovs_leg_ahead_where_the_walls_stop_the_asv_backing_off() -> None:
    """The mockup's scale: the ROV waits at its lane's start, the ASV on the lane ahead.

    Without its path the planner keeps the ASV there (the ROV still: no drift cost), where
    the walls stop it backing off and the ROV would fly under the sonar; with it, the next
    1.5 m stays in view but for a few degrees (the ROV itself must be in view now). In a large
    tank the ASV backs off as the ROV comes: the same station costs nothing more.
    """
    mount = SonarMountConfig(pitch_deg=45.0)
    near = StationSettings(min_range_m=1.0, hull_radius_m=0.3, tracking_margin_m=0.2)
    mockup = StationPlanner(mount, TankBounds(length_m=4.8, width_m=3.6, depth_m=2.0), near)
    rov = np.array([3.0, 1.0, -1.0])
    path = rov + np.outer(np.arange(1, 7) * 0.25, [0.0, 1.0, 0.0])  # north, 1.5 m
    asv = np.array([3.0, 2.1])  # north of it, facing it: the ROV mid-aperture now
    here = mockup.choose(rov, asv, -math.pi / 2)
    assert here is not None
    beyond = mockup._beyond_margin_deg(here.position_xy, here.heading_rad, rov, path)
    chosen = mockup.choose(rov, asv, -math.pi / 2, path_m=path)
    assert chosen is not None
    seen = mockup._beyond_margin_deg(chosen.position_xy, chosen.heading_rad, rov, path)
    assert beyond > 50.0
    assert seen < 5.0
    assert mockup.view_is_good(chosen.view)
    large = StationPlanner(mount, TANK, near)
    offset = np.array([0.0, 10.0, 0.0])
    assert (
        large._beyond_margin_deg(
            here.position_xy + offset[:2], here.heading_rad, rov + offset, path + offset
        )
        == 0.0
    )


def test_a_steered_hull_stays_where_it_sees_the_rov_and_turns_to_it() -> None:
    """ArduRover's GUIDED turns a hull to its way: from a good place it only turns.

    The lateral planner moves to its ring's best station; the steered one stays where it is
    (a move would take the sonar off the ROV), turned to face the ROV.
    """
    rov = np.array([16.0, 8.0, -3.5])
    planner = _planner()
    # At the ideal distance, on a bearing between the planner's rings' (every 5 deg).
    bearing = math.radians(7.5)
    sonar_off = planner.ideal_distance(rov)
    here = rov[:2] - (sonar_off + MOUNT.position_m[0]) * np.array(
        [math.cos(bearing), math.sin(bearing)]
    )
    steered = _planner(drive="steered").choose(rov, here, 0.0)
    lateral = _planner(drive="lateral").choose(rov, here, 0.0)
    assert steered is not None
    assert lateral is not None
    assert float(np.linalg.norm(steered.position_xy - here)) < 1e-9
    assert abs(steered.view.azimuth_rad) < math.radians(0.5)
    assert float(np.linalg.norm(lateral.position_xy - here)) > 0.05


def test_a_steered_hull_is_blind_on_a_way_off_the_rov_and_not_on_one_at_it() -> None:
    """The blind seconds: turning to the way, driving, turning to the station's heading."""
    planner = _planner(drive="steered", transit_speed_m_s=0.5, turn_rate_rad_s=math.radians(15.0))
    rov = np.array([16.0, 8.0, -3.5])
    here = np.array([8.0, 8.0])
    # Straight at the ROV: the sonar stays on it.
    assert planner.blind_s(here, 0.0, np.array([9.0, 8.0]), 0.0, rov) == 0.0
    # Abeam, 2 m: 90 deg out, 4 s, 90 deg back = 6 + 4 + 6 s.
    assert math.isclose(
        planner.blind_s(here, 0.0, np.array([8.0, 10.0]), 0.0, rov), 16.0, rel_tol=1e-9
    )
    # No move (the autopilot's arrival): no way to be blind on.
    assert planner.blind_s(here, 0.0, here + 0.01, 1.0, rov) == 0.0


def test_a_steered_hull_is_blind_on_a_way_over_the_rov() -> None:
    """A way to the ROV's far side starts at the ROV but goes round it (the follower's spiral).

    Driving at the ROV keeps the sonar on it only until the ROV sinks under the aperture; the
    follower then goes round, across the line of sight (`capsd bench follow`, nfp: charged as
    a way at the ROV, such a station was chosen again at each reacquisition and the mission
    stalled at a lane's end).
    """
    planner = _planner(drive="steered", transit_speed_m_s=0.5, turn_rate_rad_s=math.radians(15.0))
    rov = np.array([16.0, 8.0, -3.5])
    here = np.array([10.0, 8.2])
    far_side = np.array([22.0, 7.8])
    blind = planner.blind_s(here, 0.0, far_side, math.pi, rov)
    # Half a turn round at 6 m: about 19 m at 0.5 m/s, and the turns.
    assert blind > 35.0
    assert planner.blind_s(here, 0.0, np.array([12.0, 8.1]), 0.0, rov) == 0.0  # at it, short


def test_a_steered_station_ahead_sees_a_rov_flying_at_it_by_backing_away() -> None:
    """The ROV's leg along the line of sight, at the station: the hull keeps pace astern.

    Turning where it stands, the station would see the ROV pass under its aperture; a steered
    hull backs away along the line of sight facing the ROV (MAV_CMD_DO_SET_REVERSE), the
    sonar on it all the way, so the path cost counts only what the walls stop it seeing.
    """
    planner = _planner(drive="steered")
    rov = np.array([20.0, 8.0, -4.0])
    lane = rov + np.outer(np.arange(1, 49) * 0.25, [-1.0, 0.0, 0.0])  # 12 m west, at the ASV
    here = rov[:2] - (planner.ideal_distance(rov) + MOUNT.position_m[0]) * np.array([1.0, 0.0])
    heading = 0.0
    paced = planner._beyond_margin_deg(here, heading, rov, lane)
    # Backing away from x = 13.2 to the walls' clearance (2.1 m): only the last metres unseen.
    stay_only = sum(
        max(
            0.0,
            abs(planner.view(here, planner.facing(here, p), p).elevation_rad)
            - (planner.half_aperture - planner.settings.elevation_margin_rad),
        )
        for p in lane
    )
    assert math.degrees(stay_only) > 200.0
    assert paced < 0.1 * math.degrees(stay_only)


def test_a_steered_hull_backs_away_from_the_rov_facing_it() -> None:
    """Astern (MAV_CMD_DO_SET_REVERSE) the sonar stays on the ROV: no blind seconds."""
    from capsd.services.asv_follow.station import drive_heading

    planner = _planner(drive="steered")
    rov = np.array([16.0, 8.0, -3.5])
    here = np.array([8.0, 8.0])
    assert planner.blind_s(here, 0.0, np.array([7.0, 8.0]), 0.0, rov) == 0.0
    hull, direction = drive_heading(math.pi, 0.0)
    assert hull == pytest.approx(0.0)
    assert direction == "reverse"
    # Across the ROV's bearing: ahead, and the current direction kept within the margin.
    assert drive_heading(math.pi / 2, 0.0)[1] == "forward"
    assert drive_heading(math.radians(100.0), 0.0, current="reverse")[1] == "reverse"
    assert drive_heading(math.radians(100.0), 0.0, current="forward")[1] == "forward"


def test_a_steered_hull_too_near_the_rov_backs_straight_away_from_it() -> None:
    """Too near, between the rings' bearings: the station is on the line of sight, astern.

    (A ring's point 2.5 deg round was a way 48 deg off the ROV astern: the sonar off it, lost
    for 5 s in an nfp run.)
    """
    from capsd.services.asv_follow.station import drive_heading

    planner = _planner(drive="steered")
    rov = np.array([16.0, 8.0, -3.5])
    bearing = math.radians(2.5)  # from the ASV to the ROV, between two rings' bearings
    here = rov[:2] - 4.8 * np.array([math.cos(bearing), math.sin(bearing)])
    station = planner.choose(rov, here, bearing)
    assert station is not None
    way = station.position_xy - here
    hull, direction = drive_heading(math.atan2(way[1], way[0]), planner.facing(here, rov))
    assert direction == "reverse"
    assert abs(wrap_angle(hull - planner.facing(here, rov))) < math.radians(1.0)
    assert planner.blind_s(here, bearing, station.position_xy, station.heading_rad, rov) == 0.0


def test_a_steered_hull_takes_a_station_that_sees_the_rest_of_the_lane() -> None:
    """The nfp lawnmower's lane at y = 10 m, the ASV north of it after the lane before.

    North of this lane the walls leave the ASV 4 m at most: stations abeam look at the ROV from
    40-60 deg off the lane, and each move after it along the lane is across the line of sight,
    blind for a steered hull (ArduRover SITL, docs/JOURNAL.md session 33). With the rest of the
    lane as its path (the steered default) the planner takes a station from which the hull, pursuing
    the ROV along the line of sight alone, keeps the whole lane inside the aperture's margin:
    ahead of the ROV, about along the lane, backing away before it facing it (since session
    38 on whichever side of the lane's line that pursuit works out; one move there, against
    727 degrees unseen staying). With the next 1.5 m (the lateral default) a station the ROV
    soon flies out of the view of.
    """
    from capsd.services.asv_follow.service import MotionConfig, StationConfig

    drive = MotionConfig().drive_settings(StationConfig().settings())
    planner = StationPlanner(MOUNT, TANK, drive)
    rov = np.array([22.0, 10.0, -4.0])
    lane = rov + np.outer(np.arange(1, 65) * 0.25, [-1.0, 0.0, 0.0])  # west to x = 6 m
    asv, heading = np.array([16.8, 12.8]), math.radians(-40.0)
    reach = MotionConfig().settings().path_ahead_m
    assert reach >= 16.0
    whole = planner.choose(rov, asv, heading, path_m=lane[: int(reach / 0.25)])
    near = planner.choose(rov, asv, heading, path_m=lane[:6])
    assert whole is not None
    assert near is not None
    unseen_whole = planner._beyond_margin_deg(whole.position_xy, whole.heading_rad, rov, lane)
    unseen_near = planner._beyond_margin_deg(near.position_xy, near.heading_rad, rov, lane)
    assert unseen_whole < 0.02 * unseen_near
    assert unseen_whole < 1.0
    stay = planner._beyond_margin_deg(asv, planner.facing(asv, rov), rov, lane)
    assert stay > 100.0 * max(unseen_whole, 1.0)
    assert float(near.position_xy[1]) > 10.0
    sight = whole.view.azimuth_rad + whole.heading_rad + planner.mount_yaw
    assert abs(wrap_angle(sight)) < math.radians(25.0)  # looking along the lane, east
    lateral = msgspec.convert({"drive": "lateral"}, MotionConfig).settings()
    assert lateral.path_ahead_m == pytest.approx(1.5)


def test_a_steered_hull_pursues_along_the_sight_and_a_wall_that_stops_it_costs_blind_time() -> None:
    """A ROV flying west at the west wall, then north (the nfp lawnmower's lane end).

    The hull watches by turning and moves only along the line of sight, which carries the
    bearing round as the ROV goes on (docs/JOURNAL.md session 38). From ahead of the ROV on its lane
    it backs into the wall's clearance and must slide along the wall, blind; from 20-40 deg
    north of the lane the lane stays in view but the leg after it comes at the hull; from as
    far south nothing leaves the aperture's margin. (Every point weighed alike: the pursuit's
    geometry alone.)
    """
    planner = _planner(drive="steered", path_discount_m=0.0)
    rov = np.array([12.0, 8.0, -4.0])
    lane = rov + np.outer(np.arange(1, 25) * 0.25, [-1.0, 0.0, 0.0])  # to x = 6 m
    turn = np.array([6.0, 8.0, -4.0]) + np.outer(np.arange(1, 9) * 0.25, [0.0, 1.0, 0.0])
    path = np.vstack([lane, turn])
    distance = planner.ideal_distance(rov) + MOUNT.position_m[0]

    def station(off_lane_deg: float) -> np.ndarray:
        bearing = math.radians(180.0 - off_lane_deg)
        here = rov[:2] + distance * np.array([math.cos(bearing), math.sin(bearing)])
        assert planner.clear(here)
        return here

    s = planner.settings
    one_slide_deg = s.blind_cost_per_s / s.path_cost_per_deg * math.pi / s.turn_rate_rad_s
    ahead = planner._beyond_margin_deg(station(0.0), 0.0, rov, path)
    assert ahead > one_slide_deg  # into the wall, then along it
    for north in (20.0, 40.0):
        assert planner._beyond_margin_deg(station(north), 0.0, rov, lane) == 0.0
        assert planner._beyond_margin_deg(station(north), 0.0, rov, path) > 100.0
    for south in (-20.0, -40.0):
        assert planner._beyond_margin_deg(station(south), 0.0, rov, path) == 0.0
    # Without the pursuit (the hull turning where it stands) the south station would not see
    # the lane's end: it is the move along the sight that keeps it.
    here = station(-20.0)
    limit = planner.half_aperture - s.elevation_margin_rad
    assert any(
        abs(planner.view(here, planner.facing(here, p), p).elevation_rad) > limit for p in path
    )


def test_a_steered_hull_does_not_turn_off_the_rov_now_for_the_legs_far_end() -> None:
    """Session 40's nfp demo, seed 1, t = 101 s (its recorded fix, pose and leg).

    The ROV flies at the hull along the lane y = 6 m, 6 m off; the lane ends 12 m on, near the
    west wall, where backing away along the line of sight runs into the wall's clearance. With
    every point of the leg weighed alike, that far end's cost outweighed 10 s blind now: the
    hull turned to a station 1.5 m across the line of sight and lost the ROV for 6 s. Weighed
    down with the distance along the leg, the hull stays on the line of sight.
    """
    rov = np.array([17.78, 6.01, -3.99])
    here, heading = np.array([11.43, 5.72]), 0.0437
    lane = np.array(
        [[x, 6.0, -4.0] for x in np.arange(18.336, 6.0, -0.25)]
        + [[6.0, y, -4.0] for y in np.arange(6.25, 8.01, 0.25)]
    )
    blind = {}
    for discount in (0.0, 10.0):
        planner = StationPlanner(
            MOUNT,
            TANK,
            StationSettings(
                drive="steered",
                target_elevation_rad=math.radians(-3.0),
                transit_speed_m_s=0.5,
                path_discount_m=discount,
            ),
        )
        chosen = planner.choose(
            rov,
            here,
            heading,
            rov_velocity_m_s=np.array([-0.267, 0.028]),
            current_bearing_rad=0.0873,
            path_m=lane,
        )
        assert chosen is not None
        blind[discount] = planner.blind_s(
            here, heading, chosen.position_xy, chosen.heading_rad, rov
        )
    assert blind[0.0] > 5.0
    assert blind[10.0] == 0.0


def test_the_path_weights_fall_with_the_distance_along_the_path() -> None:
    path = np.array([[0.0, 0.0, -4.0], [3.0, 4.0, -4.0], [3.0, 14.0, -4.0]])
    weights = _planner(path_discount_m=5.0)._path_weights(path)
    assert weights == pytest.approx([1.0, math.exp(-1.0), math.exp(-3.0)])
    assert _planner(path_discount_m=0.0)._path_weights(path) == pytest.approx([1.0, 1.0, 1.0])


SERVO = msgspec.convert(
    {"pitch_deg": 45.0, "tilt": {"min_deg": -15.0, "max_deg": 40.0}}, SonarMountConfig
)


@given(
    asv=st.tuples(st.floats(2.0, 26.0), st.floats(2.0, 14.0)),
    heading=st.floats(-math.pi, math.pi),
    rov=st.tuples(st.floats(1.0, 27.0), st.floats(1.0, 15.0), st.floats(-7.5, -1.0)),
    target_deg=st.floats(-5.0, 5.0),
)
def test_the_servo_angle_puts_the_rov_at_the_target_elevation_or_is_at_a_limit(
    asv: tuple[float, float], heading: float, rov: tuple[float, float, float], target_deg: float
) -> None:
    """What the follower tilts the sonar to, checked through the beam model (conical)."""
    planner = StationPlanner(
        SERVO, TANK, StationSettings(target_elevation_rad=math.radians(target_deg))
    )
    tilt = planner.tilt_rad(np.array(asv), heading, np.array(rov))
    lo, hi = math.radians(-15.0), math.radians(40.0)
    assert lo - 1e-12 <= tilt <= hi + 1e-12
    body = Transform.from_euler_zyx(
        (asv[0], asv[1], 0.0), yaw_rad=heading, pitch_rad=0.0, roll_rad=0.0
    )
    sonar = body.compose(SERVO.transform(tilt_rad=tilt))
    _, _, elevation = to_polar("conical", sonar.inverse().apply(np.array(rov)))
    if lo + 1e-9 < tilt < hi - 1e-9:
        assert elevation == pytest.approx(math.radians(target_deg), abs=1e-9)
    elif tilt >= hi - 1e-9:
        assert elevation < math.radians(target_deg) + 1e-9  # too steep below: tilted fully down
    else:
        assert elevation > math.radians(target_deg) - 1e-9  # too shallow: tilted fully up


def test_no_servo_no_tilt_and_the_stations_are_chosen_for_its_zero() -> None:
    """Stations are the fixed sonar's: the servo only keeps the ROV centred between them."""
    rov, asv = np.array([10.0, 8.0, -4.0]), np.array([4.0, 8.0])
    assert _planner().tilt_rad(asv, 0.0, rov) == 0.0
    below = StationSettings(target_elevation_rad=math.radians(-3.0))
    fixed = StationPlanner(msgspec.structs.replace(SERVO, tilt=None), TANK, below)
    tilted = StationPlanner(SERVO, TANK, below)
    a, b = fixed.choose(rov, asv, 0.0), tilted.choose(rov, asv, 0.0)
    assert a is not None
    assert b is not None
    assert np.allclose(a.position_xy, b.position_xy)
    assert a.heading_rad == b.heading_rad
    # ... where the servo's zero sees it at the target, the servo stays at its zero; moved
    # nearer, it tilts down by the depression gained.
    assert b.view.elevation_rad == pytest.approx(math.radians(-3.0), abs=1e-6)
    assert tilted.tilt_rad(b.position_xy, b.heading_rad, rov) == pytest.approx(0.0, abs=1e-6)
    way = rov[:2] - b.position_xy
    nearer = b.position_xy + 0.5 * way / np.linalg.norm(way)
    steeper = tilted.view(nearer, b.heading_rad, rov).elevation_rad
    assert steeper < b.view.elevation_rad
    assert tilted.tilt_rad(nearer, b.heading_rad, rov) == pytest.approx(
        b.view.elevation_rad - steeper, abs=1e-6
    )


@settings(max_examples=60, deadline=None)
@given(
    asv=st.tuples(st.floats(2.0, 26.0), st.floats(2.0, 14.0)),
    heading=st.floats(-math.pi, math.pi),
    off_deg=st.floats(-85.0, 85.0),
    distance=st.floats(0.5, 15.0),
    depression_deg=st.floats(20.0, 65.0),
)
def test_the_pan_and_tilt_put_the_rov_on_the_boresight_wherever_the_hull_faces(
    asv: tuple[float, float], heading: float, off_deg: float, distance: float,
    depression_deg: float,
) -> None:  # fmt: skip
    """Within the servos' ranges: the ROV at azimuth 0 and the target elevation."""
    mount = msgspec.convert({"tilt": {}, "pan": {}}, SonarMountConfig)
    planner = StationPlanner(mount, TANK, StationSettings(target_elevation_rad=-0.05))
    # The ROV `off_deg` off the bow from the sonar, `depression_deg` down: both servos reach it.
    sonar = planner.sonar_xy(np.array(asv), heading)
    bearing = heading + math.radians(off_deg)
    look = np.array(
        [
            sonar[0] + distance * math.cos(bearing),
            sonar[1] + distance * math.sin(bearing),
            planner.sonar_z - distance * math.tan(math.radians(depression_deg)),
        ]
    )
    pan, tilt = planner.pan_tilt_rad(np.array(asv), heading, look)
    assert pan == pytest.approx(math.radians(off_deg), abs=1e-9)
    body = Transform.from_euler_zyx(
        (asv[0], asv[1], 0.0), yaw_rad=heading, pitch_rad=0.0, roll_rad=0.0
    )
    seen = body.compose(mount.transform(tilt_rad=tilt, pan_rad=pan))
    _, azimuth, elevation = to_polar("conical", seen.inverse().apply(look))
    assert abs(azimuth) < 1e-6
    assert elevation == pytest.approx(-0.05, abs=1e-6)
    # Without a pan servo: the tilt alone, as before.
    plain = StationPlanner(
        msgspec.structs.replace(mount, pan=None), TANK, StationSettings(target_elevation_rad=-0.05)
    )
    assert plain.pan_tilt_rad(np.array(asv), heading, look) == (
        0.0,
        plain.tilt_rad(np.array(asv), heading, look),
    )


@settings(max_examples=60, deadline=None)
@given(
    asv=st.tuples(st.floats(2.0, 26.0), st.floats(2.0, 14.0)),
    heading=st.floats(-math.pi, math.pi),
    rov=st.tuples(st.floats(1.0, 27.0), st.floats(1.0, 15.0), st.floats(-7.5, -1.0)),
    tilt_deg=st.floats(-15.0, 40.0),
    pan_deg=st.floats(-90.0, 90.0),
    beam=st.sampled_from(["planar", "conical"]),
)
def test_the_view_and_the_mask_with_the_servos_turned_are_those_of_a_mount_turned_as_far(
    asv: tuple[float, float], heading: float, rov: tuple[float, float, float],
    tilt_deg: float, pan_deg: float, beam: Literal["planar", "conical"],
) -> None:  # fmt: skip
    """A servo's angle is the mount's pitch (tilt) or yaw (pan) plus it, the sonar unmoved."""
    servos = msgspec.convert(
        {"tilt": {}, "pan": {}, "beam_model": beam, "roll_deg": 0.0}, SonarMountConfig
    )
    turned = msgspec.structs.replace(
        servos,
        tilt=None,
        pan=None,
        pitch_deg=servos.pitch_deg + tilt_deg,
        yaw_deg=servos.yaw_deg + pan_deg,
    )
    fixtures = (TankFixture(name="rack", lo_m=(8.0, 4.0, -8.0), hi_m=(12.0, 6.0, -5.0)),)
    tank = msgspec.structs.replace(TANK, fixtures=fixtures)
    a = StationPlanner(servos, tank, StationSettings())
    b = StationPlanner(turned, tank, StationSettings())
    at, there = np.array(asv), np.array(rov)
    tilt, pan = math.radians(tilt_deg), math.radians(pan_deg)
    va = a.view(at, heading, there, tilt_rad=tilt, pan_rad=pan)
    vb = b.view(at, heading, there)
    assert va.range_m == pytest.approx(vb.range_m, abs=1e-9)
    assert wrap_angle(va.azimuth_rad - vb.azimuth_rad) == pytest.approx(0.0, abs=1e-9)
    assert va.elevation_rad == pytest.approx(vb.elevation_rad, abs=1e-9)
    assert a.masked(at, heading, there, tilt_rad=tilt, pan_rad=pan) == b.masked(at, heading, there)


def test_the_reached_view_is_the_servos_aim_and_without_servos_the_view() -> None:
    """What a pre-dive check judges: the ROV on the boresight at the target elevation."""
    rov = np.array([14.0, 9.0, -3.0])
    asv = np.array([9.0, 8.0])
    fixed = _planner(target_elevation_rad=-0.05)
    view, tilt, pan = fixed.reached_view(asv, 0.0, rov)
    assert (tilt, pan) == (0.0, 0.0)
    assert view == fixed.view(asv, 0.0, rov)
    mount = msgspec.convert({"tilt": {}, "pan": {}}, SonarMountConfig)
    servos = StationPlanner(mount, TANK, StationSettings(target_elevation_rad=-0.05))
    view, tilt, pan = servos.reached_view(asv, 1.0, rov)  # the ROV about 49 deg off the bow
    assert (pan, tilt) == servos.pan_tilt_rad(asv, 1.0, rov)
    assert abs(view.azimuth_rad) < 1e-9
    assert view.elevation_rad == pytest.approx(-0.05, abs=1e-9)


def test_stations_keep_the_preferred_range_where_any_can_and_the_minimum_where_none_can() -> None:
    """The mockup's pan-tilt rules: 1.2 m off where a station can be, 1.1 m on the middle lane."""
    from capsd.harness import follow_config

    config = follow_config("mockup", tilt="pan-tilt")
    settings = config.motion.drive_settings(config.station.settings())
    assert (settings.min_range_m, settings.preferred_min_range_m) == (1.1, 1.2)
    planner = StationPlanner(config.sonar, config.tank, settings)
    strict = StationPlanner(
        config.sonar,
        config.tank,
        dataclasses.replace(settings, min_range_m=1.2, preferred_min_range_m=None),
    )
    asv = np.array([2.4, 1.8])
    # A lane's end by the wall: stations 1.2 m off exist, and are taken.
    end = np.array([3.8, 1.0, -1.0])
    chosen = planner.choose(end, asv, 0.0)
    assert chosen is not None
    assert chosen.view.range_m >= 1.2
    # Mid tank, on the lane through the ASV's box: none keeps 1.2 m, one keeps 1.1 m.
    middle = np.array([2.2, 1.67, -1.0])
    assert strict.choose(middle, asv, 0.0) is None
    chosen = planner.choose(middle, asv, 0.0)
    assert chosen is not None
    assert 1.1 <= chosen.view.range_m < 1.2
    assert planner.view_is_good(chosen.view)
    assert not planner.view_is_good(chosen.view, min_range_m=1.2)


def test_the_preferred_range_is_checked_against_the_band() -> None:
    from capsd.errors import ConfigError
    from capsd.services.asv_follow.service import StationConfig

    with pytest.raises((ValueError, ConfigError), match="preferred_min_range_m"):
        StationConfig(min_range_m=2.0, preferred_min_range_m=1.5)
    with pytest.raises((ValueError, ConfigError), match="preferred_min_range_m"):
        StationConfig(max_range_m=15.0, preferred_min_range_m=15.0)
    assert StationConfig(preferred_min_range_m=2.5).settings().preferred_min_range_m == 2.5


@pytest.mark.parametrize("pan", [True, False])
def test_a_big_turn_goes_the_way_that_keeps_the_rov_in_reach(pan: bool) -> None:
    """From 20 deg to -138 deg, the ROV at 145 deg: with a pan the long way (+202) keeps it.

    (The pan holds the ROV from 55 deg on; without one the long way sees it for 40 deg only,
    not worth its 44 extra degrees.)
    """
    mount = msgspec.convert({"tilt": {}, "pan": {}} if pan else {}, SonarMountConfig)
    planner = StationPlanner(mount, TANK, StationSettings(drive="steered"))
    asv = np.array([10.0, 8.0])
    heading = math.radians(20.0)
    short = wrap_angle(math.radians(-138.0) - heading)
    assert short == pytest.approx(math.radians(-158.0))
    behind = asv + 2.0 * np.array([math.cos(math.radians(145.0)), math.sin(math.radians(145.0))])
    rov = np.array([behind[0], behind[1], -1.0])
    turn = planner.turn_keeping_view(asv, heading, short, rov)
    assert turn == pytest.approx(short + 2.0 * math.pi if pan else short)
    # The ROV on the short way's side (at -60 deg): the short way.
    side = asv + 2.0 * np.array([math.cos(math.radians(-60.0)), math.sin(math.radians(-60.0))])
    assert planner.turn_keeping_view(asv, heading, short, np.array([*side, -1.0])) == short
    # A turn under 90 deg is never made the long way.
    assert planner.turn_keeping_view(asv, heading, math.radians(-80.0), rov) == math.radians(-80.0)
