"""`capsd import-bag`: a ROS 1 or ROS 2 bag into a replayable CAP-SD recording (MCAP).

The paper's datasets are rosbags. A mapping file says which topics become which CAP-SD keys:

    site: tank
    topics:
      /scan:      {vehicle: asv, as: scan}           # sensor_msgs/LaserScan -> LidarScan
      /imu/data:  {vehicle: asv, as: imu}            # sensor_msgs/Imu       -> ImuSample
      /slam/odom: {vehicle: asv, as: external_pose}  # a pose message        -> AsvPose
      /mocap/rov: {vehicle: rov, as: reference}      # a pose message        -> ReferencePose

Pose messages: PoseStamped, PoseWithCovarianceStamped, TransformStamped, /tf (TFMessage, with
`child_frame`) and Odometry. An `external_pose` is an input and needs an orientation and a
covariance (or `position_sigma_m` and `angle_sigma_deg` in the mapping); a `reference` (motion
capture, what `capsd evaluate` scores fixes against; no service reads it) needs a position only.

Messages are decoded with `rosbags` (either bag format, its own type definitions) and converted
with capsd.ros_messages (the ROS 2 input's conversions), so a bag and a live rmw_zenoh stream
give the same payloads. Each becomes an MCAP message with the bag's receive time as log time;
`capsd replay` then puts them on the bus with their original timing. A topic whose message type
its kind cannot take fails the import before anything is written; a message that does not
convert is counted with its reason and skipped; a mapped topic that yields nothing fails it.
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, Literal

import msgspec

from capsd import topics
from capsd.codec import Codec
from capsd.config import ConfigSection, load_config
from capsd.errors import CapsdError
from capsd.payloads import Payload
from capsd.progress import Progress
from capsd.recording import McapRecorder, Sample
from capsd.ros_messages import (
    IMU_TYPE,
    POSE_TYPES,
    SCAN_TYPE,
    PoseSigma,
    asv_pose,
    imu_payload,
    pose_type_of,
    reference_pose,
    scan_payload,
    stamped_poses,
)
from capsd.topics import Topic

Kind = Literal["scan", "imu", "external_pose", "reference"]
StampSource = Literal["header", "receive"]
PositiveFloat = Annotated[float, msgspec.Meta(gt=0.0)]


class TopicMap(ConfigSection, frozen=True, kw_only=True):
    vehicle: Annotated[str, msgspec.Meta(pattern=r"^[a-z0-9_]{1,32}$")]
    as_: Kind = msgspec.field(name="as")
    # header: the message's own stamp (the sensor's clock); receive: the bag's receive time,
    # for publishers that leave the header empty.
    stamp: StampSource = "header"
    child_frame: str | None = None  # the tracked body, for TransformStamped and /tf
    position_sigma_m: PositiveFloat | None = None  # an external pose without a covariance
    angle_sigma_deg: PositiveFloat | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if (self.position_sigma_m is None) != (self.angle_sigma_deg is None):
            raise ValueError("fields 'position_sigma_m' and 'angle_sigma_deg' go together")

    def sigma(self) -> PoseSigma | None:
        return PoseSigma.from_degrees(self.position_sigma_m, self.angle_sigma_deg)


class Mapping(ConfigSection, frozen=True, kw_only=True):
    """The mapping file: the site and, per bag topic, what it becomes."""

    site: str = "tank"
    topics: dict[str, TopicMap]


_TOPIC: dict[Kind, Topic[Any]] = {
    "scan": topics.ASV_SCAN,
    "imu": topics.ASV_IMU,
    "external_pose": topics.ASV_POSE_EXTERNAL,
    "reference": topics.REFERENCE_POSE,
}
_POSE_NAMES = ", ".join(name.split("/")[-1] for name in POSE_TYPES.values())
_ACCEPTS: dict[Kind, str] = {
    "scan": "sensor_msgs/LaserScan",
    "imu": "sensor_msgs/Imu",
    "external_pose": _POSE_NAMES,
    "reference": _POSE_NAMES,
}


def _check_type(topic: str, spec: TopicMap, msgtype: str) -> None:
    """Fail before any message is read when a topic's type is not one its kind takes."""
    kind = spec.as_
    if kind in ("scan", "imu"):
        ok = msgtype == (SCAN_TYPE if kind == "scan" else IMU_TYPE)
    else:
        pose = pose_type_of(msgtype)
        ok = pose is not None
        if pose == "tf" and spec.child_frame is None:
            raise CapsdError(
                f"{topic} ({msgtype}) mapped as {kind}: a /tf topic needs `child_frame`, "
                "the tracked body's frame"
            )
    if not ok:
        raise CapsdError(
            f"{topic} is {msgtype}, which `as: {kind}` cannot take (it takes {_ACCEPTS[kind]})"
        )


def _convert(
    spec: TopicMap, msg: Any, msgtype: str, receive_ns: int, next_seq: Callable[[], int]
) -> list[Payload]:
    if spec.as_ == "scan":
        return [scan_payload(msg, next_seq())]
    if spec.as_ == "imu":
        return [imu_payload(msg, next_seq())]
    kind = pose_type_of(msgtype)
    assert kind is not None  # _check_type let only pose types through
    poses = stamped_poses(msg, kind, child_frame=spec.child_frame)
    out: list[Payload] = []
    for pose in poses:
        if spec.stamp == "receive":
            pose = dataclasses.replace(pose, stamp_ns=receive_ns)
        elif pose.stamp_ns == 0:
            raise ValueError("header stamp is zero: map the topic with `stamp: receive`")
        if spec.as_ == "reference":
            out.append(reference_pose(pose, next_seq()))
        else:
            out.append(asv_pose(pose, next_seq(), sigma=spec.sigma()))
    return out


def _reason(exc: Exception) -> str:
    text = str(exc).splitlines()[0][:160] if str(exc) else ""
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def import_bag(bag: Path, mapping_file: Path, out: Path) -> dict[str, Any]:
    """Convert `bag` by `mapping_file` into the MCAP `out`; returns counts.

    Raises CapsdError (nothing written) when the bag is unreadable, no mapped topic is in it, or
    a topic's type is not one its kind takes. `empty_topics` in the result names mapped topics
    present in the bag that gave no message (the caller fails on them).
    """
    from rosbags.highlevel import AnyReader

    mapping = load_config(mapping_file, Mapping)
    codecs: dict[Kind, Codec[Any]] = {k: Codec(t.payload) for k, t in _TOPIC.items()}
    written: Counter[str] = Counter()
    per_topic: Counter[str] = Counter()
    rejected: Counter[str] = Counter()
    try:
        reader = AnyReader([bag])
        reader.open()
    except Exception as exc:  # rosbags raises its own errors per format
        raise CapsdError(f"{bag}: not a readable ROS bag ({exc})") from exc
    try:
        present = {c.topic for c in reader.connections}
        chosen = [c for c in reader.connections if c.topic in mapping.topics]
        missing = sorted(set(mapping.topics) - present)
        if not chosen:
            raise CapsdError(f"{bag}: none of the mapped topics is in the bag ({sorted(present)})")
        for connection in chosen:
            _check_type(connection.topic, mapping.topics[connection.topic], connection.msgtype)
        recorder = McapRecorder(out)
        try:
            span = max(reader.duration, 1)
            bar = Progress(span / 1e9, label="importing bag", unit=" s")
            seqs: Counter[str] = Counter()
            for connection, timestamp, raw in reader.messages(connections=chosen):
                spec = mapping.topics[connection.topic]
                key = _TOPIC[spec.as_].key(mapping.site, spec.vehicle)

                def next_seq(key: str = key) -> int:
                    seqs[key] += 1
                    return seqs[key] - 1

                try:
                    msg = reader.deserialize(raw, connection.msgtype)
                    payloads = _convert(spec, msg, connection.msgtype, timestamp, next_seq)
                except Exception as exc:  # a broken message: counted with why, the import goes on
                    rejected[f"{connection.topic}: {_reason(exc)}"] += 1
                    continue
                codec = codecs[spec.as_]
                for payload in payloads:
                    recorder.write(Sample(key, codec.encoding, codec.encode(payload), timestamp))
                    written[key] += 1
                    per_topic[connection.topic] += 1
                bar.update((timestamp - reader.start_time) / 1e9)
            bar.close()
        finally:
            recorder.close()
    finally:
        reader.close()
    return {
        "written": dict(written),
        "rejected": dict(rejected),
        "mapped_topics_missing": missing,
        "empty_topics": sorted({c.topic for c in chosen} - set(per_topic)),
        "unmapped_topics": sorted(present - set(mapping.topics)),
    }
