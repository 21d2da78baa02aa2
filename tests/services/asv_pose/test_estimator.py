"""The pose estimator on simulated IMU and LiDAR against the simulator's truth."""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
import pytest

from capsd.bench.asv_pose import rms_errors
from capsd.geometry import Transform, euler_zyx_to_matrix, matrix_to_euler_zyx
from capsd.services.asv_pose.estimator import AsvPoseEstimator, EstimatorSettings
from capsd.services.asv_pose.scan_match import tank_walls
from capsd.simulator.lidar import LidarModel, scan
from capsd.simulator.world import TankName, make_tank

SECOND = 1_000_000_000


def _rms_errors(
    tank: TankName, mode: Literal["follow", "stationary"], seconds: float
) -> tuple[float, float, float, float, str]:
    r = rms_errors(tank, mode, seconds)
    return (
        float(r["position_mm"]) / 1000,
        float(r["yaw_deg"]),
        float(r["roll_deg"]),
        float(r["pitch_deg"]),
        str(r["status"]),
    )


@pytest.mark.parametrize("mode", ["stationary", "follow"])
@pytest.mark.parametrize("tank", ["nfp", "mockup"])
def test_meets_the_pose_targets(tank: TankName, mode: Literal["follow", "stationary"]) -> None:
    # Issue 9's targets: position <= 20 mm, yaw <= 0.3 deg, roll/pitch <= 0.2 deg, also while
    # the ASV manoeuvres (following the ROV).
    pos, yaw, roll, pitch, status = _rms_errors(tank, mode, 30.0)
    assert status == "ok"
    assert pos < 0.020
    assert yaw < 0.3
    assert roll < 0.2
    assert pitch < 0.2


def _turning_yaw_errors(scan_late_s: float) -> np.ndarray:
    """Heading errors (deg) of an ASV turning on the spot at 15 deg/s, over the last 3 s of 6.

    The follower's turn rate, in the nfp tank. Each scan reaches the estimator `scan_late_s`
    after its stamp (IMU samples up to then first); negative: before the IMU samples up to it.
    """
    tank = make_tank("nfp", clutter="off")
    model = LidarModel()
    rng = np.random.default_rng(1)
    rate = math.radians(15.0)
    position = np.array([14.0, 8.0, 0.0])
    estimator = AsvPoseEstimator(
        tank_walls(tank.length_m, tank.width_m),
        heading_prior_rad=0.0,
        settings=EstimatorSettings(lidar_position_m=(0.0, 0.0, 0.0)),
    )
    imu = [(k * 5_000_000, "imu") for k in range(1200)]  # 200 Hz, 6 s
    scans = [(k * 66_666_667, "scan") for k in range(90)]  # 15 Hz
    # Delivery order: each input at when it reaches the estimator.
    arrivals = sorted(
        [(t, 0, t, kind) for t, kind in imu]
        + [(t + int(scan_late_s * 1e9), 1, t, kind) for t, kind in scans]
    )
    errors = []
    for _, _, stamp, kind in arrivals:
        yaw = rate * stamp / 1e9
        if kind == "imu":
            estimator.on_imu(stamp, np.array([0.0, 0.0, rate]), np.array([0.0, 0.0, 9.81]))
            if stamp > 3 * SECOND:
                est = matrix_to_euler_zyx(estimator.estimate(stamp).rotation)[0]
                errors.append(math.degrees(math.atan2(math.sin(est - yaw), math.cos(est - yaw))))
        else:
            pose = Transform(euler_zyx_to_matrix(yaw, 0.0, 0.0), position)
            estimator.on_scan(stamp, scan(model, pose, tank, rng), model.angles())
    return np.array(errors)


@pytest.mark.parametrize("scan_late_s", [0.04, -0.04, 0.0])
def test_a_turning_asv_keeps_its_heading_whichever_stream_arrives_first(
    scan_late_s: float,
) -> None:
    # The match's heading holds at the scan's stamp: the gyro's turn since (or until) then
    # is kept. Taking it as the newest IMU sample's heading was 0.6 deg off here (40 ms at
    # 15 deg/s: 6 cm at a ROV 6 m off).
    errors = _turning_yaw_errors(scan_late_s)
    assert np.sqrt(np.mean(errors**2)) < 0.1
