"""The locator service: per-ping CAP-SD fixes from detections, ASV pose and ROV depth/attitude.

Inputs are time-aligned at each ping's `stamp_ns` (pose: linear + slerp; depth: linear).
This is the per-frame fix; the tracking filter of issue 4 builds on it.
"""

from __future__ import annotations

import logging
import math
from typing import Annotated

import msgspec
import numpy as np

from capsd import topics
from capsd.config import ConfigSection, ServiceConfig
from capsd.geometry import Array, Transform, quat_slerp, quat_to_matrix
from capsd.mounts import RovConfig, SonarMountConfig
from capsd.payloads import AsvPose, Detection, RovAttitude, RovDepth, RovFix, SonarDetections
from capsd.runner import Publisher, ServiceRunner
from services.locator.fix import FixUncertainty, rov_centre_z, solve_fix
from services.locator.timeline import Timeline

logger = logging.getLogger(__name__)


class LocatorInputs(ConfigSection, frozen=True, kw_only=True):
    """Whose streams the locator reads."""

    asv_vehicle: str = "asv"
    rov_vehicle: str = "rov"
    # How far past the newest sample an input may be extrapolated before the fix is refused.
    max_extrapolation_s: Annotated[float, msgspec.Meta(ge=0.0, le=1.0)] = 0.15
    buffer_s: Annotated[float, msgspec.Meta(gt=0.0, le=30.0)] = 5.0


class Config(ServiceConfig, frozen=True, kw_only=True):
    """Locator configuration."""

    vehicle: str = "topside"
    inputs: LocatorInputs = LocatorInputs()
    sonar: SonarMountConfig = SonarMountConfig()
    rov: RovConfig = RovConfig()
    max_conditioning: Annotated[float, msgspec.Meta(gt=0.0)] = 10.0
    min_confidence: Annotated[float, msgspec.Meta(ge=0.0, le=1.0)] = 0.5


def _lerp_pose(a: tuple[Array, Array], b: tuple[Array, Array], f: float) -> tuple[Array, Array]:
    return a[0] + f * (b[0] - a[0]), quat_slerp(a[1], b[1], f)


def _lerp_float(a: float, b: float, f: float) -> float:
    return a + f * (b - a)


def _lerp_quat(a: Array, b: Array, f: float) -> Array:
    return quat_slerp(a, b, f)


class Locator:
    """Holds the aligned input timelines and turns one detection message into one RovFix."""

    def __init__(self, config: Config):
        self.config = config
        self.mount = config.sonar.transform()
        self.aperture_rad = math.radians(config.sonar.vertical_aperture_deg)
        self.lever_arm = np.array(config.rov.pressure_sensor_m)
        extrap = int(config.inputs.max_extrapolation_s * 1e9)
        self.poses: Timeline[tuple[Array, Array]] = Timeline(
            _lerp_pose, capacity=int(config.inputs.buffer_s * 200), max_extrapolation_ns=extrap
        )
        self.pose_cov: Array = np.eye(6) * 1e-4
        self.depths: Timeline[float] = Timeline(
            _lerp_float, capacity=int(config.inputs.buffer_s * 100), max_extrapolation_ns=extrap
        )
        self.depth_sigma_m = 0.01
        self.attitudes: Timeline[Array] = Timeline(
            _lerp_quat, capacity=int(config.inputs.buffer_s * 100), max_extrapolation_ns=extrap
        )

    def on_pose(self, pose: AsvPose) -> None:
        if pose.status == "lost":
            return  # a lost pose is not a pose: fixes needing it are refused as missing
        self.poses.add(pose.stamp_ns, (np.array(pose.position_m), np.array(pose.orientation_xyzw)))
        self.pose_cov = np.array(pose.covariance).reshape(6, 6)

    def on_depth(self, depth: RovDepth) -> None:
        self.depths.add(depth.stamp_ns, depth.depth_m)
        self.depth_sigma_m = depth.sigma_m

    def on_attitude(self, attitude: RovAttitude) -> None:
        self.attitudes.add(attitude.stamp_ns, np.array(attitude.orientation_xyzw))

    def locate(self, detections: SonarDetections, *, seq: int) -> RovFix:
        """The fix for one ping, or an invalid RovFix that says why there is none."""
        stamp = detections.stamp_ns
        refused = RovFix(stamp_ns=stamp, seq=seq, method="capsd", quality="invalid")
        best: Detection | None = max(
            detections.detections, key=lambda d: d.confidence, default=None
        )
        if best is None or best.confidence < self.config.min_confidence:
            return msgspec.structs.replace(refused, no_fix_reason="no_detection")
        pose = self.poses.at(stamp)
        depth = self.depths.at(stamp)
        attitude = self.attitudes.at(stamp)
        refused = msgspec.structs.replace(
            refused,
            asv_pose_stamp_ns=pose.stamp_ns,
            depth_stamp_ns=depth.stamp_ns,
            attitude_stamp_ns=attitude.stamp_ns,
        )
        for name, lookup in (("asv_pose", pose), ("depth", depth), ("attitude", attitude)):
            if lookup.failure is not None:
                return msgspec.structs.replace(refused, no_fix_reason=f"{name}_{lookup.failure}")
        assert pose.value is not None
        assert depth.value is not None
        assert attitude.value is not None
        asv = Transform(quat_to_matrix(pose.value[1]), pose.value[0])
        z = rov_centre_z(depth.value, quat_to_matrix(attitude.value), self.lever_arm)
        result = solve_fix(
            asv_pose=asv,
            sonar_mount=self.mount,
            range_m=best.range_m,
            azimuth_rad=best.azimuth_rad,
            rov_z_m=z,
            vertical_aperture_rad=self.aperture_rad,
            beam_model=self.config.sonar.beam_model,
            max_conditioning=self.config.max_conditioning,
            uncertainty=FixUncertainty(
                range_sigma_m=max(best.range_sigma_m, 1e-4),
                azimuth_sigma_rad=max(best.azimuth_sigma_rad, 1e-5),
                rov_z_sigma_m=self.depth_sigma_m,
                asv_pose_covariance=self.pose_cov,
            ),
        )
        finite_conditioning = (
            result.conditioning
            if result.conditioning is not None and math.isfinite(result.conditioning)
            else None
        )
        if result.position_m is None or result.covariance_m2 is None:
            return msgspec.structs.replace(
                refused, no_fix_reason=result.reason, conditioning=finite_conditioning
            )
        x, y, z = (float(v) for v in result.position_m)
        return msgspec.structs.replace(
            refused,
            quality="good",
            raw_position_m=(x, y, z),
            raw_covariance_m2=tuple(float(v) for v in result.covariance_m2.ravel()),
            conditioning=finite_conditioning,
        )


def main(config: Config) -> int:
    """Run the locator until stopped."""
    locator = Locator(config)
    with ServiceRunner("locator", config) as runner:
        fixes: Publisher[RovFix] = runner.publisher(topics.ROV_FIX)

        def on_detections(detections: SonarDetections) -> None:
            fixes.put(locator.locate(detections, seq=fixes.next_seq()))

        asv, rov = config.inputs.asv_vehicle, config.inputs.rov_vehicle
        runner.subscribe(topics.ASV_POSE, locator.on_pose, vehicle=asv)
        runner.subscribe(topics.ROV_DEPTH, locator.on_depth, vehicle=rov)
        runner.subscribe(topics.ROV_ATTITUDE, locator.on_attitude, vehicle=rov)
        runner.subscribe(topics.SONAR_DETECTIONS, on_detections, vehicle=asv)
        runner.run()
    return 0
