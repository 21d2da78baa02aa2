"""A fake SICK TiM5xx on loopback that speaks CoLa-A: for tests of the TiM client.

It answers `sEN LMDscandata 1` with `sEA LMDscandata 1` and then streams `sSN LMDscandata`
telegrams at `rate_hz`; `sRN LMDscandata` gets one `sRA`. The scans come from a callback
(scan index -> ranges in mm), in random-size TCP pieces; optionally one telegram in
`corrupt_every` is garbled, and after `cut_after` telegrams the connection is cut in the middle
of a telegram (the client must reconnect); `prefix` bytes (a hostile peer's) go first once
streaming starts. Only 127.0.0.1 is ever used.
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable
from typing import Self

import numpy as np

from capsd.protocols.cola import ColaStream, format_scan, telegram

# A TiM571: 270 deg at 1/3 deg, 15 Hz; SICK angles (90 = ahead), so -45 .. 225.
START_ANGLE_DEG = -45.0
STEP_DEG = 1.0 / 3.0
SAMPLES = 811


class FakeTim:
    """`with FakeTim(scan_mm) as tim:` serves on `tim.port` until the block ends."""

    def __init__(
        self,
        scan_mm: Callable[[int], list[int]],
        *,
        rate_hz: float = 15.0,
        corrupt_every: int = 0,
        cut_after: int = 0,
        prefix: bytes = b"",
        seed: int = 0,
    ):
        self.scan_mm = scan_mm
        self.rate_hz = rate_hz
        self.corrupt_every = corrupt_every
        self.cut_after = cut_after
        self.prefix = prefix
        self.prefix_sent_at: float | None = None  # time.monotonic() when the prefix was out
        self.rng = np.random.default_rng(seed)
        self.requests: list[str] = []
        self.connections = 0
        self.sent = 0
        self._stop = threading.Event()
        self._server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._server.bind(("127.0.0.1", 0))
        self._server.listen(1)
        self._server.settimeout(0.1)
        self.port = int(self._server.getsockname()[1])
        self._thread = threading.Thread(target=self._serve, name="fake-tim", daemon=True)

    def __enter__(self) -> Self:
        self._thread.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._server.close()

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._server.accept()
            except TimeoutError:
                continue
            self.connections += 1
            with conn:
                self._session(conn)

    def _telegram(self, command: str) -> bytes:
        k = self.sent
        self.sent += 1
        text = format_scan(
            scan_counter=k,
            time_us=int(k * 1e6 / self.rate_hz),
            scan_frequency_hz=self.rate_hz,
            start_angle_deg=START_ANGLE_DEG,
            step_deg=STEP_DEG,
            ranges_mm=self.scan_mm(k),
            command=command,
        )
        if self.corrupt_every and k % self.corrupt_every == self.corrupt_every - 1:
            text = text.replace("DIST1 3F800000", "DIST1 ZZZZ")  # a garbled field
        return telegram(text)

    def _session(self, conn: socket.socket) -> None:
        conn.settimeout(0.02)
        stream = ColaStream()
        streaming = False
        next_scan = time.monotonic()
        while not self._stop.is_set():
            try:
                chunk = conn.recv(4096)
                if chunk == b"":
                    return
            except TimeoutError:
                chunk = b""
            except OSError:
                return
            for item in stream.feed(chunk):
                if not isinstance(item, str):
                    continue
                self.requests.append(item)
                if item == "sEN LMDscandata 1":
                    conn.sendall(telegram("sEA LMDscandata 1"))
                    streaming = True
                    if self.prefix:
                        self._send_in_pieces(conn, self.prefix)
                        self.prefix_sent_at = time.monotonic()
                        next_scan = time.monotonic()
                elif item == "sEN LMDscandata 0":
                    conn.sendall(telegram("sEA LMDscandata 0"))
                    streaming = False
                elif item == "sRN LMDscandata":
                    conn.sendall(self._telegram("sRA"))
            if streaming and time.monotonic() >= next_scan:
                next_scan += 1.0 / self.rate_hz
                data = self._telegram("sSN")
                if self.cut_after and self.sent == self.cut_after:
                    conn.sendall(data[: len(data) // 2])  # cut mid-telegram
                    return
                try:
                    self._send_in_pieces(conn, data)
                except OSError:
                    return

    def _send_in_pieces(self, conn: socket.socket, data: bytes) -> None:
        pos = 0
        while pos < len(data):
            n = int(self.rng.integers(1, 1500))
            conn.sendall(data[pos : pos + n])
            pos += n
