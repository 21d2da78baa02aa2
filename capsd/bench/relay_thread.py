"""A relay's thread: started on entering a `with` block, stopped and its sockets closed on exit."""

from __future__ import annotations

import socket
import threading
from typing import Self


class RelayThread(threading.Thread):
    """Subclasses relay in `run` until `_halt` is set and list their sockets in `_sockets`."""

    def __init__(self, name: str):
        super().__init__(name=name, daemon=True)
        self._halt = threading.Event()

    def __enter__(self) -> Self:
        self.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        self._halt.set()
        self.join(timeout=2.0)
        for sock in self._sockets():
            sock.close()

    def _sockets(self) -> list[socket.socket]:
        raise NotImplementedError
