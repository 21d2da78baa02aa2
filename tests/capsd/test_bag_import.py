"""ROS 1 and ROS 2 bags (written with rosbags) imported into CAP-SD recordings and read back."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import pytest
from rosbags.rosbag2 import Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from capsd.payloads import AsvPose, ImuSample, LidarScan, ReferencePose
from capsd.recording import channel_counts, read
from tests.conftest import REPO

STORE = get_typestore(Stores.ROS2_HUMBLE)
T = STORE.types


def _header(ns: int) -> Any:
    stamp = T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
    return T["std_msgs/msg/Header"](stamp=stamp, frame_id="x")


def _write_bag(path: Path) -> None:
    vec = T["geometry_msgs/msg/Vector3"]
    with Writer(path, version=9) as writer:
        scan_c = writer.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=STORE)
        imu_c = writer.add_connection("/imu/data", "sensor_msgs/msg/Imu", typestore=STORE)
        other = writer.add_connection("/camera/info", "std_msgs/msg/String", typestore=STORE)
        for k in range(10):
            t = 1_700_000_000_000_000_000 + k * 100_000_000
            scan = T["sensor_msgs/msg/LaserScan"](
                header=_header(t),
                angle_min=-1.0,
                angle_max=1.0,
                angle_increment=0.5,
                time_increment=0.0,
                scan_time=0.1,
                range_min=0.1,
                range_max=20.0,
                ranges=np.array([1.0, 2.0, np.nan, 4.0, 5.0], dtype=np.float32),
                intensities=np.zeros(0, dtype=np.float32),
            )
            writer.write(scan_c, t, bytes(STORE.serialize_cdr(scan, "sensor_msgs/msg/LaserScan")))
            imu = T["sensor_msgs/msg/Imu"](
                header=_header(t),
                orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                orientation_covariance=np.zeros(9),
                angular_velocity=vec(x=0.0, y=0.0, z=0.1),
                angular_velocity_covariance=np.zeros(9),
                linear_acceleration=vec(x=0.0, y=0.0, z=9.81),
                linear_acceleration_covariance=np.zeros(9),
            )
            writer.write(imu_c, t + 1, bytes(STORE.serialize_cdr(imu, "sensor_msgs/msg/Imu")))
            text = T["std_msgs/msg/String"](data="ignored")
            writer.write(other, t + 2, bytes(STORE.serialize_cdr(text, "std_msgs/msg/String")))
        writer.write(scan_c, t + 3, b"\x00\x01\x00\x00broken")  # counted, skipped


def test_import_bag_then_read_the_recording(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    _write_bag(bag)
    out = tmp_path / "run.mcap"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "capsd",
            "import-bag",
            str(bag),
            "--mapping",
            str(REPO / "deploy" / "bag_mapping.yaml"),
            "-o",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=REPO,
    )
    assert proc.returncode == 0, proc.stderr
    assert "rejected 1 messages of /scan" in proc.stderr
    assert "mapped but not in the bag: ['/odom']" in proc.stderr
    counts = channel_counts(out)
    assert counts == {"cap/tank/asv/asv/scan": 10, "cap/tank/asv/asv/imu": 10}
    records = list(read(out))
    scans = [msgspec.json.decode(r.data, type=LidarScan) for r in records if r.key.endswith("scan")]
    imus = [msgspec.json.decode(r.data, type=ImuSample) for r in records if r.key.endswith("imu")]
    assert scans[0].ranges_m == (1.0, 2.0, 0.0, 4.0, 5.0)  # NaN: no return
    assert scans[3].stamp_ns == 1_700_000_000_300_000_000  # the header's stamp
    assert imus[0].angular_velocity_rad_s == (0.0, 0.0, 0.1)
    assert [r.log_time_ns for r in records] == sorted(r.log_time_ns for r in records)


def test_import_bag_names_a_bad_bag(tmp_path: Path) -> None:
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "capsd",
            "import-bag",
            str(tmp_path / "nothing"),
            "--mapping",
            str(REPO / "deploy" / "bag_mapping.yaml"),
            "-o",
            str(tmp_path / "x.mcap"),
        ],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=REPO,
    )
    assert proc.returncode == 2
    assert "not a readable ROS bag" in proc.stderr


ROS1 = get_typestore(Stores.ROS1_NOETIC)
# Noetic's store lacks tf2_msgs; a recorded bag carries its definition, as this one will.
ROS1.register(
    get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage")
)
R1 = ROS1.types
START_NS = 1_689_094_943_000_000_000


def _r1_header(ns: int, frame: str = "mocap") -> Any:
    stamp = R1["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
    return R1["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame)


def _pose(x: float, *, w: float) -> Any:
    return R1["geometry_msgs/msg/Pose"](
        position=R1["geometry_msgs/msg/Point"](x=x, y=-0.1, z=-1.1),
        orientation=R1["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=w),
    )


def _transform(ns: int, child: str, x: float) -> Any:
    return R1["geometry_msgs/msg/TransformStamped"](
        header=_r1_header(ns),
        child_frame_id=child,
        transform=R1["geometry_msgs/msg/Transform"](
            translation=R1["geometry_msgs/msg/Vector3"](x=x, y=0.0, z=-1.0),
            rotation=R1["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        ),
    )


def _write_ros1_bag(path: Path) -> None:
    """The pose messages people record, as a ROS 1 bag (the paper's authors' format)."""
    from rosbags.rosbag1 import Writer as Ros1Writer

    kinds = {
        "/cap": "geometry_msgs/msg/PoseStamped",
        "/amcl_pose": "geometry_msgs/msg/PoseWithCovarianceStamped",
        "/vicon/rov": "geometry_msgs/msg/TransformStamped",
        "/tf": "tf2_msgs/msg/TFMessage",
        "/odom": "nav_msgs/msg/Odometry",
    }
    with Ros1Writer(path) as writer:
        conns = {t: writer.add_connection(t, m, typestore=ROS1) for t, m in kinds.items()}
        for k in range(20):
            t = START_NS + k * 10_000_000
            msgs = {
                # The authors' bag: a position with an all-zero quaternion.
                "/cap": R1[kinds["/cap"]](header=_r1_header(t), pose=_pose(0.01 * k, w=0.0)),
                "/amcl_pose": R1[kinds["/amcl_pose"]](
                    header=_r1_header(t),
                    pose=R1["geometry_msgs/msg/PoseWithCovariance"](
                        pose=_pose(1.0, w=1.0), covariance=np.eye(6).ravel() * 1e-4
                    ),
                ),
                "/vicon/rov": _transform(t, "rov", 2.0),
                "/tf": R1[kinds["/tf"]](
                    transforms=[_transform(t, "asv", 5.0), _transform(t, "rov", 3.0 + k)]
                ),
                "/odom": R1[kinds["/odom"]](
                    header=_r1_header(t),
                    child_frame_id="base_link",
                    pose=R1["geometry_msgs/msg/PoseWithCovariance"](
                        pose=_pose(4.0, w=1.0), covariance=np.eye(6).ravel() * 1e-4
                    ),
                    twist=R1["geometry_msgs/msg/TwistWithCovariance"](
                        twist=R1["geometry_msgs/msg/Twist"](
                            linear=R1["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                            angular=R1["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                        ),
                        covariance=np.zeros(36),
                    ),
                ),
            }
            for topic, msg in msgs.items():
                writer.write(conns[topic], t + 5, ROS1.serialize_ros1(msg, kinds[topic]))


def _import(bag: Path, mapping: str, tmp_path: Path) -> subprocess.CompletedProcess[str]:
    mapping_file = tmp_path / "mapping.yaml"
    mapping_file.write_text(mapping)
    return subprocess.run(
        [sys.executable, "-m", "capsd", "import-bag", str(bag), "--mapping", str(mapping_file),
         "-o", str(tmp_path / "out.mcap")],
        capture_output=True, text=True, timeout=60, cwd=REPO,
    )  # fmt: skip


def test_pose_messages_as_references_and_inputs(tmp_path: Path) -> None:
    bag = tmp_path / "poses.bag"
    _write_ros1_bag(bag)
    proc = _import(
        bag,
        "topics:\n"
        "  /cap: {vehicle: rov, as: reference}\n"
        "  /vicon/rov: {vehicle: vicon, as: reference}\n"
        "  /tf: {vehicle: tfrov, as: reference, child_frame: rov}\n"
        "  /amcl_pose: {vehicle: asv, as: external_pose}\n"
        "  /odom: {vehicle: odo, as: external_pose}\n",
        tmp_path,
    )
    assert proc.returncode == 0, proc.stderr
    assert channel_counts(tmp_path / "out.mcap") == {
        "cap/tank/rov/ref/pose": 20,
        "cap/tank/vicon/ref/pose": 20,
        "cap/tank/tfrov/ref/pose": 20,  # only the child frame asked for
        "cap/tank/asv/asv/pose_external": 20,
        "cap/tank/odo/asv/pose_external": 20,
    }
    records = list(read(tmp_path / "out.mcap"))
    refs = [msgspec.json.decode(r.data, type=ReferencePose) for r in records
            if r.key == "cap/tank/rov/ref/pose"]  # fmt: skip
    assert refs[3].position_m == (0.03, -0.1, -1.1)
    assert refs[3].orientation_xyzw is None  # the zero quaternion: a position only
    assert refs[3].stamp_ns == START_NS + 30_000_000  # the header's stamp
    assert refs[3].frame_id == "mocap"
    tf = [msgspec.json.decode(r.data, type=ReferencePose) for r in records
          if r.key == "cap/tank/tfrov/ref/pose"]  # fmt: skip
    assert [p.position_m[0] for p in tf[:3]] == [3.0, 4.0, 5.0]
    ext = [msgspec.json.decode(r.data, type=AsvPose) for r in records
           if r.key == "cap/tank/asv/asv/pose_external"]  # fmt: skip
    assert ext[0].covariance[0] == pytest.approx(1e-4)


def test_a_pose_without_orientation_is_no_input_and_the_reason_is_said(tmp_path: Path) -> None:
    bag = tmp_path / "poses.bag"
    _write_ros1_bag(bag)
    proc = _import(bag, "topics:\n  /cap: {vehicle: asv, as: external_pose}\n", tmp_path)
    assert proc.returncode == 2
    assert "rejected 20 messages of /cap: ValueError: orientation is not a rotation" in proc.stderr
    assert "mapped topics gave no message: ['/cap']" in proc.stderr
    # Without covariance, an input needs sigmas; with them it imports.
    proc = _import(bag, "topics:\n  /vicon/rov: {vehicle: asv, as: external_pose}\n", tmp_path)
    assert proc.returncode == 2
    assert "carries no covariance" in proc.stderr
    proc = _import(
        bag,
        "topics:\n  /vicon/rov: {vehicle: asv, as: external_pose, position_sigma_m: 0.01, "
        "angle_sigma_deg: 0.5}\n",
        tmp_path,
    )
    assert proc.returncode == 0, proc.stderr


def test_a_wrong_message_type_fails_before_writing(tmp_path: Path) -> None:
    bag = tmp_path / "poses.bag"
    _write_ros1_bag(bag)
    proc = _import(bag, "topics:\n  /cap: {vehicle: asv, as: scan}\n", tmp_path)
    assert proc.returncode == 2
    assert "/cap is geometry_msgs/msg/PoseStamped, which `as: scan` cannot take" in proc.stderr
    assert not (tmp_path / "out.mcap").exists()
    proc = _import(bag, "topics:\n  /tf: {vehicle: rov, as: reference}\n", tmp_path)
    assert proc.returncode == 2
    assert "needs `child_frame`" in proc.stderr
