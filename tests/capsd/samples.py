"""One valid instance of every payload type, for round-trip tests."""

from __future__ import annotations

import math

from capsd.payloads import (
    AsvPose,
    AutopilotStatus,
    Detection,
    FoxgloveTime,
    GhostEcho,
    GroundTruth,
    Health,
    ImuSample,
    LidarScan,
    Log,
    Payload,
    ReferencePose,
    RovAttitude,
    RovDepth,
    RovFix,
    RovVelocity,
    SimControl,
    SonarDetections,
    SonarFrame,
    SonarLabel,
    SonarTilt,
    StreamStats,
    VehicleCommand,
)

_IDENTITY = (0.0, 0.0, 0.0, 1.0)
_COV6 = tuple(float(i == j) * 1e-4 for i in range(6) for j in range(6))
_COV3 = tuple(float(i == j) * 1e-3 for i in range(3) for j in range(3))
STAMP = 1_795_000_000_123_456_789

SAMPLES: tuple[Payload, ...] = (
    Health(
        stamp_ns=STAMP, seq=3, service="locator", state="ok", pid=42, host="asv",
        software_version="0.1.0", uptime_s=12.5,
        inputs=(StreamStats(key="cap/t/asv/asv/pose", count=10, rate_hz=50.0,
                            last_stamp_ns=STAMP),),
        outputs=(StreamStats(key="cap/t/topside/locator/fix", count=2, rate_hz=10.0),),
        decode_errors=1, dropped=0, last_error="bad payload", last_error_stamp_ns=STAMP,
        counters={"sent": 10, "stale": 1},
    ),
    Log(
        stamp_ns=STAMP, seq=0, timestamp=FoxgloveTime(sec=STAMP // 10**9, nsec=STAMP % 10**9),
        level=2, message="service started", name="locator", file="runner.py", line=10,
    ),
    AsvPose(stamp_ns=STAMP, seq=1, position_m=(1.0, 2.0, 0.01), orientation_xyzw=_IDENTITY,
            covariance=_COV6),
    ImuSample(stamp_ns=STAMP, seq=1, angular_velocity_rad_s=(0.01, -0.02, 0.0),
              linear_acceleration_m_s2=(0.1, 0.0, 9.81)),
    LidarScan(stamp_ns=STAMP, seq=1, angle_min_rad=-math.radians(135), angle_increment_rad=0.0058,
              range_min_m=0.05, range_max_m=25.0, ranges_m=(1.0, 0.0, 2.5)),
    SonarFrame(stamp_ns=STAMP, seq=7, ping_id=7, n_ranges=4, n_beams=4, sample_bits=8,
               image=memoryview(bytes(range(16))), azimuths_rad=(-0.2, -0.05, 0.05, 0.2),
               range_start_m=0.0, range_resolution_m=0.0025, sound_speed_m_s=1480.0,
               gain_percent=50.0, frequency_hz=1.2e6, vertical_aperture_rad=math.radians(20)),
    SonarDetections(stamp_ns=STAMP, seq=7, ping_id=7, detector="cnn", detections=(
        Detection(range_m=5.2, azimuth_rad=0.1, range_sigma_m=0.02, azimuth_sigma_rad=0.003,
                  confidence=0.9, range_extent_m=0.4, azimuth_extent_rad=0.08),)),
    SonarTilt(stamp_ns=STAMP, seq=3, tilt_rad=0.17, pan_rad=-0.4),
    RovDepth(stamp_ns=STAMP, seq=1, depth_m=3.2, pressure_pa=132_000.0, temperature_c=18.5),
    RovAttitude(stamp_ns=STAMP, seq=1, orientation_xyzw=(0.0, 0.0, math.sin(0.25), math.cos(0.25))),
    RovVelocity(stamp_ns=STAMP, seq=1, velocity_m_s=(0.2, 0.0, -0.05), covariance_m2_s2=_COV3),
    AutopilotStatus(stamp_ns=STAMP, seq=1, armed=True, mode="POSHOLD", ekf_flags=0x3FF),
    RovFix(stamp_ns=STAMP, seq=1, method="capsd", quality="good", raw_position_m=(3.0, 4.0, -2.0),
           raw_covariance_m2=_COV3, conditioning=0.5, track_state="tracking",
           position_m=(3.0, 4.0, -2.0), velocity_m_s=(0.1, 0.0, 0.0), covariance_m2=_COV3,
           asv_pose_stamp_ns=STAMP, depth_stamp_ns=STAMP, attitude_stamp_ns=STAMP),
    SonarLabel(stamp_ns=STAMP, seq=7, ping_id=7, visible=True, range_m=5.2, azimuth_rad=0.1,
               elevation_rad=0.05, range_min_m=5.0, range_max_m=5.4, azimuth_min_rad=0.05,
               azimuth_max_rad=0.15, overlap=False,
               ghosts=(GhostEcho(range_m=7.5, azimuth_rad=0.1),), rov_position_m=(3.0, 4.0, -2.0)),
    GroundTruth(stamp_ns=STAMP, seq=1, asv_position_m=(1.0, 1.0, 0.0),
                asv_orientation_xyzw=_IDENTITY,
                rov_position_m=(3.0, 4.0, -2.0), rov_orientation_xyzw=_IDENTITY),
    SimControl(stamp_ns=STAMP, seq=1, mute=("asv/scan@asv",), for_s=5.0),
    ReferencePose(stamp_ns=STAMP, seq=3, position_m=(0.5, -0.1, -1.1), frame_id="mocap"),
    VehicleCommand(stamp_ns=STAMP, seq=2, mission="nfp-lawnmower", kind="goto", waypoint=3,
                   position_m=(12.0, 6.0, -3.5), heading_rad=0.5, reason="repeat",
                   leg_end_m=(16.0, 6.0, -3.5)),
)  # fmt: skip
