"""ROS messages (as `rosbags` decodes them) into CAP-SD payloads: one conversion for bags and live.

`capsd import-bag` and the ROS 2 input (rmw_zenoh) both call these, so a bag and a live stream
give the same payloads. Pose messages of every common kind (PoseStamped,
PoseWithCovarianceStamped, TransformStamped, a /tf message for one child frame, Odometry)
become a `StampedPose` first, then an AsvPose (an input: it must carry an orientation and a
covariance, or be given sigmas) or a ReferencePose (for evaluation: a position suffices).
A message that does not convert raises ValueError saying why.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from capsd.payloads import AsvPose, ImuSample, LidarScan, ReferencePose

PoseType = Literal["pose_stamped", "pose_with_covariance", "transform", "tf", "odometry"]
POSE_TYPES: dict[PoseType, str] = {
    "pose_stamped": "geometry_msgs/msg/PoseStamped",
    "pose_with_covariance": "geometry_msgs/msg/PoseWithCovarianceStamped",
    "transform": "geometry_msgs/msg/TransformStamped",
    "tf": "tf2_msgs/msg/TFMessage",
    "odometry": "nav_msgs/msg/Odometry",
}
SCAN_TYPE = "sensor_msgs/msg/LaserScan"
IMU_TYPE = "sensor_msgs/msg/Imu"
_QUAT_ZERO = 1e-6


def pose_type_of(msgtype: str) -> PoseType | None:
    """The pose kind of a ROS message type name (ROS 1 or ROS 2 spelling), None if not a pose."""
    normal = msgtype if "/msg/" in msgtype else msgtype.replace("/", "/msg/", 1)
    for kind, name in POSE_TYPES.items():
        if name == normal:
            return kind
    return None


@dataclass(frozen=True)
class StampedPose:
    """A pose as a ROS message states it: header stamp and frame, position, maybe more."""

    stamp_ns: int
    frame_id: str
    position_m: tuple[float, float, float]
    orientation_xyzw: tuple[float, float, float, float] | None  # None: zero quaternion
    covariance: tuple[float, ...] | None  # 6 x 6 (x y z roll pitch yaw), None if not carried


@dataclass(frozen=True)
class PoseSigma:
    """Standard deviations for a pose message without a covariance (an input needs one)."""

    position_m: float
    angle_rad: float

    @classmethod
    def from_degrees(cls, position_m: float | None, angle_deg: float | None) -> PoseSigma | None:
        """From a config's two optional fields (None unless both are given)."""
        if position_m is None or angle_deg is None:
            return None
        return cls(position_m, math.radians(angle_deg))

    def covariance(self) -> tuple[float, ...]:
        diagonal = [self.position_m**2] * 3 + [self.angle_rad**2] * 3
        return tuple(float(v) for v in np.diag(diagonal).ravel())


def stamp_ns(header: Any) -> int:
    """A header's stamp in Unix ns (ROS 2 `nanosec`, ROS 1 `nsec`: rosbags gives the former)."""
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def _stamped(
    header: Any, position: Any, orientation: Any, covariance: Any | None, what: str
) -> StampedPose:
    xyz = (float(position.x), float(position.y), float(position.z))
    quat = (float(orientation.x), float(orientation.y), float(orientation.z), float(orientation.w))
    if not _finite(*xyz, *quat):
        raise ValueError(f"{what}: position or orientation not finite")
    norm = math.sqrt(sum(v * v for v in quat))
    unit = None if norm < _QUAT_ZERO else (quat[0] / norm, quat[1] / norm, quat[2] / norm,
                                           quat[3] / norm)  # fmt: skip
    cov: tuple[float, ...] | None = None
    if covariance is not None:
        cov = tuple(float(v) for v in np.asarray(covariance, dtype=np.float64).ravel())
        if len(cov) != 36 or not _finite(*cov):
            raise ValueError(f"{what}: covariance not finite or not 6 x 6")
    return StampedPose(stamp_ns(header), str(header.frame_id), xyz, unit, cov)


def stamped_poses(msg: Any, kind: PoseType, *, child_frame: str | None = None) -> list[StampedPose]:
    """The poses a message carries (a /tf message: those of `child_frame`, maybe none)."""
    if kind == "pose_stamped":
        return [_stamped(msg.header, msg.pose.position, msg.pose.orientation, None, kind)]
    if kind in ("pose_with_covariance", "odometry"):
        pose = msg.pose.pose
        return [_stamped(msg.header, pose.position, pose.orientation, msg.pose.covariance, kind)]
    transforms = [msg] if kind == "transform" else list(msg.transforms)
    out = []
    for t in transforms:
        if child_frame is not None and str(t.child_frame_id).strip("/") != child_frame.strip("/"):
            continue
        out.append(_stamped(t.header, t.transform.translation, t.transform.rotation, None, kind))
    return out


def asv_pose(pose: StampedPose, seq: int, *, sigma: PoseSigma | None = None) -> AsvPose:
    """An input pose (asv_pose's `source: external`): orientation and a covariance required."""
    if pose.orientation_xyzw is None:
        raise ValueError("orientation is not a rotation (zero quaternion): not usable as a pose")
    covariance = pose.covariance
    if covariance is None:
        if sigma is None:
            raise ValueError(
                "the message carries no covariance: give the pose's sigmas in the mapping "
                "(position_sigma_m, angle_sigma_deg)"
            )
        covariance = sigma.covariance()
    return AsvPose(
        stamp_ns=pose.stamp_ns,
        seq=seq,
        position_m=pose.position_m,
        orientation_xyzw=pose.orientation_xyzw,
        covariance=covariance,
        status="ok",
        source="external",
    )


def reference_pose(pose: StampedPose, seq: int) -> ReferencePose:
    """A reference system's pose (what fixes are scored against): a position suffices."""
    return ReferencePose(
        stamp_ns=pose.stamp_ns,
        seq=seq,
        position_m=pose.position_m,
        orientation_xyzw=pose.orientation_xyzw,
        frame_id=pose.frame_id,
    )


def scan_payload(msg: Any, seq: int) -> LidarScan:
    """sensor_msgs/LaserScan -> LidarScan (ranges outside the valid band become 0)."""
    ranges = np.asarray(msg.ranges, dtype=np.float64)
    if ranges.size == 0:
        raise ValueError("LaserScan without ranges")
    increment = float(msg.angle_increment)
    start = float(msg.angle_min)
    if not _finite(increment, start) or increment == 0.0:
        raise ValueError(f"LaserScan angle_increment {increment} / angle_min {start} unusable")
    r_min, r_max = float(msg.range_min), float(msg.range_max)
    if not _finite(r_min, r_max) or r_max <= 0.0:
        raise ValueError(f"LaserScan range_max {r_max} unusable")
    valid = np.isfinite(ranges) & (ranges >= r_min) & (ranges <= r_max)
    ranges = np.where(valid, ranges, 0.0)
    intensities = np.asarray(msg.intensities, dtype=np.float64)
    if intensities.size != ranges.size or not np.all(np.isfinite(intensities)):
        intensities = np.zeros(0)
    if increment < 0.0:  # a scanner that turns clockwise: same rays, increasing angle
        start = start + increment * (ranges.size - 1)
        increment = -increment
        ranges = ranges[::-1]
        intensities = intensities[::-1]
    return LidarScan(
        stamp_ns=stamp_ns(msg.header),
        seq=seq,
        angle_min_rad=start,
        angle_increment_rad=increment,
        time_increment_s=max(0.0, float(msg.time_increment)),
        range_min_m=max(0.0, r_min),
        range_max_m=r_max,
        ranges_m=tuple(float(r) for r in ranges),
        intensities=tuple(float(v) for v in intensities),
    )


def imu_payload(msg: Any, seq: int) -> ImuSample:
    """sensor_msgs/Imu -> ImuSample (orientation, if any, is not used: our tilt filter runs)."""
    w, a = msg.angular_velocity, msg.linear_acceleration
    values = (float(w.x), float(w.y), float(w.z), float(a.x), float(a.y), float(a.z))
    if not _finite(*values):
        raise ValueError("Imu with non-finite rates or accelerations")
    return ImuSample(
        stamp_ns=stamp_ns(msg.header),
        seq=seq,
        angular_velocity_rad_s=values[:3],
        linear_acceleration_m_s2=values[3:],
    )
