"""Where the ROV can be in a frame, from its depth and the sonar's pose (depth-aware search).

The ROV's pressure sensor puts it on a horizontal plane; the sonar sees only the slab of
elevations inside its vertical aperture. A candidate at (range, azimuth) can be the ROV only if
some elevation inside the aperture (plus a margin for the beam's skirts) puts that point within
`tolerance_m` of the ROV's plane: anything else (the floor, a wall, clutter above or below the
ROV) is rejected whatever it looks like. The same geometry bounds the ranges at which the ROV
can appear at all, which focuses the search.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from capsd.geometry import Array, Transform, wrap_angle
from capsd.sonar_geometry import BeamModel

ELEVATION_SAMPLES = 15
AZIMUTH_SAMPLES = 15


@dataclass(frozen=True)
class DepthGate:
    """The ROV's plane seen from one ping's sonar pose."""

    sonar_in_world: Transform  # H_W_S at the ping
    rov_z_m: float  # world z of the ROV's centre (negative under water)
    tolerance_m: float  # the ROV's half height, lever arm, depth and pose errors
    half_aperture_rad: float  # including the margin for the vertical beam's skirts
    beam_model: BeamModel

    def _directions_z(self, azimuths: Array) -> Array:
        """World z component of unit beam directions: azimuths x elevations."""
        elevations = np.linspace(-self.half_aperture_rad, self.half_aperture_rad, ELEVATION_SAMPLES)
        theta = np.asarray(azimuths, dtype=np.float64)[:, None]
        ct, st = np.cos(theta), np.sin(theta)
        ce, se = np.cos(elevations)[None, :], np.sin(elevations)[None, :]
        if self.beam_model == "planar":
            dirs = np.stack(np.broadcast_arrays(ce * ct, ce * st, se), axis=-1)
        else:
            dirs = np.stack(np.broadcast_arrays(ct * ce, st, ct * se), axis=-1)
        rotation_z = self.sonar_in_world.rotation[2]
        return np.asarray(dirs @ rotation_z, dtype=np.float64)

    def plausible(self, range_m: float, azimuth_rad: float) -> bool:
        """Whether a candidate can lie on the ROV's plane within the aperture."""
        z = self.sonar_in_world.translation[2] + range_m * self._directions_z(
            np.array([azimuth_rad])
        )
        return bool(z.min() - self.tolerance_m <= self.rov_z_m <= z.max() + self.tolerance_m)

    def elevation_at(self, range_m: float, azimuth_rad: float) -> float | None:
        """The elevation at which a point at (range, azimuth) lies on the ROV's plane.

        The root nearer the boresight (the other lies far outside any aperture); None where
        the plane is out of reach at that range and bearing.
        """
        if range_m <= 0.0:
            return None
        a, b, c = (float(v) for v in self.sonar_in_world.rotation[2])
        ct, st = math.cos(azimuth_rad), math.sin(azimuth_rad)
        k = (self.rov_z_m - float(self.sonar_in_world.translation[2])) / range_m
        # World z of a unit beam direction: A cos(e) + C sin(e) + B, by the beam model.
        if self.beam_model == "planar":
            cos_part, sin_part, rest = a * ct + b * st, c, 0.0
        else:
            cos_part, sin_part, rest = a * ct, c * ct, b * st
        norm = math.hypot(cos_part, sin_part)
        if norm < 1e-12 or abs(k - rest) > norm:
            return None
        phase = math.atan2(sin_part, cos_part)
        spread = math.acos((k - rest) / norm)
        roots = [wrap_angle(phase + spread), wrap_angle(phase - spread)]
        return min(roots, key=abs)

    def range_window(self, half_fov_rad: float) -> tuple[float, float] | None:
        """The slant ranges at which the ROV's plane crosses the fan (None: nowhere)."""
        azimuths = np.linspace(-half_fov_rad, half_fov_rad, AZIMUTH_SAMPLES)
        dz = self._directions_z(azimuths).ravel()
        height = self.rov_z_m - self.sonar_in_world.translation[2]
        ranges = []
        for offset in (-self.tolerance_m, self.tolerance_m):
            with np.errstate(divide="ignore", invalid="ignore"):
                r = (height + offset) / dz
            ranges.append(r[np.isfinite(r) & (r > 0.0)])
        hits = np.concatenate(ranges)
        if hits.size == 0:
            return None
        if abs(height) <= self.tolerance_m:  # the sonar itself is inside the ROV's slab
            hits = np.append(hits, 0.0)
        # A ray that dips less steeply reaches the plane further away: between the extremes
        # every range is reachable (continuity over elevation and azimuth).
        near = float(hits.min())
        far = float(hits.max())
        return (max(near, 0.0), far if math.isfinite(far) else math.inf)
