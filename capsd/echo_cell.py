"""What else shares a sonar echo's range cell: mapped fixtures the 2D image cannot tell apart.

A multibeam image has range and bearing but no elevation: everything inside the vertical
aperture at the same range (within the cell's half-width) and bearing lands in the same pixel.
An echo whose cell also holds a mapped fixture (a rack's top, a sandbag, a pipe) may be that
fixture; a ROV seen in such a cell may be hidden in it. Used by the locator (such echoes may not
start a track) and by the ASV's follower (such views are avoided).
"""

from __future__ import annotations

import numpy as np

from capsd.geometry import Array, Transform
from capsd.sonar_geometry import BeamModel, beam_directions
from capsd.tank import TankFixture

_ELEVATION_SAMPLES = 21


def cell_points(
    sonar_pose: Transform,
    *,
    range_m: float,
    azimuth_rad: float,
    beam_model: BeamModel,
    vertical_aperture_rad: float,
    half_width_m: float,
    skip_elevation_rad: float | None = None,
    skip_within_rad: float = 0.026,
) -> Array:
    """World points (n x 3) across the cell's elevations at its near, middle and far range.

    Elevations within `skip_within_rad` of `skip_elevation_rad` (the echo's own) are left out.
    """
    half = vertical_aperture_rad / 2.0
    elevations = np.linspace(-half, half, _ELEVATION_SAMPLES)
    if skip_elevation_rad is not None:
        elevations = elevations[np.abs(elevations - skip_elevation_rad) > skip_within_rad]
    directions = beam_directions(beam_model, azimuth_rad, elevations)
    ranges = (range_m - half_width_m, range_m, range_m + half_width_m)
    local = np.concatenate([r * directions for r in ranges]).reshape(-1, 3)
    return np.asarray(local @ sonar_pose.rotation.T + sonar_pose.translation)


def fixture_boxes(fixtures: tuple[TankFixture, ...], margin_m: float) -> tuple[Array, Array]:
    """The fixtures' boxes grown by `margin_m`: (lo, hi), each k x 3."""
    lo = np.array([f.lo_m for f in fixtures], dtype=np.float64).reshape(-1, 3) - margin_m
    hi = np.array([f.hi_m for f in fixtures], dtype=np.float64).reshape(-1, 3) + margin_m
    return lo, hi


def any_inside(points: Array, boxes: tuple[Array, Array]) -> bool:
    """Whether any point lies inside any box."""
    lo, hi = boxes
    if not len(lo) or not len(points):
        return False
    inside = (points[:, None, :] >= lo[None]) & (points[:, None, :] <= hi[None])
    return bool(np.any(np.all(inside, axis=2)))
