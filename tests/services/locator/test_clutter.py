"""Clutter map: static echoes are learned, a passing ROV is not, old cells are forgotten."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from capsd.services.locator.clutter import ClutterMap, ClutterSettings

SECOND = 1_000_000_000


def test_an_echo_that_stays_put_becomes_static_and_is_forgotten_later() -> None:
    clutter = ClutterMap(ClutterSettings(static_after_s=5.0, min_sightings=10))
    sandbag = np.array([18.8, 7.1, -3.5])
    for k in range(60):  # 6 s at 10 Hz, jittering within a cell's neighbourhood
        clutter.observe(k * SECOND // 10, sandbag + np.array([0.1 * np.sin(k), 0.05, 0.0]))
    assert clutter.is_static(6 * SECOND, sandbag)
    assert clutter.is_static(6 * SECOND, sandbag + np.array([0.4, 0.0, 0.0]))  # a neighbour
    # Beside it, as a ROV that lost its fix there holds: not the sandbag's echo.
    assert not clutter.is_static(6 * SECOND, sandbag + np.array([0.0, 0.7, 0.0]))
    assert not clutter.is_static(6 * SECOND, sandbag + np.array([2.0, 0.0, 0.0]))
    assert clutter.static_cells(6 * SECOND) >= 1
    assert not clutter.is_static(6 * SECOND + 61 * SECOND, sandbag)


def test_a_short_burst_is_not_static() -> None:
    clutter = ClutterMap(ClutterSettings(static_after_s=5.0, min_sightings=10))
    spot = np.array([3.0, 3.0, -2.0])
    for k in range(40):  # 40 sightings, but within 2 s
        clutter.observe(k * SECOND // 20, spot)
    assert not clutter.is_static(2 * SECOND, spot)


@given(
    speed=st.floats(0.2, 1.0),
    heading=st.floats(0.0, 2 * np.pi),
    rate_hz=st.sampled_from([10, 20, 40]),
)
def test_a_moving_object_is_never_static(speed: float, heading: float, rate_hz: int) -> None:
    """Something moving at 0.2 m/s or more never sits in one 3 x 3 neighbourhood for 10 s."""
    settings = ClutterSettings(cell_m=0.5, static_after_s=10.0)
    clutter = ClutterMap(settings)
    start = np.array([10.0, 8.0, -3.0])
    direction = np.array([np.cos(heading), np.sin(heading), 0.0])
    for k in range(30 * rate_hz):
        t = k / rate_hz
        position = start + direction * speed * t
        clutter.observe(int(t * 1e9), position)
        assert not clutter.is_static(int(t * 1e9), position)
