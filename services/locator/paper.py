"""The paper's fix (Cheng et al., section III), kept as the benchmark baseline.

Sphere |p - t_S| = R, the plane through the sonar with normal n = R_W_S (sin theta, -cos theta, 0)
(the planar beam model) and the plane z = -depth (the pressure sensor's depth, no lever arm).
The two planes meet in a line; the line meets the sphere in two points; the one with S-frame
x > 0 is kept (nearest the boresight plane if both are). There is no aperture check and no
conditioning test: that is the paper's method, not ours.
"""

from __future__ import annotations

import math

import numpy as np

from capsd.geometry import Array, Transform


def paper_fix(
    *, sonar_pose: Transform, range_m: float, azimuth_rad: float, depth_m: float
) -> Array | None:
    """The paper's ROV position, or None when the three surfaces do not meet in front."""
    centre = sonar_pose.translation
    normal = sonar_pose.rotation @ np.array([math.sin(azimuth_rad), -math.cos(azimuth_rad), 0.0])
    up = np.array([0.0, 0.0, 1.0])
    direction = np.cross(normal, up)
    norm = float(np.linalg.norm(direction))
    if norm < 1e-12:
        return None  # beam plane parallel to the depth plane
    direction /= norm
    z = -depth_m
    # A point on both planes: n . (p - c) = 0 and p_z = z, taken closest to the sonar.
    # Solve in the horizontal plane: n_xy . (q - c_xy) = -n_z (z - c_z).
    n_xy = normal[:2]
    offset = -normal[2] * (z - centre[2]) / float(n_xy @ n_xy)
    point = np.array([*(centre[:2] + offset * n_xy), z])
    # |point + s d - c|^2 = R^2 with d horizontal and unit.
    rel = point - centre
    b = float(rel @ direction)
    c = float(rel @ rel) - range_m**2
    disc = b * b - c
    if disc < 0.0:
        return None
    root = math.sqrt(disc)
    candidates = [point + s * direction for s in (-b + root, -b - root)]
    to_sonar = sonar_pose.inverse()
    in_front = [(p, to_sonar.apply(p)) for p in candidates]
    in_front = [(p, ps) for p, ps in in_front if ps[0] > 0.0]
    if not in_front:
        return None
    return min(in_front, key=lambda pair: abs(float(pair[1][2])))[0]
