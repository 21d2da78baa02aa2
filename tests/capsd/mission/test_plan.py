"""Mission plans: lawnmower lanes, inspection points, the geofence, bad files named."""

from __future__ import annotations

from pathlib import Path

import msgspec
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capsd.errors import ConfigError
from capsd.mission.plan import (
    Lawnmower,
    cross_track_m,
    lawnmower_waypoints,
    load_plan,
)
from capsd.tank import TankBounds

TANK = TankBounds(length_m=28.0, width_m=16.0, depth_m=8.0)


@settings(max_examples=60, deadline=None)
@given(
    ax=st.floats(1.0, 27.0),
    ay=st.floats(1.0, 15.0),
    bx=st.floats(1.0, 27.0),
    by=st.floats(1.0, 15.0),
    spacing=st.floats(0.2, 5.0),
    along=st.sampled_from(["x", "y"]),
)
def test_lawnmower_covers_the_rectangle_with_lanes_no_wider_than_the_spacing(
    ax: float, ay: float, bx: float, by: float, spacing: float, along: str
) -> None:
    pattern = msgspec.convert(
        {
            "corner_a_m": [ax, ay],
            "corner_b_m": [bx, by],
            "depth_m": 3.0,
            "spacing_m": spacing,
            "along": along,
        },
        Lawnmower,
    )
    points = lawnmower_waypoints(pattern)
    p = np.array([w.position_m for w in points])
    assert len(p) % 2 == 0
    assert np.all(p[:, 2] == -3.0)
    across = 1 if along == "x" else 0
    lanes = p[::2, across]
    # The first lane on one edge, the last on the other, none further apart than the spacing.
    assert lanes[0] == pytest.approx((ax, ay)[across])
    assert lanes[-1] == pytest.approx((bx, by)[across])
    assert np.all(np.abs(np.diff(lanes)) <= spacing + 1e-9)
    # Each lane runs end to end, alternating direction.
    for k in range(len(points) // 2):
        start, end = p[2 * k], p[2 * k + 1]
        assert start[across] == end[across]
        if k:
            assert np.allclose(start[:2], p[2 * k - 1][:2], atol=spacing + 1e-9)


def test_points_plan_is_read_with_depths_as_negative_z(tmp_path: Path) -> None:
    f = tmp_path / "plan.yaml"
    f.write_text(
        "name: racks\npoints:\n"
        "  - {position_m: [5.0, 4.0], depth_m: 3.0, dwell_s: 10}\n"
        "  - {position_m: [9.0, 4.0], depth_m: 2.5}\n"
    )
    plan, points = load_plan(f, tank=TANK)
    assert plan.name == "racks"
    assert [w.position_m for w in points] == [(5.0, 4.0, -3.0), (9.0, 4.0, -2.5)]
    assert [w.dwell_s for w in points] == [10.0, 0.0]


@pytest.mark.parametrize(
    ("text", "where", "why"),
    [
        ("points:\n  - {position_m: [27.9, 4.0], depth_m: 3.0}\n", "waypoint 0", "geofence"),
        ("points:\n  - {position_m: [5.0, 4.0], depth_m: 7.8}\n", "waypoint 0", "geofence"),
        ("name: x\n", "<root>", "exactly one"),
        ("points:\n  - {position_m: [5.0, 4.0], depth_m: -1}\n", "points", ">"),
        ("speed_m_s: fast\npoints: []\n", "speed_m_s", "float"),
    ],
)
def test_a_bad_plan_fails_naming_where_and_why(
    tmp_path: Path, text: str, where: str, why: str
) -> None:
    f = tmp_path / "plan.yaml"
    f.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_plan(f, tank=TANK)
    assert str(f) in str(err.value)
    assert where in str(err.value)
    assert why in str(err.value)


def test_fence_keeps_clear_of_walls_floor_and_surface() -> None:
    assert TANK.clear_of_walls((1.0, 1.0, -1.0), 0.5)
    assert not TANK.clear_of_walls((0.4, 1.0, -1.0), 0.5)
    assert not TANK.clear_of_walls((1.0, 15.6, -1.0), 0.5)
    assert not TANK.clear_of_walls((1.0, 1.0, -0.2), 0.5)
    assert not TANK.clear_of_walls((1.0, 1.0, -7.7), 0.5)


@settings(max_examples=100, deadline=None)
@given(
    st.lists(st.floats(-10, 10), min_size=9, max_size=9),
)
def test_cross_track_is_the_distance_to_the_segment(v: list[float]) -> None:
    p, a, b = np.array(v[:3]), np.array(v[3:6]), np.array(v[6:])
    d = cross_track_m(p, a, b)
    # Never more than to either end, never less than to the closest of many points on it.
    samples = a + np.linspace(0, 1, 2001)[:, None] * (b - a)
    nearest = float(np.min(np.linalg.norm(samples - p, axis=1)))
    assert d <= min(np.linalg.norm(p - a), np.linalg.norm(p - b)) + 1e-9
    assert d == pytest.approx(nearest, abs=float(np.linalg.norm(b - a)) / 2000 + 1e-9)


def test_the_example_plans_fit_the_example_tank() -> None:
    from capsd.config import load_config
    from capsd.services.locator.service import Config as LocatorConfig
    from tests.conftest import REPO

    tank = load_config(REPO / "deploy/config/locator.yaml", LocatorConfig).tank
    assert tank is not None
    plans = sorted((REPO / "deploy/missions").glob("*.yaml"))
    assert plans
    for path in plans:
        _, points = load_plan(path, tank=tank)
        assert len(points) >= 2
