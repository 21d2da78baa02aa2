"""Real-time simulator service at detection level: publishes what the real services would.

Streams (each stamped at its measurement instant, with the vehicle's clock offset):
ASV pose (`asv`), sonar detections (`asv`), ROV depth and attitude (`rov`), truth (`sim`).
Noise models: pose position N(0, pose_sigma_m) per axis; detection range N(0, range_sigma_m),
azimuth N(0, azimuth_sigma_deg); depth N(0, depth_sigma_m) on the pressure sensor, which sits at
the configured lever arm from the ROV centre. The full image-forming simulator is issue 3.
"""

from __future__ import annotations

import math
import time
from typing import Annotated

import msgspec
import numpy as np

from capsd import topics
from capsd.config import ConfigSection, ServiceConfig
from capsd.geometry import Transform, euler_zyx_to_matrix, matrix_to_quat
from capsd.mounts import RovConfig, SonarMountConfig
from capsd.payloads import (
    AsvPose,
    Detection,
    GroundTruth,
    RovAttitude,
    RovDepth,
    SonarDetections,
)
from capsd.runner import ServiceRunner
from capsd.sonar_geometry import to_polar
from simulator.world import TANKS, RovState, TankName, Trajectory, TrajectoryName

Rate = Annotated[float, msgspec.Meta(gt=0.0, le=200.0)]
Sigma = Annotated[float, msgspec.Meta(ge=0.0, le=10.0)]


class Rates(ConfigSection, frozen=True, kw_only=True):
    asv_pose_hz: Rate = 50.0
    sonar_hz: Rate = 10.0
    depth_hz: Rate = 10.0
    attitude_hz: Rate = 20.0


class Noise(ConfigSection, frozen=True, kw_only=True):
    pose_sigma_m: Sigma = 0.01
    range_sigma_m: Sigma = 0.02
    azimuth_sigma_deg: Sigma = 0.3
    depth_sigma_m: Sigma = 0.01


class Config(ServiceConfig, frozen=True, kw_only=True):
    """Simulator configuration."""

    vehicle: str = "sim"
    asv_vehicle: str = "asv"
    rov_vehicle: str = "rov"
    tank: TankName = "nfp"
    trajectory: TrajectoryName = "square"
    rov_speed_m_s: Annotated[float, msgspec.Meta(gt=0.0, le=0.5)] = 0.3
    seed: int = 0
    sonar: SonarMountConfig = SonarMountConfig()
    rov: RovConfig = RovConfig()
    sonar_max_range_m: Annotated[float, msgspec.Meta(gt=0.1, le=120.0)] = 30.0
    sonar_half_fov_deg: Annotated[float, msgspec.Meta(gt=0.0, le=90.0)] = 65.0
    # The ASV keeps station so the ROV sits near the sonar's boresight (it "follows").
    asv_follow_lag_s: Annotated[float, msgspec.Meta(gt=0.0, le=60.0)] = 2.0
    rates: Rates = Rates()
    noise: Noise = Noise()


class Simulation:
    """Deterministic world state and sensor models; `step(t)` returns due measurements."""

    def __init__(self, config: Config):
        self.config = config
        self.rng = np.random.default_rng(config.seed)
        self.tank = TANKS[config.tank]
        self.trajectory = Trajectory(self.tank, config.trajectory, speed_m_s=config.rov_speed_m_s)
        self.mount = config.sonar.transform()
        self.lever_arm = np.array(config.rov.pressure_sensor_m)
        self.asv_xy = self._asv_target(self.trajectory.state(0.0))

    def _asv_target(self, rov: RovState) -> np.ndarray:
        # Stand back so the ROV appears on the boresight: horizontal offset = height / tan(pitch).
        height = -float(rov.position_m[2])
        back = height / math.tan(max(math.radians(self.config.sonar.pitch_deg), math.radians(5.0)))
        return np.asarray(rov.position_m[:2] - np.array([back + self.mount.translation[0], 0.0]))

    def advance_asv(self, rov: RovState, dt_s: float) -> None:
        alpha = min(1.0, dt_s / self.config.asv_follow_lag_s)
        self.asv_xy = self.asv_xy + alpha * (self._asv_target(rov) - self.asv_xy)

    def asv_pose(self, t_s: float) -> Transform:
        roll = math.radians(1.0) * math.sin(2 * math.pi * t_s / 4.0)
        pitch = math.radians(0.8) * math.sin(2 * math.pi * t_s / 5.0 + 1.0)
        heave = 0.02 * math.sin(2 * math.pi * t_s / 4.5)
        return Transform(euler_zyx_to_matrix(0.0, pitch, roll), np.array([*self.asv_xy, heave]))

    def detection(self, rov: RovState, asv: Transform) -> Detection | None:
        cfg = self.config
        p_s = asv.compose(self.mount).inverse().apply(rov.position_m)
        r, azimuth, elevation = to_polar(cfg.sonar.beam_model, p_s)
        if (
            p_s[0] <= 0.0
            or r > cfg.sonar_max_range_m
            or abs(azimuth) > math.radians(cfg.sonar_half_fov_deg)
            or abs(elevation) > math.radians(cfg.sonar.vertical_aperture_deg) / 2.0
        ):
            return None
        sigma_az = math.radians(cfg.noise.azimuth_sigma_deg)
        return Detection(
            range_m=max(0.05, r + float(self.rng.normal(0.0, cfg.noise.range_sigma_m))),
            azimuth_rad=azimuth + float(self.rng.normal(0.0, sigma_az)),
            range_sigma_m=cfg.noise.range_sigma_m,
            azimuth_sigma_rad=sigma_az,
            confidence=0.95,
            range_extent_m=0.45,
            azimuth_extent_rad=0.6 / max(r, 0.6),
        )

    def depth(self, rov: RovState) -> float:
        sensor_z = float(rov.position_m[2] + (rov.rotation @ self.lever_arm)[2])
        return -sensor_z + float(self.rng.normal(0.0, self.config.noise.depth_sigma_m))


def _tuple3(v: np.ndarray) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


def _quat(m: np.ndarray) -> tuple[float, float, float, float]:
    q = matrix_to_quat(m)
    return (float(q[0]), float(q[1]), float(q[2]), float(q[3]))


def main(config: Config) -> int:
    """Run the simulator in real time until stopped."""
    sim = Simulation(config)
    noise = config.noise
    with ServiceRunner("sim", config) as runner:
        asv_pose = runner.publisher(topics.ASV_POSE, vehicle=config.asv_vehicle)
        detections = runner.publisher(topics.SONAR_DETECTIONS, vehicle=config.asv_vehicle)
        depth = runner.publisher(topics.ROV_DEPTH, vehicle=config.rov_vehicle)
        attitude = runner.publisher(topics.ROV_ATTITUDE, vehicle=config.rov_vehicle)
        truth = runner.publisher(topics.SIM_TRUTH)
        start_ns = time.time_ns()
        periods = {
            "pose": 1.0 / config.rates.asv_pose_hz,
            "sonar": 1.0 / config.rates.sonar_hz,
            "depth": 1.0 / config.rates.depth_hz,
            "attitude": 1.0 / config.rates.attitude_hz,
        }
        due = dict.fromkeys(periods, 0.0)
        last_t = 0.0
        pose_var = noise.pose_sigma_m**2
        pose_cov = tuple(
            float(v) for v in np.diag([pose_var] * 3 + [math.radians(0.1) ** 2] * 3).ravel()
        )

        def step() -> None:
            nonlocal last_t
            now_ns = time.time_ns()
            t = (now_ns - start_ns) / 1e9
            rov = sim.trajectory.state(t)
            sim.advance_asv(rov, t - last_t)
            last_t = t
            asv = sim.asv_pose(t)
            if t >= due["pose"]:
                due["pose"] = t + periods["pose"]
                noisy = asv.translation + sim.rng.normal(0.0, noise.pose_sigma_m, 3)
                asv_pose.put(
                    AsvPose(
                        stamp_ns=now_ns,
                        seq=asv_pose.next_seq(),
                        position_m=_tuple3(noisy),
                        orientation_xyzw=_quat(asv.rotation),
                        covariance=pose_cov,
                        source="sim",
                    )
                )
            if t >= due["depth"]:
                due["depth"] = t + periods["depth"]
                depth.put(
                    RovDepth(
                        stamp_ns=now_ns,
                        seq=depth.next_seq(),
                        depth_m=sim.depth(rov),
                        sigma_m=max(noise.depth_sigma_m, 1e-4),
                    )
                )
            if t >= due["attitude"]:
                due["attitude"] = t + periods["attitude"]
                attitude.put(
                    RovAttitude(
                        stamp_ns=now_ns,
                        seq=attitude.next_seq(),
                        orientation_xyzw=_quat(rov.rotation),
                    )
                )
            if t >= due["sonar"]:
                due["sonar"] = t + periods["sonar"]
                found = sim.detection(rov, asv)
                ping_seq = detections.next_seq()
                detections.put(
                    SonarDetections(
                        stamp_ns=now_ns,
                        seq=ping_seq,
                        ping_id=ping_seq,
                        detector="sim_truth_noise",
                        detections=(found,) if found is not None else (),
                    )
                )
                truth.put(
                    GroundTruth(
                        stamp_ns=now_ns,
                        seq=truth.next_seq(),
                        asv_position_m=_tuple3(asv.translation),
                        asv_orientation_xyzw=_quat(asv.rotation),
                        rov_position_m=_tuple3(rov.position_m),
                        rov_orientation_xyzw=_quat(rov.rotation),
                        rov_velocity_m_s=_tuple3(rov.velocity_m_s),
                    )
                )

        runner.run(step, period_s=0.005)
    return 0
