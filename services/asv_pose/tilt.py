"""Roll and pitch of the ASV from its IMU: gyro-dominant, accelerometer-corrected, bias-aware.

State: the unit "up" direction u expressed in the body frame B (what gravity's reaction points
along) and a gyro bias estimate b. For each sample, with dt from the stamps (never assumed):
1. rotate the IMU readings into B with the mounting R_B_I;
2. predict: the body turns by (omega - b) dt, so u turns the other way:
   u <- u - ((omega - b) x u) dt, renormalised;
3. correct toward the accelerometer's direction a/|a| (after removing the vehicle's own
   acceleration when the caller knows it) with a small gain, smaller still when |a| is far from
   g: w = exp(-((|a| - g) / accel_tolerance)^2). The gyro carries the attitude through the
   ASV's manoeuvres; the paper's filter trusted the accelerometer, so a lateral 1 m/s^2 became
   5.8 deg of roll. Note that a lateral acceleration hardly changes |a|: only the slow gain
   limits its leak, and the compensation removes it;
   the error e = a_hat x u drives u (proportional, kp) and the bias (integral, ki);
4. roll = atan2(u_y, u_z), pitch = atan2(-u_x, hypot(u_y, u_z)) (Z-Y-X, z up: for R = Rz Ry Rx
   the up direction in B is (-sin p, sin r cos p, cos r cos p)).
Tuning: kp sets how fast the accelerometer corrects (time constant ~ 1 / kp seconds); ki how
fast the bias is learnt; accel_tolerance how much |a| may differ from g before the
accelerometer is distrusted. A gap longer than `max_gap_s` re-initialises from the next
accelerometer reading (counted).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from capsd.geometry import Array

G = 9.80665


@dataclass(frozen=True)
class TiltSettings:
    kp: float = 0.2  # 1/s: the accelerometer corrects over ~5 s, the gyro carries shorter motion
    ki: float = 0.03  # 1/s^2: learns a 0.01 rad/s gyro bias within ~40 s
    accel_tolerance_m_s2: float = 0.3
    max_gap_s: float = 0.5
    mounting: Array | None = None  # R_B_I; None: the IMU is aligned with the body


class TiltFilter:
    """Feed samples in time order with `update`; read `roll_rad`, `pitch_rad`."""

    def __init__(self, settings: TiltSettings | None = None):
        self.settings = settings or TiltSettings()
        self._mount = np.eye(3) if self.settings.mounting is None else self.settings.mounting
        self.up = np.array([0.0, 0.0, 1.0])
        self.bias = np.zeros(3)
        self._last_ns: int | None = None
        self.gaps = 0
        self.rejected = 0

    def update(
        self,
        stamp_ns: int,
        gyro_rad_s: Array,
        accel_m_s2: Array,
        *,
        linear_accel_body_m_s2: Array | None = None,
    ) -> None:
        """Fuse one IMU sample (IMU frame).

        `linear_accel_body_m_s2`, when the caller knows the vehicle's own acceleration (from
        its position track), is removed from the specific force so that only gravity remains:
        no lateral acceleration then leaks into tilt.
        """
        s = self.settings
        omega = self._mount @ np.asarray(gyro_rad_s, dtype=np.float64)
        accel = self._mount @ np.asarray(accel_m_s2, dtype=np.float64)
        if linear_accel_body_m_s2 is not None:
            accel = accel - np.asarray(linear_accel_body_m_s2, dtype=np.float64)
        norm = float(np.linalg.norm(accel))
        if not (math.isfinite(norm) and np.all(np.isfinite(omega))):
            self.rejected += 1
            return
        if self._last_ns is None:
            self._start(stamp_ns, accel, norm)
            return
        dt = (stamp_ns - self._last_ns) / 1e9
        if dt <= 0.0:
            self.rejected += 1  # out of order or duplicate: time only moves forward
            return
        if dt > s.max_gap_s:
            self.gaps += 1
            self._start(stamp_ns, accel, norm)
            return
        self._last_ns = stamp_ns
        rate = omega - self.bias
        if norm > 0.0:
            weight = math.exp(-(((norm - G) / s.accel_tolerance_m_s2) ** 2))
            error = np.cross(accel / norm, self.up) * weight
        else:
            error = np.zeros(3)
        # The correction acts like an extra rotation rate that turns u toward a_hat:
        # -(kp e) x u with e = a_hat x u equals kp (a_hat - u cos) (toward a_hat).
        self.bias -= s.ki * error * dt
        rate = rate + s.kp * error
        self.up = self.up - np.cross(rate, self.up) * dt
        self.up /= np.linalg.norm(self.up)

    def _start(self, stamp_ns: int, accel: Array, norm: float) -> None:
        self._last_ns = stamp_ns
        if norm > 0.0:
            self.up = accel / norm

    @property
    def roll_rad(self) -> float:
        return math.atan2(float(self.up[1]), float(self.up[2]))

    @property
    def pitch_rad(self) -> float:
        return math.atan2(-float(self.up[0]), math.hypot(float(self.up[1]), float(self.up[2])))
