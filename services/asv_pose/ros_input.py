"""ROS 2 sensors in: LaserScan, Imu and an external pose from rmw_zenoh, as CAP-SD payloads.

For ASVs that already run ROS 2 drivers (or a SLAM) over rmw_zenoh: this process subscribes to
their topics on the same Zenoh network, decodes the CDR payloads with `rosbags` (the ROS 2
message definitions of `distro`), and publishes the same LidarScan / ImuSample payloads the
simulator and the TiM client publish, and the external pose as an AsvPose on
`asv/pose_external` (for asv_pose's `source: external`). Stamps come from the messages'
headers. rmw_zenoh keys are `<domain_id>/<topic without leading slash>/<DDS type>/<type hash>`;
the hash is matched by a wildcard, so any ROS 2 distribution's publisher is heard.

Edge checks: a payload that does not decode, or decodes to nonsense (no ranges, a zero or NaN
angle increment, a non-finite pose), is counted and dropped with a rate-limited error; ranges
that are NaN, infinite or outside [range_min, range_max] become 0 (no return), as in LidarScan.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Callable
from typing import Annotated, Any, Literal

import msgspec
import numpy as np
import zenoh

from capsd import topics
from capsd.config import ServiceConfig
from capsd.keys import is_concrete
from capsd.payloads import AsvPose, ImuSample, LidarScan
from capsd.runner import ServiceRunner

logger = logging.getLogger(__name__)

Distro = Literal["humble", "jazzy"]
PoseType = Literal["odometry", "pose_with_covariance"]
ROS_TYPES = {
    "scan": "sensor_msgs/msg/LaserScan",
    "imu": "sensor_msgs/msg/Imu",
    "odometry": "nav_msgs/msg/Odometry",
    "pose_with_covariance": "geometry_msgs/msg/PoseWithCovarianceStamped",
}


class Config(ServiceConfig, frozen=True, kw_only=True):
    """ROS 2 input configuration."""

    vehicle: str = "asv"
    domain_id: Annotated[int, msgspec.Meta(ge=0, le=232)] = 0
    distro: Distro = "humble"
    scan_topic: str | None = "/scan"
    imu_topic: str | None = "/imu/data"
    pose_topic: str | None = None  # e.g. /slam/odom: an existing SLAM's pose
    pose_type: PoseType = "odometry"

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("scan_topic", "imu_topic", "pose_topic"):
            topic = getattr(self, name)
            if topic is not None and (not topic.strip("/") or any(c in topic for c in "*$?# ")):
                raise ValueError(f"field '{name}': {topic!r} is not a ROS 2 topic name")


def dds_type_name(ros_type: str) -> str:
    """'sensor_msgs/msg/Imu' -> 'sensor_msgs::msg::dds_::Imu_' (rmw_zenoh's key chunk)."""
    package, kind, name = ros_type.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def ros_key(domain_id: int, topic: str, ros_type: str, type_hash: str = "*") -> str:
    """The rmw_zenoh key expression of a topic (any type hash by default)."""
    return f"{domain_id}/{topic.strip('/')}/{dds_type_name(ros_type)}/{type_hash}"


def _stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


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
        stamp_ns=_stamp_ns(msg.header),
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
        stamp_ns=_stamp_ns(msg.header),
        seq=seq,
        angular_velocity_rad_s=values[:3],
        linear_acceleration_m_s2=values[3:],
    )


def pose_payload(msg: Any, seq: int, *, pose_type: PoseType) -> AsvPose:
    """nav_msgs/Odometry or geometry_msgs/PoseWithCovarianceStamped -> AsvPose (external)."""
    with_cov = msg.pose  # both carry a PoseWithCovariance at .pose
    p, q = with_cov.pose.position, with_cov.pose.orientation
    position = (float(p.x), float(p.y), float(p.z))
    quat = (float(q.x), float(q.y), float(q.z), float(q.w))
    cov = tuple(float(v) for v in np.asarray(with_cov.covariance, dtype=np.float64).ravel())
    if len(cov) != 36 or not _finite(*position, *quat, *cov):
        raise ValueError(f"{pose_type} pose or covariance not finite (or not 6 x 6)")
    norm = math.sqrt(sum(v * v for v in quat))
    if norm < 1e-6:
        raise ValueError(f"{pose_type} orientation is not a rotation (zero quaternion)")
    return AsvPose(
        stamp_ns=_stamp_ns(msg.header),
        seq=seq,
        position_m=position,
        orientation_xyzw=(quat[0] / norm, quat[1] / norm, quat[2] / norm, quat[3] / norm),
        covariance=cov,
        status="ok",
        source="external",
    )


def main(config: Config) -> int:
    """Bridge the configured ROS 2 topics until stopped."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE if config.distro == "humble" else Stores.ROS2_JAZZY)
    counts: Counter[str] = Counter()
    with ServiceRunner("ros_input", config) as runner:
        runner.add_counters(lambda: dict(counts))
        subscribers = []

        def bridge(
            topic_name: str,
            ros_type: str,
            convert: Callable[[Any, int], Any],
            publish: Callable[[Any], None],
            next_seq: Callable[[], int],
            what: str,
        ) -> None:
            key = ros_key(config.domain_id, topic_name, ros_type)

            def on_sample(sample: zenoh.Sample) -> None:
                key_expr = str(sample.key_expr)
                if not is_concrete(key_expr):
                    counts[f"{what}_wildcard_keys"] += 1
                    runner.report_error(f"ROS 2 {what} with a wildcard key '{key_expr}' dropped")
                    return
                try:
                    msg = store.deserialize_cdr(sample.payload.to_bytes(), ros_type)
                    payload = convert(msg, next_seq())
                except Exception as exc:  # rosbags raises many types for bad CDR
                    counts[f"{what}_rejected"] += 1
                    runner.report_error(f"ROS 2 {what} on '{key_expr}' dropped: {exc}")
                    return
                publish(payload)
                counts[what] += 1

            subscribers.append(runner.session.declare_subscriber(key, on_sample))
            logger.info("bridging ROS 2 topic", extra={"fields": {"key": key, "as": what}})

        if config.scan_topic is not None:
            out_scan = runner.publisher(topics.ASV_SCAN)
            bridge(
                config.scan_topic,
                ROS_TYPES["scan"],
                scan_payload,
                out_scan.put,
                out_scan.next_seq,
                "scans",
            )
        if config.imu_topic is not None:
            out_imu = runner.publisher(topics.ASV_IMU)
            bridge(
                config.imu_topic,
                ROS_TYPES["imu"],
                imu_payload,
                out_imu.put,
                out_imu.next_seq,
                "imu",
            )
        if config.pose_topic is not None:
            out_pose = runner.publisher(topics.ASV_POSE_EXTERNAL)

            def convert_pose(msg: Any, seq: int) -> AsvPose:
                return pose_payload(msg, seq, pose_type=config.pose_type)

            bridge(
                config.pose_topic,
                ROS_TYPES[config.pose_type],
                convert_pose,
                out_pose.put,
                out_pose.next_seq,
                "poses",
            )
        try:
            runner.run()
        finally:
            for sub in subscribers:
                sub.undeclare()
    return 0
