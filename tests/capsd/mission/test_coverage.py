"""Where the ASV can watch a plan from: the path sampled, fewest stops, `capsd mission check`."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import msgspec
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capsd.cli import main
from capsd.harness import follow_config
from capsd.mission.coverage import METRE_S, coverage, fewest_stops, hull_turns, sample_path
from capsd.mission.plan import Waypoint, load_plan
from capsd.services.asv_follow.service import Config as FollowConfig
from capsd.services.asv_follow.station import StationPlanner

REPO = Path(__file__).resolve().parents[3]
MOCKUP_PLAN = REPO / "deploy/missions/mockup-lawnmower.yaml"

corner = st.tuples(st.floats(0.0, 20.0), st.floats(0.0, 20.0), st.floats(-5.0, -0.5))


@settings(max_examples=60, deadline=None)
@given(corners=st.lists(corner, min_size=2, max_size=6), step=st.floats(0.05, 2.0))
def test_the_sampled_path_passes_every_waypoint_no_step_apart(
    corners: list[tuple[float, float, float]], step: float
) -> None:
    points = [Waypoint(c) for c in corners]
    path, leg, along = sample_path(points, step)
    # Each waypoint is a sample: the last one on its leg (or the first point).
    for k, c in enumerate(corners):
        last = np.flatnonzero(leg == k)[-1]
        assert np.allclose(path[last], c)
    gaps = np.linalg.norm(np.diff(path, axis=0), axis=1)
    assert np.all(gaps <= step + 1e-9)
    assert np.all(np.diff(leg) >= 0)
    for k in range(1, len(corners)):
        on = along[leg == k]
        assert np.all(np.diff(on) > 0)
        assert on[-1] == pytest.approx(math.dist(corners[k - 1], corners[k]))


def _fewest_by_search(seen: np.ndarray) -> int:
    """The fewest runs of consecutive seen points that one place sees whole, by brute force."""
    rows = [i for i in range(len(seen)) if seen[i].any()]
    best = len(rows)
    # A cut before point i (i in rows[1:]); runs never span an unseen point.
    for cuts in itertools.product((False, True), repeat=max(len(rows) - 1, 0)):
        runs, start = 0, 0
        feasible = True
        for i in range(len(rows)):
            end = i == len(rows) - 1 or cuts[i] or rows[i + 1] != rows[i] + 1
            if end:
                if not np.logical_and.reduce(seen[rows[start : i + 1]], axis=0).any():
                    feasible = False
                    break
                runs += 1
                start = i + 1
        if feasible:
            best = min(best, runs)
    return best


@settings(max_examples=80, deadline=None)
@given(
    seen=st.integers(1, 8).flatmap(
        lambda n: st.lists(st.lists(st.booleans(), min_size=4, max_size=4), min_size=n, max_size=n)
    )
)
def test_fewest_stops_is_the_fewest_and_each_place_sees_its_whole_stretch(
    seen: list[list[bool]],
) -> None:
    matrix = np.array(seen, dtype=bool)
    stretches = fewest_stops(matrix)
    assert len(stretches) == _fewest_by_search(matrix)
    covered: list[int] = []
    for first, last, places in stretches:
        assert len(places) > 0
        assert matrix[first : last + 1][:, places].all()
        covered += range(first, last + 1)
    assert covered == [i for i in range(len(matrix)) if matrix[i].any()]


def test_fewest_stops_by_hand() -> None:
    seen = np.array([[1, 1, 0], [0, 1, 1], [0, 0, 1], [0, 0, 0], [1, 0, 0], [1, 0, 1]], dtype=bool)
    stretches = [(a, b, list(p)) for a, b, p in fewest_stops(seen)]
    # Place 1 sees points 0-1; 2 sees point 2; nothing sees 3; place 0 sees 4-5.
    assert stretches == [(0, 1, [1]), (2, 2, [2]), (4, 5, [0])]


@pytest.fixture(scope="module")
def mockup() -> tuple[StationPlanner, list[Waypoint]]:
    config = follow_config("mockup")
    planner = StationPlanner(
        config.sonar, config.tank, config.motion.drive_settings(config.station.settings())
    )
    _, points = load_plan(MOCKUP_PLAN, tank=config.tank)
    return planner, points


def test_each_stop_of_the_mockup_plan_sees_its_stretch_and_the_middle_lane_only_from_the_east(
    mockup: tuple[StationPlanner, list[Waypoint]],
) -> None:
    planner, points = mockup
    found = coverage(planner, points, path_step_m=0.1, place_step_m=0.05)
    assert found.seen_any.all()
    covered: list[int] = []
    for stretch in found.stretches:
        place = np.array(stretch.station_xy)
        assert planner.clear(place)
        for point in found.path_m[stretch.first : stretch.last + 1]:
            view = planner.view(place, planner.facing(place, point), point)
            assert planner.view_is_good(view)
        covered += range(stretch.first, stretch.last + 1)
    assert covered == list(range(len(found.path_m)))
    # The least blind route: a place that sees each point, never blinder than the stops (it
    # may keep to them; only its tie-break by metres moved can trade a little), and not
    # without a blind move: the crossing to the east side cannot be made facing the ROV.
    route = found.route
    assert route is not None
    for sample, place in enumerate(route.places):
        assert found.seen[sample, place]
    stops_blind = sum(s.blind_s for s in found.stretches)
    stops_moved = sum(s.move_m for s in found.stretches)
    assert route.blind_s <= stops_blind + METRE_S * stops_moved
    assert route.blind_s > 0.0
    assert route.moves >= len(found.stretches) - 1
    # The lane at x = 2.2 m, mid tank: from the west the ASV's origin stays 1.5 m off the wall
    # and its sonar sits 0.3 m ahead of it, nearer the lane than the 0.63 m a ROV 0.8 m below
    # it needs to be inside the aperture's lower margin (45 + 10 - 3 deg down).
    lane = (np.abs(found.path_m[:, 0] - 2.2) < 1e-6) & (np.abs(found.path_m[:, 1] - 1.8) < 0.25)
    assert lane.any()
    for i in np.flatnonzero(lane):
        assert np.all(found.places_xy[found.seen[i], 0] > 2.2)


def test_mission_check_draws_writes_and_passes_the_mockup_plan(tmp_path: Path) -> None:
    png, out = tmp_path / "check.png", tmp_path / "check.json"
    args = ["mission", "check", str(MOCKUP_PLAN), "--tank", "mockup"]
    assert main([*args, "--png", str(png), "--json", str(out)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    figures = json.loads(out.read_text())
    n = len(figures["path_m"])
    assert len(figures["leg"]) == len(figures["seen"]) == n
    assert all(figures["seen"])
    assert len(figures["route"]["station_xy_m"]) == n
    # The stops cover the path in order, one after another.
    stops = figures["stops"]
    assert stops[0]["first"] == 0
    assert stops[-1]["last"] == n - 1
    assert all(b["first"] == a["last"] + 1 for a, b in itertools.pairwise(stops))


def test_mission_check_fails_a_point_no_place_sees(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    # 0.1 m deep: above the sonar (0.2 m down), which looks down only.
    plan = tmp_path / "shallow.yaml"
    plan.write_text(
        "name: shallow\n"
        "points:\n"
        "  - {position_m: [2.4, 1.8], depth_m: 1.0}\n"
        "  - {position_m: [2.4, 1.8], depth_m: 0.1}\n"
        "clearance_m: 0.05\n"
    )
    assert main(["mission", "check", str(plan), "--tank", "mockup"]) == 1
    out = capfd.readouterr().out
    assert "NOT seen from any place" in out


def test_mission_check_names_a_bad_follower_config(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    config = tmp_path / "asv_follow.yaml"
    config.write_text("station:\n  min_range_m: -1\n")
    assert main(["mission", "check", str(MOCKUP_PLAN), "--follow-config", str(config)]) == 2
    err = capfd.readouterr().err
    assert str(config) in err
    assert "min_range_m" in err


def test_mission_check_says_when_the_asv_has_nowhere_to_be(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    # A 3 x 3 m tank: the default follower keeps its origin 2.1 m off every wall.
    config = tmp_path / "asv_follow.yaml"
    config.write_text("tank: {length_m: 3.0, width_m: 3.0, depth_m: 2.0}\n")
    plan = tmp_path / "one.yaml"
    plan.write_text(
        "name: one\npoints:\n  - {position_m: [1.5, 1.5], depth_m: 1.0}\nclearance_m: 0.2\n"
    )
    assert main(["mission", "check", str(plan), "--follow-config", str(config)]) == 1
    out = capfd.readouterr().out
    assert "NO place in this 3 x 3 m tank" in out
    assert "fewest ASV stops: 0" in out


def _planner_for(config: FollowConfig) -> StationPlanner:
    return StationPlanner(
        config.sonar, config.tank, config.motion.drive_settings(config.station.settings())
    )


def test_the_servos_see_the_mockup_plan_from_stations_further_off_than_a_fixed_sonar_can(
    mockup: tuple[StationPlanner, list[Waypoint]],
) -> None:
    """With the ROV kept 1.2 m off, pan-tilt servos see the plan; a sonar fixed at 45 deg cannot.

    (The demo's pan-tilt rules prefer 1.2 m, `preferred_min_range_m`; here it is the minimum.)
    """
    _, points = mockup
    pan_tilt = follow_config("mockup", tilt="pan-tilt")
    station = msgspec.structs.replace(pan_tilt.station, min_range_m=1.2)
    servos = msgspec.structs.replace(pan_tilt, station=station)
    fixed = msgspec.structs.replace(follow_config("mockup"), station=station)
    blind = coverage(_planner_for(fixed), points, path_step_m=0.1, place_step_m=0.075)
    assert not blind.seen_any.all()
    planner = _planner_for(servos)
    found = coverage(planner, points, path_step_m=0.1, place_step_m=0.075)
    assert found.seen_any.all()
    # What a seen point's view is with the servos where the follower turns them, from some
    # heading of the hull the pan allows (facing, or turned off the ROV).
    turns = hull_turns(planner)
    assert turns[0] == 0.0
    for i in range(0, len(found.path_m), 7):
        point = found.path_m[i]
        place = found.places_xy[int(np.flatnonzero(found.seen[i])[0])]
        facing = planner.facing(place, point)
        views = [planner.reached_view(place, facing + t, point)[0] for t in turns]
        assert any(planner.view_is_good(v) and v.range_m >= 1.2 for v in views)


def test_a_pan_lets_the_hull_turn_within_its_range_less_the_margin() -> None:
    config = follow_config("mockup", tilt="pan-tilt")
    assert config.sonar.pan is not None
    pan = msgspec.structs.replace(config.sonar.pan, min_deg=-50.0, max_deg=90.0)
    sonar = msgspec.structs.replace(config.sonar, pan=pan)
    planner = StationPlanner(sonar, config.tank, config.station.settings())
    turns = [round(math.degrees(t), 6) for t in hull_turns(planner)]
    # Turned left (+) the pan turns right, to -50 deg at most: 35 deg with the margin.
    assert turns == [0.0, 35.0, -45.0, -75.0]
    assert hull_turns(_planner_for(follow_config("mockup", tilt="servo"))) == [0.0]


def test_mission_check_takes_the_demos_servos_only_with_a_simulated_tank(
    capfd: pytest.CaptureFixture[str],
) -> None:
    args = ["mission", "check", str(MOCKUP_PLAN), "--sonar-tilt", "pan-tilt"]
    assert main(args) == 2
    assert "--sonar-tilt goes with --tank" in capfd.readouterr().err
    assert main([*args, "--tank", "mockup"]) == 0
    assert "pan-tilt servos" in capfd.readouterr().out
