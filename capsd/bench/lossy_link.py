"""A degraded network link on loopback: a UDP relay that delays, drops and reorders datagrams.

For when `tc netem` is not available (it is not on these machines). Zenoh runs its UDP link
through it: one side connects to `listen_port`, the relay forwards to `target_port` and the
replies back. Each datagram, either way, is dropped with probability `loss` or sent after
`delay_s` plus a uniform jitter of up to `jitter_s` (datagrams closer than the jitter come
out of order). Seeded: the same seed drops the same datagrams.
"""

from __future__ import annotations

import heapq
import random
import select
import socket
import time
from dataclasses import dataclass, field

from capsd.bench.relay_thread import RelayThread


@dataclass
class LinkCounts:
    forwarded: int = 0
    dropped: int = 0
    reordered: int = 0
    by_direction: dict[str, int] = field(default_factory=lambda: {"out": 0, "back": 0})


class LossyLink(RelayThread):
    """`with LossyLink(listen_port=..., target_port=...):` relays until the block ends."""

    def __init__(
        self,
        *,
        listen_port: int,
        target_port: int,
        delay_s: float = 0.2,
        jitter_s: float = 0.04,
        loss: float = 0.1,
        seed: int = 0,
    ):
        super().__init__("lossy-link")
        self.delay_s, self.jitter_s, self.loss = delay_s, jitter_s, loss
        self.counts = LinkCounts()
        self._rng = random.Random(seed)
        self._target = ("127.0.0.1", target_port)
        self._outer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._outer.bind(("127.0.0.1", listen_port))
        self._inner = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._inner.bind(("127.0.0.1", 0))
        self._client: tuple[str, int] | None = None
        self._queue: list[tuple[float, int, str, bytes]] = []
        self._sent_seq = {"out": -1, "back": -1}
        self._seq = 0

    def _sockets(self) -> list[socket.socket]:
        return [self._outer, self._inner]

    def summary(self) -> str:
        c = self.counts
        return f"{c.forwarded} datagrams through, {c.dropped} dropped, {c.reordered} out of order"

    def _schedule(self, direction: str, data: bytes) -> None:
        if self._rng.random() < self.loss:
            self.counts.dropped += 1
            return
        due = time.monotonic() + self.delay_s + self._rng.uniform(0.0, self.jitter_s)
        heapq.heappush(self._queue, (due, self._seq, direction, data))
        self._seq += 1

    def run(self) -> None:
        while not self._halt.is_set():
            now = time.monotonic()
            while self._queue and self._queue[0][0] <= now:
                _, seq, direction, data = heapq.heappop(self._queue)
                if seq < self._sent_seq[direction]:
                    self.counts.reordered += 1
                self._sent_seq[direction] = max(self._sent_seq[direction], seq)
                try:
                    if direction == "out":
                        self._inner.sendto(data, self._target)
                    elif self._client is not None:
                        self._outer.sendto(data, self._client)
                except OSError:
                    continue  # the far end is not there (yet): a lost datagram, as on a link
                self.counts.forwarded += 1
                self.counts.by_direction[direction] += 1
            timeout = 0.005 if not self._queue else max(0.0, min(0.005, self._queue[0][0] - now))
            ready, _, _ = select.select([self._outer, self._inner], [], [], timeout)
            for sock in ready:
                try:
                    data, addr = sock.recvfrom(65535)
                except OSError:
                    continue
                if sock is self._outer:
                    self._client = addr
                    self._schedule("out", data)
                else:
                    self._schedule("back", data)
