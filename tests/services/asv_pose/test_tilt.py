"""The tilt filter against analytic cases: static tilt, constant rotation, lateral acceleration."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from capsd.geometry import euler_zyx_to_matrix
from capsd.services.asv_pose.tilt import G, TiltFilter, TiltSettings
from capsd.simulator.imu import Imu, ImuModel

RATE_HZ = 200.0


def _run(
    filt: TiltFilter,
    rotation_at: Callable[[float], np.ndarray],
    accel_w_at: Callable[[float], np.ndarray],
    seconds: float,
    *,
    imu: Imu | None = None,
    seed: int = 0,
) -> list[tuple[float, float, float]]:
    """(t, roll error deg, pitch error deg) along a run."""
    imu = imu or Imu(
        ImuModel(
            gyro_sigma_rad_s=0.0,
            accel_sigma_m_s2=0.0,
            gyro_bias_sigma_rad_s=0.0,
            accel_bias_sigma_m_s2=0.0,
        ),
        np.eye(3),
        np.random.default_rng(seed),
    )
    rng = np.random.default_rng(seed)
    out = []
    for k in range(int(seconds * RATE_HZ)):
        t = k / RATE_HZ
        gyro, accel = imu.sample(t, rotation_at, accel_w_at(t), rng)
        filt.update(int(t * 1e9), gyro, accel)
        yaw_true = rotation_at(t)
        pitch = math.asin(-float(yaw_true[2, 0]))
        roll = math.atan2(float(yaw_true[2, 1]), float(yaw_true[2, 2]))
        out.append((t, math.degrees(filt.roll_rad - roll), math.degrees(filt.pitch_rad - pitch)))
    return out


def _still(_t: float) -> np.ndarray:
    return np.zeros(3)


def test_static_tilt() -> None:
    r = euler_zyx_to_matrix(0.7, math.radians(4.0), math.radians(-6.0))
    errors = _run(TiltFilter(), lambda _t: r, _still, 5.0)
    _, roll_err, pitch_err = errors[-1]
    assert abs(roll_err) < 0.01
    assert abs(pitch_err) < 0.01


def test_constant_rotation_is_followed_by_the_gyro() -> None:
    # Rolling at 2 deg/s for 5 s (to 10 deg): no lag beyond a few hundredths of a degree.
    errors = _run(
        TiltFilter(), lambda t: euler_zyx_to_matrix(0.0, 0.0, math.radians(2.0 * t)), _still, 5.0
    )
    assert max(abs(e[1]) for e in errors) < 0.05
    assert max(abs(e[2]) for e in errors) < 0.05


def test_lateral_acceleration_does_not_leak_into_roll() -> None:
    # Level ASV pushed sideways at 1 m/s^2 for 3 s: an accelerometer-trusting filter reads
    # atan(1 / 9.81) = 5.8 deg of roll. Uncompensated, the slow gain only limits the leak
    # (to ~3 deg for a 3 s push); compensated with the known acceleration, nothing leaks.
    level = euler_zyx_to_matrix(0.0, 0.0, 0.0)

    def push(t: float) -> np.ndarray:
        return np.array([0.0, 1.0, 0.0]) if 1.0 <= t < 4.0 else np.zeros(3)

    naive = math.degrees(math.atan2(1.0, G))
    uncompensated = max(abs(e[1]) for e in _run(TiltFilter(), lambda _t: level, push, 6.0))
    assert uncompensated < 0.6 * naive

    filt = TiltFilter()
    imu = Imu(
        ImuModel(
            gyro_sigma_rad_s=0.0,
            accel_sigma_m_s2=0.0,
            gyro_bias_sigma_rad_s=0.0,
            accel_bias_sigma_m_s2=0.0,
        ),
        np.eye(3),
        np.random.default_rng(0),
    )
    rng = np.random.default_rng(0)
    worst = 0.0
    for k in range(int(6.0 * RATE_HZ)):
        t = k / RATE_HZ
        gyro, accel = imu.sample(t, lambda _t: level, push(t), rng)
        filt.update(int(t * 1e9), gyro, accel, linear_accel_body_m_s2=level.T @ push(t))
        worst = max(worst, abs(math.degrees(filt.roll_rad)))
    assert worst < 0.01


def test_learns_the_gyro_bias_and_applies_the_mounting() -> None:
    # The IMU is mounted turned 90 deg about z and has a roll-rate bias of 0.01 rad/s.
    mount_r_i_b = euler_zyx_to_matrix(math.pi / 2, 0.0, 0.0).T  # R_I_B
    imu = Imu(
        ImuModel(
            gyro_sigma_rad_s=0.002,
            accel_sigma_m_s2=0.02,
            gyro_bias_sigma_rad_s=0.0,
            accel_bias_sigma_m_s2=0.0,
        ),
        mount_r_i_b,
        np.random.default_rng(1),
    )
    imu.gyro_bias = np.array([0.01, 0.0, 0.0])

    def waves(t: float) -> np.ndarray:
        return euler_zyx_to_matrix(
            0.0, math.radians(1.0) * math.sin(1.4 * t), math.radians(1.5) * math.sin(1.7 * t)
        )

    filt = TiltFilter(TiltSettings(mounting=mount_r_i_b.T))
    errors = _run(filt, waves, _still, 60.0, imu=imu)
    late = [e for e in errors if e[0] > 40.0]
    rms_roll = math.sqrt(sum(e[1] ** 2 for e in late) / len(late))
    rms_pitch = math.sqrt(sum(e[2] ** 2 for e in late) / len(late))
    assert rms_roll < 0.2
    assert rms_pitch < 0.2
    # The bias, seen in the body frame (the IMU's x is the body's y after a 90 deg mount).
    assert np.linalg.norm(filt.bias - mount_r_i_b.T @ np.array([0.01, 0.0, 0.0])) < 0.003


def test_gaps_and_bad_samples_are_counted_and_survived() -> None:
    filt = TiltFilter()
    filt.update(1_000_000, np.zeros(3), np.array([0.0, 0.0, G]))
    filt.update(2_000_000, np.array([np.nan, 0.0, 0.0]), np.array([0.0, 0.0, G]))
    filt.update(500_000, np.zeros(3), np.array([0.0, 0.0, G]))  # older than the last: refused
    filt.update(2_000_000_000, np.zeros(3), np.array([0.0, G * math.sin(0.1), G * math.cos(0.1)]))
    assert filt.rejected == 2
    assert filt.gaps == 1
    assert filt.roll_rad == pytest.approx(0.1)
