"""The moving-echo test: a static source never passes, a ROV on the move does."""

from __future__ import annotations

import math
from collections import deque

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capsd.geometry import Array, Transform, euler_zyx_to_matrix
from capsd.services.locator.moving_echo import MovingEchoes, MovingEchoSettings, _scatter_m
from capsd.sonar_geometry import BeamModel, to_polar

SECOND = 1_000_000_000
HALF_APERTURE = math.radians(10.0)


def _sonar(
    x_m: float, y_m: float, yaw_rad: float, pitch_rad: float = math.radians(30)
) -> Transform:
    return Transform(euler_zyx_to_matrix(yaw_rad, pitch_rad, 0.0), np.array([x_m, y_m, -0.3]))


def _sight(
    echoes: MovingEchoes, model: BeamModel, stamp_ns: int, sonar: Transform, point: Array
) -> bool:
    r, azimuth, _ = to_polar(model, sonar.inverse().apply(point))
    return echoes.observe(stamp_ns, sonar, range_m=r, azimuth_rad=azimuth, position_m=point)


def _visible(model: BeamModel, sonar: Transform, point: Array) -> bool:
    _, azimuth, elevation = to_polar(model, sonar.inverse().apply(point))
    return abs(elevation) <= HALF_APERTURE and abs(azimuth) <= math.radians(60)


@settings(max_examples=60, deadline=None)
@given(
    model=st.sampled_from(["conical", "planar"]),
    ahead_m=st.floats(2.0, 15.0),
    across_m=st.floats(-3.0, 3.0),
    speed_m_s=st.floats(0.0, 0.6),
    heading_rad=st.floats(-math.pi, math.pi),
    turn_rad_s=st.floats(-0.2, 0.2),
)
def test_a_static_source_never_moved_whatever_the_sonar_does(
    model: BeamModel,
    ahead_m: float,
    across_m: float,
    speed_m_s: float,
    heading_rad: float,
    turn_rad_s: float,
) -> None:
    echoes = MovingEchoes(MovingEchoSettings(), beam_model=model, half_aperture_rad=HALF_APERTURE)
    start = _sonar(0.0, 0.0, 0.0)
    # A fixture inside the aperture of the first ping (the depth its range and the pitch give).
    point = start.apply(np.array([ahead_m, across_m, ahead_m * math.sin(math.radians(4))]))
    for k in range(50):  # 5 s at 10 Hz
        t = k / 10
        sonar = _sonar(
            speed_m_s * t * math.cos(heading_rad),
            speed_m_s * t * math.sin(heading_rad),
            turn_rad_s * t,
        )
        if _visible(model, sonar, point):
            assert not _sight(echoes, model, k * SECOND // 10, sonar, point)


@pytest.mark.parametrize("model", ["conical", "planar"])
@pytest.mark.parametrize("asv_speed_m_s", [0.0, 0.3])
def test_a_rov_on_the_move_has_moved_after_the_minimum_age(
    model: BeamModel, asv_speed_m_s: float
) -> None:
    """0.3 m/s across the view: judged after 1 s; moved once 0.3 m from any static source."""
    echoes = MovingEchoes(MovingEchoSettings(), beam_model=model, half_aperture_rad=HALF_APERTURE)
    start = np.array([8.0, -1.0, -4.0])
    verdicts = []
    for k in range(40):  # 4 s at 10 Hz
        t = k / 10
        sonar = _sonar(asv_speed_m_s * t, 0.0, 0.0)
        rov = start + np.array([0.0, 0.3 * t, 0.0])
        assert _visible(model, sonar, rov)
        verdicts.append(_sight(echoes, model, k * SECOND // 10, sonar, rov))
    first = verdicts.index(True)
    assert 10 <= first <= 25, verdicts  # not before 1 s; the shift grows at ~0.3 m/s
    assert all(verdicts[first:])


def test_a_rov_hovering_is_static_and_another_echo_is_its_own_chain() -> None:
    echoes = MovingEchoes(
        MovingEchoSettings(), beam_model="conical", half_aperture_rad=HALF_APERTURE
    )
    hover = np.array([8.0, 0.0, -4.0])
    for k in range(40):
        stamp = k * SECOND // 10
        sonar = _sonar(0.0, 0.2 * k / 10, 0.0)
        assert not _sight(echoes, "conical", stamp, sonar, hover)
        # A second echo 2 m off, jumping about: it never joins the hovering one's chain.
        other = hover + np.array([2.0, (-1) ** k * 0.25, 0.0])
        _sight(echoes, "conical", stamp, sonar, other)
    assert len(echoes._chains) >= 2


def test_a_chain_not_seen_for_a_while_is_forgotten() -> None:
    echoes = MovingEchoes(
        MovingEchoSettings(), beam_model="conical", half_aperture_rad=HALF_APERTURE
    )
    sonar = _sonar(0.0, 0.0, 0.0)
    start = np.array([8.0, -1.0, -4.0])
    verdicts = []
    for k in range(40):
        if 10 <= k < 25:
            continue  # 1.5 s unseen: longer than forget_after_s, the chain starts over
        rov = start + np.array([0.0, 0.3 * k / 10, 0.0])
        verdicts.append(_sight(echoes, "conical", k * SECOND // 10, sonar, rov))
    # Seen again at 2.5 s: a new chain, judged no sooner than 1 s (10 sightings) later.
    assert not any(verdicts[:20])
    assert verdicts[-1]


def test_an_echo_jumping_about_a_fixture_has_not_moved() -> None:
    """A rack top's brightest point jumps from corner to corner: not a ROV, however far."""
    sonar = _sonar(0.0, 0.0, 0.0)
    rng = np.random.default_rng(5)
    corners = np.array([[8.0, -0.6, -4.0], [8.4, -0.6, -4.0], [8.0, -0.2, -4.0], [8.4, -0.2, -4.0]])

    def verdicts(settings: MovingEchoSettings) -> list[bool]:
        echoes = MovingEchoes(settings, beam_model="conical", half_aperture_rad=HALF_APERTURE)
        out = []
        for k in range(60):  # 6 s at 10 Hz, each ping one corner (a few cm of noise)
            point = corners[k % 4 if k < 4 else rng.integers(0, 4)] + rng.normal(0, 0.02, 3)
            point[2] = -4.0
            out.append(_sight(echoes, "conical", k * SECOND // 10, sonar, point))
        return out

    # The shift alone calls it moved (the corners are 0.4 m apart) ...
    assert any(verdicts(MovingEchoSettings(max_scatter_m=10.0)))
    # ... the path's scatter about a straight line does not.
    assert not any(verdicts(MovingEchoSettings()))


@settings(max_examples=60, deadline=None)
@given(
    start=st.tuples(*[st.floats(-20.0, 20.0)] * 2),
    velocity=st.tuples(*[st.floats(-1.0, 1.0)] * 2),
    wobble_m=st.floats(0.0, 0.5),
)
def test_the_path_scatter_is_the_rms_off_a_straight_line(
    start: tuple[float, float], velocity: tuple[float, float], wobble_m: float
) -> None:
    """Any straight, steady path scatters 0; alternating +-w across it scatters w."""
    direction = np.array(velocity)
    across = (
        np.array([-direction[1], direction[0]]) / float(np.linalg.norm(direction))
        if float(np.linalg.norm(direction)) > 1e-3
        else np.array([0.0, 1.0])
    )
    path: deque[tuple[float, float, float, float]] = deque()
    for k in range(40):  # 2 s at 20 Hz; an even count keeps the wobble off the fitted line
        t = k / 20
        xy = np.array(start) + direction * t + across * wobble_m * (-1) ** k
        path.append((t, float(xy[0]), float(xy[1]), -4.0))
    assert math.isclose(_scatter_m(path), wobble_m, rel_tol=0.05, abs_tol=1e-6)
