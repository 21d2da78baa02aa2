"""Joining Zenoh: a BusConfig becomes a zenoh.Config, and a session opened with retries."""

from __future__ import annotations

import json
import logging
import socket
import threading
from pathlib import Path

import zenoh

from capsd.config import BusConfig
from capsd.errors import BusError, ConfigError

logger = logging.getLogger(__name__)


def zenoh_config(bus: BusConfig) -> zenoh.Config:
    """The zenoh.Config for `bus`: explicit endpoints, scouting off unless asked, fast retry."""
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(bus.mode))
    conf.insert_json5("connect/endpoints", json.dumps(list(bus.connect)))
    conf.insert_json5("listen/endpoints", json.dumps(list(bus.listen)))
    conf.insert_json5("scouting/multicast/enabled", json.dumps(bus.multicast_scouting == "on"))
    conf.insert_json5("connect/timeout_ms", json.dumps(int(bus.connect_timeout_s * 1000)))
    # connect/retry is null by default: the whole object must be inserted (FIELD-NOTES).
    retry = {
        "period_init_ms": 100,
        "period_max_ms": int(bus.reconnect_max_s * 1000),
        "period_increase_factor": 2,
    }
    conf.insert_json5("connect/retry", json.dumps(retry))
    conf.insert_json5("transport/link/rx/max_message_size", json.dumps(bus.max_message_bytes))
    if bus.tls is not None:
        tls = {
            "root_ca_certificate": bus.tls.ca_certificate,
            "enable_mtls": True,
            "listen_certificate": bus.tls.certificate,
            "listen_private_key": bus.tls.private_key,
            "connect_certificate": bus.tls.certificate,
            "connect_private_key": bus.tls.private_key,
            "verify_name_on_connect": bus.tls.verify_name == "on",
        }
        conf.insert_json5("transport/link/tls", json.dumps(tls))
    if bus.access_control_file is not None:
        path = Path(bus.access_control_file)
        try:
            conf.insert_json5("access_control", path.read_text())
        except (OSError, zenoh.ZError) as exc:
            raise ConfigError(str(path), "access_control", str(exc)) from None
    return conf


def open_session(bus: BusConfig, *, stop: threading.Event | None = None) -> zenoh.Session:
    """Open a session, retrying while the router is unreachable until `stop` is set.

    Without `stop`, one attempt is made and BusError raised on failure (for CLI tools).
    """
    attempt = 0
    while True:
        attempt += 1
        try:
            return zenoh.open(zenoh_config(bus))
        except zenoh.ZError as exc:
            if stop is None:
                raise BusError(f"cannot join Zenoh via {list(bus.connect)}: {exc}") from None
            if bus.listen and _listen_taken(bus.listen):
                # Retrying cannot help: another process holds the port (a second router).
                raise BusError(
                    f"cannot listen on {list(bus.listen)}: the address is in use (another "
                    f"router?): {exc}"
                ) from None
            if attempt == 1 or attempt % 10 == 0:
                logger.warning(
                    "waiting for Zenoh router",
                    extra={
                        "fields": {
                            "connect": ",".join(bus.connect),
                            "attempt": attempt,
                            "error": str(exc),
                        }
                    },
                )
        if stop.wait(0.1):
            raise BusError("stopped while waiting for the Zenoh router")


def _listen_taken(endpoints: tuple[str, ...]) -> bool:
    """Whether a tcp/udp listen endpoint's port is already bound by someone else."""
    for endpoint in endpoints:
        proto, _, address = endpoint.partition("/")
        host, _, port = address.rpartition(":")
        if proto not in ("tcp", "tls", "udp") or not port.isdigit():
            continue
        kind = socket.SOCK_DGRAM if proto == "udp" else socket.SOCK_STREAM
        with socket.socket(socket.AF_INET, kind) as probe:
            try:
                probe.bind((host.strip("[]") or "0.0.0.0", int(port)))
            except OSError:
                return True
    return False
