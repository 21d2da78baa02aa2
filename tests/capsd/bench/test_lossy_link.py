"""The lossy UDP relay: delays, drops and reorders datagrams both ways, seeded."""

from __future__ import annotations

import socket
import time

from capsd.bench.lossy_link import LossyLink


def _udp() -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(0.5)
    return sock


def _port(sock: socket.socket) -> int:
    return int(sock.getsockname()[1])


def test_relay_delays_drops_and_reorders() -> None:
    with _udp() as server, _udp() as client:
        free = _udp()
        relay_port = _port(free)
        free.close()
        with LossyLink(
            listen_port=relay_port,
            target_port=_port(server),
            delay_s=0.1,
            jitter_s=0.05,
            loss=0.2,
            seed=3,
        ) as link:
            sent_at = time.monotonic()
            for i in range(200):
                client.sendto(i.to_bytes(2, "big"), ("127.0.0.1", relay_port))
            got: list[int] = []
            first_after = None
            try:
                while True:
                    data, addr = server.recvfrom(100)
                    if first_after is None:
                        first_after = time.monotonic() - sent_at
                    got.append(int.from_bytes(data, "big"))
                    server.sendto(data, addr)  # and back through the relay
            except TimeoutError:
                pass
            back = 0
            try:
                while True:
                    client.recvfrom(100)
                    back += 1
            except TimeoutError:
                pass
        assert first_after is not None
        assert first_after >= 0.1
        assert 120 < len(got) < 190  # about 20 % lost
        assert got != sorted(got)  # the jitter put some out of order
        assert 0 < back < len(got)  # the way back loses some too
        assert link.counts.dropped == 200 - len(got) + len(got) - back
        assert link.counts.reordered > 0
