"""The simulation: world state and sensor models as one time-ordered stream of bus payloads.

The same stream feeds the real-time service (paced by the wall clock) and offline runs (as fast
as the CPU allows), so both paths produce the same measurements for the same seed.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from capsd import topics
from capsd.geometry import Array, Transform, euler_zyx_to_matrix, matrix_to_quat
from capsd.payloads import (
    AsvPose,
    Detection,
    GroundTruth,
    Payload,
    RovAttitude,
    RovDepth,
    RovVelocity,
    SonarDetections,
)
from capsd.sonar_geometry import to_polar
from capsd.topics import Topic
from simulator.config import Config
from simulator.world import TANKS, RovState, Trajectory


@dataclass(frozen=True)
class Event:
    """One measurement (or truth) at sim time `t_s`, for `topic` under `vehicle`."""

    t_s: float
    topic: Topic[Any]
    vehicle: str
    payload: Payload


def _vec3(v: Array) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


def _flat(m: Array) -> tuple[float, ...]:
    return tuple(float(v) for v in m.ravel())


def _quat(m: Array) -> tuple[float, float, float, float]:
    q = matrix_to_quat(m)
    return (float(q[0]), float(q[1]), float(q[2]), float(q[3]))


class Simulation:
    """Deterministic world and sensors for one seed; `events()` yields what the bus would carry."""

    def __init__(self, config: Config):
        self.config = config
        self.rng = np.random.default_rng(config.seed)
        self.tank = TANKS[config.tank]
        self.trajectory = Trajectory(self.tank, config.trajectory, speed_m_s=config.rov_speed_m_s)
        self.mount = config.sonar.transform()
        self.lever_arm = np.array(config.rov.pressure_sensor_m)
        self.asv_xy = self._asv_target(self.trajectory.state(0.0))
        self._asv_t = 0.0
        self._seq: dict[str, int] = {}

    # ------------------------------------------------------------------ world

    def _asv_target(self, rov: RovState) -> Array:
        # Stand back so the ROV appears on the boresight: horizontal offset = height / tan(pitch).
        height = -float(rov.position_m[2])
        pitch = max(math.radians(self.config.sonar.pitch_deg), math.radians(5.0))
        back = height / math.tan(pitch) + float(self.mount.translation[0])
        return np.asarray(rov.position_m[:2] - np.array([back, 0.0]))

    def _advance_asv(self, t_s: float) -> None:
        # First-order follower, integrated in steps so the result does not depend on call rate.
        step = 0.01
        while self._asv_t + step <= t_s:
            self._asv_t += step
            alpha = step / self.config.asv_follow_lag_s
            target = self._asv_target(self.trajectory.state(self._asv_t))
            self.asv_xy = self.asv_xy + alpha * (target - self.asv_xy)

    def asv_pose(self, t_s: float) -> Transform:
        self._advance_asv(t_s)
        roll = math.radians(1.0) * math.sin(2 * math.pi * t_s / 4.0)
        pitch = math.radians(0.8) * math.sin(2 * math.pi * t_s / 5.0 + 1.0)
        heave = 0.02 * math.sin(2 * math.pi * t_s / 4.5)
        return Transform(euler_zyx_to_matrix(0.0, pitch, roll), np.array([*self.asv_xy, heave]))

    # ------------------------------------------------------------------ sensors

    def detection(self, t_s: float, rov: RovState, asv: Transform) -> Detection | None:
        cfg = self.config
        if any(start <= t_s < end for start, end in cfg.sonar_dropouts_s):
            return None
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

    # ------------------------------------------------------------------ stream

    def _next_seq(self, stream: str) -> int:
        seq = self._seq.get(stream, 0)
        self._seq[stream] = seq + 1
        return seq

    def events(self, *, start_ns: int, duration_s: float | None = None) -> Iterator[Event]:
        """Every measurement in time order; stamps are `start_ns` + sim time (ns)."""
        cfg = self.config
        noise = cfg.noise
        periods = {
            "pose": 1.0 / cfg.rates.asv_pose_hz,
            "depth": 1.0 / cfg.rates.depth_hz,
            "attitude": 1.0 / cfg.rates.attitude_hz,
            "sonar": 1.0 / cfg.rates.sonar_hz,
        }
        if cfg.rates.velocity_hz > 0.0:
            periods["velocity"] = 1.0 / cfg.rates.velocity_hz
        # Same-time ties: the sonar (and its truth) last, after the inputs it needs.
        order = {name: (9 if name == "sonar" else i) for i, name in enumerate(periods)}
        due = [(0.0, order[name], name) for name in periods]
        heapq.heapify(due)
        pose_var = noise.pose_sigma_m**2
        pose_cov = tuple(
            float(v) for v in np.diag([pose_var] * 3 + [math.radians(0.1) ** 2] * 3).ravel()
        )
        counts = dict.fromkeys(periods, 0)
        while due:
            t, rank, name = heapq.heappop(due)
            if duration_s is not None and t > duration_s:
                return
            counts[name] += 1
            heapq.heappush(due, (counts[name] * periods[name], rank, name))
            stamp = start_ns + round(t * 1e9)
            rov = self.trajectory.state(t)
            asv = self.asv_pose(t)
            if name == "pose":
                noisy = asv.translation + self.rng.normal(0.0, noise.pose_sigma_m, 3)
                yield Event(
                    t,
                    topics.ASV_POSE,
                    cfg.asv_vehicle,
                    AsvPose(
                        stamp_ns=stamp,
                        seq=self._next_seq(name),
                        position_m=_vec3(noisy),
                        orientation_xyzw=_quat(asv.rotation),
                        covariance=pose_cov,
                        source="sim",
                    ),
                )
            elif name == "depth":
                yield Event(
                    t,
                    topics.ROV_DEPTH,
                    cfg.rov_vehicle,
                    RovDepth(
                        stamp_ns=stamp,
                        seq=self._next_seq(name),
                        depth_m=self.depth(rov),
                        sigma_m=max(noise.depth_sigma_m, 1e-4),
                    ),
                )
            elif name == "velocity":
                sigma = noise.velocity_sigma_m_s
                measured = rov.velocity_m_s + self.rng.normal(0.0, sigma, 3)
                yield Event(t, topics.ROV_VELOCITY, cfg.rov_vehicle, RovVelocity(
                    stamp_ns=stamp, seq=self._next_seq(name), velocity_m_s=_vec3(measured),
                    covariance_m2_s2=_flat(np.eye(3) * max(sigma, 1e-4) ** 2)))  # fmt: skip
            elif name == "attitude":
                yield Event(
                    t,
                    topics.ROV_ATTITUDE,
                    cfg.rov_vehicle,
                    RovAttitude(
                        stamp_ns=stamp,
                        seq=self._next_seq(name),
                        orientation_xyzw=_quat(rov.rotation),
                    ),
                )
            else:
                found = self.detection(t, rov, asv)
                ping = self._next_seq(name)
                yield Event(
                    t,
                    topics.SONAR_DETECTIONS,
                    cfg.asv_vehicle,
                    SonarDetections(
                        stamp_ns=stamp,
                        seq=ping,
                        ping_id=ping,
                        detector="sim_truth_noise",
                        detections=(found,) if found is not None else (),
                    ),
                )
                yield Event(t, topics.SIM_TRUTH, cfg.vehicle, GroundTruth(
                    stamp_ns=stamp, seq=self._next_seq("truth"),
                    asv_position_m=_vec3(asv.translation), asv_orientation_xyzw=_quat(asv.rotation),
                    rov_position_m=_vec3(rov.position_m), rov_orientation_xyzw=_quat(rov.rotation),
                    rov_velocity_m_s=_vec3(rov.velocity_m_s)))  # fmt: skip
