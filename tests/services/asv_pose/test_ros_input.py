"""ROS 2 input: CDR LaserScan / Imu / Odometry into the pose service, a mocap pose as reference."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh
from rosbags.typesys import Stores, get_typestore

from capsd import topics
from capsd.codec import Codec
from capsd.geometry import Transform, euler_zyx_to_matrix, matrix_to_euler_zyx, quat_to_matrix
from capsd.health import query_health
from capsd.keys import is_concrete
from capsd.payloads import AsvPose, Health, LidarScan, ReferencePose
from capsd.ros_messages import scan_payload
from capsd.services.asv_pose.ros_input import ROS_TYPES, ros_key
from capsd.simulator.lidar import LidarModel, scan
from capsd.simulator.world import make_tank
from tests.conftest import Proc, wait_for

STORE = get_typestore(Stores.ROS2_HUMBLE)
T = STORE.types
HASH = "RIHS01_" + "ab" * 32  # any hash: the input subscribes with a wildcard


def _header(stamp_ns: int) -> Any:
    stamp = T["builtin_interfaces/msg/Time"](
        sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000
    )
    return T["std_msgs/msg/Header"](stamp=stamp, frame_id="laser")


def _laser_scan(stamp_ns: int, ranges: np.ndarray, *, increment: float = 0.01) -> Any:
    return T[ROS_TYPES["scan"]](
        header=_header(stamp_ns),
        angle_min=-math.pi,
        angle_max=-math.pi + increment * (len(ranges) - 1),
        angle_increment=increment,
        time_increment=0.0,
        scan_time=1 / 15,
        range_min=0.05,
        range_max=25.0,
        ranges=ranges.astype(np.float32),
        intensities=np.zeros(0, dtype=np.float32),
    )


def _vector(x: float, y: float, z: float) -> Any:
    return T["geometry_msgs/msg/Vector3"](x=x, y=y, z=z)


def _imu(stamp_ns: int) -> Any:
    quat = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
    return T[ROS_TYPES["imu"]](
        header=_header(stamp_ns),
        orientation=quat,
        orientation_covariance=np.full(9, -1.0),
        angular_velocity=_vector(0.0, 0.0, 0.0),
        angular_velocity_covariance=np.zeros(9),
        linear_acceleration=_vector(0.0, 0.0, 9.81),
        linear_acceleration_covariance=np.zeros(9),
    )


def _odometry(stamp_ns: int, x: float, y: float, yaw: float) -> Any:
    point = T["geometry_msgs/msg/Point"](x=x, y=y, z=0.0)
    quat = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))
    pose = T["geometry_msgs/msg/Pose"](position=point, orientation=quat)
    cov = np.diag([1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4]).ravel()
    twist = T["geometry_msgs/msg/Twist"](linear=_vector(0, 0, 0), angular=_vector(0, 0, 0))
    return T[ROS_TYPES["odometry"]](
        header=_header(stamp_ns),
        child_frame_id="base_link",
        pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov),
        twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)),
    )


def _cdr(msg: Any, ros_type: str) -> bytes:
    return bytes(STORE.serialize_cdr(msg, ros_type))


def test_scan_conversion_drops_invalid_ranges_and_orders_angles() -> None:
    ranges = np.array([1.0, np.nan, np.inf, 0.01, 30.0, 2.0])
    out = scan_payload(
        STORE.deserialize_cdr(_cdr(_laser_scan(5, ranges), ROS_TYPES["scan"]), ROS_TYPES["scan"]), 0
    )
    assert out.ranges_m == (1.0, 0.0, 0.0, 0.0, 0.0, 2.0)
    assert out.stamp_ns == 5
    clockwise = _laser_scan(5, ranges, increment=-0.01)
    out = scan_payload(clockwise, 0)
    assert out.angle_increment_rad == pytest.approx(0.01)
    assert out.ranges_m[0] == 2.0
    with pytest.raises(ValueError, match="without ranges"):
        scan_payload(_laser_scan(5, np.zeros(0)), 0)


def test_rmw_zenoh_key_layout() -> None:
    key = ros_key(3, "/asv/scan", ROS_TYPES["scan"], HASH)
    assert key == f"3/asv/scan/sensor_msgs::msg::dds_::LaserScan_/{HASH}"


class _Collect:
    def __init__(self, client: zenoh.Session, key: str, payload: type[Any]):
        self.codec = Codec(payload)
        self.got: list[Any] = []
        self.lock = threading.Lock()
        self.sub = client.declare_subscriber(key, self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        if is_concrete(str(sample.key_expr)):
            value = self.codec.decode(
                sample.payload.to_bytes(),
                encoding=str(sample.encoding),
                key_expr=str(sample.key_expr),
            )
            with self.lock:
                self.got.append(value)


def _feed(
    client: zenoh.Session,
    *,
    seconds: float,
    pose: tuple[float, float, float],
    scans: bool,
    odometry: bool,
) -> None:
    """Publish like ROS 2 drivers through rmw_zenoh: IMU at 100 Hz, scans/odometry at 10 Hz."""
    tank = make_tank("nfp")
    model = LidarModel()
    x, y, yaw = pose
    scanner = Transform(euler_zyx_to_matrix(yaw, 0.0, 0.0), np.array([x, y, 0.4]))
    rng = np.random.default_rng(0)
    imu_key = ros_key(0, "/imu/data", ROS_TYPES["imu"], HASH)
    scan_key = ros_key(0, "/scan", ROS_TYPES["scan"], HASH)
    odom_key = ros_key(0, "/slam/odom", ROS_TYPES["odometry"], HASH)
    start = time.time_ns()
    for k in range(int(seconds * 100)):
        stamp = start + k * 10_000_000
        client.put(imu_key, _cdr(_imu(stamp), ROS_TYPES["imu"]))
        if k % 10 == 0:
            if scans:
                ranges = scan(model, scanner, tank, rng)
                msg = T[ROS_TYPES["scan"]](
                    header=_header(stamp),
                    angle_min=float(model.angles()[0]),
                    angle_max=float(model.angles()[-1]),
                    angle_increment=float(model.angles()[1] - model.angles()[0]),
                    time_increment=0.0,
                    scan_time=0.1,
                    range_min=0.05,
                    range_max=float(model.range_max_m),
                    ranges=np.where(ranges > 0, ranges, np.inf).astype(np.float32),
                    intensities=np.zeros(0, dtype=np.float32),
                )
                client.put(scan_key, _cdr(msg, ROS_TYPES["scan"]))
                client.put(scan_key, b"\x00\x01\x00\x00garbage")  # a broken sample, counted
            if odometry:
                client.put(odom_key, _cdr(_odometry(stamp, x, y, yaw), ROS_TYPES["odometry"]))
        time.sleep(0.01)


@pytest.mark.integration
def test_cdr_scans_and_imu_feed_the_pose_service(
    spawn: Callable[..., Proc], router: Proc, endpoint: str, client: zenoh.Session, tmp_path: Path
) -> None:
    poses = _Collect(client, topics.ASV_POSE.key("tank", "asv"), AsvPose)
    scans = _Collect(client, topics.ASV_SCAN.key("tank", "asv"), LidarScan)
    spawn("run", "ros_input", "--config", "deploy/config/ros_input.yaml", "--connect", endpoint)
    pose_config = tmp_path / "asv_pose.yaml"
    pose_config.write_text("heading_prior_deg: 20.0\n")
    spawn("run", "asv_pose", "--config", str(pose_config), "--connect", endpoint)
    time.sleep(2.0)  # both joined
    truth = (12.0, 7.0, math.radians(35.0))
    _feed(client, seconds=4.0, pose=truth, scans=True, odometry=False)
    wait_for(lambda: any(p.status == "ok" for p in poses.got), timeout_s=10, what="an ok pose")
    assert scans.got
    ok = [p for p in poses.got if p.status == "ok"]
    last = ok[-1]
    assert last.source == "scan_match"
    assert math.hypot(last.position_m[0] - truth[0], last.position_m[1] - truth[1]) < 0.05
    yaw = matrix_to_euler_zyx(quat_to_matrix(np.array(last.orientation_xyzw)))[0]
    assert abs(math.remainder(yaw - truth[2], 2 * math.pi)) < math.radians(1.0)
    health = query_health(client, site="tank", vehicle="asv", service="ros_input", timeout_s=2)
    assert health is not None
    assert health.counters["scans_rejected"] >= 1  # the garbage samples
    assert health.counters["imu"] >= 100


@pytest.mark.integration
def test_external_slam_pose_replaces_the_scan_matcher(
    spawn: Callable[..., Proc], router: Proc, endpoint: str, client: zenoh.Session, tmp_path: Path
) -> None:
    poses = _Collect(client, topics.ASV_POSE.key("tank", "asv"), AsvPose)
    ros_config = tmp_path / "ros.yaml"
    ros_config.write_text("scan_topic: null\npose_topic: /slam/odom\npose_type: odometry\n")
    spawn("run", "ros_input", "--config", str(ros_config), "--connect", endpoint)
    pose_config = tmp_path / "asv_pose.yaml"
    pose_config.write_text("source: external\n")
    spawn("run", "asv_pose", "--config", str(pose_config), "--connect", endpoint)
    time.sleep(2.0)
    truth = (5.0, 3.0, math.radians(-60.0))
    _feed(client, seconds=2.0, pose=truth, scans=False, odometry=True)
    wait_for(lambda: any(p.status == "ok" for p in poses.got), timeout_s=10, what="an ok pose")
    last = [p for p in poses.got if p.status == "ok"][-1]
    assert last.source == "external"
    assert math.hypot(last.position_m[0] - truth[0], last.position_m[1] - truth[1]) < 0.01


def _pose_stamped(stamp_ns: int, x: float) -> Any:
    point = T["geometry_msgs/msg/Point"](x=x, y=1.0, z=-1.5)
    quat = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
    return T[ROS_TYPES["pose_stamped"]](
        header=_header(stamp_ns), pose=T["geometry_msgs/msg/Pose"](position=point, orientation=quat)
    )


@pytest.mark.integration
def test_a_mocap_pose_becomes_a_reference_no_service_reads(
    spawn: Callable[..., Proc], router: Proc, endpoint: str, client: zenoh.Session, tmp_path: Path
) -> None:
    references = _Collect(client, topics.REFERENCE_POSE.key("tank", "rov"), ReferencePose)
    ros_config = tmp_path / "ros.yaml"
    ros_config.write_text(
        "scan_topic: null\nimu_topic: null\nreference_topic: /mocap/rov/pose\n"
        "reference_type: pose_stamped\nreference_vehicle: rov\n"
    )
    spawn("run", "ros_input", "--config", str(ros_config), "--connect", endpoint)
    time.sleep(2.0)
    key = ros_key(0, "/mocap/rov/pose", ROS_TYPES["pose_stamped"], HASH)
    start = time.time_ns()
    for k in range(20):
        client.put(
            key, _cdr(_pose_stamped(start + k * 10_000_000, 0.1 * k), ROS_TYPES["pose_stamped"])
        )
        time.sleep(0.01)
    client.put(key, b"\x00\x01\x00\x00garbage")
    wait_for(lambda: len(references.got) >= 20, timeout_s=10, what="20 reference poses")
    got = sorted(references.got, key=lambda p: p.stamp_ns)
    assert got[5].position_m == pytest.approx((0.5, 1.0, -1.5))
    assert got[5].stamp_ns == start + 50_000_000
    assert got[5].frame_id == "laser"  # the header's frame, as sent

    def health_now() -> Health | None:
        return query_health(client, site="tank", vehicle="asv", service="ros_input", timeout_s=2)

    # The garbage goes out after the 20 poses that were waited for: its rejection may come
    # after them (a CI run queried Health first and found no such counter yet).
    wait_for(
        lambda: (h := health_now()) is not None and "reference_poses_rejected" in h.counters,
        timeout_s=10,
        what="the garbage payload counted",
    )
    health = health_now()
    assert health is not None
    assert health.counters["reference_poses"] == 20
    assert health.counters["reference_poses_rejected"] == 1
