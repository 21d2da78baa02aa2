"""The MAVLink adapter: what a non-blocking read returns from a stream it only partly knows."""

from __future__ import annotations

import math
import socket
import time

import pytest

from capsd.protocols.mavlink import GimbalAttitude, Heartbeat, MavLink
from tests.conftest import free_port


def _frames(count: int) -> bytes:
    """`count` SERVO_OUTPUT_RAW (a message the adapter does not convert), then a HEARTBEAT.

    Built with pymavlink here, in the test, as an autopilot's stream would carry them.
    """
    from pymavlink.dialects.v20 import ardupilotmega as mav

    link = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    link.robust_parsing = True
    frames = [link.servo_output_raw_encode(i, 0, *([1500] * 8)) for i in range(count)]
    frames.append(link.heartbeat_encode(12, 3, 0, 4, 4))
    return b"".join(bytes(frame.pack(link)) for frame in frames)


def test_a_non_blocking_read_passes_over_messages_it_does_not_know() -> None:
    """An autopilot streams many messages the bridge has no use for (SERVO_OUTPUT_RAW, ...).

    A read that gave up at the first of them left the rest for the next step, 10 ms on: in
    ArduSub SITL the bridge fell seconds behind its stream, took a 3 s old HEARTBEAT's mode
    for the vehicle's, and a mission ended on it. Read without waiting, the HEARTBEAT behind
    twenty unknown messages comes now.
    """
    port = free_port()
    with MavLink(f"udpin:127.0.0.1:{port}", system_id=1, component_id=197) as link:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as peer:
            peer.sendto(_frames(20), ("127.0.0.1", port))
            time.sleep(0.2)  # all of it in the socket's buffer
            received = link.recv(timeout_s=0.0)
        assert received is not None
        assert isinstance(received.message, Heartbeat)
        assert received.message.custom_mode == 4
        # Nothing left: a read without waiting returns at once.
        started = time.monotonic()
        assert link.recv(timeout_s=0.0) is None
        assert time.monotonic() - started < 0.5


@pytest.mark.parametrize(
    ("pitch_deg", "yaw_deg"),
    [(0.0, 0.0), (-55.0, 0.0), (-55.0, -70.0), (-80.0, 85.0), (10.0, 150.0)],
)
def test_a_mounts_pitch_and_yaw_in_the_vehicles_frame_come_back_as_sent(
    pitch_deg: float, yaw_deg: float
) -> None:
    """GIMBAL_DEVICE_ATTITUDE_STATUS's quaternion: the yaw, then the pitch (a pan-tilt mount)."""
    port = free_port()
    with (
        MavLink(f"udpin:127.0.0.1:{port}", system_id=1, component_id=197) as link,
        MavLink(f"udpout:127.0.0.1:{port}", system_id=1, component_id=1) as autopilot,
    ):
        autopilot.send_gimbal_attitude(
            time_boot_ms=1234,
            pitch_rad=math.radians(pitch_deg),
            horizon_relative=True,
            yaw_rad=math.radians(yaw_deg),
        )
        deadline = time.monotonic() + 5.0
        received = None
        while received is None and time.monotonic() < deadline:
            received = link.recv(timeout_s=0.2)
    assert received is not None
    message = received.message
    assert isinstance(message, GimbalAttitude)
    assert message.time_boot_ms == 1234
    assert message.horizon_relative
    assert math.degrees(message.pitch_rad) == pytest.approx(pitch_deg, abs=1e-4)
    assert message.yaw_rad is not None
    assert math.degrees(message.yaw_rad) == pytest.approx(yaw_deg, abs=1e-4)


def test_a_mounts_yaw_against_north_is_not_taken_for_the_hulls() -> None:
    """YAW_LOCK (earth frame): no yaw on the hull without the heading of that instant."""
    from pymavlink.dialects.v20 import ardupilotmega as mav

    sender = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    flags = mav.GIMBAL_DEVICE_FLAGS_PITCH_LOCK | mav.GIMBAL_DEVICE_FLAGS_YAW_LOCK
    nan = float("nan")
    frame = sender.gimbal_device_attitude_status_encode(
        0, 0, 99, flags, (1.0, 0.0, 0.0, 0.0), nan, nan, nan, 0
    )
    port = free_port()
    with (
        MavLink(f"udpin:127.0.0.1:{port}", system_id=1, component_id=197) as link,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as peer,
    ):
        peer.sendto(bytes(frame.pack(sender)), ("127.0.0.1", port))
        deadline = time.monotonic() + 5.0
        received = None
        while received is None and time.monotonic() < deadline:
            received = link.recv(timeout_s=0.2)
    assert received is not None
    assert isinstance(received.message, GimbalAttitude)
    assert received.message.yaw_rad is None
