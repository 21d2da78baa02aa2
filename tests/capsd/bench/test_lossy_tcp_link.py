"""The lossy TCP proxy: every byte arrives, in order, late, with stalls behind lost segments."""

from __future__ import annotations

import socket
import threading
import time

from capsd.bench.lossy_tcp_link import LossyTcpLink
from capsd.harness import free_port


def test_proxy_delivers_in_order_late_and_stalls_behind_losses() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as server:
        server.bind(("127.0.0.1", 0))
        server.listen(1)
        received = bytearray()

        def echo() -> None:
            conn, _ = server.accept()
            with conn:
                conn.settimeout(3.0)
                while len(received) < 400:
                    chunk = conn.recv(4096)
                    if not chunk:
                        return
                    received.extend(chunk)
                    conn.sendall(chunk)

        thread = threading.Thread(target=echo, daemon=True)
        thread.start()
        port = free_port()
        with LossyTcpLink(
            listen_port=port,
            target_port=int(server.getsockname()[1]),
            delay_s=0.1,
            jitter_s=0.05,
            loss=0.2,
            rto_s=0.2,
            seed=3,
        ) as link:
            with socket.create_connection(("127.0.0.1", port), timeout=3.0) as client:
                client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                started = time.monotonic()
                for i in range(200):
                    client.sendall(i.to_bytes(2, "big"))
                    time.sleep(0.002)  # separate segments, so that each can be lost
                back = bytearray()
                first_back = None
                while len(back) < 400:
                    chunk = client.recv(4096)
                    assert chunk, "the proxy closed the connection"
                    if first_back is None:
                        first_back = time.monotonic() - started
                    back.extend(chunk)
            thread.join(timeout=3.0)
            counts = link.counts
    expected = b"".join(i.to_bytes(2, "big") for i in range(200))
    assert bytes(received) == expected  # nothing lost, nothing out of order
    assert bytes(back) == expected
    assert first_back is not None
    assert first_back >= 0.2  # 0.1 s each way
    assert counts.connections == 1
    assert counts.retransmissions > 0
    assert counts.held_up > 0  # segments behind a lost one waited for it
