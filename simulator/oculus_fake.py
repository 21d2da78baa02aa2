"""A fake Oculus on loopback that speaks the protocol: for tests of the driver.

It answers on a TCP port: after a SimpleFire it streams SimplePingResult messages (given bytes,
or built from images), optionally in random-size pieces, with one corrupted message, or
dropping the connection after N pings; `prefix` bytes (a hostile peer's) go first on each
connection. With `live_clock`, pings are taken on a fixed schedule whatever the link does (a
held-up link gets them in a burst, as from a sonar's send queue), numbered 0, 1, ... and
carrying the take time in pingStartTime as the fixtures' M1200d does (nanoseconds in a u32;
a double of seconds in v2); `taken_ns[ping_id]` is each one's take time on our clock. It can
send a status datagram to a loopback port. Only 127.0.0.1 is ever used.
"""

from __future__ import annotations

import socket
import struct
import threading
import time
from collections.abc import Sequence
from typing import Self

import numpy as np

from capsd.protocols.oculus import FIRE_V1, FIRE_V2, HEADER, MSG_SIMPLE_FIRE, OCULUS_ID, STATUS


class FakeOculus:
    """`with FakeOculus(messages) as sonar:` serves on `sonar.port` until the block ends."""

    def __init__(
        self,
        messages: Sequence[bytes],
        *,
        rate_hz: float = 20.0,
        split: bool = True,
        corrupt_every: int = 0,
        drop_after: int = 0,
        prefix: Sequence[bytes] = (),
        live_clock: bool = False,
        seed: int = 0,
    ):
        self.messages = list(messages)
        self.rate_hz = rate_hz
        self.split = split
        self.corrupt_every = corrupt_every
        self.drop_after = drop_after
        self.prefix = list(prefix)
        self.prefix_sent_at: float | None = None  # time.monotonic() when the prefix was out
        self.live_clock = live_clock
        self.taken_ns: dict[int, int] = {}
        self.rng = np.random.default_rng(seed)
        self.fires: list[bytes] = []
        self.connections = 0
        self._stop = threading.Event()
        self._server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._server.bind(("127.0.0.1", 0))
        self._server.listen(1)
        self._server.settimeout(0.1)
        self.port = int(self._server.getsockname()[1])
        self._thread = threading.Thread(target=self._serve, name="fake-oculus", daemon=True)

    def __enter__(self) -> Self:
        self._thread.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self._server.close()

    def send_status(self, port: int) -> None:
        """One status broadcast, to 127.0.0.1 only."""
        datagram = STATUS.pack(
            OCULUS_ID, 7892, 0, 1, 0, STATUS.size - HEADER.size, 0, 7892, 0, 1042, 0
        )
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            sock.sendto(datagram.ljust(142, b"\0"), ("127.0.0.1", port))

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._server.accept()
            except TimeoutError:
                continue
            self.connections += 1
            with conn:
                self._stream(conn)

    def _stream(self, conn: socket.socket) -> None:
        conn.settimeout(2.0)
        try:
            header = conn.recv(HEADER.size)
            oculus_id, _s, _d, msg_id, _v, size, _sp = HEADER.unpack(header)
            if oculus_id != OCULUS_ID or msg_id != MSG_SIMPLE_FIRE:
                return
            self.fires.append(header + conn.recv(size))
        except (OSError, struct.error):
            return
        conn.settimeout(0.0)
        try:
            for junk in self.prefix:
                self._send(conn, junk)
        except OSError:
            return
        self.prefix_sent_at = time.monotonic()
        sent = 0
        period = 1.0 / self.rate_hz
        start, start_ns = time.monotonic(), time.time_ns()
        while not self._stop.is_set():
            message = self.messages[sent % len(self.messages)]
            if self.live_clock:
                due = start + sent * period
                time.sleep(max(0.0, due - time.monotonic()))
                since_ns = int((due - start) * 1e9)
                self.taken_ns[sent] = start_ns + since_ns
                message = _with_clock(message, ping_id=sent, since_ns=since_ns)
            if self.corrupt_every and sent % self.corrupt_every == self.corrupt_every - 1:
                damaged = bytearray(message)
                damaged[200:260] = b"\xff" * 60  # a broken bearing table
                message = bytes(damaged)
            try:
                self._send(conn, message)
            except OSError:
                return
            sent += 1
            if self.drop_after and sent >= self.drop_after:
                return
            if not self.live_clock:
                time.sleep(period)

    def _send(self, conn: socket.socket, message: bytes) -> None:
        conn.setblocking(True)
        if not self.split:
            conn.sendall(message)
            return
        at = 0
        while at < len(message):
            size = int(self.rng.integers(1, 4096))
            conn.sendall(message[at : at + size])
            at += size


def _with_clock(message: bytes, *, ping_id: int, since_ns: int) -> bytes:
    """A SimplePingResult renumbered, its pingStartTime set as the sonar's clock would."""
    out = bytearray(message)
    if HEADER.unpack_from(message)[4] == 2:
        at = HEADER.size + FIRE_V2.size
        struct.pack_into("<I", out, at, ping_id)
        struct.pack_into("<d", out, at + 72, since_ns / 1e9)
    else:
        at = HEADER.size + FIRE_V1.size
        struct.pack_into("<I", out, at, ping_id)
        struct.pack_into("<I", out, at + 40, since_ns % 2**32)
    return bytes(out)
