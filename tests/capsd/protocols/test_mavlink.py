"""The MAVLink adapter: what a non-blocking read returns from a stream it only partly knows."""

from __future__ import annotations

import socket
import time

from capsd.protocols.mavlink import Heartbeat, MavLink
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
