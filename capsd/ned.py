"""Tank frame W (x along the long wall, z up) to ArduSub's local NED, and back.

The world x axis points `heading_rad` clockwise from north; W is right-handed with z up, so its
y axis points 90 deg counter-clockwise from x, i.e. at heading - 90 deg. W's origin sits at
`origin_ned_m` in the EKF's local NED frame. Bodies: ours are FLU (x forward, y left, z up),
ArduPilot's FRD (x forward, y right, z down).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from capsd.geometry import Array, euler_zyx_to_matrix, matrix_to_euler_zyx

FLU_TO_FRD = np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True)
class TankToNed:
    """The fixed map from W to local NED."""

    heading_rad: float
    origin_ned_m: Array

    @property
    def rotation(self) -> Array:
        """R_NED_W: columns are W's axes in NED."""
        c, s = math.cos(self.heading_rad), math.sin(self.heading_rad)
        return np.array([[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, -1.0]])

    def position(self, p_w: Array) -> Array:
        return self.rotation @ np.asarray(p_w, dtype=np.float64) + self.origin_ned_m

    def position_to_tank(self, p_ned: Array) -> Array:
        return self.rotation.T @ (np.asarray(p_ned, dtype=np.float64) - self.origin_ned_m)

    def covariance(self, cov_w: Array) -> Array:
        r = self.rotation
        return np.asarray(r @ cov_w @ r.T)

    def attitude_to_tank(self, roll: float, pitch: float, yaw: float) -> Array:
        """R_W_R (FLU body in W) from ArduPilot's roll, pitch, yaw (FRD body in NED)."""
        r_ned_frd = euler_zyx_to_matrix(yaw, pitch, roll)
        return np.asarray(self.rotation.T @ r_ned_frd @ FLU_TO_FRD)

    def attitude_to_ned(self, r_w_r: Array) -> tuple[float, float, float]:
        """(roll, pitch, yaw) of ArduPilot's FRD body in NED from R_W_R."""
        r_ned_frd = self.rotation @ r_w_r @ FLU_TO_FRD
        yaw, pitch, roll = matrix_to_euler_zyx(r_ned_frd)
        return roll, pitch, yaw

    def body_rates_to_flu(self, p: float, q: float, r: float) -> tuple[float, float, float]:
        return p, -q, -r


def upper_triangle(cov6: Array) -> tuple[float, ...]:
    """The 21 values of a 6 x 6 matrix's upper triangle, row by row (MAVLink's layout)."""
    return tuple(float(cov6[i, j]) for i in range(6) for j in range(i, 6))
