"""The speed of sound from temperature and salinity: published values, trends, its range."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from capsd.sound_speed import SoundSpeedError, relative_sigma, speed_of_sound_m_s

# Pure water at atmospheric pressure, from Del Grosso & Mader (1972) and Bilaniuk & Wong
# (1993), as tabulated in Kaye & Laby: the equation must agree within 0.5 m/s.
PURE_WATER_M_S = {0.0: 1402.4, 10.0: 1447.3, 20.0: 1482.3, 30.0: 1509.2, 40.0: 1528.9}


@pytest.mark.parametrize(("temperature_c", "speed_m_s"), sorted(PURE_WATER_M_S.items()))
def test_pure_water_matches_the_published_values(temperature_c: float, speed_m_s: float) -> None:
    assert speed_of_sound_m_s(temperature_c, salinity_ppt=0.0) == pytest.approx(speed_m_s, abs=0.5)


def test_sea_water_matches_the_published_value() -> None:
    # 35 ppt, 10 degC, surface: 1489.8 m/s (UNESCO; Mackenzie 1981 gives the same within 0.2).
    assert speed_of_sound_m_s(10.0, salinity_ppt=35.0) == pytest.approx(1489.8, abs=0.5)


@given(
    t=st.floats(0.0, 39.0),
    dt=st.floats(0.05, 1.0),
    s=st.floats(0.0, 44.0),
    ds=st.floats(0.05, 1.0),
)
def test_warmer_or_saltier_water_carries_sound_faster(
    t: float, dt: float, s: float, ds: float
) -> None:
    base = speed_of_sound_m_s(t, salinity_ppt=s)
    assert speed_of_sound_m_s(t + dt, salinity_ppt=s) > base
    assert speed_of_sound_m_s(t, salinity_ppt=s + ds) > base


@pytest.mark.parametrize(
    ("temperature_c", "salinity_ppt", "named"),
    [(45.0, 0.0, "temperature_c"), (float("nan"), 0.0, "temperature_c"), (20.0, -1.0, "salinity")],
)
def test_outside_the_equation_s_range_is_refused_by_name(
    temperature_c: float, salinity_ppt: float, named: str
) -> None:
    with pytest.raises(SoundSpeedError, match=named):
        speed_of_sound_m_s(temperature_c, salinity_ppt=salinity_ppt)


def test_a_thermometer_s_sigma_becomes_a_relative_range_sigma() -> None:
    # About 2.6 m/s per degC at 24 degC in fresh water: 0.5 degC is 0.09 % of 1494 m/s.
    sigma = relative_sigma(24.0, salinity_ppt=0.0, temperature_sigma_c=0.5, salinity_sigma_ppt=0.0)
    slope = speed_of_sound_m_s(24.5, salinity_ppt=0.0) - speed_of_sound_m_s(23.5, salinity_ppt=0.0)
    assert sigma == pytest.approx(0.5 * slope / speed_of_sound_m_s(24.0, salinity_ppt=0.0))
    assert 0.0007 < sigma < 0.0011
    both = relative_sigma(24.0, salinity_ppt=0.0, temperature_sigma_c=0.5, salinity_sigma_ppt=1.0)
    assert both > sigma
