"""`capsd import-bag`: a ROS 1 or ROS 2 bag into a replayable CAP-SD recording (MCAP).

The paper's datasets are rosbags. A mapping file says which topics become which CAP-SD keys:

    site: tank
    topics:
      /scan:      {vehicle: asv, as: scan}           # sensor_msgs/LaserScan -> LidarScan
      /imu/data:  {vehicle: asv, as: imu}            # sensor_msgs/Imu       -> ImuSample
      /slam/odom: {vehicle: asv, as: external_pose}  # nav_msgs/Odometry or
                                                     # geometry_msgs/PoseWithCovarianceStamped

Messages are decoded with `rosbags` (either bag format, its own type definitions) and
converted with the ROS 2 input's code (services.asv_pose.ros_input), so a bag and a live
rmw_zenoh stream give the same payloads. Each becomes an MCAP message with the bag's receive
time as log time; `capsd replay` then puts them on the bus with their original timing.
A message that does not convert is counted and skipped; unmapped topics are listed.
"""

from __future__ import annotations

from collections import Counter
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
from capsd.topics import Topic
from services.asv_pose.ros_input import imu_payload, pose_payload, scan_payload

Kind = Literal["scan", "imu", "external_pose"]


class TopicMap(ConfigSection, frozen=True, kw_only=True):
    vehicle: Annotated[str, msgspec.Meta(pattern=r"^[a-z0-9_]{1,32}$")]
    as_: Kind = msgspec.field(name="as")


class Mapping(ConfigSection, frozen=True, kw_only=True):
    """The mapping file: the site and, per bag topic, what it becomes."""

    site: str = "tank"
    topics: dict[str, TopicMap]


_TOPIC: dict[Kind, Topic[Any]] = {
    "scan": topics.ASV_SCAN,
    "imu": topics.ASV_IMU,
    "external_pose": topics.ASV_POSE_EXTERNAL,
}


def _convert(kind: Kind, msg: Any, msgtype: str, seq: int) -> Payload:
    if kind == "scan":
        return scan_payload(msg, seq)
    if kind == "imu":
        return imu_payload(msg, seq)
    pose_type: Literal["odometry", "pose_with_covariance"] = (
        "odometry" if msgtype.endswith("Odometry") else "pose_with_covariance"
    )
    return pose_payload(msg, seq, pose_type=pose_type)


def import_bag(bag: Path, mapping_file: Path, out: Path) -> dict[str, Any]:
    """Convert `bag` by `mapping_file` into the MCAP `out`; returns counts."""
    from rosbags.highlevel import AnyReader

    mapping = load_config(mapping_file, Mapping)
    codecs: dict[Kind, Codec[Any]] = {k: Codec(t.payload) for k, t in _TOPIC.items()}
    written: Counter[str] = Counter()
    rejected: Counter[str] = Counter()
    try:
        reader = AnyReader([bag])
        reader.open()
    except Exception as exc:  # rosbags raises its own errors per format
        raise CapsdError(f"{bag}: not a readable ROS bag ({exc})") from exc
    recorder = McapRecorder(out)
    try:
        present = {c.topic for c in reader.connections}
        chosen = [c for c in reader.connections if c.topic in mapping.topics]
        missing = sorted(set(mapping.topics) - present)
        if not chosen:
            raise CapsdError(f"{bag}: none of the mapped topics is in the bag ({sorted(present)})")
        span = max(reader.duration, 1)
        bar = Progress(span / 1e9, label="importing bag", unit=" s")
        seqs: Counter[str] = Counter()
        for connection, timestamp, raw in reader.messages(connections=chosen):
            spec = mapping.topics[connection.topic]
            key = _TOPIC[spec.as_].key(mapping.site, spec.vehicle)
            try:
                msg = reader.deserialize(raw, connection.msgtype)
                payload = _convert(spec.as_, msg, connection.msgtype, seqs[key])
            except Exception as exc:  # a broken message: counted, the import goes on
                rejected[f"{connection.topic}: {type(exc).__name__}"] += 1
                continue
            codec = codecs[spec.as_]
            recorder.write(Sample(key, codec.encoding, codec.encode(payload), timestamp))
            seqs[key] += 1
            written[key] += 1
            bar.update((timestamp - reader.start_time) / 1e9)
        bar.close()
    finally:
        recorder.close()
        reader.close()
    return {
        "written": dict(written),
        "rejected": dict(rejected),
        "mapped_topics_missing": missing,
        "unmapped_topics": sorted(present - set(mapping.topics)),
    }
