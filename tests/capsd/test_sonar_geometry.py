"""The sonar image's geometry: distances between places of the fan."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from capsd.sonar_geometry import FanPlace, beam_direction, fan_distance_m

places = st.builds(
    FanPlace,
    st.floats(0.0, 120.0),
    st.floats(-math.radians(65.0), math.radians(65.0)),
)


@given(places, places)
def test_a_fan_distance_is_the_chord_between_the_two_places_at_elevation_zero(
    a: FanPlace, b: FanPlace
) -> None:
    # Both beam models put elevation 0 in the fan's plane: the same points either way.
    for model in ("planar", "conical"):
        chord = a.range_m * beam_direction(model, a.azimuth_rad, 0.0) - b.range_m * (
            beam_direction(model, b.azimuth_rad, 0.0)
        )
        assert fan_distance_m(a, b) == pytest.approx(float(np.linalg.norm(chord)), abs=1e-9)
    assert fan_distance_m(a, b) == fan_distance_m(b, a)
    assert fan_distance_m(a, a) == 0.0


def test_along_a_beam_it_is_the_range_difference_across_it_the_arc_s_chord() -> None:
    assert fan_distance_m(FanPlace(3.0, 0.2), FanPlace(5.5, 0.2)) == pytest.approx(2.5)
    across = fan_distance_m(FanPlace(10.0, -0.05), FanPlace(10.0, 0.05))
    assert across == pytest.approx(2 * 10.0 * math.sin(0.05))
