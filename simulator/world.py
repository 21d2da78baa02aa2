"""Tanks and trajectories: deterministic ROV and ASV motion in the world frame W (z up)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from capsd.geometry import Array, euler_zyx_to_matrix

TankName = Literal["nfp", "mockup"]
TrajectoryName = Literal["square", "lawnmower"]


@dataclass(frozen=True)
class Tank:
    """A rectangular tank: x along the long wall, y along the short wall, floor at -depth."""

    length_m: float
    width_m: float
    depth_m: float


TANKS: dict[TankName, Tank] = {
    "nfp": Tank(28.0, 16.0, 8.0),  # the paper's simulated nuclear fuel pool
    "mockup": Tank(4.8, 3.6, 2.0),  # the paper's real mock-up tank
}


@dataclass(frozen=True)
class RovState:
    """The ROV's true state at one instant."""

    position_m: Array
    velocity_m_s: Array
    rotation: Array  # R_W_R


def _waypoints(tank: Tank, trajectory: TrajectoryName) -> Array:
    """Closed waypoint loop inside the tank, 20% margin from the walls, at 40% depth."""
    mx, my = 0.3 * tank.length_m, 0.3 * tank.width_m
    x0, x1, y0, y1 = mx, tank.length_m - mx, my, tank.width_m - my
    z = -0.4 * tank.depth_m
    if trajectory == "square":
        pts = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    else:
        lanes = 4
        pts = []
        for i in range(lanes):
            y = y0 + (y1 - y0) * i / (lanes - 1)
            pts.extend([(x0, y), (x1, y)] if i % 2 == 0 else [(x1, y), (x0, y)])
    return np.array([(x, y, z) for x, y in pts])


class Trajectory:
    """Constant-speed motion along a closed polyline, yaw along the path, small dynamic tilt."""

    def __init__(self, tank: Tank, name: TrajectoryName, *, speed_m_s: float):
        self.points = _waypoints(tank, name)
        closed = np.vstack([self.points, self.points[:1]])
        self.segments = np.diff(closed, axis=0)
        self.lengths = np.linalg.norm(self.segments, axis=1)
        self.cumulative = np.concatenate([[0.0], np.cumsum(self.lengths)])
        self.period_s = float(self.cumulative[-1]) / speed_m_s
        self.speed = speed_m_s

    def state(self, t_s: float) -> RovState:
        s = (t_s * self.speed) % self.cumulative[-1]
        i = int(np.searchsorted(self.cumulative, s, side="right") - 1)
        i = min(i, len(self.segments) - 1)
        direction = self.segments[i] / self.lengths[i]
        position = self.points[i] + direction * (s - self.cumulative[i])
        yaw = math.atan2(direction[1], direction[0])
        # A BlueROV2 pitches a few degrees while it drives forward; a slow roll wobble too.
        rotation = euler_zyx_to_matrix(
            yaw, math.radians(3.0), math.radians(2.0) * math.sin(0.7 * t_s)
        )
        return RovState(position, direction * self.speed, rotation)
