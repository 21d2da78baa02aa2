"""The autopilot stand-in: listening when entered, and a clear error when it cannot listen."""

from __future__ import annotations

import socket

import pytest

from capsd.errors import CapsdError
from capsd.simulator.autopilot import AutopilotStandIn
from tests.conftest import free_port


def test_listens_on_every_port_when_entered() -> None:
    # A client (the bridge, a ground station) may connect the moment the stand-in is up.
    port, gcs_port = free_port(), free_port()
    with AutopilotStandIn(port, gcs_port=gcs_port):
        for p in (port, gcs_port):
            with socket.create_connection(("127.0.0.1", p), timeout=2.0):
                pass


def test_a_port_it_cannot_listen_on_is_named() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(CapsdError, match=f"could not listen on 127.0.0.1:{port}"):  # noqa: SIM117
            with AutopilotStandIn(port):
                pass
