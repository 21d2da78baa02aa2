"""Sonar beam geometry (CONVENTIONS.md): planar and conical models, forward and inverse.

theta is the azimuth (port positive), phi the elevation for the planar model, psi the rotation
about the receive array (y axis) for the conical model. Both map (r, theta, elevation) to a
point p_S in the sonar frame and back. The simulator and the solver must use the same model.
"""

from __future__ import annotations

import math
from typing import Literal, NamedTuple, Protocol

import numpy as np

from capsd.geometry import Array

BeamModel = Literal["planar", "conical"]


def beam_direction(model: BeamModel, azimuth_rad: float, elevation_rad: float) -> Array:
    """Unit vector in S toward (azimuth, elevation) under `model`."""
    ct, st = math.cos(azimuth_rad), math.sin(azimuth_rad)
    ce, se = math.cos(elevation_rad), math.sin(elevation_rad)
    if model == "planar":
        return np.array([ce * ct, ce * st, se])
    return np.array([ct * ce, st, ct * se])


def beam_directions(model: BeamModel, azimuth_rad: float, elevations_rad: Array) -> Array:
    """Unit vectors in S (n x 3) toward one azimuth at each of `elevations_rad` (n)."""
    ct, st = math.cos(azimuth_rad), math.sin(azimuth_rad)
    ce, se = np.cos(elevations_rad), np.sin(elevations_rad)
    if model == "planar":
        return np.stack([ce * ct, ce * st, se], axis=1)
    return np.stack([ct * ce, np.full_like(ce, st), ct * se], axis=1)


def to_polar(model: BeamModel, p_s: Array) -> tuple[float, float, float]:
    """(range, azimuth, elevation) of a point in S under `model` (inverse of beam_direction)."""
    x, y, z = (float(c) for c in p_s)
    r = math.sqrt(x * x + y * y + z * z)
    if r == 0.0:
        raise ValueError("the sonar's acoustic centre has no direction")
    if model == "planar":
        return r, math.atan2(y, x), math.asin(max(-1.0, min(1.0, z / r)))
    # conical: y = r sin(theta); x, z = r cos(theta) (cos psi, sin psi)
    azimuth = math.asin(max(-1.0, min(1.0, y / r)))
    return r, azimuth, math.atan2(z, x)


class FanPoint(Protocol):
    """A place in the sonar image: a detection, a candidate, a label."""

    @property
    def range_m(self) -> float: ...

    @property
    def azimuth_rad(self) -> float: ...


class FanPlace(NamedTuple):
    """A bare place in the sonar image."""

    range_m: float
    azimuth_rad: float


def fan_distance_m(a: FanPoint, b: FanPoint) -> float:
    """Metres between two places of the sonar image, in the fan's plane (elevation 0)."""
    return math.hypot(
        a.range_m * math.cos(a.azimuth_rad) - b.range_m * math.cos(b.azimuth_rad),
        a.range_m * math.sin(a.azimuth_rad) - b.range_m * math.sin(b.azimuth_rad),
    )
