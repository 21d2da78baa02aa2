"""Where a lost ROV could be, and the life of an unproven relocation."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from capsd.geometry import Transform, euler_zyx_to_matrix
from capsd.services.locator.moving_echo import MovingEchoSettings
from capsd.services.locator.relocation import LastSeen, Relocation, RelocationSettings
from capsd.sonar_geometry import to_polar

SECOND = 1_000_000_000
SETTINGS = RelocationSettings(radius_m=0.5, drift_m_s=0.2, carry_s=2.0, confirm_after_s=5.0)


def _relocation() -> Relocation:
    return Relocation(
        SETTINGS, MovingEchoSettings(), beam_model="planar", half_aperture_rad=math.radians(10)
    )


coordinate = st.floats(-20.0, 20.0)
speed = st.floats(-0.5, 0.5)


@settings(max_examples=200, deadline=None)
@given(
    last=st.tuples(coordinate, coordinate),
    velocity=st.tuples(speed, speed),
    elapsed_s=st.floats(0.0, 60.0),
    along=st.floats(0.0, 1.0),
    bearing=st.floats(0.0, 2 * math.pi),
    margin=st.floats(0.01, 5.0),
)
def test_reach_is_a_capsule_round_the_carried_path(
    last: tuple[float, float],
    velocity: tuple[float, float],
    elapsed_s: float,
    along: float,
    bearing: float,
    margin: float,
) -> None:
    seen = LastSeen(0, np.array([*last, -4.0]), np.array([*velocity, 0.0]))
    stamp = round(elapsed_s * SECOND)
    relocation = _relocation()
    carried = seen.velocity_m_s * min(elapsed_s, SETTINGS.carry_s)
    radius = SETTINGS.radius_m + SETTINGS.drift_m_s * elapsed_s
    on_path = seen.position_m + along * carried
    offset = np.array([math.cos(bearing), math.sin(bearing), 0.0])
    assert relocation.reachable(stamp, on_path + offset * radius * 0.999, seen)
    # Beyond the radius sideways of the whole path (or past its ends): out of reach.
    beyond = on_path + offset * (radius + margin + float(np.linalg.norm(carried)))
    assert not relocation.reachable(stamp, beyond, seen)
    assert relocation.reachable(stamp, beyond, None)  # never seen: anywhere


def test_a_relocation_ends_when_its_echo_moves_or_after_waiting() -> None:
    sonar = Transform(euler_zyx_to_matrix(0.0, math.radians(30), 0.0), np.array([0.0, 0.0, -0.3]))

    def sight(relocation: Relocation, k: int, point: np.ndarray) -> None:
        r, azimuth, _ = to_polar("planar", sonar.inverse().apply(point))
        stamp = k * SECOND // 10
        relocation.observe(stamp, sonar, range_m=r, azimuth_rad=azimuth, position_m=point)

    still = _relocation()
    still.begin(0)
    for k in range(49):
        sight(still, k, np.array([6.0, 0.0, -3.0]))
    waiting = still.active  # 4.8 s of a static echo
    sight(still, 50, np.array([6.0, 0.0, -3.0]))
    assert (waiting, still.active, still.proven_waiting) == (True, False, 1)

    moving = _relocation()
    moving.begin(0)
    k = 0
    while moving.active and k < 49:
        sight(moving, k, np.array([6.0 + 0.03 * k, 0.0, -3.0]))  # 0.3 m/s along the beam
        k += 1
    assert moving.proven_moving == 1
    assert 10 <= k <= 25, k

    taken = _relocation()
    taken.begin(0)
    taken.take_over()
    assert not taken.active
    assert taken.taken_over == 1
    taken.take_over()  # nothing to take over: not counted
    assert taken.taken_over == 1
