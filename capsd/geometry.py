"""Rigid-body geometry in numpy only: quaternions (x, y, z, w), Z-Y-X Euler, transforms, slerp.

A transform H_A_B maps coordinates in frame B to frame A: p_A = R_A_B p_B + t_A_B.
numpy only, so the light ROV install (no scipy) can use it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float64]
IndexArray = npt.NDArray[np.intp]
MaskArray = npt.NDArray[np.bool_]


def quat_normalize(q: Array) -> Array:
    """Unit quaternion with w >= 0 (one of the two equivalent signs, for stable comparisons)."""
    q = np.asarray(q, dtype=np.float64)
    norm = float(np.linalg.norm(q))
    if norm == 0.0 or not math.isfinite(norm):
        raise ValueError("quaternion has zero or non-finite norm")
    q = q / norm
    return -q if q[3] < 0.0 else q


def quat_to_matrix(q: Array) -> Array:
    """Rotation matrix of a unit quaternion (x, y, z, w)."""
    x, y, z, w = quat_normalize(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quat(m: Array) -> Array:
    """Unit quaternion (x, y, z, w) of a rotation matrix (Shepperd's method, stable)."""
    m = np.asarray(m, dtype=np.float64)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0.0:
        s = 2.0 * math.sqrt(trace + 1.0)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s]
    return quat_normalize(np.array(q))


def euler_zyx_to_matrix(yaw_rad: float, pitch_rad: float, roll_rad: float) -> Array:
    """R = Rz(yaw) Ry(pitch) Rx(roll): the Z-Y-X convention of CONVENTIONS.md."""
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    cp, sp = math.cos(pitch_rad), math.sin(pitch_rad)
    cr, sr = math.cos(roll_rad), math.sin(roll_rad)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def matrix_to_euler_zyx(m: Array) -> tuple[float, float, float]:
    """(yaw, pitch, roll) of R = Rz(yaw) Ry(pitch) Rx(roll); pitch in [-pi/2, pi/2]."""
    pitch = math.asin(max(-1.0, min(1.0, -float(m[2, 0]))))
    if abs(float(m[2, 0])) < 1.0 - 1e-12:
        yaw = math.atan2(float(m[1, 0]), float(m[0, 0]))
        roll = math.atan2(float(m[2, 1]), float(m[2, 2]))
    else:  # gimbal lock: only yaw - roll (or yaw + roll) is observable; put it all in yaw
        yaw = math.atan2(-float(m[0, 1]), float(m[1, 1]))
        roll = 0.0
    return yaw, pitch, roll


def rotvec_to_matrix(rotvec: Array) -> Array:
    """Rodrigues: rotation matrix of a rotation vector (axis * angle)."""
    v = np.asarray(rotvec, dtype=np.float64)
    angle = float(np.linalg.norm(v))
    if angle < 1e-12:
        k = skew(v)
        return np.eye(3) + k
    k = skew(v / angle)
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def skew(v: Array) -> Array:
    """The cross-product matrix [v]x."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def quat_slerp(q0: Array, q1: Array, fraction: float) -> Array:
    """Spherical linear interpolation between unit quaternions, along the shorter arc."""
    a, b = quat_normalize(q0), quat_normalize(q1)
    dot = float(np.dot(a, b))
    if dot < 0.0:
        b, dot = -b, -dot
    if dot > 0.9995:  # nearly parallel: normalised lerp is exact to ~1e-8 rad here
        return quat_normalize(a + fraction * (b - a))
    theta = math.acos(dot)
    s = math.sin(theta)
    return quat_normalize(
        (math.sin((1.0 - fraction) * theta) * a + math.sin(fraction * theta) * b) / s
    )


@dataclass(frozen=True)
class Transform:
    """H_A_B: rotation R_A_B and translation t_A_B, mapping B coordinates into A."""

    rotation: Array
    translation: Array

    @staticmethod
    def identity() -> Transform:
        return Transform(np.eye(3), np.zeros(3))

    @staticmethod
    def from_quat(
        translation: Array | tuple[float, ...], quat_xyzw: Array | tuple[float, ...]
    ) -> Transform:
        return Transform(
            quat_to_matrix(np.asarray(quat_xyzw)), np.asarray(translation, dtype=np.float64)
        )

    @staticmethod
    def from_euler_zyx(
        translation: Array | tuple[float, ...], *, yaw_rad: float, pitch_rad: float, roll_rad: float
    ) -> Transform:
        return Transform(
            euler_zyx_to_matrix(yaw_rad, pitch_rad, roll_rad),
            np.asarray(translation, dtype=np.float64),
        )

    def apply(self, point: Array) -> Array:
        """p_A = R p_B + t."""
        return self.rotation @ np.asarray(point, dtype=np.float64) + self.translation

    def compose(self, other: Transform) -> Transform:
        """H_A_C = H_A_B * H_B_C (self is H_A_B, other is H_B_C)."""
        return Transform(
            self.rotation @ other.rotation, self.rotation @ other.translation + self.translation
        )

    def inverse(self) -> Transform:
        rt = self.rotation.T
        return Transform(rt, -rt @ self.translation)

    def quat_xyzw(self) -> Array:
        return matrix_to_quat(self.rotation)


def wrap_angle(angle_rad: float) -> float:
    """The same angle in (-pi, pi]."""
    return math.atan2(math.sin(angle_rad), math.cos(angle_rad))


def distance_to_segment(point: Array, start: Array, end: Array) -> float:
    """Distance from `point` to the segment from `start` to `end` (any dimension)."""
    along = end - start
    length2 = float(along @ along)
    t = 0.0 if length2 == 0.0 else min(1.0, max(0.0, float((point - start) @ along) / length2))
    return float(np.linalg.norm(point - (start + t * along)))
