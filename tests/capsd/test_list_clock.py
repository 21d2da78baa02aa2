"""`capsd list` estimates each service's clock offset from its Health reply and warns."""

from __future__ import annotations

import subprocess
import sys
import time

import pytest
import zenoh

from capsd.codec import Codec
from capsd.keys import alive_key, health_key
from capsd.payloads import Health
from tests.conftest import REPO, Proc

pytestmark = pytest.mark.integration


def _serve_health(client: zenoh.Session, vehicle: str, skew_ns: int) -> list[object]:
    """A stand-in service whose clock runs `skew_ns` ahead of ours."""
    codec = Codec(Health)
    key = health_key("tank", vehicle, "locator")

    def answer(query: zenoh.Query) -> None:
        health = Health(
            stamp_ns=time.time_ns() + skew_ns,
            seq=0,
            service="locator",
            state="ok",
            pid=1,
            host="test",
            software_version="0",
            uptime_s=1.0,
        )
        query.reply(key, codec.encode(health), encoding=zenoh.Encoding(codec.encoding))

    return [
        client.declare_queryable(key, answer),
        client.liveliness().declare_token(alive_key("tank", vehicle, "locator")),
    ]


def test_list_shows_clock_offsets_and_warns_on_skew(
    router: Proc, endpoint: str, client: zenoh.Session
) -> None:
    held = _serve_health(client, "rov", 500_000_000) + _serve_health(client, "asv", 0)
    time.sleep(0.5)
    proc = subprocess.run(
        [sys.executable, "-m", "capsd", "list", "--connect", endpoint, "--json"],
        capture_output=True,
        text=True,
        timeout=30,
        cwd=REPO,
    )
    import json

    rows = {r["vehicle"]: r for r in map(json.loads, proc.stdout.splitlines())}
    assert abs(rows["rov"]["clock_offset_ms"] - 500.0) < 50.0
    assert abs(rows["asv"]["clock_offset_ms"]) < 50.0
    text = subprocess.run(
        [sys.executable, "-m", "capsd", "list", "--connect", endpoint],
        capture_output=True,
        text=True,
        timeout=30,
        cwd=REPO,
    ).stdout
    assert "WARNING: clock offset above 20 ms" in text
    assert "rov/locator" in text
    assert "asv/locator" not in text.split("WARNING")[1]
    for entity in held:
        entity.undeclare()  # type: ignore[attr-defined]
