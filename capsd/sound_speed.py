"""The speed of sound in water from its temperature and salinity (Coppens 1981).

A sonar turns echo time into range with the speed it assumes: the Oculus computes it from its
own thermometer (in its housing, warmed by its electronics) and the salinity it is set to, and
reports it with every ping. A few degrees off is a few tenths of a percent on every range. The
ROV's thermometer sits in the water the sound crosses; the ratio of the speed it gives to the
speed the sonar assumed rescales the ranges (`services/locator`).

Coppens (1981), "Simple equations for the speed of sound in Neptunian waters", J. Acoust. Soc.
Am. 69(3) 862-863: valid for 0-35 degC, 0-45 ppt and 0-4000 m; against the pure-water equation
of Marczak (1997) it differs by under 0.3 m/s (0.02 %) up to 40 degC at zero salinity, the range
accepted here (a fuel pond runs at 20-40 degC).
"""

from __future__ import annotations

import math
from collections.abc import Callable

from capsd.errors import CapsdError

TEMPERATURE_RANGE_C = (0.0, 40.0)
SALINITY_RANGE_PPT = (0.0, 45.0)
DEPTH_RANGE_M = (0.0, 4000.0)


class SoundSpeedError(CapsdError):
    """A temperature, salinity or depth outside the equation's range."""


def speed_of_sound_m_s(temperature_c: float, *, salinity_ppt: float, depth_m: float = 0.0) -> float:
    """The speed of sound (m/s) in water of this temperature (degC), salinity (ppt), depth (m)."""
    for name, value, (low, high) in (
        ("temperature_c", temperature_c, TEMPERATURE_RANGE_C),
        ("salinity_ppt", salinity_ppt, SALINITY_RANGE_PPT),
        ("depth_m", depth_m, DEPTH_RANGE_M),
    ):
        if not (math.isfinite(value) and low <= value <= high):
            raise SoundSpeedError(f"{name} {value} is outside the equation's {low}..{high}")
    t = temperature_c / 10.0
    s = salinity_ppt - 35.0
    d = depth_m / 1000.0  # the equation's depth is in km
    surface = (
        1449.05 + 45.7 * t - 5.21 * t**2 + 0.23 * t**3 + (1.333 - 0.126 * t + 0.009 * t**2) * s
    )
    return (
        surface
        + (16.23 + 0.253 * t) * d
        + (0.213 - 0.1 * t) * d**2
        + (0.016 + 0.0002 * s) * s * t * d
    )


def relative_sigma(
    temperature_c: float,
    *,
    salinity_ppt: float,
    temperature_sigma_c: float,
    salinity_sigma_ppt: float,
) -> float:
    """1-sigma of the speed, relative, from the temperature's and the salinity's 1-sigma."""
    speed = speed_of_sound_m_s(temperature_c, salinity_ppt=salinity_ppt)

    def slope(low: float, high: float, at: float, speed_at: Callable[[float], float]) -> float:
        # Central where it can be, one-sided at the equation's edges.
        a, b = max(at - 0.5, low), min(at + 0.5, high)
        return (speed_at(b) - speed_at(a)) / (b - a)

    per_c = slope(
        *TEMPERATURE_RANGE_C,
        temperature_c,
        lambda t: speed_of_sound_m_s(t, salinity_ppt=salinity_ppt),
    )
    per_ppt = slope(
        *SALINITY_RANGE_PPT,
        salinity_ppt,
        lambda s: speed_of_sound_m_s(temperature_c, salinity_ppt=s),
    )
    return math.hypot(per_c * temperature_sigma_c, per_ppt * salinity_sigma_ppt) / speed


__all__ = ["SoundSpeedError", "relative_sigma", "speed_of_sound_m_s"]
