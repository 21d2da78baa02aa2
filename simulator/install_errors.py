"""What a real installation gets wrong and the services do not know: drawn once per run.

The services are configured with the nominal mounts (the drawings); the simulated world uses
the nominal mounts plus these errors. Magnitudes (`realistic`, the standard deviations of
`InstallErrorsConfig`) and where they come from are in docs/INSTALL-ERRORS.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated, Literal

import msgspec
import numpy as np

from capsd.config import ConfigSection
from capsd.geometry import Transform

Sigma = Annotated[float, msgspec.Meta(ge=0.0, le=100.0)]


class InstallErrorsConfig(ConfigSection, frozen=True, kw_only=True):
    """Per-run errors; each drawn from a normal law of this standard deviation (off: none)."""

    # On by default: the world as a real installation is (docs/INSTALL-ERRORS.md). Benches
    # that measure a method rather than an installation say `off` themselves.
    mode: Literal["realistic", "off"] = "realistic"
    # The installation's own seed (None: the run's): one site's errors over several dives.
    seed: int | None = None
    sonar_angle_sigma_deg: Sigma = 0.7  # yaw, pitch and roll of the sonar against the ASV
    sonar_position_sigma_m: Sigma = 0.02
    lidar_yaw_sigma_deg: Sigma = 0.3  # the LiDAR's heading against the hull
    lidar_position_sigma_m: Sigma = 0.01
    pressure_arm_sigma_m: Sigma = 0.02  # the pressure port's place on the ROV
    # Relative, the speed the sonar assumes against the true one: its own thermometer (in its
    # housing, warmed by its electronics; about 1.8 degC at 24 degC) and its salinity setting.
    sound_speed_sigma: Sigma = 0.003
    depth_bias_sigma_m: Sigma = 0.02  # surface pressure at autopilot boot
    depth_drift_sigma_m_per_h: Sigma = 0.03  # atmospheric pressure changing during the dive
    depth_quantum_m: Sigma = 0.002  # a Bar30's 0.2 mbar
    attitude_bias_sigma_deg: Sigma = 0.5  # the ROV AHRS's roll and pitch bias
    heading_error_sigma_deg: Sigma = 2.0  # its magnetometer heading in a steel tank
    attitude_noise_deg: Sigma = 0.2
    float_trim_sigma_m: Sigma = 0.01  # the ROV's floating depth against rov.float_depth_m
    rov_thermometer_sigma_c: Sigma = 0.5  # the ROV's water thermometer (its Bar30's)


@dataclass(frozen=True)
class InstallErrors:
    """One run's errors (all zero when off)."""

    sonar: Transform  # H_nominal_true: the true sonar frame seen from the nominal one
    lidar: Transform
    pressure_arm_m: tuple[float, float, float]
    sound_speed_scale: float  # true speed / the speed the sonar assumes
    depth_bias_m: float
    depth_drift_m_per_s: float
    depth_quantum_m: float
    heading_error_rad: float  # the AHRS's heading, off about the vertical
    attitude_bias: Transform  # its roll and pitch bias, in the body (rotation only)
    attitude_noise_rad: float
    float_trim_m: float = 0.0  # the floating ROV sits this much deeper than configured
    rov_thermometer_bias_c: float = 0.0  # what the ROV's thermometer reads above the water

    @classmethod
    def none(cls) -> InstallErrors:
        zero = Transform.from_euler_zyx((0.0, 0.0, 0.0), yaw_rad=0.0, pitch_rad=0.0, roll_rad=0.0)
        return cls(zero, zero, (0.0, 0.0, 0.0), 1.0, 0.0, 0.0, 0.0, 0.0, zero, 0.0)

    @classmethod
    def draw(cls, config: InstallErrorsConfig, rng: np.random.Generator) -> InstallErrors:
        if config.mode == "off":
            return cls.none()
        c = config

        def angles(sigma_deg: float) -> list[float]:
            return [math.radians(v) for v in rng.normal(0.0, sigma_deg, 3)]

        yaw, pitch, roll = angles(c.sonar_angle_sigma_deg)
        sonar = Transform.from_euler_zyx(
            tuple(rng.normal(0.0, c.sonar_position_sigma_m, 3)),
            yaw_rad=yaw,
            pitch_rad=pitch,
            roll_rad=roll,
        )
        lidar_xy = rng.normal(0.0, c.lidar_position_sigma_m, 2)
        lidar = Transform.from_euler_zyx(
            (float(lidar_xy[0]), float(lidar_xy[1]), 0.0),
            yaw_rad=math.radians(float(rng.normal(0.0, c.lidar_yaw_sigma_deg))),
            pitch_rad=0.0,
            roll_rad=0.0,
        )
        arm = rng.normal(0.0, c.pressure_arm_sigma_m, 3)
        att_roll, att_pitch = (
            math.radians(v) for v in rng.normal(0.0, c.attitude_bias_sigma_deg, 2)
        )
        heading = math.radians(float(rng.normal(0.0, c.heading_error_sigma_deg)))
        return cls(
            sonar=sonar,
            lidar=lidar,
            pressure_arm_m=(float(arm[0]), float(arm[1]), float(arm[2])),
            sound_speed_scale=1.0 + float(rng.normal(0.0, c.sound_speed_sigma)),
            depth_bias_m=float(rng.normal(0.0, c.depth_bias_sigma_m)),
            depth_drift_m_per_s=float(rng.normal(0.0, c.depth_drift_sigma_m_per_h)) / 3600.0,
            depth_quantum_m=c.depth_quantum_m,
            heading_error_rad=heading,
            attitude_bias=Transform.from_euler_zyx(
                (0.0, 0.0, 0.0), yaw_rad=0.0, pitch_rad=att_pitch, roll_rad=att_roll
            ),
            attitude_noise_rad=math.radians(c.attitude_noise_deg),
            # Drawn last: every earlier error stays what a seed drew before it was added.
            float_trim_m=float(rng.normal(0.0, c.float_trim_sigma_m)),
            rov_thermometer_bias_c=float(rng.normal(0.0, c.rov_thermometer_sigma_c)),
        )

    def depth_reading(self, true_depth_m: float, t_s: float, noise_m: float) -> float:
        """What the pressure sensor reports: biased, drifting, noisy, quantised."""
        depth = true_depth_m + self.depth_bias_m + self.depth_drift_m_per_s * t_s + noise_m
        if self.depth_quantum_m > 0.0:
            depth = round(depth / self.depth_quantum_m) * self.depth_quantum_m
        return depth

    def attitude_reading(self, rotation: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """What the ROV's AHRS reports for its true R_W_R: heading off, tilt biased, noisy."""
        if self.attitude_noise_rad == 0.0 and self.heading_error_rad == 0.0:
            return rotation @ self.attitude_bias.rotation
        from capsd.geometry import euler_zyx_to_matrix

        yaw, pitch, roll = rng.normal(0.0, self.attitude_noise_rad, 3)
        heading = euler_zyx_to_matrix(self.heading_error_rad, 0.0, 0.0)
        noise = euler_zyx_to_matrix(float(yaw), float(pitch), float(roll))
        reported: np.ndarray = heading @ rotation @ self.attitude_bias.rotation @ noise
        return reported

    def summary(self) -> dict[str, float]:
        """The drawn errors in the units people quote (degrees, mm, ppm), for reports."""
        from capsd.geometry import matrix_to_euler_zyx

        yaw, pitch, roll = (math.degrees(v) for v in matrix_to_euler_zyx(self.sonar.rotation))
        lidar_yaw = math.degrees(matrix_to_euler_zyx(self.lidar.rotation)[0])
        _, att_pitch, att_roll = (
            math.degrees(v) for v in matrix_to_euler_zyx(self.attitude_bias.rotation)
        )
        heading = math.degrees(self.heading_error_rad)
        return {
            "sonar_yaw_deg": round(yaw, 3),
            "sonar_pitch_deg": round(pitch, 3),
            "sonar_roll_deg": round(roll, 3),
            "sonar_offset_mm": round(float(np.linalg.norm(self.sonar.translation)) * 1000, 1),
            "lidar_yaw_deg": round(lidar_yaw, 3),
            "sound_speed_ppm": round((self.sound_speed_scale - 1.0) * 1e6),
            "depth_bias_mm": round(self.depth_bias_m * 1000, 1),
            "depth_drift_mm_per_h": round(self.depth_drift_m_per_s * 3600 * 1000, 1),
            "rov_heading_error_deg": round(heading, 3),
            "rov_pitch_bias_deg": round(att_pitch, 3),
            "rov_roll_bias_deg": round(att_roll, 3),
            "pressure_arm_z_mm": round(self.pressure_arm_m[2] * 1000, 1),
            "float_trim_mm": round(self.float_trim_m * 1000, 1),
            "rov_thermometer_bias_c": round(self.rov_thermometer_bias_c, 3),
        }
