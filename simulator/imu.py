"""The ASV's IMU: gyro and accelerometer in the IMU's own frame, with noise and bias.

gyro  = R_I_B omega_B + b_g + N(0, gyro_sigma)                   [rad/s]
accel = R_I_B R_W_B^T (a_W + g e_z) + b_a + N(0, accel_sigma)     [m/s^2, specific force]
omega_B comes from the attitude's time derivative (central difference, 1 ms); biases are
constant per run, in the sensor's own frame, drawn from N(0, bias_sigma) with the run's seed;
R_I_B is the mounting.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from capsd.geometry import Array
from capsd.simulator.world import GRAVITY


@dataclass(frozen=True)
class ImuModel:
    rate_hz: float = 200.0
    gyro_sigma_rad_s: float = 0.002
    accel_sigma_m_s2: float = 0.02
    gyro_bias_sigma_rad_s: float = 0.001
    accel_bias_sigma_m_s2: float = 0.02


def body_rates(rotation_at: Callable[[float], Array], t_s: float, *, h: float = 1e-3) -> Array:
    """omega_B from R(t): vee(R^T dR/dt) by central differences."""
    r0, r1 = rotation_at(t_s - h), rotation_at(t_s + h)
    r = rotation_at(t_s)
    omega_hat = r.T @ (r1 - r0) / (2.0 * h)
    return np.array([omega_hat[2, 1], omega_hat[0, 2], omega_hat[1, 0]])


class Imu:
    """One IMU with its biases and mounting; `sample` gives (gyro, accel) at a time."""

    def __init__(self, model: ImuModel, mounting: Array, rng: np.random.Generator):
        self.model = model
        self.mounting = mounting  # R_I_B
        self.gyro_bias = rng.normal(0.0, model.gyro_bias_sigma_rad_s, 3)
        self.accel_bias = rng.normal(0.0, model.accel_bias_sigma_m_s2, 3)

    def sample(
        self,
        t_s: float,
        rotation_at: Callable[[float], Array],
        accel_w: Array,
        rng: np.random.Generator,
    ) -> tuple[Array, Array]:
        m = self.model
        omega_b = body_rates(rotation_at, t_s)
        specific_w = accel_w + np.array([0.0, 0.0, GRAVITY])
        f_b = rotation_at(t_s).T @ specific_w
        gyro = self.mounting @ omega_b + self.gyro_bias + rng.normal(0.0, m.gyro_sigma_rad_s, 3)
        accel = self.mounting @ f_b + self.accel_bias + rng.normal(0.0, m.accel_sigma_m_s2, 3)
        return gyro, accel
