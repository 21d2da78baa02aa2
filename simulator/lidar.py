"""A 2D LiDAR like a SICK TiM571 on the ASV: 270 deg, 0.333 deg steps, 15 Hz, 25 m.

The scan plane is the scanner's x-y plane, tilted with the ASV by the waves. Returns come only
from what is above the water: the walls up to their freeboard and clutter above z = 0 (a beam
that would meet the wall below the water line, or pass over it, returns nothing). Noise:
N(0, 20 mm) per range; each beam drops out with probability `dropout`. A range of 0 means no
return, as in the LidarScan payload.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from capsd.geometry import Array, Transform
from capsd.simulator import scene
from capsd.simulator.world import Tank


@dataclass(frozen=True)
class LidarModel:
    angle_min_rad: float = math.radians(-135.0)
    angle_increment_rad: float = math.radians(1.0 / 3.0)
    beams: int = 811
    range_min_m: float = 0.05
    range_max_m: float = 25.0
    sigma_m: float = 0.02
    dropout: float = 0.01
    scan_time_s: float = 1.0 / 15.0

    def angles(self) -> Array:
        return np.asarray(
            self.angle_min_rad + self.angle_increment_rad * np.arange(self.beams), dtype=np.float64
        )


def scan(model: LidarModel, scanner_pose: Transform, tank: Tank, rng: np.random.Generator) -> Array:
    """Ranges (m) of one scan; 0.0 where a beam returned nothing."""
    angles = model.angles()
    dirs_l = np.column_stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)])
    dirs_w = dirs_l @ scanner_pose.rotation.T
    hits = scene.cast(scanner_pose.translation, dirs_w, tank, rov=None, water="above")
    ranges = hits.distance + rng.normal(0.0, model.sigma_m, model.beams)
    ok = (
        np.isfinite(hits.distance)
        & (ranges >= model.range_min_m)
        & (ranges <= model.range_max_m)
        & (rng.random(model.beams) >= model.dropout)
    )
    return np.where(ok, ranges, 0.0)
