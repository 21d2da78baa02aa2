"""A degraded TCP link on loopback: a proxy that gives a stream the timing of a lossy path.

Deploy links between Zenoh routers are TCP: on a path that delays, drops and reorders
packets, TCP still delivers every byte in order, and the loss shows up as stalls. This proxy
reproduces that without `tc netem`: each segment read from one side (at most
`segment_bytes`) is written to the other after `delay_s` plus a uniform jitter of up to
`jitter_s`, plus one retransmission timeout `rto_s` per time it was lost (probability
`loss` each try), and never before the segment ahead of it (in-order delivery: a lost
segment holds up everything behind it, as TCP's head-of-line blocking does). Seeded.
"""

from __future__ import annotations

import heapq
import random
import select
import socket
import time
from dataclasses import dataclass

from capsd.bench.relay_thread import RelayThread


@dataclass
class TcpLinkCounts:
    connections: int = 0
    segments: int = 0
    retransmissions: int = 0  # segments lost at least once, delivered after a timeout
    held_up: int = 0  # segments that waited for a lost one ahead of them


@dataclass
class _Direction:
    """One way of a proxied connection, keyed by the socket it reads from."""

    sink: socket.socket
    last_due: float = 0.0
    reading: bool = True  # False once the source closed: its FIN is queued behind its data


class LossyTcpLink(RelayThread):
    """`with LossyTcpLink(listen_port=..., target_port=...):` proxies until the block ends."""

    def __init__(
        self,
        *,
        listen_port: int,
        target_port: int,
        delay_s: float = 0.2,
        jitter_s: float = 0.04,
        loss: float = 0.1,
        rto_s: float = 0.2,  # Linux's minimum retransmission timeout
        segment_bytes: int = 1448,
        seed: int = 0,
    ):
        super().__init__("lossy-tcp-link")
        self.delay_s, self.jitter_s, self.loss, self.rto_s = delay_s, jitter_s, loss, rto_s
        self.segment_bytes = segment_bytes
        self.counts = TcpLinkCounts()
        self._rng = random.Random(seed)
        self._target = ("127.0.0.1", target_port)
        self._listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._listener.bind(("127.0.0.1", listen_port))
        self._listener.listen(8)
        self._directions: dict[socket.socket, _Direction] = {}
        self._queue: list[tuple[float, int, socket.socket, bytes]] = []
        self._seq = 0

    def _sockets(self) -> list[socket.socket]:
        return [*self._directions, self._listener]

    def summary(self) -> str:
        c = self.counts
        return (
            f"{c.connections} connection(s), {c.segments} segments, {c.retransmissions} "
            f"retransmitted after {self.rto_s:g} s, {c.held_up} held up behind a loss"
        )

    def _accept(self) -> None:
        outer, _ = self._listener.accept()
        try:
            inner = socket.create_connection(self._target, timeout=1.0)
        except OSError:
            outer.close()  # the far end is not there: the connection fails, as on a link
            return
        for sock in (outer, inner):
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            sock.settimeout(2.0)  # a peer that stops reading for 2 s is cut, never waited on
        self._directions[outer] = _Direction(inner)
        self._directions[inner] = _Direction(outer)
        self.counts.connections += 1

    def _cut(self, sock: socket.socket) -> None:
        """One side closed: the other is closed too, and what was in flight is gone."""
        peer = self._directions[sock].sink
        for s in (sock, peer):
            self._directions.pop(s, None)
            s.close()
        self._queue = [item for item in self._queue if item[2] not in (sock, peer)]
        heapq.heapify(self._queue)

    def _schedule(self, direction: _Direction, data: bytes) -> None:
        """Queue a segment (b"": the source's close) for in-order delivery."""
        due = time.monotonic() + self.delay_s + self._rng.uniform(0.0, self.jitter_s)
        lost = False
        while self._rng.random() < self.loss:
            due += self.rto_s
            lost = True
        self.counts.retransmissions += lost and bool(data)
        if due < direction.last_due:
            self.counts.held_up += 1
            due = direction.last_due
        direction.last_due = due
        heapq.heappush(self._queue, (due, self._seq, direction.sink, data))
        self._seq += 1
        self.counts.segments += bool(data)

    def run(self) -> None:
        while not self._halt.is_set():
            now = time.monotonic()
            while self._queue and self._queue[0][0] <= now:
                _, _, sink, data = heapq.heappop(self._queue)
                if sink not in self._directions:
                    continue
                if not data:
                    self._cut(sink)  # the far side's close, after all it had sent
                    continue
                try:
                    sink.sendall(data)
                except OSError:
                    self._cut(sink)
            timeout = 0.005 if not self._queue else max(0.0, min(0.005, self._queue[0][0] - now))
            reading = [sock for sock, d in self._directions.items() if d.reading]
            ready, _, _ = select.select([self._listener, *reading], [], [], timeout)
            for sock in ready:
                if sock is self._listener:
                    self._accept()
                    continue
                direction = self._directions.get(sock)
                if direction is None:
                    continue  # cut earlier in this round
                try:
                    data = sock.recv(self.segment_bytes)
                except OSError:
                    data = b""
                if not data:
                    direction.reading = False
                self._schedule(direction, data)
