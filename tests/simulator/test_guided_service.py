"""The simulator process hosting the ArduSub stand-in: a GUIDED target over MAVLink flies the ROV.

A real `capsd run sim` with `guided`, a real router, and a MAVLink client in the test playing
the bridge: estimates (so the position modes are allowed), MAV_CMD_DO_SET_MODE and
SET_POSITION_TARGET_LOCAL_NED in NED. The simulator's truth on the bus shows the ROV go there.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import zenoh

from capsd import topics
from capsd.codec import Codec
from capsd.ned import TankToNed
from capsd.payloads import GroundTruth
from capsd.protocols.mavlink import Heartbeat, MavLink, ScaledPressure, message_id, mode_name
from tests.conftest import Proc, free_port, wait_for

pytestmark = pytest.mark.integration

START = (12.0, 8.0, -3.0)
TARGET = (13.5, 7.0, -3.5)
NED = TankToNed(math.radians(40.0), np.array([2.0, -1.0, 0.0]))


def test_a_guided_target_flies_the_simulated_rov(
    spawn: Callable[..., Proc], client: zenoh.Session, endpoint: str, tmp_path: Path
) -> None:
    port = free_port()
    config = tmp_path / "sim.yaml"
    config.write_text(
        f"bus:\n  connect: [{endpoint}]\ntank: nfp\nasv_mode: stationary\n"
        "water_temperature_c: 27.5\n"
        "streams: {sonar_frames: 'off', lidar: 'off', imu: 'off'}\n"
        f"guided:\n  port: {port}\n  ned_heading_deg: 40.0\n  ned_origin_m: [2.0, -1.0, 0.0]\n"
        f"  start_m: {list(START)}\n  max_speed_m_s: 0.5\n"
    )
    sim = spawn("run", "sim", "--config", str(config))
    truths: list[GroundTruth] = []
    codec = Codec(GroundTruth)

    def on_truth(sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        truths.append(codec.decode(sample.payload.to_bytes(), encoding=None, key_expr=key))

    truth_sub = client.declare_subscriber(topics.SIM_TRUTH.key("tank", "sim"), on_truth)
    try:
        _fly(port, truths)
    finally:
        truth_sub.undeclare()
    assert sim.popen.poll() is None


def _fly(port: int, truths: list[GroundTruth]) -> None:
    """Play the bridge over MAVLink: estimates, GUIDED and a target, then POSHOLD."""
    wait_for(lambda: truths, timeout_s=30, what="the simulator's truth")
    assert truths[-1].rov_position_m == pytest.approx(START, abs=0.01)

    link = MavLink(f"tcp:127.0.0.1:{port}", system_id=1, component_id=197)
    modes: list[str] = []
    temperatures: list[float] = []
    with link:  # the stand-in listens before the simulator publishes anything

        def estimate() -> None:
            # Our estimate is the truth here: the vehicle steers on it.
            north, east, down = NED.position(np.array(truths[-1].rov_position_m))
            link.send_vision_position_estimate(
                usec=time.time_ns() // 1000, x=float(north), y=float(east), z=float(down),
                roll=0.0, pitch=0.0, yaw=0.0, covariance=(0.01,) * 21, reset_counter=0,
            )  # fmt: skip

        def drain() -> None:
            while (received := link.recv(timeout_s=0.0)) is not None:
                if isinstance(received.message, Heartbeat):
                    modes.append(mode_name(received.message.custom_mode))
                elif isinstance(received.message, ScaledPressure):
                    temperatures.append(received.message.temperature_c)

        for _ in range(5):
            estimate()
            time.sleep(0.05)
        link.send_set_message_interval(
            target_system=1, message_id=message_id("SCALED_PRESSURE2"), rate_hz=5.0
        )
        link.send_set_mode(target_system=1, mode="GUIDED")
        north, east, down = NED.position(np.array(TARGET))
        link.send_position_target(
            target_system=1, time_boot_ms=0, ned_m=(float(north), float(east), float(down))
        )

        def arrived() -> bool:
            estimate()
            drain()
            return bool(np.allclose(truths[-1].rov_position_m, TARGET, atol=0.05))

        wait_for(arrived, timeout_s=30, what="the ROV at the GUIDED target")
        assert "GUIDED" in modes  # the stand-in reports the mode it took
        # Its Bar30 reads the simulated water's temperature (the locator rescales ranges by it).
        assert temperatures
        assert set(temperatures) == {27.5}
        # POSHOLD: it stops where it is.
        link.send_set_mode(target_system=1, mode="POSHOLD")
        time.sleep(2.0)
        held = np.array(truths[-1].rov_position_m)
        assert held == pytest.approx(TARGET, abs=0.08)
