"""ROS 2 sensors in: LaserScan, Imu, an external pose and a reference pose from rmw_zenoh.

For ASVs that already run ROS 2 drivers (or a SLAM) over rmw_zenoh: this process subscribes to
their topics on the same Zenoh network, decodes the CDR payloads with `rosbags` (the ROS 2
message definitions of `distro`), and publishes the same LidarScan / ImuSample payloads the
simulator and the TiM client publish, and the external pose as an AsvPose on
`asv/pose_external` (for asv_pose's `source: external`). A motion-capture system's pose of a
vehicle (`reference_topic`) becomes a ReferencePose on `<reference_vehicle>/ref/pose`, which no
service reads: `capsd record` keeps it beside the fixes for `capsd evaluate`. Conversions are
capsd.ros_messages' (the same as `capsd import-bag`). Stamps come from the messages' headers.
rmw_zenoh keys are `<domain_id>/<topic without leading slash>/<DDS type>/<type hash>`;
the hash is matched by a wildcard, so any ROS 2 distribution's publisher is heard.

Edge checks: a payload that does not decode, or decodes to nonsense (no ranges, a zero or NaN
angle increment, a non-finite pose), is counted and dropped with a rate-limited error; ranges
that are NaN, infinite or outside [range_min, range_max] become 0 (no return), as in LidarScan.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable
from typing import Annotated, Any, Literal

import msgspec
import zenoh

from capsd import topics
from capsd.config import ServiceConfig
from capsd.errors import KeyExprError
from capsd.keys import check_name, is_concrete
from capsd.payloads import AsvPose, ReferencePose
from capsd.ros_messages import (
    IMU_TYPE,
    POSE_TYPES,
    SCAN_TYPE,
    PoseSigma,
    PoseType,
    asv_pose,
    imu_payload,
    reference_pose,
    scan_payload,
    stamped_poses,
)
from capsd.runner import ServiceRunner

logger = logging.getLogger(__name__)

Distro = Literal["humble", "jazzy"]
ROS_TYPES: dict[str, str] = {"scan": SCAN_TYPE, "imu": IMU_TYPE} | {
    kind: name for kind, name in POSE_TYPES.items()
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
    # For pose types without a covariance (pose_stamped, transform, tf): the pose's sigmas.
    pose_position_sigma_m: Annotated[float, msgspec.Meta(gt=0.0)] | None = None
    pose_angle_sigma_deg: Annotated[float, msgspec.Meta(gt=0.0)] | None = None
    # A reference system (motion capture) tracking a vehicle, recorded for `capsd evaluate`.
    reference_topic: str | None = None
    reference_type: PoseType = "pose_stamped"
    reference_vehicle: str = "rov"
    # For `transform` / `tf` types: the tracked body's frame (a /tf message carries many).
    child_frame: str | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("scan_topic", "imu_topic", "pose_topic", "reference_topic"):
            topic = getattr(self, name)
            if topic is not None and (not topic.strip("/") or any(c in topic for c in "*$?# ")):
                raise ValueError(f"field '{name}': {topic!r} is not a ROS 2 topic name")
        try:
            check_name("vehicle", self.reference_vehicle)
        except KeyExprError as exc:
            raise ValueError(f"field 'reference_vehicle': {exc}") from None
        if (self.pose_position_sigma_m is None) != (self.pose_angle_sigma_deg is None):
            raise ValueError(
                "fields 'pose_position_sigma_m' and 'pose_angle_sigma_deg' go together"
            )
        uses_frame = {self.reference_type} | ({self.pose_type} if self.pose_topic else set())
        if "tf" in uses_frame and self.child_frame is None:
            raise ValueError("field 'child_frame': a /tf pose needs the tracked body's frame")

    def pose_sigma(self) -> PoseSigma | None:
        return PoseSigma.from_degrees(self.pose_position_sigma_m, self.pose_angle_sigma_deg)


def dds_type_name(ros_type: str) -> str:
    """'sensor_msgs/msg/Imu' -> 'sensor_msgs::msg::dds_::Imu_' (rmw_zenoh's key chunk)."""
    package, kind, name = ros_type.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def ros_key(domain_id: int, topic: str, ros_type: str, type_hash: str = "*") -> str:
    """The rmw_zenoh key expression of a topic (any type hash by default)."""
    return f"{domain_id}/{topic.strip('/')}/{dds_type_name(ros_type)}/{type_hash}"


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
            convert: Callable[[Any, Callable[[], int]], list[Any]],
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
                    payloads = convert(msg, next_seq)
                except Exception as exc:  # rosbags raises many types for bad CDR
                    counts[f"{what}_rejected"] += 1
                    runner.report_error(f"ROS 2 {what} on '{key_expr}' dropped: {exc}")
                    return
                for payload in payloads:  # a /tf message may carry none of the tracked frame
                    publish(payload)
                    counts[what] += 1

            subscribers.append(runner.session.declare_subscriber(key, on_sample))
            logger.info("bridging ROS 2 topic", extra={"fields": {"key": key, "as": what}})

        if config.scan_topic is not None:
            out_scan = runner.publisher(topics.ASV_SCAN)
            bridge(
                config.scan_topic,
                ROS_TYPES["scan"],
                lambda msg, seq: [scan_payload(msg, seq())],
                out_scan.put,
                out_scan.next_seq,
                "scans",
            )
        if config.imu_topic is not None:
            out_imu = runner.publisher(topics.ASV_IMU)
            bridge(
                config.imu_topic,
                ROS_TYPES["imu"],
                lambda msg, seq: [imu_payload(msg, seq())],
                out_imu.put,
                out_imu.next_seq,
                "imu",
            )
        if config.pose_topic is not None:
            out_pose = runner.publisher(topics.ASV_POSE_EXTERNAL)
            sigma = config.pose_sigma()

            def convert_pose(msg: Any, seq: Callable[[], int]) -> list[AsvPose]:
                poses = stamped_poses(msg, config.pose_type, child_frame=config.child_frame)
                return [asv_pose(p, seq(), sigma=sigma) for p in poses]

            bridge(
                config.pose_topic,
                ROS_TYPES[config.pose_type],
                convert_pose,
                out_pose.put,
                out_pose.next_seq,
                "poses",
            )
        if config.reference_topic is not None:
            out_reference = runner.publisher(
                topics.REFERENCE_POSE, vehicle=config.reference_vehicle
            )

            def convert_reference(msg: Any, seq: Callable[[], int]) -> list[ReferencePose]:
                poses = stamped_poses(msg, config.reference_type, child_frame=config.child_frame)
                return [reference_pose(p, seq()) for p in poses]

            bridge(
                config.reference_topic,
                ROS_TYPES[config.reference_type],
                convert_reference,
                out_reference.put,
                out_reference.next_seq,
                "reference_poses",
            )
        try:
            runner.run()
        finally:
            for sub in subscribers:
                sub.undeclare()
    return 0
