"""A ROS 2 bag (written with rosbags) imported into a CAP-SD recording and read back."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
from rosbags.rosbag2 import Writer
from rosbags.typesys import Stores, get_typestore

from capsd.payloads import ImuSample, LidarScan
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
