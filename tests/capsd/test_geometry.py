"""Geometry properties: quaternions, Z-Y-X Euler, transforms, slerp."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from capsd.geometry import (
    Transform,
    euler_zyx_to_matrix,
    matrix_to_euler_zyx,
    matrix_to_quat,
    quat_slerp,
    quat_to_matrix,
    rotvec_to_matrix,
)

angle = st.floats(min_value=-math.pi, max_value=math.pi)
pitch = st.floats(min_value=-1.5, max_value=1.5)
coord = st.floats(min_value=-100.0, max_value=100.0)
quat = st.tuples(*[st.floats(min_value=-1.0, max_value=1.0)] * 4).filter(
    lambda q: sum(c * c for c in q) > 0.01
)


@given(quat)
def test_quaternion_matrix_round_trip(q: tuple[float, float, float, float]) -> None:
    m = quat_to_matrix(np.array(q))
    assert np.allclose(m @ m.T, np.eye(3), atol=1e-12)
    assert math.isclose(np.linalg.det(m), 1.0, abs_tol=1e-12)
    assert np.allclose(quat_to_matrix(matrix_to_quat(m)), m, atol=1e-12)


@given(angle, pitch, angle)
def test_euler_zyx_round_trip(yaw: float, p: float, roll: float) -> None:
    m = euler_zyx_to_matrix(yaw, p, roll)
    assert np.allclose(euler_zyx_to_matrix(*matrix_to_euler_zyx(m)), m, atol=1e-9)


def test_euler_convention_is_z_then_y_then_x() -> None:
    # yaw 90 deg maps x to y; pitch +90 deg (z up) maps x to -z; roll +90 deg maps y to z.
    assert np.allclose(euler_zyx_to_matrix(math.pi / 2, 0, 0) @ [1, 0, 0], [0, 1, 0])
    assert np.allclose(euler_zyx_to_matrix(0, math.pi / 2, 0) @ [1, 0, 0], [0, 0, -1])
    assert np.allclose(euler_zyx_to_matrix(0, 0, math.pi / 2) @ [0, 1, 0], [0, 0, 1])


@given(quat, st.tuples(coord, coord, coord), st.tuples(coord, coord, coord))
def test_transform_inverse_and_compose(
    q: tuple[float, ...], t: tuple[float, ...], p: tuple[float, ...]
) -> None:
    h = Transform.from_quat(t, q)
    assert np.allclose(h.inverse().apply(h.apply(np.array(p))), p, atol=1e-9)
    assert np.allclose(h.compose(h.inverse()).rotation, np.eye(3), atol=1e-12)


@given(quat, quat, st.floats(min_value=0.0, max_value=1.0))
def test_slerp_endpoints_and_constant_speed(
    a: tuple[float, ...], b: tuple[float, ...], f: float
) -> None:
    qa, qb = np.array(a), np.array(b)
    ra, rb = quat_to_matrix(qa), quat_to_matrix(qb)
    assert np.allclose(quat_to_matrix(quat_slerp(qa, qb, 0.0)), ra, atol=1e-9)
    assert np.allclose(quat_to_matrix(quat_slerp(qa, qb, 1.0)), rb, atol=1e-9)

    def angle_between(r1: np.ndarray, r2: np.ndarray) -> float:
        return math.acos(max(-1.0, min(1.0, (np.trace(r1.T @ r2) - 1.0) / 2.0)))

    total = angle_between(ra, rb)
    mid = quat_to_matrix(quat_slerp(qa, qb, f))
    assert math.isclose(angle_between(ra, mid), f * total, abs_tol=1e-6)


def test_rotvec_matches_euler_for_single_axis() -> None:
    assert np.allclose(rotvec_to_matrix(np.array([0, 0, 0.3])), euler_zyx_to_matrix(0.3, 0, 0))
