"""Every payload type crosses a real router on 127.0.0.1 and decodes equal."""

from __future__ import annotations

import queue
import time
from functools import partial

import pytest
import zenoh

from capsd.bus import open_session
from capsd.codec import Codec
from capsd.config import BusConfig
from capsd.payloads import Payload
from tests.capsd.samples import SAMPLES
from tests.conftest import wait_for

pytestmark = pytest.mark.integration


@pytest.mark.usefixtures("router")
def test_every_payload_crosses_the_bus(client: zenoh.Session, endpoint: str) -> None:
    received: queue.Queue[tuple[str, str, bytes]] = queue.Queue()
    with open_session(BusConfig(connect=(endpoint,))) as publisher_session:
        sub = client.declare_subscriber(
            "test/roundtrip/**",
            lambda s: received.put((str(s.key_expr), str(s.encoding), s.payload.to_bytes())),
        )
        for payload in SAMPLES:
            codec: Codec[Payload] = Codec(type(payload))
            key = f"test/roundtrip/{codec.schema}"
            publisher = publisher_session.declare_publisher(
                key, encoding=zenoh.Encoding(codec.encoding)
            )
            # A put before the subscriber's route reaches this session would go nowhere.
            wait_for(partial(_matched, publisher), timeout_s=10, what="a matching route")
            got_key, encoding, data = _deliver(publisher, codec.encode(payload), received, key)
            assert got_key == key
            assert encoding == codec.encoding
            assert codec.decode(data, encoding=encoding, key_expr=got_key) == payload
            publisher.undeclare()
        sub.undeclare()


def _matched(publisher: zenoh.Publisher) -> bool:
    return publisher.matching_status


def _deliver(
    publisher: zenoh.Publisher, data: bytes, received: queue.Queue[tuple[str, str, bytes]], key: str
) -> tuple[str, str, bytes]:
    """Put until the sample arrives (a fresh route can lose the first put), at most 10 s."""
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:
        publisher.put(data)
        try:
            while True:
                got = received.get(timeout=0.5)
                if got[0] == key:
                    return got
        except queue.Empty:
            continue
    raise AssertionError(f"nothing arrived on {key} in 10 s")
