"""The ASV pose service: IMU and LiDAR scans in, the ASV's pose out at IMU rate.

See capsd.services.asv_pose.estimator for the method. It finds itself by a global search (no
position seed); the bare rectangle is 180-degree symmetric, so `heading_prior_deg` (which way the
ASV was put in the water, or a compass) picks the side, within `heading_prior_tolerance_deg`.
"""

from __future__ import annotations

import logging
import math
import threading
from typing import Annotated, Literal

import msgspec
import numpy as np

from capsd import topics
from capsd.config import ServiceConfig
from capsd.geometry import (
    euler_zyx_to_matrix,
    matrix_to_euler_zyx,
    quat_to_matrix,
)
from capsd.payloads import AsvPose, ImuSample, LidarScan
from capsd.runner import Publisher, ServiceRunner
from capsd.services.asv_pose.estimator import AsvPoseEstimator, EstimatorSettings, pose_payload
from capsd.services.asv_pose.global_search import SearchSettings
from capsd.services.asv_pose.scan_match import tank_walls
from capsd.services.asv_pose.tilt import TiltSettings

logger = logging.getLogger(__name__)

Metres = Annotated[float, msgspec.Meta(gt=0.0, le=500.0)]


class Config(ServiceConfig, frozen=True, kw_only=True):
    """ASV pose configuration."""

    vehicle: str = "asv"
    # scan_match: the built-in matcher on asv/scan; external: an existing SLAM's pose on
    # asv/pose_external (e.g. from `capsd run ros_input`), with our tilt filter and IMU rate.
    source: Literal["scan_match", "external"] = "scan_match"
    tank_length_m: Metres = 28.0
    tank_width_m: Metres = 16.0
    # Which way the ASV points at start-up (W's x = 0 deg, counter-clockwise); null: no prior,
    # only a map without the rectangle's symmetry can be searched.
    heading_prior_deg: Annotated[float, msgspec.Meta(ge=-360.0, le=360.0)] | None = 0.0
    heading_prior_tolerance_deg: Annotated[float, msgspec.Meta(gt=0.0, lt=90.0)] = 60.0
    lidar_xy_m: tuple[float, float] = (0.0, 0.0)
    # The scanner's height above the ASV's origin (the point the pose is of): on a mast it
    # sways with roll and pitch, which the scan matching takes out.
    lidar_height_m: Annotated[float, msgspec.Meta(ge=-5.0, le=5.0)] = 0.0
    imu_mount_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    tilt_kp: Annotated[float, msgspec.Meta(gt=0.0, le=10.0)] = 0.2
    tilt_ki: Annotated[float, msgspec.Meta(ge=0.0, le=1.0)] = 0.03
    min_inlier_ratio: Annotated[float, msgspec.Meta(ge=0.0, le=1.0)] = 0.6
    max_jump_m: Annotated[float, msgspec.Meta(gt=0.0, le=10.0)] = 0.5


def main(config: Config) -> int:
    """Run the pose service until stopped."""
    roll, pitch, yaw = (math.radians(v) for v in config.imu_mount_rpy_deg)
    r_b_i = euler_zyx_to_matrix(yaw, pitch, roll)
    estimator = AsvPoseEstimator(
        tank_walls(config.tank_length_m, config.tank_width_m),
        heading_prior_rad=(
            math.radians(config.heading_prior_deg) if config.heading_prior_deg is not None else None
        ),
        search_settings=SearchSettings(
            prior_tolerance_rad=math.radians(config.heading_prior_tolerance_deg)
        ),
        settings=EstimatorSettings(
            min_inlier_ratio=config.min_inlier_ratio,
            max_jump_m=config.max_jump_m,
            lidar_position_m=(*config.lidar_xy_m, config.lidar_height_m),
        ),
        tilt=TiltSettings(kp=config.tilt_kp, ki=config.tilt_ki, mounting=r_b_i),
    )
    lock = threading.Lock()  # IMU and scan callbacks may run on different Zenoh threads
    with ServiceRunner("asv_pose", config) as runner:
        poses: Publisher[AsvPose] = runner.publisher(topics.ASV_POSE)
        runner.add_counters(
            lambda: {
                "scans_accepted": estimator.accepted,
                "global_searches": estimator.searches,
                "relocalisations": estimator.relocalisations,
                "imu_rejected": estimator.tilt.rejected,
                "imu_gaps": estimator.tilt.gaps,
                **{f"scans_rejected_{k}": v for k, v in estimator.rejected.items()},
            }
        )

        def on_imu(sample: ImuSample) -> None:
            with lock:
                estimator.on_imu(
                    sample.stamp_ns,
                    np.array(sample.angular_velocity_rad_s),
                    np.array(sample.linear_acceleration_m_s2),
                )
                est = estimator.estimate(sample.stamp_ns)
            poses.put(pose_payload(est, seq=poses.next_seq(), source=config.source))

        def on_scan(scan: LidarScan) -> None:
            ranges = np.array(scan.ranges_m, dtype=np.float64)
            angles = np.asarray(
                scan.angle_min_rad + scan.angle_increment_rad * np.arange(len(ranges)),
                dtype=np.float64,
            )
            with lock:
                estimator.on_scan(scan.stamp_ns, ranges, angles)

        def on_external(pose: AsvPose) -> None:
            rotation = quat_to_matrix(np.array(pose.orientation_xyzw))
            yaw = matrix_to_euler_zyx(rotation)[0]
            cov6 = np.array(pose.covariance).reshape(6, 6)
            cov3 = cov6[np.ix_([0, 1, 5], [0, 1, 5])]
            with lock:
                estimator.on_external(
                    pose.stamp_ns, pose.position_m[0], pose.position_m[1], yaw, cov3
                )

        runner.subscribe(topics.ASV_IMU, on_imu)
        if config.source == "scan_match":
            runner.subscribe(topics.ASV_SCAN, on_scan)
        else:
            runner.subscribe(topics.ASV_POSE_EXTERNAL, on_external)
        runner.run()
    return 0
